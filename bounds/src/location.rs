//! Where a static target is, from quantized amplitudes (dissertation
//! ch. 6): the exact CRLB of a deployment, its closed form for a dense
//! network, the thresholds that serve them, and the ML estimate.
//!
//! Sensor i at distance d_i from the target at θ = (x_t, y_t) receives
//! `s_i = g(d_i) + n_i`, `n_i ~ N(0, σ²)`, and reports the cell of its
//! quantizer (or `s_i` itself). With `I(a)` the Fisher information of one
//! report about the amplitude a (`1/σ²` raw; `γ/(2πσ²)` quantized, the
//! cells' `Σ (φ(u_l) − φ(u_{l+1}))² / p_l`), the chain rule through
//! `∂a/∂θ = g'(d)/d · (θ − sensor)` gives
//!
//! ```text
//! J = Σ_i β_i G_i,  β_i = (g'(d_i)/d_i)² I(g(d_i)),
//! G_i = [(x_i − x_t)², (x_i − x_t)(y_i − y_t); …, (y_i − y_t)²]
//! ```
//!
//! (Theorem 6.2, eqs. 6.13–6.14; Theorem 6.1 raw). For sensors spread
//! uniformly at density λ, the law of large numbers turns the sum into
//! `J ≈ c I₂` with `c = λπ ∫₀^R (g'(r)/r)² r³ I(g(r)) dr` (Theorem 6.3,
//! eq. 6.29, written with `I` for `γ̃/(2πσ²)`).

use nalgebra::Matrix2;

use crate::fisher::Measurement;
use crate::quantizer::Quantizer;

mod thresholds;
pub use thresholds::{
    optimize_thresholds, optimize_thresholds_from, optimize_weighed_thresholds, uniform_quantizer,
    WeighedAmplitudes, MAX_SWEEPS,
};

/// How the target's signal amplitude falls with distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DecayLaw {
    /// `g(d) = √P₀ e^{−αd²/2}` (eq. 6.38).
    Gaussian { p0: f64, alpha: f64 },
    /// `g(d) = √(P₀ / (1 + dⁿ))`, `d₀ = 1` (eq. 6.41's model).
    PowerLaw { p0: f64, exponent: f64 },
}

/// A scenario's amplitude law `√(P₀/(1 + α dⁿ))` as this module's unit
/// power law, with α and the noise σ; `None` for another law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmplitudeLaw {
    pub law: DecayLaw,
    pub alpha: f64,
    pub sigma: f64,
}

impl AmplitudeLaw {
    /// The amplitude law's, if `law` is one.
    pub fn of(law: &crate::Law) -> Option<Self> {
        let a = law.downcast_ref::<crate::observation::Amplitude>()?;
        Some(Self {
            law: DecayLaw::PowerLaw {
                p0: a.p0,
                exponent: a.exponent,
            },
            alpha: a.alpha,
            sigma: a.sigma,
        })
    }

    /// `α^{1/n}`: the law at distance d is the unit power law at
    /// `α^{1/n} d`.
    pub fn distance_scale(&self) -> f64 {
        match self.law {
            DecayLaw::PowerLaw { exponent, .. } => self.alpha.powf(1.0 / exponent),
            DecayLaw::Gaussian { .. } => 1.0,
        }
    }
}

impl DecayLaw {
    pub fn p0(&self) -> f64 {
        match *self {
            DecayLaw::Gaussian { p0, .. } | DecayLaw::PowerLaw { p0, .. } => p0,
        }
    }

    /// `g(d)`.
    pub fn amplitude(&self, d: f64) -> f64 {
        match *self {
            DecayLaw::Gaussian { p0, alpha } => p0.sqrt() * (-alpha * d * d / 2.0).exp(),
            DecayLaw::PowerLaw { p0, exponent } => (p0 / (1.0 + d.powf(exponent))).sqrt(),
        }
    }

    /// `g` at the squared distance `d²`: [`amplitude`](Self::amplitude)
    /// without the `hypot` a distance costs and, for the power law's
    /// n = 4 and 2, without a `powf`. It agrees with `amplitude` to a few
    /// units in the last place; the ML search calls it a billion times.
    pub fn amplitude_at_squared_distance(&self, d2: f64) -> f64 {
        match *self {
            DecayLaw::Gaussian { p0, alpha } => p0.sqrt() * (-alpha * d2 / 2.0).exp(),
            DecayLaw::PowerLaw { p0, exponent } => {
                let dn = if exponent == 4.0 {
                    d2 * d2
                } else if exponent == 2.0 {
                    d2
                } else {
                    d2.powf(exponent / 2.0)
                };
                (p0 / (1.0 + dn)).sqrt()
            }
        }
    }

    /// `(g'(d)/d)²`, written so that it is finite at d = 0: `α²P₀e^{−αd²}`
    /// and `n²P₀ d^{2n−4} / (4 (1 + dⁿ)³)`.
    pub fn slope_over_distance_squared(&self, d: f64) -> f64 {
        match *self {
            DecayLaw::Gaussian { p0, alpha } => alpha * alpha * p0 * (-alpha * d * d).exp(),
            DecayLaw::PowerLaw { p0, exponent: n } => {
                n * n * p0 * d.powf(2.0 * n - 4.0) / (4.0 * (1.0 + d.powf(n)).powi(3))
            }
        }
    }

    /// The distance at which the signal's power `g²` falls to `εP₀`: the
    /// radius R beyond which the closed form neglects the sensors.
    pub fn reach(&self, epsilon: f64) -> f64 {
        match *self {
            DecayLaw::Gaussian { alpha, .. } => ((1.0 / epsilon).ln() / alpha).sqrt(),
            DecayLaw::PowerLaw { exponent, .. } => (1.0 / epsilon - 1.0).powf(1.0 / exponent),
        }
    }
}

/// `I(a)`: the Fisher information of one sensor's report about its mean
/// amplitude a, `1/σ²` raw; quantized, the cells within the quantizer's
/// window of the mean summed (those beyond add less than its tolerance),
/// which spares the sum most of a wide quantizer's cells.
pub fn amplitude_information(report: Measurement<'_>, a: f64, sigma: f64) -> f64 {
    match report {
        Measurement::Raw => 1.0 / (sigma * sigma),
        Measurement::Quantized(q) => q.fisher_scalars_exact(a, sigma * sigma).gg,
    }
}

/// The exact FIM of a deployment about the target's position (Theorems
/// 6.1 and 6.2): `Σ_i β_i G_i`.
pub fn exact_information(
    law: DecayLaw,
    report: Measurement<'_>,
    sigma: f64,
    sensors: &[[f64; 2]],
    target: [f64; 2],
) -> Matrix2<f64> {
    let mut j = Matrix2::zeros();
    for s in sensors {
        let (dx, dy) = (s[0] - target[0], s[1] - target[1]);
        let d = dx.hypot(dy);
        let beta = law.slope_over_distance_squared(d)
            * amplitude_information(report, law.amplitude(d), sigma);
        j += Matrix2::new(dx * dx, dx * dy, dx * dy, dy * dy) * beta;
    }
    j
}

/// Simpson's rule over [0, R] with this many intervals: the closed form
/// comes within 2·10⁻⁹ relative of the raw Gaussian law's exact value
/// (a test checks it), ample beside a deployment's spread around it.
const SIMPSON_INTERVALS: usize = 1000;

/// Simpson's rule over [0, R]: the step h and the nodes with their
/// coefficients (1, 4, 2, …, 4, 1), ends first, so that `∫₀^R f ≈
/// (h/3) Σ c f(r)` summed in this order is [`integrate`]'s sum.
fn simpson_nodes(radius: f64) -> (f64, impl Iterator<Item = (f64, f64)>) {
    let n = SIMPSON_INTERVALS;
    let h = radius / n as f64;
    let ends = [(0.0, 1.0), (radius, 1.0)];
    let inner = (1..n).map(move |k| (k as f64 * h, if k % 2 == 1 { 4.0 } else { 2.0 }));
    (h, ends.into_iter().chain(inner))
}

/// `∫₀^R f(r) dr` by Simpson's rule.
fn integrate(radius: f64, f: impl Fn(f64) -> f64) -> f64 {
    let (h, nodes) = simpson_nodes(radius);
    nodes.fold(0.0, |sum, (r, c)| sum + f(r) * c) * h / 3.0
}

/// The closed-form FIM's scale c (Theorem 6.3): `J ≈ c I₂` for sensors at
/// density λ within R of the target, `c = λπ ∫₀^R (g'(r)/r)² r³ I(g(r)) dr`.
pub fn closed_form_information(
    law: DecayLaw,
    report: Measurement<'_>,
    sigma: f64,
    density: f64,
    radius: f64,
) -> f64 {
    density
        * std::f64::consts::PI
        * integrate(radius, |r| {
            law.slope_over_distance_squared(r)
                * r.powi(3)
                * amplitude_information(report, law.amplitude(r), sigma)
        })
}

/// How far one deployment's J strays from the closed form (eqs. 6.36 and
/// 6.37): the variances of `J₁₁/E[J₁₁]` and of `J₁₂/E[J₁₁]` for N sensors
/// uniform within R, `(M₂ − M₁²)/(N M₁²)` and `M₂/(3N M₁²)`, with `M₁`,
/// `M₂` the moments of one sensor's `(g'/d)² (x − x_t)² I`.
pub fn relative_information_variance(
    law: DecayLaw,
    report: Measurement<'_>,
    sigma: f64,
    radius: f64,
    sensors: f64,
) -> (f64, f64) {
    let term = |r: f64| {
        law.slope_over_distance_squared(r) * amplitude_information(report, law.amplitude(r), sigma)
    };
    let r2 = radius * radius;
    let m1 = integrate(radius, |r| term(r) * r.powi(3)) / r2;
    let m2 = 0.75 * integrate(radius, |r| term(r).powi(2) * r.powi(5)) / r2;
    (
        (m2 - m1 * m1) / (sensors * m1 * m1),
        m2 / (3.0 * sensors * m1 * m1),
    )
}

/// `tr J⁻¹`: the CRLB on the sum of the two coordinates' MSEs.
pub fn crlb_trace(j: &Matrix2<f64>) -> Option<f64> {
    let det = j[(0, 0)] * j[(1, 1)] - j[(0, 1)] * j[(1, 0)];
    (det > 0.0 && det.is_finite()).then(|| (j[(0, 0)] + j[(1, 1)]) / det)
}

/// `ρ = J₁₂ / √(J₁₁ J₂₂)` (eq. 6.44).
pub fn correlation(j: &Matrix2<f64>) -> f64 {
    j[(0, 1)] / (j[(0, 0)] * j[(1, 1)]).sqrt()
}

/// `ln p(D | θ)` (eq. 6.11): the reports' cells' log-probabilities at a
/// candidate position.
pub fn log_likelihood(
    law: DecayLaw,
    quantizer: &Quantizer,
    sigma: f64,
    sensors: &[[f64; 2]],
    cells: &[u32],
    theta: [f64; 2],
) -> f64 {
    sensors
        .iter()
        .zip(cells)
        .map(|(s, &cell)| {
            let (dx, dy) = (s[0] - theta[0], s[1] - theta[1]);
            let a = law.amplitude_at_squared_distance(dx * dx + dy * dy);
            quantizer.ln_probability(cell, a, sigma * sigma)
        })
        .sum()
}

/// The ML estimate of the position: the best point of a grid over
/// `[lo, hi]²` with `step`, refined by a pattern search (halving its step
/// to 10⁻⁶) from each of the grid's `starts` best points; the highest
/// likelihood wins. The chapter's grid search and local optimizer, made
/// deterministic.
pub fn ml_estimate(
    likelihood: impl Fn([f64; 2]) -> f64,
    lo: f64,
    hi: f64,
    step: f64,
    starts: usize,
) -> [f64; 2] {
    let n = ((hi - lo) / step).floor() as usize + 1;
    let mut grid: Vec<(f64, [f64; 2])> = (0..n * n)
        .map(|k| {
            let p = [lo + step * (k / n) as f64, lo + step * (k % n) as f64];
            (likelihood(p), p)
        })
        .collect();
    grid.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best = (f64::NEG_INFINITY, [0.0, 0.0]);
    for &(v0, p0) in grid.iter().take(starts.max(1)) {
        let (mut v, mut p) = (v0, p0);
        let mut h = step / 2.0;
        while h > 1e-6 {
            let mut moved = false;
            for (dx, dy) in [(h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h)] {
                let q = [p[0] + dx, p[1] + dy];
                let w = likelihood(q);
                if w > v {
                    (v, p, moved) = (w, q, true);
                    break;
                }
            }
            if !moved {
                h /= 2.0;
            }
        }
        if v > best.0 {
            best = (v, p);
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    pub(super) const GAUSSIAN: DecayLaw = DecayLaw::Gaussian {
        p0: 1e4,
        alpha: 1.0,
    };
    pub(super) const POWER: DecayLaw = DecayLaw::PowerLaw {
        p0: 1e4,
        exponent: 4.0,
    };

    /// Sensors uniform over a square of `side` centred on the origin.
    pub(super) fn deploy(rng: &mut ChaCha8Rng, side: f64, density: f64) -> Vec<[f64; 2]> {
        let n = (density * side * side).round() as usize;
        (0..n)
            .map(|_| {
                [
                    rng.random_range(-side / 2.0..side / 2.0),
                    rng.random_range(-side / 2.0..side / 2.0),
                ]
            })
            .collect()
    }

    #[test]
    fn the_slope_term_is_the_derivative_of_the_amplitude() {
        for law in [GAUSSIAN, POWER] {
            for d in [0.3, 0.9, 1.7, 3.1] {
                let h = 1e-6;
                let slope = (law.amplitude(d + h) - law.amplitude(d - h)) / (2.0 * h);
                let expected = (slope / d).powi(2);
                let got = law.slope_over_distance_squared(d);
                assert!(
                    (got / expected - 1.0).abs() < 1e-6,
                    "{law:?} at {d}: {got} vs {expected}"
                );
            }
            assert!((law.amplitude(law.reach(1e-6)).powi(2) / law.p0() - 1e-6).abs() < 1e-12);
        }
    }

    #[test]
    fn the_amplitude_at_the_squared_distance_is_the_amplitude() {
        let cube = DecayLaw::PowerLaw {
            p0: 1e4,
            exponent: 3.0,
        };
        for law in [GAUSSIAN, POWER, cube] {
            for d in [0.0, 0.01, 0.3, 1.0, 1.7, 3.1, 9.0, 40.0] {
                let (want, got) = (law.amplitude(d), law.amplitude_at_squared_distance(d * d));
                assert!(
                    (got - want).abs() <= 1e-14 * want,
                    "{law:?} at {d}: {got} against {want}"
                );
            }
        }
    }

    /// Raw reports and the Gaussian law: `c = λπ α²P₀/σ² ∫₀^∞ r³ e^{−αr²} dr
    /// = λπP₀/(2σ²)`, a value computed here by hand, not by the code.
    #[test]
    fn the_closed_form_of_raw_gaussian_decay_is_lambda_pi_p0_over_two_sigma_squared() {
        let (density, sigma) = (2.0, 1.5);
        let c = closed_form_information(GAUSSIAN, Measurement::Raw, sigma, density, 12.0);
        let expected = density * std::f64::consts::PI * 1e4 / (2.0 * sigma * sigma);
        assert!((c / expected - 1.0).abs() < 1e-8, "{c} vs {expected}");
    }

    /// The exact FIM against one computed from its definition, independently
    /// of β: `Σ_i Σ_l ∇p_il ∇p_ilᵀ / p_il`, the cells' probabilities
    /// differentiated numerically in θ.
    #[test]
    fn the_exact_information_is_the_cells_fisher_information_by_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let sensors = deploy(&mut rng, 6.0, 2.0);
        let target = [0.2, -0.3];
        for (law, q) in [
            (GAUSSIAN, uniform_quantizer(1, GAUSSIAN, 1.0)),
            (GAUSSIAN, uniform_quantizer(3, GAUSSIAN, 1.0)),
            (POWER, uniform_quantizer(2, POWER, 1.0)),
        ] {
            let j = exact_information(law, Measurement::Quantized(&q), 1.0, &sensors, target);
            let mut by_hand = Matrix2::zeros();
            let h = 1e-5;
            for s in &sensors {
                let p = |t: [f64; 2], cell: u32| {
                    let d = (s[0] - t[0]).hypot(s[1] - t[1]);
                    q.probability(cell, law.amplitude(d), 1.0)
                };
                for cell in 0..q.cells() as u32 {
                    let p0 = p(target, cell);
                    if p0 < 1e-300 {
                        continue;
                    }
                    let gx = (p([target[0] + h, target[1]], cell)
                        - p([target[0] - h, target[1]], cell))
                        / (2.0 * h);
                    let gy = (p([target[0], target[1] + h], cell)
                        - p([target[0], target[1] - h], cell))
                        / (2.0 * h);
                    by_hand += Matrix2::new(gx * gx, gx * gy, gx * gy, gy * gy) / p0;
                }
            }
            let scale = j.norm();
            assert!(
                (j - by_hand).norm() < 1e-5 * scale,
                "{law:?}, {} bits: {j} vs {by_hand}",
                q.bits()
            );
        }
    }

    #[test]
    fn quantized_information_tends_to_the_analog_as_bits_grow() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let sensors = deploy(&mut rng, 8.0, 2.0);
        let analog = crlb_trace(&exact_information(
            GAUSSIAN,
            Measurement::Raw,
            1.0,
            &sensors,
            [0.0, 0.0],
        ))
        .unwrap();
        let mut previous = f64::INFINITY;
        for bits in [1, 2, 4, 6, 8, 10] {
            let q = uniform_quantizer(bits, GAUSSIAN, 1.0);
            let c = crlb_trace(&exact_information(
                GAUSSIAN,
                Measurement::Quantized(&q),
                1.0,
                &sensors,
                [0.0, 0.0],
            ))
            .unwrap();
            assert!(
                c >= analog * (1.0 - 1e-9) && c < previous,
                "{bits} bits: {c} (analog {analog})"
            );
            previous = c;
        }
        assert!(
            previous / analog - 1.0 < 0.01,
            "10 bits: {previous} vs analog {analog}"
        );
    }

    /// The law of large numbers, as Theorem 6.3 has it: over deployments at
    /// a high density, J₁₁ averages the closed form's c and J₁₂ averages 0.
    #[test]
    fn dense_deployments_average_the_closed_form() {
        let q = uniform_quantizer(1, GAUSSIAN, 1.0);
        let report = Measurement::Quantized(&q);
        let (side, density) = (12.0, 8.0);
        let c = closed_form_information(GAUSSIAN, report, 1.0, density, side / 2.0);
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let js: Vec<Matrix2<f64>> = (0..20)
            .map(|_| {
                exact_information(
                    GAUSSIAN,
                    report,
                    1.0,
                    &deploy(&mut rng, side, density),
                    [0.0, 0.0],
                )
            })
            .collect();
        let mean11 = js.iter().map(|j| j[(0, 0)]).sum::<f64>() / js.len() as f64;
        let mean12 = js.iter().map(|j| j[(0, 1)]).sum::<f64>() / js.len() as f64;
        assert!((mean11 / c - 1.0).abs() < 0.05, "{mean11} vs {c}");
        assert!(mean12.abs() / c < 0.05, "{mean12} vs {c}");
    }

    /// `−tr J⁻¹` of a deployment of the Gaussian law, σ = 1, the target at
    /// the origin: what the threshold searches maximize.
    fn negative_crlb_trace(sensors: &[[f64; 2]]) -> impl Fn(&Quantizer) -> f64 + '_ {
        move |q| {
            crlb_trace(&exact_information(
                GAUSSIAN,
                Measurement::Quantized(q),
                1.0,
                sensors,
                [0.0, 0.0],
            ))
            .map_or(f64::NEG_INFINITY, |t| -t)
        }
    }

    #[test]
    fn one_optimized_threshold_is_the_brute_force_best() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let sensors = deploy(&mut rng, 8.0, 1.0);
        let (lo, hi) = (-4.0, 104.0);
        let value = negative_crlb_trace(&sensors);
        let found = optimize_thresholds(1, lo, hi, &value);
        let brute = (1..20_000)
            .map(|k| lo + (hi - lo) * k as f64 / 20_000.0)
            .map(|t| (value(&Quantizer::from_thresholds(&[t]).unwrap()), t))
            .fold(
                (f64::NEG_INFINITY, 0.0),
                |a, b| if b.0 > a.0 { b } else { a },
            );
        assert!(
            value(&found) >= brute.0 - 1e-9 * brute.0.abs(),
            "{} vs brute {}",
            value(&found),
            brute.0
        );
        let uniform = value(&uniform_quantizer(1, GAUSSIAN, 1.0));
        assert!(value(&found) >= uniform);
    }

    #[test]
    fn a_warm_start_ends_no_worse_than_it_began_and_near_the_cold_search() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let sensors = deploy(&mut rng, 10.0, 2.0);
        let (lo, hi) = (-4.0, 104.0);
        let value = negative_crlb_trace(&sensors);
        let start = uniform_quantizer(2, GAUSSIAN, 1.0);
        let warm = optimize_thresholds_from(&start, lo, hi, &value);
        assert!(value(&warm) >= value(&start));
        // From the uniform start the two searches are the same search.
        let cold = optimize_thresholds(2, lo, hi, &value);
        assert_eq!(value(&warm), value(&cold));
        // From the cold search's own result, nothing is left to gain.
        let again = optimize_thresholds_from(&cold, lo, hi, &value);
        assert!(value(&again) >= value(&cold));
        assert!(value(&again) <= value(&cold) * (1.0 - 1e-3));
    }

    #[test]
    fn the_ml_estimate_finds_a_target_from_fine_reports() {
        let mut rng = ChaCha8Rng::seed_from_u64(10);
        let sensors = deploy(&mut rng, 8.0, 2.0);
        let q = uniform_quantizer(8, GAUSSIAN, 1.0);
        let target = [0.37, -0.21];
        let cells: Vec<u32> = sensors
            .iter()
            .map(|s| {
                let d = (s[0] - target[0]).hypot(s[1] - target[1]);
                let n: f64 = rng.sample(rand_distr::StandardNormal);
                q.encode(GAUSSIAN.amplitude(d) + n)
            })
            .collect();
        let at = ml_estimate(
            |t| log_likelihood(GAUSSIAN, &q, 1.0, &sensors, &cells, t),
            -4.0,
            4.0,
            0.25,
            3,
        );
        let bound = crlb_trace(&exact_information(
            GAUSSIAN,
            Measurement::Quantized(&q),
            1.0,
            &sensors,
            target,
        ))
        .unwrap();
        let error = (at[0] - target[0]).hypot(at[1] - target[1]);
        assert!(
            error < 5.0 * bound.sqrt(),
            "error {error}, CRLB {}",
            bound.sqrt()
        );
        // The refinement ends where no step of 10⁻⁶ improves the likelihood.
        let l = |t| log_likelihood(GAUSSIAN, &q, 1.0, &sensors, &cells, t);
        for (dx, dy) in [(1e-4, 0.0), (-1e-4, 0.0), (0.0, 1e-4), (0.0, -1e-4)] {
            assert!(l([at[0] + dx, at[1] + dy]) <= l(at) + 1e-9);
        }
    }
}
