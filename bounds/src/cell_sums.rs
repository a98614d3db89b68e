//! Sums over a window of quantizer cells: the Fisher information of one
//! quantized observation as three scalars, from its cells' standardized
//! edges. The exact sums the quantizer computes and the Fisher table's rows
//! are both built from these.

use std::f64::consts::FRAC_1_SQRT_2;

use crate::batch::CHUNK;
use crate::normal;

/// Half-width, in standard deviations, of the window of cells summed in the
/// Fisher information. A cell whose nearer edge is `a` standard deviations
/// away contributes about `a³ φ(a)` times the unquantized information `1/R`;
/// at 9 that is below 1e-15. `fisher_window_drops_less_than_tolerance` checks
/// that the dropped part stays below 1e-12 of the unquantized information.
pub const WINDOW_SIGMAS: f64 = 9.0;

/// The three scalars that give the Fisher information of one quantized
/// observation: with `∇h_i = (∂h_i/∂g) ∇g + (∂h_i/∂R) ∇R`,
/// `J_Y = gg ∇g∇gᵀ + gr (∇g∇Rᵀ + ∇R∇gᵀ) + rr ∇R∇Rᵀ`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FisherScalars {
    pub gg: f64,
    pub gr: f64,
    pub rr: f64,
}

impl FisherScalars {
    /// The unquantized observation: `J_Z = ∇g∇gᵀ/R + ∇R∇Rᵀ/(2R²)`.
    pub fn raw(r: f64) -> Self {
        Self {
            gg: 1.0 / r,
            gr: 0.0,
            rr: 0.5 / (r * r),
        }
    }
}

/// The Fisher scalars of one sensor at a batch of particles, as arrays.
#[derive(Debug, Clone, Copy)]
pub struct ScalarBatch {
    pub gg: [f64; CHUNK],
    pub gr: [f64; CHUNK],
    pub rr: [f64; CHUNK],
}

impl ScalarBatch {
    #[inline(always)]
    pub fn set(&mut self, i: usize, s: FisherScalars) {
        (self.gg[i], self.gr[i], self.rr[i]) = (s.gg, s.gr, s.rr);
    }

    pub(crate) fn get(&self, i: usize) -> FisherScalars {
        FisherScalars {
            gg: self.gg[i],
            gr: self.gr[i],
            rr: self.rr[i],
        }
    }
}

impl Default for ScalarBatch {
    fn default() -> Self {
        Self {
            gg: [0.0; CHUNK],
            gr: [0.0; CHUNK],
            rr: [0.0; CHUNK],
        }
    }
}

/// Standardized edge `t = (e − g)/σ` with the values every adjacent cell
/// needs, so each edge costs one `erfc` and one `exp`.
#[derive(Clone, Copy)]
pub(crate) struct Edge {
    pub(crate) t: f64,
    pub(crate) pdf: f64,
    pub(crate) x_pdf: f64,
    /// `Q(t)` for `t ≥ 0`, `Φ(t)` for `t < 0`: the tail that is small.
    tail: f64,
}

impl Edge {
    #[inline]
    pub(crate) fn at(t: f64) -> Self {
        let tail = if t >= 0.0 {
            normal::upper_tail(t)
        } else {
            normal::cdf(t)
        };
        let (pdf, x_pdf) = normal::pdf_and_x_pdf(t);
        Self {
            t,
            pdf,
            x_pdf,
            tail,
        }
    }

    /// Mass between this edge and a higher one.
    #[inline]
    pub(crate) fn mass_to(&self, upper: &Edge) -> f64 {
        if self.t >= 0.0 {
            self.tail - upper.tail
        } else if upper.t <= 0.0 {
            upper.tail - self.tail
        } else {
            0.5 * (libm::erf(upper.t * FRAC_1_SQRT_2) - libm::erf(self.t * FRAC_1_SQRT_2))
        }
    }
}

/// `Σα²/h, Σαβ/h, Σβ²/h` over the cells between consecutive standardized
/// edges, each edge costing one `erfc` and one `exp`.
#[inline]
pub(crate) fn window_sums(mut edges: impl Iterator<Item = f64>) -> [f64; 3] {
    let mut sums = [0.0; 3];
    let Some(first) = edges.next() else {
        return sums;
    };
    let mut lower = Edge::at(first);
    for t in edges {
        let upper = Edge::at(t);
        accumulate_between(&mut sums, &lower, &upper);
        lower = upper;
    }
    sums
}

/// Adds the cell between two edges, `lower` below `upper`.
#[inline]
pub(crate) fn accumulate_between(sums: &mut [f64; 3], lower: &Edge, upper: &Edge) {
    accumulate(
        sums,
        lower.mass_to(upper),
        lower.pdf - upper.pdf,
        lower.x_pdf - upper.x_pdf,
    );
}

/// Adds one cell's `α²/h, αβ/h, β²/h` (standardized α, β).
#[inline]
pub(crate) fn accumulate(sums: &mut [f64; 3], h: f64, alpha: f64, beta: f64) {
    if h > 0.0 {
        // α/h before α·(α/h): 1/h alone overflows for a subnormal h.
        let (a, b) = (alpha / h, beta / h);
        sums[0] += alpha * a;
        sums[1] += alpha * b;
        sums[2] += beta * b;
    }
}

/// `∂h/∂g = α/σ`, `∂h/∂R = β/(2R)`.
#[inline]
pub(crate) fn scalars_from_sums(sums: [f64; 3], variance: f64) -> FisherScalars {
    let sigma = variance.sqrt();
    FisherScalars {
        gg: sums[0] / variance,
        gr: sums[1] / (2.0 * variance * sigma),
        rr: sums[2] / (4.0 * variance * variance),
    }
}
