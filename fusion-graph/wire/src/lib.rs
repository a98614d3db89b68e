//! cqnet's wire format, below every actor and every transport: who sends
//! ([`ActorId`]), the fixed header, the one table of message kinds, the
//! built-in payloads, the payloads a program declares for its own protocols,
//! and the codec that trusts no byte it decodes.

pub mod actor;
mod message;
pub mod payloads;

pub use actor::ActorId;
pub use message::*;

/// A message that could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    #[error("message too long ({len} bytes)")]
    TooLong { len: usize },
    #[error("message truncated")]
    Truncated,
    #[error("wire format version {got}, expected {expected}", expected = WIRE_VERSION)]
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
