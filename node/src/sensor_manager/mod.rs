//! Sensor managers: which of its sensors a node activates each step
//! (Stone Soup's name for the role). The choice goes out as an activation
//! message, counted like any other, never as a shared random draw.
//!
//! - [`UniformRandom`]: seed 000's policy, uniformly at random within the
//!   node's own sensors, honouring a network-wide cap;
//! - [`Closest`]: the sensors nearest the predicted target, network-wide.

mod closest;
mod random;

pub use closest::Closest;
pub use random::UniformRandom;

use fusion_graph::scenario::SensorManagerKind;
use fusion_graph::Scenario;

use bounds::State;

/// What a node knows when it chooses.
#[derive(Debug, Clone, Copy)]
pub struct SelectionContext<'a> {
    pub step: u32,
    pub node: u16,
    /// The node's own sensors, in increasing order; choices index into it.
    pub own_sensors: &'a [u16],
    /// The live nodes this node can reach (`view[i]` for node i).
    pub view: &'a [bool],
    /// The fusion filter's predicted particles for this step (the global
    /// predictive density), when the manager asked for them with
    /// [`SensorManager::needs_prediction`].
    pub predicted: Option<&'a [State]>,
    /// Every sensor's position, by sensor id.
    pub sensor_positions: &'a [[f64; 2]],
    /// Each node's sensors, by node.
    pub node_sensors: &'a [Vec<u16>],
}

/// The scenario's manager (`sensors.manager`).
pub fn for_scenario(scenario: &Scenario) -> Box<dyn SensorManager> {
    match scenario.sensors.manager {
        SensorManagerKind::Random => Box::new(UniformRandom::for_scenario(scenario)),
        SensorManagerKind::Closest => Box::new(Closest::for_scenario(scenario)),
    }
}

pub trait SensorManager {
    /// Whether [`choose`](Self::choose) scores candidates on the predicted
    /// particles: the node then predicts before it activates anyone.
    fn needs_prediction(&self) -> bool {
        false
    }

    /// The sensors to activate this step, as increasing positions in
    /// `context.own_sensors`.
    fn choose(&mut self, context: &SelectionContext<'_>) -> Vec<usize>;
}
