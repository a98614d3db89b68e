//! A table of the Fisher scalars of an infinite uniform quantizer.
//!
//! For cells of width Δ, a mean g at fraction `u` of its cell and a standard
//! deviation `σ = sΔ`, the standardized edges are `(m − u)/s`, so the window
//! sums `Σα²/h, Σαβ/h, Σβ²/h` depend on `(u, s)` alone, whatever the bit
//! depth or range. One table, built once per process, serves every uniform
//! quantizer wherever its outer cells are out of reach; bicubic Lagrange
//! interpolation reads it, in u and along [`crate::width_axis`] (even in
//! the half-width `1/(2s)` within octaves, the axis the likelihood table
//! shares).
//!
//! From s = 1 up the sums depend on u by less than 1.2e-7 (their
//! peak-to-peak swing over u is 2.3e-7 at s = 1 for the largest, Σβ²/h of
//! scale 2, and falls as exp(−2π²s²): 4e-9 at s = 1.1), so a row there is
//! the sums' mean over u and the interpolation is cubic in s alone. Only
//! the axis's top octave, s ≤ 1 (`width_axis::below_one`), keeps the grid
//! over u; its stencils stay within it.
//!
//! Rows (one per value of s) are computed on first use, so a process pays
//! only for the range of σ/Δ it meets. `table_matches_the_exact_sums`
//! bounds its error against the exact sums (below 1e-6 of the unquantized
//! information; 5.8e-8 seen).

use std::sync::OnceLock;

use crate::cell_sums::{window_sums, WINDOW_SIGMAS};
use crate::shared_rows::{LazyRows, PlainRow, SharedRows};
use crate::width_axis::{self, lagrange_weights, Stencil};

/// Grid points over the cell fraction u ∈ [0, 1) (periodic).
pub(crate) const U_POINTS: usize = 128;
/// The table covers `S_MIN < σ/Δ < S_MAX`. Below it the exact sums are
/// used (few cells when σ ≪ Δ); above it, the fine-cell expansion
/// (`fine_cell_sums`).
pub use crate::width_axis::{S_MAX, S_MIN};

/// Samples over u for the mean of a row that has no grid: the trapezoid
/// rule is exact for a periodic function up to harmonics of this order,
/// and the rest are below 1e-30 here.
const FLAT_SAMPLES: usize = 8;

/// The grid over u of one row, padded with one column before and two after
/// (the periodic neighbours), so that the four-column stencil of any `u` is
/// one contiguous run.
pub(crate) type Grid = [[f64; 3]; U_POINTS + 3];

/// The sums' mean over u at one value of s.
pub(crate) type Means = [f64; 3];

crate::shared_rows::kept_by_reference!(Grid);

// SAFETY: three f64.
unsafe impl PlainRow for Means {
    type Kept = Self;
    #[inline(always)]
    fn keep(row: &'static Self) -> Self::Kept {
        *row
    }
    #[inline(always)]
    fn kept(kept: &Self::Kept) -> &Self {
        kept
    }
}

/// Per value of s, the sums' mean over u and, below s = 1, the grid over u
/// (whose row of means is taken from it).
#[derive(Default)]
pub struct FisherTable {
    means: LazyRows<Means>,
    grids: LazyRows<Grid>,
}

/// The process-wide table; its rows fill in as they are first needed.
pub fn table() -> &'static FisherTable {
    static TABLE: OnceLock<FisherTable> = OnceLock::new();
    TABLE.get_or_init(FisherTable::default)
}

/// Window sums for an infinite grid of unit cells, mean at fraction `u` of
/// cell 0, standard deviation `s`.
pub fn grid_sums(u: f64, s: f64) -> [f64; 3] {
    let first = (u - WINDOW_SIGMAS * s).floor() as i64;
    let last = (u + WINDOW_SIGMAS * s).floor() as i64;
    window_sums((first..=last + 1).map(|m| (m as f64 - u) / s))
}

fn mean_of(sums: &[[f64; 3]]) -> [f64; 3] {
    let n = sums.len() as f64;
    let total = sums
        .iter()
        .fold([0.0; 3], |t, v| [t[0] + v[0], t[1] + v[1], t[2] + v[2]]);
    total.map(|t| t / n)
}

impl FisherTable {
    /// The means of row `is`, built on first use.
    #[inline(always)]
    fn means(&self, is: usize) -> &Means {
        self.means.get(is, |is| {
            if width_axis::below_one(is) {
                let grid = self.grid(is);
                return mean_of(&grid[1..=U_POINTS]);
            }
            let s = width_axis::row_s(is);
            let sums: [[f64; 3]; FLAT_SAMPLES] =
                std::array::from_fn(|iu| grid_sums(iu as f64 / FLAT_SAMPLES as f64, s));
            mean_of(&sums)
        })
    }

    /// The grid of row `is` (one below s = 1), built on first use.
    #[inline(always)]
    fn grid(&self, is: usize) -> &Grid {
        debug_assert!(width_axis::below_one(is));
        self.grids.get(is, |is| {
            let s = width_axis::row_s(is);
            let sums: [[f64; 3]; U_POINTS] =
                std::array::from_fn(|iu| grid_sums(iu as f64 / U_POINTS as f64, s));
            std::array::from_fn(|c| sums[(c + U_POINTS - 1) % U_POINTS])
        })
    }

    /// Rows not built yet come from (or go to) memory other processes share.
    pub(crate) fn share(&self, means: SharedRows<Means>, grids: SharedRows<Grid>) {
        self.means.share(means);
        self.grids.share(grids);
    }

    /// Interpolated sums at `(u, s)`; from `S_MAX` up, the fine-cell
    /// expansion; `None` at `S_MIN` and below.
    #[inline]
    pub fn lookup(&self, u: f64, s: f64) -> Option<[f64; 3]> {
        self.lookup_at(u, s, width_axis::stencil(0.5 / s).as_ref())
    }

    /// [`lookup`](Self::lookup) with the rows over s already found
    /// (`None` outside the axis).
    #[inline(always)]
    pub fn lookup_at(&self, u: f64, s: f64, rows: Option<&Stencil>) -> Option<[f64; 3]> {
        if s >= S_MAX {
            return Some(fine_cell_sums(s));
        }
        let Stencil { first, weights: ws } = *rows?;
        let mut out = [0.0; 3];
        if !width_axis::below_one(first) {
            for (a, wsa) in ws.iter().enumerate() {
                let v = self.means(first + a);
                out[0] += wsa * v[0];
                out[1] += wsa * v[1];
                out[2] += wsa * v[2];
            }
            return Some(out);
        }
        // `modulo` lands in [0, 1), so `xu` is in [0, U_POINTS).
        let xu = crate::modulo(u, 1.0) * U_POINTS as f64;
        let iu = (xu as usize).min(U_POINTS - 1);
        let wu = lagrange_weights(xu - iu as f64);
        // Σ over the four rows first, element by element over the stencil's
        // twelve contiguous values (which the compiler can vectorise), then
        // over the four columns.
        let mut acc = [0.0; 12];
        for (a, wsa) in ws.iter().enumerate() {
            // Grid column c holds u-column c − 1: columns iu − 1 ..= iu + 2.
            let grid = self.grid(first + a);
            let stencil: &[f64; 12] = grid[iu..iu + 4]
                .as_flattened()
                .try_into()
                .expect("a padded row holds every four-column stencil");
            for (t, v) in acc.iter_mut().zip(stencil) {
                *t += wsa * v;
            }
        }
        for (wub, column) in wu.iter().zip(acc.chunks_exact(3)) {
            out[0] += wub * column[0];
            out[1] += wub * column[1];
            out[2] += wub * column[2];
        }
        Some(out)
    }
}

/// The sums when cells are much finer than σ (s = σ/Δ ≫ 1): the
/// unquantized (1, 0, 2) less a Sheppard-like correction in 1/s². The
/// dependence on u is of order exp(−2π²s²), nil here, and the next term is
/// O(s⁻⁶), below 1e-10 for s > 64. Without it a 13-bit bearing (s ≈ 65)
/// summed 1,200 cells per particle and sensor; 16 bits, ten thousand.
#[inline(always)]
fn fine_cell_sums(s: f64) -> [f64; 3] {
    let inv2 = 1.0 / (s * s);
    [
        1.0 - inv2 / 12.0 + inv2 * inv2 / 144.0,
        0.0,
        2.0 - inv2 / 3.0 + inv2 * inv2 / 20.0,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn table_matches_the_exact_sums() {
        let t = table();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut worst: f64 = 0.0;
        for _ in 0..20_000 {
            let u = rng.random::<f64>();
            let s = (rng.random_range(S_MIN.ln()..S_MAX.ln()))
                .exp()
                .max(S_MIN.next_up());
            let exact = grid_sums(u, s);
            let table = t.lookup(u, s).unwrap();
            // Scale: the unquantized sums are (1, 0, 2) in standardized units.
            for (a, b, scale) in [
                (table[0], exact[0], 1.0),
                (table[1], exact[1], 1.0),
                (table[2], exact[2], 2.0),
            ] {
                worst = worst.max((a - b).abs() / scale);
            }
        }
        assert!(worst < 1e-6, "worst relative error {worst:e}");
    }

    /// The expansion's coefficients were read off the exact sums; this holds
    /// them to the exact sums over the whole range it serves.
    #[test]
    fn fine_cells_follow_the_expansion_in_one_over_s_squared() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut worst: f64 = 0.0;
        for _ in 0..300 {
            let u = rng.random::<f64>();
            let s = (rng.random_range(S_MAX.ln()..600f64.ln())).exp();
            let exact = grid_sums(u, s);
            let fine = table().lookup(u, s).unwrap();
            for k in 0..3 {
                worst = worst.max((fine[k] - exact[k]).abs());
            }
        }
        assert!(worst < 1e-9, "worst error {worst:e}");
        // And the correction matters: dropping it errs by about 1/(12 s²).
        let s = S_MAX * 1.01;
        assert!((1.0 - grid_sums(0.4, s)[0]) > 1e-5);
    }

    #[test]
    fn lagrange_weights_reproduce_cubics() {
        let f = |x: f64| 2.0 * x * x * x - x * x + 3.0 * x - 5.0;
        let t = 0.37;
        let w = lagrange_weights(t);
        let v: f64 = w
            .iter()
            .zip([-1.0, 0.0, 1.0, 2.0])
            .map(|(w, x)| w * f(x))
            .sum();
        assert!((v - f(t)).abs() < 1e-12);
    }
}
