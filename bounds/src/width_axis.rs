//! The axis over the cell's half-width in standard deviations, shared by
//! the Fisher and the likelihood tables: `w = Δ/(2σ) = 1/(2s)`, with
//! `s = σ/Δ` as the tables' documentation counts it.
//!
//! Rows sit evenly in w within each octave `[2^o, 2^(o+1))`, `PER_OCTAVE`
//! of them, so that a row and its interpolation weights come from the bits
//! of w: the exponent is the octave and the top bits of the mantissa the
//! row. No logarithm, where the log-spaced axis this replaced took one per
//! lookup (a fifth of a likelihood lookup's instructions, callgrind), and
//! w itself is one product of the 1/σ the lookups need anyway. Each
//! octave has one row before and two after its own, at the same spacing,
//! so that a cubic stencil never straddles two spacings; the few rows at
//! an octave's boundary are computed twice.
//!
//! Why w and not s: the cell's log-probability depends on s through
//! `w ± v` (v up to 12 σ), smooth in w at every scale, but in s its
//! derivatives grow like `1/s⁵` at small s. An axis even in s within
//! octaves needed twice the rows for the same error (1.1e-9 at 256 rows an
//! octave, 1.3e-8 at 128), and building them cost every process 50 ms.

/// The tables cover `S_MIN < s < S_MAX`, that is `1/128 < w < 1`.
pub const S_MIN: f64 = 0.5;
pub const S_MAX: f64 = 64.0;
/// Rows per octave, evenly spaced in w.
const PER_OCTAVE: usize = 128;
/// The octave `[2^FIRST_OCTAVE, 2^(FIRST_OCTAVE + 1))` of w is octave 0
/// here: w from 1/128.
const FIRST_OCTAVE: i64 = -7;
/// Octaves from w = 1/128 up to w = 1.
const OCTAVES: usize = 7;
/// An octave's rows: one before its own, its own, two after.
const ROWS_PER_OCTAVE: usize = PER_OCTAVE + 3;
/// Rows of a table over the whole axis.
pub const ROWS: usize = OCTAVES * ROWS_PER_OCTAVE;

/// The four rows a lookup reads (`first .. first + 4`) and their cubic
/// Lagrange weights.
#[derive(Debug, Clone, Copy)]
pub struct Stencil {
    pub first: usize,
    pub weights: [f64; 4],
}

/// The w at which row `row` is computed.
fn row_w(row: usize) -> f64 {
    let octave = (row / ROWS_PER_OCTAVE) as i32 + FIRST_OCTAVE as i32;
    let k = (row % ROWS_PER_OCTAVE) as f64 - 1.0;
    2f64.powi(octave) * (1.0 + k / PER_OCTAVE as f64)
}

/// The s = 1/(2w) at which row `row` is computed.
pub fn row_s(row: usize) -> f64 {
    0.5 / row_w(row)
}

/// Whether row `row` belongs to the top octave, w ≥ 1/2 (s ≤ 1): the one
/// where the Fisher sums still depend on where the mean sits in its cell.
pub fn below_one(row: usize) -> bool {
    row >= (OCTAVES - 1) * ROWS_PER_OCTAVE
}

/// The bits of 2^52, and 2^52: `2^52 + m` for a mantissa `m < 2^52` is
/// `EXPONENT_52 | m`.
const EXPONENT_52: u64 = 0x4330_0000_0000_0000;
const TWO_52: f64 = 4_503_599_627_370_496.0;

/// The stencil at half-width `w`, or `None` outside `(1/128, 1)` (or NaN).
#[inline(always)]
pub fn stencil(w: f64) -> Option<Stencil> {
    let (inside, stencil) = stencil_lane(w);
    inside.then_some(stencil)
}

/// [`stencil`] without a branch, so that a loop over lanes vectorises:
/// whether w is inside the axis, and its stencil if it is (row 0 and
/// meaningless weights if not).
#[inline(always)]
pub fn stencil_lane(w: f64) -> (bool, Stencil) {
    let inside = w > 0.5 / S_MAX && w < 0.5 / S_MIN;
    let bits = w.to_bits();
    // A positive normal number: the biased exponent, then the mantissa.
    let octave = ((bits >> 52) as i64).wrapping_sub(1023 + FIRST_OCTAVE) as usize;
    let mantissa = bits & ((1 << 52) - 1);
    // The place in the octave in rows is x = mantissa / 2^52 · 128, whose
    // whole part k is the mantissa's top seven bits and whose fraction
    // x − k is its low 45 bits over 2^45, exactly. Both by the bits, which
    // vectorise: x86 has no vector conversion between doubles and 64-bit
    // integers before AVX-512, and a 32-bit one saturates lane by lane.
    const FRACTION_BITS: u32 = 52 - PER_OCTAVE.trailing_zeros();
    const _: () = assert!(PER_OCTAVE.is_power_of_two());
    let k = (mantissa >> FRACTION_BITS) as usize;
    let fraction = mantissa & ((1 << FRACTION_BITS) - 1);
    // `fraction as f64`, exactly (below 2^52), by the bits.
    let fraction =
        (f64::from_bits(fraction | EXPONENT_52) - TWO_52) * (1.0 / (1u64 << FRACTION_BITS) as f64);
    // Row k − 1 of the octave is its (k − 1 + 1)-th.
    let first = octave.wrapping_mul(ROWS_PER_OCTAVE).wrapping_add(k);
    (
        inside,
        Stencil {
            first: if inside { first } else { 0 },
            weights: lagrange_weights(fraction),
        },
    )
}

/// Cubic Lagrange weights for nodes −1, 0, 1, 2 at offset `t` from node 0.
#[inline(always)]
pub fn lagrange_weights(t: f64) -> [f64; 4] {
    // By products only: a division by 6 is not a multiplication to the
    // compiler, and would be two divisions on every lookup's critical path.
    const SIXTH: f64 = 1.0 / 6.0;
    let (tm1, tp1, tm2) = (t - 1.0, t + 1.0, t - 2.0);
    [
        -t * tm1 * tm2 * SIXTH,
        tp1 * tm1 * tm2 * 0.5,
        -tp1 * t * tm2 * 0.5,
        tp1 * t * tm1 * SIXTH,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stencil's row and weights from the mantissa's bits are those of
    /// the plain arithmetic, `x = mantissa · 128 / 2^52` truncated, bit for
    /// bit.
    #[test]
    fn the_bits_give_the_truncation() {
        let mut w = 0.5 / S_MAX * 1.000_001;
        while w < 0.5 / S_MIN {
            for w in [w, w.next_up(), w.next_down()] {
                let (inside, st) = stencil_lane(w);
                let bits = w.to_bits();
                let octave = ((bits >> 52) as i64 - 1023 - FIRST_OCTAVE) as usize;
                let x = (bits & ((1 << 52) - 1)) as f64 * (PER_OCTAVE as f64 / 2f64.powi(52));
                let k = x as usize;
                assert!(inside);
                assert_eq!(st.first, octave * ROWS_PER_OCTAVE + k, "{w}");
                let want = lagrange_weights(x - k as f64).map(f64::to_bits);
                assert_eq!(st.weights.map(f64::to_bits), want, "{w}");
            }
            w *= 1.000_37;
        }
    }

    /// The stencil's rows bracket w: the second at or below it, the third
    /// above, one spacing apart, and the weights put w where it is.
    #[test]
    fn the_stencil_brackets_w() {
        let mut w = 0.5 / S_MAX * 1.0001;
        while w < 0.5 / S_MIN {
            let st = stencil(w).unwrap();
            let nodes: Vec<f64> = (st.first..st.first + 4).map(row_w).collect();
            assert!(nodes[1] <= w && w < nodes[2], "{w}: {nodes:?}");
            let spacing = nodes[2] - nodes[1];
            for pair in nodes.windows(2) {
                assert!(
                    (pair[1] - pair[0] - spacing).abs() < 1e-12 * w,
                    "{w}: {nodes:?}"
                );
            }
            assert!(spacing <= w / PER_OCTAVE as f64 && spacing > w / (2 * PER_OCTAVE + 1) as f64);
            let at: f64 = st.weights.iter().zip(&nodes).map(|(a, n)| a * n).sum();
            assert!((at - w).abs() < 1e-12 * w, "{w}: {at}");
            assert!(st.first + 4 <= ROWS);
            assert_eq!(below_one(st.first), w >= 0.5, "{w}");
            w *= 1.0137;
        }
        for w in [0.5 / S_MAX, 0.5 / S_MIN, f64::NAN, f64::INFINITY, 0.0, -0.3] {
            assert!(stencil(w).is_none(), "{w}");
        }
        assert!(stencil((0.5 / S_MIN).next_down()).is_some());
        assert!(stencil((0.5 / S_MAX).next_up()).is_some());
    }
}
