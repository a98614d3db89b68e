//! The sensor actor as an I/O-free state machine.
//!
//! A sensor learns the true state of step k from the launcher's tick and
//! whether it is active from its node's activation message; the two arrive in
//! either order. When it has both, it measures through its observation model,
//! quantizes (or not) and emits one observation message. The noise of step k
//! is drawn from a generator seeded by (scenario seed, sensor, k), so the
//! observation does not depend on message timing: the in-process driver and
//! the multi-process runtime see the same values.

use std::f64::consts::PI;

use bounds::{ObservationModel, Quantizer, State};
use fusion_graph::scenario::{ObservationConfig, Scenario};
use fusion_graph::wire::{Message, Payload};
use fusion_graph::{ActorId, Topology};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The observation model of the scenario, placed at `position`.
pub fn observation_model(config: &ObservationConfig, position: [f64; 2]) -> ObservationModel {
    match *config {
        ObservationConfig::Bearing { sigma_theta, d0 } => ObservationModel::Bearing {
            sensor: position,
            sigma_theta,
            d0,
        },
        ObservationConfig::Rss {
            p0,
            zeta,
            d0,
            sigma,
        } => ObservationModel::Rss {
            sensor: position,
            p0,
            zeta,
            d0,
            sigma,
        },
        ObservationConfig::Amplitude {
            p0,
            alpha,
            exponent,
            sigma,
        } => ObservationModel::Amplitude {
            sensor: position,
            p0,
            alpha,
            exponent,
            sigma,
        },
    }
}

/// The scenario's quantizer, or `None` when sensors send raw values.
pub fn quantizer(s: &Scenario) -> Option<Quantizer> {
    if s.quantizer.raw {
        return None;
    }
    let q = match s.observation {
        ObservationConfig::Bearing { .. } => Quantizer::uniform_wrapped(s.quantizer.bits, -PI, PI),
        _ => Quantizer::uniform(
            s.quantizer.bits,
            s.quantizer.lo.unwrap_or(0.0),
            s.quantizer.hi.unwrap_or(1.0),
        ),
    };
    Some(q.expect("validated with the scenario"))
}

/// A seed for one purpose of one actor at one step, so that streams of
/// randomness never depend on the order in which messages arrive.
pub fn stream_seed(scenario_seed: u64, actor: ActorId, step: u32, purpose: u64) -> u64 {
    let (kind, index) = actor.to_wire();
    let mut x = scenario_seed ^ 0x9e37_79b9_7f4a_7c15;
    for v in [kind as u64, index as u64, step as u64, purpose] {
        // splitmix64
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

const NOISE_STREAM: u64 = 1;

/// What a sensor is told.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorInput {
    /// The launcher's tick: the step and the true state.
    Tick { step: u32, truth: State },
    /// The node's activation for a step.
    Activation { step: u32, active: bool },
}

#[derive(Debug, Clone)]
pub struct SensorActor {
    index: u16,
    model: ObservationModel,
    quantizer: Option<Quantizer>,
    seed: u64,
    /// The latest tick not yet measured.
    truth: Option<(u32, State)>,
    /// The latest step this sensor was activated for.
    activated: Option<u32>,
    last_sent: Option<u32>,
}

impl SensorActor {
    pub fn new(scenario: &Scenario, topology: &Topology, index: u16) -> Self {
        Self {
            index,
            model: observation_model(
                &scenario.observation,
                topology.sensor_positions[index as usize],
            ),
            quantizer: quantizer(scenario),
            seed: scenario.seed,
            truth: None,
            activated: None,
            last_sent: None,
        }
    }

    pub fn id(&self) -> ActorId {
        ActorId::Sensor(self.index)
    }

    /// Handles one input; returns the observation to send, if this completes one.
    pub fn handle(&mut self, input: SensorInput) -> Option<Message> {
        match input {
            SensorInput::Tick { step, truth } => self.truth = Some((step, truth)),
            SensorInput::Activation { step, active } => {
                if active {
                    self.activated = Some(step);
                }
            }
        }
        let (step, truth) = self.truth?;
        if self.activated != Some(step) || self.last_sent == Some(step) {
            return None;
        }
        self.last_sent = Some(step);
        Some(Message::new(self.id(), step, 0, self.measure(step, &truth)))
    }

    fn measure(&self, step: u32, truth: &State) -> Payload {
        let mut rng =
            ChaCha8Rng::seed_from_u64(stream_seed(self.seed, self.id(), step, NOISE_STREAM));
        let z = self.model.sample(truth, &mut rng);
        match &self.quantizer {
            Some(q) => Payload::Observation { cell: q.encode(z) },
            None => Payload::RawObservation { value: z },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn actor() -> SensorActor {
        let s = Scenario::default_scenario();
        let t = Topology::from_scenario(&s, "d").unwrap();
        SensorActor::new(&s, &t, 12)
    }

    #[test]
    fn measures_once_per_step_when_both_inputs_arrived_in_either_order() {
        let truth = State::new(1000.0, 900.0, -6.0, -7.0);
        let mut a = actor();
        assert!(a.handle(SensorInput::Tick { step: 1, truth }).is_none());
        let first = a
            .handle(SensorInput::Activation {
                step: 1,
                active: true,
            })
            .unwrap();
        assert!(
            a.handle(SensorInput::Activation {
                step: 1,
                active: true
            })
            .is_none(),
            "one observation per step"
        );
        let mut b = actor();
        b.handle(SensorInput::Activation {
            step: 1,
            active: true,
        });
        let second = b.handle(SensorInput::Tick { step: 1, truth }).unwrap();
        assert_eq!(
            first, second,
            "arrival order must not change the observation"
        );
        // Not activated: silent.
        assert!(a.handle(SensorInput::Tick { step: 2, truth }).is_none());
        assert!(a
            .handle(SensorInput::Activation {
                step: 2,
                active: false
            })
            .is_none());
    }

    #[test]
    fn quantized_observation_lands_near_the_true_bearing() {
        let truth = State::new(1000.0, 900.0, -6.0, -7.0);
        let mut a = actor();
        let q = quantizer(&Scenario::default_scenario()).unwrap();
        let e = a.model.evaluate(&truth);
        let mut misses = 0;
        for step in 1..=200 {
            a.handle(SensorInput::Tick { step, truth });
            let Some(Message {
                payload: Payload::Observation { cell },
                ..
            }) = a.handle(SensorInput::Activation { step, active: true })
            else {
                panic!("no observation")
            };
            let err = bounds::wrap_angle(q.representative(cell) - e.g).abs();
            if err > 4.0 * e.r.sqrt() + 0.025 {
                misses += 1;
            }
        }
        assert!(misses <= 1, "{misses} of 200 beyond 4σ");
    }
}
