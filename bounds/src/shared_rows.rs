//! The tables' rows in memory that several processes map: each row built
//! once by whichever process first needs it, read by the others.
//!
//! Why: the likelihood and Fisher tables build their rows on first use
//! ([`LazyRows`]). In `cqnet sim` one process builds each row
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
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::OnceLock;
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

pub(crate) use kept_by_reference;

const EMPTY: u32 = 0;
const BUILDING: u32 = 1;
const READY: u32 = 2;

/// How long a process waits for a row another process is building before
/// it builds its own copy. A row takes well under a millisecond to build.
const WAIT_FOR_BUILDER: Duration = Duration::from_millis(2);

/// Offsets are kept to cache lines, so that no row shares a line with a
/// state word that others write.
pub(crate) const LINE: usize = 64;

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
    pub(crate) unsafe fn at(base: *mut u8) -> Self {
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

/// One value per row of the axis, each built on first use, so that a
/// process pays only for the range of σ/Δ it meets. A fixed length, so
/// that indexing a stencil's rows needs no check. The rows are this
/// process's own, or live in memory that several processes share
/// ([`crate::shared_rows`]); the lookups read them alike.
pub struct LazyRows<T: PlainRow> {
    rows: Box<[OnceLock<T::Kept>; ROWS]>,
    shared: OnceLock<SharedRows<T>>,
}

impl<T: PlainRow> LazyRows<T> {
    pub fn new() -> Self {
        Self {
            rows: Box::new(std::array::from_fn(|_| OnceLock::new())),
            shared: OnceLock::new(),
        }
    }

    /// Row `row`, built by `build(row)` if it is not yet. The fast path (an
    /// acquire load) is inlined into the lookups; the build is not.
    #[inline(always)]
    pub fn get(&self, row: usize, build: impl FnOnce(usize) -> T) -> &T {
        match self.rows[row].get() {
            Some(kept) => T::kept(kept),
            None => self.build(row, build),
        }
    }

    /// From now on, rows not built yet come from (or go to) `shared`.
    /// Returns false if the rows were shared already.
    pub fn share(&self, shared: SharedRows<T>) -> bool {
        self.shared.set(shared).is_ok()
    }

    /// A row lives as long as the process: the tables are process-wide,
    /// and a row in shared memory is never unmapped.
    #[cold]
    #[inline(never)]
    fn build(&self, row: usize, build: impl FnOnce(usize) -> T) -> &T {
        let kept = self.rows[row].get_or_init(|| {
            T::keep(match self.shared.get() {
                Some(shared) => shared.get_or_build(row, build),
                None => Box::leak(Box::new(build(row))),
            })
        });
        T::kept(kept)
    }
}

impl<T: PlainRow> Default for LazyRows<T> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::line_aligned_memory as memory;
    use std::sync::atomic::AtomicUsize;

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
}
