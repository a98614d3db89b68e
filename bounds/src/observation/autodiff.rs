//! Gradients for free: a law that gives g and R as generic arithmetic gets
//! ∇g and ∇R by forward-mode automatic differentiation, exact to rounding.
//!
//! The arithmetic is `num-dual`'s dual numbers: the law is evaluated once
//! on numbers that carry their derivatives along, in the two position
//! directions for a law of the position (most are), in all four otherwise.
//! A likelihood, which needs g and R only, evaluates the same arithmetic on
//! plain `f64`, at the cost of the law itself.

use num_dual::{DualNum, DualSVec64};

use crate::State;

use super::{Evaluation, ObservationLaw};

/// A number the law's arithmetic runs on: `f64`, or a dual number that
/// carries derivatives. Every operation of `f64` a law needs is here
/// (`sqrt`, `atan2`, `ln`, `powf`, `exp`, …, from [`DualNum`]).
pub trait Real: DualNum<Primitive = f64> + Copy {}

impl<T: DualNum<Primitive = f64> + Copy> Real for T {}

/// `atan2(y, x)` with its derivative `(x ∇y − y ∇x)/(x² + y²)` at the cost
/// of one library call: `num-dual`'s own `atan2` also takes the
/// arctangent of the ratio for its derivative. The value is `f64::atan2`'s
/// exactly (the added term is `(y·x₀ − x·y₀)/r₀²`, whose value is an exact
/// zero), so a law may use it on plain numbers and on duals alike.
#[inline]
pub fn atan2<D: Real>(y: D, x: D) -> D {
    let (y0, x0) = (y.re(), x.re());
    let r2 = y0 * y0 + x0 * x0;
    (y * x0 - x * y0) / r2 + y0.atan2(x0)
}

/// An observation law given as g and R alone, generic over the number
/// they are computed in. Wrapped in [`Autodiff`], it is an
/// [`ObservationLaw`] whose gradients are exact.
///
/// ```
/// use bounds::observation::{Autodiff, DifferentiableLaw, Real};
///
/// /// Range: `g = ‖p − s‖`, `R = σ²`.
/// #[derive(Debug)]
/// struct Range { sigma: f64 }
///
/// impl DifferentiableLaw for Range {
///     fn mean<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
///         let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
///         (dx * dx + dy * dy).sqrt()
///     }
///     fn variance<D: Real>(&self, _sensor: [f64; 2], _x: [D; 4]) -> D {
///         D::from(self.sigma * self.sigma)
///     }
/// }
///
/// let law = bounds::Law::new("range", Autodiff(Range { sigma: 2.0 }));
/// let e = law.at([0.0, 0.0]).evaluate(&bounds::State::new(3.0, 4.0, 0.0, 0.0));
/// assert_eq!(e.g, 5.0);
/// assert!((e.grad_g[0] - 0.6).abs() < 1e-15);
/// ```
pub trait DifferentiableLaw: std::fmt::Debug + Send + Sync + 'static {
    /// `g(x)` for a sensor at `sensor`.
    fn mean<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D;

    /// `R(x)`.
    fn variance<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D;

    /// See [`ObservationLaw::is_angular`].
    fn is_angular(&self) -> bool {
        false
    }

    /// See [`ObservationLaw::depends_on_position_only`].
    fn depends_on_position_only(&self) -> bool {
        true
    }

    /// See [`ObservationLaw::is_placed`].
    fn is_placed(&self) -> bool {
        true
    }
}

/// A [`DifferentiableLaw`] with its gradients by automatic differentiation.
#[derive(Debug, Clone, Copy)]
pub struct Autodiff<L>(pub L);

impl<L: DifferentiableLaw> Autodiff<L> {
    /// g and R with their derivatives in the first `N` state components.
    #[inline]
    fn seeded<const N: usize>(&self, sensor: [f64; 2], x: &State) -> Evaluation {
        let lane = |k: usize| {
            let d = DualSVec64::<N>::from_re(x[k]);
            if k < N {
                d.derivative(k)
            } else {
                d
            }
        };
        let xs = [lane(0), lane(1), lane(2), lane(3)];
        let g = self.0.mean(sensor, xs);
        let r = self.0.variance(sensor, xs);
        Evaluation {
            g: g.re,
            grad_g: gradient(&g.eps),
            r: r.re,
            grad_r: gradient(&r.eps),
        }
    }
}

/// A dual number's derivative part as a state-sized gradient; a part
/// with no derivative (a constant) is zero.
#[inline]
fn gradient<const N: usize>(
    eps: &num_dual::Derivative<f64, nalgebra::Const<N>, nalgebra::U1>,
) -> State {
    let mut out = State::zeros();
    if let Some(v) = &eps.0 {
        for k in 0..N {
            out[k] = v[k];
        }
    }
    out
}

impl<L: DifferentiableLaw> ObservationLaw for Autodiff<L> {
    #[inline]
    fn evaluate(&self, sensor: [f64; 2], x: &State) -> Evaluation {
        if self.0.depends_on_position_only() {
            self.seeded::<2>(sensor, x)
        } else {
            self.seeded::<4>(sensor, x)
        }
    }

    #[inline]
    fn mean_and_variance(&self, sensor: [f64; 2], x: &State) -> (f64, f64) {
        let xs = [x[0], x[1], x[2], x[3]];
        (self.0.mean(sensor, xs), self.0.variance(sensor, xs))
    }

    fn is_angular(&self) -> bool {
        self.0.is_angular()
    }

    fn depends_on_position_only(&self) -> bool {
        self.0.depends_on_position_only()
    }

    fn is_placed(&self) -> bool {
        self.0.is_placed()
    }
}
