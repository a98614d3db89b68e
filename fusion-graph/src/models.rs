//! What a scenario means, defined once: the dynamics, the sensors'
//! observation law, the quantizer, the prior, the wire sizes and the streams
//! of randomness. Validation builds these through the `bounds` constructors,
//! and every actor builds its own from the same functions, so nothing is
//! mapped field by field twice and nothing is assumed valid.

use std::f64::consts::PI;

use bounds::observation::ObservationLaw;
use bounds::{Dynamics, Gaussian, Mat4, ParameterError, Quantizer, State};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::scenario::{Scenario, TargetStart};
use crate::topology::Topology;
use crate::ScenarioError;
use wire::ActorId;
use wire::WireFormat;

/// The models of a scenario, built from its values by the `bounds`
/// constructors.
#[derive(Debug, Clone)]
pub struct Models {
    pub dynamics: Dynamics,
    pub law: bounds::Law,
    /// `None` when sensors send raw values.
    pub quantizer: Option<Quantizer>,
    /// `P_0`.
    pub prior_cov: Mat4,
}

/// What a scenario's models are called in errors when no file is at hand.
const VALIDATED: &str = "<scenario>";

impl Scenario {
    /// The scenario's models. Fails, naming the key, on a value the models
    /// refuse; validation calls this, so a loaded scenario always succeeds.
    pub fn models(&self) -> Result<Models, ScenarioError> {
        self.models_named(VALIDATED)
    }

    pub(crate) fn models_named(&self, file: &str) -> Result<Models, ScenarioError> {
        let invalid = |section: &str, e: ParameterError| ScenarioError::Invalid {
            file: file.into(),
            key: format!("{section}.{}", e.parameter),
            expected: e.expected.into(),
            got: e.value.to_string(),
        };
        let dynamics = match self.dynamics.turn() {
            Some(turn) => Dynamics::new(*turn).map_err(|e| invalid("dynamics", e))?,
            None => Dynamics::of(self.dynamics.motion().clone()).map_err(|e| {
                ScenarioError::Invalid {
                    file: file.into(),
                    key: "dynamics".into(),
                    expected: format!("a model whose process noise is usable: {e}"),
                    got: format!("kind = \"{}\"", self.dynamics.kind()),
                }
            })?,
        };
        // A program's law checked its parameters as it was built.
        if let Some(law) = self.observation.built_in() {
            law.validate().map_err(|e| invalid("observation", e))?;
        }
        let quantizer = self.quantizer_model(file)?;
        let sd = self.filter.prior_std;
        for (i, s) in sd.iter().enumerate() {
            if !(s.is_finite() && *s > 0.0) {
                return Err(ScenarioError::Invalid {
                    file: file.into(),
                    key: format!("filter.prior_std[{i}]"),
                    expected: "a finite number > 0".into(),
                    got: s.to_string(),
                });
            }
        }
        let prior_cov = Mat4::from_diagonal(&State::from(sd.map(|s| s * s)));
        Ok(Models {
            dynamics,
            law: self.observation.law().clone(),
            quantizer,
            prior_cov,
        })
    }

    fn quantizer_model(&self, file: &str) -> Result<Option<Quantizer>, ScenarioError> {
        let q = &self.quantizer;
        // An angle's cells wrap at ±π whatever the file says.
        let built = if self.observation.law().is_angular() {
            Quantizer::uniform_wrapped(q.bits, -PI, PI)
        } else {
            match (q.lo, q.hi) {
                (Some(lo), Some(hi)) => Quantizer::uniform(q.bits, lo, hi),
                _ => {
                    return Err(ScenarioError::Invalid {
                        file: file.into(),
                        key: "quantizer.lo/quantizer.hi".into(),
                        expected: "a finite range lo < hi for a non-bearing observation".into(),
                        got: format!("{:?}..{:?}", q.lo, q.hi),
                    })
                }
            }
        };
        // The quantizer is built (and its bits checked) even when sensors
        // send raw values: `raw` is a switch, not a licence for a bad value.
        let built = built.map_err(|e| {
            let (key, expected) = match e {
                bounds::QuantizerError::BitsOutOfRange { .. } => (
                    "quantizer.bits",
                    format!("an integer from 1 to {}", bounds::quantizer::MAX_BITS),
                ),
                _ => (
                    "quantizer.lo/quantizer.hi",
                    "a finite range lo < hi".to_string(),
                ),
            };
            ScenarioError::Invalid {
                file: file.into(),
                key: key.into(),
                expected,
                got: match e {
                    bounds::QuantizerError::BitsOutOfRange { bits } => bits.to_string(),
                    _ => format!("{:?}..{:?}", q.lo, q.hi),
                },
            }
        })?;
        Ok((!q.raw).then_some(built))
    }

    /// The prior every filter starts from: `N(m_0, P_0)`. With the truth
    /// at the target's state (`target.start = "fixed"`), `m_0` is drawn once
    /// per run from `N(x_true(0), P_0)` (docs/equations.md's default
    /// scenario); with the truth drawn from the prior, `m_0` is the
    /// target's state.
    pub fn network_prior(&self, models: &Models) -> Gaussian {
        let nominal = State::from(self.target.initial_state());
        let mean = match self.target.start {
            TargetStart::Fixed => nominal + self.start_offset(),
            TargetStart::Prior => nominal,
        };
        Gaussian {
            mean,
            cov: models.prior_cov,
        }
    }

    /// The true state at step 0 of this run: the target's state, or the
    /// state plus this run's offset when the truth is drawn from the prior.
    pub fn true_initial_state(&self) -> State {
        let nominal = State::from(self.target.initial_state());
        match self.target.start {
            TargetStart::Fixed => nominal,
            TargetStart::Prior => nominal + self.start_offset(),
        }
    }

    /// This run's draw `sd ∘ n` from its prior stream (the prior's
    /// standard deviations are per component, its covariance diagonal).
    fn start_offset(&self) -> State {
        let sd = State::from(self.filter.prior_std);
        let mut rng = stream_rng(self.seed, ActorId::Launcher, 0, Stream::Prior);
        let noise = State::from_fn(|_, _| {
            rand::Rng::sample::<f64, _>(&mut rng, rand_distr::StandardNormal)
        });
        sd.component_mul(&noise)
    }

    /// The wire sizes this scenario fixes on this topology.
    pub fn wire_format(&self, topology: &Topology) -> WireFormat {
        WireFormat {
            cell_bytes: (self.quantizer.bits as usize).div_ceil(8),
            // An activation mask has at least one byte.
            activation_bytes: topology.most_sensors_per_node().div_ceil(8).max(1),
            payloads: self.vocabulary.payloads(),
        }
    }
}

/// The streams of randomness of a run, one per purpose. Each actor draws
/// each purpose at each step from its own generator, so results never depend
/// on the order in which messages arrive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u64)]
pub enum Stream {
    /// A sensor's measurement noise.
    SensorNoise = 1,
    /// A node's random choice of sensors.
    Activation = 2,
    LocalFilter = 3,
    FusionFilter = 4,
    /// The prior mean `m_0`.
    Prior = 5,
    /// The centralized reference's filter.
    CentralFilter = 6,
    /// The true trajectory's process noise.
    Truth = 7,
    /// A sensor's coin for random censoring.
    Censoring = 8,
    /// The random-exchange paper's matching of a step, which every node
    /// draws alike (drawn for the launcher, standing for the network).
    Exchange = 9,
    /// A fusion centre's sensing matrix, or its random choice of sensors,
    /// for a multiple-access channel.
    SensingMatrix = 10,
    /// A multiple-access channel's receiver noise.
    ReceiverNoise = 11,
    /// The sensing matrices a fusion centre draws to weigh a design.
    DesignSamples = 12,
}

/// The seed of `stream` for `actor` at `step`: splitmix64 over the four.
pub fn stream_seed(scenario_seed: u64, actor: ActorId, step: u32, stream: Stream) -> u64 {
    let (kind, index) = actor.to_wire();
    let mut x = scenario_seed ^ 0x9e37_79b9_7f4a_7c15;
    for v in [kind as u64, index as u64, step as u64, stream as u64] {
        x = x
            .wrapping_add(v.wrapping_mul(0xbf58_476d_1ce4_e5b9))
            .wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = x;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        x = z ^ (z >> 31);
    }
    x
}

/// A generator for `stream` of `actor` at `step`.
pub fn stream_rng(scenario_seed: u64, actor: ActorId, step: u32, stream: Stream) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(stream_seed(scenario_seed, actor, step, stream))
}

/// The seed of an actor's link shaper (injected loss and jitter on its
/// incoming links). `sim` and `run` must agree on it for `run --lockstep`
/// to reproduce `sim` under link faults, so it is defined here only.
pub fn link_fault_seed(scenario_seed: u64, actor: ActorId) -> u64 {
    match actor {
        ActorId::Launcher => scenario_seed,
        ActorId::Node(i) => scenario_seed ^ (0x1000 + i as u64),
        ActorId::Sensor(i) => scenario_seed ^ (0x5000 + i as u64),
        ActorId::Mac(i) => scenario_seed ^ (0x9000 + i as u64),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::DEFAULT_SCENARIO;

    /// One draw per run, on the truth's side or the prior's: fixed puts the
    /// truth at the nominal state and the prior mean off it; prior the
    /// other way round, by the same offset.
    #[test]
    fn the_start_draw_goes_to_the_truth_or_to_the_prior() {
        let fixed = Scenario::default_scenario();
        let mut drawn = fixed.clone();
        drawn.target.start = TargetStart::Prior;
        let m = fixed.models().unwrap();
        let nominal = State::from(fixed.target.initial_state());
        assert_eq!(fixed.true_initial_state(), nominal);
        assert_eq!(drawn.network_prior(&m).mean, nominal);
        let offset = fixed.network_prior(&m).mean - nominal;
        assert!(offset.norm() > 0.0);
        assert!((drawn.true_initial_state() - nominal - offset).norm() < 1e-9);
        // Another seed, another draw.
        let mut other = drawn.clone();
        other.seed += 1;
        assert_ne!(other.true_initial_state(), drawn.true_initial_state());
    }

    #[test]
    fn the_default_scenario_builds_its_models() {
        let s = Scenario::default_scenario();
        let m = s.models().unwrap();
        assert_eq!(m.quantizer.as_ref().unwrap().cells(), 256);
        assert_eq!(m.prior_cov[(0, 0)], 2500.0);
        let p = s.network_prior(&m);
        assert_eq!(
            p,
            s.network_prior(&m),
            "the prior is drawn from its own stream"
        );
    }

    #[test]
    fn a_value_the_models_refuse_names_its_key_even_after_loading() {
        let mut s = Scenario::from_toml(DEFAULT_SCENARIO, "d", &[]).unwrap();
        s.quantizer.bits = 17;
        let e = s.models().unwrap_err().to_string();
        assert!(e.contains("quantizer.bits") && e.contains("1 to 16"), "{e}");
        s.quantizer.bits = 8;
        let mut turn = *s.dynamics.turn().unwrap();
        turn.maneuver_accel = -1.0;
        s.dynamics = turn.into();
        let e = s.models().unwrap_err().to_string();
        assert!(e.contains("dynamics.maneuver_accel"), "{e}");
    }

    #[test]
    fn streams_differ_by_every_coordinate() {
        let base = stream_seed(1, ActorId::Node(2), 3, Stream::Activation);
        assert_ne!(
            base,
            stream_seed(2, ActorId::Node(2), 3, Stream::Activation)
        );
        assert_ne!(
            base,
            stream_seed(1, ActorId::Sensor(2), 3, Stream::Activation)
        );
        assert_ne!(
            base,
            stream_seed(1, ActorId::Node(2), 4, Stream::Activation)
        );
        assert_ne!(
            base,
            stream_seed(1, ActorId::Node(2), 3, Stream::LocalFilter)
        );
    }
}
