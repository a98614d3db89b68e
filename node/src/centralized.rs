//! The centralized reference: one filter that receives every active sensor's
//! observation, with the centralized conditional PCRLB. The distributed
//! bound is judged against it.

use bounds::BoundError;
use fusion_graph::scenario::Scenario;
use fusion_graph::wire::{Message, Payload};
use fusion_graph::{ActorId, Topology};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sensor::stream_seed;

use crate::actor::{network_prior, sensing_model};
use crate::estimator::{LocalFilter, LocalUpdate, Observation, ObservedValue, SensingModel};

const CENTRAL_STREAM: u64 = 6;

pub struct CentralizedReference {
    model: SensingModel,
    filter: LocalFilter,
    step: u32,
    received: Vec<Observation>,
}

impl CentralizedReference {
    pub fn new(scenario: &Scenario, topology: &Topology) -> Result<Self, BoundError> {
        let rng = ChaCha8Rng::seed_from_u64(stream_seed(
            scenario.seed,
            ActorId::Launcher,
            0,
            CENTRAL_STREAM,
        ));
        Ok(Self {
            model: sensing_model(scenario, topology),
            filter: LocalFilter::new(
                scenario.filter.particles as usize,
                &network_prior(scenario),
                rng,
            )?,
            step: 0,
            received: Vec::new(),
        })
    }

    /// Collects an observation message of the current step.
    pub fn observe(&mut self, message: &Message) {
        let ActorId::Sensor(sensor) = message.header.sender else {
            return;
        };
        let value = match message.payload {
            Payload::Observation { cell } => ObservedValue::Cell(cell),
            Payload::RawObservation { value } => ObservedValue::Raw(value),
            _ => return,
        };
        if message.header.step == self.step + 1 && !self.received.iter().any(|o| o.sensor == sensor)
        {
            self.received.push(Observation { sensor, value });
        }
    }

    /// Runs the step with what was collected: estimate and centralized bound.
    pub fn finish_step(&mut self) -> Result<LocalUpdate, BoundError> {
        self.received.sort_by_key(|o| o.sensor);
        let update = self.filter.step(&self.model, &self.received, false);
        self.received.clear();
        self.step += 1;
        update
    }
}
