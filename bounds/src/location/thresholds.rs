//! Thresholds that serve a location bound: the uniform quantizer of §6.7.1
//! and a coordinate search for the thresholds that maximize an objective.
//!
//! The search moves one threshold at a time, and one threshold bounds only
//! the two cells either side of it. When the objective is the Fisher
//! information of many sensors (a deployment's J, or the closed form's
//! integral, a sum over its quadrature nodes), each sensor's information
//! is the sum over its cells: all but those two stay put while the
//! threshold moves. [`optimize_weighed_thresholds`] holds them, so a trial
//! position costs each sensor one edge (one `erfc` and one `exp`) instead
//! of every edge within its window, and a sensor whose window the two
//! cells do not reach costs nothing.

use std::ops::RangeInclusive;

use nalgebra::Matrix2;

use super::DecayLaw;
use crate::cell_sums::{accumulate_between, window_sums, Edge, WINDOW_SIGMAS};
use crate::quantizer::Quantizer;

/// The uniform quantizer of section 6.7.1: `2^bits` cells dividing
/// `[−4σ, √P₀ + 4σ]` equally, the outer two open.
pub fn uniform_quantizer(bits: u8, law: DecayLaw, sigma: f64) -> Quantizer {
    Quantizer::uniform(bits, -4.0 * sigma, law.p0().sqrt() + 4.0 * sigma)
        .expect("a valid range and bits 1 to the quantizer's maximum")
}

/// The most sweeps [`optimize_thresholds`] makes.
pub const MAX_SWEEPS: usize = 12;

/// Thresholds that maximize `objective` (larger is better), in `(lo, hi)`:
/// coordinate ascent from the uniform quantizer's thresholds, each
/// threshold searched between its neighbours on a grid (512 points over
/// all thresholds, at least 64 each, on the first sweep; 32 after) and
/// refined by golden section, sweeping until a sweep gains less than 10⁻⁹
/// relative (at most [`MAX_SWEEPS`]). The chapter finds its optimal thresholds
/// with a local optimizer from several starts; this is deterministic, and
/// its 1-bit result is checked against a brute-force search.
pub fn optimize_thresholds(
    bits: u8,
    lo: f64,
    hi: f64,
    objective: impl FnMut(&Quantizer) -> f64,
) -> Quantizer {
    let start = Quantizer::uniform(bits, lo, hi).expect("valid bits and range");
    optimize_thresholds_from(&start, lo, hi, objective)
}

/// [`optimize_thresholds`] from `start`'s thresholds rather than the
/// uniform ones: a design already near the optimum (the closed form's, for
/// one deployment's) spares the sweeps that would walk there, which at
/// 64 cells cost most of the search. `start`'s thresholds must lie in
/// `(lo, hi)`.
pub fn optimize_thresholds_from(
    start: &Quantizer,
    lo: f64,
    hi: f64,
    objective: impl FnMut(&Quantizer) -> f64,
) -> Quantizer {
    coordinate_ascent(start, lo, hi, &mut WholeQuantizer(objective))
}

/// [`optimize_thresholds_from`] for an objective of the information that
/// `points` carry, `objective(Σ_j w_j I(a_j))`: the same search, with each
/// trial position costing each point the one edge that moved (see the
/// module's doc). Its values differ from the whole sum's in the last bits
/// only (the sum's order differs, and cells wholly outside a point's
/// window stay out of it as the threshold moves).
pub fn optimize_weighed_thresholds(
    start: &Quantizer,
    lo: f64,
    hi: f64,
    points: &WeighedAmplitudes,
    sigma: f64,
    objective: impl Fn(&Matrix2<f64>) -> f64,
) -> Quantizer {
    let mut held = HeldCells {
        points,
        sigma,
        objective,
        constant: [0.0; 3],
        moving: Vec::with_capacity(points.len()),
        at: Vec::new(),
    };
    coordinate_ascent(start, lo, hi, &mut held)
}

/// Amplitudes at which one report's information `I(a)` is weighed, each
/// with a symmetric 2 × 2 weight `(w₁₁, w₁₂, w₂₂)`: `J = Σ_j w_j I(a_j)`.
#[derive(Debug, Clone, Default)]
pub struct WeighedAmplitudes {
    amplitudes: Vec<f64>,
    weights: Vec<[f64; 3]>,
}

impl WeighedAmplitudes {
    /// A deployment's sensors about a target (Theorem 6.2):
    /// `w_i = (g'(d_i)/d_i)² G_i` at `a_i = g(d_i)`, as
    /// [`super::exact_information`] sums them.
    pub fn of_deployment(law: DecayLaw, sensors: &[[f64; 2]], target: [f64; 2]) -> Self {
        let mut points = Self::default();
        for s in sensors {
            let (dx, dy) = (s[0] - target[0], s[1] - target[1]);
            let d = dx.hypot(dy);
            let slope = law.slope_over_distance_squared(d);
            points.push(
                law.amplitude(d),
                [slope * dx * dx, slope * dx * dy, slope * dy * dy],
            );
        }
        points
    }

    /// The closed form's integral (Theorem 6.3) at its quadrature nodes:
    /// `J₁₁ = c`, the other entries zero.
    pub fn of_closed_form(law: DecayLaw, density: f64, radius: f64) -> Self {
        let scale = density * std::f64::consts::PI;
        let mut points = Self::default();
        let (h, nodes) = super::simpson_nodes(radius);
        for (r, c) in nodes {
            let weight = scale * (c * h / 3.0) * law.slope_over_distance_squared(r) * r.powi(3);
            points.push(law.amplitude(r), [weight, 0.0, 0.0]);
        }
        points
    }

    fn push(&mut self, amplitude: f64, weight: [f64; 3]) {
        self.amplitudes.push(amplitude);
        self.weights.push(weight);
    }

    pub fn len(&self) -> usize {
        self.amplitudes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.amplitudes.is_empty()
    }

    /// `Σ_j w_j I(a_j)` with this quantizer, each `I` summed over its
    /// window as [`Quantizer::fisher_scalars_exact`] sums it.
    pub fn information(&self, q: &Quantizer, sigma: f64) -> Matrix2<f64> {
        let mut j = [0.0; 3];
        for (&a, w) in self.amplitudes.iter().zip(&self.weights) {
            add_weighed(&mut j, w, q.fisher_scalars_exact(a, sigma * sigma).gg);
        }
        matrix(j)
    }
}

fn add_weighed(sum: &mut [f64; 3], w: &[f64; 3], information: f64) {
    for (s, w) in sum.iter_mut().zip(w) {
        *s += w * information;
    }
}

fn matrix(j: [f64; 3]) -> Matrix2<f64> {
    Matrix2::new(j[0], j[1], j[1], j[2])
}

/// An objective as the search sees it: threshold `k` is about to move with
/// the others held at `t`, then its value with threshold `k` at `x`.
trait Coordinate {
    fn hold(&mut self, k: usize, t: &[f64]);
    fn value(&mut self, k: usize, x: f64, t: &mut [f64]) -> f64;
}

/// The search of [`optimize_thresholds`], over any [`Coordinate`].
fn coordinate_ascent(
    start: &Quantizer,
    lo: f64,
    hi: f64,
    objective: &mut impl Coordinate,
) -> Quantizer {
    let mut t: Vec<f64> = (1..start.cells())
        .map(|i| start.cell_edges(i as u32).0)
        .collect();
    debug_assert!(t.iter().all(|&x| x > lo && x < hi), "start within (lo, hi)");
    for sweep in 0..MAX_SWEEPS {
        // The objective has local maxima as narrow as a few grid steps of
        // 32: the first sweep looks finer, over 512 points in all.
        let grid = if sweep == 0 {
            (512 / t.len()).max(64)
        } else {
            32
        };
        let mut before = None;
        let mut best = f64::NEG_INFINITY;
        for k in 0..t.len() {
            objective.hold(k, &t);
            let current = t[k];
            // The current thresholds' value as this coordinate's
            // decomposition gives it, so that every comparison below is
            // between values computed alike.
            best = objective.value(k, current, &mut t);
            before.get_or_insert(best);
            let left = if k == 0 { lo } else { t[k - 1] };
            let right = if k + 1 == t.len() { hi } else { t[k + 1] };
            let mut at = |x: f64, t: &mut Vec<f64>| objective.value(k, x, t);
            let (mut x_best, mut v_best) = (current, best);
            let step = (right - left) / (grid + 1) as f64;
            for g in 1..=grid {
                let x = left + step * g as f64;
                let v = at(x, &mut t);
                if v > v_best {
                    (x_best, v_best) = (x, v);
                }
            }
            // Golden section within a grid step either side.
            let (mut a, mut b) = (
                (x_best - step).max(left + 1e-12),
                (x_best + step).min(right - 1e-12),
            );
            let ratio = (5f64.sqrt() - 1.0) / 2.0;
            for _ in 0..40 {
                let (c, d) = (b - ratio * (b - a), a + ratio * (b - a));
                if at(c, &mut t) > at(d, &mut t) {
                    b = d;
                } else {
                    a = c;
                }
            }
            let mid = 0.5 * (a + b);
            let v_mid = at(mid, &mut t);
            if v_mid > v_best {
                (x_best, v_best) = (mid, v_mid);
            }
            t[k] = x_best;
            best = v_best;
        }
        let before = before.unwrap_or(best);
        if best - before <= 1e-9 * best.abs() {
            break;
        }
    }
    Quantizer::from_thresholds(&t).expect("the search keeps the thresholds increasing")
}

/// An objective of the whole quantizer, rebuilt at every trial position.
struct WholeQuantizer<F>(F);

impl<F: FnMut(&Quantizer) -> f64> Coordinate for WholeQuantizer<F> {
    fn hold(&mut self, _: usize, _: &[f64]) {}

    fn value(&mut self, k: usize, x: f64, t: &mut [f64]) -> f64 {
        t[k] = x;
        match Quantizer::from_thresholds(t) {
            Ok(q) => (self.0)(&q),
            Err(_) => f64::NEG_INFINITY,
        }
    }
}

/// A point whose window the moving threshold's two cells reach: its
/// information from the other cells of its window, and the two fixed
/// outer edges of the moving cells, standardized.
struct Moving {
    point: usize,
    rest: f64,
    below: Edge,
    above: Edge,
}

/// The weighed points' information with every cell but the moving two held.
struct HeldCells<'a, F> {
    points: &'a WeighedAmplitudes,
    sigma: f64,
    objective: F,
    /// `Σ w_j I(a_j)` over the points the moving cells do not reach.
    constant: [f64; 3],
    moving: Vec<Moving>,
    /// The edges `−∞, t…, +∞` as last held.
    at: Vec<f64>,
}

impl<F: Fn(&Matrix2<f64>) -> f64> Coordinate for HeldCells<'_, F> {
    fn hold(&mut self, k: usize, t: &[f64]) {
        self.at.clear();
        self.at.push(f64::NEG_INFINITY);
        self.at.extend_from_slice(t);
        self.at.push(f64::INFINITY);
        let (edges, sigma) = (&self.at[..], self.sigma);
        let variance = sigma * sigma;
        // Threshold k is edge k + 1: the cells either side are k and k + 1.
        let (left, right) = (k, k + 1);
        self.constant = [0.0; 3];
        self.moving.clear();
        for (j, (&a, w)) in self
            .points
            .amplitudes
            .iter()
            .zip(&self.points.weights)
            .enumerate()
        {
            let window = window_cells(edges, a, sigma);
            if *window.end() < left || *window.start() > right {
                let all = cells_sum(edges, window, a, sigma);
                add_weighed(&mut self.constant, w, all / variance);
                continue;
            }
            let (first, last) = (*window.start(), *window.end());
            let below = match left.checked_sub(1) {
                Some(end) => cells_sum(edges, first..=last.min(end), a, sigma),
                None => 0.0,
            };
            let rest = below + cells_sum(edges, first.max(right + 1)..=last, a, sigma);
            let standard = |e: f64| Edge::at((e - a) / sigma);
            self.moving.push(Moving {
                point: j,
                rest,
                below: standard(edges[left]),
                above: standard(edges[right + 1]),
            });
        }
    }

    fn value(&mut self, _: usize, x: f64, _: &mut [f64]) -> f64 {
        let variance = self.sigma * self.sigma;
        let mut j = self.constant;
        for m in &self.moving {
            let a = self.points.amplitudes[m.point];
            let mid = Edge::at((x - a) / self.sigma);
            let mut sums = [0.0; 3];
            accumulate_between(&mut sums, &m.below, &mid);
            accumulate_between(&mut sums, &mid, &m.above);
            add_weighed(
                &mut j,
                &self.points.weights[m.point],
                (m.rest + sums[0]) / variance,
            );
        }
        (self.objective)(&matrix(j))
    }
}

/// The cells `first..=last` within [`WINDOW_SIGMAS`] of `a`, as
/// [`Quantizer::fisher_scalars_exact`] sums them, for edges `−∞, t…, +∞`.
fn window_cells(edges: &[f64], a: f64, sigma: f64) -> RangeInclusive<usize> {
    let last_cell = edges.len() - 2;
    let cell = |x: f64| {
        edges
            .partition_point(|&e| e <= x)
            .saturating_sub(1)
            .min(last_cell)
    };
    cell(a - WINDOW_SIGMAS * sigma)..=cell(a + WINDOW_SIGMAS * sigma)
}

/// `Σ α²/h` (standardized) over the cells `range`; zero for an empty one.
fn cells_sum(edges: &[f64], range: RangeInclusive<usize>, a: f64, sigma: f64) -> f64 {
    let (first, last) = (*range.start(), *range.end());
    if first > last || last >= edges.len() - 1 {
        return 0.0;
    }
    window_sums((first..=last + 1).map(|m| (edges[m] - a) / sigma))[0]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fisher::Measurement;
    use crate::location::{closed_form_information, crlb_trace, exact_information};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use crate::location::tests::{GAUSSIAN, POWER};

    /// `count` sensors over a square of `side`, from `seed`.
    fn deploy(seed: u64, side: f64, count: usize) -> Vec<[f64; 2]> {
        let density = count as f64 / (side * side);
        crate::location::tests::deploy(&mut ChaCha8Rng::seed_from_u64(seed), side, density)
    }

    fn relative(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs().max(1e-300)
    }

    #[test]
    fn weighed_points_sum_to_the_exact_and_closed_form_information() {
        for (law, bits) in [(GAUSSIAN, 2), (POWER, 4)] {
            let q = uniform_quantizer(bits, law, 1.0);
            let sensors = deploy(3, 12.0, 150);
            let target = [0.4, -0.7];
            let exact = exact_information(law, Measurement::Quantized(&q), 1.0, &sensors, target);
            let weighed =
                WeighedAmplitudes::of_deployment(law, &sensors, target).information(&q, 1.0);
            for (a, b) in weighed.iter().zip(exact.iter()) {
                assert!(relative(*a, *b) < 1e-12, "{law:?}: {a} against {b}");
            }
            let closed = closed_form_information(law, Measurement::Quantized(&q), 1.0, 2.0, 6.0);
            let weighed = WeighedAmplitudes::of_closed_form(law, 2.0, 6.0).information(&q, 1.0);
            assert!(
                relative(weighed[(0, 0)], closed) < 1e-12,
                "{weighed} against {closed}"
            );
            assert_eq!(weighed[(0, 1)], 0.0);
        }
    }

    /// With every cell but two held, the information at a moved threshold
    /// is the whole quantizer's, recomputed from scratch.
    #[test]
    fn holding_the_other_cells_gives_the_whole_sum_at_every_trial_position() {
        for (law, bits, sigma) in [(GAUSSIAN, 3, 1.0), (POWER, 4, 1.0), (POWER, 5, 2.5)] {
            let sensors = deploy(5, 16.0, 200);
            let points = WeighedAmplitudes::of_deployment(law, &sensors, [0.0, 0.0]);
            let q = uniform_quantizer(bits, law, sigma);
            let mut t: Vec<f64> = (1..q.cells()).map(|i| q.cell_edges(i as u32).0).collect();
            let mut held = HeldCells {
                points: &points,
                sigma,
                objective: |j: &Matrix2<f64>| j[(0, 0)] + 3.0 * j[(0, 1)] + 7.0 * j[(1, 1)],
                constant: [0.0; 3],
                moving: Vec::new(),
                at: Vec::new(),
            };
            let mut rng = ChaCha8Rng::seed_from_u64(8);
            for k in [0, t.len() / 2, t.len() - 1] {
                held.hold(k, &t);
                let left = if k == 0 { -4.0 * sigma } else { t[k - 1] };
                let right = t
                    .get(k + 1)
                    .copied()
                    .unwrap_or(law.p0().sqrt() + 4.0 * sigma);
                for _ in 0..5 {
                    let x = rng.random_range(left..right);
                    let got = held.value(k, x, &mut t);
                    let mut moved = t.clone();
                    moved[k] = x;
                    let j = points.information(&Quantizer::from_thresholds(&moved).unwrap(), sigma);
                    let want = j[(0, 0)] + 3.0 * j[(0, 1)] + 7.0 * j[(1, 1)];
                    assert!(
                        relative(got, want) < 1e-11,
                        "{law:?}, {bits} bits, threshold {k} at {x}: {got} against {want}"
                    );
                }
                t[k] = 0.5 * (left + right);
            }
        }
    }

    /// The weighed search is the whole-quantizer search, sped up: from the
    /// same start it ends at the same CRLB.
    #[test]
    fn the_weighed_search_ends_where_the_whole_search_does() {
        let sensors = deploy(11, 10.0, 200);
        let (lo, hi) = (-4.0, 104.0);
        let negative_trace = |j: &Matrix2<f64>| crlb_trace(j).map_or(f64::NEG_INFINITY, |t| -t);
        for bits in [1, 2, 3] {
            let start = uniform_quantizer(bits, GAUSSIAN, 1.0);
            let whole = optimize_thresholds_from(&start, lo, hi, |q| {
                negative_trace(&exact_information(
                    GAUSSIAN,
                    Measurement::Quantized(q),
                    1.0,
                    &sensors,
                    [0.0, 0.0],
                ))
            });
            let points = WeighedAmplitudes::of_deployment(GAUSSIAN, &sensors, [0.0, 0.0]);
            let weighed = optimize_weighed_thresholds(&start, lo, hi, &points, 1.0, negative_trace);
            let value = |q: &Quantizer| negative_trace(&points.information(q, 1.0));
            assert!(
                relative(value(&weighed), value(&whole)) < 1e-9,
                "{bits} bits: {} against {}",
                value(&weighed),
                value(&whole)
            );
        }
    }
}
