//! The sensitivities of a cell's probability and the Fisher scalars of one
//! quantized observation: exact, over all cells, off the tables, or
//! censored.

use super::cells::{Quantizer, UniformCells};
use super::table_reads::Spread;
use crate::cell_sums::{accumulate, accumulate_between, scalars_from_sums, window_sums, Edge};
use crate::cell_sums::{FisherScalars, WINDOW_SIGMAS};
use crate::normal::{self, interval_mass};
use crate::QuantizerError;

/// `(h, ∂h/∂g, ∂h/∂R)` of one cell at one `(g, R)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellSensitivity {
    pub probability: f64,
    pub d_mean: f64,
    pub d_variance: f64,
}

impl Quantizer {
    /// `(h_i, ∂h_i/∂g, ∂h_i/∂R)`, with `∂h/∂g = (φ(a) − φ(b))/σ` and
    /// `∂h/∂R = (aφ(a) − bφ(b))/(2R)`.
    pub fn sensitivity(&self, index: u32, mean: f64, variance: f64) -> CellSensitivity {
        let sigma = variance.sqrt();
        let mut s = CellSensitivity {
            probability: 0.0,
            d_mean: 0.0,
            d_variance: 0.0,
        };
        for j in self.copies(index as usize, mean, sigma) {
            let (a, b) = self.standardized(index as usize, j as f64, mean, sigma);
            s.probability += interval_mass(a, b);
            s.d_mean += (normal::pdf(a) - normal::pdf(b)) / sigma;
            s.d_variance += (normal::x_pdf(a) - normal::x_pdf(b)) / (2.0 * variance);
        }
        s
    }

    /// `(∂ ln h_i/∂g, ∂ ln h_i/∂R)`: [`sensitivity`](Self::sensitivity)
    /// divided by `h_i`, with each `φ/h` taken as `exp(ln φ − ln h)` so that
    /// it stays finite where `h_i` and `φ` both underflow (a particle tens of
    /// σ from the received cell), where `∂h/h` would be `0/0`.
    pub fn ln_sensitivity(&self, index: u32, mean: f64, variance: f64) -> (f64, f64) {
        let ln_h = self.ln_probability(index, mean, variance);
        if !ln_h.is_finite() {
            return (0.0, 0.0);
        }
        let sigma = variance.sqrt();
        // φ(z)/h and zφ(z)/h; an infinite edge contributes nothing.
        let ratio = |z: f64| {
            if z.is_finite() {
                let r = (-0.5 * z * z - 0.5 * (2.0 * std::f64::consts::PI).ln() - ln_h).exp();
                (r, z * r)
            } else {
                (0.0, 0.0)
            }
        };
        let (mut d_mean, mut d_variance) = (0.0, 0.0);
        for j in self.copies(index as usize, mean, sigma) {
            let (a, b) = self.standardized(index as usize, j as f64, mean, sigma);
            let ((pa, xa), (pb, xb)) = (ratio(a), ratio(b));
            d_mean += (pa - pb) / sigma;
            d_variance += (xa - xb) / (2.0 * variance);
        }
        (d_mean, d_variance)
    }

    /// Fisher scalars of one observation with mean g and variance R. For a
    /// uniform quantizer whose outer cells are out of the window this reads
    /// the shared table ([`crate::fisher_table`]); otherwise it sums the cells
    /// within [`WINDOW_SIGMAS`] of the mean. Allocation-free: this is the
    /// per-particle hot path.
    #[inline]
    pub fn fisher_scalars(&self, mean: f64, variance: f64) -> FisherScalars {
        self.uniform
            .as_ref()
            .and_then(|cells| {
                self.tabled_fisher_scalars(cells, mean, &Spread::new(variance, cells))
            })
            .unwrap_or_else(|| self.fisher_scalars_exact(mean, variance))
    }

    /// The table's Fisher scalars, if the cells within the window are all
    /// of the uniform grid (not an unbounded outer cell, nor a wrapped
    /// cell met twice).
    #[inline]
    pub(super) fn tabled_fisher_scalars(
        &self,
        cells: &UniformCells,
        mean: f64,
        spread: &Spread,
    ) -> Option<FisherScalars> {
        if !Self::window_tabled(cells, mean, spread.sigma) {
            return Self::wrapped_read(cells, mean, spread);
        }
        Self::fisher_read(cells, mean, spread)
    }

    /// The scalars of a wrapped quantizer whose window spans the circle,
    /// off its own table ([`crate::wrapped_table`]), where σ is a cell or
    /// more; `None` otherwise (an unwrapped quantizer, or σ narrower than
    /// a cell, whose window holds fewer than 18 cells to sum exactly).
    #[inline]
    pub(super) fn wrapped_read(
        cells: &UniformCells,
        mean: f64,
        spread: &Spread,
    ) -> Option<FisherScalars> {
        if !cells.wrapped || spread.s < 1.0 {
            return None;
        }
        let (t, u) = (
            spread.sigma * cells.per_period,
            (mean - cells.lo) * cells.per_width,
        );
        let sums = crate::wrapped_table::table(cells.cells).lookup(t, u);
        Some(Self::scalars_of(sums, spread))
    }

    /// `scalars_from_sums`, by multiplications.
    #[inline(always)]
    fn scalars_of(sums: [f64; 3], spread: &Spread) -> FisherScalars {
        let per_variance = spread.per_sigma * spread.per_sigma;
        FisherScalars {
            gg: sums[0] * per_variance,
            gr: sums[1] * (0.5 * per_variance * spread.per_sigma),
            rr: sums[2] * (0.25 * per_variance * per_variance),
        }
    }

    /// Whether the cells within [`WINDOW_SIGMAS`] of the mean are all of the
    /// uniform grid (not an unbounded outer cell, nor a wrapped cell met
    /// twice): those the Fisher table serves.
    #[inline(always)]
    pub(super) fn window_tabled(cells: &UniformCells, mean: f64, sigma: f64) -> bool {
        let reach = WINDOW_SIGMAS * sigma;
        if cells.wrapped {
            2.0 * reach < cells.period
        } else {
            mean - reach >= cells.inner.0 && mean + reach <= cells.inner.1
        }
    }

    /// The Fisher table's scalars at the mean's place in its cell.
    #[inline(always)]
    pub(super) fn fisher_read(
        cells: &UniformCells,
        mean: f64,
        spread: &Spread,
    ) -> Option<FisherScalars> {
        let u = (mean - cells.lo) * cells.per_width;
        let sums = crate::fisher_table::table().lookup_at(u, spread.s, spread.rows.as_ref())?;
        Some(Self::scalars_of(sums, spread))
    }

    /// Fisher scalars summed exactly over the cells within [`WINDOW_SIGMAS`]
    /// of the mean.
    pub fn fisher_scalars_exact(&self, mean: f64, variance: f64) -> FisherScalars {
        let sigma = variance.sqrt();
        if self.wraps_round(sigma) {
            return self.fisher_scalars_all_cells(mean, variance);
        }
        let (first, last) = (
            self.unrolled_cell(mean - WINDOW_SIGMAS * sigma),
            self.unrolled_cell(mean + WINDOW_SIGMAS * sigma),
        );
        let sums = window_sums((first..=last + 1).map(|m| (self.unrolled_edge(m) - mean) / sigma));
        scalars_from_sums(sums, variance)
    }

    /// Fisher scalars summed over every cell (and, for a wrapped
    /// quantizer, each cell's copies within the window, or the copy
    /// either side). The reference that the window and the tables are
    /// tested against.
    pub fn fisher_scalars_all_cells(&self, mean: f64, variance: f64) -> FisherScalars {
        let sigma = variance.sqrt();
        let mut sums = [0.0; 3];
        for i in 0..self.cells() {
            let s = self.sensitivity(i as u32, mean, variance);
            // Back to the standardized α = φ(a) − φ(b), β = aφ(a) − bφ(b).
            accumulate(
                &mut sums,
                s.probability,
                s.d_mean * sigma,
                s.d_variance * 2.0 * variance,
            );
        }
        scalars_from_sums(sums, variance)
    }

    /// The edges of cell `index` (of its first period, for a wrapped
    /// quantizer).
    pub fn cell_edges(&self, index: u32) -> (f64, f64) {
        let i = index as usize;
        (self.edges[i], self.edges[i + 1])
    }

    /// Fisher scalars of a censored observation: the sensor stays silent
    /// when its raw value falls in `silent = (lo, hi)` (unrolled next to
    /// the mean, for a wrapped quantizer) and otherwise sends its cell. The
    /// outcomes are the silence and each cell's part outside the window (a
    /// cell that holds the whole window is one outcome of two pieces).
    ///
    /// Only the cells the window touches differ from the uncensored
    /// observation, so this takes [`fisher_scalars`](Self::fisher_scalars)
    /// (off the table, where it serves) and replaces those cells' terms:
    /// a few cells rather than every cell within [`WINDOW_SIGMAS`].
    pub fn censored_fisher_scalars(
        &self,
        mean: f64,
        variance: f64,
        silent: (f64, f64),
    ) -> FisherScalars {
        let base = self.fisher_scalars(mean, variance);
        let sigma = variance.sqrt();
        let reach = if self.wrapped {
            // One period at most: a wider window would meet a cell twice.
            (WINDOW_SIGMAS * sigma).min(0.5 * self.period() * (1.0 - 1e-12))
        } else {
            WINDOW_SIGMAS * sigma
        };
        let (lo, hi) = (silent.0.min(silent.1), silent.0.max(silent.1));
        let (from, to) = (lo.max(mean - reach), hi.min(mean + reach));
        if from >= to {
            // The window is where the value (almost) never falls.
            return base;
        }
        // Each edge's Φ and φ once: the cells' edges, and the window's.
        let edge = |z: f64| Edge::at((z - mean) / sigma);
        let (window_lo, window_hi) = (edge(lo), edge(hi));
        let (mut removed, mut added) = ([0.0; 3], [0.0; 3]);
        let (first, last) = (self.unrolled_cell(from), self.unrolled_cell(to));
        let mut lower = edge(self.unrolled_edge(first));
        for m in first..=last {
            let upper = edge(self.unrolled_edge(m + 1));
            accumulate_between(&mut removed, &lower, &upper);
            // The cell's part below the window and its part above it: one
            // outcome, its mass and derivatives the sums of the parts'.
            let mut outside = [0.0; 3];
            let below = (lower.t < window_lo.t).then(|| {
                let top = if upper.t < window_lo.t {
                    &upper
                } else {
                    &window_lo
                };
                (lower, *top)
            });
            let above = (upper.t > window_hi.t).then(|| {
                let bottom = if lower.t > window_hi.t {
                    &lower
                } else {
                    &window_hi
                };
                (*bottom, upper)
            });
            for (a, b) in below.into_iter().chain(above) {
                outside[0] += a.mass_to(&b);
                outside[1] += a.pdf - b.pdf;
                outside[2] += a.x_pdf - b.x_pdf;
            }
            accumulate(&mut added, outside[0], outside[1], outside[2]);
            lower = upper;
        }
        accumulate_between(&mut added, &window_lo, &window_hi);
        let change = scalars_from_sums(
            [
                added[0] - removed[0],
                added[1] - removed[1],
                added[2] - removed[2],
            ],
            variance,
        );
        FisherScalars {
            gg: base.gg + change.gg,
            gr: base.gr + change.gr,
            rr: base.rr + change.rr,
        }
    }

    /// Index of the cell containing z, counting cells of the periodic
    /// extension for a wrapped quantizer (cell m is cell `m mod L` shifted by
    /// `⌊m/L⌋` periods).
    pub(super) fn unrolled_cell(&self, z: f64) -> i64 {
        let l = self.cells();
        if !self.wrapped {
            return self.edges[1..l].partition_point(|e| *e <= z) as i64;
        }
        let lo = self.edges[0];
        let k = ((z - lo) / self.period()).floor();
        let within = z - k * self.period();
        let i = self.edges[1..l].partition_point(|e| *e <= within);
        k as i64 * l as i64 + i as i64
    }

    /// Lower edge of unrolled cell m (so `unrolled_edge(m + 1)` is its upper).
    #[inline]
    pub(super) fn unrolled_edge(&self, m: i64) -> f64 {
        if !self.wrapped {
            return self.edges[m as usize];
        }
        let l = self.cells() as i64;
        self.edges[m.rem_euclid(l) as usize] + m.div_euclid(l) as f64 * self.period()
    }
}

/// Fisher information of one quantized observation of a scalar
/// `Z ~ N(mean, σ²)` about its mean: `Σ_i (φ(a_i) − φ(b_i))² / (σ² h_i)`.
///
/// Returns NaN for invalid input (thresholds not finite and strictly
/// increasing, σ not positive), as f64 functions do for points outside their
/// domain; [`try_quantized_fisher_information`] says what was wrong instead.
pub fn quantized_fisher_information(thresholds: &[f64], mean: f64, sigma: f64) -> f64 {
    try_quantized_fisher_information(thresholds, mean, sigma).unwrap_or(f64::NAN)
}

/// [`quantized_fisher_information`] with the reason for invalid input.
pub fn try_quantized_fisher_information(
    thresholds: &[f64],
    mean: f64,
    sigma: f64,
) -> Result<f64, QuantizerError> {
    if !(sigma.is_finite() && sigma > 0.0) {
        return Err(QuantizerError::BadSigma { sigma });
    }
    let q = Quantizer::from_thresholds(thresholds)?;
    Ok(q.fisher_scalars_all_cells(mean, sigma * sigma).gg)
}
