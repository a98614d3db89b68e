//! The centralized reference: one filter that receives every active sensor's
//! observation, with the centralized conditional PCRLB. The distributed
//! bound is judged against it.

use fusion_graph::scenario::Scenario;
use fusion_graph::{stream_rng, ActorId, Stream, Topology};
use wire::{Message, Payload};

use crate::estimator::{LocalFilter, LocalUpdate, Observation, ObservedValue, SensingModel};
use crate::NodeError;

pub struct CentralizedReference {
    model: SensingModel,
    filter: LocalFilter,
    step: u32,
    received: Vec<Observation>,
}

impl CentralizedReference {
    pub fn new(scenario: &Scenario, topology: &Topology) -> Result<Self, NodeError> {
        let rng = stream_rng(scenario.seed, ActorId::Launcher, 0, Stream::CentralFilter);
        let models = scenario.models()?;
        let prior = scenario.network_prior(&models);
        Ok(Self {
            model: SensingModel::new(&models, topology),
            filter: LocalFilter::new(scenario.filter.particles as usize, &prior, rng)
                .map_err(NodeError::Reference)?
                .with_resampling(scenario.filter.resampler),
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

    /// Runs the step with what was collected: estimate and centralized
    /// bound. A step that fails (its bound's information no longer
    /// positive definite, say) is logged and gives nothing, as a node's
    /// does: the reference goes on to the next step rather than ending
    /// the run it is only a yardstick for.
    pub fn finish_step(&mut self) -> Option<LocalUpdate> {
        self.received.sort_by_key(|o| o.sensor);
        let update = self.filter.update(
            &self.model,
            &crate::estimator::Evidence {
                received: &self.received,
                ..Default::default()
            },
            false,
        );
        self.received.clear();
        self.step += 1;
        update
            .inspect_err(|e| {
                tracing::error!(step = self.step, error = %e, "centralized reference step failed; no row for it");
            })
            .ok()
    }
}
