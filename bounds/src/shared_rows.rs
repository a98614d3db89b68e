//! The tables' rows in memory that several processes map: each row built
//! once by whichever process first needs it, read by the others.
//!
//! Why: the likelihood and Fisher tables build their rows on first use
//! (`width_axis::LazyRows`). In `cqnet sim` one process builds each row
//! once; in `cqnet run` every node process built every row it met, nine
//! times over, and kept its own copy of the same numbers: 125 million of a
//! node's 1,075 million instructions in a 200-step run (callgrind).
//!
//! The memory is mapped by the caller (this crate does no I/O) and starts
//! zeroed. Its layout: a header word, then per table a state word for each
//! row and the rows themselves. A row is claimed by a compare-and-swap of
//! its state from empty to building; its builder writes it and then marks
//! it ready with a release store, and readers take it only after an
//! acquire load sees it ready. So a row is read only once whole, and
//! never written again. A process that finds a row being built waits for
//! it a little, yielding, and builds a private copy if it is not done: a
//! builder killed halfway (the fault injector kills nodes) leaves its row
//! claimed for good, and the others must not wait on it forever. Every
//! process computes a row with the same code, so a row is the same to the
//! bit whoever built it.

use std::marker::PhantomData;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::width_axis::ROWS;

/// A row type that may live in shared memory: numbers only, no pointer
/// and nothing to drop, laid out alike in every process of one build.
///
/// # Safety
/// The type must be plain data: every field a number or an array of them.
pub unsafe trait PlainRow: Copy + Send + Sync + 'static {
    /// How a process keeps a row once it has it: a reference to the one
    /// copy (a large row, whose one copy the processes' caches share), or
    /// the row itself (a few numbers, read without following a pointer).
    type Kept: Send + Sync + 'static;
    fn keep(row: &'static Self) -> Self::Kept;
    fn kept(kept: &Self::Kept) -> &Self;
}

/// Rows kept by reference.
macro_rules! kept_by_reference {
    ($($row:ty),*) => {$(
        // SAFETY: arrays of f64.
        unsafe impl PlainRow for $row {
            type Kept = &'static Self;
            #[inline(always)]
            fn keep(row: &'static Self) -> Self::Kept {
                row
            }
            #[inline(always)]
            fn kept(kept: &Self::Kept) -> &Self {
                kept
            }
        }
    )*};
}

kept_by_reference!(crate::mass_table::MassRow, crate::fisher_table::Grid);

// SAFETY: three f64.
unsafe impl PlainRow for crate::fisher_table::Means {
    type Kept = Self;
    #[inline(always)]
    fn keep(row: &'static Self) -> Self::Kept {
        *row
    }
    #[inline(always)]
    fn kept(kept: &Self::Kept) -> &Self {
        kept
    }
}

const EMPTY: u32 = 0;
const BUILDING: u32 = 1;
const READY: u32 = 2;

/// How long a process waits for a row another process is building before
/// it builds its own copy. A row takes well under a millisecond to build.
const WAIT_FOR_BUILDER: Duration = Duration::from_millis(2);

/// Offsets are kept to cache lines, so that no row shares a line with a
/// state word that others write.
const LINE: usize = 64;

const fn round_up(n: usize) -> usize {
    n.div_ceil(LINE) * LINE
}

/// The rows of one table in shared memory: `ROWS` state words, then
/// `ROWS` slots.
pub struct SharedRows<T: PlainRow> {
    states: *const AtomicU32,
    slots: *mut T,
    _rows: PhantomData<T>,
}

// SAFETY: the memory is only touched through atomics, or by the one
// process that claimed a slot, or read once the slot is ready.
unsafe impl<T: PlainRow> Send for SharedRows<T> {}
// SAFETY: as above.
unsafe impl<T: PlainRow> Sync for SharedRows<T> {}

impl<T: PlainRow> SharedRows<T> {
    /// Bytes one table takes.
    pub const BYTES: usize =
        round_up(round_up(ROWS * size_of::<AtomicU32>()) + ROWS * size_of::<T>());

    /// # Safety
    /// `base` is aligned to a cache line, valid for [`Self::BYTES`] bytes for
    /// the rest of the process, zeroed or written only by `SharedRows<T>`
    /// of this build, and touched by nothing else.
    unsafe fn at(base: *mut u8) -> Self {
        const { assert!(align_of::<T>() <= LINE) };
        Self {
            states: base.cast(),
            slots: base.add(round_up(ROWS * size_of::<AtomicU32>())).cast(),
            _rows: PhantomData,
        }
    }

    fn state(&self, row: usize) -> &AtomicU32 {
        assert!(row < ROWS);
        // SAFETY: within the state words, which live as long as the process.
        unsafe { &*self.states.add(row) }
    }

    /// Row `row`: the shared one if it is (or becomes) ready, else a copy
    /// built here and kept for the rest of the process.
    pub fn get_or_build(&self, row: usize, build: impl FnOnce(usize) -> T) -> &'static T {
        let state = self.state(row);
        let claimed = state
            .compare_exchange(EMPTY, BUILDING, Ordering::AcqRel, Ordering::Acquire)
            .is_ok();
        if claimed {
            let value = build(row);
            // SAFETY: this process claimed the slot; no one reads it until
            // the release store below.
            unsafe { self.slots.add(row).write(value) };
            state.store(READY, Ordering::Release);
            return self.ready(row);
        }
        let started = Instant::now();
        while started.elapsed() < WAIT_FOR_BUILDER {
            if state.load(Ordering::Acquire) == READY {
                return self.ready(row);
            }
            std::thread::yield_now();
        }
        Box::leak(Box::new(build(row)))
    }

    fn ready(&self, row: usize) -> &'static T {
        debug_assert_eq!(self.state(row).load(Ordering::Relaxed), READY);
        // SAFETY: the slot is ready, so whole and never written again, and
        // the memory lives as long as the process.
        unsafe { &*self.slots.add(row) }
    }
}

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
    let sizes = (size_of::<crate::mass_table::MassRow>() as u64)
        ^ (size_of::<crate::fisher_table::Means>() as u64) << 16
        ^ (size_of::<crate::fisher_table::Grid>() as u64) << 32;
    0xC0DE_0000_0000_0000 ^ sizes ^ (ROWS as u64) << 48
}

/// Bytes that [`share_table_rows`] needs.
pub const fn shared_table_bytes() -> usize {
    LINE + SharedRows::<crate::mass_table::MassRow>::BYTES
        + SharedRows::<crate::fisher_table::Means>::BYTES
        + SharedRows::<crate::fisher_table::Grid>::BYTES
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
        let mass = SharedRows::at(next(SharedRows::<crate::mass_table::MassRow>::BYTES));
        let means = SharedRows::at(next(SharedRows::<crate::fisher_table::Means>::BYTES));
        let grids = SharedRows::at(next(SharedRows::<crate::fisher_table::Grid>::BYTES));
        crate::mass_table::table().share(mass);
        crate::fisher_table::table().share(means, grids);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::width_axis::LazyRows;
    use std::alloc::{alloc_zeroed, Layout};
    use std::sync::atomic::AtomicUsize;

    /// Zeroed, line-aligned memory that lives as long as the test process,
    /// as a mapping does.
    fn memory(bytes: usize) -> *mut u8 {
        let layout = Layout::from_size_align(bytes, LINE).unwrap();
        // SAFETY: a non-zero size; never freed, like a mapping kept for good.
        let p = unsafe { alloc_zeroed(layout) };
        assert!(!p.is_null());
        p
    }

    type Row = [f64; 5];
    kept_by_reference!(Row);

    fn row_value(row: usize) -> Row {
        std::array::from_fn(|k| (row * 10 + k) as f64 / 3.0)
    }

    /// Two processes' tables over one piece of memory: the second reads the
    /// row the first built, in place, and never builds it.
    #[test]
    fn two_tables_on_one_memory_build_each_row_once() {
        let base = memory(SharedRows::<Row>::BYTES);
        let (a, b) = (LazyRows::<Row>::new(), LazyRows::<Row>::new());
        // SAFETY: zeroed, aligned, kept, and used only by these tables.
        unsafe {
            assert!(a.share(SharedRows::at(base)));
            assert!(b.share(SharedRows::at(base)));
        }
        let builds = AtomicUsize::new(0);
        let build = |row| {
            builds.fetch_add(1, Ordering::Relaxed);
            row_value(row)
        };
        let from_a = a.get(17, build) as *const Row;
        let from_b = b.get(17, |_| panic!("the row was built already")) as *const Row;
        assert_eq!(from_a, from_b, "both read the one row in shared memory");
        assert!(
            (base as usize..base as usize + SharedRows::<Row>::BYTES).contains(&(from_a as usize))
        );
        assert_eq!(b.get(17, build), &row_value(17));
        assert_eq!(builds.load(Ordering::Relaxed), 1);
        // Another row, first wanted by the second table.
        assert_eq!(b.get(ROWS - 1, build), &row_value(ROWS - 1));
        assert_eq!(
            a.get(ROWS - 1, |_| panic!("built already")),
            &row_value(ROWS - 1)
        );
        assert_eq!(builds.load(Ordering::Relaxed), 2);
    }

    /// A row whose builder died halfway stays claimed: the next process
    /// waits a little, then builds its own copy, with the same numbers.
    #[test]
    fn a_row_claimed_by_a_dead_builder_is_built_here() {
        let base = memory(SharedRows::<Row>::BYTES);
        // SAFETY: as above.
        let shared = unsafe { SharedRows::<Row>::at(base) };
        shared.state(3).store(BUILDING, Ordering::Release);
        let t = LazyRows::<Row>::new();
        // SAFETY: as above.
        unsafe { t.share(SharedRows::at(base)) };
        let started = Instant::now();
        let got = t.get(3, row_value) as *const Row;
        assert!(started.elapsed() >= WAIT_FOR_BUILDER);
        assert!(
            !(base as usize..base as usize + SharedRows::<Row>::BYTES).contains(&(got as usize))
        );
        // SAFETY: a row of the table, kept for good.
        assert_eq!(unsafe { *got }, row_value(3));
        assert_eq!(shared.state(3).load(Ordering::Acquire), BUILDING);
    }

    /// Rows wanted side by side by several threads (as processes would):
    /// each is built into the shared memory once, and every reader sees it
    /// whole. A reader that gave up waiting (its builder descheduled past
    /// the wait, on a loaded machine) built a private copy, counted apart.
    #[test]
    fn racing_builders_build_each_shared_row_once() {
        let base = memory(SharedRows::<Row>::BYTES) as usize;
        let inside =
            |p: *const Row| (base..base + SharedRows::<Row>::BYTES).contains(&(p as usize));
        let (builds, private) = (AtomicUsize::new(0), AtomicUsize::new(0));
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    let t = LazyRows::<Row>::new();
                    // SAFETY: as above.
                    unsafe { t.share(SharedRows::at(base as *mut u8)) };
                    for row in (0..ROWS).step_by(7) {
                        let got = t.get(row, |row| {
                            builds.fetch_add(1, Ordering::Relaxed);
                            row_value(row)
                        });
                        assert_eq!(got, &row_value(row));
                        if !inside(got) {
                            private.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                });
            }
        });
        let rows = ROWS.div_ceil(7);
        assert_eq!(
            builds.load(Ordering::Relaxed),
            rows + private.load(Ordering::Relaxed)
        );
        // SAFETY: as above.
        let shared = unsafe { SharedRows::<Row>::at(base as *mut u8) };
        for row in 0..ROWS {
            let want = if row % 7 == 0 { READY } else { EMPTY };
            assert_eq!(shared.state(row).load(Ordering::Acquire), want, "row {row}");
        }
    }

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
