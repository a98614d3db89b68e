//! Target dynamics: how the state moves from one step to the next.
//!
//! A motion model is a trait, [`MotionModel`]: the transition `f`, its
//! Jacobian `F̃` and the process noise `Q`, which is all the predictor and
//! the bound's D terms need. cqnet's own is the clockwise coordinated turn
//! whose turn rate depends on speed, with constant velocity as its
//! `a_m = 0` case; a program's gives `f` and `Q`, and its Jacobian, or
//! gives `f` generically ([`DifferentiableMotion`]) and gets `F̃` by
//! automatic differentiation. [`Dynamics`] is a model with what every step
//! needs of it computed once: `Q⁻¹` and a factor of `Q`.

use std::any::Any;
use std::fmt;
use std::sync::Arc;

use nalgebra::{Cholesky, Matrix2};
use num_dual::DualSVec64;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::batch::{StateLanes, CHUNK};
use crate::{Mat4, ParameterError, State};

const POSITIVE: &str = "a finite number > 0";
const NON_NEGATIVE: &str = "a finite number >= 0";

/// Below this |ωT| the trigonometric ratios use their Taylor series, whose
/// truncation error (~(ωT)⁴) is then far below f64 precision.
const SMALL_TURN: f64 = 1e-4;

/// `x(k) = F(Ω(x)) x(k−1) + ξ`, `Ω(x) = −a_m / max(‖v‖, v_min)`, `ξ ~ N(0, Q)`.
///
/// Its serde form is the scenario file's `[dynamics]` keys, every one
/// checked.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CoordinatedTurn {
    /// Sampling period T, seconds.
    pub period: f64,
    /// Manoeuvre acceleration a_m ≥ 0, m/s². Zero gives constant velocity.
    pub maneuver_accel: f64,
    /// Speed floor v_min > 0 that keeps the turn rate finite, m/s; 0.1
    /// when a file leaves it out.
    #[serde(default = "default_min_speed")]
    pub min_speed: f64,
    /// Process-noise intensity: σ_v in m s^-3/2 for the continuous model,
    /// σ in m/s² for the discrete one.
    pub sigma_v: f64,
    /// Which white-noise acceleration model gives Q.
    #[serde(default)]
    pub process_noise: ProcessNoise,
}

fn default_min_speed() -> f64 {
    0.1
}

/// The two white-noise acceleration models of the literature (Bar-Shalom,
/// Li and Kirubarajan §6.2–6.3). They differ in Q, per axis:
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProcessNoise {
    /// Continuous white noise acceleration, integrated over the period:
    /// `σ_v² [[T³/3, T²/2], [T²/2, T]]` (seeds 000 and 001).
    #[default]
    Continuous,
    /// Piecewise-constant acceleration, one draw per period:
    /// `σ² [[T⁴/4, T³/2], [T³/2, T²]]` (dissertation ch. 3), which is rank
    /// one per axis.
    Discrete,
}

/// How the target's state moves over one period: `x(k) = f(x(k−1)) + ξ`,
/// `ξ ~ N(0, Q)`.
///
/// The predictor and the bound call
/// [`transition_batch`](Self::transition_batch) once per batch of
/// particles, so a model's cost per particle is its arithmetic.
pub trait MotionModel: Any + fmt::Debug + Send + Sync {
    /// `f(x)`.
    fn transition(&self, x: &State) -> State;

    /// `F̃(x) = ∂f/∂x`.
    fn jacobian(&self, x: &State) -> Mat4;

    /// `f(x)` and `F̃(x)` together, for a model that shares work between
    /// them.
    fn transition_and_jacobian(&self, x: &State) -> (State, Mat4) {
        (self.transition(x), self.jacobian(x))
    }

    /// `Q`, the covariance of the process noise over one period; positive
    /// definite, since the bound's recursion needs `Q⁻¹`.
    fn process_noise(&self) -> Mat4;

    /// [`transition_and_jacobian`](Self::transition_and_jacobian) at a
    /// batch of states, bit for bit.
    fn transition_batch(&self, x: &StateLanes, out: &mut TransitionBatch) {
        for i in 0..CHUNK {
            let lane = State::new(x.c[0][i], x.c[1][i], x.c[2][i], x.c[3][i]);
            let (next, f) = self.transition_and_jacobian(&lane);
            out.set_general(i, &next, &f);
        }
    }
}

/// A motion model given as `f` alone, generic over the number it is
/// computed in ([`crate::observation::Real`]). Wrapped in
/// [`AutodiffMotion`], it is a [`MotionModel`] whose Jacobian is exact.
pub trait DifferentiableMotion: fmt::Debug + Send + Sync + 'static {
    /// `f(x)`.
    fn transition<D: crate::observation::Real>(&self, x: [D; 4]) -> [D; 4];

    /// `Q`.
    fn process_noise(&self) -> Mat4;
}

/// A [`DifferentiableMotion`] with its Jacobian by automatic differentiation.
#[derive(Debug, Clone, Copy)]
pub struct AutodiffMotion<M>(pub M);

impl<M: DifferentiableMotion> MotionModel for AutodiffMotion<M> {
    fn transition(&self, x: &State) -> State {
        State::from(self.0.transition([x[0], x[1], x[2], x[3]]))
    }

    fn jacobian(&self, x: &State) -> Mat4 {
        self.transition_and_jacobian(x).1
    }

    fn transition_and_jacobian(&self, x: &State) -> (State, Mat4) {
        let lane = |k: usize| DualSVec64::<4>::from_re(x[k]).derivative(k);
        let out = self.0.transition([lane(0), lane(1), lane(2), lane(3)]);
        let mut f = Mat4::zeros();
        for (row, y) in out.iter().enumerate() {
            if let Some(d) = &y.eps.0 {
                for col in 0..4 {
                    f[(row, col)] = d[col];
                }
            }
        }
        (State::from_fn(|k, _| out[k].re), f)
    }

    fn process_noise(&self) -> Mat4 {
        self.0.process_noise()
    }
}

/// A motion model as a scenario holds it: its name and its implementation,
/// shared. The coordinated turn is held as itself, so that its batch runs
/// inlined and vectorised; a program's model is one call through a
/// pointer per batch.
#[derive(Clone)]
pub struct Motion {
    name: &'static str,
    imp: MotionImp,
}

#[derive(Clone)]
enum MotionImp {
    Turn(CoordinatedTurn),
    Other(Arc<dyn MotionModel>),
}

macro_rules! with_model {
    ($self:expr, $m:ident => $body:expr) => {
        match &$self.imp {
            MotionImp::Turn($m) => $body,
            MotionImp::Other(other) => {
                let $m = &**other;
                $body
            }
        }
    };
}

impl Motion {
    /// A program's model, called `name` in scenarios.
    pub fn new(name: &'static str, model: impl MotionModel) -> Self {
        Self {
            name,
            imp: MotionImp::Other(Arc::new(model)),
        }
    }

    /// The name scenarios call it by.
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// The model itself, if it is a `T`.
    pub fn downcast_ref<T: MotionModel>(&self) -> Option<&T> {
        with_model!(self, m => (m as &dyn Any).downcast_ref::<T>())
    }
}

impl From<CoordinatedTurn> for Motion {
    fn from(model: CoordinatedTurn) -> Self {
        Self {
            name: CoordinatedTurn::KIND,
            imp: MotionImp::Turn(model),
        }
    }
}

impl MotionModel for Motion {
    #[inline]
    fn transition(&self, x: &State) -> State {
        with_model!(self, m => m.transition(x))
    }

    #[inline]
    fn jacobian(&self, x: &State) -> Mat4 {
        with_model!(self, m => m.jacobian(x))
    }

    #[inline]
    fn transition_and_jacobian(&self, x: &State) -> (State, Mat4) {
        with_model!(self, m => m.transition_and_jacobian(x))
    }

    fn process_noise(&self) -> Mat4 {
        with_model!(self, m => MotionModel::process_noise(m))
    }

    #[inline(always)]
    fn transition_batch(&self, x: &StateLanes, out: &mut TransitionBatch) {
        with_model!(self, m => m.transition_batch(x, out))
    }
}

impl fmt::Debug for Motion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        with_model!(self, m => fmt::Debug::fmt(m, f))
    }
}

impl PartialEq for Motion {
    /// The coordinated turn by its parameters; a program's model when it
    /// is the same value.
    fn eq(&self, other: &Self) -> bool {
        match (&self.imp, &other.imp) {
            (MotionImp::Turn(a), MotionImp::Turn(b)) => a == b,
            (MotionImp::Other(a), MotionImp::Other(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

/// Everything about one transition that the filters and bounds need, computed
/// once: `Q`, `Q⁻¹` and the Cholesky factor used to sample `ξ`.
#[derive(Debug, Clone)]
pub struct Dynamics {
    pub model: Motion,
    q: Mat4,
    q_inv: Mat4,
    q_chol: Mat4,
}

impl CoordinatedTurn {
    /// What scenarios call it (`[dynamics] kind`).
    pub const KIND: &'static str = "coordinated_turn";

    pub fn constant_velocity(period: f64, sigma_v: f64) -> Self {
        Self {
            period,
            maneuver_accel: 0.0,
            min_speed: 1.0,
            sigma_v,
            process_noise: ProcessNoise::Continuous,
        }
    }

    /// Turn rate Ω(x), rad/s (negative: clockwise).
    pub fn turn_rate(&self, x: &State) -> f64 {
        self.turn_rate_of(x[2], x[3])
    }

    /// Ω at the velocity `(vx, vy)`.
    #[inline(always)]
    fn turn_rate_of(&self, vx: f64, vy: f64) -> f64 {
        -self.maneuver_accel / (vx * vx + vy * vy).sqrt().max(self.min_speed)
    }

    /// `f(x) = F(Ω(x)) x`.
    pub fn transition(&self, x: &State) -> State {
        Self::apply(&TurnTerms::new(self.turn_rate(x), self.period), x)
    }

    /// `F̃(x) = ∂f/∂x`, including the dependence of Ω on the velocity:
    /// `F̃ = F(Ω) + (∂F/∂ω · x) (∂Ω/∂x)ᵀ`.
    pub fn jacobian(&self, x: &State) -> Mat4 {
        self.jacobian_from(&TurnTerms::new(self.turn_rate(x), self.period), x)
    }

    /// `f(x)` and `F̃(x)` from one evaluation of the turn's trigonometry:
    /// a predictor that also carries a bound needs both at every particle.
    pub fn transition_and_jacobian(&self, x: &State) -> (State, Mat4) {
        let t = TurnTerms::new(self.turn_rate(x), self.period);
        (Self::apply(&t, x), self.jacobian_from(&t, x))
    }

    /// [`transition_and_jacobian`](Self::transition_and_jacobian) at a
    /// batch of states, bit for bit, vectorised ([`crate::batch`]): f(x)
    /// and the two blocks of F̃ that vary, `F̃ = [[I, A], [0, B]]`.
    #[inline(always)]
    pub fn transition_batch(&self, x: &StateLanes, out: &mut TransitionBatch) {
        out.carried = true;
        let (mut omega, mut wt) = ([0.0; CHUNK], [0.0; CHUNK]);
        for i in 0..CHUNK {
            omega[i] = self.turn_rate_of(x.c[2][i], x.c[3][i]);
            wt[i] = omega[i] * self.period;
        }
        let (mut sin, mut cos) = ([0.0; CHUNK], [0.0; CHUNK]);
        crate::batch::sincos(&wt, &mut sin, &mut cos);
        for i in 0..CHUNK {
            let t = TurnTerms::with(omega[i], self.period, sin[i], cos[i]);
            let lane = State::new(x.c[0][i], x.c[1][i], x.c[2][i], x.c[3][i]);
            let next = Self::apply(&t, &lane);
            let (a, b) = self.jacobian_blocks(&t, &lane);
            for k in 0..4 {
                out.next[k][i] = next[k];
                out.a[k][i] = a[k];
                out.b[k][i] = b[k];
            }
        }
    }

    #[inline(always)]
    fn apply(t: &TurnTerms, x: &State) -> State {
        let (vx, vy) = (x[2], x[3]);
        State::new(
            x[0] + t.s * vx - t.c * vy,
            x[1] + t.c * vx + t.s * vy,
            t.cos * vx - t.sin * vy,
            t.sin * vx + t.cos * vy,
        )
    }

    #[inline]
    fn jacobian_from(&self, t: &TurnTerms, x: &State) -> Mat4 {
        let (a, b) = self.jacobian_blocks(t, x);
        Mat4::new(
            1.0, 0.0, a[0], a[1], //
            0.0, 1.0, a[2], a[3], //
            0.0, 0.0, b[0], b[1], //
            0.0, 0.0, b[2], b[3],
        )
    }

    /// The blocks A (rows 0–1) and B (rows 2–3) of columns 2–3 of
    /// `F̃ = [[I, A], [0, B]]`, row by row: F(ω)'s, plus `(∂F/∂ω · x)(∂Ω/∂v)ᵀ`
    /// while the turn rate follows the speed. Branch-free, so that a loop
    /// over lanes vectorises.
    #[inline(always)]
    fn jacobian_blocks(&self, t: &TurnTerms, x: &State) -> ([f64; 4], [f64; 4]) {
        let (vx, vy) = (x[2], x[3]);
        let v = speed(x);
        let turning = self.maneuver_accel > 0.0 && v > self.min_speed;
        let period = self.period;
        // ∂(F x)/∂ω
        let df = [
            t.ds * vx - t.dc * vy,
            t.dc * vx + t.ds * vy,
            -period * (t.sin * vx + t.cos * vy),
            period * (t.cos * vx - t.sin * vy),
        ];
        // Ω = −a_m/‖v‖ ⇒ ∂Ω/∂v = a_m v / ‖v‖³
        let k = self.maneuver_accel / (v * v * v);
        let (dw_dvx, dw_dvy) = (k * vx, k * vy);
        let f = [[t.s, -t.c], [t.c, t.s], [t.cos, -t.sin], [t.sin, t.cos]];
        let entry = |r: usize, c: usize, dw: f64| {
            if turning {
                f[r][c] + df[r] * dw
            } else {
                f[r][c]
            }
        };
        (
            [
                entry(0, 0, dw_dvx),
                entry(0, 1, dw_dvy),
                entry(1, 0, dw_dvx),
                entry(1, 1, dw_dvy),
            ],
            [
                entry(2, 0, dw_dvx),
                entry(2, 1, dw_dvy),
                entry(3, 0, dw_dvx),
                entry(3, 1, dw_dvy),
            ],
        )
    }

    /// `Q`: `σ_v² [[T³/3 I, T²/2 I], [T²/2 I, T I]]` (continuous) or
    /// `σ² [[T⁴/4 I, T³/2 I], [T³/2 I, T² I]]` (discrete).
    pub fn process_noise(&self) -> Mat4 {
        let t = self.period;
        let q = self.sigma_v * self.sigma_v;
        let (pp, pv, vv) = match self.process_noise {
            ProcessNoise::Continuous => (t * t * t / 3.0, t * t / 2.0, t),
            ProcessNoise::Discrete => (t.powi(4) / 4.0, t.powi(3) / 2.0, t * t),
        };
        let block = |c: f64| Matrix2::identity() * (q * c);
        let mut m = Mat4::zeros();
        m.fixed_view_mut::<2, 2>(0, 0).copy_from(&block(pp));
        m.fixed_view_mut::<2, 2>(0, 2).copy_from(&block(pv));
        m.fixed_view_mut::<2, 2>(2, 0).copy_from(&block(pv));
        m.fixed_view_mut::<2, 2>(2, 2).copy_from(&block(vv));
        m
    }

    /// A factor `L` with `L Lᵀ = Q`, for sampling `ξ = L n`. The discrete
    /// model's Q is singular (one acceleration per axis drives both position
    /// and velocity), so it has no Cholesky factor; its exact factor is the
    /// gain `σ [T²/2, T]` per axis.
    pub fn process_noise_factor(&self) -> Mat4 {
        match self.process_noise {
            ProcessNoise::Continuous => Cholesky::new(self.process_noise())
                .map(|c| c.l())
                .unwrap_or_else(Mat4::zeros),
            ProcessNoise::Discrete => {
                let t = self.period;
                let (p, v) = (self.sigma_v * t * t / 2.0, self.sigma_v * t);
                let mut l = Mat4::zeros();
                l[(0, 0)] = p;
                l[(2, 0)] = v;
                l[(1, 1)] = p;
                l[(3, 1)] = v;
                l
            }
        }
    }
}

impl CoordinatedTurn {
    /// The parameters checked: T, σ_v and v_min positive, a_m ≥ 0, and
    /// the continuous noise model (which makes Q positive definite).
    pub fn validate(&self) -> Result<(), ParameterError> {
        let model = self;
        let check = |parameter, value: f64, expected| {
            let ok = value.is_finite()
                && if expected == POSITIVE {
                    value > 0.0
                } else {
                    value >= 0.0
                };
            if ok {
                Ok(())
            } else {
                Err(ParameterError {
                    parameter,
                    expected,
                    value,
                })
            }
        };
        check("period", model.period, POSITIVE)?;
        check("sigma_v", model.sigma_v, POSITIVE)?;
        check("min_speed", model.min_speed, POSITIVE)?;
        check("maneuver_accel", model.maneuver_accel, NON_NEGATIVE)?;
        if model.process_noise == ProcessNoise::Discrete {
            // The filters could sample it (`process_noise_factor`), but the
            // PCRLB recursion that every node runs needs Q⁻¹.
            return Err(ParameterError {
                parameter: "process_noise",
                expected:
                    "\"continuous\": the discrete model's Q is singular, and the PCRLB needs Q⁻¹",
                value: model.sigma_v,
            });
        }
        Ok(())
    }
}

impl MotionModel for CoordinatedTurn {
    #[inline]
    fn transition(&self, x: &State) -> State {
        CoordinatedTurn::transition(self, x)
    }

    #[inline]
    fn jacobian(&self, x: &State) -> Mat4 {
        CoordinatedTurn::jacobian(self, x)
    }

    #[inline]
    fn transition_and_jacobian(&self, x: &State) -> (State, Mat4) {
        CoordinatedTurn::transition_and_jacobian(self, x)
    }

    fn process_noise(&self) -> Mat4 {
        CoordinatedTurn::process_noise(self)
    }

    #[inline(always)]
    fn transition_batch(&self, x: &StateLanes, out: &mut TransitionBatch) {
        CoordinatedTurn::transition_batch(self, x, out)
    }
}

impl Dynamics {
    /// The coordinated turn, its parameters checked
    /// ([`CoordinatedTurn::validate`]).
    pub fn new(model: CoordinatedTurn) -> Result<Self, ParameterError> {
        model.validate()?;
        Self::of(model.into()).map_err(|_| ParameterError {
            parameter: "sigma_v",
            expected: "a value that makes Q positive definite",
            value: model.sigma_v,
        })
    }

    /// Any motion model, whose `Q` must be positive definite.
    pub fn of(model: Motion) -> Result<Self, NotPositiveDefinite> {
        let q = model.process_noise();
        let chol = Cholesky::new(q).ok_or(NotPositiveDefinite)?;
        let q_inv = chol.inverse();
        Ok(Self {
            model,
            q,
            q_inv,
            q_chol: chol.l(),
        })
    }

    pub fn q(&self) -> &Mat4 {
        &self.q
    }

    /// `Q⁻¹`.
    pub fn q_inv(&self) -> &Mat4 {
        &self.q_inv
    }

    pub fn transition(&self, x: &State) -> State {
        self.model.transition(x)
    }

    pub fn jacobian(&self, x: &State) -> Mat4 {
        self.model.jacobian(x)
    }

    /// [`MotionModel::transition_batch`].
    #[inline(always)]
    pub fn transition_batch(&self, x: &StateLanes, out: &mut TransitionBatch) {
        self.model.transition_batch(x, out)
    }

    /// The factor `L` of `Q = L Lᵀ` that [`sample_noise`](Self::sample_noise) draws with.
    pub fn noise_factor(&self) -> &Mat4 {
        &self.q_chol
    }

    /// One draw of `ξ ~ N(0, Q)`.
    pub fn sample_noise<R: Rng + ?Sized>(&self, rng: &mut R) -> State {
        let n = State::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal));
        self.q_chol * n
    }

    /// One draw from `p(x(k) | x(k−1))`: the predictor's proposal.
    pub fn propagate<R: Rng + ?Sized>(&self, x: &State, rng: &mut R) -> State {
        self.transition(x) + self.sample_noise(rng)
    }
}

/// A motion model's `Q` that is not positive definite.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the process noise Q is not positive definite")]
pub struct NotPositiveDefinite;

/// f(x) and `F̃(x)` at a batch of states, as arrays: `next[k][i]` is
/// component k of lane i's f(x). `F̃ = [[C, A], [D, B]]` in 2×2 blocks,
/// each row by row (`a[0]`, `a[1]` its first row). Most motion models
/// carry the position by the velocity, `C = I` and `D = 0`, and then say
/// so (`carried`) and leave `c` and `d` unwritten: the bound's sums take
/// a shorter way for them.
#[derive(Debug, Clone, Copy)]
pub struct TransitionBatch {
    pub next: [[f64; CHUNK]; 4],
    pub a: [[f64; CHUNK]; 4],
    pub b: [[f64; CHUNK]; 4],
    pub c: [[f64; CHUNK]; 4],
    pub d: [[f64; CHUNK]; 4],
    /// `C = I` and `D = 0` in every lane.
    pub carried: bool,
}

impl Default for TransitionBatch {
    fn default() -> Self {
        Self {
            next: [[0.0; CHUNK]; 4],
            a: [[0.0; CHUNK]; 4],
            b: [[0.0; CHUNK]; 4],
            c: [[0.0; CHUNK]; 4],
            d: [[0.0; CHUNK]; 4],
            carried: false,
        }
    }
}

impl TransitionBatch {
    /// Lane `i` from its f(x) and a Jacobian of any form; the batch is
    /// then not `carried`.
    pub fn set_general(&mut self, i: usize, next: &State, f: &Mat4) {
        self.carried = false;
        for k in 0..4 {
            self.next[k][i] = next[k];
            let (row, col) = (k / 2, k % 2);
            self.c[k][i] = f[(row, col)];
            self.a[k][i] = f[(row, col + 2)];
            self.d[k][i] = f[(row + 2, col)];
            self.b[k][i] = f[(row + 2, col + 2)];
        }
    }

    /// Lane `i`'s Jacobian.
    pub fn jacobian(&self, i: usize) -> Mat4 {
        let (a, b) = (&self.a, &self.b);
        let (c, d) = if self.carried {
            ([1.0, 0.0, 0.0, 1.0], [0.0; 4])
        } else {
            let (c, d) = (&self.c, &self.d);
            (
                [c[0][i], c[1][i], c[2][i], c[3][i]],
                [d[0][i], d[1][i], d[2][i], d[3][i]],
            )
        };
        Mat4::new(
            c[0], c[1], a[0][i], a[1][i], //
            c[2], c[3], a[2][i], a[3][i], //
            d[0], d[1], b[0][i], b[1][i], //
            d[2], d[3], b[2][i], b[3][i],
        )
    }
}

/// ‖v‖. Not `hypot`, whose guard against overflow costs a library call
/// per particle and is not needed for speeds.
#[inline]
fn speed(x: &State) -> f64 {
    (x[2] * x[2] + x[3] * x[3]).sqrt()
}

/// The trigonometric entries of F(ω) and their derivatives in ω.
#[derive(Clone, Copy)]
struct TurnTerms {
    sin: f64,
    cos: f64,
    /// sin(ωT)/ω
    s: f64,
    /// (1 − cos ωT)/ω
    c: f64,
    /// d/dω of `s`
    ds: f64,
    /// d/dω of `c`
    dc: f64,
}

impl TurnTerms {
    fn new(omega: f64, period: f64) -> Self {
        let (sin, cos) = libm::sincos(omega * period);
        Self::with(omega, period, sin, cos)
    }

    /// The terms from ω and the sine and cosine of ωT (fdlibm's, so that
    /// a batch's vectorised ones are the same, [`crate::batch::sincos`]).
    /// Branch-free: both forms are computed and one kept, so that a loop
    /// over lanes vectorises.
    #[inline(always)]
    fn with(omega: f64, period: f64, sin: f64, cos: f64) -> Self {
        let wt = omega * period;
        // Below SMALL_TURN, the Taylor series.
        let t2 = period * period;
        let t3 = t2 * period;
        let small = Self {
            sin,
            cos,
            s: period - omega * omega * t3 / 6.0,
            c: omega * t2 / 2.0 - omega * omega * omega * t2 * t2 / 24.0,
            ds: -omega * t3 / 3.0,
            dc: t2 / 2.0 - omega * omega * t2 * t2 / 8.0,
        };
        let w2 = omega * omega;
        // 1 − cos ωT = sin²ωT / (1 + cos ωT): the subtraction loses half
        // the digits at the small turn rates of the default scenario, and
        // this form needs no second sine. Near a half turn, where 1 + cos
        // cancels instead, the subtraction is exact enough.
        let one_minus_cos = if cos > 0.0 {
            sin * sin / (1.0 + cos)
        } else {
            1.0 - cos
        };
        let general = Self {
            sin,
            cos,
            s: sin / omega,
            c: one_minus_cos / omega,
            ds: (period * cos * omega - sin) / w2,
            dc: (period * sin * omega - one_minus_cos) / w2,
        };
        if wt.abs() < SMALL_TURN {
            small
        } else {
            general
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{central_jacobian, random_state};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    fn turning() -> CoordinatedTurn {
        CoordinatedTurn {
            period: 1.0,
            maneuver_accel: 0.1,
            min_speed: 0.1,
            sigma_v: 0.05,
            process_noise: ProcessNoise::Continuous,
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn batch_avx2(model: &CoordinatedTurn, x: &StateLanes, out: &mut TransitionBatch) {
        model.transition_batch(x, out)
    }

    /// The batch is `transition_and_jacobian` state by state, bit for bit,
    /// vectorised or not: turning and constant velocity, fast, slow (the
    /// speed floor), still, and turns from tiny (the Taylor form) to a
    /// quarter turn and beyond (fdlibm's argument reduction).
    #[test]
    fn the_batch_is_transition_and_jacobian_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let sharp = CoordinatedTurn {
            maneuver_accel: 40.0,
            ..turning()
        };
        for model in [
            turning(),
            sharp,
            CoordinatedTurn::constant_velocity(1.0, 0.5),
        ] {
            for n in [CHUNK, 17] {
                let mut states: Vec<State> = (0..n)
                    .map(|_| {
                        let speed = 10f64.powf(rng.random_range(-3.0..2.0));
                        let heading = rng.random_range(-PI..PI);
                        State::new(
                            rng.random_range(-500.0..500.0),
                            rng.random_range(-500.0..500.0),
                            speed * heading.sin(),
                            speed * heading.cos(),
                        )
                    })
                    .collect();
                states[0] = State::new(1.0, 2.0, 0.0, 0.0);
                let lanes = StateLanes::of(&states);
                let mut plain = TransitionBatch::default();
                model.transition_batch(&lanes, &mut plain);
                let mut wide = TransitionBatch::default();
                if crate::batch::has_avx2() {
                    // SAFETY: the CPU has AVX2.
                    unsafe { batch_avx2(&model, &lanes, &mut wide) };
                } else {
                    wide = plain;
                }
                for (i, x) in states.iter().enumerate() {
                    let (next, jac) = model.transition_and_jacobian(x);
                    for b in [&plain, &wide] {
                        let got_jac = Mat4::new(
                            1.0, 0.0, b.a[0][i], b.a[1][i], //
                            0.0, 1.0, b.a[2][i], b.a[3][i], //
                            0.0, 0.0, b.b[0][i], b.b[1][i], //
                            0.0, 0.0, b.b[2][i], b.b[3][i],
                        );
                        let got_next = State::from_fn(|k, _| b.next[k][i]);
                        let same = |p: &[f64], q: &[f64]| {
                            p.iter().zip(q).all(|(a, b)| a.to_bits() == b.to_bits())
                        };
                        assert!(
                            same(got_next.as_slice(), next.as_slice())
                                && same(got_jac.as_slice(), jac.as_slice()),
                            "{model:?} at {x:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn jacobian_matches_central_differences_over_random_states() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for model in [
            turning(),
            CoordinatedTurn {
                maneuver_accel: 2.0,
                ..turning()
            },
        ] {
            for i in 0..2000 {
                // A third of the states are slow targets (but above v_min,
                // where Ω is smooth).
                let speed_scale = if i % 3 == 0 { 0.3 } else { 20.0 };
                let x = random_state(&mut rng, 1500.0, speed_scale);
                if speed(&x) < 1.5 * model.min_speed {
                    continue;
                }
                let numeric = central_jacobian(|y| model.transition(y), &x, 1e-6);
                let analytic = model.jacobian(&x);
                assert_eq!(
                    model.transition_and_jacobian(&x),
                    (model.transition(&x), analytic),
                    "one evaluation gives what the two apart give"
                );
                let err = (numeric - analytic).abs().max();
                assert!(
                    err < 1e-6,
                    "state {x:?}: error {err}\n{analytic}\n{numeric}"
                );
            }
        }
    }

    #[test]
    fn the_two_process_noise_models_have_their_textbook_q_and_exact_factors() {
        let t: f64 = 0.5;
        for (noise, pp, pv, vv) in [
            (ProcessNoise::Continuous, t.powi(3) / 3.0, t * t / 2.0, t),
            (
                ProcessNoise::Discrete,
                t.powi(4) / 4.0,
                t.powi(3) / 2.0,
                t * t,
            ),
        ] {
            let model = CoordinatedTurn {
                process_noise: noise,
                ..CoordinatedTurn::constant_velocity(t, 0.3)
            };
            let q = model.process_noise();
            let s2 = 0.09;
            for axis in 0..2 {
                assert!((q[(axis, axis)] - s2 * pp).abs() < 1e-15, "{noise:?}");
                assert!((q[(axis, axis + 2)] - s2 * pv).abs() < 1e-15, "{noise:?}");
                assert!(
                    (q[(axis + 2, axis + 2)] - s2 * vv).abs() < 1e-15,
                    "{noise:?}"
                );
                assert_eq!(q[(axis, 1 - axis)], 0.0, "the axes are independent");
            }
            let l = model.process_noise_factor();
            assert!((l * l.transpose() - q).norm() < 1e-15, "{noise:?}");
        }
        let discrete = CoordinatedTurn {
            process_noise: ProcessNoise::Discrete,
            ..CoordinatedTurn::constant_velocity(t, 0.3)
        };
        assert!(
            discrete.process_noise().determinant().abs() < 1e-20,
            "rank two"
        );
        let err = Dynamics::new(discrete).unwrap_err();
        assert_eq!(err.parameter, "process_noise");
    }

    #[test]
    fn constant_velocity_is_the_zero_turn_limit() {
        let cv = CoordinatedTurn::constant_velocity(2.0, 1.0);
        let x = State::new(10.0, -5.0, 3.0, 4.0);
        let expected = State::new(16.0, 3.0, 3.0, 4.0);
        assert!((cv.transition(&x) - expected).norm() < 1e-12);
        // A barely turning target agrees with the series branch continuously.
        let slow_turn = CoordinatedTurn {
            maneuver_accel: 1e-7,
            ..cv
        };
        let fast_turn = CoordinatedTurn {
            maneuver_accel: 1.1e-3,
            ..cv
        };
        assert!((slow_turn.transition(&x) - expected).norm() < 1e-6);
        let err = (fast_turn.jacobian(&x)
            - central_jacobian(|y| fast_turn.transition(y), &x, 1e-6))
        .abs()
        .max();
        assert!(
            err < 1e-7,
            "{err}\n{}\n{}",
            fast_turn.jacobian(&x),
            central_jacobian(|y| fast_turn.transition(y), &x, 1e-6)
        );
    }

    #[test]
    fn clockwise_turn_keeps_speed_and_turns_right() {
        let m = turning();
        let x = State::new(0.0, 0.0, 0.0, 10.0); // heading north
        let y = m.transition(&x);
        assert!((speed(&y) - 10.0).abs() < 1e-12);
        assert!(y[2] > 0.0, "a clockwise turn from north heads east: {y:?}");
    }

    #[test]
    fn sampled_noise_has_covariance_q() {
        let d = Dynamics::new(turning()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = 200_000;
        let mut cov = Mat4::zeros();
        for _ in 0..n {
            let e = d.sample_noise(&mut rng);
            cov += e * e.transpose();
        }
        cov /= n as f64;
        let rel = (cov - d.q()).abs().max() / d.q().abs().max();
        assert!(rel < 0.02, "relative error {rel}");
        assert!((d.q() * d.q_inv() - Mat4::identity()).abs().max() < 1e-9);
    }
}
