//! The kinds of message: one table gives each built-in kind its byte on
//! the wire and its name in the counts, so that adding a kind is one line.

use crate::payloads::{Payloads, ProtocolKind};

/// Declares [`MessageKind`] from one table, `Variant = byte, "name";`,
/// with the conversions to and from the byte and the name read off the
/// same rows.
macro_rules! message_kinds {
    ($($(#[$meta:meta])* $variant:ident = $code:literal, $name:literal;)*) => {
        /// Message kinds, also the unit of byte accounting: the built-in
        /// ones, and those a program gives its protocols' own payloads
        /// ([`crate::payloads`]).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
        #[repr(u8)]
        pub enum MessageKind {
            $($(#[$meta])* $variant = $code,)*
            /// A protocol's own payload, under the kind byte the program gave it.
            Protocol(ProtocolKind) = 128,
            /// Accounting only: bytes whose kind could not be read.
            Malformed = 255,
        }

        impl MessageKind {
            /// The built-in kind of a byte; `None` for any other byte.
            pub fn from_u8(v: u8) -> Option<Self> {
                match v {
                    $($code => Some(Self::$variant),)*
                    _ => None,
                }
            }

            /// The kind of a byte read off the wire: a built-in kind, or
            /// one the program gave a payload of its own; `None` for any
            /// other byte.
            pub fn from_code(v: u8, payloads: Payloads) -> Option<Self> {
                Self::from_u8(v).or_else(|| payloads.kind(v).map(Self::Protocol))
            }

            /// The kind's name in the counts and the result files.
            pub fn name(self) -> &'static str {
                match self {
                    $(Self::$variant => $name,)*
                    Self::Protocol(k) => k.name(),
                    Self::Malformed => "malformed",
                }
            }

            /// The kind byte on the wire.
            pub fn code(self) -> u8 {
                match self {
                    $(Self::$variant => $code,)*
                    Self::Protocol(k) => k.code(),
                    Self::Malformed => 255,
                }
            }
        }
    };
}

message_kinds! {
    /// A node tells its sensors which of them are active this step.
    Activate = 2, "activate";
    /// A quantized observation: the cell index in `ceil(N_L/8)` bytes.
    Observation = 3, "observation";
    /// An unquantized observation (one f64).
    RawObservation = 4, "raw_observation";
    /// One consensus round: δη (4), δΛ (10), ΔL (10).
    Consensus = 5, "consensus";
    /// One round of the auxiliary-FIM baseline's second consensus (10).
    ConsensusAux = 6, "consensus_aux";
    /// The launcher to an actor: begin a step, stop, the nodes it can reach.
    Control = 7, "control";
    /// A node's report of its step to the launcher: estimate, bound, stage
    /// times.
    Telemetry = 8, "telemetry";
    /// A node's fused posterior, sent to a neighbour that rejoins.
    StateTransfer = 9, "state_transfer";
    /// An activation with the node's fused estimate fed back to censoring
    /// sensors (CFwMD): the mask, then 4 f64.
    ActivateFeedback = 11, "activate_feedback";
    /// The same with the estimate's covariance (CFwMD2): the mask, 4 f64,
    /// then the 10 of the upper triangle.
    ActivateFeedbackCovariance = 12, "activate_feedback_covariance";
    /// One round of KL fusion (the random-exchange paper): a Gaussian posterior in
    /// information form, η (4) and Λ (10).
    KlConsensus = 13, "kl_consensus";
    /// Random exchange (the random-exchange paper): a node asks a neighbour to swap
    /// posteriors. No body.
    ExchangeRequest = 14, "exchange_request";
    /// The neighbour's answer: 1 (accepted) or 0 (already paired).
    ExchangeReply = 15, "exchange_reply";
    /// A posterior swapped in a random exchange: mean (4), covariance (10).
    ExchangePosterior = 16, "exchange_posterior";
    /// A node relays its own sensor's measurement to its neighbours, so
    /// that each assimilates its closed neighbourhood's: sensor, value.
    NeighbourObservation = 17, "neighbour_observation";
    /// One consensus round whose sender also carries information about the
    /// step before, from observations that arrived after it closed: the 24
    /// of [`Consensus`](Self::Consensus), then ΔL_late (10). Sent instead
    /// of a `Consensus` only while that part is not zero, so it costs bytes
    /// only on the steps that have late observations.
    ConsensusLate = 18, "consensus_late";
    /// An activation that carries the quantizer the node designed for its
    /// sensors (a static target's locator): the mask, the count of
    /// thresholds (one byte), then the thresholds, increasing.
    ActivateThresholds = 19, "activate_thresholds";
    /// One piece of a locator's consensus value, which is longer than one
    /// message: the piece's index (u16), then [`LOCATION_CHUNK`](crate::LOCATION_CHUNK) f64.
    LocationConsensus = 20, "location_consensus";
    /// A fusion centre's schedule of its multiple-access channel: the
    /// slots of the step (one byte), the count of transmitting sensors
    /// (u16), then for each its place in the node's list (u16) and its
    /// column of Φ as two u32 masks, the slots it transmits in and those
    /// where it transmits its value negated.
    ActivateSlots = 21, "activate_slots";
    /// A sensor's transmissions on a multiple-access channel: the mask of
    /// its slots (u32), then the value it sent in each, f64.
    SlotValues = 22, "slot_values";
    /// What a multiple-access channel received in each slot: the count
    /// (one byte), then the sums with the receiver's noise, f64.
    MacOutput = 23, "mac_output";
    /// Sensor selection's gather: one piece of what a node sends its parent
    /// in the spanning tree, its own candidates' and its subtree's. The
    /// parent it is for (u16), the piece's place in the sender's report
    /// (u16), the report's count of pieces on its last piece and 0 before
    /// (u16), whose candidates (u16), the first one's place in that node's
    /// list (u16), the count (one byte), then each candidate's `J̄`
    /// position block, xx, xy, yy (3 f64).
    SelectionReport = 24, "selection_report";
    /// Sensor selection's choice, sent down the spanning tree: the piece
    /// and count of pieces (u16 each), the sensors chosen network-wide
    /// (u16), their `Σ J̄` position block (3 f64), the count in this piece
    /// (one byte), then the chosen sensors, increasing (u16 each).
    SelectionChoice = 25, "selection_choice";
}

#[cfg(test)]
mod tests {
    use super::MessageKind;

    #[test]
    fn every_byte_a_kind_reads_is_the_byte_it_writes_and_names_are_distinct() {
        let kinds: Vec<MessageKind> = (0..=u8::MAX).filter_map(MessageKind::from_u8).collect();
        for k in &kinds {
            assert_eq!(MessageKind::from_u8(k.code()), Some(*k));
        }
        let mut names: Vec<&str> = kinds.iter().map(|k| k.name()).collect();
        names.push(MessageKind::Malformed.name());
        let count = names.len();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), count, "two kinds share a name");
        assert!(kinds.len() >= 23, "the built-in kinds are readable");
        assert_eq!(MessageKind::from_u8(0), None);
        assert_eq!(
            MessageKind::from_u8(255),
            None,
            "malformed is never on the wire"
        );
    }
}
