//! Payloads that protocols declare for themselves, outside this crate.
//!
//! A protocol of one's own needs messages of its own, counted per link and
//! kind like every other. Rather than a variant of [`Payload`] for each,
//! a protocol declares its payload type ([`ProtocolPayload`]: a kind byte,
//! a name, a fixed size, an encoding) and registers it once at start-up with
//! [`register`]. On the wire it is an ordinary message: the header with the
//! protocol's kind byte, then its body. Decoding checks the body's length
//! and lets the protocol's own `decode` refuse what it would not accept, so
//! that a malformed message is counted and dropped at the transport, like
//! any other, and never reaches the protocol.
//!
//! Every process of a run must register the same payloads (the launcher
//! too, to name them in `links.csv`): they are the same program, so
//! registering in `main` before anything else does it.

pub use crate::protocol_kinds::{ProtocolBody, ProtocolKind, RegisterError, PROTOCOL_KINDS};

use crate::protocol_kinds;
use crate::WireError;
use crate::{Message, MessageKind, Payload, HEADER_BYTES, MAX_MESSAGE_BYTES};

/// A protocol's message body: a fixed size, its own encoding, and a
/// decoding that refuses whatever the protocol would not accept.
pub trait ProtocolPayload: Sized {
    /// The kind byte on the wire, one of [`PROTOCOL_KINDS`], unique in the
    /// program.
    const KIND: u8;
    /// The kind's name in `links.csv` and the summary: lowercase, no commas.
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

    /// The payload to put in a [`Message`].
    fn to_payload(&self) -> Payload {
        let mut bytes = Vec::with_capacity(Self::LEN);
        self.encode(&mut bytes);
        debug_assert_eq!(
            bytes.len(),
            Self::LEN,
            "{} encodes its declared size",
            Self::NAME
        );
        let kind = ProtocolKind::registered(Self::KIND)
            .unwrap_or_else(|| panic!("payload {:?} is sent before it is registered", Self::NAME));
        Payload::Protocol(ProtocolBody { kind, bytes })
    }

    /// This payload, if `payload` is one; `None` for any other kind.
    fn from_payload(payload: &Payload) -> Option<Self> {
        match payload {
            Payload::Protocol(body) if body.kind.code() == Self::KIND => {
                Self::decode(&body.bytes).ok()
            }
            _ => None,
        }
    }

    /// This payload, if `message` carries one; `None` for any other kind.
    fn from_message(message: &Message) -> Option<Self> {
        Self::from_payload(&message.payload)
    }
}

/// Registers `P`, so that messages of its kind are decoded, sized and
/// counted. Registering the same payload again is harmless.
pub fn register<P: ProtocolPayload>() -> Result<ProtocolKind, RegisterError> {
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
    protocol_kinds::claim(P::KIND, name, P::LEN, P::BOUND_BYTES, |body| {
        P::decode(body).map(drop)
    })
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
        const KIND: u8 = 200;
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

    const FORMAT: WireFormat = WireFormat {
        cell_bytes: 1,
        activation_bytes: 4,
    };

    #[test]
    fn a_registered_payload_round_trips_with_its_declared_size_and_name() {
        let kind = register::<Probe>().unwrap();
        assert_eq!(
            register::<Probe>().unwrap(),
            kind,
            "registering twice is harmless"
        );
        let probe = Probe {
            value: -2.5,
            flag: true,
        };
        let m = Message::new(ActorId::Node(3), 7, 1, probe.to_payload());
        assert_eq!(m.header.kind, MessageKind::Protocol(kind));
        assert_eq!(m.header.kind.name(), "probe");
        let bytes = m.to_bytes(&FORMAT);
        assert_eq!(Some(bytes.len()), encoded_len(m.header.kind, &FORMAT));
        let back = Message::decode(&bytes, &FORMAT).unwrap();
        assert_eq!(Probe::from_message(&back), Some(probe));
        assert_eq!(MessageKind::from_u8(200), Some(MessageKind::Protocol(kind)));
    }

    #[test]
    fn a_body_the_protocol_refuses_is_a_wire_error() {
        register::<Probe>().unwrap();
        let good = Message::new(
            ActorId::Node(1),
            1,
            0,
            Probe {
                value: 1.0,
                flag: false,
            }
            .to_payload(),
        )
        .to_bytes(&FORMAT);
        let mut flag = good.clone();
        *flag.last_mut().unwrap() = 7;
        crate::seal(&mut flag);
        assert_eq!(
            Message::decode(&flag, &FORMAT),
            Err(WireError::Flag { got: 7 })
        );
        let mut short = good.clone();
        short.pop();
        crate::seal(&mut short);
        assert!(matches!(
            Message::decode(&short, &FORMAT),
            Err(WireError::Length { .. })
        ));
    }

    /// A payload's declared bound bytes are read back from its kind, and
    /// more of them than its body has is refused.
    #[test]
    fn the_bound_bytes_a_payload_declares_are_its_kinds() {
        struct Bounded;
        impl ProtocolPayload for Bounded {
            const KIND: u8 = 230;
            const NAME: &'static str = "bounded";
            const LEN: usize = 16;
            const BOUND_BYTES: usize = 8;
            fn encode(&self, out: &mut Vec<u8>) {
                out.extend_from_slice(&[0; 16]);
            }
            fn decode(_: &[u8]) -> Result<Self, WireError> {
                Ok(Bounded)
            }
        }
        struct Overbound;
        impl ProtocolPayload for Overbound {
            const KIND: u8 = 231;
            const NAME: &'static str = "overbound";
            const LEN: usize = 4;
            const BOUND_BYTES: usize = 8;
            fn encode(&self, out: &mut Vec<u8>) {
                out.extend_from_slice(&[0; 4]);
            }
            fn decode(_: &[u8]) -> Result<Self, WireError> {
                Ok(Overbound)
            }
        }
        assert_eq!(register::<Bounded>().unwrap().bound_bytes(), 8);
        assert_eq!(register::<Probe>().unwrap().bound_bytes(), 0);
        assert!(matches!(
            register::<Overbound>(),
            Err(RegisterError::BoundBytes {
                bound: 8,
                len: 4,
                ..
            })
        ));
        assert!(
            ProtocolKind::registered(231).is_none(),
            "its kind stays free"
        );
    }

    #[test]
    fn an_unregistered_kind_is_unknown_and_clashes_are_refused() {
        assert_eq!(MessageKind::from_u8(201), None);
        struct Clash;
        impl ProtocolPayload for Clash {
            const KIND: u8 = 200;
            const NAME: &'static str = "clash";
            const LEN: usize = 1;
            fn encode(&self, out: &mut Vec<u8>) {
                out.push(0)
            }
            fn decode(_: &[u8]) -> Result<Self, WireError> {
                Ok(Clash)
            }
        }
        register::<Probe>().unwrap();
        assert!(matches!(
            register::<Clash>(),
            Err(RegisterError::KindTaken { taken: "probe", .. })
        ));
        struct Low;
        impl ProtocolPayload for Low {
            const KIND: u8 = 5;
            const NAME: &'static str = "low";
            const LEN: usize = 1;
            fn encode(&self, out: &mut Vec<u8>) {
                out.push(0)
            }
            fn decode(_: &[u8]) -> Result<Self, WireError> {
                Ok(Low)
            }
        }
        assert!(matches!(
            register::<Low>(),
            Err(RegisterError::KindOutOfRange { kind: 5, .. })
        ));
        /// The probe's name under another kind: refused, and the kind
        /// stays free.
        struct Twin;
        impl ProtocolPayload for Twin {
            const KIND: u8 = 202;
            const NAME: &'static str = "probe";
            const LEN: usize = 1;
            fn encode(&self, out: &mut Vec<u8>) {
                out.push(0)
            }
            fn decode(_: &[u8]) -> Result<Self, WireError> {
                Ok(Twin)
            }
        }
        assert!(matches!(
            register::<Twin>(),
            Err(RegisterError::NameTaken { kind: 200, .. })
        ));
        assert_eq!(ProtocolKind::registered(202), None);
    }
}
