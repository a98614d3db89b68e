//! The centralized reference: one filter that receives every active sensor's
//! observation, with the centralized conditional PCRLB. The distributed
//! bound is judged against it.

use fusion_graph::scenario::Scenario;
use fusion_graph::{stream_rng, ActorId, Stream, Topology};
use wire::{Message, Payload};

use crate::collector::in_range;
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

    /// Collects an observation message of the current step: the first
    /// from each sensor. One from a sensor the network does not have, or of
    /// a cell its quantizer does not have, is dropped, as a node drops it:
    /// the message decoded, but its values are the sender's word.
    pub fn observe(&mut self, message: &Message) {
        let ActorId::Sensor(sensor) = message.header.sender else {
            return;
        };
        let value = match message.payload {
            Payload::Observation { cell } => ObservedValue::Cell(cell),
            Payload::RawObservation { value } => ObservedValue::Raw(value),
            _ => return,
        };
        let cells = self.model.quantizer.as_ref().map(|q| q.cells());
        if usize::from(sensor) >= self.model.sensors.len() || !in_range(value, cells) {
            tracing::debug!(
                sensor,
                ?value,
                "observation out of range; the centralized reference drops it"
            );
            return;
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::scenario::DEFAULT_SCENARIO;

    fn default_scenario() -> Scenario {
        Scenario::from_toml(DEFAULT_SCENARIO, "default", &[]).unwrap()
    }

    fn reference() -> CentralizedReference {
        let scenario = default_scenario();
        let topology = Topology::from_scenario(&scenario, "default").unwrap();
        CentralizedReference::new(&scenario, &topology).unwrap()
    }

    fn observation(sensor: u16, cell: u32) -> Message {
        Message::new(ActorId::Sensor(sensor), 1, 0, Payload::Observation { cell })
    }

    /// A cell the quantizer does not have and a sensor the network does
    /// not have are dropped: the step is the one that heard nothing, to
    /// the bit, where they would otherwise have indexed past the models.
    #[test]
    fn an_observation_out_of_range_is_dropped() {
        let mut heard_garbage = reference();
        let cells = heard_garbage.model.quantizer.as_ref().unwrap().cells() as u32;
        let sensors = heard_garbage.model.sensors.len() as u16;
        heard_garbage.observe(&observation(0, cells));
        heard_garbage.observe(&observation(0, u32::MAX));
        heard_garbage.observe(&observation(sensors, 0));
        heard_garbage.observe(&observation(u16::MAX, 0));
        assert!(heard_garbage.received.is_empty());
        let garbage = heard_garbage.finish_step().unwrap();
        let nothing = reference().finish_step().unwrap();
        assert_eq!(garbage.estimate, nothing.estimate);
        assert_eq!(garbage.bound, nothing.bound);

        // An observation in range is taken.
        let mut heard = reference();
        heard.observe(&observation(sensors - 1, cells - 1));
        assert_eq!(heard.received.len(), 1);
    }

    /// A step whose bound fails (here the information made indefinite)
    /// gives no row, and the reference goes on: the next step's
    /// observations are taken, and once its information is sound again
    /// it gives rows.
    #[test]
    fn a_failed_step_gives_no_row_and_the_next_goes_on() {
        let scenario = default_scenario();
        let prior = scenario.network_prior(&scenario.models().unwrap());
        let mut r = reference();
        r.filter.reset(&prior, bounds::Mat4::identity() * -1e15);
        r.observe(&observation(0, 0));
        assert!(r.finish_step().is_none());

        let next = Message::new(ActorId::Sensor(0), 2, 0, Payload::Observation { cell: 0 });
        r.observe(&next);
        assert_eq!(r.received.len(), 1, "step 2's observation is taken");
        r.filter.reset(
            &prior,
            prior.cov.try_inverse().expect("the prior's covariance"),
        );
        let update = r.finish_step().expect("a sound step gives a row");
        assert!(update.bound.is_some_and(f64::is_finite));
    }
}
