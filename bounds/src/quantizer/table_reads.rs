//! Where the tables are read for a variance or a batch of them: σ, 1/σ,
//! σ/Δ and the rows, found once and shared by the likelihood and the
//! Fisher lookups.

use super::cells::{Quantizer, UniformCells};
use crate::batch::CHUNK;
use crate::width_axis::{self, Stencil};

/// What both tables are read at, for one variance: σ, 1/σ, `s = σ/Δ` and
/// the table rows of its half-width `Δ/(2σ)`, found once when a particle
/// needs both lookups.
#[derive(Debug, Clone, Copy)]
pub(super) struct Spread {
    pub(super) sigma: f64,
    pub(super) per_sigma: f64,
    pub(super) s: f64,
    pub(super) rows: Option<Stencil>,
}

impl Spread {
    #[inline(always)]
    pub(super) fn new(variance: f64, cells: &UniformCells) -> Self {
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
    pub(super) fn half_width(cells: &UniformCells, per_sigma: f64) -> f64 {
        0.5 * cells.width * per_sigma
    }
}

/// What the tables are read at, for a batch of means and variances, as
/// arrays: each lane's σ, 1/σ and σ/Δ, the rows over σ/Δ, and where the
/// likelihood table reads along v. Found in plain passes over every lane,
/// which vectorise. A caller keeps one across its batches, so that its
/// arrays are set up once.
pub struct TableReads {
    pub(super) sigma: [f64; CHUNK],
    pub(super) per_sigma: [f64; CHUNK],
    pub(super) s: [f64; CHUNK],
    pub(super) rows_ok: [bool; CHUNK],
    pub(super) first: [usize; CHUNK],
    pub(super) ws: [[f64; CHUNK]; 4],
    pub(super) mass_ok: [bool; CHUNK],
    pub(super) v: [f64; CHUNK],
    pub(super) iv: [usize; CHUNK],
    pub(super) wv: [[f64; CHUNK]; 4],
    pub(super) window_tabled: [bool; CHUNK],
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
    pub(super) fn find<const WITH_MASS: bool>(
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
    pub(super) fn spread(&self, i: usize) -> Spread {
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
    pub(super) fn mass_point(&self, i: usize) -> crate::mass_table::Point {
        crate::mass_table::Point {
            iv: self.iv[i],
            weights: [self.wv[0][i], self.wv[1][i], self.wv[2][i], self.wv[3][i]],
        }
    }
}
