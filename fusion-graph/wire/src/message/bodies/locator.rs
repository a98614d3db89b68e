//! A static target's locator: its consensus value is longer than one
//! message, so it travels in numbered pieces.

use super::super::codec::{exact_len, finite, put, put_all};
use super::super::Payload;
use crate::WireError;

/// The numbers in one piece of a locator's consensus value.
pub const LOCATION_CHUNK: usize = 32;

pub(in crate::message) fn encode_piece(
    chunk: u16,
    values: &[f64; LOCATION_CHUNK],
    out: &mut Vec<u8>,
) {
    put(&chunk, out);
    put_all(values, out);
}

pub(in crate::message) fn decode_piece(body: &[u8]) -> Result<Payload, WireError> {
    exact_len(body, 2 + 8 * LOCATION_CHUNK)?;
    let chunk = u16::from_le_bytes([body[0], body[1]]);
    let mut values = [0.0; LOCATION_CHUNK];
    for (v, b) in values.iter_mut().zip(body[2..].chunks_exact(8)) {
        *v = f64::from_le_bytes(b.try_into().expect("8 bytes"));
    }
    Ok(Payload::LocationConsensus {
        chunk,
        values: finite(values)?,
    })
}
