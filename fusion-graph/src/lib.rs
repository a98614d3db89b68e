//! The network's vocabulary, with no estimation and no I/O in it: scenarios
//! and the models they mean, the topology and its consensus weights, the
//! channels of a run, link faults and the rule they add up to, which host
//! runs which actor, and how an actor looks at the world.
//!
//! The wire format is the member crate `wire` (its actor id and message
//! types re-exported here), and the transports that move it are the member
//! crate `transport`, which this crate does not know.

pub mod actor;
pub mod channel;
pub mod check;
pub mod faults;
pub mod hosts;
pub mod models;
pub mod params;
pub mod scenario;
pub mod shaper;
pub mod topology;
pub mod vocabulary;
pub mod world;

pub use actor::{Actor, Outgoing, Wiring};
pub use channel::{Channel, RunId};
pub use scenario::Scenario;
pub use shaper::{LinkRule, LinkShaper};
pub use topology::{MetropolisWeights, Mixing, SpanningTree, Topology};
pub use wire::{ActorId, BitMask, Message, MessageKind, Payload, WireError, WireFormat};

pub use models::{link_fault_seed, stream_rng, stream_seed, Models, Stream};

/// A scenario that cannot be used, and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioError {
    #[error("{file}: cannot read: {message}")]
    Read { file: String, message: String },
    #[error("{file}: {message}")]
    Parse { file: String, message: String },
    #[error("{file}: `{key}`: expected {expected}, got {got}")]
    Invalid {
        file: String,
        key: String,
        expected: String,
        got: String,
    },
    #[error("--set {assignment}: {message}")]
    Override { assignment: String, message: String },
}

impl ScenarioError {
    /// The key the error is about, when it is about one: `filter.particles`
    /// for a bad value of it, a failed `--set filter.particles=…`, or a
    /// value of the wrong type there.
    pub fn key(&self) -> Option<&str> {
        match self {
            Self::Invalid { key, .. } => Some(key),
            Self::Override { assignment, .. } => Some(
                assignment
                    .split_once('=')
                    .map_or(assignment.as_str(), |(k, _)| k)
                    .trim(),
            ),
            // `from_toml` starts the message with the failing value's path.
            Self::Parse { message, .. } => message
                .strip_prefix('`')
                .and_then(|m| m.split_once('`'))
                .map(|(key, _)| key)
                .filter(|key| !key.is_empty()),
            Self::Read { .. } => None,
        }
    }
}
