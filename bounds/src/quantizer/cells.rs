//! The quantizer itself: its cells, built uniform, wrapped or from
//! thresholds, and the encoding of a value to a cell index and bytes.

use std::ops::RangeInclusive;

use crate::cell_sums::WINDOW_SIGMAS;
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
    pub(super) bits: u8,
    pub(super) edges: Vec<f64>,
    pub(super) wrapped: bool,
    /// The cell grid of a uniform quantizer, for the tables.
    pub(super) uniform: Option<UniformCells>,
}

/// Equal cells from `lo`, with the reciprocals the per-particle lookups
/// multiply by (a division is a long wait on their critical chain).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct UniformCells {
    pub(super) lo: f64,
    pub(super) width: f64,
    pub(super) per_width: f64,
    /// `1 / (hi − lo)`, for wrapping.
    pub(super) per_period: f64,
    /// What the tables' lookups ask of the quantizer, copied here so that
    /// a loop over particles reads plain fields (an index into `edges` is
    /// a bounds check, and a branch that stops a loop vectorising):
    /// whether it wraps, `e_L − e_0`, `e_1` and `e_{L−1}`, and L.
    pub(super) wrapped: bool,
    pub(super) period: f64,
    pub(super) inner: (f64, f64),
    pub(super) cells: u32,
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

    pub(super) fn period(&self) -> f64 {
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
    pub(super) fn standardized(
        &self,
        index: usize,
        shift: f64,
        mean: f64,
        sigma: f64,
    ) -> (f64, f64) {
        let p = shift * if self.wrapped { self.period() } else { 0.0 };
        (
            (self.edges[index] + p - mean) / sigma,
            (self.edges[index + 1] + p - mean) / sigma,
        )
    }

    /// The turns of the circle whose copies of cell `index` a probability
    /// sums: for a wrapped quantizer, the copy either side of the first
    /// period while the window of ±[`WINDOW_SIGMAS`] σ is narrower than
    /// the circle (the mean lies within the first period, so those hold
    /// every copy within reach), and every copy within the window once it
    /// is not (a far bearing's noise goes round the circle several times).
    #[inline]
    pub(super) fn copies(&self, index: usize, mean: f64, sigma: f64) -> RangeInclusive<i64> {
        if !self.wrapped {
            return 0..=0;
        }
        let period = self.period();
        let reach = WINDOW_SIGMAS * sigma;
        if 2.0 * reach < period {
            return -1..=1;
        }
        let first = ((mean - reach - self.edges[index + 1]) / period).ceil();
        let last = ((mean + reach - self.edges[index]) / period).floor();
        first as i64..=last as i64
    }

    /// Whether the window of ±[`WINDOW_SIGMAS`] σ is at least the circle.
    #[inline]
    pub(super) fn wraps_round(&self, sigma: f64) -> bool {
        self.wrapped && 2.0 * WINDOW_SIGMAS * sigma >= self.period()
    }
}

pub(super) fn uniform_edges(bits: u8, lo: f64, hi: f64) -> Result<Vec<f64>, QuantizerError> {
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
