//! Per-particle arithmetic in batches that the compiler vectorises.
//!
//! The filters and bounds do the same arithmetic at every particle: a
//! sensor's model and its quantized likelihood and Fisher information, the
//! coordinated turn and its Jacobian, normal draws. Written particle by
//! particle, each is a chain of scalar operations and library calls
//! (`atan2`, `sincos`) that no compiler vectorises. Here the same
//! arithmetic is split into passes over a [`CHUNK`] of particles held as
//! arrays: branch-free loops that compile to 4-wide AVX2 in a kernel's
//! copy compiled for it ([`has_avx2`]), with the few lanes a pass cannot
//! serve (special values, a table's edge, a draw the ziggurat rejects)
//! redone by the scalar code.
//!
//! Every pass gives the scalar code's result bit for bit: lanes do the same
//! operations in the same order, and Rust never contracts a multiply and an
//! add into an FMA, so a vectorised lane rounds exactly as the scalar code
//! does. The library functions the lanes replace are written out from the
//! same source (fdlibm's `atan2`, `sincos`, `exp`, `erf` and `erfc`, as the `libm` crate
//! has them; rand_distr's ziggurat). The tests hold each pass to that.

mod erf;

pub use erf::{erf, erf_or_erfc, erfc};

use crate::ziggurat_tables::{ZIG_NORM_F as F, ZIG_NORM_R as R, ZIG_NORM_X as X};
use crate::State;

/// Particles per batch: enough for the vector loops to run long, few
/// enough that a batch's arrays (a few kilobytes) stay in L1.
pub const CHUNK: usize = 64;

/// Whether this CPU has AVX2. A kernel runs a copy of itself compiled for
/// AVX2 when it does (a `#[target_feature(enable = "avx2")]` function
/// whose body is the kernel, `#[inline(always)]` down to its loops), and
/// the baseline build (x86-64's SSE2) otherwise. Either way the result is
/// the same, bit for bit (see the module's doc); only the speed differs.
#[inline]
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The states' positions `p_x`, `p_y`, as two arrays.
#[derive(Debug, Clone, Copy)]
pub struct Positions {
    pub x: [f64; CHUNK],
    pub y: [f64; CHUNK],
}

impl Positions {
    /// The positions of `states` (at most [`CHUNK`], at least one). Lanes
    /// past the last state repeat it, so that the passes, which run over
    /// every lane, meet no value a real lane would not.
    #[inline(always)]
    pub fn of(states: &[State]) -> Self {
        debug_assert!(!states.is_empty() && states.len() <= CHUNK);
        let last = states[states.len() - 1];
        let mut p = Self {
            x: [last[0]; CHUNK],
            y: [last[1]; CHUNK],
        };
        for ((x, y), s) in p.x.iter_mut().zip(p.y.iter_mut()).zip(states) {
            *x = s[0];
            *y = s[1];
        }
        p
    }
}

/// The states, component by component: `c[k][i]` is component k of
/// lane i's state. Lanes past the last state repeat it, as in
/// [`Positions::of`].
#[derive(Debug, Clone, Copy)]
pub struct StateLanes {
    pub c: [[f64; CHUNK]; 4],
}

impl StateLanes {
    #[inline(always)]
    pub fn of(states: &[State]) -> Self {
        debug_assert!(!states.is_empty() && states.len() <= CHUNK);
        let last = states[states.len() - 1];
        let mut lanes = Self {
            c: std::array::from_fn(|k| [last[k]; CHUNK]),
        };
        for (i, s) in states.iter().enumerate() {
            for k in 0..4 {
                lanes.c[k][i] = s[k];
            }
        }
        lanes
    }
}

/// Constants written by their bits, as fdlibm's source gives them.
const fn bits<const N: usize>(b: [u64; N]) -> [f64; N] {
    let mut out = [0.0; N];
    let mut i = 0;
    while i < N {
        out[i] = f64::from_bits(b[i]);
        i += 1;
    }
    out
}

/// fdlibm's (the `libm` crate's) `atan2(y, x)` lane by lane, equal to it
/// bit for bit. The branches of its argument reduction become selects, so
/// the loop vectorises; lanes with an argument it treats specially (zero,
/// infinite or NaN, subnormal, or |y/x| beyond 2^±60) are redone by
/// `libm::atan2` itself.
#[inline(always)]
pub fn atan2(y: &[f64; CHUNK], x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
    let mut ordinary = [false; CHUNK];
    for i in 0..CHUNK {
        let (r, ok) = atan2_ordinary(y[i], x[i]);
        out[i] = r;
        ordinary[i] = ok;
    }
    if ordinary.iter().all(|&ok| ok) {
        return;
    }
    for i in 0..CHUNK {
        if !ordinary[i] {
            out[i] = libm::atan2(y[i], x[i]);
        }
    }
}

/// atan(0.5), atan(1), atan(1.5), atan(∞), high parts.
const ATANHI: [f64; 4] = bits([
    0x3FDD_AC67_0561_BB4F,
    0x3FE9_21FB_5444_2D18,
    0x3FEF_730B_D281_F69B,
    0x3FF9_21FB_5444_2D18,
]);
/// Their low parts.
const ATANLO: [f64; 4] = bits([
    0x3C7A_2B7F_222F_65E2,
    0x3C81_A626_3314_5C07,
    0x3C70_0788_7AF0_CBBD,
    0x3C91_A626_3314_5C07,
]);
/// The odd polynomial's coefficients.
const AT: [f64; 11] = bits([
    0x3FD5_5555_5555_550D,
    0xBFC9_9999_9998_EBC4,
    0x3FC2_4924_9200_83FF,
    0xBFBC_71C6_FE23_1671,
    0x3FB7_45CD_C54C_206E,
    0xBFB3_B0F2_AF74_9A6D,
    0x3FB1_0D66_A0D0_3D51,
    0xBFAD_DE2D_52DE_FD9A,
    0x3FA9_7B4B_2476_0DEB,
    0xBFA2_B444_2C6A_6C2F,
    0x3F90_AD3A_E322_DA11,
]);
const PI: f64 = f64::from_bits(0x4009_21FB_5444_2D18);
const PI_LO: f64 = f64::from_bits(0x3CA1_A626_3314_5C07);

/// One lane of [`atan2`]: the result, and whether the lane is ordinary
/// (otherwise the result is to be discarded). Branch-free.
#[inline(always)]
fn atan2_ordinary(y: f64, x: f64) -> (f64, bool) {
    // The high words, as fdlibm reads them, without their signs.
    let (iy, ix) = (
        ((y.to_bits() >> 32) & 0x7fff_ffff) as i64,
        ((x.to_bits() >> 32) & 0x7fff_ffff) as i64,
    );
    // Finite, normal, and exponents less than 60 apart: then fdlibm's
    // atan2 takes its general path, z = atan(|y/x|), and atan its
    // polynomial one (2^-60 < |y/x| < 2^60 < 2^66).
    let ordinary = iy >= 0x0010_0000
        && ix >= 0x0010_0000
        && iy < 0x7ff0_0000
        && ix < 0x7ff0_0000
        && iy < ix + (60 << 20)
        && ix < iy + (60 << 20);
    let t = (y / x).abs();
    // atan's reduction: each interval's argument as a quotient (over 1
    // below 7/16, exactly t). Comparing t is comparing its high word, as
    // fdlibm does, since the bounds' low words are zero.
    let (c0, c1, c2, c3) = (t < 0.4375, t < 0.6875, t < 1.1875, t < 2.4375);
    let num = if c0 {
        t
    } else if c1 {
        2. * t - 1.
    } else if c2 {
        t - 1.
    } else if c3 {
        t - 1.5
    } else {
        -1.
    };
    let den = if c0 {
        1.
    } else if c1 {
        2. + t
    } else if c2 {
        t + 1.
    } else if c3 {
        1. + 1.5 * t
    } else {
        t
    };
    let r = num / den;
    let z = r * r;
    let w = z * z;
    let s1 = z * (AT[0] + w * (AT[2] + w * (AT[4] + w * (AT[6] + w * (AT[8] + w * AT[10])))));
    let s2 = w * (AT[1] + w * (AT[3] + w * (AT[5] + w * (AT[7] + w * AT[9]))));
    let (hi, lo) = if c1 {
        (ATANHI[0], ATANLO[0])
    } else if c2 {
        (ATANHI[1], ATANLO[1])
    } else if c3 {
        (ATANHI[2], ATANLO[2])
    } else {
        (ATANHI[3], ATANLO[3])
    };
    let reduced = hi - (r * (s1 + s2) - lo - r);
    let small = r - r * (s1 + s2);
    // Below 2^-27 atan returns its argument.
    let tiny = t < f64::from_bits(0x3e40_0000_0000_0000);
    let a = if tiny {
        t
    } else if c0 {
        small
    } else {
        reduced
    };
    let result = match (x < 0.0, y < 0.0) {
        (false, false) => a,
        (false, true) => -a,
        (true, false) => PI - (a - PI_LO),
        (true, true) => (a - PI_LO) - PI,
    };
    (result, ordinary)
}

/// fdlibm's (the `libm` crate's) `sincos(x)` lane by lane, equal to it bit
/// for bit: its polynomial kernels where `2^-27 √2 ≤ |x| ≤ π/4`, `(x, 1)`
/// below, and `libm::sincos` itself for the lanes beyond (those needing
/// its argument reduction, or not finite).
#[inline(always)]
pub fn sincos(x: &[f64; CHUNK], sin: &mut [f64; CHUNK], cos: &mut [f64; CHUNK]) {
    let mut ordinary = [false; CHUNK];
    for i in 0..CHUNK {
        let (s, c, ok) = sincos_ordinary(x[i]);
        (sin[i], cos[i], ordinary[i]) = (s, c, ok);
    }
    if ordinary.iter().all(|&ok| ok) {
        return;
    }
    for i in 0..CHUNK {
        if !ordinary[i] {
            (sin[i], cos[i]) = libm::sincos(x[i]);
        }
    }
}

/// k_sin's coefficients.
const S: [f64; 6] = bits([
    0xBFC5_5555_5555_5549,
    0x3F81_1111_1110_F8A6,
    0xBF2A_01A0_19C1_61D5,
    0x3EC7_1DE3_57B1_FE7D,
    0xBE5A_E5E6_8A2B_9CEB,
    0x3DE5_D93A_5ACF_D57C,
]);
/// k_cos's coefficients.
const C: [f64; 6] = bits([
    0x3FA5_5555_5555_554C,
    0xBF56_C16C_16C1_5177,
    0x3EFA_01A0_19CB_1590,
    0xBE92_7E4F_809C_52AD,
    0x3E21_EE9E_BDB4_B1C4,
    0xBDA8_FAE9_BE88_38D4,
]);

/// One lane of [`sincos`]: `(sin, cos, ordinary)`. Branch-free.
#[inline(always)]
fn sincos_ordinary(x: f64) -> (f64, f64, bool) {
    let ix = (x.to_bits() >> 32) & 0x7fff_ffff;
    // |x| ≤ π/4 by fdlibm's high word; below 2^-27 √2 it returns (x, 1).
    let ordinary = ix <= 0x3fe9_21fb;
    let tiny = ix < 0x3e46_a09e;
    // k_sin(x, 0, 0)
    let z = x * x;
    let w = z * z;
    let r = S[1] + z * (S[2] + z * S[3]) + z * w * (S[4] + z * S[5]);
    let v = z * x;
    let sin = x + v * (S[0] + z * r);
    // k_cos(x, 0), its tail `x * y` with y = 0 kept for the sign of zero.
    let r = z * (C[0] + z * (C[1] + z * C[2])) + w * w * (C[3] + z * (C[4] + z * C[5]));
    let hz = 0.5 * z;
    let one_less = 1.0 - hz;
    let cos = one_less + (((1.0 - one_less) - hz) + (z * r - x * 0.0));
    if tiny {
        (x, 1.0, ordinary)
    } else {
        (sin, cos, ordinary)
    }
}

/// fdlibm's (the `libm` crate's) `exp(x)` lane by lane, equal to it bit
/// for bit: its argument reduction's three cases become selects, and its
/// final `scalbn` a product by 2^k, which it is for every k a lane below
/// |x| = 708.39 meets. Lanes from there on (overflow, underflow to a
/// subnormal or zero, infinite, NaN) are redone by `libm::exp` itself.
#[inline(always)]
pub fn exp(x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
    let mut ordinary = [false; CHUNK];
    for i in 0..CHUNK {
        let (r, ok) = exp_ordinary(x[i]);
        out[i] = r;
        ordinary[i] = ok;
    }
    if ordinary.iter().all(|&ok| ok) {
        return;
    }
    for i in 0..CHUNK {
        if !ordinary[i] {
            out[i] = libm::exp(x[i]);
        }
    }
}

/// ln 2 in two parts (`k · LN2_HI` is exact for the k met), and 1/ln 2.
const LN2_HI: f64 = f64::from_bits(0x3FE6_2E42_FEE0_0000);
const LN2_LO: f64 = f64::from_bits(0x3DEA_39EF_3579_3C76);
const INV_LN2: f64 = f64::from_bits(0x3FF7_1547_652B_82FE);
/// The rational approximation's polynomial in r².
const EXP_P: [f64; 5] = bits([
    0x3FC5_5555_5555_553E,
    0xBF66_C16C_16BE_BD93,
    0x3F11_566A_AF25_DE2C,
    0xBEBB_BD41_C5D2_6BF1,
    0x3E66_3769_72BE_A4D0,
]);

/// One lane of [`exp`]: the result, and whether the lane is ordinary
/// (otherwise the result is to be discarded). Branch-free.
#[inline(always)]
fn exp_ordinary(x: f64) -> (f64, bool) {
    // fdlibm compares the high word of |x| with these; the same tests on
    // |x| itself, as doubles, vectorise where the words would not.
    // `hx < w` is `|x| < at(w)`, `hx > w` is `|x| ≥ at(w + 1)`.
    const fn at(high_word: u64) -> f64 {
        f64::from_bits(high_word << 32)
    }
    let a = x.abs();
    // |x| < 708.39 (and not NaN); |x| > ln 2 / 2; |x| ≥ 3 ln 2 / 2; and
    // |x| ≤ 2^-28, where exp(x) is 1 + x.
    let ordinary = a < at(0x4086_232b);
    let reduced = a >= at(0x3fd6_2e43);
    let far = a >= at(0x3ff0_a2b2);
    let tiny = a < at(0x3e30_0001);
    // x = k ln 2 + r, |r| ≤ ln 2 / 2. Between ln 2 / 2 and 3 ln 2 / 2,
    // k = ±1; beyond, x/ln 2 rounded half away from zero: fdlibm's `(int)`
    // truncation, here `trunc` (a rounding instruction where vectorised),
    // equal to it for every ordinary lane.
    let k_far = (INV_LN2 * x + 0.5f64.copysign(x)).trunc();
    let k = if reduced {
        if far {
            k_far
        } else {
            1f64.copysign(x)
        }
    } else {
        0.0
    };
    // With k = 0 these are fdlibm's `hi = x, lo = 0` exactly.
    let hi = x - k * LN2_HI;
    let lo = k * LN2_LO;
    let r = hi - lo;
    let rr = r * r;
    let c =
        r - rr * (EXP_P[0] + rr * (EXP_P[1] + rr * (EXP_P[2] + rr * (EXP_P[3] + rr * EXP_P[4]))));
    let y = 1.0 + (r * c / (2.0 - c) - lo + hi);
    // scalbn(y, k) is y · 2^k for −1022 ≤ k ≤ 1023, as every ordinary lane
    // has it, and y · 2⁰ = y. 2^k from the bits of k + 1023 + 2^52, whose
    // low word is the integer k + 1023.
    let biased = (k + (1023.0 + TWO_52)).to_bits() & 0x7ff;
    let scale = f64::from_bits(biased << 52);
    (if tiny { 1.0 + x } else { y * scale }, ordinary)
}

/// 2^52: below it, `v + 2^52` holds the integer v in its low bits.
const TWO_52: f64 = 4_503_599_627_370_496.0;

/// `out.len()` draws of `rand_distr::StandardNormal`: exactly those that
/// `rng.sample(StandardNormal)` gives one call at a time, leaving `rng`
/// where those calls would (the test holds ChaCha to that). The words are
/// taken in bulk (`fill_bytes`), which for rand's generators, block ones
/// like ChaCha and word ones alike, gives the words of `next_u64`.
///
/// rand_distr's ziggurat takes one 64-bit word a try, and accepts the
/// first try of 98.8 % of draws. Here the first tries of up to [`CHUNK`]
/// draws are made at once, vectorised; a draw whose first try fails goes
/// on as rand_distr's does, taking its further words from the batch's
/// unused ones first, and the next draws go on with the tries of the
/// words it left (made once: redoing the batch's tries after each
/// rejection had cost the fusion filter's step 5 % of its instructions).
/// The words are the same, in the same order, so every draw is.
#[inline(always)]
pub fn standard_normals<G: rand::RngCore + ?Sized>(rng: &mut G, out: &mut [f64]) {
    // Words drawn and not yet used, `words[start..end]`, and their first
    // tries. Never more words are drawn than draws remain, since every draw
    // uses at least one, so none is left over at the end.
    let mut words = [0u64; CHUNK];
    let (mut x, mut accepted) = ([0.0; CHUNK], [false; CHUNK]);
    let (mut start, mut end) = (0, 0);
    let mut done = 0;
    while done < out.len() {
        if start == end {
            let wanted = (out.len() - done).min(CHUNK);
            // In bulk: a block generator's bytes are its 32-bit words in
            // order, little-endian, two to a `next_u64` (low word first),
            // so these are the words `next_u64` would give one by one.
            let mut bytes = [0u8; 8 * CHUNK];
            let bytes = &mut bytes[..8 * wanted];
            rng.fill_bytes(bytes);
            for (w, b) in words.iter_mut().zip(bytes.chunks_exact(8)) {
                *w = u64::from_le_bytes(b.try_into().expect("eight bytes"));
            }
            // Every lane, vectorised; those from `wanted` on are stale.
            for j in 0..CHUNK {
                (x[j], accepted[j]) = first_try(words[j]);
            }
            (start, end) = (0, wanted);
        }
        // The accepted tries up to the next rejected one are draws.
        let run = accepted[start..end]
            .iter()
            .position(|&ok| !ok)
            .unwrap_or(end - start);
        out[done..done + run].copy_from_slice(&x[start..start + run]);
        (done, start) = (done + run, start + run);
        if start < end {
            // The rest of a rejected draw takes the batch's next words
            // first; the tries already made of those it leaves stand.
            let rejected = words[start];
            start += 1;
            let mut next = || {
                if start < end {
                    start += 1;
                    words[start - 1]
                } else {
                    rng.next_u64()
                }
            };
            out[done] = after_first_try(rejected, &mut next);
            done += 1;
        }
    }
}

/// The ziggurat's try with the word `bits`: its x, and whether x is
/// accepted outright. As rand_distr's `ziggurat` (symmetric): the low 8
/// bits pick the layer, the high 52 make u in [−1, 1).
#[inline(always)]
fn first_try(bits: u64) -> (f64, bool) {
    let i = (bits & 0xff) as usize;
    let u = f64::from_bits((bits >> 12) | (1024 << 52)) - 3.0;
    let x = u * X[i];
    (x, x.abs() < X[i + 1])
}

/// The rest of rand_distr's ziggurat for a draw whose try with `bits`
/// was not accepted outright, each further word from `next`.
#[cold]
fn after_first_try(mut bits: u64, next: &mut impl FnMut() -> u64) -> f64 {
    loop {
        let i = (bits & 0xff) as usize;
        let u = f64::from_bits((bits >> 12) | (1024 << 52)) - 3.0;
        let x = u * X[i];
        if x.abs() < X[i + 1] {
            return x;
        }
        if i == 0 {
            return normal_tail(u, next);
        }
        // StandardUniform's f64: the top 53 bits over 2^53.
        let uniform = (next() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        if F[i + 1] + (F[i] - F[i + 1]) * uniform < (-x * x / 2.0).exp() {
            return x;
        }
        bits = next();
    }
}

/// rand_distr's draw from the normal's tail beyond R (its `zero_case`).
fn normal_tail(u: f64, next: &mut impl FnMut() -> u64) -> f64 {
    // Open01's f64: the top 52 bits as a mantissa in [1, 2), less 1 − ε/2.
    let mut open01 = || f64::from_bits((next() >> 12) | (1023 << 52)) - (1.0 - f64::EPSILON / 2.0);
    let (mut x, mut y) = (1.0f64, 0.0f64);
    while -2.0 * y < x * x {
        let (x_, y_) = (open01(), open01());
        x = x_.ln() / R;
        y = y_.ln();
    }
    if u < 0.0 {
        x - R
    } else {
        R - x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::FRAC_PI_4;

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn atan2_avx2(y: &[f64; CHUNK], x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
        atan2(y, x, out)
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn atan2_avx2(y: &[f64; CHUNK], x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
        atan2(y, x, out)
    }

    fn check(y: &[f64; CHUNK], x: &[f64; CHUNK]) {
        let mut out = [0.0; CHUNK];
        if has_avx2() {
            // SAFETY: the CPU has AVX2.
            unsafe { atan2_avx2(y, x, &mut out) };
        } else {
            atan2(y, x, &mut out);
        }
        let mut scalar = [0.0; CHUNK];
        atan2(y, x, &mut scalar);
        for i in 0..CHUNK {
            let want = libm::atan2(y[i], x[i]);
            for got in [out[i], scalar[i]] {
                assert!(
                    got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                    "atan2({:e}, {:e}) = {got:e}, libm {want:e}",
                    y[i],
                    x[i]
                );
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn sincos_avx2(x: &[f64; CHUNK], sin: &mut [f64; CHUNK], cos: &mut [f64; CHUNK]) {
        sincos(x, sin, cos)
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn sincos_avx2(x: &[f64; CHUNK], sin: &mut [f64; CHUNK], cos: &mut [f64; CHUNK]) {
        sincos(x, sin, cos)
    }

    /// Bit for bit libm's, vectorised or not: turns of every size a
    /// coordinated turn meets (|ωT| from 1e-12 to π/4 and beyond), and
    /// the edges and special values.
    #[test]
    fn sincos_is_libm_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let mut batches: Vec<[f64; CHUNK]> = (0..2000)
            .map(|_| {
                std::array::from_fn(|_| {
                    let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
                    sign * 10f64.powf(rng.random_range(-12.0..0.5))
                })
            })
            .collect();
        let specials = [
            0.0,
            -0.0,
            FRAC_PI_4,
            -FRAC_PI_4,
            FRAC_PI_4.next_up(),
            f64::from_bits(0x3e46_a09e_0000_0000),
            f64::from_bits(0x3e46_a09d_ffff_ffff),
            f64::MIN_POSITIVE / 8.0,
            1e-300,
            3.0,
            -1e6,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        let mut edge = [0.5; CHUNK];
        edge[..specials.len()].copy_from_slice(&specials);
        batches.push(edge);
        for x in &batches {
            let (mut s, mut c) = ([0.0; CHUNK], [0.0; CHUNK]);
            let (mut sv, mut cv) = ([0.0; CHUNK], [0.0; CHUNK]);
            sincos(x, &mut s, &mut c);
            if has_avx2() {
                // SAFETY: the CPU has AVX2.
                unsafe { sincos_avx2(x, &mut sv, &mut cv) };
            } else {
                (sv, cv) = (s, c);
            }
            for i in 0..CHUNK {
                let (ws, wc) = libm::sincos(x[i]);
                for (gs, gc) in [(s[i], c[i]), (sv[i], cv[i])] {
                    let same =
                        |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
                    assert!(
                        same(gs, ws) && same(gc, wc),
                        "sincos({:e}) = ({gs:e}, {gc:e}), libm ({ws:e}, {wc:e})",
                        x[i]
                    );
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn normals_avx2(rng: &mut ChaCha8Rng, out: &mut [f64]) {
        standard_normals(rng, out)
    }

    /// The draws are rand_distr's, one by one, bit for bit, vectorised or
    /// not, and the generator ends where theirs does: over a million draws
    /// in batches of every length up to three chunks, enough for thousands
    /// of second tries and hundreds from the tail.
    #[test]
    fn standard_normals_are_rand_distrs_bit_for_bit() {
        use rand_distr::StandardNormal;
        let mut lengths = ChaCha8Rng::seed_from_u64(2);
        for vectorise in [false, true] {
            let mut ours = ChaCha8Rng::seed_from_u64(13);
            let mut theirs = ours.clone();
            let (mut drawn, mut tails) = (0, 0);
            while drawn < 600_000 {
                let n = lengths.random_range(0..3 * CHUNK + 2);
                let mut out = vec![0.0; n];
                if vectorise && has_avx2() {
                    // SAFETY: the CPU has AVX2.
                    unsafe { normals_avx2(&mut ours, &mut out) };
                } else {
                    standard_normals(&mut ours, &mut out);
                }
                for got in out {
                    let want: f64 = theirs.sample(StandardNormal);
                    assert_eq!(got.to_bits(), want.to_bits(), "draw {drawn}");
                    tails += usize::from(want.abs() > R);
                    drawn += 1;
                }
                assert_eq!(ours.get_word_pos(), theirs.get_word_pos());
            }
            assert!(tails > 50, "{tails} draws from the tail");
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn exp_avx2(x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
        exp(x, out)
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn exp_avx2(x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
        exp(x, out)
    }

    /// Bit for bit libm's, vectorised or not: the tempering exponents
    /// (−50 to 0) and every scale either side, the edges of the reduction's
    /// three cases and of the lanes handed to libm, and the special values.
    #[test]
    fn exp_is_libm_bit_for_bit() {
        let check = |x: &[f64; CHUNK]| {
            let mut out = [0.0; CHUNK];
            if has_avx2() {
                // SAFETY: the CPU has AVX2.
                unsafe { exp_avx2(x, &mut out) };
            } else {
                exp(x, &mut out);
            }
            let mut scalar = [0.0; CHUNK];
            exp(x, &mut scalar);
            for i in 0..CHUNK {
                let want = libm::exp(x[i]);
                for got in [out[i], scalar[i]] {
                    assert!(
                        got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                        "exp({:e}) = {got:e}, libm {want:e}",
                        x[i]
                    );
                }
            }
        };
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for _ in 0..6000 {
            let mut x = [0.0; CHUNK];
            for v in x.iter_mut() {
                *v = match rng.random_range(0..3) {
                    0 => rng.random_range(-50.0..0.0),
                    1 => rng.random_range(-760.0..760.0),
                    _ => rng.random_range(-1.0..1.0) * 10f64.powf(rng.random_range(-12.0..1.0)),
                };
            }
            check(&x);
        }
        // Each threshold's high word, and the doubles either side of it.
        let edges = [0x4086_232b_u64, 0x3fd6_2e42, 0x3ff0_a2b2, 0x3e30_0000]
            .into_iter()
            .flat_map(|w| {
                let at = f64::from_bits(w << 32);
                [
                    at.next_down(),
                    at,
                    at.next_up(),
                    f64::from_bits((w << 32) | 0xffff_ffff),
                ]
            });
        let mut specials: Vec<f64> = edges
            .chain([
                0.0,
                f64::MIN_POSITIVE,
                1e-310,
                0.5 * std::f64::consts::LN_2,
                1.5 * std::f64::consts::LN_2,
                709.78,
                709.8,
                745.13,
                745.2,
                f64::MAX,
                f64::INFINITY,
                f64::NAN,
            ])
            .collect();
        specials.extend(specials.clone().iter().map(|v| -v));
        for batch in specials.chunks(CHUNK) {
            let mut x = [0.25; CHUNK];
            x[..batch.len()].copy_from_slice(batch);
            check(&x);
        }
    }

    /// Bit for bit libm's, vectorised or not: over random offsets at every
    /// scale and sign (each of atan's five intervals, all four quadrants),
    /// and over the special values and the edges of the reduction.
    #[test]
    fn atan2_is_libm_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..4000 {
            let mut y = [0.0; CHUNK];
            let mut x = [0.0; CHUNK];
            for i in 0..CHUNK {
                let scale = 10f64.powf(rng.random_range(-3.0..4.0));
                y[i] = rng.random_range(-1.0..1.0) * scale;
                x[i] =
                    rng.random_range(-1.0..1.0) * scale * 10f64.powf(rng.random_range(-2.0..2.0));
            }
            check(&y, &x);
        }
        let specials = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.4375,
            0.6875,
            1.1875,
            2.4375,
            f64::from_bits(0x3e40_0000_0000_0000),
            f64::MIN_POSITIVE,
            f64::MIN_POSITIVE / 4.0,
            1e-300,
            1e300,
            f64::MAX,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            2f64.powi(60),
            2f64.powi(-60),
            2f64.powi(64),
            3.0,
            -7.5,
        ];
        let pairs: Vec<(f64, f64)> = specials
            .iter()
            .flat_map(|&a| specials.iter().map(move |&b| (a, b)))
            .collect();
        for batch in pairs.chunks(CHUNK) {
            let (mut y, mut x) = ([1.0; CHUNK], [1.0; CHUNK]);
            for (i, &(a, b)) in batch.iter().enumerate() {
                (y[i], x[i]) = (a, b);
            }
            check(&y, &x);
            check(&x, &y);
        }
    }
}
