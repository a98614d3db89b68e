//! A motion model of our own: the target's velocity is an
//! Ornstein–Uhlenbeck process (it forgets its heading with time constant
//! τ, driven by white acceleration of intensity σ²), its position the
//! velocity's integral. Per axis, with `a = e^{−T/τ}`:
//!
//! `v(k) = a v(k−1) + ξ_v`,  `p(k) = p(k−1) + τ (1 − a) v(k−1) + ξ_p`,
//!
//! and Q the exact discretization (`β = 1/τ`):
//! `Q_vv = σ²/(2β) (1 − a²)`, `Q_pv = σ²/(2β²) (1 − a)²`,
//! `Q_pp = σ²/(2β³) (2βT − 3 + 4a − a²)`.
//! As τ → ∞ it is the constant-velocity model with continuous white
//! noise acceleration. It gives f and Q only: cqnet differentiates f.
//!
//! ```toml
//! [dynamics]
//! kind = "ornstein_uhlenbeck"
//! period = 1.0
//! tau = 30.0       # s
//! sigma = 0.05     # m s^-3/2
//! ```

use bounds::dynamics::{AutodiffMotion, DifferentiableMotion, Motion};
use bounds::observation::Real;
use bounds::Mat4;
use node::parts::{ParamError, Params};

/// The model's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrnsteinUhlenbeck {
    pub period: f64,
    pub tau: f64,
    pub sigma: f64,
}

impl OrnsteinUhlenbeck {
    /// `e^{−T/τ}`.
    fn decay(&self) -> f64 {
        (-self.period / self.tau).exp()
    }
}

impl DifferentiableMotion for OrnsteinUhlenbeck {
    fn transition<D: Real>(&self, x: [D; 4]) -> [D; 4] {
        let a = self.decay();
        let carry = self.tau * (1.0 - a);
        [x[0] + x[2] * carry, x[1] + x[3] * carry, x[2] * a, x[3] * a]
    }

    fn process_noise(&self) -> Mat4 {
        let (t, beta, q) = (self.period, 1.0 / self.tau, self.sigma * self.sigma);
        let a = self.decay();
        let vv = q / (2.0 * beta) * (1.0 - a * a);
        let pv = q / (2.0 * beta * beta) * (1.0 - a).powi(2);
        let pp = q / (2.0 * beta.powi(3)) * (2.0 * beta * t - 3.0 + 4.0 * a - a * a);
        Mat4::new(
            pp, 0.0, pv, 0.0, //
            0.0, pp, 0.0, pv, //
            pv, 0.0, vv, 0.0, //
            0.0, pv, 0.0, vv,
        )
    }
}

/// Reads `[dynamics]`'s keys and builds the model, called
/// `ornstein_uhlenbeck`.
pub fn build(period: f64, params: &Params<'_>) -> Result<Motion, ParamError> {
    params.only(&["tau", "sigma"])?;
    let positive = f64::MIN_POSITIVE..=f64::MAX;
    let model = OrnsteinUhlenbeck {
        period,
        tau: params.number("tau", positive.clone(), 30.0)?,
        sigma: params
            .number_if_given("sigma", positive)?
            .ok_or_else(|| params.error("sigma", "a number > 0", "nothing"))?,
    };
    Ok(Motion::new("ornstein_uhlenbeck", AutodiffMotion(model)))
}
