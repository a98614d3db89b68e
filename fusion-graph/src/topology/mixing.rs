//! How fast average consensus mixes on the fusion graph, known before a
//! run: the second-largest eigenvalue modulus λ₂ of the Metropolis weight
//! matrix `W` (docs/equations.md, "How far consensus gets").
//!
//! Each round of average consensus multiplies a node's distance from the
//! average by at most λ₂ (the disagreement `x − x̄1` lives in the
//! eigenvectors other than `1`), so `N_c` rounds leave `λ₂^N_c` of the
//! initial disagreement, and a share `ε` takes `⌈ln ε / ln λ₂⌉` rounds.
//! A graph in several components mixes each within itself, towards its
//! own average: its λ₂ is the slowest component's.

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use super::Topology;

/// Components up to this size are decomposed whole; larger ones by
/// Lanczos on the operator, which finds the extreme eigenvalues in far
/// fewer steps than the component has nodes.
const DENSE_UP_TO: usize = 400;
/// Lanczos steps for a large component: enough for the extreme Ritz
/// values of a grid of thousands of nodes to settle to ~1e-9.
const LANCZOS_STEPS: usize = 300;

/// How a graph's Metropolis weights mix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mixing {
    /// λ₂: the second-largest eigenvalue modulus of `W`, the slowest
    /// component's; 0 for a graph whose components are single nodes or
    /// complete pairs (one round averages them exactly).
    pub slem: f64,
}

impl Mixing {
    /// The share of the initial disagreement left after `rounds` rounds
    /// (an upper bound, reached by the slowest mode).
    pub fn left_after(self, rounds: u32) -> f64 {
        self.slem.powi(rounds.min(i32::MAX as u32) as i32)
    }

    /// The fewest rounds that leave at most `share` of the disagreement
    /// (`0 < share < 1`); `None` if no number of rounds does (λ₂ = 1).
    pub fn rounds_for(self, share: f64) -> Option<u32> {
        if self.slem >= 1.0 {
            return None;
        }
        if self.slem <= 0.0 {
            return Some(1);
        }
        let rounds = (share.ln() / self.slem.ln()).ceil().max(1.0);
        (rounds <= u32::MAX as f64).then_some(rounds as u32)
    }

    /// The share of the disagreement `rounds` rounds of short-memory
    /// consensus leave at most: a mode of `W` with eigenvalue λ goes as
    /// `e(t+1) = (1 + α) λ e(t) − α e(t−1)`, `e(0) = 1`, `e(1) = λ` (the
    /// first round is plain), which falls as √α a round only in the long
    /// run; the worst over λ in [−λ₂, λ₂], on a fine grid.
    pub fn left_after_short_memory(self, rounds: u32) -> f64 {
        self.short_memory_left().nth(rounds as usize).unwrap_or(0.0)
    }

    /// The share short-memory consensus leaves after 0, 1, 2, … rounds.
    pub fn short_memory_left(self) -> impl Iterator<Item = f64> {
        const POINTS: usize = 401;
        let alpha = self.memory_weight();
        let lambdas: Vec<f64> = (0..POINTS)
            .map(|i| self.slem * (2.0 * i as f64 / (POINTS - 1) as f64 - 1.0))
            .collect();
        let mut before = vec![1.0; POINTS];
        let mut now = lambdas.clone();
        let mut round = 0u32;
        std::iter::from_fn(move || {
            let left = match round {
                0 => 1.0,
                _ => now.iter().map(|e| e.abs()).fold(0.0, f64::max),
            };
            if round >= 1 {
                for ((b, n), l) in before.iter_mut().zip(now.iter_mut()).zip(&lambdas) {
                    let next = (1.0 + alpha) * l * *n - alpha * *b;
                    *b = std::mem::replace(n, next);
                }
            }
            round += 1;
            Some(left)
        })
    }

    /// The short-memory weight α = 2 / (1 + √(1 − λ₂²)) − 1 of
    /// second-order consensus, `x(t+1) = (1 + α) W x(t) − α x(t−1)`,
    /// which mixes at about √α a round.
    pub fn memory_weight(self) -> f64 {
        let s = self.slem.clamp(0.0, 1.0);
        2.0 / (1.0 + (1.0 - s * s).sqrt()) - 1.0
    }
}

impl Topology {
    /// How the Metropolis weights of the nodes marked `alive` mix.
    pub fn mixing(&self, alive: &[bool]) -> Mixing {
        let slem = self
            .components(alive)
            .iter()
            .map(|c| self.component_slem(c, alive, DENSE_UP_TO))
            .fold(0.0, f64::max);
        Mixing { slem }
    }

    /// λ₂ of one component's weights: dense up to `dense_up_to` nodes,
    /// Lanczos beyond.
    fn component_slem(&self, component: &[u16], alive: &[bool], dense_up_to: usize) -> f64 {
        let n = component.len();
        if n <= 1 {
            return 0.0;
        }
        let rows = self.component_rows(component, alive);
        let extreme = if n <= dense_up_to {
            let w = DMatrix::from_fn(n, n, |i, j| {
                rows[i]
                    .iter()
                    .find(|(k, _)| *k == j)
                    .map_or(0.0, |(_, w)| *w)
            });
            SymmetricEigen::new(w).eigenvalues.iter().copied().collect()
        } else {
            lanczos_ritz_values(&rows, LANCZOS_STEPS.min(n - 1))
        };
        // The consensus eigenvalue 1 (eigenvector 1) is removed once; every
        // other is a mode of the disagreement.
        slem_without_one(extreme, n <= dense_up_to)
    }

    /// The component's Metropolis matrix by rows, its nodes in `component`
    /// order: each row's `(column, weight)`, the diagonal among them.
    fn component_rows(&self, component: &[u16], alive: &[bool]) -> Vec<Vec<(usize, f64)>> {
        let mut at = vec![usize::MAX; self.nodes()];
        for (i, &node) in component.iter().enumerate() {
            at[node as usize] = i;
        }
        component
            .iter()
            .enumerate()
            .map(|(i, &node)| {
                let weights = self.metropolis_weights(node, alive);
                std::iter::once((i, weights.own))
                    .chain(
                        weights
                            .neighbours
                            .iter()
                            .map(|(m, w)| (at[*m as usize], *w)),
                    )
                    .collect()
            })
            .collect()
    }
}

/// λ₂ from `W`'s eigenvalues (`all`: every one, the consensus eigenvalue
/// among them) or from Ritz values of `W` on the complement of `1` (the
/// consensus eigenvalue already projected out).
fn slem_without_one(mut values: Vec<f64>, all: bool) -> f64 {
    if all {
        let one = values
            .iter()
            .enumerate()
            .min_by(|a, b| (a.1 - 1.0).abs().total_cmp(&(b.1 - 1.0).abs()))
            .map(|(i, _)| i)
            .expect("a component of two or more nodes");
        values.swap_remove(one);
    }
    values.iter().map(|v| v.abs()).fold(0.0, f64::max).min(1.0)
}

/// Ritz values of `W` restricted to the complement of `1`, by `steps`
/// Lanczos steps with full reorthogonalization from a fixed start (so that
/// every process computes the same figure).
fn lanczos_ritz_values(rows: &[Vec<(usize, f64)>], steps: usize) -> Vec<f64> {
    let n = rows.len();
    let apply =
        |q: &DVector<f64>| DVector::from_fn(n, |i, _| rows[i].iter().map(|(j, w)| w * q[*j]).sum());
    let ones = DVector::from_element(n, 1.0 / (n as f64).sqrt());
    let deflate = |v: &mut DVector<f64>| {
        let along = ones.dot(v);
        v.axpy(-along, &ones, 1.0);
    };
    // A start with a part along every mode: a fixed, irregular sequence.
    let mut q = DVector::from_fn(n, |i, _| {
        ((i as f64 + 1.0) * 0.618_033_988_75).fract() - 0.5
    });
    deflate(&mut q);
    q.normalize_mut();
    let mut basis: Vec<DVector<f64>> = Vec::with_capacity(steps);
    let (mut alphas, mut betas) = (Vec::with_capacity(steps), Vec::with_capacity(steps));
    for _ in 0..steps {
        let mut v = apply(&q);
        deflate(&mut v);
        let alpha = q.dot(&v);
        v.axpy(-alpha, &q, 1.0);
        basis.push(q.clone());
        // Twice, against every vector so far: Lanczos loses orthogonality
        // as Ritz values converge.
        for _ in 0..2 {
            for b in &basis {
                let along = b.dot(&v);
                v.axpy(-along, b, 1.0);
            }
        }
        alphas.push(alpha);
        let beta = v.norm();
        if beta < 1e-12 {
            break;
        }
        betas.push(beta);
        q = v / beta;
    }
    let k = alphas.len();
    let t = DMatrix::from_fn(k, k, |i, j| match i.abs_diff(j) {
        0 => alphas[i],
        1 => betas[i.min(j)],
        _ => 0.0,
    });
    SymmetricEigen::new(t).eigenvalues.iter().copied().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(side: u32, width: f64) -> Topology {
        crate::topology::test_grid(side, side, width, width)
    }

    /// A ring of n nodes, each of degree 2: every weight is 1/3 and W's
    /// eigenvalues are (1 + 2 cos(2πk/n)) / 3, k = 0..n−1.
    #[test]
    fn a_rings_slem_is_its_closed_form() {
        for n in [3usize, 5, 8, 13] {
            let mut t = grid(3, 1500.0);
            t.neighbours = (0..n as u16)
                .map(|i| vec![(i + 1) % n as u16, (i + n as u16 - 1) % n as u16])
                .collect();
            t.node_positions = vec![[0.0, 0.0]; n].into();
            if n == 3 {
                // Three nodes in a ring are complete: weights 1/3 everywhere.
                assert!(t.mixing(&vec![true; n]).slem < 1e-12);
                continue;
            }
            let closed = (1..n)
                .map(|k| {
                    ((1.0 + 2.0 * (2.0 * std::f64::consts::PI * k as f64 / n as f64).cos()) / 3.0)
                        .abs()
                })
                .fold(0.0, f64::max);
            let got = t.mixing(&vec![true; n]).slem;
            assert!(
                (got - closed).abs() < 1e-12,
                "ring of {n}: {got} against {closed}"
            );
        }
    }

    /// The grids the scenarios build, 4-neighbour: λ₂ 0.767, 0.942 and
    /// 0.9795 for 3 × 3, 6 × 6 and 10 × 10, and the rounds a share needs.
    #[test]
    fn grids_mix_as_their_size_says() {
        let cases = [(3, 1500.0, 0.767), (6, 3000.0, 0.942), (10, 5000.0, 0.9795)];
        for (side, width, slem) in cases {
            let t = grid(side, width);
            let degrees: Vec<usize> = t.neighbours.iter().map(Vec::len).collect();
            assert_eq!(
                *degrees.iter().max().unwrap(),
                4,
                "{side}: a 4-neighbour grid"
            );
            let m = t.mixing(&t.all_alive());
            assert!((m.slem - slem).abs() < 1e-3, "{side} × {side}: {}", m.slem);
            let rounds = m.rounds_for(0.01).unwrap();
            assert!(m.left_after(rounds) <= 0.01 && m.left_after(rounds - 1) > 0.01);
        }
    }

    /// Lanczos on a large component finds what the whole decomposition
    /// finds.
    #[test]
    fn lanczos_agrees_with_the_whole_decomposition() {
        let t = grid(10, 5000.0);
        let all = t.all_alive();
        let nodes: Vec<u16> = (0..t.nodes() as u16).collect();
        let dense = t.component_slem(&nodes, &all, usize::MAX);
        let rows = t.component_rows(&nodes, &all);
        let lanczos = slem_without_one(lanczos_ritz_values(&rows, 60), false);
        assert!((dense - lanczos).abs() < 1e-9, "{dense} against {lanczos}");
    }

    /// Components mix apart: dead nodes that cut the graph leave two
    /// 3-node paths, each mixing by itself (weights 1/3, so W has
    /// eigenvalues 1, 2/3 and 0: λ₂ = 2/3); a lone node has nothing to mix.
    #[test]
    fn a_cut_graph_reports_its_slowest_component() {
        let t = grid(3, 1500.0);
        let middle: Vec<usize> = (0..9)
            .filter(|&n| (t.node_positions[n][0] - 750.0).abs() < 1.0)
            .collect();
        assert_eq!(middle.len(), 3);
        let mut alive = t.all_alive();
        for n in middle {
            alive[n] = false;
        }
        let m = t.mixing(&alive);
        assert!((m.slem - 2.0 / 3.0).abs() < 1e-12, "{}", m.slem);
        let mut lone = vec![false; 9];
        lone[0] = true;
        assert_eq!(t.mixing(&lone).slem, 0.0);
    }

    /// Second-order consensus with α from λ₂ mixes at about √α a round,
    /// faster than λ₂, on the 10 × 10 grid: iterate it on a random start.
    #[test]
    fn short_memory_mixes_at_the_root_of_its_weight() {
        let t = grid(10, 5000.0);
        let all = t.all_alive();
        let nodes: Vec<u16> = (0..t.nodes() as u16).collect();
        let rows = t.component_rows(&nodes, &all);
        let w = DMatrix::from_fn(100, 100, |i, j| {
            rows[i]
                .iter()
                .find(|(k, _)| *k == j)
                .map_or(0.0, |(_, w)| *w)
        });
        let m = t.mixing(&all);
        let alpha = m.memory_weight();
        let start = DVector::from_fn(100, |i, _| ((i * 37 % 101) as f64) / 101.0);
        let mean = start.mean();
        let spread = |x: &DVector<f64>| x.add_scalar(-mean).norm();
        let (mut before, mut now) = (start.clone(), &w * &start);
        let mut plain = now.clone();
        let rounds = 40;
        for _ in 1..rounds {
            let next = (&w * &now) * (1.0 + alpha) - &before * alpha;
            before = std::mem::replace(&mut now, next);
            plain = &w * &plain;
        }
        assert!((now.mean() - mean).abs() < 1e-12, "the average is kept");
        // Every mode is a scalar recursion: the worst over [−λ₂, λ₂] bounds
        // the whole vector's, and is nearly reached.
        let left = spread(&now) / spread(&start);
        let bound = m.left_after_short_memory(rounds);
        assert!(left <= bound * (1.0 + 1e-9), "{left} against {bound}");
        assert!(m.left_after_short_memory(1) == m.slem && m.left_after_short_memory(0) == 1.0);
        let rate = (spread(&now) / spread(&start)).powf(1.0 / rounds as f64);
        assert!(
            rate < alpha.sqrt() * 1.1,
            "{rate} against √α = {}",
            alpha.sqrt()
        );
        assert!(spread(&now) < 0.1 * spread(&plain));
    }
}
