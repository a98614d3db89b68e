//! Sensor selection negotiated over a spanning tree: the reports that
//! gather the candidates' information up the tree, and the choice sent
//! back down. Both travel in pieces, each within the consensus channel's
//! room.

use super::super::codec::{
    byte_at, count_within, exact_len, finite, finite_values, put, put_all, take, u16_at,
};
use super::super::Payload;
use crate::WireError;

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

pub(in crate::message) fn encode_report(r: &CandidateReport, out: &mut Vec<u8>) {
    put_all(&[r.to, r.part, r.parts, r.node, r.first], out);
    out.push(r.information.len() as u8);
    put_all(r.information.iter().flatten(), out);
}

pub(in crate::message) fn encode_choice(c: &ChosenSensors, out: &mut Vec<u8>) {
    put_all(&[c.part, c.parts, c.total], out);
    put(&c.sum, out);
    out.push(c.sensors.len() as u8);
    put_all(&c.sensors, out);
}

/// A [`SelectionReport`](Payload::SelectionReport) body: at most
/// [`MAX_REPORTED_CANDIDATES`] finite blocks, each with non-negative
/// diagonal (a Fisher information is positive semi-definite).
pub(in crate::message) fn decode_report(body: &[u8]) -> Result<Payload, WireError> {
    let (to, part, parts) = (u16_at(body, 0)?, u16_at(body, 2)?, u16_at(body, 4)?);
    let (node, first) = (u16_at(body, 6)?, u16_at(body, 8)?);
    // The last piece says the count; earlier pieces say 0.
    if parts != 0 && part >= parts {
        return Err(WireError::Unordered);
    }
    let count = count_within(byte_at(body, 10)? as usize, MAX_REPORTED_CANDIDATES, true)?;
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
pub(in crate::message) fn decode_choice(body: &[u8]) -> Result<Payload, WireError> {
    let (part, parts, total) = (u16_at(body, 0)?, u16_at(body, 2)?, u16_at(body, 4)?);
    // Every piece of a choice says the count: it is known before any is sent.
    if part >= parts {
        return Err(WireError::Unordered);
    }
    let sum: [f64; 3] = finite(take(body.get(6..30).ok_or(WireError::Truncated)?)?)?;
    let count = count_within(
        byte_at(body, 30)? as usize,
        MAX_CHOSEN_PER_PIECE.min(total as usize),
        true,
    )?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::message::tests::FORMAT;
    use crate::{ActorId, Message, HEADER_BYTES};

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
}
