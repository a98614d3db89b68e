//! The bodies of the built-in messages: what each payload holds, and the
//! packing of a symmetric matrix into the ten numbers of its upper triangle.

use serde::{Deserialize, Serialize};

use super::MessageKind;
use crate::payloads::ProtocolBody;

/// A set of small indices as a bit mask, bit i of byte i/8: which of a
/// node's sensors are active, or which nodes are alive.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct BitMask(Vec<u8>);

impl BitMask {
    pub fn from_indices(indices: impl IntoIterator<Item = usize>) -> Self {
        let mut bytes = Vec::new();
        for i in indices {
            if bytes.len() <= i / 8 {
                bytes.resize(i / 8 + 1, 0);
            }
            bytes[i / 8] |= 1 << (i % 8);
        }
        Self(bytes)
    }

    pub fn from_bools(set: &[bool]) -> Self {
        let mut m = Self::from_indices(set.iter().enumerate().filter(|(_, b)| **b).map(|(i, _)| i));
        m.0.resize(set.len().div_ceil(8), 0);
        m
    }

    pub fn from_bytes(bytes: Vec<u8>) -> Self {
        Self(bytes)
    }

    pub fn contains(&self, i: usize) -> bool {
        self.0.get(i / 8).is_some_and(|b| b & (1 << (i % 8)) != 0)
    }

    /// Membership of indices `0..n`.
    pub fn to_bools(&self, n: usize) -> Vec<bool> {
        (0..n).map(|i| self.contains(i)).collect()
    }

    pub fn as_bytes(&self) -> &[u8] {
        &self.0
    }
}

/// Symmetric 4×4 matrices travel as their 10 upper-triangular entries.
pub type Packed = [f64; 10];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConsensusValues {
    pub delta_eta: [f64; 4],
    pub delta_lambda: Packed,
    pub delta_l: Packed,
    /// ΔL_late, the information of late observations about the step
    /// before; present, it makes the message a
    /// [`MessageKind::ConsensusLate`].
    #[serde(skip)]
    pub delta_l_late: Option<Packed>,
}

/// The stages a node times, by their place in [`Telemetry::stage_micros`].
/// Each node kind fills the ones it has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The node's own evidence: the CF/DPF's local filter with the local
    /// bound; a tracker's or locator's weighing of its measurements.
    Local = 0,
    /// The global estimate: the CF/DPF's fusion filter with the global
    /// bounds; KL fusion's adoption; a fusion centre's weighing.
    Global = 1,
    /// Consensus rounds 2..N_c: when every neighbour is already
    /// exchanging, the rounds' own latency.
    LaterRounds = 2,
    /// The whole consensus (round 1 also waits for the slowest
    /// neighbour's filter).
    Consensus = 3,
    /// The sensor selection, from `BeginStep` to the activation (zero for
    /// a manager that chooses alone).
    Selection = 4,
    /// The selection's scoring, wherever it ran: in the step, or before it
    /// began.
    Scoring = 5,
}

impl Stage {
    pub const COUNT: usize = 6;
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Telemetry {
    pub estimate: [f64; 4],
    /// CQ/dPCRLB position bound, metres.
    pub bound: Option<f64>,
    pub local_bound: Option<f64>,
    pub aux_bound: Option<f64>,
    pub rounds_completed: u16,
    pub live_neighbours: u16,
    /// Neighbours the fusion protocol expected in its last round but did
    /// not hear (what "fewer neighbours" means is the protocol's).
    pub missed_neighbours: u16,
    pub observations: u16,
    /// Observations the innovation gate left out.
    pub gated: u16,
    /// Observations of the previous step that arrived after its listening
    /// window and were weighed this step, at the time they were taken.
    pub lagged: u16,
    pub deadline_missed: bool,
    /// Messages that arrived after their round or step had passed, since the last telemetry.
    pub late_messages: u32,
    /// Microseconds in each [`Stage`], at its place.
    pub stage_micros: [u32; Stage::COUNT],
    /// Own sensors activated several times that never answered, and the
    /// first of them (0 and `None` with censoring, where silence is an
    /// answer).
    pub unanswered_sensors: u16,
    pub first_unanswered: Option<u16>,
    /// The spread of the fusion filter's prediction for the step,
    /// `sqrt(tr_pos P(k|k−1))`, metres: how wide a cloud the sensor
    /// manager scored on.
    pub spread: Option<f64>,
    /// The sensors the node activated for the step (at most
    /// [`MAX_REPORTED_ACTIVE`]).
    pub active: Vec<u16>,
    /// A fusion centre that designs its channel's transmissions: each of
    /// its sensors' transmission probability for the step, in
    /// ten-thousandths. Empty for every other node.
    pub design: Vec<u16>,
    /// A negotiated sensor selection's choice never reached the node this
    /// step (its root was lost, or the step's deadline came first), so it
    /// activated none of its sensors.
    pub without_choice: bool,
}

impl Telemetry {
    /// A report of `estimate` and nothing else: no bounds, rounds, stage
    /// times or sensors; the fields a reporter has it sets after.
    pub fn of_estimate(estimate: [f64; 4]) -> Self {
        Self {
            estimate,
            bound: None,
            local_bound: None,
            aux_bound: None,
            rounds_completed: 0,
            live_neighbours: 0,
            missed_neighbours: 0,
            observations: 0,
            gated: 0,
            lagged: 0,
            deadline_missed: false,
            late_messages: 0,
            stage_micros: [0; Stage::COUNT],
            unanswered_sensors: 0,
            first_unanswered: None,
            spread: None,
            active: Vec::new(),
            design: Vec::new(),
            without_choice: false,
        }
    }
}

/// The most activated sensors a telemetry message may list.
pub const MAX_REPORTED_ACTIVE: usize = 256;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Control {
    /// Start the step in the header (launcher → node).
    BeginStep,
    /// Finish the current step and exit.
    Stop,
    /// The nodes this node can reach (bit i is node i).
    Membership { alive: BitMask },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateTransfer {
    pub mean: [f64; 4],
    pub covariance: Packed,
    pub information: Packed,
    pub aux_information: Packed,
}

/// A Gaussian in information form: `η = P⁻¹ m`, `Λ = P⁻¹` (upper triangle).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GaussianInformation {
    pub eta: [f64; 4],
    pub lambda: Packed,
}

/// A Gaussian as mean and covariance (upper triangle).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GaussianMoments {
    pub mean: [f64; 4],
    pub covariance: Packed,
}

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

/// One sensor's column of a sensing matrix: it transmits in the slots of
/// `slots`, its value negated in those of `negative`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlotColumn {
    /// The sensor's place in its node's list.
    pub sensor: u16,
    pub slots: u32,
    pub negative: u32,
}

/// The bytes of one [`SlotColumn`] on the wire.
pub const SLOT_COLUMN_BYTES: usize = 10;

/// The most thresholds an activation carries: a 4-bit quantizer's.
pub const MAX_THRESHOLDS: usize = 15;

/// The numbers in one piece of a locator's consensus value.
pub const LOCATION_CHUNK: usize = 32;

/// One piece of a node's report to its parent in sensor selection's
/// spanning tree: candidates of node `node` from place `first` in its
/// sensor list, each as its `J̄` position block `[xx, xy, yy]`. A report is
/// pieces `0, 1, …` in order; its last says how many there are, the others
/// carry `parts = 0`, so that a parent knows when a child's subtree is in
/// while the pieces stream up as they arrive.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateReport {
    /// The parent the report is for: the channel's other readers pass it by.
    pub to: u16,
    pub part: u16,
    /// The count of pieces, on the last; 0 on the others.
    pub parts: u16,
    pub node: u16,
    pub first: u16,
    pub information: Vec<[f64; 3]>,
}

/// The most candidates in one [`CandidateReport`]: 12 fill the consensus
/// channel's room of 300 bytes.
pub const MAX_REPORTED_CANDIDATES: usize = 12;

/// One piece of sensor selection's choice: `sensors` chosen, increasing,
/// of `total` chosen network-wide, and the chosen's `Σ J̄` position block.
#[derive(Debug, Clone, PartialEq)]
pub struct ChosenSensors {
    pub part: u16,
    pub parts: u16,
    pub total: u16,
    pub sum: [f64; 3],
    pub sensors: Vec<u16>,
}

/// The most sensors in one [`ChosenSensors`] piece.
pub const MAX_CHOSEN_PER_PIECE: usize = 128;

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
