//! Payloads that protocols declare for themselves, outside this crate.
//!
//! A protocol of one's own needs messages of its own, counted per link and
//! kind like every other. Rather than a variant of [`Payload`] for each,
//! a protocol declares its payload type ([`ProtocolPayload`]: a name, a
//! fixed size, an encoding) and the program lists it among its parts. The
//! program gives out the kind bytes, in the order its payloads are listed,
//! from [`PROTOCOL_KINDS`]: nobody picks one by hand, so two libraries'
//! payloads cannot collide, and every process of a run, being the same
//! program, gives out the same bytes.
//!
//! The kinds a program gave out travel as a value, [`Payloads`], inside
//! the [`WireFormat`](crate::WireFormat) every codec call is given: there
//! is no table in the process to register with, so a test can hold two
//! programs' payloads at once. On the wire a protocol's message is an
//! ordinary one: the header with its kind byte, then its body. Decoding
//! checks the body's length and lets the protocol's own `decode` refuse
//! what it would not accept, so that a malformed message is counted and
//! dropped at the transport, like any other, and never reaches the
//! protocol.

use std::any::TypeId;
use std::fmt;
use std::marker::PhantomData;

use crate::WireError;
use crate::{Message, MessageKind, Payload, HEADER_BYTES, MAX_MESSAGE_BYTES};

/// The kind bytes left to protocols' own payloads.
pub const PROTOCOL_KINDS: std::ops::RangeInclusive<u8> = 128..=254;

/// A protocol's message body: a fixed size, its own encoding, and a
/// decoding that refuses whatever the protocol would not accept.
pub trait ProtocolPayload: Sized + 'static {
    /// The kind's name in `links.csv` and the summary: lowercase letters,
    /// digits and `_`, unique in the program.
    const NAME: &'static str;
    /// The body's size in bytes; every message of the kind has it.
    const LEN: usize;
    /// How many of those bytes carry what the bound is computed from (the
    /// CQ/dPCRLB's ΔL, say): a run's summary counts them, in every message
    /// of the kind sent, as the bound's traffic, as it counts the built-in
    /// consensus messages' 80. None, unless the protocol says.
    const BOUND_BYTES: usize = 0;

    /// Appends exactly [`LEN`](Self::LEN) bytes.
    fn encode(&self, out: &mut Vec<u8>);

    /// The value from exactly [`LEN`](Self::LEN) bytes, or why not.
    fn decode(body: &[u8]) -> Result<Self, WireError>;
}

/// Appends `numbers` as little-endian f64s: the encoding most payloads
/// need.
pub fn put_numbers<'a>(numbers: impl IntoIterator<Item = &'a f64>, out: &mut Vec<u8>) {
    for x in numbers {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// `N` little-endian f64s from `body` (exactly `8 N` bytes, which the
/// codec has checked against the payload's `LEN`), refused unless every
/// one is finite.
pub fn finite_numbers<const N: usize>(body: &[u8]) -> Result<[f64; N], WireError> {
    if body.len() != 8 * N {
        return Err(WireError::Length {
            expected: 8 * N,
            got: body.len(),
        });
    }
    let mut numbers = [0.0; N];
    for (x, bytes) in numbers.iter_mut().zip(body.chunks_exact(8)) {
        *x = f64::from_le_bytes(bytes.try_into().expect("8 bytes"));
        if !x.is_finite() {
            return Err(WireError::NonFinite);
        }
    }
    Ok(numbers)
}

/// One payload a program declared: its kind byte, name, sizes and check.
#[derive(Clone)]
pub struct PayloadEntry {
    code: u8,
    name: &'static str,
    len: usize,
    bound_bytes: usize,
    type_id: TypeId,
    /// The protocol's own decoding, its value dropped.
    check: fn(&[u8]) -> Result<(), WireError>,
}

impl PayloadEntry {
    /// `P`'s entry under the next kind byte after those of `declared`, or
    /// why `P` cannot be declared beside them.
    pub fn next<P: ProtocolPayload>(declared: &[PayloadEntry]) -> Result<Self, RegisterError> {
        let name = P::NAME;
        let well_formed = !name.is_empty()
            && name
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
        let built_in = (0..*PROTOCOL_KINDS.start())
            .filter_map(MessageKind::from_u8)
            .chain([MessageKind::Malformed])
            .any(|k| k.name() == name);
        if !well_formed || built_in {
            return Err(RegisterError::BadName { name });
        }
        if let Some(other) = declared.iter().find(|e| e.name == name) {
            return Err(RegisterError::NameTaken {
                name,
                kind: other.code,
            });
        }
        if declared.iter().any(|e| e.type_id == TypeId::of::<P>()) {
            return Err(RegisterError::Twice { name });
        }
        if HEADER_BYTES + P::LEN > MAX_MESSAGE_BYTES {
            return Err(RegisterError::TooLong { name, len: P::LEN });
        }
        if P::BOUND_BYTES > P::LEN {
            return Err(RegisterError::BoundBytes {
                name,
                bound: P::BOUND_BYTES,
                len: P::LEN,
            });
        }
        let code = PROTOCOL_KINDS
            .clone()
            .nth(declared.len())
            .ok_or(RegisterError::Full { name })?;
        Ok(Self {
            code,
            name,
            len: P::LEN,
            bound_bytes: P::BOUND_BYTES,
            type_id: TypeId::of::<P>(),
            check: |body| P::decode(body).map(drop),
        })
    }
}

/// The payloads a program declared, as the codec and the counts read
/// them. Copied freely: the entries live as long as the program.
#[derive(Clone, Copy)]
pub struct Payloads(&'static [PayloadEntry]);

impl Payloads {
    /// A program with no payloads of its own (cqnet's built-in parts).
    pub const NONE: Self = Self(&[]);

    /// The payloads of `entries`, kept for the rest of the program (a
    /// program declares its parts once; a test that builds several keeps
    /// a few hundred bytes each).
    pub fn new(entries: Vec<PayloadEntry>) -> Self {
        if entries.is_empty() {
            return Self::NONE;
        }
        Self(Box::leak(entries.into_boxed_slice()))
    }

    /// The kind under byte `code`, if a payload has it.
    pub fn kind(self, code: u8) -> Option<ProtocolKind> {
        let at = code.checked_sub(*PROTOCOL_KINDS.start())? as usize;
        self.0.get(at).map(ProtocolKind)
    }

    /// `P`'s kind, if the program declared it.
    pub fn of<P: ProtocolPayload>(self) -> Option<PayloadKind<P>> {
        self.0
            .iter()
            .find(|e| e.type_id == TypeId::of::<P>())
            .map(|e| PayloadKind {
                kind: ProtocolKind(e),
                payload: PhantomData,
            })
    }

    /// Every declared kind, in the order of their bytes.
    pub fn kinds(self) -> impl Iterator<Item = ProtocolKind> {
        self.0.iter().map(ProtocolKind)
    }

    /// The longest declared body: the consensus and pair channels make
    /// room for it (`transport::limits`).
    pub fn longest_body(self) -> usize {
        self.0.iter().map(|e| e.len).max().unwrap_or(0)
    }
}

impl PartialEq for Payloads {
    fn eq(&self, other: &Self) -> bool {
        self.0.len() == other.0.len()
            && self
                .0
                .iter()
                .zip(other.0)
                .all(|(a, b)| a.name == b.name && a.len == b.len)
    }
}

impl fmt::Debug for Payloads {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.kinds()).finish()
    }
}

impl Default for Payloads {
    fn default() -> Self {
        Self::NONE
    }
}

/// A kind byte a program gave a payload (one of [`PROTOCOL_KINDS`]).
#[derive(Clone, Copy)]
pub struct ProtocolKind(&'static PayloadEntry);

impl ProtocolKind {
    pub fn code(self) -> u8 {
        self.0.code
    }

    /// The payload's name.
    pub fn name(self) -> &'static str {
        self.0.name
    }

    /// The bytes of each message of the kind that carry the bound's
    /// information (`ProtocolPayload::BOUND_BYTES`).
    pub fn bound_bytes(self) -> usize {
        self.0.bound_bytes
    }

    /// The payload's body size in bytes.
    pub fn body_len(self) -> usize {
        self.0.len
    }

    /// Checks a received body: its length, then the protocol's own decoding.
    pub(crate) fn check_body(self, body: &[u8]) -> Result<(), WireError> {
        if body.len() != self.0.len {
            return Err(WireError::Length {
                expected: self.0.len,
                got: body.len(),
            });
        }
        (self.0.check)(body)
    }
}

impl PartialEq for ProtocolKind {
    fn eq(&self, other: &Self) -> bool {
        self.code() == other.code()
    }
}

impl Eq for ProtocolKind {}

impl PartialOrd for ProtocolKind {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for ProtocolKind {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.code().cmp(&other.code())
    }
}

impl std::hash::Hash for ProtocolKind {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.code().hash(state)
    }
}

impl fmt::Debug for ProtocolKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}({})", self.name(), self.code())
    }
}

/// `P`'s kind in the program that declared it: how a protocol puts a `P`
/// in a message and reads one back.
pub struct PayloadKind<P> {
    kind: ProtocolKind,
    payload: PhantomData<fn() -> P>,
}

impl<P> Clone for PayloadKind<P> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<P> Copy for PayloadKind<P> {}

impl<P> fmt::Debug for PayloadKind<P> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.kind.fmt(f)
    }
}

impl<P: ProtocolPayload> PayloadKind<P> {
    /// The message kind `P`'s messages carry.
    pub fn kind(self) -> MessageKind {
        MessageKind::Protocol(self.kind)
    }

    /// `value` as the payload of a [`Message`].
    pub fn payload(self, value: &P) -> Payload {
        let mut bytes = Vec::with_capacity(P::LEN);
        value.encode(&mut bytes);
        debug_assert_eq!(bytes.len(), P::LEN, "{} encodes its declared size", P::NAME);
        Payload::Protocol(ProtocolBody {
            kind: self.kind,
            bytes,
        })
    }

    /// The `P` in `payload`, if it carries one; `None` for any other kind.
    pub fn read(self, payload: &Payload) -> Option<P> {
        match payload {
            Payload::Protocol(body) if body.kind == self.kind => P::decode(&body.bytes).ok(),
            _ => None,
        }
    }

    /// The `P` in `message`, if it carries one.
    pub fn read_message(self, message: &Message) -> Option<P> {
        self.read(&message.payload)
    }
}

/// A protocol payload as it travels: its kind and its encoded body.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProtocolBody {
    pub kind: ProtocolKind,
    pub bytes: Vec<u8>,
}

/// Why a payload could not be declared.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RegisterError {
    #[error("payload {name:?}: the name is kind {kind}'s already")]
    NameTaken { name: &'static str, kind: u8 },
    #[error("payload {name:?} is declared twice")]
    Twice { name: &'static str },
    #[error("payload {name:?}: the {} kinds left to protocols are all given out", PROTOCOL_KINDS.len())]
    Full { name: &'static str },
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ActorId;
    use crate::{encoded_len, WireFormat};

    /// A payload of the tests' own: one finite f64 and a flag byte.
    #[derive(Debug, Clone, Copy, PartialEq)]
    struct Probe {
        value: f64,
        flag: bool,
    }

    impl ProtocolPayload for Probe {
        const NAME: &'static str = "probe";
        const LEN: usize = 9;

        fn encode(&self, out: &mut Vec<u8>) {
            out.extend_from_slice(&self.value.to_le_bytes());
            out.push(u8::from(self.flag));
        }

        fn decode(body: &[u8]) -> Result<Self, WireError> {
            let value = f64::from_le_bytes(body[..8].try_into().map_err(|_| WireError::Truncated)?);
            if !value.is_finite() {
                return Err(WireError::NonFinite);
            }
            let flag = match body[8] {
                0 => false,
                1 => true,
                got => return Err(WireError::Flag { got }),
            };
            Ok(Self { value, flag })
        }
    }

    /// A payload of `LEN` zero bytes, `BOUND` of them the bound's, named `name`.
    macro_rules! blank {
        ($ty:ident, $name:literal, $len:literal, $bound:literal) => {
            struct $ty;
            impl ProtocolPayload for $ty {
                const NAME: &'static str = $name;
                const LEN: usize = $len;
                const BOUND_BYTES: usize = $bound;
                fn encode(&self, out: &mut Vec<u8>) {
                    out.extend_from_slice(&[0; $len]);
                }
                fn decode(_: &[u8]) -> Result<Self, WireError> {
                    Ok($ty)
                }
            }
        };
    }

    fn format(payloads: Payloads) -> WireFormat {
        WireFormat {
            cell_bytes: 1,
            activation_bytes: 4,
            payloads,
        }
    }

    /// Declares a payload beside those before it.
    type Declare = fn(&[PayloadEntry]) -> Result<PayloadEntry, RegisterError>;

    fn declare(list: &[Declare]) -> Payloads {
        let mut entries = Vec::new();
        for next in list {
            let entry = next(&entries).unwrap();
            entries.push(entry);
        }
        Payloads::new(entries)
    }

    #[test]
    fn a_declared_payload_round_trips_with_its_declared_size_and_name() {
        blank!(First, "first", 2, 0);
        let payloads = declare(&[PayloadEntry::next::<First>, PayloadEntry::next::<Probe>]);
        let kind = payloads.of::<Probe>().unwrap();
        assert_eq!(kind.kind().code(), 129, "kinds are given out in order");
        let probe = Probe {
            value: -2.5,
            flag: true,
        };
        let m = Message::new(ActorId::Node(3), 7, 1, kind.payload(&probe));
        assert_eq!(m.header.kind, kind.kind());
        assert_eq!(m.header.kind.name(), "probe");
        let format = format(payloads);
        let bytes = m.to_bytes(&format);
        assert_eq!(Some(bytes.len()), encoded_len(m.header.kind, &format));
        let back = Message::decode(&bytes, &format).unwrap();
        assert_eq!(kind.read_message(&back), Some(probe));
        assert_eq!(
            MessageKind::from_code(129, payloads),
            Some(MessageKind::Protocol(payloads.kind(129).unwrap()))
        );
        assert_eq!(
            Message::decode(&bytes, &self::format(Payloads::NONE)),
            Err(WireError::UnknownKind { kind: 129 }),
            "a program that did not declare it cannot read it"
        );
    }

    #[test]
    fn two_programs_payloads_live_side_by_side() {
        blank!(Other, "other", 3, 0);
        let one = declare(&[PayloadEntry::next::<Probe>]);
        let two = declare(&[PayloadEntry::next::<Other>]);
        assert_eq!(one.kind(128).unwrap().name(), "probe");
        assert_eq!(two.kind(128).unwrap().name(), "other");
        assert!(two.of::<Probe>().is_none());
    }

    #[test]
    fn a_body_the_protocol_refuses_is_a_wire_error() {
        let payloads = declare(&[PayloadEntry::next::<Probe>]);
        let format = format(payloads);
        let kind = payloads.of::<Probe>().unwrap();
        let good = Message::new(
            ActorId::Node(1),
            1,
            0,
            kind.payload(&Probe {
                value: 1.0,
                flag: false,
            }),
        )
        .to_bytes(&format);
        let mut flag = good.clone();
        *flag.last_mut().unwrap() = 7;
        crate::seal(&mut flag);
        assert_eq!(
            Message::decode(&flag, &format),
            Err(WireError::Flag { got: 7 })
        );
        let mut short = good.clone();
        short.pop();
        crate::seal(&mut short);
        assert!(matches!(
            Message::decode(&short, &format),
            Err(WireError::Length { .. })
        ));
    }

    /// A payload's declared bound bytes are read back from its kind, and
    /// more of them than its body has is refused.
    #[test]
    fn the_bound_bytes_a_payload_declares_are_its_kinds() {
        blank!(Bounded, "bounded", 16, 8);
        blank!(Overbound, "overbound", 4, 8);
        let payloads = declare(&[PayloadEntry::next::<Bounded>, PayloadEntry::next::<Probe>]);
        assert_eq!(payloads.kind(128).unwrap().bound_bytes(), 8);
        assert_eq!(payloads.kind(129).unwrap().bound_bytes(), 0);
        assert!(matches!(
            PayloadEntry::next::<Overbound>(&[]),
            Err(RegisterError::BoundBytes {
                bound: 8,
                len: 4,
                ..
            })
        ));
    }

    #[test]
    fn names_are_checked_and_not_shared() {
        blank!(Twin, "probe", 1, 0);
        blank!(Builtin, "consensus", 1, 0);
        blank!(Shouting, "Loud", 1, 0);
        let mut entries = vec![PayloadEntry::next::<Probe>(&[]).unwrap()];
        assert!(matches!(
            PayloadEntry::next::<Twin>(&entries),
            Err(RegisterError::NameTaken { kind: 128, .. })
        ));
        assert!(matches!(
            PayloadEntry::next::<Probe>(&entries),
            Err(RegisterError::NameTaken { .. }) | Err(RegisterError::Twice { .. })
        ));
        assert!(matches!(
            PayloadEntry::next::<Builtin>(&entries),
            Err(RegisterError::BadName { .. })
        ));
        assert!(matches!(
            PayloadEntry::next::<Shouting>(&entries),
            Err(RegisterError::BadName { .. })
        ));
        entries.clear();
        assert_eq!(Payloads::new(entries).kinds().count(), 0);
    }

    #[test]
    fn numbers_round_trip_and_a_bad_one_is_refused() {
        let mut out = Vec::new();
        put_numbers(&[1.5, -2.0, 0.0], &mut out);
        assert_eq!(finite_numbers::<3>(&out), Ok([1.5, -2.0, 0.0]));
        assert!(matches!(
            finite_numbers::<2>(&out),
            Err(WireError::Length {
                expected: 16,
                got: 24
            })
        ));
        out[8..16].copy_from_slice(&f64::NAN.to_le_bytes());
        assert_eq!(finite_numbers::<3>(&out), Err(WireError::NonFinite));
    }
}
