//! The standard normal distribution, computed so that cell probabilities keep
//! their relative precision far into the tails.
//!
//! `1 − Φ(x)` loses every digit once `Φ(x)` rounds to one (x ≳ 8.3), while an
//! 8-bit cell 30σ from the mean still has a perfectly representable
//! probability. So every difference of `Φ` here is taken on the side of the
//! tail, with the complementary error function, and logarithms switch to the
//! asymptotic (Mills ratio) expansion before `erfc` underflows.

use std::f64::consts::{FRAC_1_SQRT_2, LN_2, PI};

use crate::batch::CHUNK;

/// `1/√(2π)`.
pub const INV_SQRT_2PI: f64 = 0.398_942_280_401_432_7;

/// Beyond this argument `ln Q(x)` uses the asymptotic series; `Q(35) ≈ 1e-268`
/// is still a normal f64 and the series' truncation error there is ~1e-13.
const ASYMPTOTIC_FROM: f64 = 35.0;

/// Density `φ(x)`; zero at ±∞.
#[inline]
pub fn pdf(x: f64) -> f64 {
    if x.is_infinite() {
        0.0
    } else {
        INV_SQRT_2PI * (-0.5 * x * x).exp()
    }
}

/// `x φ(x)`, with the limit 0 at ±∞ (the naive product is `∞ · 0 = NaN`).
#[inline]
pub fn x_pdf(x: f64) -> f64 {
    pdf_and_x_pdf(x).1
}

/// `(φ(x), x φ(x))`, φ computed once.
#[inline]
pub fn pdf_and_x_pdf(x: f64) -> (f64, f64) {
    let pdf = pdf(x);
    (pdf, if x.is_infinite() { 0.0 } else { x * pdf })
}

/// Distribution function `Φ(x)`.
#[inline]
pub fn cdf(x: f64) -> f64 {
    0.5 * libm::erfc(-x * FRAC_1_SQRT_2)
}

/// Upper tail `Q(x) = 1 − Φ(x)`, accurate for large positive x.
#[inline]
pub fn upper_tail(x: f64) -> f64 {
    0.5 * libm::erfc(x * FRAC_1_SQRT_2)
}

/// `Q⁻¹(p)`: the x with `Q(x) = p`, for `0 < p < 1`. Bisection to the last
/// bit: it is called once per threshold, never per particle, and needs no
/// rational approximation with its own error to check.
pub fn upper_tail_inverse(p: f64) -> f64 {
    debug_assert!(p > 0.0 && p < 1.0, "Q⁻¹ of {p}");
    let (mut lo, mut hi) = (-40.0_f64, 40.0_f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        // Q falls with x.
        if upper_tail(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// `ln Q(x)`, finite for every finite x.
pub fn ln_upper_tail(x: f64) -> f64 {
    if x == f64::INFINITY {
        return f64::NEG_INFINITY;
    }
    if x < 0.0 {
        // Q(x) = 1 − Q(−x) with Q(−x) ≤ 1/2: no cancellation.
        return (-upper_tail(-x)).ln_1p();
    }
    if x < ASYMPTOTIC_FROM {
        return upper_tail(x).ln();
    }
    // Q(x) = φ(x)/x · (1 − 1/x² + 3/x⁴ − 15/x⁶ + 105/x⁸ − …)
    let inv2 = 1.0 / (x * x);
    let series = 1.0 - inv2 * (1.0 - inv2 * (3.0 - inv2 * (15.0 - inv2 * 105.0)));
    -0.5 * x * x - x.ln() - 0.5 * (2.0 * PI).ln() + series.ln()
}

/// Probability `P(a < Z < b)` for a standard normal Z, `a ≤ b`, computed on
/// the tail side so that its relative error stays near machine precision.
pub fn interval_mass(a: f64, b: f64) -> f64 {
    if a >= 0.0 {
        upper_tail(a) - upper_tail(b)
    } else if b <= 0.0 {
        upper_tail(-b) - upper_tail(-a)
    } else {
        // Straddles zero: the two erf values have opposite signs, so this is a
        // sum of magnitudes.
        0.5 * (libm::erf(b * FRAC_1_SQRT_2) - libm::erf(a * FRAC_1_SQRT_2))
    }
}

/// `ln P(a < Z < b)`, finite whenever `a < b`, however far the interval is
/// from zero.
pub fn ln_interval_mass(a: f64, b: f64) -> f64 {
    if a >= b {
        return f64::NEG_INFINITY;
    }
    if a >= 0.0 {
        ln_tail_difference(a, b)
    } else if b <= 0.0 {
        ln_tail_difference(-b, -a)
    } else {
        interval_mass(a, b).ln()
    }
}

/// [`ln_interval_mass`] at a batch of intervals, equal to it lane by
/// lane, bit for bit: the two `erfc` (an interval in a tail) or `erf`
/// (one that straddles zero) of every lane in one vectorised pass
/// ([`crate::batch::erf_or_erfc`]), then each lane's logarithm. A lane
/// whose difference the direct form would not keep to a few ulps (the far
/// tail, or a cell too narrow for its tail) takes the scalar path.
#[inline(always)]
pub fn ln_interval_mass_batch(a: &[f64; CHUNK], b: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
    // Each lane's interval as the scalar code takes it: a tail's mirrored
    // onto the positive side, and whether it is a tail.
    let (mut lo, mut hi, mut tail) = ([0.0; CHUNK], [0.0; CHUNK], [false; CHUNK]);
    let mut near_end = [0.0; CHUNK];
    for i in 0..CHUNK {
        let (l, h, t) = if a[i] >= 0.0 {
            (a[i], b[i], true)
        } else if b[i] <= 0.0 {
            (-b[i], -a[i], true)
        } else {
            (a[i], b[i], false)
        };
        near_end[i] = l;
        lo[i] = l * FRAC_1_SQRT_2;
        hi[i] = h * FRAC_1_SQRT_2;
        tail[i] = t;
    }
    let (mut e_lo, mut e_hi) = ([0.0; CHUNK], [0.0; CHUNK]);
    crate::batch::erf_or_erfc(&lo, &tail, &mut e_lo);
    crate::batch::erf_or_erfc(&hi, &tail, &mut e_hi);
    for i in 0..CHUNK {
        out[i] = if a[i] >= b[i] {
            f64::NEG_INFINITY
        } else if tail[i] {
            // ln_tail_difference's first form, from the same erfc values.
            let (qa, qb) = (0.5 * e_lo[i], 0.5 * e_hi[i]);
            if near_end[i] < ASYMPTOTIC_FROM && qb <= 0.9 * qa {
                (qa - qb).ln()
            } else {
                ln_interval_mass(a[i], b[i])
            }
        } else {
            (0.5 * (e_hi[i] - e_lo[i])).ln()
        };
    }
}

/// `ln(Q(a) − Q(b))` for `0 ≤ a < b`.
fn ln_tail_difference(a: f64, b: f64) -> f64 {
    if a < ASYMPTOTIC_FROM {
        // While Q(a) is a normal number and Q(b) ≤ 0.9 Q(a), the direct
        // difference loses at most a few ulps: one log instead of three.
        let (qa, qb) = (upper_tail(a), upper_tail(b));
        if qb <= 0.9 * qa {
            return (qa - qb).ln();
        }
    }
    // ln Q(a) + ln(1 − e^{ln Q(b) − ln Q(a)})
    let ln_qa = ln_upper_tail(a);
    if b == f64::INFINITY {
        return ln_qa;
    }
    let d = ln_upper_tail(b) - ln_qa;
    ln_qa + ln_one_minus_exp(d)
}

/// `ln(1 − eᵈ)` for `d ≤ 0`, accurate both for d near 0 and for d ≪ 0.
#[inline]
fn ln_one_minus_exp(d: f64) -> f64 {
    if d > -LN_2 {
        (-d.exp_m1()).ln()
    } else {
        (-d.exp()).ln_1p()
    }
}

/// `ln(Σ eˣⁱ)` without overflow; `−∞` for an empty or all-`−∞` input.
pub fn ln_sum_exp(values: &[f64]) -> f64 {
    let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if max == f64::NEG_INFINITY {
        return max;
    }
    max + values.iter().map(|v| (v - max).exp()).sum::<f64>().ln()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn batch_avx2(a: &[f64; CHUNK], b: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
        ln_interval_mass_batch(a, b, out)
    }

    /// The batch, in the AVX2 copy and the baseline one, against the
    /// scalar function at every lane, bit for bit: intervals anywhere from
    /// −45 to 45 and of any width, empty ones, half-lines.
    #[test]
    fn the_batch_interval_mass_is_the_scalar_one_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        for round in 0..3000 {
            let a: [f64; CHUNK] = std::array::from_fn(|_| rng.random_range(-45.0..45.0));
            let b: [f64; CHUNK] = std::array::from_fn(|i| match (round + i) % 5 {
                0 => a[i] + rng.random_range(0.0..0.01),
                1 => a[i] + rng.random_range(0.0..4.0),
                2 => rng.random_range(-45.0..45.0),
                3 => f64::INFINITY,
                _ => a[i] + 10f64.powf(rng.random_range(-12.0..0.0)),
            });
            let mut copies = Vec::new();
            let mut out = [0.0; CHUNK];
            ln_interval_mass_batch(&a, &b, &mut out);
            copies.push(out);
            #[cfg(target_arch = "x86_64")]
            if crate::batch::has_avx2() {
                // SAFETY: the CPU has AVX2.
                unsafe { batch_avx2(&a, &b, &mut out) };
                copies.push(out);
            }
            for i in 0..CHUNK {
                let want = ln_interval_mass(a[i], b[i]);
                for got in &copies {
                    assert!(
                        got[i].to_bits() == want.to_bits() || (got[i].is_nan() && want.is_nan()),
                        "ln P({}, {}) = {:e}, scalar {want:e}",
                        a[i],
                        b[i],
                        got[i]
                    );
                }
            }
        }
    }

    #[test]
    fn the_tail_inverse_gives_the_tabulated_quantiles_and_round_trips() {
        assert!((upper_tail_inverse(0.025) - 1.959_963_984_540_054).abs() < 1e-12);
        assert!((upper_tail_inverse(0.05) - 1.644_853_626_951_472_2).abs() < 1e-12);
        assert!(upper_tail_inverse(0.5).abs() < 1e-12);
        for p in [1e-12, 1e-4, 0.1, 0.3, 0.7, 0.99] {
            let x = upper_tail_inverse(p);
            assert!((upper_tail(x) - p).abs() < 1e-13 * p.max(1e-3), "{p}");
        }
    }

    #[test]
    fn cdf_known_values() {
        assert!((cdf(0.0) - 0.5).abs() < 1e-16);
        assert!((cdf(1.959_963_984_540_054) - 0.975).abs() < 1e-15);
        // Q(10) = 7.619853024160527e-24 (tabulated).
        assert!((upper_tail(10.0) / 7.619_853_024_160_527e-24 - 1.0).abs() < 1e-13);
    }

    #[test]
    // The references are mpmath's digits as printed.
    #[allow(clippy::excessive_precision, clippy::inconsistent_digit_grouping)]
    fn ln_upper_tail_matches_reference_values_on_both_sides_of_the_series_switch() {
        // ln Q(x) from mpmath at 40 digits.
        for (x, reference) in [
            (34.5, -599.585_736_259_472_36),
            (35.5, -634.614_263_155_088_4),
            (50.0, -1254.831_361_139_42),
        ] {
            let v = ln_upper_tail(x);
            assert!(
                (v - reference).abs() < 1e-11 * reference.abs(),
                "x = {x}: {v} vs {reference}"
            );
        }
    }

    #[test]
    fn ln_upper_tail_far_out_matches_the_leading_term() {
        // At x = 100, ln Q ≈ −x²/2 − ln x − ln√(2π) − 1/x²  (series to first order).
        let x = 100.0_f64;
        let expected = -0.5 * x * x - x.ln() - 0.5 * (2.0 * PI).ln() - 1.0 / (x * x);
        assert!((ln_upper_tail(x) - expected).abs() < 1e-7);
    }

    #[test]
    fn interval_mass_is_symmetric_and_additive() {
        for &(a, b) in &[(-3.0, -1.0), (-0.5, 0.25), (0.1, 7.0), (2.0, f64::INFINITY)] {
            let m = interval_mass(a, b);
            assert!((m - interval_mass(-b, -a)).abs() < 1e-16);
            let mid = if b.is_finite() {
                0.5 * (a + b)
            } else {
                a + 1.0
            };
            assert!((m - interval_mass(a, mid) - interval_mass(mid, b)).abs() < 1e-15);
        }
        assert!((interval_mass(f64::NEG_INFINITY, f64::INFINITY) - 1.0).abs() < 1e-16);
    }

    #[test]
    fn ln_interval_mass_agrees_with_direct_log_where_both_work() {
        for &(a, b) in &[(-1.0, 1.0), (3.0, 3.5), (-9.0, -8.0), (20.0, 20.1)] {
            let direct = interval_mass(a, b).ln();
            assert!((ln_interval_mass(a, b) - direct).abs() < 1e-10, "{a} {b}");
        }
        // Far beyond f64's range for the probability itself.
        let far = ln_interval_mass(60.0, 60.5);
        assert!(far.is_finite() && far < -1790.0);
    }
}
