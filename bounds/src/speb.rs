//! The bit-depth paper: the squared position error bound (SPEB) of a target located
//! from b-bit observations that take `t(b)` to arrive, while the target
//! wanders as a random walk of intensity α (position variance per second):
//!
//! ```text
//! SPEB(b) = tr((E_p{J_Q(b)} + σ0⁻² I₂)⁻¹) + 2α t(b)        (17)
//! ```
//!
//! More bits buy information (the first term falls) and cost time on a
//! rate-limited link (the second grows); the bound says which depth is
//! best. `J_Q(b)` is the position block of our `J_Y` at b bits, summed over
//! the sensors (each weighted by how often it is active), and `E_p` is over
//! the prior of the position, `N(p̄, σ0² I₂)`.

use nalgebra::{Matrix2, SMatrix};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::fisher::{expected_position_information, Measurement};
use crate::observation::ObservationModel;
use crate::State;

/// A link that delivers a message after a fixed latency plus its bits at a
/// rate, as netem's `delay` and `rate` do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateLimitedLink {
    /// Seconds before the first bit arrives.
    pub latency: f64,
    /// Bits per second.
    pub rate: f64,
}

impl RateLimitedLink {
    /// `t = latency + bits / rate`.
    pub fn delivery_delay(&self, bits: u64) -> f64 {
        self.latency + bits as f64 / self.rate
    }
}

/// The two terms of (17).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Speb {
    /// `tr((E_p{J_Q} + σ0⁻² I)⁻¹)`: what the observations leave unknown.
    pub information: f64,
    /// `2α t(b)`: how far the target wanders while they travel.
    pub motion: f64,
}

impl Speb {
    pub fn total(&self) -> f64 {
        self.information + self.motion
    }
}

/// (17) in closed form. `None` if the information is singular (no prior
/// and no observation).
pub fn speb(
    expected_information: &Matrix2<f64>,
    prior_var: f64,
    alpha: f64,
    delay: f64,
) -> Option<Speb> {
    let w = expected_information + Matrix2::identity() / prior_var;
    Some(Speb {
        information: w.try_inverse()?.trace(),
        motion: 2.0 * alpha * delay,
    })
}

/// The same bound the long way, as the appendix derives it: the 4×4 FIM of
/// `θ = [p⁺, p]` (eq. 13), the equivalent FIM of `p⁺` by its Schur
/// complement (eq. 14), and the trace of its inverse. With `α t = 0` the
/// motion is not random and `p⁺ = p`, so the EFIM is `W` itself.
pub fn speb_from_full_information(
    expected_information: &Matrix2<f64>,
    prior_var: f64,
    alpha: f64,
    delay: f64,
) -> Option<f64> {
    let w = expected_information + Matrix2::identity() / prior_var;
    if alpha * delay == 0.0 {
        return Some(w.try_inverse()?.trace());
    }
    let a = Matrix2::identity() / (alpha * delay);
    let mut j = SMatrix::<f64, 4, 4>::zeros();
    j.fixed_view_mut::<2, 2>(0, 0).copy_from(&a);
    j.fixed_view_mut::<2, 2>(0, 2).copy_from(&(-a));
    j.fixed_view_mut::<2, 2>(2, 0).copy_from(&(-a.transpose()));
    j.fixed_view_mut::<2, 2>(2, 2).copy_from(&(a + w));
    let j11 = j.fixed_view::<2, 2>(0, 0).into_owned();
    let j12 = j.fixed_view::<2, 2>(0, 2).into_owned();
    let j22 = j.fixed_view::<2, 2>(2, 2).into_owned();
    let efim = j11 - j12 * j22.try_inverse()? * j12.transpose();
    Some(efim.try_inverse()?.trace())
}

/// One sensor and the share of steps it reports in.
#[derive(Debug, Clone, Copy)]
pub struct ReportingSensor<'m> {
    pub model: &'m ObservationModel,
    pub activation: f64,
}

/// `E_p{Σ_s a_s J_Q,s(p)}` over `samples` positions drawn from
/// `N(prior_mean, prior_var I₂)`: the observations' position information,
/// averaged over the prior and over activation. `positions` is filled by
/// [`prior_positions`] so that every bit depth sees the same draws.
pub fn expected_information_over_prior(
    sensors: &[ReportingSensor<'_>],
    measurement: Measurement<'_>,
    positions: &[[f64; 2]],
) -> Matrix2<f64> {
    let mut sum = Matrix2::zeros();
    for p in positions {
        let x = State::new(p[0], p[1], 0.0, 0.0);
        for s in sensors {
            sum += expected_position_information(s.model, measurement, &x) * s.activation;
        }
    }
    sum / positions.len().max(1) as f64
}

/// Positions drawn from `N(mean, var I₂)`.
pub fn prior_positions<R: Rng + ?Sized>(
    mean: [f64; 2],
    var: f64,
    samples: usize,
    rng: &mut R,
) -> Vec<[f64; 2]> {
    let sd = var.sqrt();
    (0..samples)
        .map(|_| {
            let (u, v): (f64, f64) = (StandardNormal.sample(rng), StandardNormal.sample(rng));
            [mean[0] + sd * u, mean[1] + sd * v]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observation::SensorLaw;
    use crate::quantizer::Quantizer;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn random_information(rng: &mut ChaCha8Rng) -> Matrix2<f64> {
        let m = Matrix2::from_fn(|_, _| rng.random_range(-1.0..1.0));
        m * m.transpose() * rng.random_range(0.01..5.0)
    }

    #[test]
    fn the_closed_form_is_the_schur_complement_of_the_full_fim() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let j = random_information(&mut rng);
            let prior_var = rng.random_range(0.5..3000.0);
            let alpha = rng.random_range(0.0..20.0);
            let delay = rng.random_range(0.0..2.0);
            let closed = speb(&j, prior_var, alpha, delay).unwrap().total();
            let direct = speb_from_full_information(&j, prior_var, alpha, delay).unwrap();
            assert!(
                (closed - direct).abs() < 1e-9 * closed.max(1.0),
                "{closed} against {direct}"
            );
        }
    }

    #[test]
    fn isotropic_information_gives_two_over_its_sum_plus_the_drift() {
        let b = speb(&(Matrix2::identity() * 0.3), 100.0, 2.0, 0.25).unwrap();
        assert!((b.information - 2.0 / (0.3 + 0.01)).abs() < 1e-12);
        assert!((b.motion - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_link_delay_is_latency_plus_bits_over_rate() {
        let link = RateLimitedLink {
            latency: 0.002,
            rate: 9600.0,
        };
        assert!((link.delivery_delay(9600) - 1.002).abs() < 1e-12);
        assert_eq!(link.delivery_delay(0), 0.002);
    }

    #[test]
    fn more_bits_never_lose_information_and_approach_the_raw_bound() {
        // Three bearing sensors round a target 200 m off; σθ = 0.02 rad.
        let law = SensorLaw::Bearing {
            sigma_theta: 0.02,
            d0: 500.0,
            near_field: None,
        };
        let models: Vec<ObservationModel> = [[0.0, 0.0], [400.0, 0.0], [200.0, 400.0]]
            .iter()
            .map(|p| law.at(*p))
            .collect();
        let sensors: Vec<ReportingSensor> = models
            .iter()
            .map(|model| ReportingSensor {
                model,
                activation: 1.0,
            })
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let positions = prior_positions([200.0, 150.0], 25.0, 300, &mut rng);
        let raw = expected_information_over_prior(&sensors, Measurement::Raw, &positions);
        let bound = |j: &Matrix2<f64>| speb(j, 25.0, 0.0, 0.0).unwrap().total();
        let mut last = f64::INFINITY;
        for bits in 1..=14u8 {
            let q = Quantizer::uniform_wrapped(bits, -std::f64::consts::PI, std::f64::consts::PI)
                .unwrap();
            let j =
                expected_information_over_prior(&sensors, Measurement::Quantized(&q), &positions);
            let b = bound(&j);
            assert!(b <= last * (1.0 + 1e-9), "{bits} bits: {b} after {last}");
            assert!(
                b >= bound(&raw) * (1.0 - 1e-9),
                "{bits} bits: {b} below the raw {}",
                bound(&raw)
            );
            last = b;
        }
        assert!(
            (last / bound(&raw) - 1.0).abs() < 1e-3,
            "14 bits {last}, raw {}",
            bound(&raw)
        );
    }
}
