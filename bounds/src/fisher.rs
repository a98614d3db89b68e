//! Fisher information of one observation about the state, for a raw or a
//! quantized measurement through any [`ObservationModel`].

use crate::observation::{Evaluation, ObservationModel};
use crate::quantizer::{FisherScalars, Quantizer};
use crate::{Mat4, State};

/// How a sensor reports: the raw value, or a quantizer cell index.
#[derive(Debug, Clone, Copy)]
pub enum Measurement<'q> {
    Raw,
    Quantized(&'q Quantizer),
}

/// `J_Y(x) = Σ_i ∇h_i ∇h_iᵀ / h_i` for a quantized observation, or
/// `J_Z(x) = ∇g∇gᵀ/R + ∇R∇Rᵀ/(2R²)` for a raw one.
#[inline]
pub fn expected_information(
    model: &ObservationModel,
    measurement: Measurement<'_>,
    x: &State,
) -> Mat4 {
    information_of(&model.evaluate(x), measurement)
}

/// [`expected_information`] from a model already evaluated at the state.
#[inline]
pub fn information_of(e: &Evaluation, measurement: Measurement<'_>) -> Mat4 {
    assemble(&scalars_of(e, measurement), e)
}

/// The Fisher scalars of one observation through a model evaluated at the
/// state: `(1/R, 0, 1/(2R²))` raw, the quantizer's otherwise.
#[inline]
pub fn scalars_of(e: &Evaluation, measurement: Measurement<'_>) -> FisherScalars {
    scalars_of_mean_and_variance(e.g, e.r, measurement)
}

/// [`scalars_of`] from the model's mean g and variance R alone, all the
/// scalars depend on.
#[inline]
pub fn scalars_of_mean_and_variance(g: f64, r: f64, measurement: Measurement<'_>) -> FisherScalars {
    match measurement {
        Measurement::Raw => FisherScalars::raw(r),
        Measurement::Quantized(q) => q.fisher_scalars(g, r),
    }
}

/// The position block of [`expected_information`], for models whose g and R
/// depend on the position only (the velocity rows and columns are zero).
#[inline]
pub fn expected_position_information(
    model: &ObservationModel,
    measurement: Measurement<'_>,
    x: &State,
) -> nalgebra::Matrix2<f64> {
    position_information_of(&model.evaluate(x), measurement)
}

/// [`expected_position_information`] from a model already evaluated at
/// the state.
#[inline]
pub fn position_information_of(
    e: &Evaluation,
    measurement: Measurement<'_>,
) -> nalgebra::Matrix2<f64> {
    position_information_from(&scalars_of(e, measurement), e)
}

/// The position block of [`assemble`]: `J_Y` from the Fisher scalars and
/// the model's gradients, for a model of the position only.
#[inline]
pub fn position_information_from(s: &FisherScalars, e: &Evaluation) -> nalgebra::Matrix2<f64> {
    let [xx, xy, yy] = position_information_entries(s, e);
    nalgebra::Matrix2::new(xx, xy, xy, yy)
}

/// The three distinct entries `(xx, xy, yy)` of the symmetric
/// [`position_information_from`]: what the per-particle sums add up, at
/// half the arithmetic of the full matrices.
#[inline]
pub fn position_information_entries(s: &FisherScalars, e: &Evaluation) -> [f64; 3] {
    position_entries(
        (s.gg, s.gr, s.rr),
        (e.grad_g[0], e.grad_g[1]),
        (e.grad_r[0], e.grad_r[1]),
    )
}

/// [`position_information_entries`] from the scalars `(gg, gr, rr)` and
/// the gradients' position entries: one lane of the batched sums.
#[inline(always)]
pub fn position_entries(
    (gg, gr, rr): (f64, f64, f64),
    (gx, gy): (f64, f64),
    (rx, ry): (f64, f64),
) -> [f64; 3] {
    // gg ∇g∇gᵀ + gr (∇g∇Rᵀ + ∇R∇gᵀ) + rr ∇R∇Rᵀ, entry by entry.
    let (ax, ay) = (gg * gx + gr * rx, gg * gy + gr * ry);
    let (bx, by) = (gr * gx + rr * rx, gr * gy + rr * ry);
    [gx * ax + rx * bx, gx * ay + rx * by, gy * ay + ry * by]
}

/// `gg ∇g∇gᵀ + gr (∇g∇Rᵀ + ∇R∇gᵀ) + rr ∇R∇Rᵀ`.
#[inline]
pub fn assemble(s: &FisherScalars, e: &Evaluation) -> Mat4 {
    let gg = e.grad_g * e.grad_g.transpose();
    if e.grad_r == State::zeros() {
        return gg * s.gg;
    }
    let gr = e.grad_g * e.grad_r.transpose();
    gg * s.gg + (gr + gr.transpose()) * s.gr + e.grad_r * e.grad_r.transpose() * s.rr
}

/// `∇_x h_i(x) = (∂h/∂g) ∇g + (∂h/∂R) ∇R` for cell `index`.
pub fn cell_probability_gradient(
    model: &ObservationModel,
    q: &Quantizer,
    index: u32,
    x: &State,
) -> State {
    let e = model.evaluate(x);
    let s = q.sensitivity(index, e.g, e.r);
    e.grad_g * s.d_mean + e.grad_r * s.d_variance
}

/// `ln h_i(x)`.
pub fn ln_cell_probability(model: &ObservationModel, q: &Quantizer, index: u32, x: &State) -> f64 {
    let e = model.evaluate(x);
    q.ln_probability(index, e.g, e.r)
}

/// `∇ ln h_i(x) = ∇h_i / h_i`, from the analytic sensitivities, finite
/// even where `h_i` underflows.
pub fn score(model: &ObservationModel, q: &Quantizer, index: u32, x: &State) -> State {
    let e = model.evaluate(x);
    let (d_mean, d_variance) = q.ln_sensitivity(index, e.g, e.r);
    e.grad_g * d_mean + e.grad_r * d_variance
}

/// Observed information `−∇² ln h_y(x)` at the received cell `y`: central
/// differences of the analytic score, symmetrized. Used by the auxiliary-FIM
/// baseline (the selection paper Theorem 1).
///
/// The models give first derivatives only; differencing the analytic score
/// keeps one order of accuracy over differencing `ln h` twice.
pub fn observed_information(
    model: &ObservationModel,
    q: &Quantizer,
    index: u32,
    x: &State,
) -> Mat4 {
    let mut hess = Mat4::zeros();
    // A law of the position alone has a score that no velocity moves: those
    // columns are exactly zero, and differencing them would cost half the time.
    let moved = if model.depends_on_position_only() {
        2
    } else {
        4
    };
    for k in 0..moved {
        let step = 1e-5 * x[k].abs().max(1.0);
        let mut up = *x;
        let mut down = *x;
        up[k] += step;
        down[k] -= step;
        let column = (score(model, q, index, &up) - score(model, q, index, &down)) / (2.0 * step);
        hess.set_column(k, &column);
    }
    -(hess + hess.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observation::SensorLaw;
    use crate::testing::{central_gradient, random_state};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    fn bearing() -> ObservationModel {
        SensorLaw::Bearing {
            sigma_theta: 0.02,
            d0: 500.0,
            near_field: None,
        }
        .at([700.0, 300.0])
    }

    /// Far from the received cell `h` and `∇h` both underflow to zero; the
    /// score (and so the observed information of the auxiliary FIM) must
    /// stay finite, and agree with `∇h/h` where both are representable.
    #[test]
    fn score_is_finite_far_from_the_received_cell() {
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let model = bearing();
        // 100 m from the sensor at bearing 0.3 rad; the received cell is
        // 1.5 rad away (about 70 σ).
        let x = State::new(
            700.0 + 100.0 * 0.3_f64.sin(),
            300.0 + 100.0 * 0.3_f64.cos(),
            1.0,
            1.0,
        );
        let far = q.encode(1.8);
        assert_eq!(
            q.sensitivity(far, model.evaluate(&x).g, model.evaluate(&x).r)
                .probability,
            0.0
        );
        let s = score(&model, &q, far, &x);
        assert!(s.iter().all(|v| v.is_finite()), "{s}");
        assert!(observed_information(&model, &q, far, &x)
            .iter()
            .all(|v| v.is_finite()));
        // Near the cell, the stable form equals ∇h/h.
        let near = q.encode(0.31);
        let e = model.evaluate(&x);
        let direct = cell_probability_gradient(&model, &q, near, &x)
            / q.sensitivity(near, e.g, e.r).probability;
        let stable = score(&model, &q, near, &x);
        assert!(
            (direct - stable).norm() <= 1e-9 * direct.norm(),
            "{direct} vs {stable}"
        );
    }

    #[test]
    fn cell_probability_gradient_matches_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let q8 = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let q3 = Quantizer::uniform_wrapped(3, -PI, PI).unwrap();
        let rss = SensorLaw::Rss {
            p0: -30.0,
            zeta: 3.0,
            d0: 1.0,
            sigma: 4.0,
            near_field: None,
        }
        .at([700.0, 300.0]);
        let qr = Quantizer::uniform(4, -110.0, -40.0).unwrap();
        let mut checked = 0;
        for n in 0..3000 {
            let mut x = random_state(&mut rng, 1500.0, 10.0);
            if n % 5 == 0 {
                // Due south of the sensor: bearing at the ±π wrap.
                x[0] = 700.0 + (n as f64 % 7.0 - 3.0) * 0.3;
                x[1] = 300.0 - 50.0 - n as f64 * 0.05;
            }
            for (model, q) in [(bearing(), &q8), (bearing(), &q3), (rss.clone(), &qr)] {
                let e = model.evaluate(&x);
                // The cells that matter: the one holding g and its neighbours.
                let centre = q.encode(e.g) as i64;
                for di in -2..=2 {
                    let i = (centre + di).rem_euclid(q.cells() as i64) as u32;
                    if q.probability(i, e.g, e.r) < 1e-8 {
                        continue;
                    }
                    let analytic = cell_probability_gradient(&model, q, i, &x);
                    let numeric = central_gradient(
                        |y| {
                            let e = model.evaluate(y);
                            q.probability(i, e.g, e.r)
                        },
                        &x,
                        1e-3,
                        false,
                    );
                    let scale = analytic.abs().max().max(1e-9);
                    assert!(
                        (analytic - numeric).abs().max() / scale < 1e-4,
                        "cell {i} at {x:?}: {analytic:?} vs {numeric:?}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 10_000, "only {checked} gradients checked");
    }

    #[test]
    fn quantized_information_approaches_raw_information_with_bits() {
        let x = State::new(900.0, 800.0, 3.0, -2.0);
        let raw = expected_information(&bearing(), Measurement::Raw, &x);
        let mut prev = 0.0;
        for bits in [2u8, 4, 6, 8, 10, 12] {
            let q = Quantizer::uniform_wrapped(bits, -PI, PI).unwrap();
            let j = expected_information(&bearing(), Measurement::Quantized(&q), &x);
            let ratio = j.trace() / raw.trace();
            assert!(ratio > prev && ratio <= 1.0 + 1e-9, "{bits} bits: {ratio}");
            prev = ratio;
        }
        assert!(prev > 0.999, "{prev}");
    }

    #[test]
    fn quantized_information_is_symmetric_positive_semidefinite() {
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for _ in 0..500 {
            let x = random_state(&mut rng, 1500.0, 10.0);
            let j = expected_information(&bearing(), Measurement::Quantized(&q), &x);
            assert!((j - j.transpose()).abs().max() <= 1e-12 * j.abs().max());
            let eig = j.symmetric_eigen().eigenvalues;
            assert!(eig.min() >= -1e-9 * eig.max(), "{eig:?}");
        }
    }

    #[test]
    fn observed_information_matches_second_differences_of_ln_h() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let q = Quantizer::uniform_wrapped(6, -PI, PI).unwrap();
        let model = bearing();
        for _ in 0..200 {
            let x = random_state(&mut rng, 1500.0, 10.0);
            let e = model.evaluate(&x);
            let y = q.encode(e.g);
            let analytic = observed_information(&model, &q, y, &x);
            // Second central differences of ln h with a coarser step.
            let f = |z: &State| ln_cell_probability(&model, &q, y, z);
            let mut numeric = Mat4::zeros();
            let h = 0.05;
            for a in 0..2 {
                for b in 0..2 {
                    let mut pp = x;
                    pp[a] += h;
                    pp[b] += h;
                    let mut pm = x;
                    pm[a] += h;
                    pm[b] -= h;
                    let mut mp = x;
                    mp[a] -= h;
                    mp[b] += h;
                    let mut mm = x;
                    mm[a] -= h;
                    mm[b] -= h;
                    numeric[(a, b)] = -(f(&pp) - f(&pm) - f(&mp) + f(&mm)) / (4.0 * h * h);
                }
            }
            let scale = analytic.abs().max().max(1e-9);
            assert!(
                (analytic - numeric).abs().max() / scale < 1e-3,
                "{analytic}\n{numeric}"
            );
            // Velocity does not enter a bearing: that block is exactly zero.
            assert_eq!(analytic.fixed_view::<2, 2>(2, 2).abs().max(), 0.0);
        }
    }

    /// The information equality: averaged over the cells y ~ h(y | x), the
    /// observed information at x is the expected information J_Y(x).
    #[test]
    fn observed_information_averages_to_the_expected_information() {
        let model = bearing();
        for bits in [3u8, 8] {
            let q = Quantizer::uniform_wrapped(bits, -PI, PI).unwrap();
            for x in [
                State::new(900.0, 800.0, 3.0, -2.0),
                State::new(720.0, 360.0, 0.0, 0.0),
            ] {
                let e = model.evaluate(&x);
                let mut average = Mat4::zeros();
                for y in 0..q.cells() as u32 {
                    let p = q.probability(y, e.g, e.r);
                    if p > 1e-14 {
                        average += observed_information(&model, &q, y, &x) * p;
                    }
                }
                let expected = expected_information(&model, Measurement::Quantized(&q), &x);
                let raw = expected_information(&model, Measurement::Raw, &x);
                let err = (average - expected).abs().max() / raw.abs().max();
                assert!(
                    err < 1e-4,
                    "{bits} bits at {x:?}: {err}\n{average}\n{expected}"
                );
            }
        }
    }

    #[test]
    fn position_block_is_the_whole_information_of_a_bearing() {
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let x = State::new(900.0, 800.0, 3.0, -2.0);
        for m in [Measurement::Quantized(&q), Measurement::Raw] {
            let full = expected_information(&bearing(), m, &x);
            let block = expected_position_information(&bearing(), m, &x);
            assert!(
                (full.fixed_view::<2, 2>(0, 0) - block).abs().max() <= 1e-15 * block.abs().max()
            );
            assert_eq!(full.fixed_view::<2, 2>(2, 2).abs().max(), 0.0);
        }
    }

    #[test]
    fn raw_information_of_a_linear_sensor_is_h_h_over_r() {
        let m = SensorLaw::Linear {
            h: [1.0, 0.0, 0.0, 0.0],
            r: 4.0,
        }
        .at([0.0, 0.0]);
        let j = expected_information(&m, Measurement::Raw, &State::zeros());
        assert_eq!(j[(0, 0)], 0.25);
        assert_eq!(j.sum(), 0.25);
    }
}
