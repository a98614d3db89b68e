//! The processing nodes of cqnet, each a state machine with no I/O: the
//! consensus-based distributed particle filter (CF/DPF) with the
//! distributed CQ/dPCRLB, the random-exchange paper's trackers, a static
//! target's locator and a fusion centre behind a multiple-access channel;
//! and the centralized reference they are compared with.
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
//! - [`location`]: a static target's evidence over shared grids;
//! - [`nodes`]: the processing nodes, by kind: what every kind shares (the
//!   node core and its report), the CF/DPF node tying the filters, bounds
//!   and protocols together, the random-exchange paper's trackers, the
//!   locator, and the fusion centre behind a multiple-access channel;
//! - [`parts`]: what each fusion protocol, node kind and sensor manager a
//!   scenario can name builds, cqnet's own and a program's, in one list.

mod censoring;
pub mod centralized;
pub mod collector;
pub mod diffusion;
mod error;
pub mod estimator;
pub mod filter;
pub mod fusion;
pub mod gate;
pub mod location;
pub mod nodes;
pub mod parts;
pub mod resampler;
pub mod sensing;
pub mod sensor_manager;
mod work;

#[cfg(test)]
mod harness;

pub use centralized::CentralizedReference;
pub use error::NodeError;
pub use estimator::{
    Contribution, FusionFilter, LocalFilter, Observation, ObservedValue, SensingModel,
};
pub use nodes::cfdpf::CfDpfNode;
pub use nodes::locator::LocatorNode;
pub use nodes::mac_centre::MacCentre;
pub use nodes::trackers::TrackerNode;
pub use nodes::{processing_node, AnyNode, Node, NodeKind, ProcessingNode, Start};
pub use work::Work;

pub use fusion_graph::actor::{Actor, Outgoing};
