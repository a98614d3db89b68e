//! The kind bytes protocols claim for payloads of their own (see
//! [`crate::payloads`]): which are taken, by what name, with what size, and
//! the protocol's own check of a body. Each kind is set once and read
//! without a lock, since every received message of such a kind asks.

use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

use crate::WireError;

/// The kind bytes left to protocols' own payloads.
pub const PROTOCOL_KINDS: std::ops::RangeInclusive<u8> = 128..=254;

/// A kind byte claimed by a protocol's payload (one of [`PROTOCOL_KINDS`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct ProtocolKind(u8);

impl ProtocolKind {
    pub fn code(self) -> u8 {
        self.0
    }

    /// The kind for `code` if a payload is registered under it.
    pub fn registered(code: u8) -> Option<Self> {
        slot(code)?.get().map(|_| Self(code))
    }

    /// The registered payload's name.
    pub fn name(self) -> &'static str {
        entry(self).name
    }

    /// The bytes of each message of the kind that carry the bound's
    /// information (`ProtocolPayload::BOUND_BYTES`).
    pub fn bound_bytes(self) -> usize {
        entry(self).bound_bytes
    }

    /// The registered payload's body size in bytes.
    pub fn body_len(self) -> usize {
        entry(self).len
    }
}

/// A protocol payload as it travels: its kind and its encoded body.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProtocolBody {
    pub kind: ProtocolKind,
    pub bytes: Vec<u8>,
}

/// Why a payload could not be registered.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RegisterError {
    #[error("payload {name:?}: kind {kind} is outside {}..={}, the kinds left to protocols", PROTOCOL_KINDS.start(), PROTOCOL_KINDS.end())]
    KindOutOfRange { name: &'static str, kind: u8 },
    #[error("payload {name:?}: kind {kind} is already {taken:?}'s")]
    KindTaken {
        name: &'static str,
        kind: u8,
        taken: &'static str,
    },
    #[error("payload {name:?}: the name is kind {kind}'s already")]
    NameTaken { name: &'static str, kind: u8 },
    #[error("payload {name:?}: {len} bytes do not fit in a message")]
    TooLong { name: &'static str, len: usize },
    #[error("payload {name:?}: {bound} bytes of the bound's information in a body of {len}")]
    BoundBytes {
        name: &'static str,
        bound: usize,
        len: usize,
    },
    #[error(
        "payload {name:?}: a name is lowercase letters, digits and '_', and not a built-in kind's"
    )]
    BadName { name: &'static str },
}

/// Claims `kind` for a payload called `name` of `len` bytes, `bound_bytes`
/// of them the bound's information, whose bodies `check` accepts. Claiming
/// it again with the same name and size is harmless; with another, an
/// error.
pub fn claim(
    kind: u8,
    name: &'static str,
    len: usize,
    bound_bytes: usize,
    check: fn(&[u8]) -> Result<(), WireError>,
) -> Result<ProtocolKind, RegisterError> {
    let slot = slot(kind).ok_or(RegisterError::KindOutOfRange { name, kind })?;
    // The name is checked before the kind is claimed: a refused payload
    // must leave its kind byte free.
    if let Some(other) = PROTOCOL_KINDS
        .filter(|&k| k != kind)
        .filter_map(ProtocolKind::registered)
        .find(|k| k.name() == name)
    {
        return Err(RegisterError::NameTaken {
            name,
            kind: other.0,
        });
    }
    let entry = slot.get_or_init(|| Entry {
        name,
        len,
        bound_bytes,
        check,
    });
    if entry.name != name || entry.len != len {
        return Err(RegisterError::KindTaken {
            name,
            kind,
            taken: entry.name,
        });
    }
    Ok(ProtocolKind(kind))
}

/// Checks a received body of a claimed kind: its length, then the
/// protocol's own decoding.
pub fn check_body(kind: ProtocolKind, body: &[u8]) -> Result<(), WireError> {
    let entry = entry(kind);
    if body.len() != entry.len {
        return Err(WireError::Length {
            expected: entry.len,
            got: body.len(),
        });
    }
    (entry.check)(body)
}

/// The longest body of the kinds registered so far: the consensus and pair
/// channels make room for it (`transport::limits`).
pub fn longest_body() -> usize {
    REGISTERED
        .iter()
        .filter_map(OnceLock::get)
        .map(|e| e.len)
        .max()
        .unwrap_or(0)
}

struct Entry {
    name: &'static str,
    len: usize,
    bound_bytes: usize,
    /// The protocol's own decoding, its value dropped.
    check: fn(&[u8]) -> Result<(), WireError>,
}

const SLOTS: usize = 127;

/// One slot per kind byte of [`PROTOCOL_KINDS`], set once: reading a
/// registered kind costs no lock on the receive path.
static REGISTERED: [OnceLock<Entry>; SLOTS] = [const { OnceLock::new() }; SLOTS];

fn slot(code: u8) -> Option<&'static OnceLock<Entry>> {
    PROTOCOL_KINDS
        .contains(&code)
        .then(|| &REGISTERED[(code - PROTOCOL_KINDS.start()) as usize])
}

fn entry(kind: ProtocolKind) -> &'static Entry {
    slot(kind.0)
        .and_then(OnceLock::get)
        .expect("a ProtocolKind exists only for a registered payload")
}
