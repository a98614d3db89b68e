//! The network of cqnet, with no estimation in it: scenarios and the models
//! they mean, topology, consensus weights, wire messages, transports, link
//! faults and byte accounting.

pub mod accounting;
pub mod actor;
pub mod channel;
pub mod check;
pub mod counters;
pub mod faults;
pub mod hosts;
pub mod layout;
pub mod ledger;
pub mod models;
pub mod payloads;
pub mod protocol_kinds;
pub mod registered;
pub mod scenario;
pub mod shaper;
pub mod topology;
pub mod transport;
pub mod wire;
pub mod world_memory;

pub use accounting::{Accounting, Counters};
pub use actor::ActorId;
pub use scenario::Scenario;
pub use shaper::{LinkRule, LinkShaper};
pub use topology::{MetropolisWeights, SpanningTree, Topology};
pub use transport::{Channel, Transport};

pub use models::{link_fault_seed, stream_rng, stream_seed, Models, Stream};
pub use wire::{BitMask, Message, MessageKind, Payload, WireFormat};

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

/// A message that could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    #[error("message too long ({len} bytes)")]
    TooLong { len: usize },
    #[error("message truncated")]
    Truncated,
    #[error("wire format version {got}, expected {expected}", expected = wire::WIRE_VERSION)]
    Version { got: u8 },
    #[error("checksum {carried:#06x} does not match the message's {computed:#06x}: corrupted in transit")]
    Checksum { carried: u16, computed: u16 },
    #[error("unknown message kind {kind}")]
    UnknownKind { kind: u8 },
    #[error("unknown sender kind {kind}")]
    UnknownSender { kind: u8 },
    #[error("payload has {got} bytes, expected {expected}")]
    Length { expected: usize, got: usize },
    #[error("{extra} bytes after the payload")]
    TrailingBytes { extra: usize },
    #[error("payload carries a non-finite number")]
    NonFinite,
    #[error("a flag byte {got}, expected 0 or 1")]
    Flag { got: u8 },
    #[error(
        "thresholds, slot columns, sensors or pieces out of order, or a column outside its slots"
    )]
    Unordered,
    #[error("a Fisher information with a negative diagonal")]
    NegativeInformation,
}

/// What a transport's backend (iceoryx2, or another) reported.
pub type BackendError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Setting up a transport: the run, its services and this actor's ports.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error("run id `{id}` must be 1-32 characters of a-z, 0-9 and -")]
    BadRunId { id: String },
    #[error("{actor} is not the publisher of channel {channel}")]
    NotPublisher { channel: String, actor: String },
    #[error("setting up {what}")]
    Backend {
        what: String,
        #[source]
        source: BackendError,
    },
}

/// Publishing one message.
#[derive(Debug, thiserror::Error)]
pub enum SendError {
    #[error("{actor} does not publish on channel {channel}")]
    NotPublisher { channel: String, actor: String },
    #[error("publishing on {channel}")]
    Backend {
        channel: String,
        #[source]
        source: BackendError,
    },
}

/// Draining this actor's subscriptions.
#[derive(Debug, thiserror::Error)]
#[error("receiving on {channel}")]
pub struct ReceiveError {
    pub channel: String,
    #[source]
    pub source: BackendError,
}

/// Sleeping until woken.
#[derive(Debug, thiserror::Error)]
#[error("waiting for a wake-up")]
pub struct WaitError {
    #[source]
    pub source: BackendError,
}

/// Any transport operation's error, for callers that do several.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error(transparent)]
    Setup(#[from] SetupError),
    #[error(transparent)]
    Send(#[from] SendError),
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    #[error(transparent)]
    Wait(#[from] WaitError),
}
