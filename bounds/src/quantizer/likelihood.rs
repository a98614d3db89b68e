//! A cell's probability `h_i` and its logarithm, exact or off the tables,
//! one observation at a time or a batch of particles in lanes.

use super::cells::{Quantizer, UniformCells};
use super::table_reads::{Spread, TableReads};
use crate::batch::CHUNK;
use crate::cell_sums::{FisherScalars, ScalarBatch};
use crate::normal::{interval_mass, ln_interval_mass, ln_sum_exp};

impl Quantizer {
    /// `h_i = P(Y = i)` for `Z ~ N(mean, variance)`.
    pub fn probability(&self, index: u32, mean: f64, variance: f64) -> f64 {
        let sigma = variance.sqrt();
        self.copies(index as usize, mean, sigma)
            .map(|j| {
                let (a, b) = self.standardized(index as usize, j as f64, mean, sigma);
                interval_mass(a, b)
            })
            .sum()
    }

    /// `ln h_i`, finite even when `h_i` is far below f64's smallest number.
    /// This is what particle weights use.
    pub fn ln_probability(&self, index: u32, mean: f64, variance: f64) -> f64 {
        let sigma = variance.sqrt();
        if !self.wrapped {
            let (a, b) = self.standardized(index as usize, 0.0, mean, sigma);
            return ln_interval_mass(a, b);
        }
        if self.wraps_round(sigma) {
            // Every copy within the window counts, and none underflows:
            // each cell holds at least the mass 9 σ out.
            return self.probability(index, mean, variance).ln();
        }
        // Of the three shifted copies of the cell, the nearest to the mean
        // dominates; a copy whose nearest edge is 10σ farther contributes
        // below e⁻⁵⁰ of it, so only copies within that margin are summed.
        let distance = |j: f64| {
            let (a, b) = self.standardized(index as usize, j, mean, sigma);
            if a <= 0.0 && b >= 0.0 {
                0.0
            } else {
                a.abs().min(b.abs())
            }
        };
        let d = [distance(-1.0), distance(0.0), distance(1.0)];
        let nearest = d[0].min(d[1]).min(d[2]);
        let mut terms = [f64::NEG_INFINITY; 3];
        let mut summed = 0;
        for (k, j) in [-1.0, 0.0, 1.0].into_iter().enumerate() {
            if d[k] <= nearest + 10.0 {
                let (a, b) = self.standardized(index as usize, j, mean, sigma);
                terms[k] = ln_interval_mass(a, b);
                summed += 1;
            }
        }
        if summed == 1 {
            // The usual case (cells much narrower than the circle): the sum
            // is this one term, without three exps and a log to say so.
            return terms.into_iter().fold(f64::NEG_INFINITY, f64::max);
        }
        ln_sum_exp(&terms)
    }

    /// [`ln_probability`](Self::ln_probability) to within 1e-8, read off
    /// [`crate::mass_table`] for a cell of a uniform quantizer whose
    /// other copies (wrapped) are out of reach, within 12 σ of the mean;
    /// the exact value elsewhere. The particle filters' likelihood: a
    /// lookup instead of two `erfc` and a logarithm.
    pub fn ln_probability_interpolated(&self, index: u32, mean: f64, variance: f64) -> f64 {
        self.tabled_ln_probability(index, mean, variance)
            .unwrap_or_else(|| self.ln_probability(index, mean, variance))
    }

    #[inline]
    pub(super) fn tabled_ln_probability(
        &self,
        index: u32,
        mean: f64,
        variance: f64,
    ) -> Option<f64> {
        let cells = self.uniform.as_ref()?;
        self.tabled_ln_probability_at(cells, index, mean, &Spread::new(variance, cells))
    }

    #[inline]
    pub(super) fn tabled_ln_probability_at(
        &self,
        cells: &UniformCells,
        index: u32,
        mean: f64,
        spread: &Spread,
    ) -> Option<f64> {
        let v =
            Self::mass_offset(cells, index, mean, spread.sigma, crate::floor)? * spread.per_sigma;
        let at = crate::mass_table::point(v)?;
        Some(crate::mass_table::table().read(&at, v, spread.rows.as_ref()?))
    }

    /// The mean's offset from cell `index`'s centre, as the likelihood
    /// table reads it; `None` for a cell the table does not serve. `floor`
    /// is ⌊·⌋, exactly: [`crate::floor`], or in a vectorised loop
    /// `f64::floor` (a rounding instruction there, a library call
    /// elsewhere).
    #[inline(always)]
    pub(super) fn mass_offset(
        cells: &UniformCells,
        index: u32,
        mean: f64,
        sigma: f64,
        floor: impl Fn(f64) -> f64,
    ) -> Option<f64> {
        use crate::mass_table::V_MAX;
        let centre = cells.lo + (index as f64 + 0.5) * cells.width;
        if cells.wrapped {
            // The nearest copy, whose edges are within V_MAX σ of the mean
            // when the table serves it. The others' edges are half a period
            // less half a cell away at least, and must be 10 σ farther than
            // the nearest, as `ln_probability` requires to sum one term.
            let period = cells.period;
            if 0.5 * (period - cells.width) < (V_MAX + 10.0) * sigma {
                return None;
            }
            let d = mean - centre;
            Some(d - floor(d * cells.per_period + 0.5) * period)
        } else if index == 0 || index + 1 >= cells.cells {
            // The outer cells are unbounded: not a cell of the table.
            None
        } else {
            Some(mean - centre)
        }
    }

    /// The uniform cells, if the tables serve this quantizer and a batch of
    /// `n` lanes is long enough to pay for finding their reads in a pass.
    #[inline(always)]
    pub(super) fn batch_cells(&self, n: usize) -> Option<&UniformCells> {
        self.uniform.as_ref().filter(|_| n >= CHUNK / 4)
    }

    /// [`ln_probability_interpolated`](Self::ln_probability_interpolated)
    /// of cell `index` and [`fisher_scalars`](Self::fisher_scalars), equal
    /// to the two called apart, with what they share (σ, 1/σ and the rows
    /// of [`crate::width_axis`]) found once: the local filter's first stage
    /// needs both for every particle and sensor.
    #[inline]
    pub fn ln_probability_and_fisher(
        &self,
        index: u32,
        mean: f64,
        variance: f64,
    ) -> (f64, FisherScalars) {
        let Some(cells) = self.uniform.as_ref() else {
            return (
                self.ln_probability(index, mean, variance),
                self.fisher_scalars_exact(mean, variance),
            );
        };
        let spread = Spread::new(variance, cells);
        let ln_h = self
            .tabled_ln_probability_at(cells, index, mean, &spread)
            .unwrap_or_else(|| self.ln_probability(index, mean, variance));
        let fisher = self
            .tabled_fisher_scalars(cells, mean, &spread)
            .unwrap_or_else(|| self.fisher_scalars_exact(mean, variance));
        (ln_h, fisher)
    }

    /// [`ln_probability_and_fisher`](Self::ln_probability_and_fisher) of
    /// cell `index` at a batch of means and variances (lanes from `n` on
    /// are padding, and ignored), equal to it lane by lane, bit for bit:
    /// what both tables are read at is found for every lane in one pass the
    /// compiler vectorises ([`crate::batch`]), and the tables are read lane
    /// by lane after it. A lane the tables do not serve takes the exact
    /// value, as the scalar call does; so does every lane of a batch too
    /// short to pay for the pass, or of a quantizer whose cells are uneven.
    /// `reads` is the pass's scratch.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // a kernel's inputs, outputs and scratch
    pub fn ln_probability_and_fisher_batch(
        &self,
        index: u32,
        mean: &[f64; CHUNK],
        variance: &[f64; CHUNK],
        n: usize,
        ln_h: &mut [f64; CHUNK],
        out: &mut ScalarBatch,
        reads: &mut TableReads,
    ) {
        let Some(cells) = self.batch_cells(n) else {
            for i in 0..n {
                let (l, f) = self.ln_probability_and_fisher(index, mean[i], variance[i]);
                ln_h[i] = l;
                out.set(i, f);
            }
            return;
        };
        reads.find::<true>(cells, index, mean, variance);
        for (i, l) in ln_h[..n].iter_mut().enumerate() {
            // Each lane's Spread is rebuilt once, for both tables.
            let spread = reads.spread(i);
            *l = self.ln_probability_of_lane(index, reads, &spread, i, mean, variance);
            out.set(
                i,
                self.fisher_of_lane(cells, reads, &spread, i, mean, variance),
            );
        }
    }

    /// [`ln_probability_interpolated`](Self::ln_probability_interpolated)
    /// of cell `index` at a batch of means and variances, as
    /// [`ln_probability_and_fisher_batch`](Self::ln_probability_and_fisher_batch)
    /// gives it: equal to the scalar call lane by lane, bit for bit.
    #[inline(always)]
    pub fn ln_probability_batch(
        &self,
        index: u32,
        mean: &[f64; CHUNK],
        variance: &[f64; CHUNK],
        n: usize,
        ln_h: &mut [f64; CHUNK],
        reads: &mut TableReads,
    ) {
        let Some(cells) = self.batch_cells(n) else {
            for i in 0..n {
                ln_h[i] = self.ln_probability_interpolated(index, mean[i], variance[i]);
            }
            return;
        };
        reads.find::<true>(cells, index, mean, variance);
        for (i, l) in ln_h[..n].iter_mut().enumerate() {
            *l = self.ln_probability_of_lane(index, reads, &reads.spread(i), i, mean, variance);
        }
    }

    /// Lane `i`'s `ln h` from the likelihood table if it serves the lane,
    /// exactly otherwise.
    #[inline(always)]
    pub(super) fn ln_probability_of_lane(
        &self,
        index: u32,
        reads: &TableReads,
        spread: &Spread,
        i: usize,
        mean: &[f64; CHUNK],
        variance: &[f64; CHUNK],
    ) -> f64 {
        match (reads.mass_ok[i], &spread.rows) {
            (true, Some(rows)) => {
                crate::mass_table::table().read(&reads.mass_point(i), reads.v[i], rows)
            }
            _ => self.ln_probability(index, mean[i], variance[i]),
        }
    }

    /// [`fisher_scalars`](Self::fisher_scalars) at a batch of means and
    /// variances, as [`ln_probability_and_fisher_batch`](Self::ln_probability_and_fisher_batch)
    /// gives them: equal to the scalar call lane by lane, bit for bit.
    #[inline(always)]
    pub fn fisher_scalars_batch(
        &self,
        mean: &[f64; CHUNK],
        variance: &[f64; CHUNK],
        n: usize,
        out: &mut ScalarBatch,
        reads: &mut TableReads,
    ) {
        let Some(cells) = self.batch_cells(n) else {
            for i in 0..n {
                out.set(i, self.fisher_scalars(mean[i], variance[i]));
            }
            return;
        };
        reads.find::<false>(cells, 0, mean, variance);
        for i in 0..n {
            let spread = reads.spread(i);
            out.set(
                i,
                self.fisher_of_lane(cells, reads, &spread, i, mean, variance),
            );
        }
    }

    /// Lane `i`'s Fisher scalars from the table if it serves the lane,
    /// exactly otherwise.
    #[inline(always)]
    pub(super) fn fisher_of_lane(
        &self,
        cells: &UniformCells,
        reads: &TableReads,
        spread: &Spread,
        i: usize,
        mean: &[f64; CHUNK],
        variance: &[f64; CHUNK],
    ) -> FisherScalars {
        let tabled = if reads.window_tabled[i] {
            Self::fisher_read(cells, mean[i], spread)
        } else {
            Self::wrapped_read(cells, mean[i], spread)
        };
        tabled.unwrap_or_else(|| self.fisher_scalars_exact(mean[i], variance[i]))
    }
}
