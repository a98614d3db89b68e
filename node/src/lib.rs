//! The processing-node actor of cqnet: the consensus-based distributed
//! particle filter (CF/DPF) with the distributed CQ/dPCRLB, as a state
//! machine with no I/O; and the centralized reference it is compared with.
//!
//! Rooms, by estimation role:
//! - [`filter`]: the particle filter's predictor, updater, resampler and
//!   regulariser;
//! - [`sensing`]: the sensors' models and what a step's observations say;
//! - [`estimator`]: the CF/DPF's local and fusion filters with their bounds;
//! - [`sensor_manager`]: which sensors a node activates;
//! - [`collector`]: a step's observations, and which sensors stayed silent;
//! - [`diffusion`]: the random-exchange paper's trackers (RndEx-PF, KL fusion), one particle
//!   filter per node summarized as a Gaussian;
//! - [`gate`]: the innovation gate that leaves out implausible observations;
//! - [`fusion`]: the fusion protocols (average consensus, exact sums,
//!   random exchange, KL fusion) over a shared round engine;
//! - [`actor`]: the CF/DPF node's state machine, tying them together;
//! - [`diffusion_node`]: the random-exchange paper's node, one filter and a Gaussian to
//!   exchange or fuse;
//! - [`registry`]: the fusion protocols and sensor managers a scenario can
//!   name, the built-in ones and those a program registers;
//! - [`location`] and [`locator`]: a static target's locator, its
//!   evidence over shared grids and its node;
//! - [`mac_centre`]: a fusion centre that hears its sensors through a
//!   multiple-access channel and designs who transmits in which slot;
//! - `build`: the node a scenario describes, of whatever kind, as an
//!   [`AnyNode`]; `wiring` holds what every kind reads, publishes and
//!   sends alike.

pub mod actor;
mod build;
mod censoring;
pub mod centralized;
pub mod collector;
pub mod diffusion;
pub mod diffusion_node;
mod error;
pub mod estimator;
pub mod filter;
pub mod fusion;
pub mod gate;
pub mod location;
pub mod locator;
pub mod mac_centre;
pub mod registry;
pub mod sensing;
pub mod sensor_manager;
mod wiring;
mod work;

#[cfg(test)]
mod harness;

pub use actor::NodeActor;
pub use centralized::CentralizedReference;
pub use diffusion_node::DiffusionNode;
pub use error::NodeError;
pub use estimator::{
    Contribution, FusionFilter, LocalFilter, Observation, ObservedValue, SensingModel,
};
pub use locator::LocatorNode;
pub use mac_centre::MacCentre;
pub use build::{processing_node, AnyNode, Node, Start};
pub use work::Work;

pub use fusion_graph::actor::{Actor, Outgoing};
