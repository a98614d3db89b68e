//! The random-exchange paper's trackers: KL fusion's rounds on a Gaussian
//! in information form, random exchange's request, reply and swapped
//! posterior, and the measurements a node relays to its neighbours.

use serde::{Deserialize, Serialize};

use super::super::codec::{exact_len, finite, take};
use super::super::Payload;
use super::Packed;
use crate::WireError;

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

pub(in crate::message) fn decode_kl(body: &[u8]) -> Result<Payload, WireError> {
    let g: GaussianInformation = take(body)?;
    finite(g.eta)?;
    finite(g.lambda)?;
    Ok(Payload::KlConsensus(g))
}

pub(in crate::message) fn decode_request(body: &[u8]) -> Result<Payload, WireError> {
    exact_len(body, 0)?;
    Ok(Payload::ExchangeRequest)
}

/// One byte, 1 (accepted) or 0 (already paired), nothing else.
pub(in crate::message) fn decode_reply(body: &[u8]) -> Result<Payload, WireError> {
    exact_len(body, 1)?;
    Ok(Payload::ExchangeReply {
        accepted: match body[0] {
            0 => false,
            1 => true,
            got => return Err(WireError::Flag { got }),
        },
    })
}

pub(in crate::message) fn decode_posterior(body: &[u8]) -> Result<Payload, WireError> {
    let g: GaussianMoments = take(body)?;
    finite(g.mean)?;
    finite(g.covariance)?;
    Ok(Payload::ExchangePosterior(g))
}

pub(in crate::message) fn decode_relay(body: &[u8]) -> Result<Payload, WireError> {
    let (sensor, value): (u16, f64) = take(body)?;
    Ok(Payload::NeighbourObservation {
        sensor,
        value: finite([value])?[0],
    })
}
