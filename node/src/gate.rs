//! The innovation gate: an observation too far from what the predicted
//! particles expect is left out of the update, as a Kalman filter's
//! validation gate leaves out clutter. It is the simple defence against a
//! Byzantine sensor that reports a plausible but false target.
//!
//! The gate tests the normalized innovation squared `ν²/S` against a
//! threshold (a χ²₁ quantile: 10.83 leaves out an honest observation one
//! time in a thousand). `S` adds up the spread of the predicted measurement
//! over the particles, the sensor's noise, and the quantizer's cell
//! (`Δ²/12`). A particle cloud that has collapsed would make the spread too
//! small and the gate reject honest observations, so the spread has a
//! floor from the local conditional PCRLB (the CQ/dPCRLB paper): no estimator's
//! covariance is below `J⁻¹`, so neither is the spread of `g` below
//! `∇gᵀ J⁻¹ ∇g`.

use bounds::{wrap_angle, Mat4, State};
use nalgebra::Cholesky;

use crate::sensing::{Observation, ObservedValue, SensingModel};

/// `ν²/S` of one observation against the predicted particles (equally
/// weighted), with `information` (the local bound's J) setting the floor.
pub fn normalized_innovation_squared(
    model: &SensingModel,
    obs: &Observation,
    particles: &[State],
    information: Option<&Mat4>,
) -> f64 {
    let sensor = &model.sensors[obs.sensor as usize];
    let angular = sensor.is_angular();
    let (z, cell_variance) = match (obs.value, &model.quantizer) {
        (ObservedValue::Cell(c), Some(q)) => (q.representative(c), q.cell_width(c).powi(2) / 12.0),
        (ObservedValue::Raw(v), _) => (v, 0.0),
        (ObservedValue::Cell(_), None) => return f64::INFINITY,
    };
    let n = particles.len().max(1) as f64;
    // One pass: each particle's g as an offset from the first particle's
    // (wrapped, for angles), whose mean and spread are those of g itself.
    let Some(first) = particles.first() else {
        return f64::INFINITY;
    };
    let reference = sensor.evaluate(first).g;
    let offset = |g: f64| {
        if angular {
            wrap_angle(g - reference)
        } else {
            g - reference
        }
    };
    let (mut sum, mut sum_sq, mut noise) = (0.0, 0.0, 0.0);
    for x in particles {
        let e = sensor.evaluate(x);
        let d = offset(e.g);
        sum += d;
        sum_sq += d * d;
        noise += e.r;
    }
    let mean = sum / n;
    let spread = (sum_sq / n - mean * mean).max(0.0);
    let innovation = offset(z) - mean;
    let innovation = if angular {
        wrap_angle(innovation)
    } else {
        innovation
    };
    let floor = information.map_or(0.0, |j| bound_floor(model, obs, particles, j));
    let s = spread.max(floor) + noise / n + cell_variance;
    innovation * innovation / s
}

/// `∇gᵀ J⁻¹ ∇g` at the particles' mean; 0 if J cannot be inverted.
fn bound_floor(model: &SensingModel, obs: &Observation, particles: &[State], j: &Mat4) -> f64 {
    let Some(chol) = Cholesky::new(*j) else {
        return 0.0;
    };
    let mean = particles.iter().sum::<State>() / particles.len().max(1) as f64;
    let grad = model.sensors[obs.sensor as usize].evaluate(&mean).grad_g;
    grad.dot(&(chol.inverse() * grad))
}

/// The observations that pass the gate, and how many did not.
pub fn gate(
    model: &SensingModel,
    observations: &[Observation],
    particles: &[State],
    information: Option<&Mat4>,
    threshold: f64,
) -> (Vec<Observation>, u16) {
    let kept: Vec<Observation> = observations
        .iter()
        .filter(|o| normalized_innovation_squared(model, o, particles, information) <= threshold)
        .copied()
        .collect();
    let rejected = (observations.len() - kept.len()) as u16;
    (kept, rejected)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounds::SensorLaw;
    use fusion_graph::Scenario;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn model(law: SensorLaw, quantized: bool) -> SensingModel {
        let models = Scenario::default_scenario().models().unwrap();
        SensingModel {
            dynamics: models.dynamics,
            sensors: vec![law.at([250.0, 250.0])].into(),
            quantizer: quantized.then_some(models.quantizer.unwrap()),
        }
    }

    /// Particles around `mean`, position std `sigma`, velocity fixed.
    fn cloud(mean: State, sigma: f64, n: usize, seed: u64) -> Vec<State> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d = Normal::new(0.0, sigma).unwrap();
        (0..n)
            .map(|_| mean + State::new(d.sample(&mut rng), d.sample(&mut rng), 0.0, 0.0))
            .collect()
    }

    fn raw(value: f64) -> Observation {
        Observation {
            sensor: 0,
            value: ObservedValue::Raw(value),
        }
    }

    #[test]
    fn a_linear_gaussian_innovation_is_the_kalman_filters() {
        // z = x + v, v ~ N(0, 4); x ~ N(4, 9): S = 9 + 4, ν = 10 − 4.
        let m = model(
            SensorLaw::Linear {
                h: [1.0, 0.0, 0.0, 0.0],
                r: 4.0,
            },
            false,
        );
        let particles = cloud(State::new(4.0, 0.0, 0.0, 0.0), 3.0, 40_000, 1);
        let nis = normalized_innovation_squared(&m, &raw(10.0), &particles, None);
        let exact = 36.0 / 13.0;
        assert!((nis / exact - 1.0).abs() < 0.03, "{nis} against {exact}");
    }

    #[test]
    fn honest_bearings_pass_and_a_phantoms_do_not() {
        let m = model(
            SensorLaw::Bearing {
                sigma_theta: 0.02,
                d0: 500.0,
                near_field: None,
            },
            true,
        );
        let q = m.quantizer.clone().unwrap();
        let truth = State::new(886.4, 886.4, -6.0, -7.0);
        let particles = cloud(truth, 20.0, 2000, 2);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let cell = |x: &State, rng: &mut ChaCha8Rng| Observation {
            sensor: 0,
            value: ObservedValue::Cell(q.encode(m.sensors[0].sample(x, rng))),
        };
        let phantom = truth + State::new(600.0, 0.0, 0.0, 0.0);
        let (mut honest_out, mut phantom_in) = (0, 0);
        for _ in 0..1000 {
            let (_, h) = gate(&m, &[cell(&truth, &mut rng)], &particles, None, 10.83);
            honest_out += h;
            let (_, p) = gate(&m, &[cell(&phantom, &mut rng)], &particles, None, 10.83);
            phantom_in += 1 - p;
        }
        // About 1 in 1000 honest ones is expected out; a few more from the
        // quantizer's and the Monte Carlo spread's approximations.
        assert!(honest_out <= 10, "{honest_out} honest observations gated");
        assert!(phantom_in <= 10, "{phantom_in} phantom observations passed");
    }

    #[test]
    fn the_bound_keeps_a_collapsed_cloud_from_gating_honest_observations() {
        let m = model(
            SensorLaw::Bearing {
                sigma_theta: 0.02,
                d0: 500.0,
                near_field: None,
            },
            false,
        );
        let truth = State::new(886.4, 886.4, -6.0, -7.0);
        // Every particle at the truth: no spread at all.
        let collapsed = vec![truth; 100];
        let e = m.sensors[0].evaluate(&truth);
        // 4 noise standard deviations off.
        let obs = raw(e.g + 4.0 * e.r.sqrt());
        let alone = normalized_innovation_squared(&m, &obs, &collapsed, None);
        assert!((alone - 16.0).abs() < 1e-6, "{alone}");
        // A bound of 100 m per axis: ∇gᵀ J⁻¹ ∇g = 10⁴ / d² (|∇g| = 1/d).
        let j = Mat4::from_diagonal(&State::new(1e-4, 1e-4, 1.0, 1.0));
        let floored = normalized_innovation_squared(&m, &obs, &collapsed, Some(&j));
        let range2 = (636.4f64).hypot(636.4).powi(2);
        let expected = 16.0 * e.r / (1e4 / range2 + e.r);
        assert!(
            (floored / expected - 1.0).abs() < 1e-6,
            "{floored} against {expected}"
        );
        assert!(floored < 10.83 && alone > 10.83);
    }
}
