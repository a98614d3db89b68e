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

mod bodies;
mod crc;
mod examples;
mod kind;

pub use bodies::*;
use crc::crc16;
pub use examples::examples;
pub use kind::MessageKind;

use bincode::config::{Configuration, Fixint, Limit, LittleEndian};
use serde::{Deserialize, Serialize};

use crate::actor::ActorId;
use crate::payloads::{Payloads, ProtocolBody};
use crate::WireError;

/// Bumped whenever the encoding changes.
pub const WIRE_VERSION: u8 = 2;
/// Encoded size of [`Header`].
pub const HEADER_BYTES: usize = 13;
/// Where the checksum sits in the header.
const CHECKSUM_AT: std::ops::Range<usize> = 11..13;
/// Where the step sits in the header: after the version, the kind and the
/// sender's kind and index.
const STEP_AT: std::ops::Range<usize> = 5..9;
/// No message is larger than this; it bounds every allocation in decoding.
pub const MAX_MESSAGE_BYTES: usize = 1024;

type Config = Configuration<LittleEndian, Fixint, Limit<MAX_MESSAGE_BYTES>>;

fn config() -> Config {
    bincode::config::standard()
        .with_little_endian()
        .with_fixed_int_encoding()
        .with_limit::<MAX_MESSAGE_BYTES>()
}

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
            } => {
                put_mask(mask, format, out);
                put(estimate, out);
                if let Some(c) = covariance {
                    put(c, out);
                }
            }
            Payload::Observation { cell } => {
                out.extend_from_slice(&cell.to_le_bytes()[..format.cell_bytes])
            }
            Payload::RawObservation { value } => put(value, out),
            Payload::Consensus(v) => {
                put(v, out);
                if let Some(late) = &v.delta_l_late {
                    put(late, out);
                }
            }
            Payload::ConsensusAux { s_obs } => put(s_obs, out),
            Payload::Control(c) => put(c, out),
            Payload::Telemetry(t) => put(t, out),
            Payload::StateTransfer(s) => put(s, out),
            Payload::KlConsensus(g) => put(g, out),
            Payload::ExchangeRequest => {}
            Payload::ExchangeReply { accepted } => out.push(u8::from(*accepted)),
            Payload::ExchangePosterior(g) => put(g, out),
            Payload::NeighbourObservation { sensor, value } => {
                put(sensor, out);
                put(value, out);
            }
            Payload::ActivateThresholds { mask, thresholds } => {
                put_mask(mask, format, out);
                out.push(thresholds.len() as u8);
                for t in thresholds {
                    put(t, out);
                }
            }
            Payload::LocationConsensus { chunk, values } => {
                put(chunk, out);
                for v in values {
                    put(v, out);
                }
            }
            Payload::ActivateSlots { slots, columns } => {
                out.push(*slots);
                put(&(columns.len() as u16), out);
                for c in columns {
                    put(&c.sensor, out);
                    put(&c.slots, out);
                    put(&c.negative, out);
                }
            }
            Payload::SlotValues { slots, values } => {
                put(slots, out);
                for v in values {
                    put(v, out);
                }
            }
            Payload::MacOutput { values } => {
                out.push(values.len() as u8);
                for v in values {
                    put(v, out);
                }
            }
            Payload::SelectionReport(r) => {
                for v in [r.to, r.part, r.parts, r.node, r.first] {
                    put(&v, out);
                }
                out.push(r.information.len() as u8);
                for v in r.information.iter().flatten() {
                    put(v, out);
                }
            }
            Payload::SelectionChoice(c) => {
                for v in [c.part, c.parts, c.total] {
                    put(&v, out);
                }
                put(&c.sum, out);
                out.push(c.sensors.len() as u8);
                for v in &c.sensors {
                    put(v, out);
                }
            }
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
            MessageKind::Activate => {
                exact_len(body, format.activation_bytes)?;
                Payload::Activate {
                    mask: BitMask::from_bytes(body.to_vec()),
                }
            }
            MessageKind::ActivateFeedback | MessageKind::ActivateFeedbackCovariance => {
                let with_covariance = kind == MessageKind::ActivateFeedbackCovariance;
                let mask_len = format.activation_bytes;
                exact_len(body, mask_len + 32 + if with_covariance { 80 } else { 0 })?;
                let estimate: [f64; 4] = finite(take(&body[mask_len..mask_len + 32])?)?;
                let covariance = if with_covariance {
                    Some(finite(take(&body[mask_len + 32..])?)?)
                } else {
                    None
                };
                Payload::ActivateWithFeedback {
                    mask: BitMask::from_bytes(body[..mask_len].to_vec()),
                    estimate,
                    covariance,
                }
            }
            MessageKind::Observation => {
                exact_len(body, format.cell_bytes)?;
                let mut le = [0u8; 4];
                le[..body.len()].copy_from_slice(body);
                Payload::Observation {
                    cell: u32::from_le_bytes(le),
                }
            }
            MessageKind::RawObservation => {
                let v: f64 = take(body)?;
                Payload::RawObservation {
                    value: finite([v])?[0],
                }
            }
            MessageKind::Consensus => Payload::Consensus(consensus_values(body)?),
            MessageKind::ConsensusLate => {
                let split = CONSENSUS_BYTES.min(body.len());
                let mut v = consensus_values(&body[..split])?;
                v.delta_l_late = Some(finite(take(&body[split..])?)?);
                Payload::Consensus(v)
            }
            MessageKind::ConsensusAux => Payload::ConsensusAux {
                s_obs: finite(take(body)?)?,
            },
            MessageKind::Control => Payload::Control(take(body)?),
            MessageKind::Telemetry => {
                let t: Telemetry = take(body)?;
                finite(t.estimate)?;
                for v in [t.bound, t.local_bound, t.aux_bound, t.spread]
                    .into_iter()
                    .flatten()
                {
                    finite([v])?;
                }
                for len in [t.active.len(), t.design.len()] {
                    if len > MAX_REPORTED_ACTIVE {
                        return Err(WireError::Length {
                            expected: MAX_REPORTED_ACTIVE,
                            got: len,
                        });
                    }
                }
                if t.design.iter().any(|p| *p > 10_000) {
                    return Err(WireError::Length {
                        expected: 10_000,
                        got: t.design.iter().copied().max().unwrap_or(0) as usize,
                    });
                }
                Payload::Telemetry(t)
            }
            MessageKind::StateTransfer => {
                let s: StateTransfer = take(body)?;
                finite(s.mean)?;
                finite(s.covariance)?;
                finite(s.information)?;
                finite(s.aux_information)?;
                Payload::StateTransfer(s)
            }
            MessageKind::KlConsensus => {
                let g: GaussianInformation = take(body)?;
                finite(g.eta)?;
                finite(g.lambda)?;
                Payload::KlConsensus(g)
            }
            MessageKind::ExchangeRequest => {
                exact_len(body, 0)?;
                Payload::ExchangeRequest
            }
            MessageKind::ExchangeReply => {
                exact_len(body, 1)?;
                Payload::ExchangeReply {
                    accepted: match body[0] {
                        0 => false,
                        1 => true,
                        got => return Err(WireError::Flag { got }),
                    },
                }
            }
            MessageKind::ExchangePosterior => {
                let g: GaussianMoments = take(body)?;
                finite(g.mean)?;
                finite(g.covariance)?;
                Payload::ExchangePosterior(g)
            }
            MessageKind::NeighbourObservation => {
                let (sensor, value): (u16, f64) = take(body)?;
                Payload::NeighbourObservation {
                    sensor,
                    value: finite([value])?[0],
                }
            }
            MessageKind::ActivateThresholds => {
                let mask_len = format.activation_bytes;
                let count = *body.get(mask_len).ok_or(WireError::Truncated)? as usize;
                if count == 0 || count > MAX_THRESHOLDS {
                    return Err(WireError::Length {
                        expected: MAX_THRESHOLDS,
                        got: count,
                    });
                }
                exact_len(body, mask_len + 1 + 8 * count)?;
                let thresholds: Vec<f64> = body[mask_len + 1..]
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
                    .collect();
                for t in &thresholds {
                    finite([*t])?;
                }
                if thresholds.windows(2).any(|w| w[0] >= w[1]) {
                    return Err(WireError::Unordered);
                }
                Payload::ActivateThresholds {
                    mask: BitMask::from_bytes(body[..mask_len].to_vec()),
                    thresholds,
                }
            }
            MessageKind::LocationConsensus => {
                exact_len(body, 2 + 8 * LOCATION_CHUNK)?;
                let chunk = u16::from_le_bytes([body[0], body[1]]);
                let mut values = [0.0; LOCATION_CHUNK];
                for (v, b) in values.iter_mut().zip(body[2..].chunks_exact(8)) {
                    *v = f64::from_le_bytes(b.try_into().expect("8 bytes"));
                }
                Payload::LocationConsensus {
                    chunk,
                    values: finite(values)?,
                }
            }
            MessageKind::ActivateSlots => activate_slots(body)?,
            MessageKind::SelectionReport => selection_report(body)?,
            MessageKind::SelectionChoice => selection_choice(body)?,
            MessageKind::SlotValues => {
                let slots = u32::from_le_bytes(
                    body.get(..4)
                        .ok_or(WireError::Truncated)?
                        .try_into()
                        .expect("4 bytes"),
                );
                if slots == 0 {
                    return Err(WireError::Length {
                        expected: 1,
                        got: 0,
                    });
                }
                exact_len(body, 4 + 8 * slots.count_ones() as usize)?;
                Payload::SlotValues {
                    slots,
                    values: finite_values(&body[4..])?,
                }
            }
            MessageKind::MacOutput => {
                let count = *body.first().ok_or(WireError::Truncated)? as usize;
                if count == 0 || count > MAX_SLOTS {
                    return Err(WireError::Length {
                        expected: MAX_SLOTS,
                        got: count,
                    });
                }
                exact_len(body, 1 + 8 * count)?;
                Payload::MacOutput {
                    values: finite_values(&body[1..])?,
                }
            }
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

/// The most slots of a multiple-access channel: a column is a 32-bit mask.
pub const MAX_SLOTS: usize = 32;

/// An [`ActivateSlots`](Payload::ActivateSlots) body: slots between 1 and
/// [`MAX_SLOTS`], columns of sensors in increasing order, each in some
/// slot and no other than the step's.
fn activate_slots(body: &[u8]) -> Result<Payload, WireError> {
    let slots = *body.first().ok_or(WireError::Truncated)?;
    if slots == 0 || slots as usize > MAX_SLOTS {
        return Err(WireError::Length {
            expected: MAX_SLOTS,
            got: slots as usize,
        });
    }
    let count = u16::from_le_bytes([
        *body.get(1).ok_or(WireError::Truncated)?,
        *body.get(2).ok_or(WireError::Truncated)?,
    ]) as usize;
    exact_len(body, 3 + SLOT_COLUMN_BYTES * count)?;
    let allowed = if slots as usize == MAX_SLOTS {
        u32::MAX
    } else {
        (1u32 << slots) - 1
    };
    let mut columns: Vec<SlotColumn> = Vec::with_capacity(count);
    for b in body[3..].chunks_exact(SLOT_COLUMN_BYTES) {
        let c = SlotColumn {
            sensor: u16::from_le_bytes([b[0], b[1]]),
            slots: u32::from_le_bytes(b[2..6].try_into().expect("4 bytes")),
            negative: u32::from_le_bytes(b[6..10].try_into().expect("4 bytes")),
        };
        let in_order = columns.last().is_none_or(|l| l.sensor < c.sensor);
        if c.slots == 0 || c.slots & !allowed != 0 || c.negative & !c.slots != 0 || !in_order {
            return Err(WireError::Unordered);
        }
        columns.push(c);
    }
    Ok(Payload::ActivateSlots { slots, columns })
}

fn u16_at(body: &[u8], at: usize) -> Result<u16, WireError> {
    let b = body.get(at..at + 2).ok_or(WireError::Truncated)?;
    Ok(u16::from_le_bytes([b[0], b[1]]))
}

/// A [`SelectionReport`](Payload::SelectionReport) body: at most
/// [`MAX_REPORTED_CANDIDATES`] finite blocks, each with non-negative
/// diagonal (a Fisher information is positive semi-definite).
fn selection_report(body: &[u8]) -> Result<Payload, WireError> {
    let (to, part, parts) = (u16_at(body, 0)?, u16_at(body, 2)?, u16_at(body, 4)?);
    let (node, first) = (u16_at(body, 6)?, u16_at(body, 8)?);
    // The last piece says the count; earlier pieces say 0.
    if parts != 0 && part >= parts {
        return Err(WireError::Unordered);
    }
    let count = *body.get(10).ok_or(WireError::Truncated)? as usize;
    if count > MAX_REPORTED_CANDIDATES {
        return Err(WireError::Length {
            expected: MAX_REPORTED_CANDIDATES,
            got: count,
        });
    }
    exact_len(body, 11 + 24 * count)?;
    let values = finite_values(&body[11..])?;
    let information: Vec<[f64; 3]> = values.chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect();
    if information.iter().any(|[xx, _, yy]| *xx < 0.0 || *yy < 0.0) {
        return Err(WireError::NegativeInformation);
    }
    Ok(Payload::SelectionReport(CandidateReport {
        to,
        part,
        parts,
        node,
        first,
        information,
    }))
}

/// A [`SelectionChoice`](Payload::SelectionChoice) body: every piece
/// with its count of pieces, at most
/// [`MAX_CHOSEN_PER_PIECE`] sensors, increasing, no more than the total.
fn selection_choice(body: &[u8]) -> Result<Payload, WireError> {
    let (part, parts, total) = (u16_at(body, 0)?, u16_at(body, 2)?, u16_at(body, 4)?);
    // Every piece of a choice says the count: it is known before any is sent.
    if part >= parts {
        return Err(WireError::Unordered);
    }
    let sum: [f64; 3] = finite(take(body.get(6..30).ok_or(WireError::Truncated)?)?)?;
    let count = *body.get(30).ok_or(WireError::Truncated)? as usize;
    if count > MAX_CHOSEN_PER_PIECE || count > total as usize {
        return Err(WireError::Length {
            expected: MAX_CHOSEN_PER_PIECE.min(total as usize),
            got: count,
        });
    }
    exact_len(body, 31 + 2 * count)?;
    let sensors: Vec<u16> = body[31..]
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    if sensors.windows(2).any(|w| w[0] >= w[1]) {
        return Err(WireError::Unordered);
    }
    Ok(Payload::SelectionChoice(ChosenSensors {
        part,
        parts,
        total,
        sum,
        sensors,
    }))
}

/// Little-endian f64s, every one finite.
fn finite_values(body: &[u8]) -> Result<Vec<f64>, WireError> {
    let values: Vec<f64> = body
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
        .collect();
    for v in &values {
        finite([*v])?;
    }
    Ok(values)
}

fn put_mask(mask: &BitMask, format: &WireFormat, out: &mut Vec<u8>) {
    let bytes = mask.as_bytes();
    let n = bytes.len().min(format.activation_bytes);
    out.extend_from_slice(&bytes[..n]);
    out.resize(out.len() + format.activation_bytes - n, 0);
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
                MessageKind::Consensus => CONSENSUS_BYTES,
                MessageKind::ConsensusLate => CONSENSUS_BYTES + 8 * 10,
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

/// The body of a [`MessageKind::Consensus`]: δη, δΛ, ΔL.
const CONSENSUS_BYTES: usize = 8 * 24;

/// δη, δΛ and ΔL, each finite.
fn consensus_values(body: &[u8]) -> Result<ConsensusValues, WireError> {
    let v: ConsensusValues = take(body)?;
    finite(v.delta_eta)?;
    finite(v.delta_lambda)?;
    finite(v.delta_l)?;
    Ok(v)
}

fn put<T: Serialize>(v: &T, out: &mut Vec<u8>) {
    bincode::serde::encode_into_std_write(v, out, config()).expect("writing to a Vec cannot fail");
}

/// Decodes a whole body as one value; trailing bytes are an error.
fn take<T: for<'de> Deserialize<'de>>(body: &[u8]) -> Result<T, WireError> {
    let (v, used) =
        bincode::serde::decode_from_slice(body, config()).map_err(|_| WireError::Truncated)?;
    if used != body.len() {
        return Err(WireError::TrailingBytes {
            extra: body.len() - used,
        });
    }
    Ok(v)
}

fn exact_len(body: &[u8], expected: usize) -> Result<(), WireError> {
    if body.len() != expected {
        return Err(WireError::Length {
            expected,
            got: body.len(),
        });
    }
    Ok(())
}

fn finite<const N: usize>(v: [f64; N]) -> Result<[f64; N], WireError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(WireError::NonFinite)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const FORMAT: WireFormat = WireFormat {
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

    /// The selection's pieces: counts within their limits, pieces within
    /// their count, sensors increasing, information with a non-negative
    /// diagonal; and the largest report fits the consensus channel.
    #[test]
    fn selection_pieces_are_checked() {
        let decode = |payload: Payload| {
            Message::decode(
                &Message::new(ActorId::Node(1), 2, 1, payload).to_bytes(&FORMAT),
                &FORMAT,
            )
        };
        let report = CandidateReport {
            to: 0,
            part: 0,
            parts: 0,
            node: 1,
            first: 12,
            information: vec![[1.0, -0.5, 2.0]; MAX_REPORTED_CANDIDATES],
        };
        let full = Message::new(
            ActorId::Node(1),
            2,
            1,
            Payload::SelectionReport(report.clone()),
        );
        assert_eq!(full.to_bytes(&FORMAT).len(), HEADER_BYTES + 11 + 24 * 12);
        assert!(full.to_bytes(&FORMAT).len() <= HEADER_BYTES + 300);
        assert!(decode(Payload::SelectionReport(report.clone())).is_ok());
        let mut too_many = report.clone();
        too_many.information.push([1.0, 0.0, 1.0]);
        assert!(matches!(
            decode(Payload::SelectionReport(too_many)),
            Err(WireError::Length {
                expected: 12,
                got: 13
            })
        ));
        let past_count = CandidateReport {
            part: 3,
            parts: 3,
            ..report.clone()
        };
        assert_eq!(
            decode(Payload::SelectionReport(past_count)),
            Err(WireError::Unordered)
        );
        let negative = CandidateReport {
            information: vec![[-1.0, 0.0, 1.0]],
            ..report.clone()
        };
        assert_eq!(
            decode(Payload::SelectionReport(negative)),
            Err(WireError::NegativeInformation)
        );
        let nan = CandidateReport {
            information: vec![[1.0, f64::NAN, 1.0]],
            ..report
        };
        assert_eq!(
            decode(Payload::SelectionReport(nan)),
            Err(WireError::NonFinite)
        );

        let choice = ChosenSensors {
            part: 0,
            parts: 1,
            total: 3,
            sum: [1.0, 0.0, 1.0],
            sensors: vec![2, 9, 40],
        };
        assert!(decode(Payload::SelectionChoice(choice.clone())).is_ok());
        for bad in [
            ChosenSensors {
                sensors: vec![9, 2, 40],
                ..choice.clone()
            },
            ChosenSensors {
                sensors: vec![2, 2, 40],
                ..choice.clone()
            },
            ChosenSensors {
                part: 1,
                ..choice.clone()
            },
            ChosenSensors {
                parts: 0,
                ..choice.clone()
            },
        ] {
            assert_eq!(
                decode(Payload::SelectionChoice(bad)),
                Err(WireError::Unordered)
            );
        }
        let more_than_total = ChosenSensors { total: 2, ..choice };
        assert!(matches!(
            decode(Payload::SelectionChoice(more_than_total)),
            Err(WireError::Length { .. })
        ));
    }

    #[test]
    fn bit_masks_hold_exactly_their_indices() {
        let m = BitMask::from_indices([0, 3, 9]);
        assert_eq!(m.as_bytes(), &[0b1001, 0b10]);
        assert_eq!(m.to_bools(11).iter().filter(|b| **b).count(), 3);
        assert!(m.contains(9) && !m.contains(8) && !m.contains(100));
        let v = [
            true, false, false, true, true, false, false, false, false, true,
        ];
        assert_eq!(BitMask::from_bools(&v).to_bools(10), v);
        assert_eq!(BitMask::from_bools(&[false; 9]).as_bytes(), &[0, 0]);
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
