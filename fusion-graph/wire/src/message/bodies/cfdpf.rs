//! The CF/DPF's messages: a consensus round's values (δη, δΛ, ΔL, and
//! ΔL_late when late observations carry information about the step
//! before), the auxiliary-FIM baseline's second consensus, and the fused
//! posterior a node hands a neighbour that rejoins.

use serde::{Deserialize, Serialize};

use super::super::codec::{finite, put, take};
use super::super::Payload;
use super::Packed;
use crate::WireError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConsensusValues {
    pub delta_eta: [f64; 4],
    pub delta_lambda: Packed,
    pub delta_l: Packed,
    /// ΔL_late, the information of late observations about the step
    /// before; present, it makes the message a
    /// [`MessageKind::ConsensusLate`](crate::MessageKind::ConsensusLate).
    #[serde(skip)]
    pub delta_l_late: Option<Packed>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateTransfer {
    pub mean: [f64; 4],
    pub covariance: Packed,
    pub information: Packed,
    pub aux_information: Packed,
}

/// The body of a [`MessageKind::Consensus`](crate::MessageKind::Consensus):
/// δη, δΛ, ΔL.
pub(in crate::message) const CONSENSUS_BYTES: usize = 8 * 24;

pub(in crate::message) fn encode_consensus(v: &ConsensusValues, out: &mut Vec<u8>) {
    put(v, out);
    if let Some(late) = &v.delta_l_late {
        put(late, out);
    }
}

/// A consensus round's values; with `late`, ΔL_late follows them.
pub(in crate::message) fn decode_consensus(body: &[u8], late: bool) -> Result<Payload, WireError> {
    if !late {
        return Ok(Payload::Consensus(consensus_values(body)?));
    }
    let split = CONSENSUS_BYTES.min(body.len());
    let mut v = consensus_values(&body[..split])?;
    v.delta_l_late = Some(finite(take(&body[split..])?)?);
    Ok(Payload::Consensus(v))
}

/// δη, δΛ and ΔL, each finite.
fn consensus_values(body: &[u8]) -> Result<ConsensusValues, WireError> {
    let v: ConsensusValues = take(body)?;
    finite(v.delta_eta)?;
    finite(v.delta_lambda)?;
    finite(v.delta_l)?;
    Ok(v)
}

pub(in crate::message) fn decode_aux(body: &[u8]) -> Result<Payload, WireError> {
    Ok(Payload::ConsensusAux {
        s_obs: finite(take(body)?)?,
    })
}

pub(in crate::message) fn decode_state_transfer(body: &[u8]) -> Result<Payload, WireError> {
    let s: StateTransfer = take(body)?;
    finite(s.mean)?;
    finite(s.covariance)?;
    finite(s.information)?;
    finite(s.aux_information)?;
    Ok(Payload::StateTransfer(s))
}
