//! Wire messages: a small fixed header and a payload, bincode-encoded with
//! fixed-width little-endian integers so a message's size depends only on its
//! kind (and the scenario), never on its values.
//!
//! Decoding trusts nothing: a wrong version or checksum, an unknown kind or
//! sender, a wrong length or a non-finite number is a typed [`WireError`],
//! and random bytes never panic.
//!
//! The header's CRC-16 covers the whole message: shared memory does not flip
//! bits, but a link between hosts, or the `corrupt` fault, can, and a
//! flipped bit in a cell index or a consensus value would otherwise be
//! believed.

pub mod bodies;
mod codec;
mod crc;
mod examples;
mod kind;

pub use bodies::*;
use codec::{config, put, put_mask};
use crc::crc16;
pub use examples::examples;
pub use kind::MessageKind;

use serde::{Deserialize, Serialize};

use crate::actor::ActorId;
use crate::payloads::{Payloads, ProtocolBody};
use crate::WireError;

/// Bumped whenever the encoding changes.
pub const WIRE_VERSION: u8 = 3;
/// Encoded size of [`Header`].
pub const HEADER_BYTES: usize = 13;
/// Where the checksum sits in the header.
const CHECKSUM_AT: std::ops::Range<usize> = 11..13;
/// Where the step sits in the header: after the version, the kind and the
/// sender's kind and index.
const STEP_AT: std::ops::Range<usize> = 5..9;
/// No message is larger than this; it bounds every allocation in decoding.
pub const MAX_MESSAGE_BYTES: usize = 1024;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
struct WireHeader {
    version: u8,
    kind: u8,
    sender_kind: u8,
    sender_index: u16,
    step: u32,
    round: u16,
    /// CRC-16 of the whole message with these two bytes zero.
    checksum: u16,
}

/// The header every message carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    pub kind: MessageKind,
    pub sender: ActorId,
    pub step: u32,
    pub round: u16,
}
/// What the receiver must know to read a message: the sizes the scenario
/// fixes, and the payloads the program declared for its own protocols.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WireFormat {
    /// `ceil(N_L/8)`.
    pub cell_bytes: usize,
    /// `ceil(max sensors per node / 8)`.
    pub activation_bytes: usize,
    /// The kinds the program gave its protocols' payloads.
    pub payloads: Payloads,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    pub header: Header,
    pub payload: Payload,
}

impl Message {
    pub fn new(sender: ActorId, step: u32, round: u16, payload: Payload) -> Self {
        Self {
            header: Header {
                kind: payload.kind(),
                sender,
                step,
                round,
            },
            payload,
        }
    }

    /// Appends the encoded message to `out`.
    pub fn encode(&self, format: &WireFormat, out: &mut Vec<u8>) {
        let start = out.len();
        self.encode_unsealed(format, out);
        seal(&mut out[start..]);
    }

    fn encode_unsealed(&self, format: &WireFormat, out: &mut Vec<u8>) {
        let (sender_kind, sender_index) = self.header.sender.to_wire();
        let h = WireHeader {
            version: WIRE_VERSION,
            kind: self.header.kind.code(),
            sender_kind,
            sender_index,
            step: self.header.step,
            round: self.header.round,
            checksum: 0,
        };
        put(&h, out);
        match &self.payload {
            Payload::Activate { mask } => put_mask(mask, format, out),
            Payload::ActivateWithFeedback {
                mask,
                estimate,
                covariance,
            } => sensing::encode_feedback(mask, estimate, covariance.as_ref(), format, out),
            Payload::Observation { cell } => {
                out.extend_from_slice(&cell.to_le_bytes()[..format.cell_bytes])
            }
            Payload::RawObservation { value } => put(value, out),
            Payload::ActivateThresholds { mask, thresholds } => {
                sensing::encode_thresholds(mask, thresholds, format, out)
            }
            Payload::Control(c) => put(c, out),
            Payload::Telemetry(t) => put(t, out),
            Payload::Consensus(v) => cfdpf::encode_consensus(v, out),
            Payload::ConsensusAux { s_obs } => put(s_obs, out),
            Payload::StateTransfer(s) => put(s, out),
            Payload::KlConsensus(g) => put(g, out),
            Payload::ExchangeRequest => {}
            Payload::ExchangeReply { accepted } => out.push(u8::from(*accepted)),
            Payload::ExchangePosterior(g) => put(g, out),
            Payload::NeighbourObservation { sensor, value } => put(&(sensor, value), out),
            Payload::LocationConsensus { chunk, values } => {
                locator::encode_piece(*chunk, values, out)
            }
            Payload::ActivateSlots { slots, columns } => mac::encode_schedule(*slots, columns, out),
            Payload::SlotValues { slots, values } => mac::encode_transmissions(*slots, values, out),
            Payload::MacOutput { values } => mac::encode_output(values, out),
            Payload::SelectionReport(r) => selection::encode_report(r, out),
            Payload::SelectionChoice(c) => selection::encode_choice(c, out),
            Payload::Protocol(body) => out.extend_from_slice(&body.bytes),
        }
    }

    pub fn to_bytes(&self, format: &WireFormat) -> Vec<u8> {
        let mut v = Vec::with_capacity(256);
        self.encode(format, &mut v);
        v
    }

    /// Reads one message, rejecting anything that is not exactly a valid one.
    pub fn decode(bytes: &[u8], format: &WireFormat) -> Result<Self, WireError> {
        if bytes.len() > MAX_MESSAGE_BYTES {
            return Err(WireError::TooLong { len: bytes.len() });
        }
        let (h, used): (WireHeader, usize) =
            bincode::serde::decode_from_slice(bytes, config()).map_err(|_| WireError::Truncated)?;
        if h.version != WIRE_VERSION {
            return Err(WireError::Version { got: h.version });
        }
        let computed = checksum(bytes);
        if computed != h.checksum {
            return Err(WireError::Checksum {
                carried: h.checksum,
                computed,
            });
        }
        let kind = MessageKind::from_code(h.kind, format.payloads)
            .ok_or(WireError::UnknownKind { kind: h.kind })?;
        let sender =
            ActorId::from_wire(h.sender_kind, h.sender_index).ok_or(WireError::UnknownSender {
                kind: h.sender_kind,
            })?;
        let body = &bytes[used..];
        let payload = match kind {
            MessageKind::Activate => sensing::decode_activate(body, format)?,
            MessageKind::ActivateFeedback | MessageKind::ActivateFeedbackCovariance => {
                sensing::decode_feedback(body, kind, format)?
            }
            MessageKind::Observation => sensing::decode_observation(body, format)?,
            MessageKind::RawObservation => sensing::decode_raw(body)?,
            MessageKind::ActivateThresholds => sensing::decode_thresholds(body, format)?,
            MessageKind::Control => Payload::Control(codec::take(body)?),
            MessageKind::Telemetry => launcher::decode_telemetry(body)?,
            MessageKind::Consensus => cfdpf::decode_consensus(body, false)?,
            MessageKind::ConsensusLate => cfdpf::decode_consensus(body, true)?,
            MessageKind::ConsensusAux => cfdpf::decode_aux(body)?,
            MessageKind::StateTransfer => cfdpf::decode_state_transfer(body)?,
            MessageKind::KlConsensus => trackers::decode_kl(body)?,
            MessageKind::ExchangeRequest => trackers::decode_request(body)?,
            MessageKind::ExchangeReply => trackers::decode_reply(body)?,
            MessageKind::ExchangePosterior => trackers::decode_posterior(body)?,
            MessageKind::NeighbourObservation => trackers::decode_relay(body)?,
            MessageKind::LocationConsensus => locator::decode_piece(body)?,
            MessageKind::ActivateSlots => mac::decode_schedule(body)?,
            MessageKind::SlotValues => mac::decode_transmissions(body)?,
            MessageKind::MacOutput => mac::decode_output(body)?,
            MessageKind::SelectionReport => selection::decode_report(body)?,
            MessageKind::SelectionChoice => selection::decode_choice(body)?,
            MessageKind::Protocol(k) => {
                k.check_body(body)?;
                Payload::Protocol(ProtocolBody {
                    kind: k,
                    bytes: body.to_vec(),
                })
            }
            MessageKind::Malformed => unreachable!("never decoded from a kind byte"),
        };
        Ok(Self {
            header: Header {
                kind,
                sender,
                step: h.step,
                round: h.round,
            },
            payload,
        })
    }
}

/// Encoded size of a message of a fixed-size kind, for predicting traffic.
pub fn encoded_len(kind: MessageKind, format: &WireFormat) -> Option<usize> {
    Some(
        HEADER_BYTES
            + match kind {
                MessageKind::Activate => format.activation_bytes,
                MessageKind::ActivateFeedback => format.activation_bytes + 32,
                MessageKind::ActivateFeedbackCovariance => format.activation_bytes + 32 + 80,
                MessageKind::Observation => format.cell_bytes,
                MessageKind::RawObservation => 8,
                MessageKind::Consensus => cfdpf::CONSENSUS_BYTES,
                MessageKind::ConsensusLate => cfdpf::CONSENSUS_BYTES + 8 * 10,
                MessageKind::ConsensusAux => 8 * 10,
                MessageKind::StateTransfer => 8 * 34,
                MessageKind::KlConsensus => 8 * 14,
                MessageKind::ExchangeRequest => 0,
                MessageKind::ExchangeReply => 1,
                MessageKind::ExchangePosterior => 8 * 14,
                MessageKind::NeighbourObservation => 2 + 8,
                MessageKind::LocationConsensus => 2 + 8 * LOCATION_CHUNK,
                MessageKind::Protocol(k) => k.body_len(),
                _ => return None,
            },
    )
}

/// The checksum of an encoded message, its own two bytes read as zero.
/// A message shorter than a header has none (decoding rejects it anyway).
fn checksum(message: &[u8]) -> u16 {
    if message.len() < HEADER_BYTES {
        return 0;
    }
    let crc = crc16(0xFFFF, &message[..CHECKSUM_AT.start]);
    let crc = crc16(crc, &[0, 0]);
    crc16(crc, &message[CHECKSUM_AT.end..])
}

/// The step in an encoded message's header, read without decoding it, so
/// that a link's faults can be those of the message's step.
pub fn peek_step(message: &[u8]) -> Option<u32> {
    let bytes = message.get(STEP_AT)?;
    Some(u32::from_le_bytes(bytes.try_into().ok()?))
}

/// The kind byte of an encoded message, read without decoding it (the byte
/// after the version), so that a fault that damages a message can still
/// say what was sent.
pub fn peek_kind(message: &[u8]) -> Option<u8> {
    message.get(1).copied()
}

/// Writes the checksum into an encoded message. Fuzzers use it too, so that
/// a mutated message gets past the checksum to the code behind it.
pub fn seal(message: &mut [u8]) {
    if message.len() >= HEADER_BYTES {
        let crc = checksum(message);
        message[CHECKSUM_AT].copy_from_slice(&crc.to_le_bytes());
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    pub(crate) const FORMAT: WireFormat = WireFormat {
        cell_bytes: 1,
        activation_bytes: 4,
        payloads: crate::payloads::Payloads::NONE,
    };

    #[test]
    fn every_kind_round_trips_and_has_its_predicted_size() {
        for m in examples() {
            let bytes = m.to_bytes(&FORMAT);
            assert_eq!(Message::decode(&bytes, &FORMAT).unwrap(), m);
            if let Some(n) = encoded_len(m.header.kind, &FORMAT) {
                assert_eq!(bytes.len(), n, "{:?}", m.header.kind);
            }
        }
    }

    #[test]
    fn observation_is_header_plus_ceil_bits_over_eight() {
        let m = Message::new(
            ActorId::Sensor(1),
            1,
            0,
            Payload::Observation { cell: 0x1234 },
        );
        let f = WireFormat {
            cell_bytes: 2,
            activation_bytes: 4,
            payloads: crate::payloads::Payloads::NONE,
        };
        assert_eq!(m.to_bytes(&f).len(), HEADER_BYTES + 2);
        assert_eq!(Message::decode(&m.to_bytes(&f), &f).unwrap(), m);
        assert_eq!(
            Message::new(ActorId::Sensor(1), 1, 0, Payload::Observation { cell: 200 })
                .to_bytes(&FORMAT)
                .len(),
            14
        );
    }

    #[test]
    fn every_single_bit_flip_is_caught_by_the_checksum() {
        for m in examples() {
            let good = m.to_bytes(&FORMAT);
            for bit in 0..good.len() * 8 {
                let mut b = good.clone();
                b[bit / 8] ^= 1 << (bit % 8);
                let got = Message::decode(&b, &FORMAT);
                // A flip in the version byte is caught there first.
                assert!(
                    matches!(
                        got,
                        Err(WireError::Checksum { .. } | WireError::Version { .. })
                    ),
                    "{:?}, bit {bit}: {got:?}",
                    m.header.kind
                );
            }
        }
    }

    #[test]
    fn the_step_is_read_from_the_header_alone() {
        for m in examples() {
            assert_eq!(peek_step(&m.to_bytes(&FORMAT)), Some(m.header.step));
        }
        let m = Message::new(
            ActorId::Node(1),
            0x0102_0304,
            9,
            Payload::Control(Control::BeginStep),
        );
        assert_eq!(peek_step(&m.to_bytes(&FORMAT)), Some(0x0102_0304));
        assert_eq!(peek_step(&[2, 7, 1, 0]), None);
    }

    #[test]
    fn decoding_rejects_bad_versions_lengths_and_numbers() {
        let raw = Message::new(
            ActorId::Sensor(1),
            1,
            0,
            Payload::RawObservation { value: 0.0 },
        );
        let mut b = raw.to_bytes(&FORMAT);
        b[0] = 9;
        assert_eq!(
            Message::decode(&b, &FORMAT),
            Err(WireError::Version { got: 9 })
        );
        // Past the checksum (resealed), what is wrong is named.
        let b = raw.to_bytes(&FORMAT);
        let mut short = b[..b.len() - 1].to_vec();
        seal(&mut short);
        assert_eq!(Message::decode(&short, &FORMAT), Err(WireError::Truncated));
        let mut long = b.clone();
        long.push(0);
        seal(&mut long);
        assert!(matches!(
            Message::decode(&long, &FORMAT),
            Err(WireError::TrailingBytes { .. })
        ));
        let nan = Message::new(
            ActorId::Sensor(1),
            1,
            0,
            Payload::RawObservation { value: f64::NAN },
        );
        assert_eq!(
            Message::decode(&nan.to_bytes(&FORMAT), &FORMAT),
            Err(WireError::NonFinite)
        );
        let obs = Message::new(ActorId::Sensor(1), 1, 0, Payload::Observation { cell: 3 })
            .to_bytes(&WireFormat {
                cell_bytes: 2,
                activation_bytes: 4,
                payloads: crate::payloads::Payloads::NONE,
            });
        let mut unsealed = obs.clone();
        unsealed[12] ^= 0x40;
        assert!(matches!(
            Message::decode(&unsealed, &FORMAT),
            Err(WireError::Checksum { .. })
        ));
        assert!(matches!(
            Message::decode(&obs, &FORMAT),
            Err(WireError::Length {
                expected: 1,
                got: 2
            })
        ));
    }

    #[test]
    fn symmetric_packing_round_trips() {
        let m = [
            [1.0, 2.0, 3.0, 4.0],
            [2.0, 5.0, 6.0, 7.0],
            [3.0, 6.0, 8.0, 9.0],
            [4.0, 7.0, 9.0, 10.0],
        ];
        assert_eq!(unpack_symmetric(&pack_symmetric(&m)), m);
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = Message::decode(&bytes, &FORMAT);
        }

        #[test]
        fn corrupted_messages_never_panic(index in 0usize..examples().len(), flips in proptest::collection::vec((0usize..300, any::<u8>()), 1..6)) {
            let mut bytes = examples()[index].to_bytes(&FORMAT);
            for (at, v) in flips {
                let n = bytes.len();
                bytes[at % n] = v;
            }
            let _ = Message::decode(&bytes, &FORMAT);
            seal(&mut bytes);
            let _ = Message::decode(&bytes, &FORMAT);
        }
    }
}
