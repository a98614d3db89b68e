//! The sensor's quantizer: cells, encoding to bytes, cell probabilities
//! `h_i(x)` and their sensitivities, and the per-observation Fisher scalars.

use crate::batch::CHUNK;
use crate::cell_sums::{accumulate, accumulate_between, scalars_from_sums, window_sums, Edge};
pub use crate::cell_sums::{FisherScalars, ScalarBatch, WINDOW_SIGMAS};
use crate::normal::{self, interval_mass, ln_interval_mass, ln_sum_exp};
use crate::width_axis::{self, Stencil};
use crate::QuantizerError;

/// Largest supported bit depth (2^16 cells): the most any experiment sweeps
/// (the bit-depth paper goes to 16), and the one limit the scenario checks against.
pub const MAX_BITS: u8 = 16;

/// An N_L-bit quantizer with cell edges `e_0 < e_1 < … < e_L`.
///
/// Unwrapped quantizers have `e_0 = −∞`, `e_L = +∞`. Wrapped ones (bearings)
/// have finite `e_0 = lo`, `e_L = hi`, and a cell's probability adds the
/// Gaussian mass of the cell shifted by ±(hi − lo).
#[derive(Debug, Clone, PartialEq)]
pub struct Quantizer {
    bits: u8,
    edges: Vec<f64>,
    wrapped: bool,
    /// The cell grid of a uniform quantizer, for the tables.
    uniform: Option<UniformCells>,
}

/// Equal cells from `lo`, with the reciprocals the per-particle lookups
/// multiply by (a division is a long wait on their critical chain).
#[derive(Debug, Clone, Copy, PartialEq)]
struct UniformCells {
    lo: f64,
    width: f64,
    per_width: f64,
    /// `1 / (hi − lo)`, for wrapping.
    per_period: f64,
    /// What the tables' lookups ask of the quantizer, copied here so that
    /// a loop over particles reads plain fields (an index into `edges` is
    /// a bounds check, and a branch that stops a loop vectorising):
    /// whether it wraps, `e_L − e_0`, `e_1` and `e_{L−1}`, and L.
    wrapped: bool,
    period: f64,
    inner: (f64, f64),
    cells: u32,
}

impl UniformCells {
    /// The grid of `edges` (`e_0 = lo`, `e_L = hi` unless they were made
    /// unbounded).
    fn new(lo: f64, hi: f64, edges: &[f64], wrapped: bool) -> Self {
        let cells = edges.len() - 1;
        let width = (hi - lo) / cells as f64;
        Self {
            lo,
            width,
            per_width: 1.0 / width,
            per_period: 1.0 / (hi - lo),
            wrapped,
            period: edges[cells] - edges[0],
            inner: (edges[1], edges[cells - 1]),
            cells: cells as u32,
        }
    }
}

/// What both tables are read at, for one variance: σ, 1/σ, `s = σ/Δ` and
/// the table rows of its half-width `Δ/(2σ)`, found once when a particle
/// needs both lookups.
#[derive(Debug, Clone, Copy)]
struct Spread {
    sigma: f64,
    per_sigma: f64,
    s: f64,
    rows: Option<Stencil>,
}

impl Spread {
    #[inline(always)]
    fn new(variance: f64, cells: &UniformCells) -> Self {
        let sigma = variance.sqrt();
        let per_sigma = 1.0 / sigma;
        Self {
            sigma,
            per_sigma,
            s: sigma * cells.per_width,
            rows: width_axis::stencil(Self::half_width(cells, per_sigma)),
        }
    }

    /// The cell's half-width in standard deviations, `w = Δ/(2σ)`: where
    /// the tables' rows are found ([`crate::width_axis`]).
    #[inline(always)]
    fn half_width(cells: &UniformCells, per_sigma: f64) -> f64 {
        0.5 * cells.width * per_sigma
    }
}

/// What the tables are read at, for a batch of means and variances, as
/// arrays: each lane's σ, 1/σ and σ/Δ, the rows over σ/Δ, and where the
/// likelihood table reads along v. Found in plain passes over every lane,
/// which vectorise. A caller keeps one across its batches, so that its
/// arrays are set up once.
pub struct TableReads {
    sigma: [f64; CHUNK],
    per_sigma: [f64; CHUNK],
    s: [f64; CHUNK],
    rows_ok: [bool; CHUNK],
    first: [usize; CHUNK],
    ws: [[f64; CHUNK]; 4],
    mass_ok: [bool; CHUNK],
    v: [f64; CHUNK],
    iv: [usize; CHUNK],
    wv: [[f64; CHUNK]; 4],
    window_tabled: [bool; CHUNK],
}

impl Default for TableReads {
    fn default() -> Self {
        Self {
            sigma: [0.0; CHUNK],
            per_sigma: [0.0; CHUNK],
            s: [0.0; CHUNK],
            rows_ok: [false; CHUNK],
            first: [0; CHUNK],
            ws: [[0.0; CHUNK]; 4],
            mass_ok: [false; CHUNK],
            v: [0.0; CHUNK],
            iv: [0; CHUNK],
            wv: [[0.0; CHUNK]; 4],
            window_tabled: [false; CHUNK],
        }
    }
}

impl TableReads {
    /// Fills every lane from the means and variances; the likelihood
    /// table's reads (of cell `index`) only `WITH_MASS`.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // lanes index several arrays at once
    fn find<const WITH_MASS: bool>(
        &mut self,
        cells: &UniformCells,
        index: u32,
        mean: &[f64; CHUNK],
        variance: &[f64; CHUNK],
    ) {
        let r = self;
        // Pass by pass, each a plain loop over the lanes, so that each
        // vectorises.
        for i in 0..CHUNK {
            let sigma = variance[i].sqrt();
            r.sigma[i] = sigma;
            r.per_sigma[i] = 1.0 / sigma;
            r.s[i] = sigma * cells.per_width;
            r.window_tabled[i] = Quantizer::window_tabled(cells, mean[i], sigma);
        }
        for i in 0..CHUNK {
            let (inside, rows) =
                width_axis::stencil_lane(Spread::half_width(cells, r.per_sigma[i]));
            r.rows_ok[i] = inside;
            r.first[i] = rows.first;
            for (a, w) in rows.weights.into_iter().enumerate() {
                r.ws[a][i] = w;
            }
        }
        if !WITH_MASS {
            return;
        }
        for i in 0..CHUNK {
            let offset = Quantizer::mass_offset(cells, index, mean[i], r.sigma[i], f64::floor);
            let v = offset.unwrap_or(0.0) * r.per_sigma[i];
            let (inside, point) = crate::mass_table::point_lane(v);
            r.mass_ok[i] = offset.is_some() && inside;
            r.v[i] = v;
            r.iv[i] = point.iv;
            for (a, w) in point.weights.into_iter().enumerate() {
                r.wv[a][i] = w;
            }
        }
    }

    /// Lane `i`'s [`Spread`], as `Spread::new` gave it.
    #[inline(always)]
    fn spread(&self, i: usize) -> Spread {
        Spread {
            sigma: self.sigma[i],
            per_sigma: self.per_sigma[i],
            s: self.s[i],
            rows: self.rows_ok[i].then(|| Stencil {
                first: self.first[i],
                weights: [self.ws[0][i], self.ws[1][i], self.ws[2][i], self.ws[3][i]],
            }),
        }
    }

    #[inline(always)]
    fn mass_point(&self, i: usize) -> crate::mass_table::Point {
        crate::mass_table::Point {
            iv: self.iv[i],
            weights: [self.wv[0][i], self.wv[1][i], self.wv[2][i], self.wv[3][i]],
        }
    }
}

/// `(h, ∂h/∂g, ∂h/∂R)` of one cell at one `(g, R)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellSensitivity {
    pub probability: f64,
    pub d_mean: f64,
    pub d_variance: f64,
}

impl Quantizer {
    /// `2^bits` cells; edges `e_i = lo + i (hi − lo)/L` for `0 < i < L`, outer
    /// cells unbounded.
    pub fn uniform(bits: u8, lo: f64, hi: f64) -> Result<Self, QuantizerError> {
        let edges = uniform_edges(bits, lo, hi)?;
        let l = edges.len() - 1;
        let mut edges = edges;
        edges[0] = f64::NEG_INFINITY;
        edges[l] = f64::INFINITY;
        Ok(Self {
            bits,
            uniform: Some(UniformCells::new(lo, hi, &edges, false)),
            edges,
            wrapped: false,
        })
    }

    /// `2^bits` equal cells covering `[lo, hi)` periodically (for angles:
    /// `lo = −π`, `hi = π`).
    pub fn uniform_wrapped(bits: u8, lo: f64, hi: f64) -> Result<Self, QuantizerError> {
        let edges = uniform_edges(bits, lo, hi)?;
        Ok(Self {
            bits,
            uniform: Some(UniformCells::new(lo, hi, &edges, true)),
            edges,
            wrapped: true,
        })
    }

    /// Cells separated by the given interior thresholds (strictly increasing,
    /// finite); `thresholds.len() + 1` cells.
    pub fn from_thresholds(thresholds: &[f64]) -> Result<Self, QuantizerError> {
        if thresholds.is_empty() {
            return Err(QuantizerError::NoThresholds);
        }
        for (i, t) in thresholds.iter().enumerate() {
            if !t.is_finite() {
                return Err(QuantizerError::NonFiniteThreshold { index: i });
            }
            if i > 0 && *t <= thresholds[i - 1] {
                return Err(QuantizerError::ThresholdsNotIncreasing { index: i });
            }
        }
        let cells = thresholds.len() + 1;
        let bits = usize::BITS - (cells - 1).leading_zeros();
        if bits > MAX_BITS as u32 {
            return Err(QuantizerError::BitsOutOfRange { bits: bits as u64 });
        }
        let mut edges = Vec::with_capacity(cells + 1);
        edges.push(f64::NEG_INFINITY);
        edges.extend_from_slice(thresholds);
        edges.push(f64::INFINITY);
        Ok(Self {
            bits: bits as u8,
            edges,
            wrapped: false,
            uniform: None,
        })
    }

    pub fn bits(&self) -> u8 {
        self.bits
    }

    pub fn cells(&self) -> usize {
        self.edges.len() - 1
    }

    pub fn is_wrapped(&self) -> bool {
        self.wrapped
    }

    /// Bytes of one encoded cell index: `ceil(N_L / 8)`.
    pub fn index_bytes(&self) -> usize {
        (self.bits as usize).div_ceil(8)
    }

    fn period(&self) -> f64 {
        self.edges[self.cells()] - self.edges[0]
    }

    /// The cell a value falls in (`e_i ≤ z < e_{i+1}`); wrapped quantizers
    /// first wrap z into `[lo, hi)`. NaN maps to cell 0.
    pub fn encode(&self, z: f64) -> u32 {
        let z = if self.wrapped {
            self.edges[0] + crate::modulo(z - self.edges[0], self.period())
        } else {
            z
        };
        let l = self.cells();
        let interior = &self.edges[1..l];
        interior.partition_point(|e| *e <= z) as u32
    }

    /// Writes a cell index as `ceil(N_L/8)` little-endian bytes.
    pub fn write_index(&self, index: u32, out: &mut Vec<u8>) {
        out.extend_from_slice(&index.to_le_bytes()[..self.index_bytes()]);
    }

    /// Reads a cell index written by [`write_index`](Self::write_index),
    /// rejecting a wrong length or an index past the last cell.
    pub fn read_index(&self, bytes: &[u8]) -> Result<u32, QuantizerError> {
        if bytes.len() != self.index_bytes() {
            return Err(QuantizerError::WrongLength {
                expected: self.index_bytes(),
                got: bytes.len(),
            });
        }
        let mut le = [0u8; 4];
        le[..bytes.len()].copy_from_slice(bytes);
        let index = u32::from_le_bytes(le);
        if index as usize >= self.cells() {
            return Err(QuantizerError::IndexOutOfRange {
                index,
                cells: self.cells(),
            });
        }
        Ok(index)
    }

    /// A value inside the cell (its midpoint, or its finite edge for an
    /// unbounded outer cell): what a node reads a cell as when it needs a number.
    pub fn representative(&self, index: u32) -> f64 {
        let (a, b) = (self.edges[index as usize], self.edges[index as usize + 1]);
        match (a.is_finite(), b.is_finite()) {
            (true, true) => 0.5 * (a + b),
            (false, true) => b,
            (true, false) => a,
            (false, false) => 0.0,
        }
    }

    /// Width of cell `index`; 0 for an unbounded end cell.
    pub fn cell_width(&self, index: u32) -> f64 {
        let w = self.edges[index as usize + 1] - self.edges[index as usize];
        if w.is_finite() {
            w
        } else {
            0.0
        }
    }

    /// Standardized edges of cell `index` shifted by `shift` periods.
    #[inline]
    fn standardized(&self, index: usize, shift: f64, mean: f64, sigma: f64) -> (f64, f64) {
        let p = shift * if self.wrapped { self.period() } else { 0.0 };
        (
            (self.edges[index] + p - mean) / sigma,
            (self.edges[index + 1] + p - mean) / sigma,
        )
    }

    fn shifts(&self) -> &'static [f64] {
        if self.wrapped {
            &[-1.0, 0.0, 1.0]
        } else {
            &[0.0]
        }
    }

    /// `h_i = P(Y = i)` for `Z ~ N(mean, variance)`.
    pub fn probability(&self, index: u32, mean: f64, variance: f64) -> f64 {
        let sigma = variance.sqrt();
        self.shifts()
            .iter()
            .map(|&j| {
                let (a, b) = self.standardized(index as usize, j, mean, sigma);
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
        for (k, &j) in self.shifts().iter().enumerate() {
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
    fn tabled_ln_probability(&self, index: u32, mean: f64, variance: f64) -> Option<f64> {
        let cells = self.uniform.as_ref()?;
        self.tabled_ln_probability_at(cells, index, mean, &Spread::new(variance, cells))
    }

    #[inline]
    fn tabled_ln_probability_at(
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
    fn mass_offset(
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
    fn batch_cells(&self, n: usize) -> Option<&UniformCells> {
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
    fn ln_probability_of_lane(
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
    fn fisher_of_lane(
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
            None
        };
        tabled.unwrap_or_else(|| self.fisher_scalars_exact(mean[i], variance[i]))
    }

    /// `(h_i, ∂h_i/∂g, ∂h_i/∂R)`, with `∂h/∂g = (φ(a) − φ(b))/σ` and
    /// `∂h/∂R = (aφ(a) − bφ(b))/(2R)`.
    pub fn sensitivity(&self, index: u32, mean: f64, variance: f64) -> CellSensitivity {
        let sigma = variance.sqrt();
        let mut s = CellSensitivity {
            probability: 0.0,
            d_mean: 0.0,
            d_variance: 0.0,
        };
        for &j in self.shifts() {
            let (a, b) = self.standardized(index as usize, j, mean, sigma);
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
        for &j in self.shifts() {
            let (a, b) = self.standardized(index as usize, j, mean, sigma);
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
    fn tabled_fisher_scalars(
        &self,
        cells: &UniformCells,
        mean: f64,
        spread: &Spread,
    ) -> Option<FisherScalars> {
        if !Self::window_tabled(cells, mean, spread.sigma) {
            return None;
        }
        Self::fisher_read(cells, mean, spread)
    }

    /// Whether the cells within [`WINDOW_SIGMAS`] of the mean are all of the
    /// uniform grid (not an unbounded outer cell, nor a wrapped cell met
    /// twice): those the Fisher table serves.
    #[inline(always)]
    fn window_tabled(cells: &UniformCells, mean: f64, sigma: f64) -> bool {
        let reach = WINDOW_SIGMAS * sigma;
        if cells.wrapped {
            2.0 * reach < cells.period
        } else {
            mean - reach >= cells.inner.0 && mean + reach <= cells.inner.1
        }
    }

    /// The Fisher table's scalars at the mean's place in its cell.
    #[inline(always)]
    fn fisher_read(cells: &UniformCells, mean: f64, spread: &Spread) -> Option<FisherScalars> {
        let u = (mean - cells.lo) * cells.per_width;
        let sums = crate::fisher_table::table().lookup_at(u, spread.s, spread.rows.as_ref())?;
        // The same as `scalars_from_sums`, by multiplications.
        let per_variance = spread.per_sigma * spread.per_sigma;
        Some(FisherScalars {
            gg: sums[0] * per_variance,
            gr: sums[1] * (0.5 * per_variance * spread.per_sigma),
            rr: sums[2] * (0.25 * per_variance * per_variance),
        })
    }

    /// Fisher scalars summed exactly over the cells within [`WINDOW_SIGMAS`]
    /// of the mean.
    pub fn fisher_scalars_exact(&self, mean: f64, variance: f64) -> FisherScalars {
        let sigma = variance.sqrt();
        if self.wrapped && 2.0 * WINDOW_SIGMAS * sigma >= self.period() {
            return self.fisher_scalars_all_cells(mean, variance);
        }
        let (first, last) = (
            self.unrolled_cell(mean - WINDOW_SIGMAS * sigma),
            self.unrolled_cell(mean + WINDOW_SIGMAS * sigma),
        );
        let sums = window_sums((first..=last + 1).map(|m| (self.unrolled_edge(m) - mean) / sigma));
        scalars_from_sums(sums, variance)
    }

    /// Fisher scalars summed over every cell (and every wrap shift). The
    /// reference that the window is tested against.
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
    fn unrolled_cell(&self, z: f64) -> i64 {
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
    fn unrolled_edge(&self, m: i64) -> f64 {
        if !self.wrapped {
            return self.edges[m as usize];
        }
        let l = self.cells() as i64;
        self.edges[m.rem_euclid(l) as usize] + m.div_euclid(l) as f64 * self.period()
    }
}

fn uniform_edges(bits: u8, lo: f64, hi: f64) -> Result<Vec<f64>, QuantizerError> {
    if bits == 0 || bits > MAX_BITS {
        return Err(QuantizerError::BitsOutOfRange { bits: bits as u64 });
    }
    if !(lo.is_finite() && hi.is_finite() && lo < hi) {
        return Err(QuantizerError::EmptyRange { lo, hi });
    }
    let l = 1usize << bits;
    let step = (hi - lo) / l as f64;
    let mut edges: Vec<f64> = (0..=l).map(|i| lo + i as f64 * step).collect();
    edges[l] = hi;
    Ok(edges)
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn batch_avx2(
        q: &Quantizer,
        index: u32,
        mean: &[f64; CHUNK],
        variance: &[f64; CHUNK],
        n: usize,
        ln_h: &mut [f64; CHUNK],
        out: &mut ScalarBatch,
        reads: &mut TableReads,
    ) {
        q.ln_probability_and_fisher_batch(index, mean, variance, n, ln_h, out, reads)
    }

    /// The batch is the scalar call lane by lane, bit for bit, vectorised
    /// or not: wrapped and unwrapped, uniform and uneven cells, the inner
    /// and outer cells, σ/Δ from 0.05 to 200 (below, across and above
    /// both tables' axes), means from the cell's centre to 40 σ away, and
    /// batches long and short.
    #[test]
    fn the_batch_is_the_scalar_call_bit_for_bit() {
        let quantizers = [
            Quantizer::uniform_wrapped(8, -PI, PI).unwrap(),
            Quantizer::uniform_wrapped(3, -PI, PI).unwrap(),
            Quantizer::uniform_wrapped(12, -PI, PI).unwrap(),
            Quantizer::uniform(8, -100.0, 0.0).unwrap(),
            Quantizer::uniform(4, -3.0, 3.0).unwrap(),
            Quantizer::from_thresholds(&[-1.0, 0.0, 0.5, 2.0]).unwrap(),
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut reads = TableReads::default();
        let mut compared = 0;
        for q in &quantizers {
            let last = q.cells() as u32 - 1;
            for index in [0, 1, last / 2, last - 1, last] {
                let centre = q.representative(index);
                let width = q.cell_width(last / 2).min(1.0);
                for n in [CHUNK, 40, CHUNK / 4, 5] {
                    let (mut mean, mut variance) = ([0.0; CHUNK], [0.0; CHUNK]);
                    for i in 0..CHUNK {
                        let sigma = width * 10f64.powf(rng.random_range(-1.3..2.3));
                        mean[i] = centre + sigma * rng.random_range(-40.0..40.0);
                        variance[i] = sigma * sigma;
                    }
                    let mut plain = ([0.0; CHUNK], ScalarBatch::default());
                    q.ln_probability_and_fisher_batch(
                        index,
                        &mean,
                        &variance,
                        n,
                        &mut plain.0,
                        &mut plain.1,
                        &mut reads,
                    );
                    let mut fisher_only = ScalarBatch::default();
                    q.fisher_scalars_batch(&mean, &variance, n, &mut fisher_only, &mut reads);
                    let mut likelihood_only = [0.0; CHUNK];
                    q.ln_probability_batch(
                        index,
                        &mean,
                        &variance,
                        n,
                        &mut likelihood_only,
                        &mut reads,
                    );
                    let mut wide = ([0.0; CHUNK], ScalarBatch::default());
                    if crate::batch::has_avx2() {
                        // SAFETY: the CPU has AVX2.
                        unsafe {
                            batch_avx2(
                                q,
                                index,
                                &mean,
                                &variance,
                                n,
                                &mut wide.0,
                                &mut wide.1,
                                &mut reads,
                            )
                        };
                    } else {
                        wide = plain;
                    }
                    for i in 0..n {
                        let (ln_h, f) = q.ln_probability_and_fisher(index, mean[i], variance[i]);
                        assert_eq!(f, q.fisher_scalars(mean[i], variance[i]));
                        assert_eq!(
                            likelihood_only[i].to_bits(),
                            q.ln_probability_interpolated(index, mean[i], variance[i])
                                .to_bits()
                        );
                        assert_eq!(ln_h.to_bits(), likelihood_only[i].to_bits());
                        let with_fisher_only = (ln_h, &fisher_only);
                        for (l, out) in [
                            (plain.0[i], &plain.1),
                            (wide.0[i], &wide.1),
                            with_fisher_only,
                        ] {
                            let same = |a: f64, b: f64| a.to_bits() == b.to_bits();
                            assert!(
                                same(l, ln_h)
                                    && same(out.gg[i], f.gg)
                                    && same(out.gr[i], f.gr)
                                    && same(out.rr[i], f.rr),
                                "cell {index}, g {}, R {}: {l} {:?} vs {ln_h} {f:?}",
                                mean[i],
                                variance[i],
                                (out.gg[i], out.gr[i], out.rr[i])
                            );
                        }
                        compared += 1;
                    }
                }
            }
        }
        assert!(compared > 3000);
    }

    #[test]
    fn one_threshold_at_the_mean_gives_two_over_pi_sigma_squared() {
        for sigma in [0.1, 1.0, 7.0] {
            let j = quantized_fisher_information(&[3.0], 3.0, sigma);
            let expected = 2.0 / (PI * sigma * sigma);
            assert!((j / expected - 1.0).abs() < 1e-13, "{j} vs {expected}");
        }
    }

    #[test]
    fn information_grows_with_bits_towards_the_raw_value() {
        let sigma = 2.0;
        let raw = 1.0 / (sigma * sigma);
        let mut previous = 0.0;
        for bits in 1..=12u8 {
            let q = Quantizer::uniform(bits, -6.0 * sigma, 6.0 * sigma).unwrap();
            // Mean off-centre so that it is not special for any bit depth.
            let j = q.fisher_scalars(0.37, sigma * sigma).gg;
            assert!(j > previous, "{bits} bits: {j} <= {previous}");
            assert!(j <= raw * (1.0 + 1e-12), "{bits} bits exceeds raw: {j}");
            previous = j;
        }
        assert!(previous / raw > 0.999, "12 bits: {}", previous / raw);
    }

    #[test]
    fn cell_probabilities_sum_to_one() {
        for bits in 1..=16u8 {
            let q = Quantizer::uniform(bits, -3.0, 3.0).unwrap();
            let w = Quantizer::uniform_wrapped(bits, -PI, PI).unwrap();
            for (mean, var) in [(0.3, 1.0), (-2.9, 0.01), (5.0, 4.0)] {
                let total: f64 = (0..q.cells() as u32)
                    .map(|i| q.probability(i, mean, var))
                    .sum();
                assert!((total - 1.0).abs() < 1e-12, "{bits} bits, {mean}: {total}");
            }
            for (mean, var) in [(0.3, 0.01), (3.1, 0.05), (-3.1, 0.3)] {
                let total: f64 = (0..w.cells() as u32)
                    .map(|i| w.probability(i, mean, var))
                    .sum();
                assert!(
                    (total - 1.0).abs() < 1e-12,
                    "wrapped {bits} bits, {mean}: {total}"
                );
            }
        }
    }

    #[test]
    fn ln_probability_is_finite_thirty_sigma_out() {
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let sigma: f64 = 0.02;
        let far = 30.0 * sigma;
        let cell = q.encode(far);
        let lp = q.ln_probability(cell, 0.0, sigma * sigma);
        assert!(lp.is_finite(), "{lp}");
        // The cell's lower edge a (in σ) dominates: h ≈ Q(a) ≈ φ(a)/a · (1 − 1/a²).
        let width = 2.0 * PI / 256.0;
        let a = (-PI + cell as f64 * width) / sigma;
        assert!(a > 28.0 && a < 31.0, "{a}");
        let leading = -0.5 * a * a - (a * (2.0 * PI).sqrt()).ln() - 1.0 / (a * a);
        assert!((lp - leading).abs() < 1e-5, "{lp} vs {leading}");
        // And at 100σ, where h itself underflows to zero.
        let q = Quantizer::uniform(8, -200.0, 200.0).unwrap();
        let lp = q.ln_probability(q.encode(100.0), 0.0, 1.0);
        assert!(lp.is_finite() && lp < -4900.0, "{lp}");
        assert_eq!(q.probability(q.encode(100.0), 0.0, 1.0), 0.0);
    }

    /// The interpolated log-probability is the exact one to 1e-8, wrapped
    /// or not, near the wrap and at the outer cells, at bit depths whose
    /// σ/Δ fall below, in and above the table.
    #[test]
    fn interpolated_ln_probability_is_within_1e_8_of_the_exact() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let quantizers = [
            Quantizer::uniform_wrapped(8, -PI, PI).unwrap(),
            Quantizer::uniform_wrapped(4, -PI, PI).unwrap(),
            Quantizer::uniform_wrapped(12, -PI, PI).unwrap(),
            Quantizer::uniform(8, -100.0, 0.0).unwrap(),
        ];
        let (mut worst, mut tabled): (f64, usize) = (0.0, 0);
        for q in &quantizers {
            let span = q.cell_width(1) * q.cells() as f64;
            for _ in 0..20_000 {
                let sigma = span * rng.random_range(1e-4..0.02_f64);
                let mean = q.uniform.unwrap().lo + rng.random_range(-0.1..1.1) * span;
                let z = mean + sigma * rng.random_range(-14.0..14.0);
                let cell = q.encode(z);
                let exact = q.ln_probability(cell, mean, sigma * sigma);
                let fast = q.ln_probability_interpolated(cell, mean, sigma * sigma);
                worst = worst.max((fast - exact).abs());
                tabled += q.tabled_ln_probability(cell, mean, sigma * sigma).is_some() as usize;
            }
        }
        assert!(worst < 1e-8, "worst {worst:e}");
        // Most of the draws were read off the table, not the fallback.
        assert!(tabled > 30_000, "{tabled} of 80,000 from the table");
    }

    /// The local filter's joint lookup gives what the two lookups give
    /// apart, bit for bit, for uniform (wrapped or not) and non-uniform
    /// quantizers, in and out of the tables.
    #[test]
    fn the_joint_lookup_equals_the_two_apart() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let quantizers = [
            Quantizer::uniform_wrapped(8, -PI, PI).unwrap(),
            Quantizer::uniform_wrapped(3, -PI, PI).unwrap(),
            Quantizer::uniform(8, -100.0, 0.0).unwrap(),
            Quantizer::from_thresholds(&[-1.0, 0.0, 0.5, 2.0]).unwrap(),
        ];
        for q in &quantizers {
            let (lo, hi) = (q.edges[1], q.edges[q.cells() - 1]);
            for _ in 0..5_000 {
                let sigma = (hi - lo) * rng.random_range(1e-4..0.3_f64);
                let mean = lo + rng.random_range(-0.1..1.1) * (hi - lo);
                let cell = q.encode(mean + sigma * rng.random_range(-14.0..14.0));
                let variance = sigma * sigma;
                let (ln_h, scalars) = q.ln_probability_and_fisher(cell, mean, variance);
                assert_eq!(
                    ln_h.to_bits(),
                    q.ln_probability_interpolated(cell, mean, variance)
                        .to_bits()
                );
                assert_eq!(scalars, q.fisher_scalars(mean, variance));
            }
        }
    }

    #[test]
    fn ln_probability_agrees_with_probability() {
        let q = Quantizer::uniform_wrapped(6, -PI, PI).unwrap();
        for i in 0..q.cells() as u32 {
            let p = q.probability(i, 3.0, 0.04);
            if p > 1e-300 {
                assert!(
                    (q.ln_probability(i, 3.0, 0.04) - p.ln()).abs() < 1e-9 * p.ln().abs().max(1.0)
                );
            }
        }
    }

    #[test]
    fn fisher_window_drops_less_than_tolerance() {
        let bearing = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let rss = Quantizer::uniform(8, -100.0, 0.0).unwrap();
        let cases: Vec<(&Quantizer, f64, f64)> = vec![
            (&bearing, 0.1, 0.02),
            (&bearing, 3.13, 0.05),        // window crosses +π
            (&bearing, -PI + 0.002, 0.09), // window crosses −π
            (&bearing, 1.0, 0.004),        // far narrower than a cell
            (&rss, -50.0, 2.0),
            (&rss, -99.0, 3.0),   // window reaches the unbounded cell
            (&rss, 20.0, 1.0),    // mean beyond the last edge
            (&rss, -50.0, 0.3),   // table: interior, σ ≈ 0.8 cells
            (&bearing, 2.0, 0.5), // table: σ ≈ 20 cells
        ];
        for (q, mean, sigma) in cases {
            let v = sigma * sigma;
            let all = q.fisher_scalars_all_cells(mean, v);
            // Measured against the unquantized information of the same scalar,
            // the ceiling any quantizer approaches: the exact window drops
            // below 1e-12 of it, the table (where it applies) errs below 1e-6.
            let raw = FisherScalars::raw(v);
            for (w, tolerance) in [
                (q.fisher_scalars_exact(mean, v), 1e-12),
                (q.fisher_scalars(mean, v), 1e-6),
            ] {
                for (a, b, scale) in [
                    (w.gg, all.gg, raw.gg),
                    (w.gr, all.gr, raw.gg / sigma),
                    (w.rr, all.rr, raw.rr),
                ] {
                    assert!(
                        (a - b).abs() <= tolerance * scale,
                        "{mean} {sigma}: {a} vs {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn encoding_round_trips_through_bytes() {
        for bits in [1u8, 4, 8, 9, 12, 16] {
            let q = Quantizer::uniform_wrapped(bits, -PI, PI).unwrap();
            assert_eq!(q.index_bytes(), (bits as usize).div_ceil(8));
            for z in [-PI, -1.0, 0.0, 0.5, PI - 1e-9, PI, 7.0] {
                let i = q.encode(z);
                assert!((i as usize) < q.cells());
                let mut buf = Vec::new();
                q.write_index(i, &mut buf);
                assert_eq!(buf.len(), q.index_bytes());
                assert_eq!(q.read_index(&buf).unwrap(), i);
            }
        }
        let q = Quantizer::uniform(4, 0.0, 1.0).unwrap();
        assert!(matches!(
            q.read_index(&[16]),
            Err(QuantizerError::IndexOutOfRange { .. })
        ));
        assert!(matches!(
            q.read_index(&[1, 2]),
            Err(QuantizerError::WrongLength { .. })
        ));
    }

    #[test]
    fn encode_puts_values_in_the_cell_that_contains_them() {
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let width = 2.0 * PI / 256.0;
        assert_eq!(q.encode(-PI), 0);
        assert_eq!(q.encode(-PI + 1.5 * width), 1);
        assert_eq!(q.encode(PI), 0, "π wraps onto −π");
        assert!((q.representative(q.encode(0.3)) - 0.3).abs() <= width / 2.0);
    }

    #[test]
    fn invalid_quantizers_are_rejected() {
        assert!(matches!(
            Quantizer::uniform(0, 0.0, 1.0),
            Err(QuantizerError::BitsOutOfRange { .. })
        ));
        assert!(matches!(
            Quantizer::uniform(8, 1.0, 1.0),
            Err(QuantizerError::EmptyRange { .. })
        ));
        assert!(matches!(
            Quantizer::from_thresholds(&[1.0, 1.0]),
            Err(QuantizerError::ThresholdsNotIncreasing { index: 1 })
        ));
        assert!(quantized_fisher_information(&[0.0], 0.0, -1.0).is_nan());
    }
}
