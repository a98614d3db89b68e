//! Censoring at the sensor by the normalized innovation squared
//! (dissertation ch. 3, CFwMD).
//!
//! A sensor sends its measurement only when `νᵀ S⁻¹ ν ≥ η`, with ν the
//! innovation against the prediction its node fed back and S its variance.
//! η is chosen so that, on average, l of N sensors send: the NIS of a
//! Gaussian innovation is χ² with the measurement's dimension, so η is the
//! upper l/N quantile of that χ² (eq. 3.8).
//!
//! Silence is then information. For a scalar measurement with noise
//! variance r the likelihood of silence at a state x is (eq. 3.14; math.md
//! gives the form the proof yields, with the root over `η s` alone)
//!
//! ```text
//! P(silent | x) = Φ((√(η s) − μ)/√r) − Φ((−√(η s) − μ)/√r),    μ = h(x) − h(x̂)
//! ```
//!
//! For vector measurements there is no closed form; [`VectorSilence`]
//! estimates it by Monte Carlo, as the dissertation does (§3.7.2).

use nalgebra::{Matrix2, Vector2};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::normal;
use crate::ParameterError;

/// The NIS threshold for a budget of `l` transmissions out of `n` sensors,
/// each with `dof`-dimensional measurements.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CensoringRule {
    /// η: send when the NIS is at least this.
    pub threshold: f64,
}

impl CensoringRule {
    /// η = χ²_dof(l/N), the value the NIS exceeds with probability l/N.
    /// `dof` is 1 or 2, the dimensions the dissertation uses, for which the
    /// χ² tail inverts in closed form.
    pub fn for_budget(l: f64, n: usize, dof: u32) -> Result<Self, ParameterError> {
        let p = l / n as f64;
        if !(p > 0.0 && p <= 1.0) || n == 0 {
            return Err(ParameterError {
                parameter: "censoring budget l",
                expected: "0 < l ≤ the number of sensors",
                value: l,
            });
        }
        let threshold = match dof {
            // P(Z² ≥ η) = 2 Q(√η)
            1 => normal::upper_tail_inverse(p / 2.0).powi(2),
            // χ²₂ is exponential with mean 2
            2 => -2.0 * p.ln(),
            _ => {
                return Err(ParameterError {
                    parameter: "censoring measurement dimension",
                    expected: "1 or 2",
                    value: dof as f64,
                })
            }
        };
        Ok(Self { threshold })
    }

    /// Whether a measurement with this NIS is sent.
    pub fn sends(&self, nis: f64) -> bool {
        nis >= self.threshold
    }

    /// `P(silent | x)` of a scalar sensor: the innovation `ν ~ N(μ, r)`
    /// given x falls inside `±√(η s)`. `mu = h(x) − h(x̂)`, `s` the variance
    /// the sensor normalized by, `r` its noise variance.
    pub fn silence_probability(&self, mu: f64, s: f64, r: f64) -> f64 {
        let (half, sd) = self.window(s, r);
        normal::interval_mass((-half - mu) / sd, (half - mu) / sd)
    }

    /// `ln P(silent | x)`, finite however far x is from the prediction.
    pub fn ln_silence_probability(&self, mu: f64, s: f64, r: f64) -> f64 {
        let (half, sd) = self.window(s, r);
        normal::ln_interval_mass((-half - mu) / sd, (half - mu) / sd)
    }

    fn window(&self, s: f64, r: f64) -> (f64, f64) {
        ((self.threshold * s).sqrt(), r.sqrt())
    }
}

/// `P(νᵀ S⁻¹ ν < η | x)` for a two-dimensional innovation
/// `ν ~ N(m, R)`, `m = H(x − x̂)`, by Monte Carlo over a fixed set of draws.
/// The same draws serve every particle of a step (common random numbers),
/// so the estimate is smooth in x and the weights' noise does not depend on
/// the particle.
#[derive(Debug, Clone)]
pub struct VectorSilence {
    threshold: f64,
    s_inv: Matrix2<f64>,
    /// `L n_j`, with `L Lᵀ = R`.
    draws: Vec<Vector2<f64>>,
}

impl VectorSilence {
    pub fn new<G: Rng + ?Sized>(
        rule: &CensoringRule,
        s: &Matrix2<f64>,
        r: &Matrix2<f64>,
        samples: usize,
        rng: &mut G,
    ) -> Option<Self> {
        let s_inv = s.try_inverse()?;
        let l = r.cholesky()?.l();
        let draws = (0..samples)
            .map(|_| l * Vector2::new(rng.sample(StandardNormal), rng.sample(StandardNormal)))
            .collect();
        Some(Self {
            threshold: rule.threshold,
            s_inv,
            draws,
        })
    }

    /// The fraction of draws whose innovation `m + L n_j` stays inside.
    pub fn probability(&self, m: &Vector2<f64>) -> f64 {
        let inside = self
            .draws
            .iter()
            .filter(|d| {
                let nu = m + *d;
                (nu.transpose() * self.s_inv * nu)[0] < self.threshold
            })
            .count();
        inside as f64 / self.draws.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn the_threshold_passes_l_of_n_gaussian_innovations() {
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        for (l, n) in [(1.0, 4), (1.2, 4), (2.0, 4), (3.0, 4), (2.0, 9), (6.0, 9)] {
            let rule = CensoringRule::for_budget(l, n, 1).unwrap();
            let draws = 200_000;
            let sent = (0..draws)
                .filter(|_| {
                    let nu: f64 = rng.sample(StandardNormal);
                    rule.sends(nu * nu)
                })
                .count();
            let rate = sent as f64 / draws as f64;
            let p = l / n as f64;
            let se = (p * (1.0 - p) / draws as f64).sqrt();
            assert!((rate - p).abs() < 5.0 * se, "l={l} n={n}: {rate} vs {p}");
        }
        // Closed forms: χ²₁ upper 5 % point 3.8415, χ²₂ upper 10 % point 4.6052.
        let one = CensoringRule::for_budget(0.2, 4, 1).unwrap().threshold;
        assert!((one - 3.841_458_820_694_124).abs() < 1e-9, "{one}");
        let two = CensoringRule::for_budget(0.4, 4, 2).unwrap().threshold;
        assert!((two - 4.605_170_185_988_091).abs() < 1e-12, "{two}");
    }

    #[test]
    fn bad_budgets_are_named() {
        for (l, n, dof) in [(0.0, 4, 1), (5.0, 4, 1), (f64::NAN, 4, 1), (1.0, 0, 1)] {
            let e = CensoringRule::for_budget(l, n, dof).unwrap_err();
            assert_eq!(e.parameter, "censoring budget l");
        }
        let e = CensoringRule::for_budget(1.0, 4, 3).unwrap_err();
        assert_eq!(e.parameter, "censoring measurement dimension");
    }

    /// The issue's test: the censored likelihood against a Monte Carlo
    /// estimate of P(silence | x), simulating the sensor itself: draw its
    /// noise, form the innovation against the fed-back prediction, apply
    /// the rule.
    #[test]
    fn the_silence_likelihood_matches_a_monte_carlo_of_the_sensor() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let rule = CensoringRule::for_budget(1.0, 4, 1).unwrap();
        let (r, s) = (1.0_f64, 3.5_f64);
        let h_pred = 2.0; // h(x̂)
        for h_x in [2.0, 2.7, 0.5, 5.0, -1.0] {
            let noise = Normal::new(0.0, r.sqrt()).unwrap();
            let draws = 400_000;
            let silent = (0..draws)
                .filter(|_| {
                    let z = h_x + noise.sample(&mut rng);
                    let nu: f64 = z - h_pred;
                    !rule.sends(nu * nu / s)
                })
                .count();
            let mc = silent as f64 / draws as f64;
            let exact = rule.silence_probability(h_x - h_pred, s, r);
            let se = (exact * (1.0 - exact) / draws as f64).sqrt().max(1e-6);
            assert!(
                (mc - exact).abs() < 5.0 * se,
                "h(x)={h_x}: MC {mc} vs {exact}"
            );
            assert!((rule.ln_silence_probability(h_x - h_pred, s, r) - exact.ln()).abs() < 1e-12);
        }
        // Far from the prediction silence is nearly impossible, and the log
        // stays finite where the probability underflows.
        let far = rule.ln_silence_probability(60.0, s, r);
        assert!(far.is_finite() && far < -1000.0, "{far}");
    }

    /// Silence tells the most when x is near the prediction: the
    /// likelihood peaks at μ = 0 and is symmetric in μ.
    #[test]
    fn silence_favours_states_near_the_prediction() {
        let rule = CensoringRule::for_budget(2.0, 4, 1).unwrap();
        let at = |mu| rule.silence_probability(mu, 2.0, 1.0);
        assert!(at(0.0) > at(0.5) && at(0.5) > at(1.5) && at(1.5) > at(4.0));
        assert!((at(1.3) - at(-1.3)).abs() < 1e-15);
        // With η s = r and μ = 0, the window is ±1 standard deviation.
        let unit = CensoringRule { threshold: 1.0 };
        assert!((unit.silence_probability(0.0, 1.0, 1.0) - 0.682_689_492_137_085_9).abs() < 1e-12);
    }

    #[test]
    fn the_vector_silence_matches_the_sensor_and_the_scalar_case() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let rule = CensoringRule::for_budget(1.0, 4, 2).unwrap();
        let r = Matrix2::new(2.0, 0.0, 0.0, 4.0);
        let s = r + Matrix2::new(3.0, 1.0, 1.0, 2.0);
        let silence = VectorSilence::new(&rule, &s, &r, 100_000, &mut rng).unwrap();
        let s_inv = s.try_inverse().unwrap();
        for m in [Vector2::new(0.0, 0.0), Vector2::new(2.0, -1.0)] {
            let draws = 100_000;
            let silent = (0..draws)
                .filter(|_| {
                    let n = Vector2::new(
                        2.0_f64.sqrt() * rng.sample::<f64, _>(StandardNormal),
                        2.0 * rng.sample::<f64, _>(StandardNormal),
                    );
                    let nu = m + n;
                    !rule.sends((nu.transpose() * s_inv * nu)[0])
                })
                .count() as f64
                / draws as f64;
            let est = silence.probability(&m);
            assert!((est - silent).abs() < 0.01, "m={m:?}: {est} vs {silent}");
        }
        // A diagonal S and R with one axis of negligible spread reduce to the scalar case.
        let rule1 = CensoringRule { threshold: 2.0 };
        let r = Matrix2::new(1.0, 0.0, 0.0, 1e-12);
        let s = Matrix2::new(3.0, 0.0, 0.0, 1.0);
        let v = VectorSilence::new(&rule1, &s, &r, 200_000, &mut rng).unwrap();
        let exact = rule1.silence_probability(1.0, 3.0, 1.0);
        let est = v.probability(&Vector2::new(1.0, 0.0));
        assert!((est - exact).abs() < 0.005, "{est} vs {exact}");
    }
}
