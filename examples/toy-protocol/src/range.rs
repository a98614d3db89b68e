//! A range-only sensor of our own: it measures its distance to the target,
//! more noisily the farther the target is,
//!
//! `g = √(‖p − s‖² + h²)`, `R = σ² (1 + ‖p − s‖²/d_0²)`,
//!
//! with `h` the height the sensor stands above the plane the target moves
//! in (so that a target passing over it does not make ∇g undefined). It
//! gives g and R only: its gradients come from cqnet by automatic
//! differentiation, and with them its quantizer's likelihood, the Fisher
//! information and every bound.
//!
//! ```toml
//! [observation]
//! kind = "range"
//! sigma = 5.0      # m, at the sensor
//! d0 = 1000.0      # m, where the variance has doubled
//! height = 1.0     # m (default 1)
//!
//! [quantizer]      # a range is not an angle: the quantizer's span is given
//! bits = 8
//! lo = 0.0
//! hi = 2200.0
//! ```

use bounds::observation::{Autodiff, DifferentiableLaw, Real};
use bounds::Law;
use node::parts::{ParamError, Params};

/// The range law's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    pub sigma: f64,
    pub d0: f64,
    pub height: f64,
}

impl DifferentiableLaw for Range {
    fn mean<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
        let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
        (dx * dx + dy * dy + self.height * self.height).sqrt()
    }

    fn variance<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
        let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
        (dx * dx + dy * dy) * (self.sigma * self.sigma / (self.d0 * self.d0))
            + self.sigma * self.sigma
    }
}

/// Reads `[observation]`'s keys (every one checked, each error naming its
/// full key) and builds the law, called `range`.
pub fn build(params: &Params<'_>) -> Result<Law, ParamError> {
    params.only(&["sigma", "d0", "height"])?;
    let positive = f64::MIN_POSITIVE..=f64::MAX;
    let range = Range {
        sigma: params
            .number_if_given("sigma", positive.clone())?
            .ok_or_else(|| params.error("sigma", "a number > 0", "nothing"))?,
        d0: params
            .number_if_given("d0", positive.clone())?
            .ok_or_else(|| params.error("d0", "a number > 0", "nothing"))?,
        height: params.number("height", positive, 1.0)?,
    };
    Ok(Law::new("range", Autodiff(range)))
}
