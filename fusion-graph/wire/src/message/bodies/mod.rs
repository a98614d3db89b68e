//! The bodies of the built-in messages, each protocol's beside its
//! encoding and its checks: between a node and its sensors
//! ([`sensing`]), the launcher and its actors ([`launcher`]), the CF/DPF's
//! nodes ([`cfdpf`]), the trackers ([`trackers`]), a locator's
//! ([`locator`]), negotiated sensor selection ([`selection`]) and a
//! multiple-access channel ([`mac`]). The codec reaches each kind's body
//! through [`Payload`]; a program's own protocols declare theirs as
//! [`ProtocolPayload`](crate::payloads::ProtocolPayload)s beside the
//! protocol.

pub mod cfdpf;
pub mod launcher;
pub mod locator;
pub mod mac;
pub mod selection;
pub mod sensing;
pub mod trackers;

pub use cfdpf::{ConsensusValues, StateTransfer};
pub use launcher::{Control, Stage, Telemetry, MAX_REPORTED_ACTIVE};
pub use locator::LOCATION_CHUNK;
pub use mac::{SlotColumn, MAX_SLOTS, SLOT_COLUMN_BYTES};
pub use selection::{
    CandidateReport, ChosenSensors, MAX_CHOSEN_PER_PIECE, MAX_REPORTED_CANDIDATES,
};
pub use sensing::{BitMask, MAX_THRESHOLDS};
pub use trackers::{GaussianInformation, GaussianMoments};

use super::MessageKind;
use crate::payloads::ProtocolBody;

/// Symmetric 4×4 matrices travel as their 10 upper-triangular entries.
pub type Packed = [f64; 10];

#[derive(Debug, Clone, PartialEq)]
pub enum Payload {
    /// Bit i: the node's i-th sensor is active.
    Activate {
        mask: BitMask,
    },
    /// An activation that carries the node's feedback to censoring sensors.
    ActivateWithFeedback {
        mask: BitMask,
        estimate: [f64; 4],
        /// The upper triangle of the estimate's covariance (CFwMD2).
        covariance: Option<Packed>,
    },
    Observation {
        cell: u32,
    },
    RawObservation {
        value: f64,
    },
    Consensus(ConsensusValues),
    ConsensusAux {
        s_obs: Packed,
    },
    Control(Control),
    Telemetry(Telemetry),
    StateTransfer(StateTransfer),
    KlConsensus(GaussianInformation),
    ExchangeRequest,
    ExchangeReply {
        accepted: bool,
    },
    ExchangePosterior(GaussianMoments),
    NeighbourObservation {
        sensor: u16,
        value: f64,
    },
    /// An activation with the quantizer's thresholds, increasing (at most
    /// [`MAX_THRESHOLDS`]).
    ActivateThresholds {
        mask: BitMask,
        thresholds: Vec<f64>,
    },
    /// Piece `chunk` of a locator's consensus value.
    LocationConsensus {
        chunk: u16,
        values: [f64; LOCATION_CHUNK],
    },
    /// A fusion centre's schedule of its channel's slots: every
    /// transmitting sensor's column of the sensing matrix.
    ActivateSlots {
        slots: u8,
        columns: Vec<SlotColumn>,
    },
    /// What a sensor transmits in its slots: one value per bit of `slots`,
    /// in increasing slot order.
    SlotValues {
        slots: u32,
        values: Vec<f64>,
    },
    /// What the channel received in each slot.
    MacOutput {
        values: Vec<f64>,
    },
    /// A piece of a node's report up sensor selection's spanning tree.
    SelectionReport(CandidateReport),
    /// A piece of sensor selection's choice, down the spanning tree.
    SelectionChoice(ChosenSensors),
    /// A protocol's own payload ([`crate::payloads`]).
    Protocol(ProtocolBody),
}

impl Payload {
    pub fn kind(&self) -> MessageKind {
        match self {
            Payload::Activate { .. } => MessageKind::Activate,
            Payload::ActivateWithFeedback {
                covariance: None, ..
            } => MessageKind::ActivateFeedback,
            Payload::ActivateWithFeedback {
                covariance: Some(_),
                ..
            } => MessageKind::ActivateFeedbackCovariance,
            Payload::Observation { .. } => MessageKind::Observation,
            Payload::RawObservation { .. } => MessageKind::RawObservation,
            Payload::Consensus(v) if v.delta_l_late.is_some() => MessageKind::ConsensusLate,
            Payload::Consensus(_) => MessageKind::Consensus,
            Payload::ConsensusAux { .. } => MessageKind::ConsensusAux,
            Payload::Control(_) => MessageKind::Control,
            Payload::Telemetry(_) => MessageKind::Telemetry,
            Payload::StateTransfer(_) => MessageKind::StateTransfer,
            Payload::SelectionReport(_) => MessageKind::SelectionReport,
            Payload::SelectionChoice(_) => MessageKind::SelectionChoice,
            Payload::KlConsensus(_) => MessageKind::KlConsensus,
            Payload::ExchangeRequest => MessageKind::ExchangeRequest,
            Payload::ExchangeReply { .. } => MessageKind::ExchangeReply,
            Payload::ExchangePosterior(_) => MessageKind::ExchangePosterior,
            Payload::NeighbourObservation { .. } => MessageKind::NeighbourObservation,
            Payload::ActivateThresholds { .. } => MessageKind::ActivateThresholds,
            Payload::LocationConsensus { .. } => MessageKind::LocationConsensus,
            Payload::ActivateSlots { .. } => MessageKind::ActivateSlots,
            Payload::SlotValues { .. } => MessageKind::SlotValues,
            Payload::MacOutput { .. } => MessageKind::MacOutput,
            Payload::Protocol(body) => MessageKind::Protocol(body.kind),
        }
    }
}

/// Packs the upper triangle of a symmetric 4×4 (row-major `m[r][c]`).
/// A symmetric matrix as its upper triangle, row by row.
pub fn pack_mat4(m: &bounds::Mat4) -> Packed {
    pack_symmetric(&std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])))
}

pub fn unpack_mat4(p: &Packed) -> bounds::Mat4 {
    let a = unpack_symmetric(p);
    bounds::Mat4::from_fn(|r, c| a[r][c])
}

pub fn pack_symmetric(m: &[[f64; 4]; 4]) -> Packed {
    let mut out = [0.0; 10];
    let upper = (0..4).flat_map(|r| (r..4).map(move |c| (r, c)));
    for (slot, (r, c)) in out.iter_mut().zip(upper) {
        *slot = m[r][c];
    }
    out
}

pub fn unpack_symmetric(p: &Packed) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    let upper = (0..4).flat_map(|r| (r..4).map(move |c| (r, c)));
    for (&v, (r, c)) in p.iter().zip(upper) {
        m[r][c] = v;
        m[c][r] = v;
    }
    m
}
