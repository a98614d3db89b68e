//! Between a node and its sensors: the activations (a mask of the node's
//! sensors, with the node's feedback for censoring sensors or the
//! quantizer it designed) and the observations (a cell, or a raw value).

use serde::{Deserialize, Serialize};

use super::super::codec::{byte_at, count_within, exact_len, finite, put, put_all, put_mask, take};
use super::super::{MessageKind, Payload, WireFormat};
use super::Packed;
use crate::WireError;

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

/// The most thresholds an activation carries: a 4-bit quantizer's.
pub const MAX_THRESHOLDS: usize = 15;

pub(in crate::message) fn encode_feedback(
    mask: &BitMask,
    estimate: &[f64; 4],
    covariance: Option<&Packed>,
    format: &WireFormat,
    out: &mut Vec<u8>,
) {
    put_mask(mask, format, out);
    put(estimate, out);
    if let Some(c) = covariance {
        put(c, out);
    }
}

pub(in crate::message) fn encode_thresholds(
    mask: &BitMask,
    thresholds: &[f64],
    format: &WireFormat,
    out: &mut Vec<u8>,
) {
    put_mask(mask, format, out);
    out.push(thresholds.len() as u8);
    put_all(thresholds, out);
}

pub(in crate::message) fn decode_activate(
    body: &[u8],
    format: &WireFormat,
) -> Result<Payload, WireError> {
    exact_len(body, format.activation_bytes)?;
    Ok(Payload::Activate {
        mask: BitMask::from_bytes(body.to_vec()),
    })
}

/// A [`MessageKind::ActivateFeedback`] or
/// [`MessageKind::ActivateFeedbackCovariance`] body: the mask, the
/// estimate, and with the second its covariance, all finite.
pub(in crate::message) fn decode_feedback(
    body: &[u8],
    kind: MessageKind,
    format: &WireFormat,
) -> Result<Payload, WireError> {
    let with_covariance = kind == MessageKind::ActivateFeedbackCovariance;
    let mask_len = format.activation_bytes;
    exact_len(body, mask_len + 32 + if with_covariance { 80 } else { 0 })?;
    let estimate: [f64; 4] = finite(take(&body[mask_len..mask_len + 32])?)?;
    let covariance = if with_covariance {
        Some(finite(take(&body[mask_len + 32..])?)?)
    } else {
        None
    };
    Ok(Payload::ActivateWithFeedback {
        mask: BitMask::from_bytes(body[..mask_len].to_vec()),
        estimate,
        covariance,
    })
}

/// A cell index in the scenario's `ceil(N_L/8)` bytes.
pub(in crate::message) fn decode_observation(
    body: &[u8],
    format: &WireFormat,
) -> Result<Payload, WireError> {
    exact_len(body, format.cell_bytes)?;
    let mut le = [0u8; 4];
    le[..body.len()].copy_from_slice(body);
    Ok(Payload::Observation {
        cell: u32::from_le_bytes(le),
    })
}

pub(in crate::message) fn decode_raw(body: &[u8]) -> Result<Payload, WireError> {
    let v: f64 = take(body)?;
    Ok(Payload::RawObservation {
        value: finite([v])?[0],
    })
}

/// A [`MessageKind::ActivateThresholds`] body: the mask, then 1 to
/// [`MAX_THRESHOLDS`] finite thresholds, increasing.
pub(in crate::message) fn decode_thresholds(
    body: &[u8],
    format: &WireFormat,
) -> Result<Payload, WireError> {
    let mask_len = format.activation_bytes;
    let count = count_within(byte_at(body, mask_len)? as usize, MAX_THRESHOLDS, false)?;
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
    Ok(Payload::ActivateThresholds {
        mask: BitMask::from_bytes(body[..mask_len].to_vec()),
        thresholds,
    })
}

#[cfg(test)]
mod tests {
    use super::BitMask;

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
}
