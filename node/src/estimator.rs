//! The two filters of the CF/DPF and the bounds computed on them.
//!
//! - [`LocalFilter`]: a node's own sensors only. Gives the node's information
//!   contribution (δη, δΛ) to the fusion filter and its local conditional
//!   PCRLB. With every sensor of the network it is also the centralized
//!   reference.
//! - [`FusionFilter`]: the global posterior, weighted by the consensus sums,
//!   with the global CQ/dPCRLB and the auxiliary-FIM baseline. It predicts
//!   before consensus, so that the node's observation information ΔL is
//!   taken over the global predictive particles (the CQ/dPCRLB paper, eq. 55).

use bounds::batch::CHUNK;
use bounds::chacha::WideChaCha8;
use bounds::pcrlb::information_update;
use bounds::{BoundError, ConditionalBound, Dynamics, DynamicsTerms, Mat4, State};
use nalgebra::{Cholesky, SymmetricEigen};
use rand_chacha::ChaCha8Rng;

use crate::filter::{Gaussian, ParticleFilter};
pub use crate::sensing::{Censored, Evidence, Observation, ObservedValue, SensingModel};

/// A node's information contribution for one step (docs/equations.md, "Estimator" and
/// "Distributed bound"): everything that goes into consensus.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contribution {
    pub delta_eta: State,
    pub delta_lambda: Mat4,
    pub delta_l: Mat4,
    /// The information of the step before's observations that arrived
    /// only now, about x(k−1) ([`bounds::ConditionalBound::advance_with_late`]).
    pub delta_l_late: Mat4,
    /// Observed information at the received values (auxiliary-FIM baseline).
    pub s_obs: Mat4,
}

impl Contribution {
    pub fn zero() -> Self {
        Self {
            delta_eta: State::zeros(),
            delta_lambda: Mat4::zeros(),
            delta_l: Mat4::zeros(),
            delta_l_late: Mat4::zeros(),
            s_obs: Mat4::zeros(),
        }
    }
}

/// Fewest effective particles for which the importance-weighted posterior
/// summary is trusted.
const MIN_IMPORTANCE_ESS: f64 = 50.0;

/// A filter's prediction for the step, made at most once: the bound's
/// dynamics terms (B11, B12 over the particles before the prediction) and
/// the predicted summary, held from the predictor to the updater that
/// consumes them. Both filters predict early (for a sensor manager, or for
/// ΔL before consensus) and must not predict twice.
#[derive(Debug, Clone, Default)]
struct PendingPrediction(Option<(DynamicsTerms, Gaussian)>);

impl PendingPrediction {
    /// Predicts `filter` unless this step's prediction is already made.
    fn make(
        &mut self,
        filter: &mut ParticleFilter,
        dynamics: &Dynamics,
        rng: &mut WideChaCha8,
    ) -> Result<(), BoundError> {
        if self.0.is_none() {
            self.0 = Some(filter.predict_for_bound(dynamics, rng)?);
        }
        Ok(())
    }

    /// The predicted particles, predicting `filter` first unless this
    /// step's prediction is already made: both filters' predictor.
    fn particles<'f>(
        &mut self,
        filter: &'f mut ParticleFilter,
        dynamics: &Dynamics,
        rng: &mut WideChaCha8,
    ) -> Result<&'f [State], BoundError> {
        self.make(filter, dynamics, rng)?;
        Ok(filter.particles())
    }

    /// This step's prediction (made now if it was not), for the updater.
    fn take(
        &mut self,
        filter: &mut ParticleFilter,
        dynamics: &Dynamics,
        rng: &mut WideChaCha8,
    ) -> Result<(DynamicsTerms, Gaussian), BoundError> {
        self.make(filter, dynamics, rng)?;
        Ok(self.0.take().expect("made above"))
    }

    /// Forgets a prediction (the filter was reset).
    fn clear(&mut self) {
        self.0 = None;
    }
}

/// The local filter and its local conditional PCRLB. Its step is split in
/// two, the predictor and the updater, so that a sensor manager can score
/// candidate sensors on the predicted particles before any is activated.
#[derive(Debug, Clone)]
pub struct LocalFilter {
    filter: ParticleFilter,
    bound: ConditionalBound,
    rng: WideChaCha8,
    prediction: PendingPrediction,
    /// Each predicted particle's log-likelihood, taken while J_Y is
    /// evaluated there: the updater's first stage. Kept to allocate nothing
    /// per step.
    first_stage: Vec<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalUpdate {
    pub contribution: Contribution,
    pub estimate: State,
    /// Position bound of the local conditional PCRLB, metres.
    pub bound: Option<f64>,
}

impl LocalFilter {
    pub fn new(particles: usize, prior: &Gaussian, rng: ChaCha8Rng) -> Result<Self, BoundError> {
        // The same stream, sixteen blocks at a time (`bounds::chacha`).
        let mut rng = WideChaCha8::from_rand_chacha(&rng);
        let filter = ParticleFilter::from_gaussian(particles, prior, &mut rng)
            .ok_or(BoundError::NotPositiveDefinite("P_0"))?;
        Ok(Self {
            filter,
            bound: ConditionalBound::from_prior(&prior.cov)?,
            rng,
            prediction: PendingPrediction::default(),
            first_stage: vec![0.0; particles],
        })
    }

    /// The filter, resampling by `scheme` (`filter.resampler`).
    pub fn with_resampling(mut self, scheme: fusion_graph::scenario::Resampling) -> Self {
        self.filter = self.filter.with_resampling(scheme);
        self
    }

    /// Restarts from a Gaussian posterior and information matrix (rejoin).
    pub fn reset(&mut self, posterior: &Gaussian, information: Mat4) {
        self.prediction.clear();
        if self
            .filter
            .reset_gaussian(posterior, &mut self.rng)
            .is_some()
        {
            self.bound = ConditionalBound::from_information(information);
        }
    }

    /// Predictor: propagates the particles to this step (once; a second
    /// call before [`update`](Self::update) changes nothing) and returns them.
    pub fn predict(&mut self, model: &SensingModel) -> Result<&[State], BoundError> {
        self.prediction
            .particles(&mut self.filter, &model.dynamics, &mut self.rng)
    }

    /// Updater: weights the predicted particles by the observations received
    /// (sorted by sensor, so the result does not depend on arrival order),
    /// resamples, and advances the local bound. Predicts first if
    /// [`predict`](Self::predict) was not called. `with_observed_information`
    /// also computes the auxiliary-FIM term.
    pub fn update(
        &mut self,
        model: &SensingModel,
        evidence: &Evidence,
        with_observed_information: bool,
    ) -> Result<LocalUpdate, BoundError> {
        let Evidence {
            received: observations,
            lagged,
            silent,
            censored,
        } = *evidence;
        let (terms, predicted) =
            self.prediction
                .take(&mut self.filter, &model.dynamics, &mut self.rng)?;

        // The first stage's likelihoods, with ΔL from the same evaluations
        // when it is J_Y of the received; under censoring ΔL is every active
        // sensor's J_cens instead, and J_Y would be wasted.
        let delta_l = if censored.is_empty() {
            model.information_and_likelihood(
                observations,
                self.filter.particles(),
                self.filter.uniform_weights(),
                &mut self.first_stage,
            )?
        } else {
            model.ln_likelihoods(observations, self.filter.particles(), &mut self.first_stage);
            model.censored_information(
                censored,
                self.filter.particles(),
                self.filter.uniform_weights(),
            )?
        };
        // Late observations were taken at k−1: their information is over
        // the particles' ancestors.
        let delta_l_late = model.observation_information(
            lagged,
            self.filter.previous(),
            self.filter.uniform_weights(),
        )?;
        self.bound
            .advance_with_late(&terms, model.dynamics.q_inv(), &delta_l_late, &delta_l)?;

        if evidence.is_empty() {
            // No news: the posterior is the prediction and the contribution is zero.
            let estimate = predicted.mean;
            self.filter.resample(&mut self.rng);
            return Ok(LocalUpdate {
                contribution: Contribution {
                    delta_l,
                    ..Contribution::zero()
                },
                estimate,
                bound: self.bound.position_bound(),
            });
        }
        // The full likelihood (dissertation eq. 3.9): what arrived, and the
        // silence of every censored sensor.
        let late = |before: &State| {
            lagged
                .iter()
                .map(|o| model.ln_likelihood(o, before))
                .sum::<f64>()
        };
        // Adds the silences and the late observations to each path's
        // received part, in the same order at every stage. The silences
        // are taken a batch of particles at a time, sensor by sensor, and
        // summed particle by particle in the sensors' order.
        let add_rest = |out: &mut [f64], particles: &[State], previous: &[State]| {
            if silent.is_empty() && lagged.is_empty() {
                return;
            }
            let mut silences = vec![[0.0; CHUNK]; silent.len()];
            let batches = out
                .chunks_mut(CHUNK)
                .zip(particles.chunks(CHUNK))
                .zip(previous.chunks(CHUNK));
            for ((out, states), before) in batches {
                for (s, batch) in silent.iter().zip(silences.iter_mut()) {
                    model.ln_silence_batch(s, states, batch);
                }
                for (i, (l, before)) in out.iter_mut().zip(before).enumerate() {
                    let silence = silences.iter().map(|b| b[i]).sum::<f64>();
                    *l = *l + silence + late(before);
                }
            }
        };
        // The first stage's received part was taken with J_Y above.
        add_rest(
            &mut self.first_stage,
            self.filter.particles(),
            self.filter.previous(),
        );
        let stages = self.filter.update_paths_from(
            &mut self.rng,
            &self.first_stage,
            |particles, previous, out| {
                model.ln_likelihoods(observations, particles, out);
                add_rest(out, particles, previous);
            },
        );
        if stages == 0 {
            tracing::warn!("no particle explains this step's observations; keeping the prediction");
        }
        let posterior = self.filter.posterior_after(stages);
        let mut s_obs = Mat4::zeros();
        if with_observed_information {
            for (x, w) in self.filter.particles().iter().zip(self.filter.weights()) {
                for o in observations {
                    s_obs += model.observed_information(o, x) * *w;
                }
            }
        }
        self.filter.resample(&mut self.rng);
        self.filter.regularize(&posterior, &mut self.rng);
        // δΛ and δη from one particle set (see `importance_posterior`); the
        // tempered population's summary only when the importance weights
        // have degenerated (the first steps from a broad prior).
        let summary_posterior = match self.filter.importance_posterior() {
            Some((g, ess)) if ess >= MIN_IMPORTANCE_ESS => g,
            _ => posterior,
        };
        let position_only = observations
            .iter()
            .map(|o| o.sensor)
            .chain(silent.iter().map(|s| s.sensor))
            .chain(lagged.iter().map(|o| o.sensor))
            .all(|s| model.sensors[s as usize].depends_on_position_only());
        let contribution = information_contribution(&predicted, &summary_posterior, position_only)
            .map_or(
                Contribution {
                    delta_l,
                    delta_l_late,
                    s_obs,
                    ..Contribution::zero()
                },
                |(delta_eta, delta_lambda)| Contribution {
                    delta_eta,
                    delta_lambda,
                    delta_l,
                    delta_l_late,
                    s_obs,
                },
            );
        Ok(LocalUpdate {
            contribution,
            estimate: posterior.mean,
            bound: self.bound.position_bound(),
        })
    }

    pub fn bound(&self) -> &ConditionalBound {
        &self.bound
    }

    /// The observations that pass the innovation gate ([`crate::gate`]) on
    /// this step's predicted particles (predicting first), and how many
    /// did not.
    pub fn gate(
        &mut self,
        model: &SensingModel,
        observations: &[Observation],
        threshold: f64,
    ) -> Result<(Vec<Observation>, u16), BoundError> {
        self.predict(model)?;
        Ok(crate::gate::gate(
            model,
            observations,
            self.filter.particles(),
            Some(self.bound.information()),
            threshold,
        ))
    }

    /// A step without observations (this node missed it): prediction only.
    pub fn coast(&mut self, model: &SensingModel) -> Result<(), BoundError> {
        self.update(model, &Evidence::default(), false).map(|_| ())
    }
}

/// `δΛ = P⁻¹ − (P⁻)⁻¹`, `δη = P⁻¹μ − (P⁻)⁻¹μ⁻`; `None` if a covariance is
/// singular.
///
/// When every observation depends on position only, the exact δΛ has a zero
/// velocity block and its position block equals the difference of the
/// position marginals' informations (the likelihood multiplies the position
/// marginal alone). Estimating it that way avoids differencing two noisy
/// velocity Schur complements, whose Monte Carlo error would otherwise act on
/// the fusion filter as a spurious velocity measurement.
fn information_contribution(
    predicted: &Gaussian,
    posterior: &Gaussian,
    position_only: bool,
) -> Option<(State, Mat4)> {
    if position_only {
        let prior_info =
            Cholesky::new(predicted.cov.fixed_view::<2, 2>(0, 0).into_owned())?.inverse();
        let post_info =
            Cholesky::new(posterior.cov.fixed_view::<2, 2>(0, 0).into_owned())?.inverse();
        let eta = post_info * posterior.mean.fixed_rows::<2>(0)
            - prior_info * predicted.mean.fixed_rows::<2>(0);
        let mut lambda = Mat4::zeros();
        lambda
            .fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&(post_info - prior_info));
        return Some((State::new(eta[0], eta[1], 0.0, 0.0), lambda));
    }
    let prior_info = Cholesky::new(predicted.cov)?.inverse();
    let post_info = Cholesky::new(posterior.cov)?.inverse();
    Some((
        post_info * posterior.mean - prior_info * predicted.mean,
        post_info - prior_info,
    ))
}

/// Network sums from consensus: `Σδη`, `ΣδΛ`, `S = ΣΔL`, and `S_obs`.
pub type NetworkSums = Contribution;

/// The fusion filter, the global CQ/dPCRLB and the auxiliary-FIM baseline.
#[derive(Debug, Clone)]
pub struct FusionFilter {
    filter: ParticleFilter,
    bound: ConditionalBound,
    /// `J_AUX(k)` and the baseline bound computed from it.
    aux: Option<ConditionalBound>,
    rng: WideChaCha8,
    prediction: PendingPrediction,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionUpdate {
    pub estimate: State,
    /// `sqrt(tr_pos P(k|k−1))` of the prediction the step started from.
    pub spread: f64,
    pub posterior: Gaussian,
    pub bound: Option<f64>,
    pub aux_bound: Option<f64>,
}

impl FusionFilter {
    pub fn new(
        particles: usize,
        prior: &Gaussian,
        with_aux: bool,
        rng: ChaCha8Rng,
    ) -> Result<Self, BoundError> {
        // The same stream, sixteen blocks at a time (`bounds::chacha`).
        let mut rng = WideChaCha8::from_rand_chacha(&rng);
        let filter = ParticleFilter::from_gaussian(particles, prior, &mut rng)
            .ok_or(BoundError::NotPositiveDefinite("P_0"))?;
        let bound = ConditionalBound::from_prior(&prior.cov)?;
        Ok(Self {
            filter,
            bound,
            aux: with_aux.then_some(bound),
            rng,
            prediction: PendingPrediction::default(),
        })
    }

    /// The filter, resampling by `scheme` (`filter.resampler`).
    pub fn with_resampling(mut self, scheme: fusion_graph::scenario::Resampling) -> Self {
        self.filter = self.filter.with_resampling(scheme);
        self
    }

    pub fn information(&self) -> &Mat4 {
        self.bound.information()
    }

    pub fn aux_information(&self) -> Option<&Mat4> {
        self.aux.as_ref().map(|a| a.information())
    }

    pub fn posterior(&self) -> Gaussian {
        self.filter.summary()
    }

    /// Restarts from a neighbour's fused posterior and bounds (rejoin).
    pub fn reset(
        &mut self,
        posterior: &Gaussian,
        information: Mat4,
        aux_information: Option<Mat4>,
    ) {
        self.prediction.clear();
        if self
            .filter
            .reset_gaussian(posterior, &mut self.rng)
            .is_some()
        {
            self.bound = ConditionalBound::from_information(information);
            if let (Some(aux), Some(info)) = (self.aux.as_mut(), aux_information) {
                *aux = ConditionalBound::from_information(info);
            }
        }
    }

    /// Predictor: propagates the particles to this step, once (a second
    /// call before [`step`](Self::step) changes nothing). The node runs it
    /// before consensus, for [`observation_information`](Self::observation_information).
    pub fn predict(&mut self, model: &SensingModel) -> Result<&[State], BoundError> {
        self.prediction
            .particles(&mut self.filter, &model.dynamics, &mut self.rng)
    }

    /// The node's ΔL for the CQ/dPCRLB: its observed sensors' information
    /// averaged over this filter's *predicted* particles, the approximation
    /// of the global predictive density that the CQ/dPCRLB paper's Result 2 (eq. 55)
    /// takes the expectation over. (Over the local filter's particles, as
    /// the paper's text reads, the clouds are far wider than the global posterior,
    /// and at coarse quantization, where J_Y is a comb of peaks at the cell
    /// edges, that put the distributed bound below the centralized one.)
    ///
    /// Returns ΔL and ΔL_late: the step's information
    /// ([`SensingModel::step_information`]: every active sensor's censored
    /// law under censoring) and that of the late observations about the
    /// step before, over the particles' ancestors, the posterior at k−1.
    pub fn observation_information(
        &mut self,
        model: &SensingModel,
        evidence: &Evidence,
    ) -> Result<(Mat4, Mat4), BoundError> {
        self.predict(model)?;
        let weights = self.filter.uniform_weights();
        Ok((
            model.step_information(evidence, self.filter.particles(), weights)?,
            model.observation_information(evidence.lagged, self.filter.previous(), weights)?,
        ))
    }

    /// `L(k+1|k) = Q⁻¹ − D21 (L_G(k) + D11)⁻¹ D12`: the global bound's
    /// predicted information, D over this filter's posterior particles at k
    /// (predicting now if it has not). Sensor selection scores on it.
    pub fn predicted_information(&mut self, model: &SensingModel) -> Result<Mat4, BoundError> {
        let information = *self.bound.information();
        self.predicted_from(model, &information)
    }

    /// The same with the auxiliary FIM `J_AUX(k)` in place of `L_G(k)`, as
    /// the selection paper's eq. 32 has it; `None` when the filter carries
    /// no auxiliary FIM (`consensus.auxiliary_fim = false`).
    pub fn predicted_aux_information(
        &mut self,
        model: &SensingModel,
    ) -> Result<Option<Mat4>, BoundError> {
        let Some(aux) = self.aux_information().copied() else {
            return Ok(None);
        };
        self.predicted_from(model, &aux).map(Some)
    }

    /// `Q⁻¹ − D21 (information + D11)⁻¹ D12`, D over the posterior at k.
    fn predicted_from(
        &mut self,
        model: &SensingModel,
        information: &Mat4,
    ) -> Result<Mat4, BoundError> {
        self.predict(model)?;
        let (terms, _) = self.prediction.0.as_ref().expect("predicted above");
        let zero = Mat4::zeros();
        Ok(information_update(information, terms, model.dynamics.q_inv(), &zero)?.predicted)
    }

    /// Each of `sensors`' expected information over this step's predicted
    /// particles (predicting now if it has not).
    pub fn expected_information(
        &mut self,
        model: &SensingModel,
        sensors: &[u16],
    ) -> Result<Vec<Mat4>, BoundError> {
        self.predict(model)?;
        let (particles, weights) = (self.filter.particles(), self.filter.uniform_weights());
        sensors
            .iter()
            .map(|s| model.expected_information(*s, particles, weights))
            .collect()
    }

    /// Updater: weights the predicted particles (predicting first if
    /// [`predict`](Self::predict) was not called) by the consensus sums,
    /// resamples, and advances the global bounds.
    pub fn step(
        &mut self,
        model: &SensingModel,
        sums: &NetworkSums,
    ) -> Result<FusionUpdate, BoundError> {
        let (terms, predicted) =
            self.prediction
                .take(&mut self.filter, &model.dynamics, &mut self.rng)?;
        let (lambda, eta) = clip_negative_eigenvalues(&sums.delta_lambda, &sums.delta_eta);
        let centre = predicted.mean;
        // exp(−½xᵀΛx + xᵀη) around the predicted mean c (x = c + d), which
        // keeps the exponent's terms small: −½dᵀΛd + dᵀ(η − Λc) + const.
        let linear = eta - lambda * centre;
        let stages = self.filter.update(&mut self.rng, |x| {
            let d = x - centre;
            -0.5 * d.dot(&(lambda * d)) + d.dot(&linear)
        });
        let posterior = self.filter.posterior_after(stages);
        self.filter.resample(&mut self.rng);
        self.filter.regularize(&posterior, &mut self.rng);

        let q_inv = model.dynamics.q_inv();
        let delta_l = positive_part(&sums.delta_l);
        let aux_bound = match self.aux.as_mut() {
            Some(j_aux) => {
                // L_aux(k+1) uses J_AUX(k); then J_AUX advances with S_obs.
                let baseline = information_update(j_aux.information(), &terms, q_inv, &delta_l)?;
                j_aux.advance(&terms, q_inv, &positive_part(&sums.s_obs))?;
                bounds::position_bound(&baseline.updated)
            }
            None => None,
        };
        self.bound.advance_with_late(
            &terms,
            q_inv,
            &positive_part(&sums.delta_l_late),
            &delta_l,
        )?;
        Ok(FusionUpdate {
            estimate: posterior.mean,
            spread: (predicted.cov[(0, 0)] + predicted.cov[(1, 1)]).sqrt(),
            posterior,
            bound: self.bound.position_bound(),
            aux_bound,
        })
    }
}

impl FusionFilter {
    /// A step without consensus sums (this node missed it): prediction only.
    pub fn coast(&mut self, model: &SensingModel) -> Result<(), BoundError> {
        self.step(model, &Contribution::zero()).map(|_| ())
    }
}

/// A consensus estimate of an information matrix (ΣΔL, S_obs), which in
/// truth is positive semi-definite: as it is, bit for bit, unless it has
/// an eigenvalue below −1e-9 of its largest, when its negative
/// eigenvalues are set to zero. Average consensus mixes such matrices
/// with positive weights and never gets there; a protocol with memory
/// extrapolates, and before it has converged can overshoot into an
/// indefinite matrix, which would make the bound's recursion fail.
pub fn positive_part(m: &Mat4) -> Mat4 {
    let sym = (m + m.transpose()) * 0.5;
    let eig = SymmetricEigen::new(sym);
    let largest = eig.eigenvalues.abs().max();
    if eig.eigenvalues.iter().all(|v| *v >= -1e-9 * largest) {
        return *m;
    }
    let v = &eig.eigenvectors;
    v * Mat4::from_diagonal(&eig.eigenvalues.map(|x| x.max(0.0))) * v.transpose()
}

/// Sets the negative eigenvalues of ΣδΛ to zero (it may be indefinite after
/// consensus on Monte Carlo estimates) and removes from Σδη its component
/// along those directions. The factor `exp(−½xᵀΛx + xᵀη)` is a Gaussian only
/// while η lies in the range of Λ; a component of η along a zeroed direction
/// would be an unbounded linear tilt that drags every particle away.
/// Eigenvalues below 1e-12 of the largest count as zero.
pub fn clip_negative_eigenvalues(lambda: &Mat4, eta: &State) -> (Mat4, State) {
    let sym = (lambda + lambda.transpose()) * 0.5;
    let eig = SymmetricEigen::new(sym);
    let floor = 1e-12 * eig.eigenvalues.abs().max();
    if eig.eigenvalues.iter().all(|v| *v > floor) {
        return (sym, *eta);
    }
    let keep = eig.eigenvalues.map(|v| if v > floor { 1.0 } else { 0.0 });
    let clipped = eig.eigenvalues.component_mul(&keep);
    let v = &eig.eigenvectors;
    (
        v * Mat4::from_diagonal(&clipped) * v.transpose(),
        v * Mat4::from_diagonal(&keep) * v.transpose() * eta,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A positive semi-definite matrix (a singular one too) passes bit for
    /// bit; an indefinite one keeps its eigenvectors and loses its
    /// negative eigenvalues.
    #[test]
    fn only_an_indefinite_information_matrix_is_projected() {
        let psd = Mat4::from_diagonal(&State::new(2.0, 1.0, 0.0, 1e-20));
        let rotation = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.7);
        let mut r = Mat4::identity();
        r.fixed_view_mut::<3, 3>(0, 0).copy_from(rotation.matrix());
        let psd = r * psd * r.transpose();
        assert_eq!(positive_part(&psd), psd);
        let indefinite = r * Mat4::from_diagonal(&State::new(2.0, -0.5, 1.0, 0.0)) * r.transpose();
        let projected = positive_part(&indefinite);
        let want = r * Mat4::from_diagonal(&State::new(2.0, 0.0, 1.0, 0.0)) * r.transpose();
        assert!((projected - want).abs().max() < 1e-12, "{projected}");
    }
    use bounds::Measurement;
    use fusion_graph::{Scenario, Topology};
    use std::f64::consts::PI;

    /// One evaluation per particle and sensor gives the same J_Y sum and the
    /// same log-likelihoods, bit for bit, as evaluating each on its own, for
    /// quantized bearings and raw RSS alike (the updater's first stage
    /// depends on it), and so do the batched log-likelihoods of its later
    /// stages (three full batches and a short one).
    #[test]
    fn shared_evaluation_gives_what_separate_evaluations_give() {
        use fusion_graph::scenario::{DEFAULT_SCENARIO, RANDOM_EXCHANGE_SCENARIO};
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};

        for (text, values) in [
            (
                DEFAULT_SCENARIO,
                [ObservedValue::Cell(40), ObservedValue::Cell(200)],
            ),
            (
                RANDOM_EXCHANGE_SCENARIO,
                [ObservedValue::Raw(-75.0), ObservedValue::Raw(-81.5)],
            ),
        ] {
            let scenario = Scenario::from_toml(text, "s", &[]).unwrap();
            let topology = Topology::from_scenario(&scenario, "s").unwrap();
            let model = SensingModel::from_scenario(&scenario, &topology).unwrap();
            let observations = [
                Observation {
                    sensor: 0,
                    value: values[0],
                },
                Observation {
                    sensor: 3,
                    value: values[1],
                },
            ];
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
            let spread = Normal::new(0.0, 20.0).unwrap();
            let centre = scenario.target.initial_state();
            let particles: Vec<State> = (0..200)
                .map(|_| {
                    State::new(
                        centre[0] + spread.sample(&mut rng),
                        centre[1] + spread.sample(&mut rng),
                        1.0,
                        0.0,
                    )
                })
                .collect();
            let weights = vec![1.0 / 200.0; 200];
            let mut shared = vec![f64::NAN; 200];
            let info = model
                .information_and_likelihood(&observations, &particles, &weights, &mut shared)
                .unwrap();
            assert_eq!(
                info,
                model
                    .observation_information(&observations, &particles, &weights)
                    .unwrap()
            );
            let mut batched = vec![f64::NAN; 200];
            model.ln_likelihoods(&observations, &particles, &mut batched);
            for ((x, l), b) in particles.iter().zip(&shared).zip(&batched) {
                let separate: f64 = observations.iter().map(|o| model.ln_likelihood(o, x)).sum();
                assert_eq!(l.to_bits(), separate.to_bits());
                assert_eq!(b.to_bits(), separate.to_bits());
            }
        }
    }

    /// The node's ΔL is J_Y averaged over the fusion filter's prediction (the
    /// global predictive density of the CQ/dPCRLB paper, eq. 55), not over the local
    /// filter's wider one. At 4 bits, a target in the middle of a bearing
    /// cell, ten noise widths from either edge, gives a quantized
    /// observation next to no information; a cloud wide enough to cross the
    /// cell edges collects the peaks of J_Y there and claims a great deal.
    #[test]
    fn delta_l_is_taken_over_the_fusion_filters_prediction() {
        use fusion_graph::scenario::DEFAULT_SCENARIO;
        use rand::SeedableRng;

        let scenario =
            Scenario::from_toml(DEFAULT_SCENARIO, "default", &["quantizer.bits=4".into()]).unwrap();
        let topology = Topology::from_scenario(&scenario, "default").unwrap();
        let model = SensingModel::from_scenario(&scenario, &topology).unwrap();
        // 100 m from sensor 0 at the bearing of the middle of cell 10 (of 16).
        let [sx, sy] = topology.sensor_positions[0];
        let bearing = -PI + 10.5 * PI / 8.0;
        let target = State::new(
            sx + 100.0 * bearing.sin(),
            sy + 100.0 * bearing.cos(),
            0.0,
            0.0,
        );
        let observed = [Observation {
            sensor: 0,
            value: ObservedValue::Cell(10),
        }];
        let unquantized =
            bounds::expected_information(&model.sensors[0], Measurement::Raw, &target)
                .fixed_view::<2, 2>(0, 0)
                .trace();
        let prior = |position_sd: f64| Gaussian {
            mean: target,
            cov: Mat4::from_diagonal(&State::new(
                position_sd.powi(2),
                position_sd.powi(2),
                0.01,
                0.01,
            )),
        };
        let rng = |seed| ChaCha8Rng::seed_from_u64(seed);

        let mut fusion = FusionFilter::new(2000, &prior(0.5), false, rng(1)).unwrap();
        let received = Evidence {
            received: &observed,
            ..Evidence::default()
        };
        let (node_delta_l, _) = fusion.observation_information(&model, &received).unwrap();
        let mut local = LocalFilter::new(2000, &prior(20.0), rng(2)).unwrap();
        let local_delta_l = local
            .update(
                &model,
                &Evidence {
                    received: &observed,
                    ..Evidence::default()
                },
                false,
            )
            .unwrap()
            .contribution
            .delta_l;

        let share = |m: &Mat4| m.fixed_view::<2, 2>(0, 0).trace() / unquantized;
        assert!(share(&node_delta_l) < 1e-3, "{}", share(&node_delta_l));
        assert!(share(&local_delta_l) > 0.05, "{}", share(&local_delta_l));
        // And the fusion filter's step then uses those same predicted particles.
        let before = fusion.filter.particles().to_vec();
        fusion.predict(&model).unwrap();
        assert_eq!(fusion.filter.particles(), &before[..]);
    }

    #[test]
    fn clipping_removes_negative_directions_from_both_lambda_and_eta() {
        let m = Mat4::from_diagonal(&State::new(2.0, -1.0, 0.5, -3.0));
        let (c, eta) = clip_negative_eigenvalues(&m, &State::new(1.0, 1.0, 1.0, 1.0));
        assert!(
            (c - Mat4::from_diagonal(&State::new(2.0, 0.0, 0.5, 0.0)))
                .abs()
                .max()
                < 1e-12
        );
        assert!((eta - State::new(1.0, 0.0, 1.0, 0.0)).abs().max() < 1e-12);
        let psd = Mat4::identity() * 3.0;
        assert_eq!(clip_negative_eigenvalues(&psd, &State::zeros()).0, psd);
        // A position-only (rank-2) Λ keeps only η's position part.
        let pos = Mat4::from_diagonal(&State::new(1.0, 2.0, 0.0, 0.0));
        let (c, eta) = clip_negative_eigenvalues(&pos, &State::new(3.0, 4.0, 5.0, 6.0));
        assert!((c - pos).abs().max() < 1e-12);
        assert!((eta - State::new(3.0, 4.0, 0.0, 0.0)).abs().max() < 1e-12);
    }

    #[test]
    fn information_contribution_of_a_scalar_update() {
        let predicted = Gaussian {
            mean: State::new(0.0, 0.0, 0.0, 0.0),
            cov: Mat4::identity() * 4.0,
        };
        let posterior = Gaussian {
            mean: State::new(1.0, 0.0, 0.0, 0.0),
            cov: Mat4::identity() * 2.0,
        };
        let (eta, lambda) = information_contribution(&predicted, &posterior, false).unwrap();
        assert!((lambda - Mat4::identity() * 0.25).abs().max() < 1e-12);
        assert!((eta - State::new(0.5, 0.0, 0.0, 0.0)).abs().max() < 1e-12);
        // Position marginal only: same position block, zero velocity block.
        let (eta, lambda) = information_contribution(&predicted, &posterior, true).unwrap();
        assert!(
            (lambda - Mat4::from_diagonal(&State::new(0.25, 0.25, 0.0, 0.0)))
                .abs()
                .max()
                < 1e-12
        );
        assert!((eta - State::new(0.5, 0.0, 0.0, 0.0)).abs().max() < 1e-12);
    }

    /// For a Gaussian prior with position-velocity correlation and a linear
    /// position measurement, the position-marginal difference equals the full
    /// information difference P⁻¹ − (P⁻)⁻¹ = HᵀR⁻¹H.
    #[test]
    fn position_marginal_difference_is_exact_for_position_measurements() {
        let p_pred = Mat4::new(
            9.0, 1.0, 3.0, 0.5, 1.0, 8.0, 0.2, 2.5, 3.0, 0.2, 2.0, 0.1, 0.5, 2.5, 0.1, 1.5,
        );
        let h_r_h = Mat4::from_diagonal(&State::new(0.5, 0.25, 0.0, 0.0));
        let p_post = (p_pred.try_inverse().unwrap() + h_r_h)
            .try_inverse()
            .unwrap();
        let mu_pred = State::new(10.0, 20.0, 1.0, -1.0);
        let z = State::new(12.0, 19.0, 0.0, 0.0);
        // Posterior mean of the information filter: P (P⁻⁻¹ μ⁻ + HᵀR⁻¹ z).
        let mu_post = p_post * (p_pred.try_inverse().unwrap() * mu_pred + h_r_h * z);
        let (eta, lambda) = information_contribution(
            &Gaussian {
                mean: mu_pred,
                cov: p_pred,
            },
            &Gaussian {
                mean: mu_post,
                cov: p_post,
            },
            true,
        )
        .unwrap();
        assert!((lambda - h_r_h).abs().max() < 1e-12, "{lambda}");
        assert!((eta - h_r_h * z).abs().max() < 1e-10, "{eta}");
    }

    /// A censored sensor's silence a batch of particles at a time is its
    /// silence particle by particle, bit for bit: bearings whose
    /// innovations wrap, particles near the prediction and far from it.
    #[test]
    fn a_batch_of_silences_is_each_particles_silence() {
        use bounds::batch::CHUNK;
        use bounds::censoring::{CensoringRule, Innovation};
        use fusion_graph::scenario::DEFAULT_SCENARIO;
        use rand::{Rng, SeedableRng};

        let scenario = Scenario::from_toml(DEFAULT_SCENARIO, "default", &[]).unwrap();
        let topology = Topology::from_scenario(&scenario, "default").unwrap();
        let model = SensingModel::from_scenario(&scenario, &topology).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for round in 0..200 {
            let sensor = rng.random_range(0..model.sensors.len()) as u16;
            let silence = Censored {
                sensor,
                innovation: Innovation {
                    predicted: rng.random_range(-3.2..3.2),
                    variance: 10f64.powf(rng.random_range(-5.0..-1.0)),
                    angular: true,
                },
                rule: CensoringRule::for_budget(1.5, 3, 1).unwrap(),
            };
            let spread = if round % 2 == 0 { 30.0 } else { 1500.0 };
            let states: Vec<State> = (0..CHUNK - round % 7)
                .map(|_| {
                    State::new(
                        rng.random_range(-spread..spread) + 700.0,
                        rng.random_range(-spread..spread) + 700.0,
                        0.0,
                        0.0,
                    )
                })
                .collect();
            let mut batch = [0.0; CHUNK];
            model.ln_silence_batch(&silence, &states, &mut batch);
            for (x, got) in states.iter().zip(batch) {
                let want = model.ln_silence(&silence, x);
                assert_eq!(got.to_bits(), want.to_bits(), "{got} against {want} at {x}");
            }
        }
    }

    /// The bound's information under censoring and with late observations,
    /// on the default scenario's quantized bearings: a silent censoring
    /// sensor adds J_cens (before, nothing), every active one is counted
    /// whether it sent or not, and an observation weighed a step late
    /// tightens the bound where it used to add nothing.
    #[test]
    fn the_bound_credits_silence_and_late_observations() {
        use bounds::censoring::{CensoringRule, Innovation};
        use fusion_graph::scenario::DEFAULT_SCENARIO;
        use rand::SeedableRng;

        let scenario = Scenario::from_toml(DEFAULT_SCENARIO, "default", &[]).unwrap();
        let topology = Topology::from_scenario(&scenario, "default").unwrap();
        let model = SensingModel::from_scenario(&scenario, &topology).unwrap();
        let target = State::from(scenario.target.initial_state());
        let prior = Gaussian {
            mean: target,
            cov: Mat4::from_diagonal(&State::new(400.0, 400.0, 1.0, 1.0)),
        };
        let predicted = model.sensors[0].evaluate(&model.dynamics.transition(&target));
        let censored = |sensor: u16| Censored {
            sensor,
            innovation: Innovation {
                predicted: predicted.g,
                variance: predicted.r * 3.0,
                angular: true,
            },
            rule: CensoringRule::for_budget(1.5, 3, 1).unwrap(),
        };
        let rng = ChaCha8Rng::seed_from_u64(5);
        let fusion = FusionFilter::new(1000, &prior, false, rng.clone()).unwrap();

        // Sensor 0 silent, sensor 1 sent cell 40.
        let (silent, active) = ([censored(0)], [censored(0), censored(1)]);
        let sent = [Observation {
            sensor: 1,
            value: ObservedValue::Cell(40),
        }];
        let evidence = Evidence {
            received: &sent,
            silent: &silent,
            censored: &active,
            ..Evidence::default()
        };
        let mut f = fusion.clone();
        let (delta_l, late) = f.observation_information(&model, &evidence).unwrap();
        assert_eq!(late, Mat4::zeros());
        let particles = f.predict(&model).unwrap().to_vec();
        let weights = vec![1.0 / particles.len() as f64; particles.len()];
        let expected = model
            .censored_information(&active, &particles, &weights)
            .unwrap();
        assert!((delta_l - expected).abs().max() <= 1e-12 * expected.abs().max());
        let silent_alone = model
            .censored_information(&silent, &particles, &weights)
            .unwrap();
        let position = |m: &Mat4| m.fixed_view::<2, 2>(0, 0).trace();
        assert!(position(&silent_alone) > 0.0, "silence tells something");
        let uncensored = model
            .observation_information(&sent, &particles, &weights)
            .unwrap();
        assert!(
            position(&delta_l) > position(&(delta_l - silent_alone)),
            "the silent sensor is counted"
        );
        assert!(position(&(delta_l - silent_alone)) <= position(&uncensored) * (1.0 + 1e-9));

        // The local bound: with the silence it is tighter than with the
        // sent observation alone, as the filter weighs both.
        let bound_after = |evidence: &Evidence| {
            let mut local = LocalFilter::new(1000, &prior, rng.clone()).unwrap();
            local
                .update(&model, evidence, false)
                .unwrap()
                .bound
                .unwrap()
        };
        let only_sent = Evidence {
            received: &sent,
            ..Evidence::default()
        };
        assert!(bound_after(&evidence) < bound_after(&only_sent));

        // A late observation: about x(k−1), over the ancestors, and a
        // tighter bound than the step without it.
        let lagged = [Observation {
            sensor: 2,
            value: ObservedValue::Cell(100),
        }];
        let late_evidence = Evidence {
            lagged: &lagged,
            ..Evidence::default()
        };
        let mut f = fusion.clone();
        let (delta_l, late) = f.observation_information(&model, &late_evidence).unwrap();
        assert_eq!(delta_l, Mat4::zeros());
        assert!(position(&late) > 0.0);
        assert!(bound_after(&late_evidence) < bound_after(&Evidence::default()));
    }
}
