//! The conditional bounds on the univariate non-stationary growth model
//! (dissertation ch. 7): the offline PCRLB, Zuo et al.'s CPCRLB with its
//! auxiliary FIM, and the A-CPCRLB, for a scalar state.
//!
//! ```text
//! x_{k+1} = αx_k + βx_k/(1 + x_k²) + γ cos(1.2k) + u_k,   u_k ~ N(0, σ_u²)
//! z_k     = κ x_k² + v_k,                                  v_k ~ N(0, σ_v²)
//! ```
//!
//! With `f'(x) = α + β(1 − x²)/(1 + x²)²` and the measurement's Fisher
//! information `(2κx)²/σ_v²`, the terms of eqs. 7.4–7.6 over particles
//! are `B11 = E[f'(x_k)²]/σ_u²`, `B12 = −E[f'(x_k)]/σ_u²` (posterior at k)
//! and `B22 = 1/σ_u² + E[(2κx_{k+1})²]/σ_v²` (prediction at k+1), and
//! every bound takes one step `L' = B22 − B12²/(B11 + L)`; they differ in
//! the L they carry and the densities they take the terms over.

use rand::Rng;
use rand_distr::StandardNormal;

/// The model's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ungm {
    pub alpha: f64,
    pub beta: f64,
    pub gamma: f64,
    /// σ_u².
    pub process_variance: f64,
    /// σ_v².
    pub measurement_variance: f64,
    pub kappa: f64,
}

impl Ungm {
    /// Section 7.5.1: α = 1, β = 15, γ = 8, σ_u² = 4, σ_v² = 1, κ = 1/20.
    pub const HIGHLY_NONLINEAR: Ungm = Ungm {
        alpha: 1.0,
        beta: 15.0,
        gamma: 8.0,
        process_variance: 4.0,
        measurement_variance: 1.0,
        kappa: 1.0 / 20.0,
    };

    /// Section 7.5.2: β = 1, σ_u² = 1, σ_v² = 0.01, the rest as above.
    pub const WEAKLY_NONLINEAR: Ungm = Ungm {
        alpha: 1.0,
        beta: 1.0,
        gamma: 8.0,
        process_variance: 1.0,
        measurement_variance: 0.01,
        kappa: 1.0 / 20.0,
    };

    /// The noiseless transition from step k: `f_k(x)`.
    pub fn transition(&self, x: f64, k: u32) -> f64 {
        self.alpha * x + self.beta * x / (1.0 + x * x) + self.gamma * (1.2 * k as f64).cos()
    }

    /// `f'(x)`, the same at every k.
    pub fn slope(&self, x: f64) -> f64 {
        let s = 1.0 + x * x;
        self.alpha + self.beta * (1.0 - x * x) / (s * s)
    }

    /// A draw of `x_{k+1}` given `x_k`.
    pub fn propagate<R: Rng + ?Sized>(&self, x: f64, k: u32, rng: &mut R) -> f64 {
        let u: f64 = rng.sample(StandardNormal);
        self.transition(x, k) + self.process_variance.sqrt() * u
    }

    /// A draw of `z` at the state x.
    pub fn measure<R: Rng + ?Sized>(&self, x: f64, rng: &mut R) -> f64 {
        let v: f64 = rng.sample(StandardNormal);
        self.kappa * x * x + self.measurement_variance.sqrt() * v
    }

    /// `ln p(z | x)` up to its constant.
    pub fn ln_likelihood(&self, z: f64, x: f64) -> f64 {
        let r = z - self.kappa * x * x;
        -r * r / (2.0 * self.measurement_variance)
    }

    /// The Fisher information of one measurement about x: `(2κx)²/σ_v²`.
    pub fn measurement_information(&self, x: f64) -> f64 {
        let d = 2.0 * self.kappa * x;
        d * d / self.measurement_variance
    }
}

/// The three terms of one step of a bound's recursion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepTerms {
    pub b11: f64,
    pub b12: f64,
    pub b22: f64,
}

impl StepTerms {
    /// `B22 − B12²/(B11 + L)`: the information one step carries `L` to.
    pub fn advance(&self, information: f64) -> f64 {
        self.b22 - self.b12 * self.b12 / (self.b11 + information)
    }
}

fn weighted_mean(values: impl Iterator<Item = f64>, weights: &[f64]) -> f64 {
    let total: f64 = weights.iter().sum();
    values.zip(weights).map(|(v, w)| v * w).sum::<f64>() / total
}

/// `B11`, `B12` over the states `from` (weighted), `B22` with the
/// measurement information over the states `to` (weighted): eqs. 7.4–7.6
/// over particles, and eqs. 7.10–7.12 when `from` are the states at k−1
/// and `to` those at k.
pub fn step_terms(
    model: &Ungm,
    from: &[f64],
    from_weights: &[f64],
    to: &[f64],
    to_weights: &[f64],
) -> StepTerms {
    let q = model.process_variance;
    StepTerms {
        b11: weighted_mean(from.iter().map(|x| model.slope(*x).powi(2)), from_weights) / q,
        b12: -weighted_mean(from.iter().map(|x| model.slope(*x)), from_weights) / q,
        b22: 1.0 / q
            + weighted_mean(
                to.iter().map(|x| model.measurement_information(*x)),
                to_weights,
            ),
    }
}

/// The offline PCRLB of Tichavsky et al.: `J_{k+1} = D22 − D12²/(D11 +
/// J_k)` with the D terms averaged over `trajectories` drawn from the
/// prior `N(mean, variance)` and the model. Returns `J_0, …, J_steps`.
pub fn offline_pcrlb<R: Rng + ?Sized>(
    model: &Ungm,
    mean: f64,
    variance: f64,
    steps: u32,
    trajectories: usize,
    rng: &mut R,
) -> Vec<f64> {
    let mut x: Vec<f64> = (0..trajectories)
        .map(|_| mean + variance.sqrt() * rng.sample::<f64, _>(StandardNormal))
        .collect();
    let ones = vec![1.0; trajectories];
    let mut j = vec![1.0 / variance];
    for k in 0..steps {
        let next: Vec<f64> = x.iter().map(|x| model.propagate(*x, k, rng)).collect();
        let terms = step_terms(model, &x, &ones, &next, &ones);
        j.push(terms.advance(*j.last().expect("J_0")));
        x = next;
    }
    j
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_slope_is_the_transitions_derivative() {
        let m = Ungm::HIGHLY_NONLINEAR;
        for x in [-7.0, -1.3, 0.0, 0.4, 2.2, 9.0] {
            let h = 1e-6;
            let fd = (m.transition(x + h, 3) - m.transition(x - h, 3)) / (2.0 * h);
            assert!(
                (m.slope(x) - fd).abs() < 1e-7,
                "{x}: {} vs {fd}",
                m.slope(x)
            );
        }
    }

    /// A linear model (β = 0) and a constant measurement information: one
    /// step is the Kalman filter's information, `1/(σ_u² + α²/L) + H²/R`
    /// (Corollary 7.2, by the Woodbury identity).
    #[test]
    fn a_linear_step_is_the_kalman_information() {
        let (alpha, q, info) = (0.9, 2.0, 0.7);
        let terms = StepTerms {
            b11: alpha * alpha / q,
            b12: -alpha / q,
            b22: 1.0 / q + info,
        };
        for l in [0.01, 0.5, 3.0, 40.0] {
            let kalman = 1.0 / (q + alpha * alpha / l) + info;
            assert!((terms.advance(l) / kalman - 1.0).abs() < 1e-12);
        }
    }

    /// With β = 0 the states stay Gaussian, with mean m_{k+1} = αm_k +
    /// γcos(1.2k) and variance v_{k+1} = α²v_k + σ_u², so the D terms are
    /// known: D11 = α²/σ_u², D12 = −α/σ_u², D22 = 1/σ_u² + 4κ²(m² + v)/σ_v².
    /// The Monte Carlo recursion meets that one within its sampling error.
    #[test]
    fn the_offline_bound_of_a_linear_model_is_its_closed_form() {
        let model = Ungm {
            beta: 0.0,
            alpha: 0.8,
            ..Ungm::HIGHLY_NONLINEAR
        };
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let steps = 12;
        let mc = offline_pcrlb(&model, 1.0, 2.0, steps, 200_000, &mut rng);
        let (mut m, mut v, mut j) = (1.0f64, 2.0f64, 0.5f64);
        let q = model.process_variance;
        for k in 0..steps {
            m = model.alpha * m + model.gamma * (1.2 * k as f64).cos();
            v = model.alpha * model.alpha * v + q;
            let terms = StepTerms {
                b11: model.alpha.powi(2) / q,
                b12: -model.alpha / q,
                b22: 1.0 / q + 4.0 * model.kappa.powi(2) * (m * m + v) / model.measurement_variance,
            };
            j = terms.advance(j);
            let got = mc[k as usize + 1];
            assert!((got / j - 1.0).abs() < 0.01, "step {}: {got} vs {j}", k + 1);
        }
    }
}
