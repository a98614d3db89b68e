//! Sensor observation models: `z = g(x) + v`, `v ~ N(0, R(x))`.
//!
//! What a sensor measures is a law, [`ObservationLaw`]: g, ∇g, R and ∇R
//! at a state, for a sensor standing at a position. The Fisher
//! information of a quantized observation, its likelihood, the censoring
//! window and every bound follow from these four, so nothing downstream
//! knows which law it serves. cqnet's own laws (bearing, RSS, amplitude,
//! linear) are in [`laws`] with their gradients written out; a law of a
//! program's own implements the trait, or gives g and R alone
//! ([`DifferentiableLaw`]) and gets its gradients by automatic
//! differentiation ([`Autodiff`]). [`check_gradients`] checks any law's
//! against central differences.
//!
//! A scenario's law is a [`Law`]: a name and an implementation, cheap to
//! clone and shared by every sensor.

mod autodiff;
mod check;
pub mod laws;

use std::any::Any;
use std::f64::consts::PI;
use std::fmt;
use std::sync::Arc;

use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::batch::{Positions, CHUNK};
use crate::{ParameterError, State};

pub use autodiff::{atan2, Autodiff, DifferentiableLaw, Real};
#[cfg(test)]
pub(crate) use check::central as central_gradient;
pub use check::{check_gradients, GradientMismatch};
pub use laws::{Amplitude, Bearing, Linear, Rss};

/// g, ∇g, R and ∇R at one state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evaluation {
    pub g: f64,
    pub grad_g: State,
    pub r: f64,
    pub grad_r: State,
}

/// [`Evaluation`]s of one sensor at a batch of states, as arrays, for a
/// law that depends on the position only: `∇g = (gx, gy, 0, 0)`,
/// `∇R = (rx, ry, 0, 0)`.
#[derive(Debug, Clone, Copy)]
pub struct Evaluations {
    pub g: [f64; CHUNK],
    pub r: [f64; CHUNK],
    pub gx: [f64; CHUNK],
    pub gy: [f64; CHUNK],
    pub rx: [f64; CHUNK],
    pub ry: [f64; CHUNK],
}

impl Default for Evaluations {
    fn default() -> Self {
        Self {
            g: [0.0; CHUNK],
            r: [0.0; CHUNK],
            gx: [0.0; CHUNK],
            gy: [0.0; CHUNK],
            rx: [0.0; CHUNK],
            ry: [0.0; CHUNK],
        }
    }
}

/// Distances below this are treated as this, so that a target passing over a
/// sensor gives large but finite gradients instead of NaN.
pub const MIN_DISTANCE: f64 = 1e-3;

/// What a sensor measures and how noisily: the mean `g` and variance `R`
/// of a scalar measurement of state `x` by a sensor at `sensor`, with
/// their gradients in the state.
///
/// The filters call [`evaluate_batch`](Self::evaluate_batch) once per
/// batch of particles, so a law's cost per particle is its arithmetic,
/// not a call through a pointer; a law gains by overriding it with
/// arithmetic over the batch's arrays, as the bearing does.
pub trait ObservationLaw: Any + fmt::Debug + Send + Sync {
    /// g, ∇g, R and ∇R at `x`.
    fn evaluate(&self, sensor: [f64; 2], x: &State) -> Evaluation;

    /// g and R at `x`, without the gradients: what a likelihood needs.
    /// The same values as [`evaluate`](Self::evaluate)'s, bit for bit.
    #[inline]
    fn mean_and_variance(&self, sensor: [f64; 2], x: &State) -> (f64, f64) {
        let e = self.evaluate(sensor, x);
        (e.g, e.r)
    }

    /// [`evaluate`](Self::evaluate) at a batch of states (`states`, whose
    /// positions are `at`), bit for bit, for a law whose g and R depend
    /// on the position only: the gradients' velocity entries are zero
    /// and not written.
    #[inline]
    fn evaluate_batch(
        &self,
        sensor: [f64; 2],
        states: &[State],
        _at: &Positions,
        out: &mut Evaluations,
    ) {
        for (i, x) in states.iter().enumerate() {
            let e = self.evaluate(sensor, x);
            out.g[i] = e.g;
            out.r[i] = e.r;
            (out.gx[i], out.gy[i]) = (e.grad_g[0], e.grad_g[1]);
            (out.rx[i], out.ry[i]) = (e.grad_r[0], e.grad_r[1]);
        }
    }

    /// Whether g is an angle, so observations and quantizer cells wrap at
    /// ±π.
    fn is_angular(&self) -> bool {
        false
    }

    /// Whether g and R depend on the position only (not on the velocity).
    fn depends_on_position_only(&self) -> bool {
        true
    }

    /// Whether where the sensor stands matters to what it measures.
    fn is_placed(&self) -> bool {
        true
    }
}

/// An observation law as a scenario holds it: its name and its
/// implementation, shared.
///
/// cqnet's own laws are held as themselves rather than behind a pointer,
/// so that a batch of particles runs their arithmetic inlined (and
/// vectorised, for the bearing) as before they were a trait's; a
/// program's law is one call through a pointer per batch.
#[derive(Clone)]
pub struct Law {
    name: &'static str,
    imp: Imp,
}

#[derive(Clone)]
enum Imp {
    Bearing(Bearing),
    Rss(Rss),
    Amplitude(Amplitude),
    Linear(Linear),
    Other(Arc<dyn ObservationLaw>),
}

/// Runs `$body` with `$law` bound to the law itself, statically for
/// cqnet's own.
macro_rules! with_law {
    ($self:expr, $law:ident => $body:expr) => {
        match &$self.imp {
            Imp::Bearing($law) => $body,
            Imp::Rss($law) => $body,
            Imp::Amplitude($law) => $body,
            Imp::Linear($law) => $body,
            Imp::Other(other) => {
                let $law = &**other;
                $body
            }
        }
    };
}

impl Law {
    /// A program's law, called `name` in scenarios.
    pub fn new(name: &'static str, law: impl ObservationLaw) -> Self {
        Self {
            name,
            imp: Imp::Other(Arc::new(law)),
        }
    }

    /// The name scenarios call it by.
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// The law itself, if it is a `T`: for the few methods that hold only
    /// for one law (the amplitude sensors' closed-form location bound).
    pub fn downcast_ref<T: ObservationLaw>(&self) -> Option<&T> {
        with_law!(self, law => (law as &dyn Any).downcast_ref::<T>())
    }

    /// Whether the law is a `T`.
    pub fn is<T: ObservationLaw>(&self) -> bool {
        self.downcast_ref::<T>().is_some()
    }

    /// This law at the sensor position `sensor`.
    pub fn at(&self, sensor: [f64; 2]) -> ObservationModel {
        ObservationModel {
            sensor,
            law: self.clone(),
        }
    }
}

impl ObservationLaw for Law {
    #[inline]
    fn evaluate(&self, sensor: [f64; 2], x: &State) -> Evaluation {
        with_law!(self, law => law.evaluate(sensor, x))
    }

    #[inline]
    fn mean_and_variance(&self, sensor: [f64; 2], x: &State) -> (f64, f64) {
        with_law!(self, law => law.mean_and_variance(sensor, x))
    }

    #[inline(always)]
    fn evaluate_batch(
        &self,
        sensor: [f64; 2],
        states: &[State],
        at: &Positions,
        out: &mut Evaluations,
    ) {
        with_law!(self, law => law.evaluate_batch(sensor, states, at, out))
    }

    fn is_angular(&self) -> bool {
        with_law!(self, law => law.is_angular())
    }

    fn depends_on_position_only(&self) -> bool {
        with_law!(self, law => law.depends_on_position_only())
    }

    fn is_placed(&self) -> bool {
        with_law!(self, law => law.is_placed())
    }
}

impl fmt::Debug for Law {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        with_law!(self, law => fmt::Debug::fmt(law, f))
    }
}

impl PartialEq for Law {
    /// cqnet's own laws are equal when their parameters are; a program's
    /// when they are the same value.
    fn eq(&self, other: &Self) -> bool {
        match (&self.imp, &other.imp) {
            (Imp::Bearing(a), Imp::Bearing(b)) => a == b,
            (Imp::Rss(a), Imp::Rss(b)) => a == b,
            (Imp::Amplitude(a), Imp::Amplitude(b)) => a == b,
            (Imp::Linear(a), Imp::Linear(b)) => a == b,
            (Imp::Other(a), Imp::Other(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

/// cqnet's own laws as a scenario file spells them: `kind` and the law's
/// parameters, every one checked.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SensorLaw {
    /// [`Bearing`]: `g = atan2(p_x − X_s, p_y − Y_s)`,
    /// `R = σ_θ² (1 + (d/d_0)²)`.
    Bearing {
        sigma_theta: f64,
        d0: f64,
        /// Metres; [`MIN_DISTANCE`] when not given
        /// ([`SensorLaw::bearing_near_field`]).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        near_field: Option<f64>,
    },
    /// [`Rss`]: `g = P_0 − 5 ζ log10((d² + h²)/d_0²)`, `R = σ_r²`, with a
    /// target passing over the sensor giving the log-distance law's
    /// largest but finite information, `(10ζ/ln10)² / (4 h² σ²)` at
    /// `d = h`, rather than one growing as 1/d².
    Rss {
        p0: f64,
        zeta: f64,
        d0: f64,
        sigma: f64,
        /// `h`, metres; the reference distance `d_0` when not given
        /// ([`SensorLaw::rss_near_field`]).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        near_field: Option<f64>,
    },
    /// [`Amplitude`]: `g = sqrt(P_0 / (1 + α dⁿ))`, `R = σ²`.
    Amplitude {
        p0: f64,
        alpha: f64,
        exponent: f64,
        sigma: f64,
    },
    /// [`Linear`]: `g = hᵀx`, `R = r`.
    Linear { h: [f64; 4], r: f64 },
}

impl SensorLaw {
    /// The names of cqnet's own laws, as `kind` spells them.
    pub const KINDS: [&'static str; 4] = ["bearing", "rss", "amplitude", "linear"];

    /// The RSS law's near field `h`: as given, or the reference distance
    /// `d_0`, inside which the log-distance law (a far-field law, fitted
    /// from `d_0` outwards) is not the sensor's physics.
    pub fn rss_near_field(near_field: Option<f64>, d0: f64) -> f64 {
        near_field.unwrap_or(d0)
    }

    /// The bearing law's near field: as given, or [`MIN_DISTANCE`]. The
    /// law is of a point target seen from a point sensor, for which a
    /// bearing tells the position ever better as the target nears; a real
    /// target has an extent within which its bearing is not a direction,
    /// and a scenario with targets that pass over sensors should state it.
    /// The default only keeps the arithmetic finite, so that scenarios
    /// written without it keep their results.
    pub fn bearing_near_field(near_field: Option<f64>) -> f64 {
        near_field.unwrap_or(MIN_DISTANCE)
    }

    /// This law at the sensor position `sensor`.
    pub fn at(self, sensor: [f64; 2]) -> ObservationModel {
        Law::from(self).at(sensor)
    }

    /// Every parameter in its range: noise and distances positive, levels finite.
    pub fn validate(&self) -> Result<(), ParameterError> {
        let check = |parameter, value: f64, positive: bool| {
            let ok = value.is_finite() && (!positive || value > 0.0);
            if ok {
                Ok(())
            } else {
                Err(ParameterError {
                    parameter,
                    expected: if positive {
                        "a finite number > 0"
                    } else {
                        "a finite number"
                    },
                    value,
                })
            }
        };
        match *self {
            Self::Bearing {
                sigma_theta,
                d0,
                near_field,
            } => {
                check("sigma_theta", sigma_theta, true)?;
                if let Some(h) = near_field {
                    check("near_field", h, true)?;
                }
                check("d0", d0, true)
            }
            Self::Rss {
                p0,
                zeta,
                d0,
                sigma,
                near_field,
            } => {
                check("p0", p0, false)?;
                check("zeta", zeta, true)?;
                check("d0", d0, true)?;
                if let Some(h) = near_field {
                    check("near_field", h, true)?;
                }
                check("sigma", sigma, true)
            }
            Self::Amplitude {
                p0,
                alpha,
                exponent,
                sigma,
            } => {
                check("p0", p0, true)?;
                check("alpha", alpha, true)?;
                check("exponent", exponent, true)?;
                check("sigma", sigma, true)
            }
            Self::Linear { h, r } => {
                for v in h {
                    check("h", v, false)?;
                }
                check("r", r, true)
            }
        }
    }
}

impl From<SensorLaw> for Law {
    fn from(law: SensorLaw) -> Self {
        let (name, imp) = match law {
            SensorLaw::Bearing {
                sigma_theta,
                d0,
                near_field,
            } => (
                "bearing",
                Imp::Bearing(Bearing {
                    sigma_theta,
                    d0,
                    near_field: SensorLaw::bearing_near_field(near_field),
                }),
            ),
            SensorLaw::Rss {
                p0,
                zeta,
                d0,
                sigma,
                near_field,
            } => (
                "rss",
                Imp::Rss(Rss {
                    p0,
                    zeta,
                    d0,
                    sigma,
                    near_field: SensorLaw::rss_near_field(near_field, d0),
                }),
            ),
            SensorLaw::Amplitude {
                p0,
                alpha,
                exponent,
                sigma,
            } => (
                "amplitude",
                Imp::Amplitude(Amplitude {
                    p0,
                    alpha,
                    exponent,
                    sigma,
                }),
            ),
            SensorLaw::Linear { h, r } => ("linear", Imp::Linear(Linear { h, r })),
        };
        Self { name, imp }
    }
}

/// A sensor's observation model: its law at its position (X_s, Y_s).
#[derive(Debug, Clone, PartialEq)]
pub struct ObservationModel {
    pub sensor: [f64; 2],
    pub law: Law,
}

impl ObservationModel {
    /// Whether g is an angle, so observations and quantizer cells wrap at ±π.
    pub fn is_angular(&self) -> bool {
        self.law.is_angular()
    }

    /// Whether g and R depend on the position only (not on the velocity).
    pub fn depends_on_position_only(&self) -> bool {
        self.law.depends_on_position_only()
    }

    /// Where the sensor stands, when its law depends on it.
    pub fn sensor_position(&self) -> Option<[f64; 2]> {
        self.law.is_placed().then_some(self.sensor)
    }

    /// g, ∇g, R and ∇R at `x`.
    #[inline]
    pub fn evaluate(&self, x: &State) -> Evaluation {
        self.law.evaluate(self.sensor, x)
    }

    /// [`ObservationLaw::evaluate_batch`] for this sensor, for a law of
    /// the position only ([`depends_on_position_only`](Self::depends_on_position_only)).
    #[inline(always)]
    pub fn evaluate_batch(&self, states: &[State], at: &Positions, out: &mut Evaluations) {
        debug_assert!(self.depends_on_position_only() && states.len() <= CHUNK);
        self.law.evaluate_batch(self.sensor, states, at, out)
    }

    /// g and R at `x`, without the gradients: what a likelihood needs.
    /// The same values as [`evaluate`](Self::evaluate)'s, bit for bit.
    #[inline]
    pub fn mean_and_variance(&self, x: &State) -> (f64, f64) {
        self.law.mean_and_variance(self.sensor, x)
    }

    /// One noisy, unquantized measurement of the true state (angles wrapped).
    pub fn sample<R: Rng + ?Sized>(&self, x: &State, rng: &mut R) -> f64 {
        let e = self.evaluate(x);
        let z = e.g + e.r.sqrt() * rng.sample::<f64, _>(StandardNormal);
        if self.is_angular() {
            wrap_angle(z)
        } else {
            z
        }
    }
}

/// Wraps an angle into (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let w = crate::modulo(a + PI, 2.0 * PI) - PI;
    if w == -PI {
        PI
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::random_state;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::LN_10;

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn evaluate_avx2(
        model: &ObservationModel,
        states: &[State],
        at: &Positions,
        out: &mut Evaluations,
    ) {
        model.evaluate_batch(states, at, out)
    }

    /// The batch is `evaluate` state by state, bit for bit, vectorised or
    /// not, for every law of the position, with states near, far, and on
    /// the sensor (the distance floor).
    #[test]
    fn the_batch_is_evaluate_bit_for_bit() {
        let laws = [
            SensorLaw::Bearing {
                sigma_theta: 0.05,
                d0: 200.0,
                near_field: None,
            },
            SensorLaw::Rss {
                p0: -30.0,
                zeta: 3.0,
                d0: 1.0,
                sigma: 2.0,
                near_field: None,
            },
            SensorLaw::Amplitude {
                p0: 100.0,
                alpha: 0.01,
                exponent: 2.0,
                sigma: 0.5,
            },
            SensorLaw::Linear {
                h: [1.0, -2.0, 0.0, 0.0],
                r: 3.0,
            },
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        for law in laws {
            let model = law.at([120.0, -35.0]);
            for n in [CHUNK, 23] {
                let mut states: Vec<State> = (0..n)
                    .map(|_| {
                        let scale = 10f64.powf(rng.random_range(-4.0..4.0));
                        State::new(
                            120.0 + scale * rng.random_range(-1.0..1.0),
                            -35.0 + scale * rng.random_range(-1.0..1.0),
                            rng.random_range(-9.0..9.0),
                            rng.random_range(-9.0..9.0),
                        )
                    })
                    .collect();
                states[0] = State::new(120.0, -35.0, 1.0, 1.0);
                let at = Positions::of(&states);
                let mut plain = Evaluations::default();
                model.evaluate_batch(&states, &at, &mut plain);
                let mut wide = Evaluations::default();
                if crate::batch::has_avx2() {
                    // SAFETY: the CPU has AVX2.
                    unsafe { evaluate_avx2(&model, &states, &at, &mut wide) };
                } else {
                    wide = plain;
                }
                for (i, x) in states.iter().enumerate() {
                    let e = model.evaluate(x);
                    let want = [e.g, e.r, e.grad_g[0], e.grad_g[1], e.grad_r[0], e.grad_r[1]];
                    for b in [&plain, &wide] {
                        let got = [b.g[i], b.r[i], b.gx[i], b.gy[i], b.rx[i], b.ry[i]];
                        assert!(
                            got.iter()
                                .zip(want)
                                .all(|(a, b)| a.to_bits() == b.to_bits()),
                            "{law:?} at {x:?}: {got:?} vs {want:?}"
                        );
                    }
                }
            }
        }
    }

    /// The RSS near field: over the sensor the information is finite, it
    /// peaks at `d = h` at `(10ζ/ln10)²/(4h²σ²)`, and the gradient is the
    /// law's own there too (central differences).
    #[test]
    fn rss_information_is_bounded_in_the_near_field() {
        let (zeta, sigma, h) = (3.0, 4.0, 2.0);
        let model = SensorLaw::Rss {
            p0: -30.0,
            zeta,
            d0: 1.0,
            sigma,
            near_field: Some(h),
        }
        .at([50.0, 50.0]);
        let info = |d: f64| {
            let e = model.evaluate(&State::new(50.0 + d, 50.0, 0.0, 0.0));
            e.grad_g.norm_squared() / e.r
        };
        let peak = (10.0 * zeta / LN_10).powi(2) / (4.0 * h * h * sigma * sigma);
        assert_eq!(info(0.0), 0.0);
        assert!(
            (info(h) / peak - 1.0).abs() < 1e-12,
            "{} vs {peak}",
            info(h)
        );
        for d in [0.01, 0.5, 1.0, 1.9, 2.1, 5.0, 40.0] {
            assert!(info(d) < peak, "d = {d}");
        }
        for d in [0.3, 2.0, 7.0] {
            let x = State::new(50.0 + d, 50.0 - 0.4 * d, 1.0, 0.0);
            let fd = crate::testing::central_gradient(|y| model.evaluate(y).g, &x, 1e-6, false);
            let grad = model.evaluate(&x).grad_g;
            assert!(
                (fd - grad).norm() < 1e-6 * grad.norm(),
                "d = {d}: {fd} vs {grad}"
            );
        }
        // Without `near_field` it is the reference distance d0.
        let default = SensorLaw::Rss {
            p0: -30.0,
            zeta,
            d0: 1.0,
            sigma,
            near_field: None,
        }
        .at([0.0, 0.0]);
        assert_eq!(default.evaluate(&State::zeros()).g, -30.0);
    }

    /// The bearing near field: inside it the information stops growing
    /// (`|∇g|² ≤ 1/h²`), outside it the law is untouched, and left out it
    /// is the 1 mm that only keeps the arithmetic finite.
    #[test]
    fn bearing_information_stops_growing_inside_the_near_field() {
        let law = |near_field| SensorLaw::Bearing {
            sigma_theta: 0.02,
            d0: 500.0,
            near_field,
        };
        let with = law(Some(5.0)).at([0.0, 0.0]);
        for d in [0.1, 1.0, 3.0, 4.9] {
            let e = with.evaluate(&State::new(d * 0.6, d * 0.8, 0.0, 0.0));
            assert!(
                e.grad_g.norm_squared() <= 1.0 / 25.0 * (1.0 + 1e-12),
                "d = {d}"
            );
        }
        let far = State::new(30.0, -40.0, 1.0, 0.0);
        assert_eq!(with.evaluate(&far), law(None).at([0.0, 0.0]).evaluate(&far));
        let near = State::new(1e-4, 2e-4, 0.0, 0.0);
        assert_eq!(
            law(None).at([0.0, 0.0]).evaluate(&near),
            law(Some(MIN_DISTANCE)).at([0.0, 0.0]).evaluate(&near)
        );
    }

    fn models() -> Vec<ObservationModel> {
        vec![
            SensorLaw::Bearing {
                sigma_theta: 0.02,
                d0: 500.0,
                near_field: None,
            }
            .at([250.0, 750.0]),
            SensorLaw::Rss {
                p0: -30.0,
                zeta: 3.0,
                d0: 1.0,
                sigma: 2.0,
                near_field: None,
            }
            .at([250.0, 750.0]),
            SensorLaw::Amplitude {
                p0: 1e4,
                alpha: 1e-3,
                exponent: 2.0,
                sigma: 0.5,
            }
            .at([250.0, 750.0]),
            // The other whole exponents take their own branch of dⁿ, and
            // a fractional one `powf`.
            SensorLaw::Amplitude {
                p0: 1e4,
                alpha: 1e-2,
                exponent: 1.0,
                sigma: 0.5,
            }
            .at([250.0, 750.0]),
            SensorLaw::Amplitude {
                p0: 1e4,
                alpha: 1e-4,
                exponent: 3.0,
                sigma: 0.5,
            }
            .at([250.0, 750.0]),
            SensorLaw::Amplitude {
                p0: 1e4,
                alpha: 1e-4,
                exponent: 4.0,
                sigma: 0.5,
            }
            .at([250.0, 750.0]),
            SensorLaw::Amplitude {
                p0: 1e4,
                alpha: 1e-4,
                exponent: 2.5,
                sigma: 0.5,
            }
            .at([250.0, 750.0]),
            SensorLaw::Linear {
                h: [1.0, 0.5, -0.25, 2.0],
                r: 4.0,
            }
            .at([0.0, 0.0]),
        ]
    }

    /// The states the gradients are checked at: random over the region, some
    /// within a few metres of the sensor, and some due south of it where the
    /// bearing is ±π (the wrap).
    fn states(rng: &mut ChaCha8Rng) -> Vec<State> {
        let mut v: Vec<State> = (0..1000).map(|_| random_state(rng, 1500.0, 20.0)).collect();
        for i in 0..200 {
            let r = 0.5 + i as f64 * 0.05;
            let a = i as f64 * 0.7;
            v.push(State::new(
                250.0 + r * a.sin(),
                750.0 + r * a.cos(),
                1.0,
                1.0,
            ));
        }
        for i in 0..100 {
            // South of the sensor, slightly east and west: bearings near ±π.
            let east = (i as f64 - 50.0) * 0.01;
            v.push(State::new(
                250.0 + east + 1e-3,
                750.0 - 100.0 - i as f64,
                0.0,
                0.0,
            ));
        }
        v
    }

    /// The built-in bearing's arithmetic as a program's law would give
    /// it, g and R alone: its automatic gradients must be the written-out
    /// ones, to rounding.
    #[derive(Debug)]
    struct BearingByHand;

    impl DifferentiableLaw for BearingByHand {
        fn mean<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
            (x[0] - sensor[0]).atan2(x[1] - sensor[1])
        }

        fn variance<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
            let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
            (dx * dx + dy * dy) * (0.02 * 0.02 / (500.0 * 500.0)) + 0.02 * 0.02
        }

        fn is_angular(&self) -> bool {
            true
        }
    }

    /// Every law's gradients, the built-ins' written out and a program's
    /// automatic, agree with central differences ([`check_gradients`]).
    #[test]
    fn gradients_match_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let xs = states(&mut rng);
        let mut laws = models();
        laws.push(Law::new("bearing_by_hand", Autodiff(BearingByHand)).at([250.0, 750.0]));
        for m in laws {
            if let Err(e) = check_gradients(&m.law, m.sensor, &xs) {
                panic!("{:?}: {e}", m.law);
            }
        }
    }

    /// The same law through [`atan2`], the one-call dual arctangent.
    #[derive(Debug)]
    struct BearingByHelper;

    impl DifferentiableLaw for BearingByHelper {
        fn mean<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
            atan2(x[0] - sensor[0], x[1] - sensor[1])
        }

        fn variance<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
            BearingByHand.variance(sensor, x)
        }

        fn is_angular(&self) -> bool {
            true
        }
    }

    /// [`atan2`] on plain numbers is `f64::atan2` bit for bit, and on duals
    /// it gives the gradient `num-dual`'s own gives, to rounding.
    #[test]
    fn the_one_call_arctangent_is_the_arctangent() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let sensor = [250.0, 750.0];
        let plain = Law::new("by_hand", Autodiff(BearingByHand)).at(sensor);
        let helped = Law::new("by_helper", Autodiff(BearingByHelper)).at(sensor);
        for x in states(&mut rng) {
            let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
            assert_eq!(atan2(dx, dy).to_bits(), dx.atan2(dy).to_bits());
            let (a, b) = (plain.evaluate(&x), helped.evaluate(&x));
            assert_eq!(a.g.to_bits(), b.g.to_bits());
            for k in 0..4 {
                let (p, q) = (a.grad_g[k], b.grad_g[k]);
                assert!(
                    (p - q).abs() <= 1e-12 * p.abs().max(q.abs()),
                    "{x:?}: {a:?} vs {b:?}"
                );
            }
        }
    }

    /// Automatic gradients are the closed form's to rounding: the built-in
    /// bearing against the same law given without its gradients.
    #[test]
    fn automatic_gradients_are_the_closed_forms_to_rounding() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let built_in = models().remove(0);
        let by_hand = Law::new("bearing_by_hand", Autodiff(BearingByHand)).at(built_in.sensor);
        for x in states(&mut rng) {
            let (a, b) = (built_in.evaluate(&x), by_hand.evaluate(&x));
            let close = |p: f64, q: f64| (p - q).abs() <= 1e-12 * p.abs().max(q.abs()).max(1e-300);
            assert!(close(a.g, b.g) && close(a.r, b.r), "{x:?}");
            for k in 0..4 {
                assert!(
                    close(a.grad_g[k], b.grad_g[k]),
                    "∇g at {x:?}: {a:?} vs {b:?}"
                );
                assert!(
                    close(a.grad_r[k], b.grad_r[k]),
                    "∇R at {x:?}: {a:?} vs {b:?}"
                );
            }
        }
    }

    #[test]
    fn mean_and_variance_are_those_of_the_full_evaluation() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for m in models() {
            for x in &states(&mut rng) {
                let e = m.evaluate(x);
                let (g, r) = m.mean_and_variance(x);
                assert_eq!((g.to_bits(), r.to_bits()), (e.g.to_bits(), e.r.to_bits()));
            }
        }
    }

    #[test]
    fn bearing_is_measured_clockwise_from_north() {
        let m = SensorLaw::Bearing {
            sigma_theta: 0.01,
            d0: 100.0,
            near_field: None,
        }
        .at([0.0, 0.0]);
        let at = |x, y| m.evaluate(&State::new(x, y, 0.0, 0.0)).g;
        assert!((at(0.0, 10.0) - 0.0).abs() < 1e-15);
        assert!((at(10.0, 0.0) - PI / 2.0).abs() < 1e-15);
        assert!((at(-10.0, 0.0) + PI / 2.0).abs() < 1e-15);
        assert!((at(0.0, -10.0).abs() - PI).abs() < 1e-15);
    }

    #[test]
    fn wrap_angle_lands_in_half_open_interval() {
        for a in [-7.0, -PI, -3.0, 0.0, 3.0, PI, 7.0, 100.0] {
            let w = wrap_angle(a);
            assert!(w > -PI && w <= PI, "{a} -> {w}");
            assert!(
                ((w - a) / (2.0 * PI)).fract().abs() < 1e-12
                    || ((w - a) / (2.0 * PI)).fract().abs() > 1.0 - 1e-12
            );
        }
    }
}
