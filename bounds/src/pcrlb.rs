//! Posterior Cramér-Rao bound recursions over weighted particle sets.
//!
//! Conditional PCRLB (the CQ/dPCRLB paper Result 1):
//!
//! ```text
//! B11 = Σ_j w_j F̃(x_j)ᵀ Q⁻¹ F̃(x_j)
//! B12 = −Σ_j w_j F̃(x_j)ᵀ Q⁻¹,          B21 = B12ᵀ
//! B22 = Q⁻¹ + Σ_j w_j Σ_s J_s(x_j(k+1|k))
//! L(k+1|k) = Q⁻¹ − B21 (L(k) + B11)⁻¹ B12
//! L(k+1)   = L(k+1|k) + Σ_j w_j Σ_s J_s(x_j(k+1|k))
//! ```
//!
//! The distributed CQ/dPCRLB (Result 2) and the auxiliary-FIM baseline
//! (the selection paper Theorem 1) are the same update with the observation term
//! replaced by a network sum, so one function serves all three.

use nalgebra::{Cholesky, Matrix2};
use rand::Rng;

use crate::batch::{has_avx2, Positions, StateLanes, CHUNK};
use crate::cell_sums::FisherScalars;
pub use crate::cell_sums::ScalarBatch;
use crate::dynamics::{Dynamics, TransitionBatch};
use crate::fisher::{assemble, position_entries, Measurement};
use crate::observation::{Evaluations, ObservationModel};
use crate::quantizer::TableReads;
use crate::{BoundError, Mat4, State};

/// One sensor as the bound sees it: its model and how it reports.
#[derive(Debug, Clone, Copy)]
pub struct SensorTerm<'a> {
    pub model: &'a ObservationModel,
    pub measurement: Measurement<'a>,
}

/// The dynamics part of the recursion, B11 and B12.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicsTerms {
    pub b11: Mat4,
    pub b12: Mat4,
}

/// `L(k+1|k)` and `L(k+1)` from one step of the recursion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InformationStep {
    pub predicted: Mat4,
    pub updated: Mat4,
}

impl InformationStep {
    /// `ΔL = L(k+1) − L(k+1|k)`: the observation information this step added.
    pub fn observation_information(&self) -> Mat4 {
        self.updated - self.predicted
    }
}

/// B11 and B12 over the posterior particles at time k.
pub fn dynamics_terms(
    dynamics: &Dynamics,
    particles: &[State],
    weights: &[f64],
) -> Result<DynamicsTerms, BoundError> {
    check_weights(particles.len(), weights)?;
    let mut sum = DynamicsTermsSum::new(dynamics);
    if has_avx2() {
        // SAFETY: the CPU has AVX2.
        unsafe { add_batches_avx2(dynamics, particles, weights, &mut sum) };
    } else {
        add_batches(dynamics, particles, weights, &mut sum);
    }
    Ok(sum.total())
}

/// Adds every particle's Jacobian to `sum`, a batch at a time.
#[inline(always)]
fn add_batches(
    dynamics: &Dynamics,
    particles: &[State],
    weights: &[f64],
    sum: &mut DynamicsTermsSum,
) {
    let mut batch = TransitionBatch::default();
    for (states, ws) in particles.chunks(CHUNK).zip(weights.chunks(CHUNK)) {
        dynamics.transition_batch(&StateLanes::of(states), &mut batch);
        sum.add_batch(&batch, ws);
    }
}

/// [`add_batches`] compiled for AVX2.
#[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx2"))]
unsafe fn add_batches_avx2(
    dynamics: &Dynamics,
    particles: &[State],
    weights: &[f64],
    sum: &mut DynamicsTermsSum,
) {
    add_batches(dynamics, particles, weights, sum)
}

/// [`dynamics_terms`] accumulated one particle's Jacobian at a time, for a
/// predictor that computes each `F̃_j` along with `f(x_j)`
/// ([`Dynamics::transition_batch`]). The caller checks the weights.
pub struct DynamicsTermsSum<'q> {
    forms: FormSum<'q>,
    /// `Σ w F̃` of the Jacobians that took the long way; those of the form
    /// `[[I, A], [0, B]]` add to `mean_a`, `mean_b` and, for the identity,
    /// to `forms.weight` (`1·w` is `w`, and `0·w` adds nothing).
    mean_jac: Mat4,
    mean_a: Matrix2<f64>,
    mean_b: Matrix2<f64>,
}

impl<'q> DynamicsTermsSum<'q> {
    pub fn new(dynamics: &'q Dynamics) -> Self {
        Self {
            forms: FormSum::new(dynamics.q_inv()),
            mean_jac: Mat4::zeros(),
            mean_a: Matrix2::zeros(),
            mean_b: Matrix2::zeros(),
        }
    }

    #[inline]
    pub fn add(&mut self, jacobian: &Mat4, weight: f64) {
        match self.forms.blocks_of(jacobian) {
            Some((a, b)) => self.add_blocks(&a, &b, weight),
            None => {
                self.forms.add_general(jacobian, weight);
                self.mean_jac += jacobian * weight;
            }
        }
    }

    /// [`add`](Self::add) of `F̃ = [[I, A], [0, B]]`, when Q⁻¹ has the
    /// block form ([`FormSum`]).
    #[inline(always)]
    fn add_blocks(&mut self, a: &Matrix2<f64>, b: &Matrix2<f64>, weight: f64) {
        self.forms.add_blocks(a, b, weight);
        self.mean_a += a * weight;
        self.mean_b += b * weight;
    }

    /// [`add`](Self::add) of the first `weights.len()` Jacobians of a
    /// batch ([`Dynamics::transition_batch`]), in order, with their weights.
    #[inline(always)]
    pub fn add_batch(&mut self, batch: &TransitionBatch, weights: &[f64]) {
        if !batch.carried {
            for (i, &weight) in weights.iter().enumerate() {
                self.add(&batch.jacobian(i), weight);
            }
            return;
        }
        let (a, b) = (&batch.a, &batch.b);
        for (i, &weight) in weights.iter().enumerate() {
            let block_a = Matrix2::new(a[0][i], a[1][i], a[2][i], a[3][i]);
            let block_b = Matrix2::new(b[0][i], b[1][i], b[2][i], b[3][i]);
            if self.forms.blocks.is_some() {
                self.add_blocks(&block_a, &block_b, weight);
            } else {
                self.add(&carried(&block_a, &block_b), weight);
            }
        }
    }

    pub fn total(&self) -> DynamicsTerms {
        let mut mean_jac = carried(&self.mean_a, &self.mean_b);
        mean_jac[(0, 0)] = self.forms.weight;
        mean_jac[(1, 1)] = self.forms.weight;
        DynamicsTerms {
            b11: self.forms.total(),
            b12: -((self.mean_jac + mean_jac).transpose() * self.forms.q_inv),
        }
    }
}

/// `[[I, A], [0, B]]`.
fn carried(a: &Matrix2<f64>, b: &Matrix2<f64>) -> Mat4 {
    let mut f = Mat4::identity();
    f.fixed_view_mut::<2, 2>(0, 2).copy_from(a);
    f.fixed_view_mut::<2, 2>(2, 2).copy_from(b);
    f
}

/// `Σ_j w_j F̃_jᵀ Q⁻¹ F̃_j` (B11), accumulated particle by particle.
///
/// The white-noise acceleration models make `Q⁻¹ = [[p I, r I], [r I, s I]]`
/// in 2×2 blocks, and every motion model here has `F̃ = [[I, A], [0, B]]`
/// (position carried by velocity, velocity turned). Then F̃ᵀQ⁻¹F̃ is
/// `[[p I, pA + rB], [(pA + rB)ᵀ, p AᵀA + r (AᵀB + BᵀA) + s BᵀB]]`: a few
/// dozen flops a particle instead of two 4×4 products (B11 was a tenth of a
/// `sim` run). A Q⁻¹ or a Jacobian of another form takes the long way.
struct FormSum<'q> {
    q_inv: &'q Mat4,
    blocks: Option<(f64, f64, f64)>,
    weight: f64,
    off: Matrix2<f64>,
    corner: Matrix2<f64>,
    general: Mat4,
}

impl<'q> FormSum<'q> {
    fn new(q_inv: &'q Mat4) -> Self {
        let (p, r, s) = (q_inv[(0, 0)], q_inv[(0, 2)], q_inv[(2, 2)]);
        let block = |row: usize, col: usize, c: f64| {
            q_inv[(row, col)] == c
                && q_inv[(row + 1, col + 1)] == c
                && q_inv[(row, col + 1)] == 0.0
                && q_inv[(row + 1, col)] == 0.0
        };
        let blocks = (block(0, 0, p) && block(0, 2, r) && block(2, 0, r) && block(2, 2, s))
            .then_some((p, r, s));
        Self {
            q_inv,
            blocks,
            weight: 0.0,
            off: Matrix2::zeros(),
            corner: Matrix2::zeros(),
            general: Mat4::zeros(),
        }
    }

    /// A's and B's blocks of `f = [[I, A], [0, B]]`, if Q⁻¹ has the block
    /// form and f that form.
    #[inline]
    fn blocks_of(&self, f: &Mat4) -> Option<(Matrix2<f64>, Matrix2<f64>)> {
        let carried = f.fixed_view::<2, 2>(0, 0) == Matrix2::identity()
            && f.fixed_view::<2, 2>(2, 0) == Matrix2::zeros();
        (self.blocks.is_some() && carried).then(|| {
            (
                f.fixed_view::<2, 2>(0, 2).into(),
                f.fixed_view::<2, 2>(2, 2).into(),
            )
        })
    }

    fn add_general(&mut self, f: &Mat4, w: f64) {
        self.general += (f.transpose() * self.q_inv * f) * w;
    }

    #[inline(always)]
    fn add_blocks(&mut self, a: &Matrix2<f64>, b: &Matrix2<f64>, w: f64) {
        let Some((p, r, s)) = self.blocks else {
            unreachable!("blocks are added only where Q⁻¹ has the block form");
        };
        let atb = a.transpose() * b;
        self.weight += w;
        self.off += (a * p + b * r) * w;
        self.corner +=
            (a.transpose() * a * p + (atb + atb.transpose()) * r + b.transpose() * b * s) * w;
    }

    fn total(&self) -> Mat4 {
        let mut b11 = self.general;
        if let Some((p, _, _)) = self.blocks {
            b11[(0, 0)] += p * self.weight;
            b11[(1, 1)] += p * self.weight;
            let mut upper_right = b11.fixed_view_mut::<2, 2>(0, 2);
            upper_right += self.off;
            let mut lower_left = b11.fixed_view_mut::<2, 2>(2, 0);
            lower_left += self.off.transpose();
            let mut corner = b11.fixed_view_mut::<2, 2>(2, 2);
            corner += self.corner;
        }
        b11
    }
}

/// `Σ_j w_j Σ_s J_s(x_j)`: expected observation information of the given
/// sensors over a weighted particle set (the predicted particles).
pub fn observation_information(
    sensors: &[SensorTerm<'_>],
    particles: &[State],
    weights: &[f64],
) -> Result<Mat4, BoundError> {
    observation_information_with(
        sensors,
        particles,
        weights,
        ExpectedScalars {
            sensors,
            reads: TableReads::default(),
        },
    )
}

/// The Fisher scalars of a batch of particles, as
/// [`observation_information_with`] asks for them: `scalars(first, sensor,
/// g, r, n, out)`. A source is a named type with an `#[inline(always)]`
/// method, not a closure: it is then certain to be compiled into the
/// kernel's AVX2 copy, where a closure the compiler declines to inline is
/// not (that cost the bound update a third).
pub trait BatchScalars {
    fn scalars(
        &mut self,
        first: usize,
        sensor: usize,
        g: &[f64; CHUNK],
        r: &[f64; CHUNK],
        n: usize,
        out: &mut ScalarBatch,
    );
}

/// The expected information's scalars: each sensor's as it reports.
struct ExpectedScalars<'a> {
    sensors: &'a [SensorTerm<'a>],
    reads: TableReads,
}

impl BatchScalars for ExpectedScalars<'_> {
    #[inline(always)]
    fn scalars(
        &mut self,
        _first: usize,
        sensor: usize,
        g: &[f64; CHUNK],
        r: &[f64; CHUNK],
        n: usize,
        out: &mut ScalarBatch,
    ) {
        match self.sensors[sensor].measurement {
            Measurement::Quantized(q) => q.fisher_scalars_batch(g, r, n, out, &mut self.reads),
            Measurement::Raw => {
                for (i, &r) in r[..n].iter().enumerate() {
                    out.set(i, FisherScalars::raw(r));
                }
            }
        }
    }
}

/// [`observation_information`] with the Fisher scalars from
/// `scalars(first, sensor, g, r, n, out)`: those of sensor `sensor` at the
/// `n` particles from `first` on, whose model's means and variances are the
/// first `n` of `g` and `r` (the rest is padding), into `out`. A filter that needs the likelihood at the same
/// particles (the local filter over its prediction) computes both there,
/// sharing the model's evaluation and what the two lookups have in common.
///
/// Models of the position only (every law but a linear one that reads the
/// velocity) are evaluated [`CHUNK`] particles at a time, vectorised
/// ([`crate::batch`]); the sums are taken in the same order either way.
#[inline]
pub fn observation_information_with(
    sensors: &[SensorTerm<'_>],
    particles: &[State],
    weights: &[f64],
    mut scalars: impl BatchScalars,
) -> Result<Mat4, BoundError> {
    check_weights(particles.len(), weights)?;
    if sensors.iter().all(|s| s.model.depends_on_position_only()) {
        // Only the 2×2 position block is non-zero: accumulate just that.
        let [xx, xy, yy] = if has_avx2() {
            // SAFETY: the CPU has AVX2.
            unsafe { position_information_sum_avx2(sensors, particles, weights, &mut scalars) }
        } else {
            position_information_sum(sensors, particles, weights, &mut scalars)
        };
        let total = nalgebra::Matrix2::new(xx, xy, xy, yy);
        let mut full = Mat4::zeros();
        full.fixed_view_mut::<2, 2>(0, 0).copy_from(&total);
        return Ok(symmetrized(full));
    }
    let mut total = Mat4::zeros();
    let (mut g, mut r, mut batch) = ([0.0; CHUNK], [0.0; CHUNK], ScalarBatch::default());
    for (j, (x, &w)) in particles.iter().zip(weights).enumerate() {
        let mut per_particle = Mat4::zeros();
        for (k, s) in sensors.iter().enumerate() {
            let e = s.model.evaluate(x);
            (g[0], r[0]) = (e.g, e.r);
            scalars.scalars(j, k, &g, &r, 1, &mut batch);
            per_particle += assemble(&batch.get(0), &e);
        }
        total += per_particle * w;
    }
    Ok(symmetrized(total))
}

/// [`position_information_sum`] compiled for AVX2.
#[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx2"))]
unsafe fn position_information_sum_avx2(
    sensors: &[SensorTerm<'_>],
    particles: &[State],
    weights: &[f64],
    scalars: &mut impl BatchScalars,
) -> [f64; 3] {
    position_information_sum(sensors, particles, weights, scalars)
}

/// `(xx, xy, yy)` of `Σ_j w_j Σ_s J_s(x_j)` for models of the position
/// only, a batch of particles at a time: each sensor's model and scalars
/// over the batch, each particle's entries summed over the sensors in
/// order, then weighted into the total particle by particle.
#[inline(always)]
fn position_information_sum(
    sensors: &[SensorTerm<'_>],
    particles: &[State],
    weights: &[f64],
    scalars: &mut impl BatchScalars,
) -> [f64; 3] {
    let mut total = [0.0; 3];
    let mut e = Evaluations::default();
    let mut s = ScalarBatch::default();
    let mut per_particle = [[0.0; CHUNK]; 3];
    for (c, (states, ws)) in particles
        .chunks(CHUNK)
        .zip(weights.chunks(CHUNK))
        .enumerate()
    {
        let n = states.len();
        let at = Positions::of(states);
        per_particle.iter_mut().for_each(|p| p.fill(0.0));
        for (k, sensor) in sensors.iter().enumerate() {
            sensor.model.evaluate_batch(states, &at, &mut e);
            scalars.scalars(c * CHUNK, k, &e.g, &e.r, n, &mut s);
            for i in 0..CHUNK {
                let entries = position_entries(
                    (s.gg[i], s.gr[i], s.rr[i]),
                    (e.gx[i], e.gy[i]),
                    (e.rx[i], e.ry[i]),
                );
                for (p, v) in per_particle.iter_mut().zip(entries) {
                    p[i] += v;
                }
            }
        }
        for (i, w) in ws.iter().enumerate() {
            for (t, p) in total.iter_mut().zip(&per_particle) {
                *t += p[i] * w;
            }
        }
    }
    total
}

/// One step: `L(k+1|k) = Q⁻¹ − B21 (L(k) + B11)⁻¹ B12`, `L(k+1) = L(k+1|k) + obs`.
pub fn information_update(
    previous: &Mat4,
    terms: &DynamicsTerms,
    q_inv: &Mat4,
    observation_info: &Mat4,
) -> Result<InformationStep, BoundError> {
    let inner = Cholesky::new(symmetrized(previous + terms.b11))
        .ok_or(BoundError::NotPositiveDefinite("L(k) + B11"))?;
    let b21 = terms.b12.transpose();
    let predicted = symmetrized(q_inv - b21 * inner.solve(&terms.b12));
    let updated = symmetrized(predicted + observation_info);
    if !updated.iter().all(|v| v.is_finite()) {
        return Err(BoundError::NonFinite);
    }
    Ok(InformationStep { predicted, updated })
}

/// The position bound in metres: `sqrt(tr[L⁻¹]_pos)`, the trace of the 2×2
/// position block of the inverse information. Directly comparable with RMSE.
pub fn position_bound(information: &Mat4) -> Option<f64> {
    let cov = Cholesky::new(symmetrized(*information))?.inverse();
    let trace = cov[(0, 0)] + cov[(1, 1)];
    (trace >= 0.0 && trace.is_finite()).then(|| trace.sqrt())
}

/// A conditional PCRLB carried from step to step: the information matrix
/// `L(k)`, starting at `P_0⁻¹`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConditionalBound {
    information: Mat4,
}

impl ConditionalBound {
    pub fn from_prior(prior_cov: &Mat4) -> Result<Self, BoundError> {
        let inv = Cholesky::new(*prior_cov)
            .ok_or(BoundError::NotPositiveDefinite("P_0"))?
            .inverse();
        Ok(Self { information: inv })
    }

    pub fn from_information(information: Mat4) -> Self {
        Self { information }
    }

    pub fn information(&self) -> &Mat4 {
        &self.information
    }

    pub fn position_bound(&self) -> Option<f64> {
        position_bound(&self.information)
    }

    /// Advances `L(k) → L(k+1)` given this step's dynamics terms (from the
    /// posterior particles at k) and observation information (the local
    /// `Σ_j w_j Σ_s J_s`, or a network sum S for the distributed bounds).
    /// The bound is left unchanged on error.
    pub fn advance(
        &mut self,
        terms: &DynamicsTerms,
        q_inv: &Mat4,
        observation_info: &Mat4,
    ) -> Result<InformationStep, BoundError> {
        self.advance_with_late(terms, q_inv, &Mat4::zeros(), observation_info)
    }

    /// [`advance`](Self::advance) when observations of step k were weighed
    /// only after step k closed, each on its particle's path at the time it
    /// was taken: their information `late` is about x(k), so it joins
    /// `L(k)` before the prediction,
    /// `L(k+1) = B22 − B21 (L(k) + ΔL_late(k) + B11)⁻¹ B12 + ΔL(k+1)`.
    /// `L(k)` as reported at step k stays without them: the filter did not
    /// have them then.
    pub fn advance_with_late(
        &mut self,
        terms: &DynamicsTerms,
        q_inv: &Mat4,
        late: &Mat4,
        observation_info: &Mat4,
    ) -> Result<InformationStep, BoundError> {
        let previous = self.information + late;
        let step = information_update(&previous, terms, q_inv, observation_info)?;
        self.information = step.updated;
        Ok(step)
    }
}

/// The non-conditional PCRLB of Tichavsky et al., with its expectations taken
/// by Monte Carlo over `trajectories` simulated trajectories from the prior.
/// Returns `J(0), J(1), …, J(steps)`.
#[allow(clippy::too_many_arguments)]
pub fn nonconditional_pcrlb<R: Rng + ?Sized>(
    dynamics: &Dynamics,
    sensors: &[SensorTerm<'_>],
    prior_mean: &State,
    prior_cov: &Mat4,
    steps: usize,
    trajectories: usize,
    rng: &mut R,
) -> Result<Vec<Mat4>, BoundError> {
    let always = vec![1.0; sensors.len()];
    nonconditional_pcrlb_random_activation(
        dynamics,
        sensors,
        &always,
        prior_mean,
        prior_cov,
        steps,
        trajectories,
        rng,
    )
}

/// The same bound when sensor `i` is active at each step with probability
/// `activation[i]`, independently of the state (random sensor selection).
/// The expectation over the activations enters B22 linearly:
/// `E[Σ_s 1{s active} J_s] = Σ_s p_s J_s`.
#[allow(clippy::too_many_arguments)]
pub fn nonconditional_pcrlb_random_activation<R: Rng + ?Sized>(
    dynamics: &Dynamics,
    sensors: &[SensorTerm<'_>],
    activation: &[f64],
    prior_mean: &State,
    prior_cov: &Mat4,
    steps: usize,
    trajectories: usize,
    rng: &mut R,
) -> Result<Vec<Mat4>, BoundError> {
    if trajectories == 0 {
        return Err(BoundError::NoParticles);
    }
    if sensors.len() != activation.len() {
        return Err(BoundError::ActivationCount {
            sensors: sensors.len(),
            probabilities: activation.len(),
        });
    }
    let chol = Cholesky::new(*prior_cov).ok_or(BoundError::NotPositiveDefinite("P_0"))?;
    let mut states = prior_draws(prior_mean, &chol, trajectories, rng);
    let weights = vec![1.0 / trajectories as f64; trajectories];
    let mut bound = ConditionalBound::from_information(chol.inverse());
    let mut out = Vec::with_capacity(steps + 1);
    out.push(*bound.information());
    for _ in 0..steps {
        let terms = dynamics_terms(dynamics, &states, &weights)?;
        for x in states.iter_mut() {
            *x = dynamics.propagate(x, rng);
        }
        // Runs of sensors with the same probability share one pass.
        let mut obs = Mat4::zeros();
        let mut start = 0;
        while start < sensors.len() {
            let p = activation[start];
            let end = start + activation[start..].iter().take_while(|q| **q == p).count();
            if p != 0.0 {
                obs += observation_information(&sensors[start..end], &states, &weights)? * p;
            }
            start = end;
        }
        bound.advance(&terms, dynamics.q_inv(), &obs)?;
        out.push(*bound.information());
    }
    Ok(out)
}

/// `n` draws from `N(mean, L Lᵀ)`: the starts of the trajectories the
/// non-conditional bounds take their expectations over.
pub(crate) fn prior_draws<R: Rng + ?Sized>(
    mean: &State,
    prior: &Cholesky<f64, nalgebra::U4>,
    n: usize,
    rng: &mut R,
) -> Vec<State> {
    let l = prior.l();
    (0..n)
        .map(|_| mean + l * State::from_fn(|_, _| rng.sample::<f64, _>(rand_distr::StandardNormal)))
        .collect()
}

fn check_weights(particles: usize, weights: &[f64]) -> Result<(), BoundError> {
    if particles == 0 {
        return Err(BoundError::NoParticles);
    }
    if weights.len() != particles {
        return Err(BoundError::WeightCount {
            particles,
            weights: weights.len(),
        });
    }
    Ok(())
}

#[inline]
fn symmetrized(m: Mat4) -> Mat4 {
    (m + m.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::{CoordinatedTurn, ProcessNoise};
    use crate::observation::SensorLaw;
    use crate::quantizer::Quantizer;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    fn position_sensors() -> [ObservationModel; 2] {
        [
            SensorLaw::Linear {
                h: [1.0, 0.0, 0.0, 0.0],
                r: 25.0,
            }
            .at([0.0, 0.0]),
            SensorLaw::Linear {
                h: [0.0, 1.0, 0.0, 0.0],
                r: 16.0,
            }
            .at([0.0, 0.0]),
        ]
    }

    fn prior_cov() -> Mat4 {
        Mat4::from_diagonal(&State::new(2500.0, 2500.0, 4.0, 4.0))
    }

    /// The Kalman filter's information recursion for F, Q, H, R:
    /// `J(k+1) = (F J(k)⁻¹ Fᵀ + Q)⁻¹ + Hᵀ R⁻¹ H`.
    fn kalman_information(
        dynamics: &Dynamics,
        models: &[ObservationModel],
        steps: usize,
    ) -> Vec<Mat4> {
        let f = dynamics.jacobian(&State::new(0.0, 0.0, 1.0, 1.0));
        let mut hrh = Mat4::zeros();
        for m in models {
            if let Some(l) = m.law.downcast_ref::<crate::observation::Linear>() {
                let h = State::from(l.h);
                hrh += h * h.transpose() / l.r;
            }
        }
        let mut j = prior_cov().try_inverse().unwrap();
        let mut out = vec![j];
        for _ in 0..steps {
            let p_pred = f * j.try_inverse().unwrap() * f.transpose() + dynamics.q();
            j = p_pred.try_inverse().unwrap() + hrh;
            out.push(j);
        }
        out
    }

    fn relative_error(a: &Mat4, b: &Mat4) -> f64 {
        (a - b).abs().max() / b.abs().max()
    }

    /// Observations weighed a step late, in the linear-Gaussian limit: the
    /// bound that adds their information to L(k) before predicting is the
    /// Kalman filter that had them on time, one step after they arrive.
    /// The sensors' turns: on time, late, both, late, none, ...
    #[test]
    fn late_information_joins_the_state_it_was_taken_at() {
        let dynamics = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.5)).unwrap();
        let models = position_sensors();
        let info = |m: &ObservationModel| {
            let l = m.law.downcast_ref::<crate::observation::Linear>().unwrap();
            State::from(l.h) * State::from(l.h).transpose() / l.r
        };
        let (x_info, y_info) = (info(&models[0]), info(&models[1]));
        // (on time, late) information of each step.
        let schedule = [
            (x_info, Mat4::zeros()),
            (Mat4::zeros(), x_info + y_info),
            (y_info, x_info),
            (Mat4::zeros(), y_info),
            (Mat4::zeros(), Mat4::zeros()),
            (x_info + y_info, Mat4::zeros()),
            (Mat4::zeros(), x_info),
            (Mat4::zeros(), x_info + y_info),
        ];
        let f = dynamics.jacobian(&State::zeros());
        let kalman_predict = |j: &Mat4| {
            (f * j.try_inverse().unwrap() * f.transpose() + dynamics.q())
                .try_inverse()
                .unwrap()
        };
        let one = [State::new(100.0, 200.0, 3.0, -1.0)];
        let terms = dynamics_terms(&dynamics, &one, &[1.0]).unwrap();
        let mut bound = ConditionalBound::from_prior(&prior_cov()).unwrap();
        let mut kalman = prior_cov().try_inverse().unwrap();
        let mut late_before = Mat4::zeros();
        for (k, (on_time, late)) in schedule.iter().enumerate() {
            bound
                .advance_with_late(&terms, dynamics.q_inv(), &late_before, on_time)
                .unwrap();
            // The Kalman filter sees step k's every measurement at step k.
            kalman = kalman_predict(&kalman) + on_time + late;
            // The bound has all but this step's late ones.
            assert!(
                relative_error(&(bound.information() + late), &kalman) < 1e-9,
                "step {k}"
            );
            late_before = *late;
        }
        // Without the late term the bound forgets them: a looser bound.
        let mut forgetful = ConditionalBound::from_prior(&prior_cov()).unwrap();
        for (on_time, _) in &schedule {
            forgetful
                .advance(&terms, dynamics.q_inv(), on_time)
                .unwrap();
        }
        assert!(forgetful.position_bound().unwrap() > 1.2 * bound.position_bound().unwrap());
    }

    #[test]
    fn linear_gaussian_limit_reproduces_the_kalman_information() {
        let dynamics = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.5)).unwrap();
        let models = position_sensors();
        let sensors: Vec<SensorTerm> = models
            .iter()
            .map(|m| SensorTerm {
                model: m,
                measurement: Measurement::Raw,
            })
            .collect();
        let kalman = kalman_information(&dynamics, &models, 60);

        // Exact expectations: F̃ and J are constant, so one particle of weight 1 is exact.
        let mut bound = ConditionalBound::from_prior(&prior_cov()).unwrap();
        let one = [State::new(100.0, 200.0, 3.0, -1.0)];
        for (k, kalman_k) in kalman.iter().enumerate().skip(1) {
            let terms = dynamics_terms(&dynamics, &one, &[1.0]).unwrap();
            let obs = observation_information(&sensors, &one, &[1.0]).unwrap();
            bound.advance(&terms, dynamics.q_inv(), &obs).unwrap();
            assert!(
                relative_error(bound.information(), kalman_k) < 1e-9,
                "step {k}"
            );
        }

        // The particle version (Monte Carlo over trajectories) agrees too;
        // with a linear model its Monte Carlo error is zero up to rounding.
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mc = nonconditional_pcrlb(
            &dynamics,
            &sensors,
            &State::new(0.0, 0.0, 5.0, 5.0),
            &prior_cov(),
            60,
            500,
            &mut rng,
        )
        .unwrap();
        for k in 0..=60 {
            assert!(
                relative_error(&mc[k], &kalman[k]) < 1e-9,
                "Monte Carlo step {k}"
            );
        }
    }

    /// B11 by 2×2 blocks is the 4×4 product F̃ᵀQ⁻¹F̃ summed, to rounding,
    /// for turning targets at two periods (some particles below the turn's
    /// minimum speed), and a Q⁻¹ not of the block form takes the long way
    /// and gives the product exactly.
    #[test]
    fn b11_by_blocks_is_the_full_product() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for period in [1.0, 0.25] {
            let dynamics = Dynamics::new(CoordinatedTurn {
                period,
                maneuver_accel: 0.1,
                min_speed: 0.1,
                sigma_v: 0.05,
                process_noise: ProcessNoise::Continuous,
            })
            .unwrap();
            let particles: Vec<State> = (0..500)
                .map(|i| {
                    let speed = if i % 7 == 0 { 0.05 } else { 10.0 };
                    let heading = rng.random::<f64>() * 2.0 * PI;
                    State::new(
                        rng.random::<f64>() * 1000.0,
                        rng.random::<f64>() * 1000.0,
                        speed * heading.sin(),
                        speed * heading.cos(),
                    )
                })
                .collect();
            let weights: Vec<f64> = (0..500).map(|i| (1 + i % 3) as f64 / 1000.0).collect();
            let full = particles
                .iter()
                .zip(&weights)
                .fold(Mat4::zeros(), |acc, (x, w)| {
                    let f = dynamics.jacobian(x);
                    acc + f.transpose() * dynamics.q_inv() * f * *w
                });
            assert!(
                FormSum::new(dynamics.q_inv()).blocks.is_some(),
                "Q⁻¹ = {} is of the block form",
                dynamics.q_inv()
            );
            let blocks = dynamics_terms(&dynamics, &particles, &weights).unwrap().b11;
            assert!(
                (blocks - full).norm() <= 1e-12 * full.norm(),
                "T = {period}: {blocks} vs {full}"
            );
            let mut other = *dynamics.q_inv();
            other[(0, 1)] = 1e-3;
            other[(1, 0)] = 1e-3;
            let mut sum = FormSum::new(&other);
            assert!(sum.blocks.is_none());
            let f = dynamics.jacobian(&particles[1]);
            assert!(sum.blocks_of(&f).is_none());
            sum.add_general(&f, 1.0);
            assert_eq!(sum.total(), f.transpose() * other * f);
        }
    }

    /// A predictor's batches add up to the same B11 and B12 as its
    /// particles added one by one, bit for bit.
    #[test]
    fn batches_of_jacobians_sum_as_their_particles_do() {
        let dynamics = Dynamics::new(CoordinatedTurn {
            period: 1.0,
            maneuver_accel: 0.1,
            min_speed: 0.1,
            sigma_v: 0.05,
            process_noise: ProcessNoise::Continuous,
        })
        .unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let particles: Vec<State> = (0..150)
            .map(|_| State::new(10.0, -20.0, 3.0, -4.0) + dynamics.sample_noise(&mut rng) * 30.0)
            .collect();
        let weight = 1.0 / particles.len() as f64;
        let mut one_by_one = DynamicsTermsSum::new(&dynamics);
        for x in &particles {
            one_by_one.add(&dynamics.jacobian(x), weight);
        }
        let mut batched = DynamicsTermsSum::new(&dynamics);
        let mut batch = TransitionBatch::default();
        for chunk in particles.chunks(CHUNK) {
            dynamics.transition_batch(&crate::batch::StateLanes::of(chunk), &mut batch);
            batched.add_batch(&batch, &vec![weight; chunk.len()]);
        }
        let (a, b) = (one_by_one.total(), batched.total());
        let bits = |m: &Mat4| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.b11), bits(&b.b11));
        assert_eq!(bits(&a.b12), bits(&b.b12));
        assert!(a.b11.norm() > 0.0 && a.b12.norm() > 0.0);
    }

    #[test]
    fn observation_information_is_the_difference_of_updated_and_predicted() {
        let dynamics = Dynamics::new(CoordinatedTurn {
            period: 1.0,
            maneuver_accel: 0.1,
            min_speed: 0.1,
            sigma_v: 0.05,
            process_noise: ProcessNoise::Continuous,
        })
        .unwrap();
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let model = SensorLaw::Bearing {
            sigma_theta: 0.02,
            d0: 500.0,
            near_field: None,
        }
        .at([250.0, 250.0]);
        let sensors = [SensorTerm {
            model: &model,
            measurement: Measurement::Quantized(&q),
        }];
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let particles: Vec<State> = (0..200)
            .map(|_| {
                State::new(1000.0, 1000.0, -6.0, -7.0) + dynamics.sample_noise(&mut rng) * 50.0
            })
            .collect();
        let w = vec![1.0 / 200.0; 200];
        let terms = dynamics_terms(&dynamics, &particles, &w).unwrap();
        let obs = observation_information(&sensors, &particles, &w).unwrap();
        let mut bound = ConditionalBound::from_prior(&prior_cov()).unwrap();
        let step = bound.advance(&terms, dynamics.q_inv(), &obs).unwrap();
        assert!(relative_error(&step.observation_information(), &obs) < 1e-9);
        assert!(bound.position_bound().unwrap() < position_bound(&step.predicted).unwrap());
    }

    /// For position-only models the sum is taken over the 2×2 position
    /// block's three distinct entries; it must be the full 4×4 sum of
    /// [`expected_information`] over the particles.
    #[test]
    fn the_position_block_sum_is_the_full_sum() {
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let models = [
            SensorLaw::Bearing {
                sigma_theta: 0.02,
                d0: 500.0,
                near_field: None,
            }
            .at([250.0, 250.0]),
            SensorLaw::Bearing {
                sigma_theta: 0.05,
                d0: 100.0,
                near_field: None,
            }
            .at([900.0, 1300.0]),
        ];
        let sensors: Vec<SensorTerm> = models
            .iter()
            .map(|model| SensorTerm {
                model,
                measurement: Measurement::Quantized(&q),
            })
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let particles: Vec<State> = (0..300)
            .map(|_| {
                State::new(
                    rng.random_range(0.0..1500.0),
                    rng.random_range(0.0..1500.0),
                    rng.random_range(-10.0..10.0),
                    rng.random_range(-10.0..10.0),
                )
            })
            .collect();
        let w: Vec<f64> = (0..300).map(|j| (1 + j % 7) as f64).collect();
        let mut full = Mat4::zeros();
        for (x, w) in particles.iter().zip(&w) {
            for model in &models {
                full +=
                    crate::fisher::expected_information(model, Measurement::Quantized(&q), x) * *w;
            }
        }
        let blocks = observation_information(&sensors, &particles, &w).unwrap();
        assert!(
            relative_error(&blocks, &full) < 1e-12,
            "{blocks} against {full}"
        );
    }

    #[test]
    fn more_bits_give_a_tighter_bearing_bound() {
        let dynamics = Dynamics::new(CoordinatedTurn {
            period: 1.0,
            maneuver_accel: 0.1,
            min_speed: 0.1,
            sigma_v: 0.05,
            process_noise: ProcessNoise::Continuous,
        })
        .unwrap();
        let models: Vec<ObservationModel> = [[250.0, 250.0], [750.0, 250.0], [500.0, 900.0]]
            .iter()
            .map(|s| {
                SensorLaw::Bearing {
                    sigma_theta: 0.02,
                    d0: 500.0,
                    near_field: None,
                }
                .at(*s)
            })
            .collect();
        let mut bounds = Vec::new();
        for bits in [2u8, 4, 8] {
            let q = Quantizer::uniform_wrapped(bits, -PI, PI).unwrap();
            let sensors: Vec<SensorTerm> = models
                .iter()
                .map(|m| SensorTerm {
                    model: m,
                    measurement: Measurement::Quantized(&q),
                })
                .collect();
            let mut rng = ChaCha8Rng::seed_from_u64(8);
            let j = nonconditional_pcrlb(
                &dynamics,
                &sensors,
                &State::new(600.0, 600.0, -5.0, -5.0),
                &prior_cov(),
                20,
                200,
                &mut rng,
            )
            .unwrap();
            bounds.push(position_bound(&j[20]).unwrap());
        }
        assert!(bounds[0] > bounds[1] && bounds[1] > bounds[2], "{bounds:?}");
    }

    /// A linear sensor active half the time carries, in expectation, the
    /// information of one always active with twice the noise variance; on
    /// the same trajectories the two bounds agree to rounding.
    #[test]
    fn random_activation_enters_as_expected_information() {
        let dynamics = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.5)).unwrap();
        let law = |r: f64| SensorLaw::Linear {
            h: [1.0, 0.0, 0.0, 0.0],
            r,
        };
        let (half_time, double_noise) = (law(25.0).at([0.0, 0.0]), law(50.0).at([0.0, 0.0]));
        let term = |m| SensorTerm {
            model: m,
            measurement: Measurement::Raw,
        };
        let run = |sensor, p: f64| {
            let mut rng = ChaCha8Rng::seed_from_u64(11);
            nonconditional_pcrlb_random_activation(
                &dynamics,
                &[term(sensor)],
                &[p],
                &State::new(0.0, 0.0, 1.0, 1.0),
                &prior_cov(),
                15,
                50,
                &mut rng,
            )
            .unwrap()
        };
        let (a, b) = (run(&half_time, 0.5), run(&double_noise, 1.0));
        for k in 0..=15 {
            assert!(relative_error(&a[k], &b[k]) < 1e-12, "step {k}");
        }
        assert!(matches!(
            nonconditional_pcrlb_random_activation(
                &dynamics,
                &[term(&half_time)],
                &[],
                &State::zeros(),
                &prior_cov(),
                1,
                1,
                &mut ChaCha8Rng::seed_from_u64(1)
            ),
            Err(BoundError::ActivationCount { .. })
        ));
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let dynamics = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.5)).unwrap();
        assert!(matches!(
            dynamics_terms(&dynamics, &[], &[]),
            Err(BoundError::NoParticles)
        ));
        assert!(matches!(
            dynamics_terms(&dynamics, &[State::zeros()], &[0.5, 0.5]),
            Err(BoundError::WeightCount { .. })
        ));
        assert!(ConditionalBound::from_prior(&(-Mat4::identity())).is_err());
        assert_eq!(position_bound(&Mat4::zeros()), None);
    }

    #[test]
    fn position_bound_of_a_diagonal_information() {
        let info = Mat4::from_diagonal(&State::new(1.0 / 9.0, 1.0 / 16.0, 1.0, 1.0));
        assert!((position_bound(&info).unwrap() - 5.0).abs() < 1e-12);
    }
}
