//! What a node knows about its sensors and what they tell it: the
//! dynamics, every sensor's observation model and the quantizer
//! ([`SensingModel`]), and a step's observations and silences
//! ([`Observation`], [`Evidence`]). Both filters and the innovation gate
//! weigh observations through it.

use std::f64::consts::PI;
use std::sync::{Arc, Mutex, Weak};

use bounds::batch::{has_avx2, Positions, CHUNK};
use bounds::censoring::{CensoringRule, Innovation};
use bounds::fisher::{observed_information, scalars_of_mean_and_variance};
use bounds::observation::Evaluations;
use bounds::pcrlb::{
    observation_information, observation_information_with, BatchScalars, ScalarBatch,
};
use bounds::quantizer::TableReads;
use bounds::{
    wrap_angle, BoundError, Dynamics, Law, Mat4, Measurement, ObservationModel, Quantizer,
    SensorTerm, State,
};
use fusion_graph::{Models, Scenario, ScenarioError, Topology};

/// One received observation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    pub sensor: u16,
    pub value: ObservedValue,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ObservedValue {
    Cell(u32),
    Raw(f64),
}

/// An active sensor under NIS censoring, with the innovation statistics
/// it censored by: whether it sent or stayed silent, what it did is a
/// measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Censored {
    pub sensor: u16,
    pub innovation: Innovation,
    pub rule: CensoringRule,
}

/// What a step tells the local filter about the target.
#[derive(Debug, Clone, Copy, Default)]
pub struct Evidence<'a> {
    /// This step's observations, sorted by sensor.
    pub received: &'a [Observation],
    /// Observations of the step before that arrived after it closed: each
    /// is weighed at the time it was taken, on each particle's path.
    pub lagged: &'a [Observation],
    /// Active sensors that censored themselves this step.
    pub silent: &'a [Censored],
    /// Under NIS censoring, every active sensor of this step, sent or
    /// silent: the bound takes the censored law's information of each.
    pub censored: &'a [Censored],
}

impl Evidence<'_> {
    pub(crate) fn is_empty(&self) -> bool {
        self.received.is_empty() && self.lagged.is_empty() && self.silent.is_empty()
    }
}

/// What the estimators share: the dynamics, every sensor's model and the quantizer.
#[derive(Debug, Clone)]
pub struct SensingModel {
    pub dynamics: Dynamics,
    /// By sensor id; one list shared by every node of a process that holds
    /// the same law and layout ([`sensor_models`]).
    pub sensors: Arc<[ObservationModel]>,
    pub quantizer: Option<Quantizer>,
}

/// Every sensor's model under `law`, built once per law and layout in a
/// process: in `sim` every node holds the same list, and a copy per node
/// made a network's memory grow as the square of its nodes (1,600 nodes
/// held 5 GB of them). The last list built is remembered while anyone
/// holds it; the layout is the topology's own list, which its clones
/// share, and the remembered `Weak` keeps its address from being reused.
fn sensor_models(law: &Law, positions: &Arc<[[f64; 2]]>) -> Arc<[ObservationModel]> {
    type Remembered = (Weak<[[f64; 2]]>, Law, Weak<[ObservationModel]>);
    static LAST: Mutex<Option<Remembered>> = Mutex::new(None);
    let mut last = LAST.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((layout, l, models)) = last.as_ref() {
        if std::ptr::addr_eq(layout.as_ptr(), Arc::as_ptr(positions)) && l == law {
            if let Some(models) = models.upgrade() {
                return models;
            }
        }
    }
    let models: Arc<[ObservationModel]> = positions.iter().map(|p| law.at(*p)).collect();
    *last = Some((
        Arc::downgrade(positions),
        law.clone(),
        Arc::downgrade(&models),
    ));
    models
}

impl SensingModel {
    /// The scenario's models, with every sensor of the topology.
    pub fn from_scenario(scenario: &Scenario, topology: &Topology) -> Result<Self, ScenarioError> {
        Ok(Self::new(&scenario.models()?, topology))
    }

    pub fn new(models: &Models, topology: &Topology) -> Self {
        Self {
            sensors: sensor_models(&models.law, &topology.sensor_positions),
            dynamics: models.dynamics.clone(),
            quantizer: models.quantizer.clone(),
        }
    }

    fn measurement(&self) -> Measurement<'_> {
        match &self.quantizer {
            Some(q) => Measurement::Quantized(q),
            None => Measurement::Raw,
        }
    }

    /// Every sensor of the network as the bounds take it, by sensor id.
    pub fn sensor_terms(&self) -> Vec<SensorTerm<'_>> {
        self.sensors
            .iter()
            .map(|model| SensorTerm {
                model,
                measurement: self.measurement(),
            })
            .collect()
    }

    /// `ln p(y | x)` of one observation.
    pub fn ln_likelihood(&self, obs: &Observation, x: &State) -> f64 {
        let (g, r) = self.sensors[obs.sensor as usize].mean_and_variance(x);
        self.ln_likelihood_of(obs, g, r)
    }

    /// [`ln_likelihood`](Self::ln_likelihood) from the observing sensor's
    /// mean g and variance R at the state.
    #[inline]
    fn ln_likelihood_of(&self, obs: &Observation, g: f64, r: f64) -> f64 {
        let model = &self.sensors[obs.sensor as usize];
        match (obs.value, &self.quantizer) {
            // Within 1e-8 of the exact ln h (a weight's relative error).
            (ObservedValue::Cell(cell), Some(q)) => q.ln_probability_interpolated(cell, g, r),
            (ObservedValue::Raw(z), _) => {
                let d = if model.is_angular() {
                    wrap_angle(z - g)
                } else {
                    z - g
                };
                -0.5 * (d * d / r + r.ln() + (2.0 * PI).ln())
            }
            (ObservedValue::Cell(_), None) => f64::NEG_INFINITY,
        }
    }

    /// `Σ_o ln p(o | x_j)` of every particle into `out` (one value per
    /// particle): bit for bit [`ln_likelihood`](Self::ln_likelihood) summed
    /// particle by particle, but each observing sensor's model and the
    /// likelihood table's reads taken a batch of particles at a time,
    /// vectorised ([`bounds::batch`]).
    pub fn ln_likelihoods(
        &self,
        observations: &[Observation],
        particles: &[State],
        out: &mut [f64],
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            fn with_avx2(m: &SensingModel, o: &[Observation], p: &[State], out: &mut [f64]) {
                m.ln_likelihoods_batched(o, p, out)
            }
            if has_avx2() {
                // SAFETY: the CPU has AVX2.
                return unsafe { with_avx2(self, observations, particles, out) };
            }
        }
        self.ln_likelihoods_batched(observations, particles, out)
    }

    #[inline(always)]
    fn ln_likelihoods_batched(
        &self,
        observations: &[Observation],
        particles: &[State],
        out: &mut [f64],
    ) {
        let mut e = Evaluations::default();
        let mut reads = TableReads::default();
        for (states, out) in particles.chunks(CHUNK).zip(out.chunks_mut(CHUNK)) {
            // What `Iterator::sum` starts from.
            out.fill(-0.0);
            let at = Positions::of(states);
            for o in observations {
                let model = &self.sensors[o.sensor as usize];
                if !model.depends_on_position_only() {
                    for (l, x) in out.iter_mut().zip(states) {
                        *l += self.ln_likelihood(o, x);
                    }
                    continue;
                }
                model.evaluate_batch(states, &at, &mut e);
                match (o.value, &self.quantizer) {
                    (ObservedValue::Cell(cell), Some(q)) => {
                        let mut ln_h = [0.0; CHUNK];
                        q.ln_probability_batch(
                            cell,
                            &e.g,
                            &e.r,
                            states.len(),
                            &mut ln_h,
                            &mut reads,
                        );
                        for (l, h) in out.iter_mut().zip(ln_h) {
                            *l += h;
                        }
                    }
                    _ => {
                        for (i, l) in out.iter_mut().enumerate() {
                            *l += self.ln_likelihood_of(o, e.g[i], e.r[i]);
                        }
                    }
                }
            }
        }
    }

    /// `ln P(silent | x)` of a censored sensor: its innovation, given x,
    /// is `N(h(x) − h(x̂), r(x))`, inside the window with this probability.
    pub fn ln_silence(&self, silence: &Censored, x: &State) -> f64 {
        let e = self.sensors[silence.sensor as usize].evaluate(x);
        silence.innovation.ln_silence(&silence.rule, e.g, e.r)
    }

    /// [`ln_silence`](Self::ln_silence) at a batch of states (at most
    /// [`CHUNK`]; the lanes past them are not to be read), bit for bit,
    /// the interval masses vectorised.
    pub fn ln_silence_batch(&self, silence: &Censored, states: &[State], out: &mut [f64; CHUNK]) {
        let (mut mu, mut r) = ([0.0; CHUNK], [1.0; CHUNK]);
        for ((m, r), x) in mu.iter_mut().zip(r.iter_mut()).zip(states) {
            let e = self.sensors[silence.sensor as usize].evaluate(x);
            *m = silence.innovation.of(e.g);
            *r = e.r;
        }
        let s = silence.innovation.variance;
        silence.rule.ln_silence_probability_batch(&mu, s, &r, out);
    }

    /// A step's observation information for the conditional bound over a
    /// particle set: under NIS censoring `Σ_s J_cens,s` over every active
    /// sensor, sent or silent (silence is a measurement too; no traffic is
    /// needed, the node knows each window), otherwise `Σ_s J_Y,s` over the
    /// observations received.
    pub fn step_information(
        &self,
        evidence: &Evidence,
        particles: &[State],
        weights: &[f64],
    ) -> Result<Mat4, BoundError> {
        if evidence.censored.is_empty() {
            return self.observation_information(evidence.received, particles, weights);
        }
        self.censored_information(evidence.censored, particles, weights)
    }

    /// `Σ_s Σ_j w_j J_cens,s(x_j)` ([`bounds::censoring::SilenceWindow`]).
    pub fn censored_information(
        &self,
        censored: &[Censored],
        particles: &[State],
        weights: &[f64],
    ) -> Result<Mat4, BoundError> {
        let sensors: Vec<SensorTerm> = censored
            .iter()
            .map(|c| SensorTerm {
                model: &self.sensors[c.sensor as usize],
                measurement: self.measurement(),
            })
            .collect();
        let windows: Vec<_> = censored
            .iter()
            .map(|c| c.innovation.silence_window(&c.rule))
            .collect();
        bounds::censoring::censored_information(&sensors, &windows, particles, weights)
    }

    /// `Σ_s Σ_j w_j J_Y,s(x_j)`: the expected information of the observed
    /// sensors over a particle set (zero with no observations).
    pub fn observation_information(
        &self,
        observations: &[Observation],
        particles: &[State],
        weights: &[f64],
    ) -> Result<Mat4, BoundError> {
        if observations.is_empty() {
            return Ok(Mat4::zeros());
        }
        let sensors = self.terms(observations);
        observation_information(&sensors, particles, weights)
    }

    /// Each observing sensor's model and how it reports.
    fn terms(&self, observations: &[Observation]) -> Vec<SensorTerm<'_>> {
        observations
            .iter()
            .map(|o| SensorTerm {
                model: &self.sensors[o.sensor as usize],
                measurement: self.measurement(),
            })
            .collect()
    }

    /// [`observation_information`](Self::observation_information), and
    /// each particle's `Σ_o ln p(o | x_j)` into `ln_likelihood`, from one
    /// evaluation of each observing sensor's model per particle.
    pub fn information_and_likelihood(
        &self,
        observations: &[Observation],
        particles: &[State],
        weights: &[f64],
        ln_likelihood: &mut [f64],
    ) -> Result<Mat4, BoundError> {
        ln_likelihood.iter_mut().for_each(|l| *l = 0.0);
        let sensors = self.terms(observations);
        let first_stage = FirstStage {
            model: self,
            observations,
            ln_likelihood,
            reads: TableReads::default(),
        };
        observation_information_with(&sensors, particles, weights, first_stage)
    }

    /// `J̄_s = Σ_j w_j J_Y,s(x_j)`: what sensor `s` would be expected to add
    /// over a particle set, before anything is observed (sensor selection).
    pub fn expected_information(
        &self,
        sensor: u16,
        particles: &[State],
        weights: &[f64],
    ) -> Result<Mat4, BoundError> {
        let term = SensorTerm {
            model: &self.sensors[sensor as usize],
            measurement: self.measurement(),
        };
        observation_information(&[term], particles, weights)
    }

    /// `−∇² ln p(y | x)`: the observed information at the received value.
    pub fn observed_information(&self, obs: &Observation, x: &State) -> Mat4 {
        let model = &self.sensors[obs.sensor as usize];
        match (obs.value, &self.quantizer) {
            (ObservedValue::Cell(cell), Some(q)) => observed_information(model, q, cell, x),
            // For a raw Gaussian observation the expected and observed
            // information differ only by terms with zero mean; use the expected one.
            _ => bounds::expected_information(model, Measurement::Raw, x),
        }
    }
}

/// The local filter's first stage, as [`observation_information_with`]
/// asks for its Fisher scalars: each batch's log-likelihoods added into
/// `ln_likelihood` from the same evaluations and table reads. A named type,
/// so that its `#[inline(always)]` method is compiled into the kernel's
/// AVX2 copy.
struct FirstStage<'a> {
    model: &'a SensingModel,
    observations: &'a [Observation],
    ln_likelihood: &'a mut [f64],
    reads: TableReads,
}

impl BatchScalars for FirstStage<'_> {
    #[inline(always)]
    fn scalars(
        &mut self,
        first: usize,
        k: usize,
        g: &[f64; CHUNK],
        r: &[f64; CHUNK],
        n: usize,
        out: &mut ScalarBatch,
    ) {
        let observation = &self.observations[k];
        let ln_likelihood = &mut self.ln_likelihood[first..first + n];
        match (observation.value, &self.model.quantizer) {
            (ObservedValue::Cell(cell), Some(q)) => {
                let mut ln_h = [0.0; CHUNK];
                q.ln_probability_and_fisher_batch(cell, g, r, n, &mut ln_h, out, &mut self.reads);
                for (l, h) in ln_likelihood.iter_mut().zip(ln_h) {
                    *l += h;
                }
            }
            _ => {
                let measurement = self.model.measurement();
                for (i, l) in ln_likelihood.iter_mut().enumerate() {
                    *l += self.model.ln_likelihood_of(observation, g[i], r[i]);
                    out.set(i, scalars_of_mean_and_variance(g[i], r[i], measurement));
                }
            }
        }
    }
}
