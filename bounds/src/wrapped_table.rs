//! A table of the Fisher scalars of a wrapped uniform quantizer whose noise
//! reaches round the circle.
//!
//! The Fisher table ([`crate::fisher_table`]) sums an infinite grid of
//! cells, which is a wrapped quantizer's sum only while the window of
//! ±[`WINDOW_SIGMAS`] σ fits in one period P. A bearing's variance grows
//! with the square of the distance, so a sensor a few kilometres from the
//! target passes that point (σ > P/18: 0.35 rad), and there every cell
//! collects mass from several turns of the circle. Summing them exactly
//! costs every cell's `erfc` on every turn, per particle: a field twice as
//! wide cost 50 times as much.
//!
//! With cells of width Δ = P/L and the mean at fraction u of its cell, the
//! sums depend on `t = σ/P`, u and L alone, so one table per L serves:
//! over t alone from [`GRID_CELLS`] cells up, where the dependence on u is
//! below 1e-12, and over t and u below that. Its rows come from the
//! wrapped normal's Fourier series, exact for the circle: with
//! `ρ_k = exp(−k²σ²/2)` (σ in radians of the circle) and cell i centred
//! `θ_i` from the mean,
//!
//! ```text
//! h_i = 1/L + Σ_k c_k cos(kθ_i),   c_k = 2ρ_k sin(kΔ/2)/(πk),
//! α_i = σ ∂h_i/∂μ  = σ  Σ_k c_k k sin(kθ_i),
//! β_i = 2σ² ∂h_i/∂σ² = −σ² Σ_k c_k k² cos(kθ_i),
//! ```
//!
//! which needs fewer terms the wider the noise (27 at t = 1/18, 2 at
//! t = 1), where the cells' `erfc`s need more turns. Past
//! [`T_VANISH`] every sum is below 1e-18 of the unquantized information:
//! the observation says nothing, and the table reads zero.
//!
//! Rows are built on first use, each process its own (a row of 256 cells
//! takes about a tenth of a millisecond). `table_matches_the_folded_cells`
//! bounds the error against the cells' sums by `erfc` (below 1e-9 of the
//! unquantized information; 5.5e-10 seen).

use std::f64::consts::PI;
use std::sync::OnceLock;

use crate::cell_sums::{accumulate, WINDOW_SIGMAS};
use crate::fisher_table::{Grid, U_POINTS};
use crate::quantizer::MAX_BITS;
use crate::width_axis::lagrange_weights;

/// Where the table starts, in `t = σ/P`: the window spans the period.
/// Below it the Fisher table serves.
pub const T_WRAP: f64 = 0.5 / WINDOW_SIGMAS;

/// From here on the sums read zero: the largest, Σβ²/h, is about
/// `2(2πt)⁴ρ₁²` for `ρ₁ = exp(−2π²t²)`, below 1e-18 at t = 1.25.
pub const T_VANISH: f64 = 1.25;

/// Spacing of the rows in t. Cubic interpolation errs by about
/// `h⁴ f''''/40`; the sums' fourth derivative peaks near 5e5 at t = 0.25.
const STEP: f64 = 1.0 / 2048.0;
const PER_STEP: f64 = 2048.0;

/// Row 0 sits two steps below [`T_WRAP`], so that the stencil of any
/// `t ≥ T_WRAP` (rows r − 1 ..= r + 2) starts at row 1 or later.
const T_FIRST: f64 = T_WRAP - 2.0 * STEP;

/// Enough rows for the stencil of any `t < T_VANISH`.
const ROWS: usize = ((T_VANISH - T_FIRST) * PER_STEP) as usize + 4;

/// Samples over u for a row's mean: the trapezoid rule is exact for a
/// periodic function up to harmonics of this order (as in the Fisher
/// table).
const FLAT_SAMPLES: usize = 8;

/// Terms of the Fourier series are kept while `k²σ²/2 < 45`, so the first
/// dropped `ρ_k` is below 3e-20.
const LAST_EXPONENT: f64 = 45.0;

/// The rows of one number of cells: their means over u from
/// [`GRID_CELLS`] cells up, the grid over u below.
pub struct WrappedTable {
    cells: u32,
    means: Box<[OnceLock<[f64; 3]>]>,
    grids: Box<[OnceLock<Box<Grid>>]>,
}

/// From this many cells up the sums' swing over u is below 1e-12 (4e-13
/// at 128 cells; 1.3e-9 at 64, 1.7e-6 at 32, 2.7e-4 at 16): the wrapped
/// sums' dependence on u falls only geometrically in L, as the terms α²/h
/// of a circle's cells are not confined to a Gaussian's reach.
pub const GRID_CELLS: u32 = 128;

/// The process-wide table of a wrapped quantizer of `cells` cells (a power
/// of two, as every uniform quantizer's).
pub fn table(cells: u32) -> &'static WrappedTable {
    static TABLES: [OnceLock<WrappedTable>; MAX_BITS as usize + 1] =
        [const { OnceLock::new() }; MAX_BITS as usize + 1];
    debug_assert!(cells.is_power_of_two());
    TABLES[cells.trailing_zeros() as usize].get_or_init(|| WrappedTable {
        cells,
        means: (0..ROWS).map(|_| OnceLock::new()).collect(),
        grids: (0..ROWS).map(|_| OnceLock::new()).collect(),
    })
}

impl WrappedTable {
    /// Interpolated sums `Σα²/h, Σαβ/h, Σβ²/h` at `t = σ/P ≥ T_WRAP` and
    /// the mean at fraction `u` of its cell, for `σ/Δ ≥ 1` (narrower noise
    /// has fewer than 18 cells in its window, summed exactly).
    #[inline]
    pub fn lookup(&self, t: f64, u: f64) -> [f64; 3] {
        debug_assert!(t >= T_WRAP);
        if t >= T_VANISH {
            return [0.0; 3];
        }
        let x = (t - T_FIRST) * PER_STEP;
        let r = x as usize;
        let w = lagrange_weights(x - r as f64);
        let mut out = [0.0; 3];
        if self.cells >= GRID_CELLS {
            for (a, wa) in w.iter().enumerate() {
                let row = self.means(r - 1 + a);
                for k in 0..3 {
                    out[k] += wa * row[k];
                }
            }
            return out;
        }
        // `modulo` lands in [0, 1), so `xu` is in [0, U_POINTS).
        let xu = crate::modulo(u, 1.0) * U_POINTS as f64;
        let iu = (xu as usize).min(U_POINTS - 1);
        let wu = lagrange_weights(xu - iu as f64);
        for (a, wa) in w.iter().enumerate() {
            // Grid column c holds u-column c − 1: columns iu − 1 ..= iu + 2.
            let grid = self.grid(r - 1 + a);
            for (b, wub) in wu.iter().enumerate() {
                let v = &grid[iu + b];
                for k in 0..3 {
                    out[k] += wa * wub * v[k];
                }
            }
        }
        out
    }

    #[inline(always)]
    fn means(&self, r: usize) -> &[f64; 3] {
        match self.means[r].get() {
            Some(row) => row,
            None => self.build_means(r),
        }
    }

    #[inline(always)]
    fn grid(&self, r: usize) -> &Grid {
        match self.grids[r].get() {
            Some(row) => row,
            None => self.build_grid(r),
        }
    }

    fn row_t(r: usize) -> f64 {
        T_FIRST + r as f64 * STEP
    }

    #[cold]
    #[inline(never)]
    fn build_means(&self, r: usize) -> &[f64; 3] {
        self.means[r].get_or_init(|| {
            let mut mean = [0.0; 3];
            for iu in 0..FLAT_SAMPLES {
                let u = iu as f64 / FLAT_SAMPLES as f64;
                let sums = fourier_sums(self.cells, Self::row_t(r), u);
                for k in 0..3 {
                    mean[k] += sums[k] / FLAT_SAMPLES as f64;
                }
            }
            mean
        })
    }

    #[cold]
    #[inline(never)]
    fn build_grid(&self, r: usize) -> &Grid {
        self.grids[r].get_or_init(|| {
            let t = Self::row_t(r);
            let sums: Vec<[f64; 3]> = (0..U_POINTS)
                .map(|iu| fourier_sums(self.cells, t, iu as f64 / U_POINTS as f64))
                .collect();
            // Padded with the periodic neighbours, as the Fisher table's.
            Box::new(std::array::from_fn(|c| sums[(c + U_POINTS - 1) % U_POINTS]))
        })
    }
}

/// The sums of `cells` equal cells round a circle, for a wrapped normal of
/// standard deviation `t` periods whose mean is at fraction `u` of cell 0,
/// from the wrapped normal's Fourier series (the module's equations).
pub fn fourier_sums(cells: u32, t: f64, u: f64) -> [f64; 3] {
    let l = cells as usize;
    let width = 2.0 * PI / l as f64;
    let sigma = 2.0 * PI * t;
    let terms = ((2.0 * LAST_EXPONENT).sqrt() / sigma).floor().max(1.0) as usize;
    // c_k, and its multiples by k and k² for the derivatives.
    let c: Vec<f64> = (1..=terms)
        .map(|k| {
            let k = k as f64;
            2.0 * (-0.5 * k * k * sigma * sigma).exp() * (0.5 * k * width).sin() / (PI * k)
        })
        .collect();
    // A cell whose probability is this small has |α|, |β| of the series'
    // rounding, and α²/h would be noise; the mass there is so far out that
    // its true terms sum below 1e-12.
    let floor = 1e-14 / l as f64;
    let mut sums = [0.0; 3];
    for i in 0..l {
        let theta = (i as f64 + 0.5 - u) * width;
        let (s1, c1) = theta.sin_cos();
        // cos(kθ), sin(kθ) by the angle-addition recurrence.
        let (mut ck, mut sk) = (c1, s1);
        let (mut h, mut dm, mut dv) = (1.0 / l as f64, 0.0, 0.0);
        for (k, ck_coef) in c.iter().enumerate() {
            let k = (k + 1) as f64;
            h += ck_coef * ck;
            dm += ck_coef * k * sk;
            dv += ck_coef * k * k * ck;
            (ck, sk) = (ck * c1 - sk * s1, sk * c1 + ck * s1);
        }
        if h > floor {
            accumulate(&mut sums, h, sigma * dm, -sigma * sigma * dv);
        }
    }
    sums
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quantizer::Quantizer;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The cells' sums by `erfc`, every copy of every cell within the
    /// window: the reference, computed another way than the table's rows.
    fn folded(bits: u8, t: f64, u: f64) -> [f64; 3] {
        let q = Quantizer::uniform_wrapped(bits, -PI, PI).unwrap();
        let width = 2.0 * PI / q.cells() as f64;
        let sigma = 2.0 * PI * t;
        let v = sigma * sigma;
        let s = q.fisher_scalars_all_cells(-PI + u * width, v);
        [s.gg * v, s.gr * 2.0 * v * sigma, s.rr * 4.0 * v * v]
    }

    #[test]
    fn the_series_equals_the_folded_cells() {
        for (bits, t, u) in [
            (8, 0.06, 0.3),
            (4, 0.3, 0.9),
            (2, 0.7, 0.0),
            (10, 0.11, 0.5),
        ] {
            let (a, b) = (fourier_sums(1 << bits, t, u), folded(bits, t, u));
            for k in 0..3 {
                assert!(
                    (a[k] - b[k]).abs() < 1e-11,
                    "{bits} {t} {u}: {a:?} vs {b:?}"
                );
            }
        }
    }

    #[test]
    fn table_matches_the_folded_cells() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut worst: f64 = 0.0;
        for bits in [1u8, 3, 5, 6, 7, 8, 11] {
            let l = 1u32 << bits;
            // Where the table is read: past the window's span and σ ≥ Δ.
            let from = T_WRAP.max(1.0 / l as f64);
            for _ in 0..150 {
                let t = rng.random_range(from..1.4);
                let u = rng.random::<f64>();
                let (a, b) = (table(l).lookup(t, u), folded(bits, t, u));
                // Against the unquantized (1, 0, 2).
                for (k, scale) in [1.0, 1.0, 2.0].into_iter().enumerate() {
                    worst = worst.max((a[k] - b[k]).abs() / scale);
                }
            }
        }
        assert!(worst < 1e-9, "worst error {worst:e}");
    }

    #[test]
    fn the_sums_vanish_where_the_table_stops() {
        for bits in [1u8, 8] {
            let s = fourier_sums(1 << bits, T_VANISH, 0.2);
            assert!(s.iter().all(|v| v.abs() < 1e-18), "{s:?}");
        }
        // And they are far from nothing where it starts.
        assert!(table(256).lookup(T_WRAP, 0.3)[0] > 0.99);
    }
}
