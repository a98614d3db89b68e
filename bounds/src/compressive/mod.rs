//! Sensor management by compressive sensing over a multiple-access channel
//! (dissertation ch. 4; docs/equations.md, "Compressive sensor
//! management"), as pure functions.
//!
//! Sensor j measures `s_j = a_j(x) + v_j`, `v_j ~ N(0, r)`. In each of M
//! slots of a shared channel, every sensor transmits `φ_ij s_j` at once
//! and the receiver hears the sum plus its own noise:
//!
//! ```text
//! z = Φ s + e,   e ~ N(0, ε I_M),   so   z | x ~ N(Φ a(x), r ΦΦᵀ + ε I_M)   (eq. 4.13)
//! ```
//!
//! `φ_ij` is ±1 with probability `p_j / 2` each and 0 otherwise (eq. 4.7):
//! the transmission probabilities `p` are the design. The fusion centre
//! chooses them to maximize `det J(p)` under the energy budget
//! `M Σ p_j ≤ E` (eqs. 4.25–4.26), with `J(p)` the recursion of eq. 4.8
//! whose observation term takes `E_Φ[Φᵀ R⁻¹ Φ] ≈ M/(rΣp + ε) diag(p)`
//! (eq. 4.19):
//!
//! ```text
//! J(p) = A + M/(r Σp + ε) Σ_j p_j G_j,   G_j = E_x[∇a_j ∇a_jᵀ],
//! A = Q⁻¹ − Q⁻¹F (J_prev + FᵀQ⁻¹F)⁻¹ FᵀQ⁻¹.
//! ```
//!
//! Only the position block depends on p, so `log det J(p)` is, up to a
//! constant, `log det(K + B(p))` over 2 × 2 matrices with
//! `K = ((A⁻¹)_pos)⁻¹`. For a fixed total `s = Σp` it is concave in p;
//! [`optimal_probabilities`] climbs it by projected gradient over the
//! capped simplex and searches s by golden section.

mod counted_once;

pub use counted_once::{
    counted_once_probabilities, diagonal_information, CountedOnce, DrawnMatrices, SAMPLES,
};

use nalgebra::{Cholesky, Matrix2};
use rand::Rng;

use crate::{Mat4, State};

/// The most slots a design may have: a sensor's column travels as a
/// 32-bit mask.
pub const MAX_SLOTS: usize = 32;

/// A sensing matrix Φ, M × N, with entries in {−1, 0, 1}.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SensingMatrix {
    slots: usize,
    sensors: usize,
    /// Row-major: entry (i, j) at `i · sensors + j`.
    entries: Vec<i8>,
}

impl SensingMatrix {
    /// All zeros.
    pub fn zeros(slots: usize, sensors: usize) -> Self {
        assert!(slots <= MAX_SLOTS, "at most {MAX_SLOTS} slots");
        Self {
            slots,
            sensors,
            entries: vec![0; slots * sensors],
        }
    }

    /// Eq. 4.7: each entry of column j is +1 or −1 with probability
    /// `p_j / 2` each, else 0; drawn column by column, slot by slot.
    pub fn draw<R: Rng + ?Sized>(p: &[f64], slots: usize, rng: &mut R) -> Self {
        let mut phi = Self::zeros(slots, p.len());
        for (j, &pj) in p.iter().enumerate() {
            for i in 0..slots {
                let u: f64 = rng.random();
                if u < pj / 2.0 {
                    phi.set(i, j, 1);
                } else if u < pj {
                    phi.set(i, j, -1);
                }
            }
        }
        phi
    }

    /// Every sensor in a slot of its own: the all-send case over parallel
    /// channels.
    pub fn identity(sensors: usize) -> Self {
        let mut phi = Self::zeros(sensors, sensors);
        for j in 0..sensors {
            phi.set(j, j, 1);
        }
        phi
    }

    /// `chosen[i]` alone in slot i: a selection of sensors, each on a
    /// channel of its own.
    pub fn selection(chosen: &[usize], sensors: usize) -> Self {
        let mut phi = Self::zeros(chosen.len(), sensors);
        for (i, &j) in chosen.iter().enumerate() {
            phi.set(i, j, 1);
        }
        phi
    }

    /// A matrix from its columns as (slots with a non-zero entry, slots
    /// whose entry is −1) bit masks, as activations carry them.
    pub fn from_columns(slots: usize, columns: &[(u32, u32)]) -> Self {
        let mut phi = Self::zeros(slots, columns.len());
        for (j, &(nonzero, negative)) in columns.iter().enumerate() {
            for i in 0..slots {
                if nonzero & (1 << i) != 0 {
                    phi.set(i, j, if negative & (1 << i) != 0 { -1 } else { 1 });
                }
            }
        }
        phi
    }

    pub fn slots(&self) -> usize {
        self.slots
    }

    pub fn sensors(&self) -> usize {
        self.sensors
    }

    pub fn get(&self, i: usize, j: usize) -> i8 {
        self.entries[i * self.sensors + j]
    }

    fn set(&mut self, i: usize, j: usize, v: i8) {
        self.entries[i * self.sensors + j] = v;
    }

    /// Column j as (slots with a non-zero entry, slots whose entry is −1).
    pub fn column(&self, j: usize) -> (u32, u32) {
        let (mut nonzero, mut negative) = (0u32, 0u32);
        for i in 0..self.slots {
            match self.get(i, j) {
                0 => {}
                v => {
                    nonzero |= 1 << i;
                    if v < 0 {
                        negative |= 1 << i;
                    }
                }
            }
        }
        (nonzero, negative)
    }

    /// The non-zero entries: the transmissions, one unit of energy each.
    pub fn transmissions(&self) -> usize {
        self.entries.iter().filter(|v| **v != 0).count()
    }

    /// The sensors with a non-zero column, in increasing order.
    pub fn transmitters(&self) -> Vec<usize> {
        (0..self.sensors)
            .filter(|&j| self.column(j).0 != 0)
            .collect()
    }
}

/// The likelihood of a received z given the sensors' noiseless signals
/// (eq. 4.13): `N(Φa, rΦΦᵀ + εI)`. Built once per step, evaluated per
/// particle without allocating.
#[derive(Debug, Clone)]
pub struct MacLikelihood {
    phi: SensingMatrix,
    /// The transmitters (sensors with a non-zero column).
    transmitters: Vec<usize>,
    /// The lower Cholesky factor of `rΦΦᵀ + εI`, row-major M × M.
    chol: Vec<f64>,
    /// `−½ log det(2π R)`: the density's normalizer.
    normalizer: f64,
}

impl MacLikelihood {
    /// `None` if `rΦΦᵀ + εI` is not positive definite (ε ≤ 0 with an
    /// empty slot).
    pub fn new(phi: SensingMatrix, r: f64, epsilon: f64) -> Option<Self> {
        let m = phi.slots();
        let mut cov = nalgebra::DMatrix::<f64>::zeros(m, m);
        for a in 0..m {
            for b in 0..m {
                let dot: i32 = (0..phi.sensors())
                    .map(|j| i32::from(phi.get(a, j)) * i32::from(phi.get(b, j)))
                    .sum();
                cov[(a, b)] = r * f64::from(dot) + if a == b { epsilon } else { 0.0 };
            }
        }
        let l = Cholesky::new(cov)?.l();
        let log_det: f64 = (0..m).map(|i| 2.0 * l[(i, i)].ln()).sum();
        let normalizer = -0.5 * (log_det + m as f64 * (2.0 * std::f64::consts::PI).ln());
        let chol = (0..m)
            .flat_map(|i| (0..m).map(move |k| (i, k)))
            .map(|(i, k)| l[(i, k)])
            .collect();
        Some(Self {
            transmitters: phi.transmitters(),
            phi,
            chol,
            normalizer,
        })
    }

    pub fn sensing_matrix(&self) -> &SensingMatrix {
        &self.phi
    }

    /// The sensors whose signals enter the likelihood.
    pub fn transmitters(&self) -> &[usize] {
        &self.transmitters
    }

    /// `ln N(z; Φa, R)`, with `signal(j)` the noiseless signal `a_j(x)` of
    /// sensor j (asked only for the transmitters).
    #[inline]
    pub fn ln_likelihood(&self, z: &[f64], mut signal: impl FnMut(usize) -> f64) -> f64 {
        let m = self.phi.slots();
        let mut residual = [0.0; MAX_SLOTS];
        residual[..m].copy_from_slice(&z[..m]);
        for &j in &self.transmitters {
            let a = signal(j);
            for (i, r) in residual.iter_mut().enumerate().take(m) {
                *r -= f64::from(self.phi.get(i, j)) * a;
            }
        }
        // Solve L w = residual; the quadratic form is |w|².
        let mut quadratic = 0.0;
        for i in 0..m {
            let row = &self.chol[i * m..i * m + i];
            let w = (residual[i]
                - row
                    .iter()
                    .zip(&residual[..i])
                    .map(|(l, w)| l * w)
                    .sum::<f64>())
                / self.chol[i * m + i];
            residual[i] = w;
            quadratic += w * w;
        }
        self.normalizer - 0.5 * quadratic
    }

    /// The observation information this Φ gives, over weighted states: the
    /// position block of `E_x[∇(Φa)ᵀ R⁻¹ ∇(Φa)]` (eq. 4.14 for the drawn
    /// Φ rather than averaged over Φ), with `gradient(j, x)` sensor j's
    /// `∇a_j` at x. Unlike eq. 4.19 it counts a sensor heard in several
    /// slots once: its noise `v_j` is the same in each.
    pub fn information(
        &self,
        states: &[State],
        weights: &[f64],
        mut gradient: impl FnMut(usize, &State) -> State,
    ) -> PositionBlock {
        let m = self.phi.slots();
        let mut block = [0.0; 3];
        for (x, w) in states.iter().zip(weights) {
            // h = ∇(Φa): a row per slot, its x and y columns.
            let (mut hx, mut hy) = ([0.0; MAX_SLOTS], [0.0; MAX_SLOTS]);
            for &j in &self.transmitters {
                let g = gradient(j, x);
                for i in 0..m {
                    let phi = f64::from(self.phi.get(i, j));
                    hx[i] += phi * g[0];
                    hy[i] += phi * g[1];
                }
            }
            // hᵀR⁻¹h = |L⁻¹h|², column by column.
            for i in 0..m {
                let row = &self.chol[i * m..i * m + i];
                let d = self.chol[i * m + i];
                hx[i] = (hx[i] - row.iter().zip(&hx[..i]).map(|(l, v)| l * v).sum::<f64>()) / d;
                hy[i] = (hy[i] - row.iter().zip(&hy[..i]).map(|(l, v)| l * v).sum::<f64>()) / d;
                block[0] += w * hx[i] * hx[i];
                block[1] += w * hx[i] * hy[i];
                block[2] += w * hy[i] * hy[i];
            }
        }
        block
    }
}

/// A position block `[xx, xy, yy]`.
pub type PositionBlock = [f64; 3];

/// `G_j = E_x[∇a_j ∇a_jᵀ]` over weighted states, position block; `gradient`
/// gives `∇a_j` at a state (its velocity entries are zero).
pub fn expected_outer_product(
    states: &[State],
    weights: &[f64],
    mut gradient: impl FnMut(&State) -> State,
) -> PositionBlock {
    let mut g = [0.0; 3];
    for (x, w) in states.iter().zip(weights) {
        let d = gradient(x);
        g[0] += w * d[0] * d[0];
        g[1] += w * d[0] * d[1];
        g[2] += w * d[1] * d[1];
    }
    g
}

/// The information before this step's observations, eq. 4.8 without
/// `D22,b`: `Q⁻¹ − Q⁻¹F (J_prev + FᵀQ⁻¹F)⁻¹ FᵀQ⁻¹` for a linear
/// transition F. `None` if `J_prev + FᵀQ⁻¹F` is singular.
pub fn predicted_information(previous: &Mat4, f: &Mat4, q_inv: &Mat4) -> Option<Mat4> {
    let d11 = f.transpose() * q_inv * f;
    let d12 = -(f.transpose() * q_inv);
    let inner = symmetric(previous + d11);
    let inv = Cholesky::new(inner)?.inverse();
    Some(symmetric(q_inv - d12.transpose() * inv * d12))
}

/// `J = A + (the position block of) Σ_j w_j G_j`.
pub fn with_observations(predicted: &Mat4, blocks: &[PositionBlock], weights: &[f64]) -> Mat4 {
    let mut j = *predicted;
    for (g, w) in blocks.iter().zip(weights) {
        j[(0, 0)] += w * g[0];
        j[(0, 1)] += w * g[1];
        j[(1, 0)] += w * g[1];
        j[(1, 1)] += w * g[2];
    }
    j
}

/// Eq. 4.19's weights: `M p_j / (r Σp + ε)`, the diagonal of
/// `E_Φ[Φᵀ R⁻¹ Φ]`.
pub fn gamma_weights(p: &[f64], slots: usize, r: f64, epsilon: f64) -> Vec<f64> {
    let scale = slots as f64 / (r * p.iter().sum::<f64>() + epsilon);
    p.iter().map(|pj| scale * pj).collect()
}

/// The design problem at one step: maximize `log det J(p)` subject to
/// `M Σp ≤ E`, `0 ≤ p_j ≤ 1`.
#[derive(Debug, Clone)]
pub struct DesignProblem<'a> {
    /// `J` before the step's observations (eq. 4.8 without `D22,b`).
    pub predicted: Mat4,
    /// Each sensor's `G_j`.
    pub blocks: &'a [PositionBlock],
    pub slots: usize,
    pub energy: f64,
    pub r: f64,
    pub epsilon: f64,
}

impl DesignProblem<'_> {
    /// `log det J(p)` up to a constant that does not depend on p: `log
    /// det(K + B(p))`, `K = ((A⁻¹)_pos)⁻¹`. `None` if A is not positive
    /// definite.
    pub fn objective(&self, p: &[f64]) -> Option<f64> {
        let k = self.schur()?;
        Some(log_det2(&(k + self.gain(p))))
    }

    /// `log det J(p)` itself, for checks.
    pub fn log_det(&self, p: &[f64]) -> Option<f64> {
        let j = with_observations(
            &self.predicted,
            self.blocks,
            &gamma_weights(p, self.slots, self.r, self.epsilon),
        );
        Cholesky::new(symmetric(j)).map(|c| c.determinant().ln())
    }

    fn schur(&self) -> Option<Matrix2<f64>> {
        let cov = Cholesky::new(symmetric(self.predicted))?.inverse();
        Matrix2::new(cov[(0, 0)], cov[(0, 1)], cov[(1, 0)], cov[(1, 1)]).try_inverse()
    }

    /// `B(p) = M/(rΣp + ε) Σ p_j G_j`.
    fn gain(&self, p: &[f64]) -> Matrix2<f64> {
        let scale = self.slots as f64 / (self.r * p.iter().sum::<f64>() + self.epsilon);
        weighted_sum(Matrix2::zeros(), self.blocks, p, scale)
    }

    /// The largest total `Σp` the budget and the caps allow.
    pub fn largest_total(&self) -> f64 {
        (self.energy / self.slots as f64).min(self.blocks.len() as f64)
    }
}

/// The golden-section search on the total stops when its bracket is this
/// share of the budget: the design's slot probabilities move by about as
/// much, far inside the noise of anything measured with them.
const GOLDEN_TOLERANCE: f64 = 1e-6;

/// The transmission probabilities that maximize `det J(p)` (eqs.
/// 4.25–4.26). For each total `s = Σp` the objective is concave in p:
/// projected gradient ascent over `{0 ≤ p ≤ 1, Σp = s}` finds its maximum;
/// the total is searched by golden section over `(0, E/M]`, and the
/// budget's end is always tried. `None` if the predicted information is
/// not positive definite.
pub fn optimal_probabilities(problem: &DesignProblem) -> Option<Vec<f64>> {
    let k = problem.schur()?;
    let n = problem.blocks.len();
    if n == 0 {
        return Some(Vec::new());
    }
    let top = problem.largest_total();
    let solve = |s: f64| {
        let p = best_for_total(problem, &k, s);
        let value = log_det2(&(k + problem.gain(&p)));
        (value, p)
    };
    let mut best = solve(top);
    // Golden section on the total: with a single slot the sum of many
    // weak sensors can lose to a few strong ones, so the budget's end is
    // not always best.
    let ratio = (5f64.sqrt() - 1.0) / 2.0;
    let (mut lo, mut hi) = (top * 1e-3, top);
    let mut a = hi - ratio * (hi - lo);
    let mut b = lo + ratio * (hi - lo);
    let (mut fa, mut fb) = (solve(a), solve(b));
    // To a millionth of the budget: the bracket shrinks by the ratio a
    // step, 29 steps from the whole budget.
    while hi - lo > GOLDEN_TOLERANCE * top {
        if fa.0 > fb.0 {
            hi = b;
            b = a;
            fb = fa;
            a = hi - ratio * (hi - lo);
            fa = solve(a);
        } else {
            lo = a;
            a = b;
            fa = fb;
            b = lo + ratio * (hi - lo);
            fb = solve(b);
        }
    }
    for candidate in [fa, fb] {
        if candidate.0 > best.0 {
            best = candidate;
        }
    }
    Some(best.1)
}

/// `base + Σ_j scale·p_j G_j`.
fn weighted_sum(
    mut base: Matrix2<f64>,
    blocks: &[PositionBlock],
    p: &[f64],
    scale: f64,
) -> Matrix2<f64> {
    for (g, pj) in blocks.iter().zip(p) {
        base += Matrix2::new(g[0], g[1], g[1], g[2]) * (scale * pj);
    }
    base
}

/// Projected gradient ascent of `log det(K + B(p))` over `{0 ≤ p ≤ 1,
/// Σp = s}`, with a backtracking step. Its buffers are made once: the
/// search takes thousands of steps a design.
fn best_for_total(problem: &DesignProblem, k: &Matrix2<f64>, s: f64) -> Vec<f64> {
    let n = problem.blocks.len();
    let start = project_capped_simplex(&vec![s / n as f64; n], s);
    let mut fixed = FixedTotal {
        problem,
        k: *k,
        total: s,
        // On this total the weights' scale M/(rs + ε) is fixed.
        scale: problem.slots as f64 / (problem.r * s + problem.epsilon),
    };
    climb(
        &mut fixed,
        start,
        Steps {
            first: 1.0,
            largest: f64::INFINITY,
            smallest: 1e-14,
            moved: 1e-12,
            iterations: 2000,
        },
    )
}

/// Eq. 4.19's objective on one total, for [`climb`].
struct FixedTotal<'a> {
    problem: &'a DesignProblem<'a>,
    k: Matrix2<f64>,
    total: f64,
    scale: f64,
}

impl Climb for FixedTotal<'_> {
    fn value(&mut self, p: &[f64]) -> f64 {
        log_det2(&weighted_sum(self.k, self.problem.blocks, p, self.scale))
    }

    fn gradient(&mut self, p: &[f64], out: &mut [f64]) -> bool {
        let Some(inv) = weighted_sum(self.k, self.problem.blocks, p, self.scale).try_inverse()
        else {
            return false;
        };
        for (d, g) in out.iter_mut().zip(self.problem.blocks) {
            // ∂/∂p_j log det(K + B) = scale · tr((K + B)⁻¹ G_j)
            *d = self.scale * (inv[(0, 0)] * g[0] + 2.0 * inv[(0, 1)] * g[1] + inv[(1, 1)] * g[2]);
        }
        true
    }

    fn project(&self, y: &[f64], out: &mut [f64]) {
        project_into(y, self.total, out);
    }
}

/// An objective the designs climb: its value at a trial point, its
/// gradient at the accepted one, and the projection onto its feasible set.
pub(crate) trait Climb {
    /// The objective at `p`, a trial until [`accept`](Self::accept).
    fn value(&mut self, p: &[f64]) -> f64;
    /// The trial last valued is the new point.
    fn accept(&mut self) {}
    /// The gradient at the accepted point `p` into `out`; false if there
    /// is none.
    fn gradient(&mut self, p: &[f64], out: &mut [f64]) -> bool;
    fn project(&self, y: &[f64], out: &mut [f64]);
}

/// How [`climb`] steps.
pub(crate) struct Steps {
    pub first: f64,
    /// The most a step may grow to.
    pub largest: f64,
    /// Backtracking below this ends the climb.
    pub smallest: f64,
    /// A move smaller than this (largest coordinate) ends the climb.
    pub moved: f64,
    pub iterations: usize,
}

/// Projected gradient ascent from `start`, which must be feasible: a
/// scale-free step along the gradient (the gradient's size varies by
/// orders of magnitude with the target's distance from the sensors),
/// halved until the projected point is better, doubled after it is.
pub(crate) fn climb(objective: &mut impl Climb, start: Vec<f64>, steps: Steps) -> Vec<f64> {
    let n = start.len();
    let mut p = start;
    let mut current = objective.value(&p);
    objective.accept();
    let mut step = steps.first;
    let mut gradient = vec![0.0; n];
    let (mut ascent, mut trial) = (vec![0.0; n], vec![0.0; n]);
    for _ in 0..steps.iterations {
        if !objective.gradient(&p, &mut gradient) {
            break;
        }
        let norm = gradient.iter().fold(0.0f64, |m, d| m.max(d.abs()));
        if norm == 0.0 || !norm.is_finite() {
            break;
        }
        let mut moved = false;
        while step > steps.smallest {
            for ((a, pj), d) in ascent.iter_mut().zip(&p).zip(&gradient) {
                *a = pj + step * d / norm;
            }
            objective.project(&ascent, &mut trial);
            let v = objective.value(&trial);
            if v > current {
                let change = trial
                    .iter()
                    .zip(&p)
                    .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                std::mem::swap(&mut p, &mut trial);
                objective.accept();
                current = v;
                moved = change > steps.moved;
                step = (step * 2.0).min(steps.largest);
                break;
            }
            step /= 2.0;
        }
        if !moved {
            break;
        }
    }
    p
}

/// The Euclidean projection of y onto `{0 ≤ p ≤ 1, Σp = s}`: `p_j =
/// clamp(y_j − τ, 0, 1)` with τ found by bisection.
pub fn project_capped_simplex(y: &[f64], s: f64) -> Vec<f64> {
    let mut out = vec![0.0; y.len()];
    project_into(y, s, &mut out);
    out
}

/// [`project_capped_simplex`] into `out`.
fn project_into(y: &[f64], s: f64, out: &mut [f64]) {
    let total = |tau: f64| y.iter().map(|v| (v - tau).clamp(0.0, 1.0)).sum::<f64>();
    let (mut lo, mut hi) = (
        y.iter().fold(f64::INFINITY, |m, v| m.min(*v)) - 1.0,
        y.iter().fold(f64::NEG_INFINITY, |m, v| m.max(*v)),
    );
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        // Once the midpoint is an end, this step's update is the last
        // that changes anything (later steps repeat it): stop there, with
        // the ends 200 steps would have left, after some 60.
        let settled = mid == lo || mid == hi;
        if total(mid) > s {
            lo = mid;
        } else {
            hi = mid;
        }
        if settled {
            break;
        }
    }
    let tau = 0.5 * (lo + hi);
    for (o, v) in out.iter_mut().zip(y) {
        *o = (v - tau).clamp(0.0, 1.0);
    }
}

fn log_det2(m: &Matrix2<f64>) -> f64 {
    let det = m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)];
    if det > 0.0 {
        det.ln()
    } else {
        f64::NEG_INFINITY
    }
}

fn symmetric(m: Mat4) -> Mat4 {
    (m + m.transpose()) * 0.5
}

/// K distinct sensors of N uniformly at random, in the order drawn (a
/// partial Fisher–Yates shuffle).
pub fn random_selection<R: Rng + ?Sized>(count: usize, sensors: usize, rng: &mut R) -> Vec<usize> {
    let mut all: Vec<usize> = (0..sensors).collect();
    let count = count.min(sensors);
    for i in 0..count {
        let j = rng.random_range(i..sensors);
        all.swap(i, j);
    }
    all.truncate(count);
    all
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The bisection that stops once its midpoint is an end leaves the
    /// projection all 200 steps would, bit for bit.
    #[test]
    fn the_projection_stops_where_two_hundred_steps_would_end() {
        let all_steps = |y: &[f64], s: f64| -> Vec<f64> {
            let total = |tau: f64| y.iter().map(|v| (v - tau).clamp(0.0, 1.0)).sum::<f64>();
            let (mut lo, mut hi) = (
                y.iter().fold(f64::INFINITY, |m, v| m.min(*v)) - 1.0,
                y.iter().fold(f64::NEG_INFINITY, |m, v| m.max(*v)),
            );
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if total(mid) > s {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            let tau = 0.5 * (lo + hi);
            y.iter().map(|v| (v - tau).clamp(0.0, 1.0)).collect()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        for n in [1, 2, 5, 25, 100] {
            for _ in 0..200 {
                let scale = 10f64.powi(rng.random_range(-3..4));
                let y: Vec<f64> = (0..n)
                    .map(|_| scale * rng.random_range(-1.0..2.0))
                    .collect();
                let s = rng.random_range(0.0..n as f64);
                let got = project_capped_simplex(&y, s);
                let want = all_steps(&y, s);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got), bits(&want), "n = {n}, s = {s}, y = {y:?}");
            }
        }
    }

    /// Eq. 4.13 against the density written out with a dense inverse and
    /// determinant.
    #[test]
    fn the_likelihood_is_the_gaussian_of_eq_4_13() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for slots in [1, 3, 6] {
            let phi = SensingMatrix::draw(&[0.9, 0.1, 0.5, 0.0, 0.7], slots, &mut rng);
            let (r, eps) = (1.3, 0.2);
            let like = MacLikelihood::new(phi.clone(), r, eps).unwrap();
            let a = [3.0, -1.0, 0.5, 8.0, 2.0];
            let z: Vec<f64> = (0..slots).map(|i| 0.7 * i as f64 - 1.0).collect();
            let m = slots;
            let phi_d = nalgebra::DMatrix::from_fn(m, 5, |i, j| f64::from(phi.get(i, j)));
            let cov = &phi_d * phi_d.transpose() * r + nalgebra::DMatrix::identity(m, m) * eps;
            let mean = &phi_d * nalgebra::DVector::from_row_slice(&a);
            let resid = nalgebra::DVector::from_row_slice(&z) - mean;
            let inv = cov.clone().try_inverse().unwrap();
            let direct = -0.5 * (resid.transpose() * inv * &resid)[(0, 0)]
                - 0.5 * (cov.determinant() * (2.0 * std::f64::consts::PI).powi(m as i32)).ln();
            let got = like.ln_likelihood(&z, |j| a[j]);
            assert!(
                (got - direct).abs() < 1e-10,
                "{slots} slots: {got} vs {direct}"
            );
        }
    }

    /// The information of a drawn Φ against `∇(Φa)ᵀ R⁻¹ ∇(Φa)` written
    /// out densely; with every sensor on a channel of its own it is
    /// `Σ G_j / (r + ε)`.
    #[test]
    fn the_information_of_a_drawn_matrix_is_eq_4_14() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let grads = [
            State::new(1.0, 0.5, 0.0, 0.0),
            State::new(-0.3, 2.0, 0.0, 0.0),
            State::new(0.7, -0.7, 0.0, 0.0),
        ];
        let (r, eps) = (1.0, 0.1);
        let x = [State::zeros()];
        for slots in [1, 2, 4] {
            let phi = SensingMatrix::draw(&[0.8, 0.6, 0.9], slots, &mut rng);
            let like = MacLikelihood::new(phi.clone(), r, eps).unwrap();
            let got = like.information(&x, &[1.0], |j, _| grads[j]);
            let phi_d = nalgebra::DMatrix::from_fn(slots, 3, |i, j| f64::from(phi.get(i, j)));
            let h = nalgebra::DMatrix::from_fn(3, 2, |j, c| grads[j][c]);
            let cov =
                &phi_d * phi_d.transpose() * r + nalgebra::DMatrix::identity(slots, slots) * eps;
            let dense = (&phi_d * &h).transpose() * cov.try_inverse().unwrap() * (&phi_d * &h);
            for (g, d) in got
                .iter()
                .zip([dense[(0, 0)], dense[(0, 1)], dense[(1, 1)]])
            {
                assert!(
                    (g - d).abs() < 1e-10,
                    "{slots} slots: {got:?} against {dense}"
                );
            }
        }
        let parallel = MacLikelihood::new(SensingMatrix::identity(3), r, eps).unwrap();
        let got = parallel.information(&x, &[1.0], |j, _| grads[j]);
        let sum: f64 = grads.iter().map(|g| g[0] * g[0]).sum::<f64>() / (r + eps);
        assert!((got[0] - sum).abs() < 1e-12);
    }

    /// Where eq. 4.19 goes wrong: one sensor sure to transmit in all M
    /// slots gives M copies of the same measurement, worth `G/(r + ε/M)`,
    /// not the `M G/(r + ε)` the approximation (a law of large numbers
    /// over many transmitting sensors) promises.
    #[test]
    fn eq_4_19_counts_one_sensor_in_m_slots_m_times() {
        let g = State::new(1.0, 0.0, 0.0, 0.0);
        let (r, eps, m) = (1.0, 0.1, 6);
        let phi = SensingMatrix::draw(&[1.0], m, &mut ChaCha8Rng::seed_from_u64(1));
        let exact = MacLikelihood::new(phi, r, eps).unwrap().information(
            &[State::zeros()],
            &[1.0],
            |_, _| g,
        )[0];
        assert!(
            (exact - 1.0 / (r + eps / m as f64)).abs() < 1e-12,
            "{exact}"
        );
        let promised = gamma_weights(&[1.0], m, r, eps)[0];
        assert!((promised - m as f64 / (r + eps)).abs() < 1e-12);
        assert!(promised > 5.0 * exact);
    }

    #[test]
    fn the_drawn_matrix_has_eq_4_7s_frequencies() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let p = [0.0, 0.3, 1.0];
        let (mut plus, mut minus, mut total) = ([0usize; 3], [0usize; 3], 0usize);
        for _ in 0..4000 {
            let phi = SensingMatrix::draw(&p, 5, &mut rng);
            for j in 0..3 {
                for i in 0..5 {
                    match phi.get(i, j) {
                        1 => plus[j] += 1,
                        -1 => minus[j] += 1,
                        _ => {}
                    }
                }
            }
            total += 5;
        }
        for j in 0..3 {
            let n = total as f64;
            let half = p[j] / 2.0;
            let sd = (half * (1.0 - half) / n).sqrt();
            for count in [plus[j], minus[j]] {
                assert!(
                    (count as f64 / n - half).abs() <= 5.0 * sd + 1e-12,
                    "sensor {j}: {count} of {n}"
                );
            }
        }
    }

    #[test]
    fn columns_round_trip_through_their_masks() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let phi = SensingMatrix::draw(&[0.5; 7], 6, &mut rng);
        let columns: Vec<(u32, u32)> = (0..7).map(|j| phi.column(j)).collect();
        assert_eq!(SensingMatrix::from_columns(6, &columns), phi);
        let ones: u32 = columns.iter().map(|c| c.0.count_ones()).sum();
        assert_eq!(ones as usize, phi.transmissions());
    }

    pub(super) fn small_problem(
        blocks: &[PositionBlock],
        slots: usize,
        energy: f64,
    ) -> DesignProblem<'_> {
        let predicted = Mat4::from_diagonal(&State::new(0.3, 0.2, 1.0, 1.0));
        DesignProblem {
            predicted,
            blocks,
            slots,
            energy,
            r: 1.0,
            epsilon: 0.1,
        }
    }

    /// On three sensors, against every p on a grid of 0.01 under the
    /// budget: the optimizer is never worse than the grid's best, and its
    /// objective is `log det J` up to one constant.
    #[test]
    fn the_optimizer_beats_a_brute_force_grid() {
        let blocks = [[4.0, 0.0, 0.1], [0.1, 0.0, 3.0], [2.0, 1.9, 2.0]];
        for (slots, energy) in [(1, 6.0), (3, 6.0), (6, 6.0), (2, 1.0)] {
            let problem = small_problem(&blocks, slots, energy);
            let p = optimal_probabilities(&problem).unwrap();
            let budget = energy / slots as f64;
            assert!(p.iter().all(|v| (-1e-12..=1.0 + 1e-12).contains(v)));
            assert!(p.iter().sum::<f64>() <= budget + 1e-9, "{p:?}");
            let got = problem.objective(&p).unwrap();
            let mut best = f64::NEG_INFINITY;
            for a in 0..=100 {
                for b in 0..=100 {
                    for c in 0..=100 {
                        let q = [a as f64 / 100.0, b as f64 / 100.0, c as f64 / 100.0];
                        if q.iter().sum::<f64>() > budget + 1e-12 || q.iter().sum::<f64>() == 0.0 {
                            continue;
                        }
                        best = best.max(problem.objective(&q).unwrap());
                    }
                }
            }
            assert!(
                got >= best - 1e-9,
                "M = {slots}: {got} < grid {best} at {p:?}"
            );
            assert!(
                got - best < 1e-2,
                "M = {slots}: {got} far above grid {best}"
            );
            let offset = problem.log_det(&p).unwrap() - got;
            let other = problem.log_det(&[0.2, 0.1, 0.05]).unwrap()
                - problem.objective(&[0.2, 0.1, 0.05]).unwrap();
            assert!(
                (offset - other).abs() < 1e-9,
                "objective is log det J up to a constant"
            );
        }
    }

    /// Two sensors seeing the target from perpendicular directions share
    /// the probability; a third that adds nothing gets none.
    #[test]
    fn the_design_spreads_over_complementary_sensors() {
        let blocks = [[5.0, 0.0, 0.0], [0.0, 0.0, 5.0], [0.0, 0.0, 0.0]];
        let problem = small_problem(&blocks, 6, 6.0);
        let p = optimal_probabilities(&problem).unwrap();
        assert!(p[2] < 1e-6, "{p:?}");
        assert!(p[0] > 0.2 && p[1] > 0.2, "{p:?}");
        assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-6, "{p:?}");
    }

    #[test]
    fn the_projection_meets_the_total_and_the_caps() {
        let p = project_capped_simplex(&[3.0, 0.2, -1.0, 0.5], 1.5);
        assert!((p.iter().sum::<f64>() - 1.5).abs() < 1e-9);
        assert!(p.iter().all(|v| (0.0..=1.0).contains(v)));
        assert!((p[0] - 1.0).abs() < 1e-9 && p[2] == 0.0);
    }

    /// The linear-Gaussian limit: with every sensor always sending on a
    /// channel of its own (Γ = I/(r + ε)), one step of eq. 4.8 is the
    /// Kalman filter's information update `P⁻¹ + Hᵀ(r + ε)⁻¹H` after its
    /// prediction `(F P Fᵀ + Q)⁻¹`.
    #[test]
    fn one_step_is_the_kalman_information_update() {
        let f = Mat4::new(
            1.0, 0.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        );
        let q = Mat4::from_diagonal(&State::new(0.1, 0.1, 0.2, 0.2));
        let p0 = Mat4::from_diagonal(&State::new(4.0, 4.0, 1.0, 1.0));
        let prior =
            predicted_information(&p0.try_inverse().unwrap(), &f, &q.try_inverse().unwrap())
                .unwrap();
        let kalman_prior = (f * p0 * f.transpose() + q).try_inverse().unwrap();
        assert!((prior - kalman_prior).abs().max() < 1e-9);
        let h = [
            State::new(1.0, 0.5, 0.0, 0.0),
            State::new(-0.3, 2.0, 0.0, 0.0),
        ];
        let blocks: Vec<PositionBlock> = h
            .iter()
            .map(|g| expected_outer_product(&[State::zeros()], &[1.0], |_| *g))
            .collect();
        let (r, eps) = (1.0, 0.25);
        let j = with_observations(&prior, &blocks, &gamma_weights(&[1.0, 1.0], 2, r, eps));
        let mut kalman = kalman_prior;
        for g in &h {
            kalman += g * g.transpose() / (r + eps);
        }
        // Γ with both sensors always sending: 2/(2r + ε) each, not 1/(r + ε):
        // eq. 4.19 is the average over slots shared by both.
        let shared = with_observations(&prior, &blocks, &[2.0 / (2.0 * r + eps); 2]);
        assert!((j - shared).abs().max() < 1e-12);
        let parallel = with_observations(&prior, &blocks, &[1.0 / (r + eps); 2]);
        assert!((parallel - kalman).abs().max() < 1e-9);
    }
}
