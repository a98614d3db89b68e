//! The resampler: which old particle each new one copies, from the
//! weights. Four schemes (`filter.resampler`), each unbiased (particle i
//! is copied `N w_i` times in expectation) and each allocating nothing:
//! `take(slot, ancestor)` is called once for every new particle's slot,
//! with the old particle it copies.
//!
//! The weights are normalized (they sum to one, up to rounding); the walk
//! over their cumulative sum never runs past the last particle, so that
//! rounding cannot make a copy of nothing.

use fusion_graph::scenario::Resampling;
use rand::Rng;

/// Resamples `weights` by `scheme`.
pub fn resample<R: Rng + ?Sized>(
    scheme: Resampling,
    weights: &[f64],
    rng: &mut R,
    take: impl FnMut(usize, usize),
) {
    match scheme {
        Resampling::Systematic => systematic(weights, rng, take),
        Resampling::Stratified => stratified(weights, rng, take),
        Resampling::Residual => residual(weights, rng, take),
        Resampling::Multinomial => multinomial(weights, rng, take),
    }
}

/// One uniform draw places `n` evenly spaced points on the weights'
/// cumulative sum.
pub fn systematic<R: Rng + ?Sized>(weights: &[f64], rng: &mut R, take: impl FnMut(usize, usize)) {
    let step = 1.0 / weights.len() as f64;
    let mut u = rng.random::<f64>() * step;
    ascending_points(
        weights,
        |_| {
            let point = u;
            u += step;
            point
        },
        take,
    );
}

/// One uniform point in each of `n` equal strata of the cumulative sum.
pub fn stratified<R: Rng + ?Sized>(weights: &[f64], rng: &mut R, take: impl FnMut(usize, usize)) {
    let step = 1.0 / weights.len() as f64;
    ascending_points(
        weights,
        |slot| (slot as f64 + rng.random::<f64>()) * step,
        take,
    );
}

/// Slot `s` copies the particle under `point(s)` on the weights'
/// cumulative sum, for points that never decrease from slot to slot, so
/// that one walk up the sum serves them all.
#[inline(always)]
fn ascending_points(
    weights: &[f64],
    mut point: impl FnMut(usize) -> f64,
    mut take: impl FnMut(usize, usize),
) {
    let n = weights.len();
    let mut cumulative = weights[0];
    let mut i = 0;
    for slot in 0..n {
        let u = point(slot);
        while u > cumulative && i + 1 < n {
            i += 1;
            cumulative += weights[i];
        }
        take(slot, i);
    }
}

/// `n` independent draws. Drawn as `n` sorted uniforms, generated from the
/// largest down (the largest of k uniforms is `v^(1/k)`, and the rest lie
/// below it uniformly), so that one walk down the cumulative sum serves
/// them all without sorting or a buffer.
pub fn multinomial<R: Rng + ?Sized>(weights: &[f64], rng: &mut R, take: impl FnMut(usize, usize)) {
    let n = weights.len();
    let total: f64 = weights.iter().sum();
    descending_draws(n, total, n, |k| weights[k], rng, take, 0);
}

/// `⌊N w_i⌋` copies of each particle, then the `R` slots left drawn
/// multinomially from the remainders `N w_i − ⌊N w_i⌋`.
pub fn residual<R: Rng + ?Sized>(weights: &[f64], rng: &mut R, mut take: impl FnMut(usize, usize)) {
    let n = weights.len();
    let scale = n as f64;
    let mut slot = 0;
    let mut left = 0.0;
    for (i, w) in weights.iter().enumerate() {
        let copies = (scale * w).floor() as usize;
        for _ in 0..copies.min(n - slot) {
            take(slot, i);
            slot += 1;
        }
        left += scale * w - (scale * w).floor();
    }
    let remainder = |k: usize| scale * weights[k] - (scale * weights[k]).floor();
    descending_draws(n - slot, left, n, remainder, rng, take, slot);
}

/// `count` independent draws from the masses `mass(0..len)` (summing to
/// `total`), handed to `take` as slots `first..first + count`.
fn descending_draws<R: Rng + ?Sized>(
    count: usize,
    total: f64,
    len: usize,
    mass: impl Fn(usize) -> f64,
    rng: &mut R,
    mut take: impl FnMut(usize, usize),
    first: usize,
) {
    if count == 0 {
        return;
    }
    // `below`: the cumulative mass under particle i.
    let mut i = len - 1;
    let mut below = total - mass(i);
    let mut u = 1.0;
    for k in (1..=count).rev() {
        u *= rng.random::<f64>().powf(1.0 / k as f64);
        let point = u * total;
        while point < below && i > 0 {
            i -= 1;
            below -= mass(i);
        }
        take(first + k - 1, i);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    const SCHEMES: [Resampling; 4] = [
        Resampling::Systematic,
        Resampling::Stratified,
        Resampling::Residual,
        Resampling::Multinomial,
    ];

    /// Unbiased: over many resamplings, particle i's mean number of copies
    /// is `N w_i`, within 4.5 standard errors (each scheme's own, from
    /// the copies' spread), for weights from nearly uniform to one
    /// particle holding most; and every slot is filled once.
    #[test]
    fn every_scheme_copies_each_particle_n_times_its_weight_in_expectation() {
        let mut rng = ChaCha8Rng::seed_from_u64(58);
        let n = 12;
        let mut raw: Vec<Vec<f64>> = vec![
            (0..n).map(|i| 1.0 + 0.01 * i as f64).collect(),
            (0..n).map(|i| (i as f64 * 0.7).exp()).collect(),
            (0..n).map(|_| rng.random::<f64>()).collect(),
        ];
        raw[2][3] = 0.0;
        let trials = 40_000;
        for weights in raw {
            let total: f64 = weights.iter().sum();
            let weights: Vec<f64> = weights.iter().map(|w| w / total).collect();
            for scheme in SCHEMES {
                let (mut sum, mut sum_sq) = (vec![0.0; n], vec![0.0; n]);
                for _ in 0..trials {
                    let mut copies = vec![0usize; n];
                    let mut filled = vec![false; n];
                    resample(scheme, &weights, &mut rng, |slot, i| {
                        assert!(!filled[slot], "{scheme:?}: slot {slot} twice");
                        filled[slot] = true;
                        copies[i] += 1;
                    });
                    assert!(filled.iter().all(|f| *f), "{scheme:?}: a slot left empty");
                    for i in 0..n {
                        sum[i] += copies[i] as f64;
                        sum_sq[i] += (copies[i] * copies[i]) as f64;
                    }
                }
                for i in 0..n {
                    let mean = sum[i] / trials as f64;
                    let var = (sum_sq[i] / trials as f64 - mean * mean).max(0.0);
                    let se = (var / trials as f64).sqrt().max(1e-9);
                    let expected = n as f64 * weights[i];
                    assert!(
                        (mean - expected).abs() <= 4.5 * se + 1e-12,
                        "{scheme:?}, particle {i}: {mean} copies on average, expected {expected} (se {se})"
                    );
                }
            }
        }
    }

    /// A particle of zero weight is never copied, by any scheme.
    #[test]
    fn a_particle_of_no_weight_is_never_copied() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let weights = [0.0, 0.5, 0.0, 0.5, 0.0];
        for scheme in SCHEMES {
            for _ in 0..2000 {
                resample(scheme, &weights, &mut rng, |_, i| {
                    assert!(weights[i] > 0.0, "{scheme:?} copied particle {i}");
                });
            }
        }
    }

    /// The schemes differ in the spread of the copies: multinomial's
    /// variance of particle i's copies is `N w_i (1 − w_i)`, the others'
    /// less (residual's by the deterministic part, systematic's and
    /// stratified's at most a quarter on each particle here).
    #[test]
    fn multinomial_spreads_the_copies_as_the_binomial_and_the_others_less() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let weights = [0.05, 0.15, 0.3, 0.5];
        let n = weights.len();
        let trials = 40_000;
        let variance = |scheme, rng: &mut ChaCha8Rng| {
            let (mut s, mut s2) = (0.0, 0.0);
            for _ in 0..trials {
                let mut c = 0.0;
                resample(scheme, &weights, rng, |_, i| c += (i == 2) as u8 as f64);
                s += c;
                s2 += c * c;
            }
            s2 / trials as f64 - (s / trials as f64).powi(2)
        };
        let binomial = n as f64 * 0.3 * 0.7;
        let m = variance(Resampling::Multinomial, &mut rng);
        assert!((m / binomial - 1.0).abs() < 0.05, "{m} against {binomial}");
        for scheme in [
            Resampling::Systematic,
            Resampling::Stratified,
            Resampling::Residual,
        ] {
            let v = variance(scheme, &mut rng);
            assert!(v < 0.8 * binomial, "{scheme:?}: {v} against {binomial}");
        }
    }
}
