//! A bootstrap particle filter: predictor (the transition prior), updater
//! (log-likelihood weights), resampler ([`crate::resampler`]), and Gaussian
//! summaries.
//! Buffers are allocated once; a step allocates nothing.

use bounds::batch::{has_avx2, StateLanes, CHUNK};
use bounds::dynamics::TransitionBatch;
use bounds::pcrlb::DynamicsTermsSum;
pub use bounds::Gaussian;
use bounds::{BoundError, Dynamics, DynamicsTerms, Mat4, State};
use fusion_graph::scenario::Resampling;
use nalgebra::Cholesky;
use rand::Rng;
use rand_distr::StandardNormal;

#[derive(Debug, Clone)]
pub struct ParticleFilter {
    particles: Vec<State>,
    /// Each particle's state one step back on its own path (its ancestor at
    /// the last prediction), so that an observation that arrives a step late
    /// can be weighed at the time it was taken.
    previous: Vec<State>,
    weights: Vec<f64>,
    uniform: Vec<f64>,
    scratch: Vec<State>,
    scratch_previous: Vec<State>,
    /// Per-particle log-likelihood of the update in progress.
    ln_likelihood: Vec<f64>,
    /// The posterior as the predicted particles weighted by the whole
    /// likelihood (before any tempering stage moved them), with its ESS.
    importance_posterior: Option<(Gaussian, f64)>,
    resampling: Resampling,
}

/// The tempered updater never lets the effective sample size fall below
/// this fraction of N in one stage: N/2, the usual threshold of adaptive
/// tempering. With 0.2 and the mean-and-covariance-keeping regularizer,
/// the steep first steps from a 50 m prior left 1000 particles too few
/// distinct velocities, and 2 of 20 default runs lost the target for good
/// (RMSE 8.8 m and 5.5 m); at 0.5 none did, for 4 % more time per step
/// (`cqnet sim --runs 20`: 59.5 against 57.0 steps/s per run).
const ESS_FLOOR: f64 = 0.5;
/// At most this many tempering stages per update; the last takes the rest.
const MAX_STAGES: usize = 24;

impl ParticleFilter {
    /// `n` particles drawn from `N(mean, cov)`; `None` if cov is not positive definite.
    pub fn from_gaussian<R: Rng + ?Sized>(n: usize, g: &Gaussian, rng: &mut R) -> Option<Self> {
        let mut f = Self {
            particles: vec![State::zeros(); n],
            previous: vec![State::zeros(); n],
            weights: vec![1.0 / n as f64; n],
            uniform: vec![1.0 / n as f64; n],
            scratch: vec![State::zeros(); n],
            scratch_previous: vec![State::zeros(); n],
            ln_likelihood: vec![0.0; n],
            importance_posterior: None,
            resampling: Resampling::Systematic,
        };
        f.reset_gaussian(g, rng)?;
        Some(f)
    }

    /// Redraws every particle from `N(mean, cov)` with uniform weights.
    pub fn reset_gaussian<R: Rng + ?Sized>(&mut self, g: &Gaussian, rng: &mut R) -> Option<()> {
        let l = Cholesky::new(g.cov)?.l();
        for p in self.particles.iter_mut() {
            *p = g.mean + l * State::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal));
        }
        // No path behind a fresh draw: the ancestor is the particle itself.
        self.previous.copy_from_slice(&self.particles);
        self.weights.copy_from_slice(&self.uniform);
        Some(())
    }

    /// The filter, resampling by `scheme` from now on (systematic
    /// unless told).
    pub fn with_resampling(mut self, scheme: Resampling) -> Self {
        self.resampling = scheme;
        self
    }

    pub fn len(&self) -> usize {
        self.particles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.particles.is_empty()
    }

    pub fn particles(&self) -> &[State] {
        &self.particles
    }

    /// Each particle's ancestor at the last prediction.
    pub fn previous(&self) -> &[State] {
        &self.previous
    }

    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    pub fn uniform_weights(&self) -> &[f64] {
        &self.uniform
    }

    /// Predictor: `x_j(k) ~ p(x(k) | x_j(k−1))`; weights become uniform (the
    /// particles come from the previous step's resampler).
    pub fn predict<R: Rng + ?Sized>(&mut self, dynamics: &Dynamics, rng: &mut R) {
        self.advance(dynamics, rng, |_, _| {});
    }

    /// Moves every particle to `f(x) + ξ`, a batch at a time, keeping where
    /// it was as its previous state; weights become uniform. `each_batch`
    /// sees each batch's transitions (and how many are real) before the
    /// noise is added. The noise is drawn particle by particle, in order,
    /// as [`Dynamics::propagate`] draws it.
    fn advance<R: Rng + ?Sized>(
        &mut self,
        dynamics: &Dynamics,
        rng: &mut R,
        mut each_batch: impl FnMut(&TransitionBatch, usize),
    ) {
        // The particles become the previous states by a swap, not a copy
        // (32 KB at 1000 particles, four times a node-step); every particle
        // is then written from its previous state.
        std::mem::swap(&mut self.previous, &mut self.particles);
        let mut batch = TransitionBatch::default();
        for (chunk, before) in self
            .particles
            .chunks_mut(CHUNK)
            .zip(self.previous.chunks(CHUNK))
        {
            transition_batch(dynamics, &StateLanes::of(before), &mut batch);
            each_batch(&batch, chunk.len());
            add_process_noise(dynamics, &batch, chunk, rng);
        }
        self.weights.copy_from_slice(&self.uniform);
    }

    /// Predictor for a linear model `x(k) = F x(k−1) + L ε`, `ε ~ N(0, I)`,
    /// with any factor `L` of Q, a singular one included (white-noise
    /// acceleration sampled once a step, or a target held to one axis),
    /// which [`Dynamics`] refuses because the bound's recursion needs Q⁻¹.
    /// Draws as [`predict`](Self::predict) does; weights become uniform.
    pub fn predict_linear<R: Rng + ?Sized>(&mut self, f: &Mat4, noise_factor: &Mat4, rng: &mut R) {
        std::mem::swap(&mut self.previous, &mut self.particles);
        let mut draws = [0.0; 4 * CHUNK];
        for (chunk, before) in self
            .particles
            .chunks_mut(CHUNK)
            .zip(self.previous.chunks(CHUNK))
        {
            let draws = &mut draws[..4 * chunk.len()];
            standard_normals(rng, draws);
            for ((p, x), n) in chunk.iter_mut().zip(before).zip(draws.chunks_exact(4)) {
                *p = f * x + noise_factor * State::from_column_slice(n);
            }
        }
        self.weights.copy_from_slice(&self.uniform);
    }

    /// Predictor step for a filter that also carries a bound: B11 and B12
    /// over the particles before the prediction, then the prediction and its
    /// summary.
    pub fn predict_for_bound<R: Rng + ?Sized>(
        &mut self,
        dynamics: &Dynamics,
        rng: &mut R,
    ) -> Result<(DynamicsTerms, Gaussian), BoundError> {
        if self.particles.is_empty() {
            return Err(BoundError::NoParticles);
        }
        // One pass: each particle's Jacobian for the bound and its
        // transition share the turn's trigonometry; the noise is drawn in
        // the same order as `predict` draws it. Weights are uniform here.
        let mut sum = DynamicsTermsSum::new(dynamics);
        let weight = 1.0 / self.particles.len() as f64;
        let weights = [weight; CHUNK];
        self.advance(dynamics, rng, |batch, n| {
            sum.add_batch(batch, &weights[..n])
        });
        Ok((sum.total(), self.summary()))
    }

    /// Updater with adaptive tempering (progressive correction): the
    /// likelihood is applied as `p(y|x)^δ₁ … p(y|x)^δ_m`, `Σδ = 1`, each δ the
    /// largest that keeps the effective sample size above `ESS_FLOOR · N`,
    /// with resampling and regularization between stages. A likelihood much
    /// sharper than the prediction (the first steps from a 50 m prior, many
    /// sensors at once) would otherwise leave a handful of particles carrying
    /// all the weight. Leaves the particles weighted by the last stage;
    /// returns the number of stages, 0 if no particle has a finite likelihood.
    pub fn update<R: Rng + ?Sized>(
        &mut self,
        rng: &mut R,
        mut ln_likelihood: impl FnMut(&State) -> f64,
    ) -> usize {
        self.update_paths(rng, |x, _| ln_likelihood(x))
    }

    /// [`update`](Self::update) with a likelihood of each particle's path:
    /// its state now and one step back.
    pub fn update_paths<R: Rng + ?Sized>(
        &mut self,
        rng: &mut R,
        mut ln_likelihood: impl FnMut(&State, &State) -> f64,
    ) -> usize {
        self.update_stages(rng, None, |particles, previous, out| {
            for ((l, x), before) in out.iter_mut().zip(particles).zip(previous) {
                *l = ln_likelihood(x, before);
            }
        })
    }

    /// [`update`](Self::update) with the log-likelihoods of all particles
    /// at once, `ln_likelihood(particles, out)`, for a caller that
    /// evaluates them in batches.
    pub fn update_batched<R: Rng + ?Sized>(
        &mut self,
        rng: &mut R,
        mut ln_likelihood: impl FnMut(&[State], &mut [f64]),
    ) -> usize {
        self.update_stages(rng, None, |particles, _, out| ln_likelihood(particles, out))
    }

    /// The updater with the first stage's log-likelihoods already known
    /// (`first[j]` for particle j as it stands): the caller took them while
    /// evaluating the same models for something else. Each later stage's
    /// come from `ln_likelihood(particles, previous, out)`, over the paths.
    pub fn update_paths_from<R: Rng + ?Sized>(
        &mut self,
        rng: &mut R,
        first: &[f64],
        ln_likelihood: impl FnMut(&[State], &[State], &mut [f64]),
    ) -> usize {
        self.update_stages(rng, Some(first), ln_likelihood)
    }

    /// The bootstrap updater in one stage, without tempering or
    /// regularization: weights `∝ p(y | x_j)` from `ln_likelihood(particles,
    /// out)`. For a model whose tables must come out of the textbook filter
    /// itself; the node's own filter uses [`update`](Self::update). Returns
    /// false, leaving the weights uniform, if no particle has a finite
    /// likelihood.
    pub fn update_untempered(&mut self, ln_likelihood: impl FnOnce(&[State], &mut [f64])) -> bool {
        ln_likelihood(&self.particles, &mut self.ln_likelihood);
        let max = self.largest_ln_likelihood();
        if !max.is_finite() {
            self.weights.copy_from_slice(&self.uniform);
            return false;
        }
        self.set_tempered_weights(1.0, max);
        true
    }

    fn update_stages<R: Rng + ?Sized>(
        &mut self,
        rng: &mut R,
        first: Option<&[f64]>,
        mut ln_likelihood: impl FnMut(&[State], &[State], &mut [f64]),
    ) -> usize {
        let floor = ESS_FLOOR * self.particles.len() as f64;
        let mut done = 0.0;
        for stage in 1..=MAX_STAGES {
            match first {
                Some(first) if stage == 1 && first.len() == self.ln_likelihood.len() => {
                    self.ln_likelihood.copy_from_slice(first)
                }
                _ => ln_likelihood(&self.particles, &self.previous, &mut self.ln_likelihood),
            }
            let max = self.largest_ln_likelihood();
            if !max.is_finite() {
                self.weights.copy_from_slice(&self.uniform);
                return 0;
            }
            let remaining = 1.0 - done;
            self.set_tempered_weights(remaining, max);
            if stage == 1 {
                // remaining = 1: these are the untempered importance weights.
                self.importance_posterior = Some((self.summary(), self.effective_sample_size()));
            }
            if stage == MAX_STAGES || self.effective_sample_size() >= floor {
                return stage;
            }
            let delta = self.largest_step(remaining, max, floor, self.effective_sample_size());
            self.set_tempered_weights(delta, max);
            done += delta;
            let posterior = self.summary();
            self.resample(rng);
            self.regularize(&posterior, rng);
        }
        MAX_STAGES
    }

    fn largest_ln_likelihood(&self) -> f64 {
        self.ln_likelihood
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Normalized weights `∝ exp(δ (ℓ_j − max))`.
    fn set_tempered_weights(&mut self, delta: f64, max: f64) {
        let mut total = 0.0;
        let weights = &mut self.weights;
        tempered_exponentials(&self.ln_likelihood, delta, max, |first, w| {
            weights[first..first + w.len()].copy_from_slice(w);
            // In particle order, as one loop would sum them.
            for v in w {
                total += v;
            }
        });
        self.weights.iter_mut().for_each(|w| *w /= total);
    }

    /// The last update's posterior as importance weights on the predicted
    /// particles, and its effective sample size. Its difference from the
    /// predicted summary is what the CF/DPF exchanges; taking both from the
    /// same particles keeps their Monte Carlo errors from adding up.
    pub fn importance_posterior(&self) -> Option<(Gaussian, f64)> {
        self.importance_posterior
    }

    /// The posterior summary after an update that took `stages` stages.
    /// After a single stage the particles and weights are those the
    /// importance posterior was summarized from, so that summary is reused
    /// rather than taken again.
    pub fn posterior_after(&self, stages: usize) -> Gaussian {
        match (stages, self.importance_posterior) {
            (1, Some((g, _))) => g,
            _ => self.summary(),
        }
    }

    /// ESS of weights `∝ exp(δ (ℓ_j − max))`.
    fn tempered_ess(&self, delta: f64, max: f64) -> f64 {
        let (mut s1, mut s2) = (0.0, 0.0);
        tempered_exponentials(&self.ln_likelihood, delta, max, |_, w| {
            for v in w {
                s1 += v;
                s2 += v * v;
            }
        });
        s1 * s1 / s2
    }

    /// The largest δ ≤ `upper` whose tempered ESS stays above `floor`,
    /// given `ess_upper`, the ESS at `upper` (below `floor`).
    ///
    /// Regula falsi with the Illinois modification on `ln ESS(δ) − ln floor`,
    /// which is nearly linear in δ: a handful of ESS evaluations (each an exp
    /// per particle) where bisection to the same tolerance took 14, and the
    /// fusion filter tempers most steps. It stops when the ESS is within
    /// 0.1 % above the floor or the bracket is narrower than `upper · 2⁻¹⁴`,
    /// and returns the bracket's lower end, whose ESS is at least `floor`.
    fn largest_step(&self, upper: f64, max: f64, floor: f64, ess_upper: f64) -> f64 {
        let target = floor.ln();
        let excess = |ess: f64| ess.ln() - target;
        let (mut lo, mut hi) = (0.0, upper);
        // The ends' values as the secant uses them (the Illinois rule halves
        // one that stays put twice), and the lower end's true excess.
        let (mut g_lo, mut g_hi) = (excess(self.particles.len() as f64), excess(ess_upper));
        let mut lo_excess = g_lo;
        // Which end moved last: 1 the lower, −1 the upper.
        let mut side = 0;
        for _ in 0..40 {
            if hi - lo <= upper / 16384.0 || lo_excess <= 1e-3 {
                break;
            }
            let mut mid = hi - g_hi * (hi - lo) / (g_hi - g_lo);
            if !(mid > lo && mid < hi) {
                mid = 0.5 * (lo + hi);
            }
            let g = excess(self.tempered_ess(mid, max));
            if g >= 0.0 {
                (lo, g_lo, lo_excess) = (mid, g, g);
                if side == 1 {
                    g_hi *= 0.5;
                }
                side = 1;
            } else {
                (hi, g_hi) = (mid, g);
                if side == -1 {
                    g_lo *= 0.5;
                }
                side = -1;
            }
        }
        lo.max(upper * 1e-6)
    }

    /// `1 / Σ w²`.
    pub fn effective_sample_size(&self) -> f64 {
        1.0 / self.weights.iter().map(|w| w * w).sum::<f64>()
    }

    /// Weighted mean and covariance of the current particles.
    pub fn summary(&self) -> Gaussian {
        summarize(&self.particles, &self.weights)
    }

    /// The resampler: each particle copied `N w` times in expectation, by
    /// the filter's scheme ([`with_resampling`](Self::with_resampling));
    /// weights become uniform.
    pub fn resample<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        let (particles, previous) = (&self.particles, &self.previous);
        let (scratch, scratch_previous) = (&mut self.scratch, &mut self.scratch_previous);
        crate::resampler::resample(self.resampling, &self.weights, rng, |slot, i| {
            scratch[slot] = particles[i];
            scratch_previous[slot] = previous[i];
        });
        std::mem::swap(&mut self.particles, &mut self.scratch);
        std::mem::swap(&mut self.previous, &mut self.scratch_previous);
        self.weights.copy_from_slice(&self.uniform);
    }
}

impl ParticleFilter {
    /// Regularizer with Liu–West shrinkage: after resampling, moves each
    /// particle to `a x + (1 − a) μ + h L ε`, `ε ~ N(0, I)`, `L Lᵀ = Σ`,
    /// `a = √(1 − h²)`, with (μ, Σ) the posterior summary and
    /// `h = (4 / (N (n_x + 2)))^{1/(n_x + 4)}` (the optimal bandwidth for a
    /// Gaussian kernel, Musso et al. 2001).
    ///
    /// The jitter re-diversifies resampled copies, which the small process
    /// noise of the default scenario cannot do. The shrinkage is why it keeps
    /// the posterior's mean and covariance: `a²Σ + h²Σ = Σ`. A kernel without
    /// it widens the cloud by `h²Σ` at every resampling (about 16 % at
    /// N = 1000), and every bound computed on the particles inherits that.
    /// Skipped if Σ is not positive definite.
    pub fn regularize<R: Rng + ?Sized>(&mut self, posterior: &Gaussian, rng: &mut R) {
        let h2 = kernel_bandwidth_squared(self.particles.len());
        let Some(chol) = Cholesky::new(posterior.cov * h2) else {
            return;
        };
        let l = chol.l();
        let a = (1.0 - h2).sqrt();
        let pull = posterior.mean * (1.0 - a);
        let mut draws = [0.0; 4 * CHUNK];
        for chunk in self.particles.chunks_mut(CHUNK) {
            let draws = &mut draws[..4 * chunk.len()];
            standard_normals(rng, draws);
            for (p, n) in chunk.iter_mut().zip(draws.chunks_exact(4)) {
                *p = *p * a + pull + l * State::from_column_slice(n);
            }
        }
    }
}

/// `h²` of the Gaussian kernel for `n` particles of dimension 4, below 1
/// for every `n ≥ 1` (so the shrinkage `√(1 − h²)` is real).
fn kernel_bandwidth_squared(n: usize) -> f64 {
    (4.0 / (n.max(1) as f64 * 6.0)).powf(1.0 / 4.0)
}

/// Each state of `chunk` moved to its transition in `batch` plus a draw of
/// the process noise `ξ ~ N(0, Q)`, with the factor and the draws that
/// [`Dynamics::sample_noise`] takes.
fn add_process_noise<R: Rng + ?Sized>(
    dynamics: &Dynamics,
    batch: &TransitionBatch,
    chunk: &mut [State],
    rng: &mut R,
) {
    let mut draws = [0.0; 4 * CHUNK];
    let draws = &mut draws[..4 * chunk.len()];
    standard_normals(rng, draws);
    let factor = dynamics.noise_factor();
    for (i, (p, n)) in chunk.iter_mut().zip(draws.chunks_exact(4)).enumerate() {
        let next = State::from_fn(|k, _| batch.next[k][i]);
        *p = next + factor * State::from_column_slice(n);
    }
}

/// `bounds::batch::standard_normals`, compiled for AVX2 where the CPU has
/// it (the same draws either way).
fn standard_normals<R: Rng + ?Sized>(rng: &mut R, out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn with_avx2<R: Rng + ?Sized>(rng: &mut R, out: &mut [f64]) {
            bounds::batch::standard_normals(rng, out)
        }
        if has_avx2() {
            // SAFETY: the CPU has AVX2.
            return unsafe { with_avx2(rng, out) };
        }
    }
    bounds::batch::standard_normals(rng, out)
}

/// `exp(δ (ℓ_j − max))` of every log-likelihood ℓ_j, handed to `each` a
/// batch at a time with the index of the batch's first: fdlibm's `exp`,
/// vectorised ([`bounds::batch::exp`]). The tempering search takes these
/// sums several times a stage, and glibc's `exp` one call at a time was
/// 12 % of the fusion filter's step (perf).
fn tempered_exponentials(ln: &[f64], delta: f64, max: f64, mut each: impl FnMut(usize, &[f64])) {
    let (mut x, mut w) = ([0.0; CHUNK], [0.0; CHUNK]);
    for (b, chunk) in ln.chunks(CHUNK).enumerate() {
        for (x, l) in x.iter_mut().zip(chunk) {
            *x = delta * (l - max);
        }
        // Padding lanes of a short last batch: exp(0), never a special case.
        x[chunk.len()..].fill(0.0);
        exp_batch(&x, &mut w);
        each(b * CHUNK, &w[..chunk.len()]);
    }
}

/// [`bounds::batch::exp`], compiled for AVX2 where the CPU has it.
fn exp_batch(x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn with_avx2(x: &[f64; CHUNK], out: &mut [f64; CHUNK]) {
            bounds::batch::exp(x, out)
        }
        if has_avx2() {
            // SAFETY: the CPU has AVX2.
            return unsafe { with_avx2(x, out) };
        }
    }
    bounds::batch::exp(x, out)
}

/// [`Dynamics::transition_batch`], compiled for AVX2 where the CPU has it
/// (the same result either way, [`bounds::batch`]).
fn transition_batch(dynamics: &Dynamics, x: &StateLanes, out: &mut TransitionBatch) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn with_avx2(dynamics: &Dynamics, x: &StateLanes, out: &mut TransitionBatch) {
            dynamics.transition_batch(x, out)
        }
        if has_avx2() {
            // SAFETY: the CPU has AVX2.
            return unsafe { with_avx2(dynamics, x, out) };
        }
    }
    dynamics.transition_batch(x, out)
}

/// Weighted mean and covariance.
pub fn summarize(particles: &[State], weights: &[f64]) -> Gaussian {
    let mut mean = State::zeros();
    for (p, w) in particles.iter().zip(weights) {
        mean += p * *w;
    }
    // The ten entries on and above the diagonal, row by row; the rest by
    // symmetry (a full outer product per particle doubled the arithmetic).
    let mut upper = [0.0; 10];
    for (p, w) in particles.iter().zip(weights) {
        let d = p - mean;
        let wd = d * *w;
        let mut k = 0;
        for i in 0..4 {
            for j in i..4 {
                upper[k] += wd[i] * d[j];
                k += 1;
            }
        }
    }
    let mut cov = Mat4::zeros();
    let mut k = 0;
    for i in 0..4 {
        for j in i..4 {
            cov[(i, j)] = upper[k];
            cov[(j, i)] = upper[k];
            k += 1;
        }
    }
    Gaussian { mean, cov }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounds::pcrlb::dynamics_terms;
    use bounds::CoordinatedTurn;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn prior() -> Gaussian {
        Gaussian {
            mean: State::new(100.0, 200.0, 3.0, -4.0),
            cov: Mat4::from_diagonal(&State::new(25.0, 16.0, 1.0, 0.25)),
        }
    }

    /// A measurement of x(k−1) that arrives after the prediction to k,
    /// weighed on each particle's path, gives the Kalman filter's answer
    /// for x(k): update at k−1, then predict. Weighing it on x(k) instead
    /// (as if fresh) would not.
    #[test]
    fn a_lagged_measurement_weighed_on_the_path_is_the_kalman_answer() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let dynamics = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.5)).unwrap();
        let mut f = ParticleFilter::from_gaussian(40_000, &prior(), &mut rng).unwrap();
        f.predict(&dynamics, &mut rng);
        let (z, r) = (104.0, 4.0);
        f.update_paths(&mut rng, |_, before| -0.5 * (z - before[0]).powi(2) / r);
        let pf = f.summary();
        // Kalman: update the prior with z on p_x, then predict.
        let p = prior().cov;
        let gain = p.column(0) / (p[(0, 0)] + r);
        let mean = prior().mean + gain * (z - prior().mean[0]);
        let cov = p - gain * p.row(0);
        let fm = dynamics.jacobian(&mean);
        let (kf_mean, kf_cov) = (fm * mean, fm * cov * fm.transpose() + dynamics.q());
        assert!(
            (pf.mean - kf_mean).abs().max() < 0.06,
            "{pf:?} vs {kf_mean:?}"
        );
        assert!((pf.cov[(0, 0)] / kf_cov[(0, 0)] - 1.0).abs() < 0.05);
        // As if fresh: the same z weighed on x(k) lands elsewhere, since
        // p_x moved by v_x = 3 in the step.
        let mut g = ParticleFilter::from_gaussian(40_000, &prior(), &mut rng).unwrap();
        g.predict(&dynamics, &mut rng);
        g.update(&mut rng, |x| -0.5 * (z - x[0]).powi(2) / r);
        assert!((g.summary().mean[0] - kf_mean[0]).abs() > 1.0);
    }

    #[test]
    fn draws_match_the_gaussian_they_came_from() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let f = ParticleFilter::from_gaussian(20_000, &prior(), &mut rng).unwrap();
        let s = f.summary();
        assert!((s.mean - prior().mean).abs().max() < 0.1);
        assert!((s.cov - prior().cov).abs().max() < 0.6);
    }

    /// The regularizer keeps the posterior's covariance: averaged over 20
    /// resample-and-regularize passes at N = 1000 (the default), each
    /// element of the covariance after stays within 2 % (relative to
    /// `√(Σ_ii Σ_jj)`) of the posterior's. A kernel without shrinkage widens
    /// it by h² ≈ 16 % and fails this by a factor of eight.
    #[test]
    fn regularization_keeps_the_posterior_mean_and_covariance() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let correlated = Gaussian {
            mean: prior().mean,
            cov: Mat4::new(
                25.0, 6.0, 2.0, 0.0, //
                6.0, 16.0, 0.0, -1.0, //
                2.0, 0.0, 1.0, 0.1, //
                0.0, -1.0, 0.1, 0.25,
            ),
        };
        let passes = 20;
        let mut worst_mean = 0.0_f64;
        let mut ratio_sum = Mat4::zeros();
        for _ in 0..passes {
            let mut f = ParticleFilter::from_gaussian(1000, &correlated, &mut rng).unwrap();
            // A position likelihood makes the weights, and so the posterior, non-trivial.
            for (w, p) in f.weights.iter_mut().zip(&f.particles) {
                *w = (-0.5 * ((p[0] - 103.0).powi(2) + (p[1] - 198.0).powi(2)) / 9.0).exp();
            }
            let total: f64 = f.weights.iter().sum();
            f.weights.iter_mut().for_each(|w| *w /= total);
            let posterior = f.summary();
            f.resample(&mut rng);
            f.regularize(&posterior, &mut rng);
            let after = f.summary();
            let sd = posterior.cov.diagonal().map(f64::sqrt);
            for i in 0..4 {
                worst_mean = worst_mean.max((after.mean[i] - posterior.mean[i]).abs() / sd[i]);
                for j in 0..4 {
                    ratio_sum[(i, j)] +=
                        (after.cov[(i, j)] - posterior.cov[(i, j)]) / (sd[i] * sd[j]);
                }
            }
        }
        let mean_error = ratio_sum / passes as f64;
        assert!(
            mean_error.abs().max() < 0.02,
            "covariance moved by {mean_error}"
        );
        // One pass's mean moves by the resampler's and the kernel's noise only.
        assert!(worst_mean < 0.15, "mean moved by {worst_mean} sd");
    }

    #[test]
    fn systematic_resampling_keeps_expected_counts() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut f = ParticleFilter::from_gaussian(1000, &prior(), &mut rng).unwrap();
        // Particle 0 gets half the mass, the rest share the other half.
        f.weights.fill(0.5 / 999.0);
        f.weights[0] = 0.5;
        let heavy = f.particles[0];
        f.resample(&mut rng);
        let copies = f.particles().iter().filter(|p| **p == heavy).count();
        assert!((499..=501).contains(&copies), "{copies}");
        assert!(f.weights().iter().all(|w| *w == 1e-3));
    }

    #[test]
    fn a_gaussian_likelihood_moves_the_mean_as_the_kalman_update_does() {
        // Scalar check on p_x: prior N(100, 25), observation 105 with variance 25
        // gives posterior mean 102.5 and variance 12.5 (importance ESS ≈ 0.73 N).
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut f = ParticleFilter::from_gaussian(50_000, &prior(), &mut rng).unwrap();
        let stages = f.update(&mut rng, |p| -0.5 * (p[0] - 105.0).powi(2) / 25.0);
        assert_eq!(
            stages, 1,
            "a likelihood as broad as the prior needs no tempering"
        );
        let s = f.summary();
        assert!((s.mean[0] - 102.5).abs() < 0.1, "{}", s.mean[0]);
        assert!((s.cov[(0, 0)] - 12.5).abs() < 0.4, "{}", s.cov[(0, 0)]);
    }

    /// One untempered stage is Bayes' rule on the importance weights: the
    /// Kalman update's mean and variance, even for a likelihood sharp
    /// enough that the tempered updater would split it.
    #[test]
    fn the_untempered_update_is_the_kalman_update_in_one_stage() {
        // Prior N(100, 25) on p_x, observation 104 with variance 4: posterior
        // mean 100 + 25/29 · 4 and variance 25 · 4 / 29.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut f = ParticleFilter::from_gaussian(200_000, &prior(), &mut rng).unwrap();
        let weighed = f.update_untempered(|particles, out| {
            for (l, p) in out.iter_mut().zip(particles) {
                *l = -0.5 * (p[0] - 104.0).powi(2) / 4.0;
            }
        });
        assert!(weighed);
        let s = f.summary();
        assert!(
            (s.mean[0] - (100.0 + 100.0 / 29.0)).abs() < 0.05,
            "{}",
            s.mean[0]
        );
        assert!(
            (s.cov[(0, 0)] - 100.0 / 29.0).abs() < 0.1,
            "{}",
            s.cov[(0, 0)]
        );
        assert!(!f.update_untempered(|_, out| out.fill(f64::NEG_INFINITY)));
        assert!(f.weights().iter().all(|w| *w == f.uniform_weights()[0]));
    }

    /// The linear predictor moves the cloud's covariance to F P Fᵀ + L Lᵀ,
    /// with a singular L: nothing is added along the axes L leaves out.
    #[test]
    fn the_linear_predictor_adds_a_singular_noise_where_it_acts_only() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let mut f = ParticleFilter::from_gaussian(200_000, &prior(), &mut rng).unwrap();
        let mut transition = Mat4::identity();
        transition[(0, 2)] = 1.0;
        transition[(1, 3)] = 1.0;
        let mut factor = Mat4::zeros();
        factor[(0, 0)] = 0.5;
        factor[(2, 0)] = 1.0;
        let first = f.particles()[0];
        f.predict_linear(&transition, &factor, &mut rng);
        assert_eq!(f.previous()[0], first, "each particle keeps its ancestor");
        let before = prior().cov;
        let expected = transition * before * transition.transpose() + factor * factor.transpose();
        let got = f.summary().cov;
        for i in 0..4 {
            for j in 0..4 {
                let scale = (expected[(i, i)] * expected[(j, j)]).sqrt();
                assert!(
                    (got[(i, j)] - expected[(i, j)]).abs() < 0.02 * scale,
                    "({i}, {j}): {} against {}",
                    got[(i, j)],
                    expected[(i, j)]
                );
            }
        }
    }

    #[test]
    fn a_sharp_likelihood_is_tempered_and_still_lands_on_the_posterior() {
        // Prior N(100, 25) on p_x, observation 112 with variance 0.01: one
        // reweighting would leave a handful of particles; tempering keeps the
        // cloud and finds the posterior N(111.9952, 0.009996).
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut f = ParticleFilter::from_gaussian(5_000, &prior(), &mut rng).unwrap();
        let stages = f.update(&mut rng, |p| -0.5 * (p[0] - 112.0).powi(2) / 0.01);
        assert!(stages > 1, "{stages} stages");
        let s = f.summary();
        assert!((s.mean[0] - 111.9952).abs() < 0.02, "{}", s.mean[0]);
        assert!(
            (s.cov[(0, 0)].sqrt() - 0.09998).abs() < 0.03,
            "{}",
            s.cov[(0, 0)].sqrt()
        );
        assert!(
            f.effective_sample_size() > 0.2 * 5_000.0 * 0.99,
            "{}",
            f.effective_sample_size()
        );
    }

    /// The tempering step is the largest that keeps the ESS above the
    /// floor: at most 0.1 % above it, or within the bracket's tolerance of
    /// where a 60-step bisection puts the crossing.
    #[test]
    fn the_tempering_step_keeps_the_ess_just_above_the_floor() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut f = ParticleFilter::from_gaussian(1000, &prior(), &mut rng).unwrap();
        for sharpness in [10.0, 100.0, 1e3, 1e5] {
            for (l, p) in f.ln_likelihood.iter_mut().zip(&f.particles) {
                *l = -0.5 * sharpness * (p[0] - 103.0).powi(2) / 25.0;
            }
            let max = f
                .ln_likelihood
                .iter()
                .copied()
                .fold(f64::NEG_INFINITY, f64::max);
            let floor = 500.0;
            let upper = 1.0;
            let ess_upper = f.tempered_ess(upper, max);
            assert!(
                ess_upper < floor,
                "sharpness {sharpness}: nothing to search"
            );
            let delta = f.largest_step(upper, max, floor, ess_upper);
            let ess = f.tempered_ess(delta, max);
            let (mut lo, mut hi) = (0.0, upper);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if f.tempered_ess(mid, max) >= floor {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            assert!(ess >= floor, "sharpness {sharpness}: ESS {ess}");
            assert!(
                ess <= floor * 1.001 || (lo - delta).abs() <= upper / 16384.0,
                "sharpness {sharpness}: δ {delta} against {lo}, ESS {ess}"
            );
        }
    }

    #[test]
    fn the_bound_terms_come_from_the_particles_before_prediction() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let d = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.1)).unwrap();
        let mut f = ParticleFilter::from_gaussian(100, &prior(), &mut rng).unwrap();
        let before = f.particles().to_vec();
        let expected = dynamics_terms(&d, &before, f.uniform_weights()).unwrap();
        let (terms, predicted) = f.predict_for_bound(&d, &mut rng).unwrap();
        assert_eq!(terms, expected);
        assert_eq!(predicted, f.summary());
        assert!((f.particles()[0][0] - before[0][0] - before[0][2]).abs() < 1.0);
    }

    #[test]
    fn impossible_observations_leave_weights_uniform() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut f = ParticleFilter::from_gaussian(10, &prior(), &mut rng).unwrap();
        assert_eq!(f.update(&mut rng, |_| f64::NEG_INFINITY), 0);
        assert!(f.weights().iter().all(|w| *w == 0.1));
    }
}
