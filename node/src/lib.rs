//! The processing-node actor of cqnet: the consensus-based distributed
//! particle filter (CF/DPF) with the distributed CQ/dPCRLB, as a state
//! machine with no I/O; and the centralized reference it is compared with.

pub mod actor;
pub mod centralized;
pub mod estimator;
pub mod filter;

pub use actor::{network_prior, sensing_model, wire_format, NodeActor, Outgoing};
pub use centralized::CentralizedReference;
pub use estimator::{
    Contribution, FusionFilter, LocalFilter, Observation, ObservedValue, SensingModel,
};
