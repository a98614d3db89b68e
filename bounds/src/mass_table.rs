//! A table of the log-probability of one cell of an infinite uniform
//! quantizer, for the particle filters' likelihood.
//!
//! A cell of width Δ centred at c, and a measurement `N(g, σ²)`: with
//! `v = (g − c)/σ` and `s = σ/Δ`, the cell's probability is
//! `Φ(1/(2s) − v) − Φ(−1/(2s) − v)`, a function of `(v, s)` alone. Its
//! logarithm falls like `−v²/2`; what is left, `G(v, s) = ln P + v²/2`,
//! is smooth and slowly varying, and that is what the table holds, over
//! `|v| ≤ V_MAX` and `S_MIN < s < S_MAX`, read by bicubic Lagrange
//! interpolation in v and s (over [`crate::width_axis`]).
//!
//! Why: the quantized likelihood of each particle and sensor took two
//! `erfc`, their `exp`s and a logarithm, three fifths of the particle
//! filter's time (`cargo bench -p node -- "particle filter alone"`). The
//! lookup is sixteen products and the two sets of weights.
//! `lookup_matches_the_exact_log_mass` bounds its error: below 1e-8 in
//! `ln P` (1.9e-9 seen), a relative error of 1e-8 in a particle's weight,
//! far below the filter's Monte Carlo error. Outside the table the caller
//! computes the exact value.

use std::sync::OnceLock;

use crate::normal::ln_interval_mass;
use crate::shared_rows::{LazyRows, PlainRow, SharedRows};
use crate::width_axis::{self, lagrange_weights, Stencil};

/// The table covers `|v| ≤ V_MAX`: particles within 12 σ of the cell.
pub const V_MAX: f64 = 12.0;
/// Grid points per unit of v. 64 gave an error of 5.2e-10, but every
/// process builds its own rows, one exact `ln P` per point: 265 million
/// instructions in a 300-step default `sim` at 64 (callgrind), paid again
/// by each node process of a `run`. 32 halves that, for 1.9e-9.
const V_PER_UNIT: usize = 32;
const V_POINTS: usize = 2 * V_MAX as usize * V_PER_UNIT + 1;

/// One row over v, padded with one point before and two after so that a
/// four-point stencil never leaves it.
pub(crate) type MassRow = [f64; V_POINTS + 3];

crate::shared_rows::kept_by_reference!(MassRow);

#[derive(Default)]
pub struct LnMassTable {
    rows: LazyRows<MassRow>,
}

/// The process-wide table; its rows fill in as they are first needed.
pub fn table() -> &'static LnMassTable {
    static TABLE: OnceLock<LnMassTable> = OnceLock::new();
    TABLE.get_or_init(LnMassTable::default)
}

/// `ln P` of a cell of unit width, exactly: standardized mean `v`, `s = σ/Δ`.
pub fn exact(v: f64, s: f64) -> f64 {
    let half = 0.5 / s;
    ln_interval_mass(-half - v, half - v)
}

impl LnMassTable {
    /// Row `is`, built on first use.
    #[inline(always)]
    fn row(&self, is: usize) -> &MassRow {
        self.rows.get(is, |is| {
            let s = width_axis::row_s(is);
            // Point k is at v = (k − 1)/V_PER_UNIT − V_MAX.
            std::array::from_fn(|k| {
                let v = (k as f64 - 1.0) / V_PER_UNIT as f64 - V_MAX;
                exact(v, s) + 0.5 * v * v
            })
        })
    }

    /// Rows not built yet come from (or go to) memory other processes share.
    pub(crate) fn share(&self, rows: SharedRows<MassRow>) {
        self.rows.share(rows);
    }

    /// `ln P` at `(v, s)`, or `None` outside the table.
    #[inline]
    pub fn lookup(&self, v: f64, s: f64) -> Option<f64> {
        self.lookup_at(v, &width_axis::stencil(0.5 / s)?)
    }

    /// [`lookup`](Self::lookup) with the rows over s already found.
    #[inline]
    pub fn lookup_at(&self, v: f64, rows: &Stencil) -> Option<f64> {
        Some(self.read(&point(v)?, v, rows))
    }

    /// `ln P` at the point `at` of v (which [`point`] found) and the rows
    /// over s: the four rows' stencils weighted, then over v.
    #[inline(always)]
    pub fn read(&self, at: &Point, v: f64, rows: &Stencil) -> f64 {
        let Point { iv, weights: wv } = *at;
        // Over the rows first, point by point (vectorisable), then over v.
        let mut acc = [0.0; 4];
        for (a, wsa) in rows.weights.iter().enumerate() {
            // Row point k holds grid point k − 1: points iv − 1 ..= iv + 2.
            let stencil: &[f64; 4] = self.row(rows.first + a)[iv..iv + 4]
                .try_into()
                .expect("a padded row holds every four-point stencil");
            for (t, p) in acc.iter_mut().zip(stencil) {
                *t += wsa * p;
            }
        }
        let g = wv[0] * acc[0] + wv[1] * acc[1] + wv[2] * acc[2] + wv[3] * acc[3];
        g - 0.5 * v * v
    }
}

/// Where a lookup reads along v: the stencil's first point (`iv .. iv + 4`
/// of a padded row) and its cubic weights.
#[derive(Debug, Clone, Copy, Default)]
pub struct Point {
    pub iv: usize,
    pub weights: [f64; 4],
}

/// The [`Point`] of v, or `None` outside `|v| ≤ V_MAX` (or NaN).
#[inline(always)]
pub fn point(v: f64) -> Option<Point> {
    let (inside, at) = point_lane(v);
    inside.then_some(at)
}

/// 2^52: below it, `n + 2^52` holds the integer n in its low bits.
const TWO_52: f64 = 4_503_599_627_370_496.0;

/// [`point`] without a branch, so that a loop over lanes vectorises:
/// whether v is inside the table, and its point if it is (a point within
/// the rows, with meaningless weights, if not).
#[inline(always)]
pub fn point_lane(v: f64) -> (bool, Point) {
    let inside = v.abs() <= V_MAX; // false for NaN
    let xv = (v + V_MAX) * V_PER_UNIT as f64;
    // ⌊xv⌋ within the rows (0 for NaN: `max` takes the number), as a
    // double, then its bits as the integer: both vectorise, where a
    // conversion to an integer saturates lane by lane. Inside, xv is in
    // [0, 768], so this is the truncation `as` would give.
    let at = xv.floor().max(0.0).min((V_POINTS - 2) as f64);
    let iv = ((at + TWO_52).to_bits() - TWO_52.to_bits()) as usize;
    (
        inside,
        Point {
            iv,
            weights: lagrange_weights(xv - at),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::width_axis::{S_MAX, S_MIN};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The point found through the floor and the bits is the truncation
    /// of `(v + V_MAX) · V_PER_UNIT`, with the same weights, bit for bit,
    /// across the table and at its edges; outside, a point within the rows.
    #[test]
    fn the_point_is_the_truncation() {
        let mut v = -V_MAX;
        while v <= V_MAX {
            for v in [v, v.next_up(), v.next_down()] {
                let (inside, at) = point_lane(v);
                let xv = (v + V_MAX) * V_PER_UNIT as f64;
                let iv = (xv as i32).clamp(0, V_POINTS as i32 - 2) as usize;
                assert_eq!(inside, v.abs() <= V_MAX, "{v}");
                assert_eq!(at.iv, iv, "{v}");
                let want = crate::width_axis::lagrange_weights(xv - iv as f64);
                assert_eq!(at.weights.map(f64::to_bits), want.map(f64::to_bits), "{v}");
            }
            v += 0.003_17;
        }
        for v in [f64::NAN, f64::INFINITY, -1e300, 1e300, 12.5, -12.5] {
            let (inside, at) = point_lane(v);
            assert!(!inside && at.iv <= V_POINTS - 2, "{v}");
        }
    }

    #[test]
    fn lookup_matches_the_exact_log_mass() {
        let t = table();
        let inside = |s: f64| s.clamp(S_MIN.next_up(), S_MAX.next_down());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut worst: f64 = 0.0;
        for _ in 0..50_000 {
            let v = rng.random_range(-V_MAX..=V_MAX);
            let s = inside(rng.random_range(S_MIN.ln()..S_MAX.ln()).exp());
            let got = t.lookup(v, s).unwrap();
            worst = worst.max((got - exact(v, s)).abs());
        }
        // And a sweep, whose worst is at the largest |v| and smallest s.
        let mut s = S_MIN.next_up();
        while s < S_MAX {
            for v in [-V_MAX, -7.3, -0.41, 0.0, 2.9, V_MAX] {
                worst = worst.max((t.lookup(v, s).unwrap() - exact(v, s)).abs());
            }
            s *= 1.0037;
        }
        assert!(worst < 1e-8, "worst error {worst:e}");
        // The ends of both ranges.
        for (v, s) in [
            (V_MAX, S_MIN.next_up()),
            (-V_MAX, S_MAX.next_down()),
            (0.0, S_MIN.next_up()),
            (V_MAX, 1.0),
        ] {
            let got = t.lookup(v, s).unwrap();
            assert!(
                (got - exact(v, s)).abs() < 1e-8,
                "({v}, {s}): {got} vs {}",
                exact(v, s)
            );
        }
        assert!(t.lookup(V_MAX + 0.1, 1.0).is_none());
        assert!(t.lookup(0.0, S_MIN).is_none());
        assert!(t.lookup(0.0, S_MAX).is_none());
    }
}
