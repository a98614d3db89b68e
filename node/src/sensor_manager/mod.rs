//! Sensor managers: which of its sensors a node activates each step
//! (Stone Soup's name for the role). The choice goes out as an activation
//! message, counted like any other, never as a shared random draw.
//!
//! - [`UniformRandom`]: seed 000's policy, uniformly at random within the
//!   node's own sensors, honouring a network-wide cap.

mod random;

pub use random::UniformRandom;

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
    /// The local filter's predicted particles for this step, when the
    /// manager asked for them with [`SensorManager::needs_prediction`].
    pub predicted: Option<&'a [State]>,
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
