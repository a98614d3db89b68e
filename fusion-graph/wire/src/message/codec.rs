//! The pieces every body's encoding is made of: bincode with fixed-width
//! little-endian integers, so that a message's size depends only on its
//! kind (and the scenario), never on its values; and the checks that make
//! decoding trust nothing.

use bincode::config::{Configuration, Fixint, Limit, LittleEndian};
use serde::{Deserialize, Serialize};

use super::{BitMask, WireFormat, MAX_MESSAGE_BYTES};
use crate::WireError;

type Config = Configuration<LittleEndian, Fixint, Limit<MAX_MESSAGE_BYTES>>;

pub(super) fn config() -> Config {
    bincode::config::standard()
        .with_little_endian()
        .with_fixed_int_encoding()
        .with_limit::<MAX_MESSAGE_BYTES>()
}

pub(super) fn put<T: Serialize>(v: &T, out: &mut Vec<u8>) {
    bincode::serde::encode_into_std_write(v, out, config()).expect("writing to a Vec cannot fail");
}

/// Appends each of `values`.
pub(super) fn put_all<'a, T: Serialize + 'a>(
    values: impl IntoIterator<Item = &'a T>,
    out: &mut Vec<u8>,
) {
    for v in values {
        put(v, out);
    }
}

/// A node's activation mask, padded or cut to the scenario's width.
pub(super) fn put_mask(mask: &BitMask, format: &WireFormat, out: &mut Vec<u8>) {
    let bytes = mask.as_bytes();
    let n = bytes.len().min(format.activation_bytes);
    out.extend_from_slice(&bytes[..n]);
    out.resize(out.len() + format.activation_bytes - n, 0);
}

/// Decodes a whole body as one value; trailing bytes are an error.
pub(super) fn take<T: for<'de> Deserialize<'de>>(body: &[u8]) -> Result<T, WireError> {
    let (v, used) =
        bincode::serde::decode_from_slice(body, config()).map_err(|_| WireError::Truncated)?;
    if used != body.len() {
        return Err(WireError::TrailingBytes {
            extra: body.len() - used,
        });
    }
    Ok(v)
}

pub(super) fn exact_len(body: &[u8], expected: usize) -> Result<(), WireError> {
    if body.len() != expected {
        return Err(WireError::Length {
            expected,
            got: body.len(),
        });
    }
    Ok(())
}

/// A count read off the wire, refused above `most` (or at zero, unless
/// `zero` is allowed).
pub(super) fn count_within(count: usize, most: usize, zero: bool) -> Result<usize, WireError> {
    if (count == 0 && !zero) || count > most {
        return Err(WireError::Length {
            expected: most,
            got: count,
        });
    }
    Ok(count)
}

pub(super) fn finite<const N: usize>(v: [f64; N]) -> Result<[f64; N], WireError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(WireError::NonFinite)
    }
}

/// Little-endian f64s, every one finite.
pub(super) fn finite_values(body: &[u8]) -> Result<Vec<f64>, WireError> {
    let values: Vec<f64> = body
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
        .collect();
    for v in &values {
        finite([*v])?;
    }
    Ok(values)
}

pub(super) fn u16_at(body: &[u8], at: usize) -> Result<u16, WireError> {
    let b = body.get(at..at + 2).ok_or(WireError::Truncated)?;
    Ok(u16::from_le_bytes([b[0], b[1]]))
}

pub(super) fn byte_at(body: &[u8], at: usize) -> Result<u8, WireError> {
    body.get(at).copied().ok_or(WireError::Truncated)
}
