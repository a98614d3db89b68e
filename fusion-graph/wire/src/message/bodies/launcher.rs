//! Between the launcher and its actors: the launcher's control (begin a
//! step, stop, who is alive) and a node's report of its step.

use serde::{Deserialize, Serialize};

use super::super::codec::{finite, take};
use super::super::Payload;
use super::BitMask;
use crate::WireError;

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
    /// Consensus rounds of the step that ended at their deadline without
    /// a neighbour's value they awaited: the result then depends on timing.
    pub short_rounds: u16,
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
    /// How far the node still was from the neighbours it heard in its
    /// consensus's last round: the largest relative difference of their
    /// values from its own (0: agreed; the protocol's measure). `None` if
    /// its protocol has none or it heard nobody. Eight bytes either way
    /// ([`fixed_width`]), so that the report's size does not depend on
    /// what a round heard.
    #[serde(with = "fixed_width")]
    pub disagreement: Option<f64>,
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
            short_rounds: 0,
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
            disagreement: None,
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

/// A [`Payload::Telemetry`] body: every number finite, the lists within
/// their limits and the design's probabilities at most one.
pub(in crate::message) fn decode_telemetry(body: &[u8]) -> Result<Payload, WireError> {
    let t: Telemetry = take(body)?;
    finite(t.estimate)?;
    for v in [
        t.bound,
        t.local_bound,
        t.aux_bound,
        t.spread,
        t.disagreement,
    ]
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
    Ok(Payload::Telemetry(t))
}

/// An optional number in a fixed eight bytes: `None` as NaN, which no
/// report's number may be, so that a message's size depends on its kind
/// alone.
mod fixed_width {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(v.unwrap_or(f64::NAN))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
        let v = f64::deserialize(d)?;
        Ok((!v.is_nan()).then_some(v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ActorId, Message, Payload};

    /// A report is as long whether its node measured a disagreement or
    /// not, and reads back as it was.
    #[test]
    fn a_report_has_one_size_whatever_its_disagreement() {
        let format = crate::message::tests::FORMAT;
        let with = |d: Option<f64>| {
            let mut t = Telemetry::of_estimate([1.0, 2.0, 3.0, 4.0]);
            t.disagreement = d;
            Message::new(ActorId::Node(3), 5, 0, Payload::Telemetry(t))
        };
        let (none, some) = (with(None), with(Some(0.25)));
        let (a, b) = (none.to_bytes(&format), some.to_bytes(&format));
        assert_eq!(a.len(), b.len());
        assert_eq!(Message::decode(&a, &format).unwrap(), none);
        assert_eq!(Message::decode(&b, &format).unwrap(), some);
        let infinite = with(Some(f64::INFINITY)).to_bytes(&format);
        assert_eq!(
            Message::decode(&infinite, &format),
            Err(crate::WireError::NonFinite)
        );
    }
}
