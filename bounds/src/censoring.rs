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
//! variance r the likelihood of silence at a state x is (eq. 3.14; docs/equations.md
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

use crate::batch::CHUNK;
use crate::cell_sums::{accumulate, scalars_from_sums, FisherScalars, ScalarBatch};
use crate::dynamics::Dynamics;
use crate::fisher::{assemble, Measurement};
use crate::normal;
use crate::observation::{wrap_angle, ObservationModel};
use crate::pcrlb::{observation_information_with, BatchScalars, SensorTerm};
use crate::{BoundError, Mat4, ParameterError, State};

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

    /// [`ln_silence_probability`](Self::ln_silence_probability) at a
    /// batch of offsets `mu` and noise variances `r` with one `s`, equal
    /// to it lane by lane, bit for bit, and vectorised
    /// ([`normal::ln_interval_mass_batch`]): a silent sensor's likelihood
    /// at a batch of particles.
    pub fn ln_silence_probability_batch(
        &self,
        mu: &[f64; CHUNK],
        s: f64,
        r: &[f64; CHUNK],
        out: &mut [f64; CHUNK],
    ) {
        #[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx2"))]
        unsafe fn avx2(
            rule: &CensoringRule,
            mu: &[f64; CHUNK],
            s: f64,
            r: &[f64; CHUNK],
            out: &mut [f64; CHUNK],
        ) {
            rule.silence_batch(mu, s, r, out)
        }
        if crate::batch::has_avx2() {
            // SAFETY: the CPU has AVX2.
            unsafe { avx2(self, mu, s, r, out) }
        } else {
            self.silence_batch(mu, s, r, out)
        }
    }

    #[inline(always)]
    fn silence_batch(&self, mu: &[f64; CHUNK], s: f64, r: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
        let (mut a, mut b) = ([0.0; CHUNK], [0.0; CHUNK]);
        for i in 0..CHUNK {
            let (half, sd) = self.window(s, r[i]);
            a[i] = (-half - mu[i]) / sd;
            b[i] = (half - mu[i]) / sd;
        }
        normal::ln_interval_mass_batch(&a, &b, out)
    }

    #[inline(always)]
    fn window(&self, s: f64, r: f64) -> (f64, f64) {
        ((self.threshold * s).sqrt(), r.sqrt())
    }
}

/// What a node feeds back to a censoring sensor with its activation: its
/// fused estimate of the previous step, `x̂(k−1|k−1)`, and for CFwMD2 its
/// covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feedback {
    pub estimate: State,
    pub covariance: Option<Mat4>,
}

/// A scalar sensor's innovation statistics for one step: the predicted
/// measurement `h(x̂(k|k−1))` and the variance `s` it normalizes by. The
/// sensor computes them to censor; its node computes the same, from the
/// same feedback, to weigh the sensor's silence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Innovation {
    pub predicted: f64,
    pub variance: f64,
    /// Bearings: innovations wrap at ±π.
    pub angular: bool,
}

impl Innovation {
    /// `ν = z − h(x̂)`, wrapped for angles.
    pub fn of(&self, z: f64) -> f64 {
        let nu = z - self.predicted;
        if self.angular {
            wrap_angle(nu)
        } else {
            nu
        }
    }

    /// The normalized innovation squared of a measurement.
    pub fn nis(&self, z: f64) -> f64 {
        let nu = self.of(z);
        nu * nu / self.variance
    }

    /// `ln P(silent | x)` at a state whose predicted measurement is `g`
    /// with noise variance `r`: `μ = h(x) − h(x̂)`.
    pub fn ln_silence(&self, rule: &CensoringRule, g: f64, r: f64) -> f64 {
        rule.ln_silence_probability(self.of(g), self.variance, r)
    }

    /// Where the sensor stays silent under `rule`: raw values within
    /// `√(η s)` of the prediction.
    pub fn silence_window(&self, rule: &CensoringRule) -> SilenceWindow {
        SilenceWindow {
            centre: self.predicted,
            half_width: (rule.threshold * self.variance).sqrt(),
            angular: self.angular,
        }
    }
}

/// The values of a censoring sensor's measurement for which it stays
/// silent: `|z − ĥ| < √(η s)`, wrapped for bearings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SilenceWindow {
    /// `ĥ = h(x̂(k|k−1))`.
    pub centre: f64,
    /// `√(η s)`.
    pub half_width: f64,
    pub angular: bool,
}

impl SilenceWindow {
    /// The window's edges in the measurement's units, unrolled next to a
    /// mean `g` for bearings, so that `g` and the window are on one line.
    pub fn edges_near(&self, g: f64) -> (f64, f64) {
        let centre = if self.angular {
            g - wrap_angle(g - self.centre)
        } else {
            self.centre
        };
        // A window as wide as the circle is silence whatever the bearing.
        let half = if self.angular {
            self.half_width.min(std::f64::consts::PI)
        } else {
            self.half_width
        };
        (centre - half, centre + half)
    }

    /// The Fisher scalars of the censored measurement at a state where the
    /// sensor's mean is `g` and its variance `r`: information from the
    /// value when it is sent, and from the silence when it is not.
    ///
    /// Raw: with `a`, `b` the window's edges standardized by `(z − g)/√r`
    /// and `P_s = Φ(b) − Φ(a)`, the continuous part outside the window adds
    /// `∫ (∂ ln p)² p dz` over `u ∉ [a, b]`, and the silence the one cell
    /// `[a, b]`:
    ///
    /// ```text
    /// gg = [1 − P_s + bφ(b) − aφ(a) + (φ(a) − φ(b))²/P_s] / r
    /// ```
    ///
    /// (the `gr`, `rr` terms likewise from `∫u³φ` and `∫u⁴φ`). Quantized:
    /// the cells outside the window and the one merged cell inside it
    /// ([`Quantizer::censored_fisher_scalars`]).
    pub fn fisher_scalars(&self, g: f64, r: f64, measurement: Measurement<'_>) -> FisherScalars {
        let silent = self.edges_near(g);
        match measurement {
            Measurement::Quantized(q) => q.censored_fisher_scalars(g, r, silent),
            Measurement::Raw => raw_censored_scalars(g, r, silent),
        }
    }

    /// `J_cens(x)`: the censored measurement's Fisher information.
    pub fn information(
        &self,
        model: &ObservationModel,
        measurement: Measurement<'_>,
        x: &State,
    ) -> Mat4 {
        let e = model.evaluate(x);
        assemble(&self.fisher_scalars(e.g, e.r, measurement), &e)
    }
}

/// [`SilenceWindow::fisher_scalars`] of a raw measurement, in the
/// standardized sums of [`crate::cell_sums`]: over the whole line they are
/// `(1, 0, 2)`, the unquantized `(1/r, 0, 1/(2r²))`, and the window's part
/// is taken out in closed form (`∫u²φ = Φ − uφ`, `∫(u³ − u)φ = −(u² + 1)φ`,
/// `∫(u² − 1)²φ = 2Φ − (u³ + u)φ`) and put back as one cell.
fn raw_censored_scalars(g: f64, r: f64, (lo, hi): (f64, f64)) -> FisherScalars {
    let sigma = r.sqrt();
    let (a, b) = ((lo - g) / sigma, (hi - g) / sigma);
    let (pa, pb) = (normal::pdf(a), normal::pdf(b));
    let (apa, bpb) = (normal::x_pdf(a), normal::x_pdf(b));
    let p_s = normal::interval_mass(a, b);
    // u^k φ(u) at an edge from uφ(u), 0 at ±∞.
    let times = |u: f64, upu: f64, k: i32| if u.is_finite() { u.powi(k) * upu } else { 0.0 };
    let mut sums = [
        1.0 - p_s + bpb - apa,
        (times(b, bpb, 1) + pb) - (times(a, apa, 1) + pa),
        2.0 - 2.0 * p_s + (times(b, bpb, 2) + bpb) - (times(a, apa, 2) + apa),
    ];
    accumulate(&mut sums, p_s, pa - pb, apa - bpb);
    scalars_from_sums(sums, r)
}

/// `Σ_s Σ_j w_j J_cens,s(x_j)`: the expected information of censoring
/// sensors over a particle set, sensor `s` with its silence window
/// `windows[s]`, whether it sent or stayed silent (its silence is a
/// measurement as much as its value is). The expected information's own
/// batched sum ([`observation_information_with`]) with the censored
/// scalars in place of `J_Y`'s.
pub fn censored_information(
    sensors: &[SensorTerm<'_>],
    windows: &[SilenceWindow],
    particles: &[State],
    weights: &[f64],
) -> Result<Mat4, BoundError> {
    debug_assert_eq!(sensors.len(), windows.len());
    observation_information_with(
        sensors,
        particles,
        weights,
        CensoredScalars { sensors, windows },
    )
}

/// The censored measurement's Fisher scalars, sensor by sensor, as
/// [`observation_information_with`] asks for them.
struct CensoredScalars<'a> {
    sensors: &'a [SensorTerm<'a>],
    windows: &'a [SilenceWindow],
}

impl BatchScalars for CensoredScalars<'_> {
    #[inline(always)]
    fn scalars(
        &mut self,
        _first: usize,
        sensor: usize,
        g: &[f64; CHUNK],
        r: &[f64; CHUNK],
        n: usize,
        out: &mut ScalarBatch,
    ) {
        let (window, measurement) = (&self.windows[sensor], self.sensors[sensor].measurement);
        for i in 0..n {
            out.set(i, window.fisher_scalars(g[i], r[i], measurement));
        }
    }
}

/// One sensor's side of NIS censoring in a network: the rule, and for
/// CFwMD the sensor's own Kalman (EKF) covariance, linearized at the fed
/// back estimate. A sensor is activated only now and then, so the recursion
/// advances when it is: it coasts over the steps it missed, then updates as
/// if it used its measurement. Its node keeps a copy that sees the same
/// activations and feedback, so both hold the same covariance.
#[derive(Debug, Clone)]
pub struct NisCensor {
    pub rule: CensoringRule,
    own_covariance: Mat4,
    last_step: Option<u32>,
}

impl NisCensor {
    pub fn new(rule: CensoringRule, prior_covariance: Mat4) -> Self {
        Self {
            rule,
            own_covariance: prior_covariance,
            last_step: None,
        }
    }

    /// The innovation statistics of `step` from the feedback: with the fed
    /// back covariance (CFwMD2) or the sensor's own (CFwMD), which this
    /// advances to `step`.
    pub fn innovation(
        &mut self,
        step: u32,
        feedback: &Feedback,
        model: &ObservationModel,
        dynamics: &Dynamics,
    ) -> Innovation {
        let f = dynamics.jacobian(&feedback.estimate);
        let predict = |p: &Mat4| f * p * f.transpose() + dynamics.q();
        let predicted_state = dynamics.transition(&feedback.estimate);
        let e = model.evaluate(&predicted_state);
        let predicted_cov = match feedback.covariance {
            Some(p) => predict(&p),
            None => {
                let missed = self
                    .last_step
                    .map_or(0, |last| step.saturating_sub(last + 1).min(MAX_COAST));
                for _ in 0..missed {
                    self.own_covariance = predict(&self.own_covariance);
                }
                predict(&self.own_covariance)
            }
        };
        let s = (e.grad_g.transpose() * predicted_cov * e.grad_g)[0] + e.r;
        if feedback.covariance.is_none() {
            let k = predicted_cov * e.grad_g / s;
            let updated = predicted_cov - k * e.grad_g.transpose() * predicted_cov;
            self.own_covariance = 0.5 * (updated + updated.transpose());
            self.last_step = Some(step);
        }
        Innovation {
            predicted: e.g,
            variance: s,
            angular: model.is_angular(),
        }
    }
}

/// Coasting a covariance further than this changes nothing a threshold
/// can tell, and bounds the work a forged step number can cause.
const MAX_COAST: u32 = 1000;

/// `P(νᵀ S⁻¹ ν < η | x)` for a two-dimensional innovation
/// `ν ~ N(m, R)`, `m = H(x − x̂)`, by Monte Carlo over a fixed set of draws.
/// The same draws serve every particle of a step (common random numbers),
/// so the estimate is smooth in x and the weights' noise does not depend on
/// the particle.
#[derive(Debug, Clone)]
pub struct VectorSilence {
    threshold: f64,
    s_inv: Matrix2<f64>,
    /// Per draw `d_j = L n_j` (`L Lᵀ = R`), what its NIS
    /// `(m + d)ᵀ S⁻¹ (m + d)` needs beside `mᵀ S⁻¹ m`: the two components
    /// of `2 S⁻¹ d` and `dᵀ S⁻¹ d`. Every particle of a step asks about the
    /// same draws, so each is worked out once, and held as three arrays so
    /// that the count over draws runs as vector instructions.
    twice_s_inv_d: [Vec<f64>; 2],
    d_s_inv_d: Vec<f64>,
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
        let mut silence = Self {
            threshold: rule.threshold,
            s_inv,
            twice_s_inv_d: [Vec::with_capacity(samples), Vec::with_capacity(samples)],
            d_s_inv_d: Vec::with_capacity(samples),
        };
        for _ in 0..samples {
            let d = l * Vector2::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
            let s_inv_d = s_inv * d;
            let twice = 2.0 * s_inv_d;
            silence.twice_s_inv_d[0].push(twice[0]);
            silence.twice_s_inv_d[1].push(twice[1]);
            silence.d_s_inv_d.push(d.dot(&s_inv_d));
        }
        Some(silence)
    }

    /// The fraction of draws whose innovation `m + L n_j` stays inside.
    pub fn probability(&self, m: &Vector2<f64>) -> f64 {
        let m_s_inv_m = m.dot(&(self.s_inv * m));
        let [x, y] = &self.twice_s_inv_d;
        let mut inside = 0usize;
        for ((x, y), c) in x.iter().zip(y).zip(&self.d_s_inv_d) {
            // `m · (2 S⁻¹ d)` as nalgebra's dot sums it: x first.
            let nis = m_s_inv_m + (m[0] * x + m[1] * y) + c;
            inside += usize::from(nis < self.threshold);
        }
        inside as f64 / self.d_s_inv_d.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Quantizer;
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

    /// The sensor and its node, fed the same activations and feedback,
    /// hold the same covariance and compute the same innovation; CFwMD2's
    /// uses the fed-back covariance and no history.
    #[test]
    fn a_sensor_and_its_nodes_copy_agree_step_by_step() {
        use crate::dynamics::CoordinatedTurn;
        use crate::observation::SensorLaw;
        let dynamics = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.5)).unwrap();
        let model = SensorLaw::Bearing {
            sigma_theta: 0.02,
            d0: 500.0,
            near_field: None,
        }
        .at([100.0, 200.0]);
        let rule = CensoringRule::for_budget(1.0, 3, 1).unwrap();
        let prior = Mat4::from_diagonal(&State::new(2500.0, 2500.0, 4.0, 4.0));
        let (mut sensor, mut node) = (NisCensor::new(rule, prior), NisCensor::new(rule, prior));
        let mut last = None;
        for (step, x) in [(1, 10.0), (2, 12.0), (5, 20.0), (6, 23.0)] {
            let feedback = Feedback {
                estimate: State::new(x, 400.0, 2.0, -1.0),
                covariance: None,
            };
            let a = sensor.innovation(step, &feedback, &model, &dynamics);
            let b = node.innovation(step, &feedback, &model, &dynamics);
            assert_eq!(a, b);
            assert!(a.variance > 0.02f64.powi(2));
            last = Some(a);
        }
        // The recursion learnt: the variance fell from the prior's.
        let mut fresh = NisCensor::new(rule, prior);
        let first = fresh.innovation(
            6,
            &Feedback {
                estimate: State::new(23.0, 400.0, 2.0, -1.0),
                covariance: None,
            },
            &model,
            &dynamics,
        );
        assert!(last.unwrap().variance < first.variance);
        // CFwMD2: s = gᵀ (F P Fᵀ + Q) g + r, whatever came before.
        let p = Mat4::identity() * 9.0;
        let fed = Feedback {
            estimate: State::new(0.0, 400.0, 0.0, 0.0),
            covariance: Some(p),
        };
        let c = sensor.innovation(7, &fed, &model, &dynamics);
        let f = dynamics.jacobian(&fed.estimate);
        let pred = dynamics.transition(&fed.estimate);
        let e = model.evaluate(&pred);
        let s = (e.grad_g.transpose() * (f * p * f.transpose() + dynamics.q()) * e.grad_g)[0] + e.r;
        assert!((c.variance - s).abs() < 1e-15 * s);
        assert_eq!(c.predicted, e.g);
    }

    #[test]
    fn angular_innovations_wrap() {
        let i = Innovation {
            predicted: 3.1,
            variance: 0.01,
            angular: true,
        };
        assert!((i.of(-3.1) - (2.0 * std::f64::consts::PI - 6.2)).abs() < 1e-12);
        let rule = CensoringRule { threshold: 1.0 };
        // A state whose bearing is just across ±π from the prediction is
        // as likely to be silent as one just this side.
        let across = i.ln_silence(&rule, -3.13, 0.0001);
        let mu = -3.13 - 3.1 + 2.0 * std::f64::consts::PI;
        let this_side = i.ln_silence(&rule, 3.1 - mu, 0.0001);
        assert!((across - this_side).abs() < 1e-9, "{across} vs {this_side}");
    }

    /// A bearing sensor whose noise grows with distance (∇R ≠ 0, so every
    /// Fisher scalar matters), far from ±π so that wrapping plays no part
    /// in the direct sums below.
    fn bearing_case() -> (crate::ObservationModel, State) {
        let model = crate::SensorLaw::Bearing {
            sigma_theta: 0.05,
            d0: 300.0,
            near_field: None,
        }
        .at([0.0, 0.0]);
        (model, State::new(300.0, 400.0, 1.0, -1.0))
    }

    /// `Σ ∇P∇Pᵀ/P` over outcomes given by their probability at a state,
    /// the gradients by central differences: the expected information of
    /// a discrete law, computed directly.
    fn direct_discrete_information(outcomes: &[&dyn Fn(&State) -> f64], x: &State) -> Mat4 {
        let mut j = Mat4::zeros();
        for p in outcomes {
            let at = p(x);
            if at > 1e-300 {
                let grad = crate::testing::central_gradient(|y| p(y), x, 1e-3, false);
                j += grad * grad.transpose() / at;
            }
        }
        j
    }

    fn relative_gap(a: &Mat4, b: &Mat4) -> f64 {
        (a - b).norm() / b.norm()
    }

    /// J_cens of a raw measurement against the censored law's information
    /// evaluated directly: the score of `N(z; g(x), r(x))` by differences
    /// in x, squared and integrated over the values outside the window,
    /// plus the silence's `∇P_s∇P_sᵀ/P_s`.
    #[test]
    fn raw_censored_information_is_the_censored_laws() {
        let (model, x) = bearing_case();
        let (g, r) = model.mean_and_variance(&x);
        let sd = r.sqrt();
        for (offset, half) in [(0.0, 0.6), (0.03, 0.05), (-0.1, 0.2), (0.4, 0.01)] {
            let window = SilenceWindow {
                centre: g + offset,
                half_width: half,
                angular: true,
            };
            let (lo, hi) = window.edges_near(g);
            let ln_density = |z: f64, y: &State| {
                let (gy, ry) = model.mean_and_variance(y);
                -0.5 * ((z - gy).powi(2) / ry + ry.ln())
            };
            // Midpoint rule over ±12 σ, outside the window.
            let n = 40_000;
            let (from, to) = (g - 12.0 * sd, g + 12.0 * sd);
            let dz = (to - from) / n as f64;
            let mut j = Mat4::zeros();
            for i in 0..n {
                let z = from + (i as f64 + 0.5) * dz;
                if z > lo && z < hi {
                    continue;
                }
                let score = crate::testing::central_gradient(|y| ln_density(z, y), &x, 1e-3, false);
                let p =
                    (-0.5 * (z - g).powi(2) / r).exp() / (2.0 * std::f64::consts::PI * r).sqrt();
                j += score * score.transpose() * p * dz;
            }
            let silence = |y: &State| {
                let (gy, ry) = model.mean_and_variance(y);
                normal::interval_mass((lo - gy) / ry.sqrt(), (hi - gy) / ry.sqrt())
            };
            j += direct_discrete_information(&[&silence], &x);
            let ours = window.information(&model, Measurement::Raw, &x);
            // Relative to the direct value, or to the uncensored information
            // where the window leaves almost none (its differences cancel).
            let uncensored = crate::fisher::expected_information(&model, Measurement::Raw, &x);
            assert!(
                (ours - j).norm() < 2e-4 * j.norm() + 1e-7 * uncensored.norm(),
                "window {offset} ± {half}: {ours} vs direct {j}"
            );
        }
    }

    /// The same with a quantizer: the outcomes are the silence and each
    /// cell's part outside the window, their probabilities taken cell by
    /// cell over the whole quantizer.
    #[test]
    fn quantized_censored_information_is_the_censored_laws() {
        let (model, x) = bearing_case();
        let (g, _) = model.mean_and_variance(&x);
        for bits in [3u8, 5, 8] {
            let q = Quantizer::uniform(bits, g - 1.0, g + 1.0).unwrap();
            // A window inside one cell, across several, and at an edge.
            for (offset, half) in [(0.01, 0.003), (0.0, 0.3), (0.05, 0.1)] {
                let window = SilenceWindow {
                    centre: g + offset,
                    half_width: half,
                    angular: true,
                };
                let (lo, hi) = window.edges_near(g);
                let mass = |y: &State, a: f64, b: f64| {
                    let (gy, ry) = model.mean_and_variance(y);
                    if a >= b {
                        return 0.0;
                    }
                    normal::interval_mass((a - gy) / ry.sqrt(), (b - gy) / ry.sqrt())
                };
                type Outcome<'a> = Box<dyn Fn(&State) -> f64 + 'a>;
                let cells: Vec<Outcome> = (0..q.cells() as u32)
                    .map(|c| {
                        let (a, b) = q.cell_edges(c);
                        let mass = &mass;
                        Box::new(move |y: &State| mass(y, a, b.min(lo)) + mass(y, a.max(hi), b))
                            as Box<dyn Fn(&State) -> f64>
                    })
                    .collect();
                let silence = |y: &State| mass(y, lo, hi);
                let mut outcomes: Vec<&dyn Fn(&State) -> f64> =
                    cells.iter().map(|c| c.as_ref()).collect();
                outcomes.push(&silence);
                let direct = direct_discrete_information(&outcomes, &x);
                let ours = window.information(&model, Measurement::Quantized(&q), &x);
                assert!(
                    relative_gap(&ours, &direct) < 1e-5,
                    "{bits} bits, window {offset} ± {half}: {ours} vs direct {direct}"
                );
            }
        }
    }

    /// As η → 0 the window closes and the censored information is the
    /// uncensored one, raw and quantized; as it covers every value, the
    /// sensor always stays silent and tells nothing.
    #[test]
    fn censored_information_tends_to_the_uncensored_and_to_nothing() {
        let (model, x) = bearing_case();
        let e = model.evaluate(&x);
        let q = Quantizer::uniform_wrapped(6, -std::f64::consts::PI, std::f64::consts::PI).unwrap();
        for measurement in [Measurement::Raw, Measurement::Quantized(&q)] {
            let uncensored = crate::fisher::information_of(&e, measurement);
            let mut previous_gap = f64::INFINITY;
            for eta in [1e-2, 1e-4, 1e-6, 1e-8] {
                let window = Innovation {
                    predicted: e.g + 0.01,
                    variance: e.r * 2.0,
                    angular: true,
                }
                .silence_window(&CensoringRule { threshold: eta });
                let gap = relative_gap(&window.information(&model, measurement, &x), &uncensored);
                assert!(gap < previous_gap, "η = {eta}: gap {gap} did not shrink");
                previous_gap = gap;
            }
            assert!(previous_gap < 1e-3, "{previous_gap}");
            // Censoring never adds information: J_cens ≤ J_Y.
            let window = SilenceWindow {
                centre: e.g,
                half_width: 2.0 * e.r.sqrt(),
                angular: true,
            };
            let censored = window.information(&model, measurement, &x);
            let eig = (uncensored - censored).symmetric_eigen().eigenvalues;
            assert!(eig.min() > -1e-9 * uncensored.norm(), "{eig}");
            let everywhere = SilenceWindow {
                centre: e.g,
                half_width: 10.0,
                angular: true,
            };
            assert!(
                everywhere.information(&model, measurement, &x).norm() < 1e-9 * uncensored.norm()
            );
        }
    }

    /// The batched sum over particles is the sum of each particle's
    /// `J_cens`, for raw and quantized bearings, over more particles than
    /// one batch holds.
    #[test]
    fn the_censored_sum_over_particles_is_each_particles() {
        let (model, x) = bearing_case();
        let q = Quantizer::uniform_wrapped(8, -std::f64::consts::PI, std::f64::consts::PI).unwrap();
        let g = model.mean_and_variance(&x).0;
        let windows = [
            SilenceWindow {
                centre: g + 0.01,
                half_width: 0.08,
                angular: true,
            },
            SilenceWindow {
                centre: g - 0.2,
                half_width: 0.05,
                angular: true,
            },
        ];
        let particles: Vec<State> = (0..150)
            .map(|j| x + State::new(j as f64 * 0.7 - 50.0, 30.0 - j as f64 * 0.4, 0.0, 0.0))
            .collect();
        let weights = vec![1.0 / 150.0; 150];
        for measurement in [Measurement::Raw, Measurement::Quantized(&q)] {
            let sensors = [SensorTerm {
                model: &model,
                measurement,
            }; 2];
            let batched = censored_information(&sensors, &windows, &particles, &weights).unwrap();
            let mut direct = Mat4::zeros();
            for (p, w) in particles.iter().zip(&weights) {
                for window in &windows {
                    direct += window.information(&model, measurement, p) * *w;
                }
            }
            assert!(
                (batched - direct).norm() < 1e-9 * direct.norm(),
                "{batched} vs {direct}"
            );
        }
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
