//! A multiple-access channel between sensors and their fusion centre: the
//! centre's schedule of the slots (each transmitting sensor's column of
//! the sensing matrix), a sensor's transmissions, and what the channel
//! received in each slot.

use super::super::codec::{byte_at, count_within, exact_len, finite_values, put, put_all, u16_at};
use super::super::Payload;
use crate::WireError;

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

/// The most slots of a multiple-access channel: a column is a 32-bit mask.
pub const MAX_SLOTS: usize = 32;

pub(in crate::message) fn encode_schedule(slots: u8, columns: &[SlotColumn], out: &mut Vec<u8>) {
    out.push(slots);
    put(&(columns.len() as u16), out);
    for c in columns {
        put(&c.sensor, out);
        put(&c.slots, out);
        put(&c.negative, out);
    }
}

pub(in crate::message) fn encode_transmissions(slots: u32, values: &[f64], out: &mut Vec<u8>) {
    put(&slots, out);
    put_all(values, out);
}

pub(in crate::message) fn encode_output(values: &[f64], out: &mut Vec<u8>) {
    out.push(values.len() as u8);
    put_all(values, out);
}

/// An [`ActivateSlots`](Payload::ActivateSlots) body: slots between 1 and
/// [`MAX_SLOTS`], columns of sensors in increasing order, each in some
/// slot and no other than the step's.
pub(in crate::message) fn decode_schedule(body: &[u8]) -> Result<Payload, WireError> {
    let slots = byte_at(body, 0)?;
    count_within(slots as usize, MAX_SLOTS, false)?;
    let count = u16_at(body, 1)? as usize;
    exact_len(body, 3 + SLOT_COLUMN_BYTES * count)?;
    let allowed = if slots as usize == MAX_SLOTS {
        u32::MAX
    } else {
        (1u32 << slots) - 1
    };
    let mut columns: Vec<SlotColumn> = Vec::with_capacity(count);
    for b in body[3..].chunks_exact(SLOT_COLUMN_BYTES) {
        let c = SlotColumn {
            sensor: u16::from_le_bytes([b[0], b[1]]),
            slots: u32::from_le_bytes(b[2..6].try_into().expect("4 bytes")),
            negative: u32::from_le_bytes(b[6..10].try_into().expect("4 bytes")),
        };
        let in_order = columns.last().is_none_or(|l| l.sensor < c.sensor);
        if c.slots == 0 || c.slots & !allowed != 0 || c.negative & !c.slots != 0 || !in_order {
            return Err(WireError::Unordered);
        }
        columns.push(c);
    }
    Ok(Payload::ActivateSlots { slots, columns })
}

/// A [`SlotValues`](Payload::SlotValues) body: a mask of at least one
/// slot, then a finite value for each.
pub(in crate::message) fn decode_transmissions(body: &[u8]) -> Result<Payload, WireError> {
    let slots = u32::from_le_bytes(
        body.get(..4)
            .ok_or(WireError::Truncated)?
            .try_into()
            .expect("4 bytes"),
    );
    if slots == 0 {
        return Err(WireError::Length {
            expected: 1,
            got: 0,
        });
    }
    exact_len(body, 4 + 8 * slots.count_ones() as usize)?;
    Ok(Payload::SlotValues {
        slots,
        values: finite_values(&body[4..])?,
    })
}

/// A [`MacOutput`](Payload::MacOutput) body: 1 to [`MAX_SLOTS`] finite
/// sums.
pub(in crate::message) fn decode_output(body: &[u8]) -> Result<Payload, WireError> {
    let count = count_within(byte_at(body, 0)? as usize, MAX_SLOTS, false)?;
    exact_len(body, 1 + 8 * count)?;
    Ok(Payload::MacOutput {
        values: finite_values(&body[1..])?,
    })
}
