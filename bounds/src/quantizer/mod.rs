//! The sensor's quantizer: cells, encoding to bytes, cell probabilities
//! `h_i(x)` and their sensitivities, and the per-observation Fisher scalars.
//!
//! `cells.rs` is the quantizer and its encoding, `likelihood.rs` a cell's
//! probability, `fisher.rs` the Fisher scalars, and `table_reads.rs` where
//! both read the tables.

mod cells;
mod fisher;
mod likelihood;
mod table_reads;

pub use crate::cell_sums::{FisherScalars, ScalarBatch, WINDOW_SIGMAS};
pub use cells::{Quantizer, MAX_BITS};
pub use fisher::{quantized_fisher_information, try_quantized_fisher_information, CellSensitivity};
pub use table_reads::TableReads;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::batch::CHUNK;
    use crate::QuantizerError;
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
        let coarse = Quantizer::uniform_wrapped(2, -PI, PI).unwrap();
        let cases: Vec<(&Quantizer, f64, f64)> = vec![
            (&bearing, 0.1, 0.02),
            (&bearing, 3.13, 0.05),        // window crosses +π
            (&bearing, -PI + 0.002, 0.09), // window crosses −π
            (&bearing, 1.0, 0.004),        // far narrower than a cell
            (&rss, -50.0, 2.0),
            (&rss, -99.0, 3.0), // window reaches the unbounded cell
            (&rss, 20.0, 1.0),  // mean beyond the last edge
            (&rss, -50.0, 0.3), // table: interior, σ ≈ 0.8 cells
            // The window spans the circle: the wrapped table.
            (&bearing, 2.0, 0.5),  // σ ≈ 20 cells
            (&bearing, 0.3, 0.36), // just past the span
            (&bearing, -3.0, 1.5), // several turns in the window
            (&bearing, 1.0, 9.0),  // past where the table reads zero
            (&coarse, 0.7, 0.9),   // 4 cells, over u too
            (&coarse, 0.7, 0.3),   // narrower than a cell: exact
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
