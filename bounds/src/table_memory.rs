//! The one file of memory a run's node processes share for their tables'
//! rows: a header naming this build's layout, then the likelihood table's
//! rows, the Fisher table's means and its grids ([`crate::shared_rows`]
//! holds each). Whichever process first needs a row builds it there.

use std::sync::atomic::{AtomicU64, Ordering};

use crate::fisher_table::{Grid, Means};
use crate::mass_table::MassRow;
use crate::shared_rows::{SharedRows, LINE};
use crate::width_axis::ROWS;

/// What goes wrong in sharing the tables' rows.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ShareError {
    #[error("shared table memory of {got} bytes; the tables need {need}")]
    TooSmall { got: usize, need: usize },
    #[error("shared table memory is not aligned to {LINE} bytes")]
    Misaligned,
    #[error("shared table memory holds another build's layout (header {found:#x}, this build's {expected:#x})")]
    OtherLayout { found: u64, expected: u64 },
}

/// The header: a constant and this build's row sizes, so that a process of
/// another build (another row layout) finds a mismatch, not wrong rows.
fn layout_word() -> u64 {
    let sizes = (size_of::<MassRow>() as u64)
        ^ (size_of::<Means>() as u64) << 16
        ^ (size_of::<Grid>() as u64) << 32;
    0xC0DE_0000_0000_0000 ^ sizes ^ (ROWS as u64) << 48
}

/// Bytes that [`share_table_rows`] needs.
pub const fn shared_table_bytes() -> usize {
    LINE + SharedRows::<MassRow>::BYTES + SharedRows::<Means>::BYTES + SharedRows::<Grid>::BYTES
}

/// Puts the rows of this process's likelihood and Fisher tables in
/// `memory`, which other processes map too. Rows built before the call
/// stay this process's own; every later one is shared.
///
/// # Safety
/// `memory` must stay mapped for the rest of the process, start zeroed,
/// and be written only through this function's tables, in this process
/// and in every other that maps it.
pub unsafe fn share_table_rows(memory: *mut u8, len: usize) -> Result<(), ShareError> {
    let need = shared_table_bytes();
    if len < need {
        return Err(ShareError::TooSmall { got: len, need });
    }
    if !(memory as usize).is_multiple_of(LINE) {
        return Err(ShareError::Misaligned);
    }
    let expected = layout_word();
    // SAFETY: aligned, within `memory`, and only ever touched atomically.
    let header = unsafe { &*memory.cast::<AtomicU64>() };
    match header.compare_exchange(0, expected, Ordering::AcqRel, Ordering::Acquire) {
        Ok(_) => {}
        Err(found) if found == expected => {}
        Err(found) => return Err(ShareError::OtherLayout { found, expected }),
    }
    let mut at = LINE;
    let mut next = |bytes: usize| {
        // SAFETY: the regions tile `memory`, each at a multiple of LINE.
        let base = unsafe { memory.add(at) };
        at += bytes;
        base
    };
    // SAFETY: each region is within `memory`, line-aligned, and the
    // caller's promise covers the rest.
    unsafe {
        let mass = SharedRows::at(next(SharedRows::<MassRow>::BYTES));
        let means = SharedRows::at(next(SharedRows::<Means>::BYTES));
        let grids = SharedRows::at(next(SharedRows::<Grid>::BYTES));
        crate::mass_table::table().share(mass);
        crate::fisher_table::table().share(means, grids);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::line_aligned_memory as memory;

    #[test]
    fn memory_too_small_misaligned_or_of_another_layout_is_refused() {
        let need = shared_table_bytes();
        let base = memory(need + LINE);
        // SAFETY: each call is refused before it touches the tables.
        unsafe {
            assert_eq!(
                share_table_rows(base, need - 1),
                Err(ShareError::TooSmall {
                    got: need - 1,
                    need
                })
            );
            assert_eq!(
                share_table_rows(base.add(8), need),
                Err(ShareError::Misaligned)
            );
            (*base.cast::<AtomicU64>()).store(0xBAD, Ordering::Relaxed);
            assert_eq!(
                share_table_rows(base, need),
                Err(ShareError::OtherLayout {
                    found: 0xBAD,
                    expected: layout_word()
                })
            );
        }
    }
}
