//! The processing-node actor of cqnet: the consensus-based distributed
//! particle filter (CF/DPF) with the distributed CQ/dPCRLB, as a state
//! machine with no I/O; and the centralized reference it is compared with.
//!
//! Rooms, by estimation role:
//! - [`filter`]: the particle filter's predictor, updater, resampler and
//!   regulariser;
//! - [`estimator`]: the CF/DPF's local and fusion filters with their bounds;
//! - [`sensor_manager`]: which sensors a node activates;
//! - [`collector`]: a step's observations, and which sensors stayed silent;
//! - [`diffusion`]: seed 004's trackers (RndEx-PF, KL fusion), one particle
//!   filter per node summarized as a Gaussian;
//! - [`gate`]: the innovation gate that leaves out implausible observations;
//! - [`fusion`]: the fusion protocols (average consensus, exact sums,
//!   min-consensus, random exchange, KL fusion) over a shared round engine;
//! - [`actor`]: the CF/DPF node's state machine, tying them together;
//! - [`diffusion_node`]: seed 004's node, one filter and a Gaussian to
//!   exchange or fuse;
//! - [`processing`]: either node behind one face, as the scenario says.

pub mod actor;
pub mod centralized;
pub mod collector;
pub mod diffusion;
pub mod diffusion_node;
pub mod estimator;
pub mod filter;
pub mod fusion;
pub mod gate;
pub mod processing;
pub mod sensor_manager;

#[cfg(test)]
mod harness;

pub use actor::{NodeActor, NodeError, Work};
pub use centralized::CentralizedReference;
pub use diffusion_node::DiffusionNode;
pub use estimator::{
    Contribution, FusionFilter, LocalFilter, Observation, ObservedValue, SensingModel,
};
pub use processing::ProcessingNode;

use fusion_graph::transport::Channel;
use fusion_graph::wire::{Message, Payload, Telemetry};
use fusion_graph::ActorId;

/// A message to publish.
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    pub channel: Channel,
    pub message: Message,
    pub receivers: Vec<ActorId>,
    /// Whom to wake, when not every receiver: the activation reaches all of
    /// a node's sensors but wakes only the active ones.
    pub wake: Option<Vec<ActorId>>,
}

impl Outgoing {
    /// A node's telemetry for `step`, to the launcher.
    pub(crate) fn telemetry(node: u16, step: u32, telemetry: Telemetry) -> Self {
        Self {
            channel: Channel::Telemetry(node),
            message: Message::new(ActorId::Node(node), step, 0, Payload::Telemetry(telemetry)),
            receivers: vec![ActorId::Launcher],
            wake: None,
        }
    }
}

/// A stage's time for telemetry: whole microseconds, saturating.
pub(crate) fn micros(d: std::time::Duration) -> u32 {
    d.as_micros().min(u32::MAX as u128) as u32
}

/// An estimate for telemetry: a component that is not finite is sent as 0
/// (the wire carries no NaN the launcher would have to guard against).
pub(crate) fn reported_estimate(estimate: &bounds::State) -> [f64; 4] {
    std::array::from_fn(|i| {
        if estimate[i].is_finite() {
            estimate[i]
        } else {
            0.0
        }
    })
}
