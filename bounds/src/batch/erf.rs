//! fdlibm's (the `libm` crate's) `erf` and `erfc`, lane by lane, equal to
//! them bit for bit. A censored sensor's silence is a normal interval's
//! mass at every particle, two of these each; one at a time, their
//! branches on the argument's range and two `exp` calls were a third of
//! a censoring trial.
//!
//! fdlibm splits the argument's range four ways, each with its own
//! rational approximation. Here every lane evaluates all of them and
//! keeps its own, so the loop has no branch and vectorises. The far
//! range's two approximations (below and above 1/0.35) have one shape,
//! so a lane picks its coefficients instead; the shorter one's missing
//! top coefficient is zero, which leaves its Horner sum exactly as
//! fdlibm computes it. The far range's two exponentials are
//! [`super::exp_ordinary`]'s. Lanes it does not serve (infinite or NaN,
//! `erfc` from |x| = 28 on, an exponential that underflows) are redone by
//! `libm` itself.

// fdlibm's constants as its source prints them (to 21 digits), so that
// each can be checked against it; they parse to the same doubles.
#![allow(clippy::excessive_precision)]

use super::{exp_ordinary, CHUNK};

const ERX: f64 = 8.45062911510467529297e-01;
const EFX8: f64 = 1.02703333676410069053e+00;
/// |x| < 0.84375: `x + x·P(x²)/Q(x²)`.
const PP: [f64; 5] = [
    1.28379167095512558561e-01,
    -3.25042107247001499370e-01,
    -2.84817495755985104766e-02,
    -5.77027029648944159157e-03,
    -2.37630166566501626084e-05,
];
const QQ: [f64; 5] = [
    3.97917223959155352819e-01,
    6.50222499887672944485e-02,
    5.08130628187576562776e-03,
    1.32494738004321644526e-04,
    -3.96022827877536812320e-06,
];
/// 0.84375 ≤ |x| < 1.25: `erx + P(s)/Q(s)`, s = |x| − 1.
const PA: [f64; 7] = [
    -2.36211856075265944077e-03,
    4.14856118683748331666e-01,
    -3.72207876035701323847e-01,
    3.18346619901161753674e-01,
    -1.10894694282396677476e-01,
    3.54783043256182359371e-02,
    -2.16637559486879084300e-03,
];
const QA: [f64; 6] = [
    1.06420880400844228286e-01,
    5.40397917702171048937e-01,
    7.18286544141962662868e-02,
    1.26171219808761642112e-01,
    1.36370839120290507362e-02,
    1.19844998467991074170e-02,
];
/// 1.25 ≤ |x| < 1/0.35: R(s)/S(s), s = 1/x².
const RA: [f64; 8] = [
    -9.86494403484714822705e-03,
    -6.93858572707181764372e-01,
    -1.05586262253232909814e+01,
    -6.23753324503260060396e+01,
    -1.62396669462573470355e+02,
    -1.84605092906711035994e+02,
    -8.12874355063065934246e+01,
    -9.81432934416914548592e+00,
];
const SA: [f64; 8] = [
    1.96512716674392571292e+01,
    1.37657754143519042600e+02,
    4.34565877475229228821e+02,
    6.45387271733267880336e+02,
    4.29008140027567833386e+02,
    1.08635005541779435134e+02,
    6.57024977031928170135e+00,
    -6.04244152148580987438e-02,
];
/// |x| ≥ 1/0.35, padded with a zero top coefficient to RA's and SA's
/// length: `c₆ + s·0` is `c₆`, so the sums are fdlibm's.
const RB: [f64; 8] = [
    -9.86494292470009928597e-03,
    -7.99283237680523006574e-01,
    -1.77579549177547519889e+01,
    -1.60636384855821916062e+02,
    -6.37566443368389627722e+02,
    -1.02509513161107724954e+03,
    -4.83519191608651397019e+02,
    0.0,
];
const SB: [f64; 8] = [
    3.03380607434824582924e+01,
    3.25792512996573918826e+02,
    1.53672958608443695994e+03,
    3.19985821950859553908e+03,
    2.55305040643316442583e+03,
    4.74528541206955367215e+02,
    -2.24409524465858183362e+01,
    0.0,
];
/// The smallest positive normal, fdlibm's `x1p_1022`.
const TINY: f64 = f64::from_bits(0x0010_0000_0000_0000);

/// `erfc(x)` where `complement[i]`, `erf(x)` elsewhere, lane by lane,
/// equal to `libm::erfc` and `libm::erf` bit for bit.
#[inline(always)]
pub fn erf_or_erfc(x: &[f64; CHUNK], complement: &[bool; CHUNK], out: &mut [f64; CHUNK]) {
    let mut ordinary = [false; CHUNK];
    for i in 0..CHUNK {
        let (v, ok) = lane(x[i], complement[i]);
        out[i] = v;
        ordinary[i] = ok;
    }
    if ordinary.iter().all(|&ok| ok) {
        return;
    }
    for i in 0..CHUNK {
        if !ordinary[i] {
            out[i] = if complement[i] {
                libm::erfc(x[i])
            } else {
                libm::erf(x[i])
            };
        }
    }
}

/// `erf(x)` lane by lane, as `libm::erf`.
#[inline(always)]
pub fn erf(x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
    erf_or_erfc(x, &[false; CHUNK], out)
}

/// `erfc(x)` lane by lane, as `libm::erfc`.
#[inline(always)]
pub fn erfc(x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
    erf_or_erfc(x, &[true; CHUNK], out)
}

/// One lane: the value, and whether the lane is ordinary (otherwise the
/// value is to be discarded). Branch-free: fdlibm's tests on the high word
/// of |x| become comparisons of |x| itself, `hx < w` as `|x| < at(w)`.
#[inline(always)]
fn lane(x: f64, complement: bool) -> (f64, bool) {
    const fn at(high_word: u64) -> f64 {
        f64::from_bits(high_word << 32)
    }
    let a = x.abs();
    // fdlibm's sign is the sign bit: −0 counts as negative.
    let negative = x.is_sign_negative();
    let finite = a < at(0x7ff0_0000);
    let small = a < at(0x3feb_0000); // 0.84375
    let middle = a < at(0x3ff4_0000); // 1.25
    let near = a < at(0x4006_db6d); // 1/0.35

    // |x| < 0.84375.
    let z = x * x;
    let r = PP[0] + z * (PP[1] + z * (PP[2] + z * (PP[3] + z * PP[4])));
    let s = 1.0 + z * (QQ[0] + z * (QQ[1] + z * (QQ[2] + z * (QQ[3] + z * QQ[4]))));
    let y = r / s;

    // 0.84375 ≤ |x| < 1.25: fdlibm's erfc1.
    let t = a - 1.0;
    let p = PA[0] + t * (PA[1] + t * (PA[2] + t * (PA[3] + t * (PA[4] + t * (PA[5] + t * PA[6])))));
    let q = 1.0 + t * (QA[0] + t * (QA[1] + t * (QA[2] + t * (QA[3] + t * (QA[4] + t * QA[5])))));
    let erfc1 = 1.0 - ERX - p / q;

    // 1.25 ≤ |x|: fdlibm's erfc2, coefficients chosen by the lane.
    let c = |k: usize| if near { RA[k] } else { RB[k] };
    let d = |k: usize| if near { SA[k] } else { SB[k] };
    let w = 1.0 / (a * a);
    let rr = c(0)
        + w * (c(1) + w * (c(2) + w * (c(3) + w * (c(4) + w * (c(5) + w * (c(6) + w * c(7)))))));
    let ss = 1.0
        + w * (d(0)
            + w * (d(1)
                + w * (d(2) + w * (d(3) + w * (d(4) + w * (d(5) + w * (d(6) + w * d(7))))))));
    let zz = f64::from_bits(a.to_bits() & 0xffff_ffff_0000_0000);
    let (e1, ok1) = exp_ordinary(-zz * zz - 0.5625);
    let (e2, ok2) = exp_ordinary((zz - a) * (zz + a) + rr / ss);
    let erfc2 = e1 * e2 / a;
    // erfc2 of fdlibm returns erfc1 below 1.25.
    let far = if middle { erfc1 } else { erfc2 };
    let far_ok = middle || (ok1 && ok2);

    if complement {
        let value = if a < at(0x3c70_0000) {
            1.0 - x
        } else if small {
            if negative || a < at(0x3fd0_0000) {
                1.0 - (x + x * y)
            } else {
                0.5 - (x - 0.5 + x * y)
            }
        } else if negative {
            2.0 - far
        } else {
            far
        };
        let ok = finite && (small || (a < at(0x403c_0000) && far_ok));
        (value, ok)
    } else {
        let magnitude = if a < at(0x4018_0000) {
            1.0 - far
        } else {
            1.0 - TINY
        };
        let value = if a < at(0x3e30_0000) {
            0.125 * (8.0 * x + EFX8 * x)
        } else if small {
            x + x * y
        } else if negative {
            -magnitude
        } else {
            magnitude
        };
        let ok = finite && (small || a >= at(0x4018_0000) || far_ok);
        (value, ok)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::batch::has_avx2;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn erf_or_erfc_avx2(x: &[f64; CHUNK], c: &[bool; CHUNK], out: &mut [f64; CHUNK]) {
        erf_or_erfc(x, c, out)
    }

    /// Both functions at every lane, in the AVX2 copy and the baseline
    /// one, against `libm`, bit for bit (NaN as NaN).
    fn check(x: &[f64; CHUNK]) {
        for complement in [false, true] {
            let flags = [complement; CHUNK];
            let mut baseline = [0.0; CHUNK];
            erf_or_erfc(x, &flags, &mut baseline);
            let mut copies = vec![baseline];
            #[cfg(target_arch = "x86_64")]
            if has_avx2() {
                let mut out = [0.0; CHUNK];
                // SAFETY: the CPU has AVX2.
                unsafe { erf_or_erfc_avx2(x, &flags, &mut out) };
                copies.push(out);
            }
            for (i, &xi) in x.iter().enumerate() {
                let want = if complement {
                    libm::erfc(xi)
                } else {
                    libm::erf(xi)
                };
                for got in &copies {
                    assert!(
                        got[i].to_bits() == want.to_bits() || (got[i].is_nan() && want.is_nan()),
                        "{}({xi:e}) = {:e}, libm {want:e}",
                        if complement { "erfc" } else { "erf" },
                        got[i]
                    );
                }
            }
        }
    }

    #[test]
    fn equal_to_libm_bit_for_bit_over_every_range() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for _ in 0..4000 {
            // Uniform over the ranges met, and log-uniform magnitudes from
            // subnormal to past erfc's underflow.
            let x: [f64; CHUNK] = std::array::from_fn(|i| {
                let sign = if rng.random::<bool>() { -1.0 } else { 1.0 };
                if i % 2 == 0 {
                    rng.random_range(-30.0..30.0)
                } else {
                    sign * 10f64.powf(rng.random_range(-310.0..1.7))
                }
            });
            check(&x);
        }
    }

    #[test]
    fn equal_to_libm_at_each_range_edge_and_special_value() {
        let edges = [
            0x3feb_0000u64, // 0.84375
            0x3ff4_0000,    // 1.25
            0x4006_db6d,    // 1/0.35
            0x4018_0000,    // 6
            0x403c_0000,    // 28
            0x3e30_0000,    // 2^-28
            0x3c70_0000,    // 2^-56
            0x3fd0_0000,    // 1/4
        ];
        let mut values = vec![0.0, -0.0, f64::INFINITY, f64::NEG_INFINITY, f64::NAN];
        for w in edges {
            let at = f64::from_bits(w << 32);
            for v in [
                at,
                at.next_down(),
                at.next_up(),
                f64::from_bits((w << 32) | 0xffff_ffff),
            ] {
                values.extend([v, -v]);
            }
        }
        // 26 to 27.5: where erfc's exponential underflows.
        values.extend((0..40).map(|k| 26.0 + 0.04 * f64::from(k)));
        for chunk in values.chunks(CHUNK) {
            let mut x = [1.0; CHUNK];
            x[..chunk.len()].copy_from_slice(chunk);
            check(&x);
        }
    }
}
