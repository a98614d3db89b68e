//! Checking a law's gradients against central differences: for cqnet's own
//! laws in its tests, and for a program's in its own.

use crate::State;

use super::{wrap_angle, ObservationLaw};

/// A gradient that central differences disagree with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("∇{what} at {state:?}: the law gives {given:?}, central differences {numeric:?}")]
pub struct GradientMismatch {
    /// `"g"` or `"R"`.
    pub what: &'static str,
    pub state: [f64; 4],
    pub given: [f64; 4],
    pub numeric: [f64; 4],
}

/// Checks ∇g and ∇R of `law`, for a sensor at `sensor`, against central
/// differences of its g and R at every state of `states`, within a
/// relative 10⁻⁵ of the gradient's largest entry. The step is 10⁻⁴ of the
/// distance to the sensor, between 10⁻⁴ and 10⁻² (a law of the position
/// changes on the scale of that distance); an angle's differences are
/// wrapped, so that a bearing crossing ±π does not look like a jump of 2π.
pub fn check_gradients(
    law: &dyn ObservationLaw,
    sensor: [f64; 2],
    states: &[State],
) -> Result<(), GradientMismatch> {
    for x in states {
        let e = law.evaluate(sensor, x);
        let d = if law.is_placed() {
            (x[0] - sensor[0]).hypot(x[1] - sensor[1])
        } else {
            100.0
        };
        let h = 1e-4 * d.clamp(1.0, 100.0);
        let num_g = central(|y| law.evaluate(sensor, y).g, x, h, law.is_angular());
        let num_r = central(|y| law.evaluate(sensor, y).r, x, h, false);
        for (what, given, numeric) in [("g", e.grad_g, num_g), ("R", e.grad_r, num_r)] {
            let scale = given.abs().max().max(1e-12);
            if (numeric - given).abs().max() / scale >= 1e-5 || !given.iter().all(|v| v.is_finite())
            {
                return Err(GradientMismatch {
                    what,
                    state: (*x).into(),
                    given: given.into(),
                    numeric: numeric.into(),
                });
            }
        }
    }
    Ok(())
}

/// Central-difference gradient of a scalar function; for an angle, the
/// difference is wrapped so that crossing ±π does not look like a jump of 2π.
pub(crate) fn central(f: impl Fn(&State) -> f64, x: &State, step: f64, angular: bool) -> State {
    let mut g = State::zeros();
    for k in 0..4 {
        let (mut up, mut down) = (*x, *x);
        up[k] += step;
        down[k] -= step;
        let mut diff = f(&up) - f(&down);
        if angular {
            diff = wrap_angle(diff);
        }
        g[k] = diff / (2.0 * step);
    }
    g
}
