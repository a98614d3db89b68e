//! The world in memory: the target's true state of recent steps, which the
//! launcher writes and every sensor reads.
//!
//! A sensor observes the target; it is told nothing about it. So the truth
//! is not a message: the launcher (on another host, that host's agent)
//! writes each step's state into a ring of recent steps in the run's
//! shared memory, and a sensor activated for step k reads step k there.
//! `sim` keeps the same ring on its heap.
//!
//! Each slot is a sequence lock: the writer makes its sequence odd, writes
//! the step and the state, and makes it even again; a reader that sees an
//! odd sequence, or a different one after reading, reads again. So a
//! reader never takes a torn state, and a writer never waits for readers.
//! A reader asking for a step the ring no longer holds, or does not hold
//! yet, is told so ([`TruthMissing`]): never a stale value.
//!
//! Layout (little-endian u64 words, one cache line per slot):
//!
//! | word | meaning |
//! |---|---|
//! | 0 | magic `CQWRLD01` |
//! | 1 | capacity (slots) |
//! | 2 | the latest step written |
//! | 3–7 | reserved |
//! | 8 + 8·i | slot i: sequence, step, the state's four components (f64 bits), two reserved |

use std::sync::atomic::{fence, AtomicU64, Ordering};
use std::sync::Arc;

use bounds::State;

use fusion_graph::channel::RunId;
use fusion_graph::world::{TruthMissing, WorldView};

const MAGIC: u64 = u64::from_le_bytes(*b"CQWRLD01");
const HEADER_WORDS: usize = 8;
const SLOT_WORDS: usize = 8;
const CAPACITY_AT: usize = 1;
const LATEST_AT: usize = 2;
/// The name of the ring's file among the run's shared memory.
const FILE_NAME: &str = "world";

/// Steps the ring holds. A sensor reads the step of the activation it
/// handles; activations queue at most `QUEUE_DEPTH` (64) deep, so a sensor
/// stopped by SIGSTOP and continued reads steps up to that far back, with
/// room to spare.
pub const WORLD_STEPS: usize = 1024;

/// How many times a reader retries a slot that a writer is in the middle
/// of, yielding between tries, before it gives up: a writer killed
/// mid-write leaves the slot odd for good, and a sensor must not hang.
const TORN_RETRIES: u32 = 10_000;

/// The words a ring lives in: a shared file or, for `sim`, the heap.
enum Words {
    Shared(memmap2::MmapMut),
    SharedReadOnly(memmap2::Mmap),
    Heap(Arc<[AtomicU64]>),
}

impl Words {
    fn as_slice(&self) -> &[AtomicU64] {
        let (start, len) = match self {
            Words::Shared(m) => (m.as_ptr(), m.len()),
            Words::SharedReadOnly(m) => (m.as_ptr(), m.len()),
            Words::Heap(words) => return words,
        };
        // SAFETY: a mapping is page-aligned, its length is a whole number
        // of words (checked when it was opened), it lives as long as
        // `self`, and every access to it goes through these atomics.
        // Atomic loads of a read-only mapping are plain loads on the
        // platforms we build for.
        unsafe { std::slice::from_raw_parts(start.cast::<AtomicU64>(), len / 8) }
    }
}

fn words_for(capacity: usize) -> usize {
    HEADER_WORDS + capacity * SLOT_WORDS
}

/// The writer's side: one per run and host.
pub struct TruthRing {
    words: Words,
    capacity: usize,
}

impl TruthRing {
    /// A ring of `capacity` steps on the heap, for a network in one
    /// process, and its reader.
    pub fn on_heap(capacity: usize) -> (Self, TruthReader) {
        let words: Arc<[AtomicU64]> = (0..words_for(capacity))
            .map(|_| AtomicU64::new(0))
            .collect();
        let reader = TruthReader {
            words: Words::Heap(words.clone()),
            capacity,
        };
        let ring = Self {
            words: Words::Heap(words),
            capacity,
        };
        ring.init();
        (ring, reader)
    }

    /// Creates (or takes over, zeroed) the ring of run `run` in shared
    /// memory, for its sensors to map with [`TruthReader::open`].
    pub fn create(run: &RunId) -> std::io::Result<Self> {
        let len = words_for(WORLD_STEPS) * 8;
        let mut map = crate::iceoryx::map_run_memory(run, FILE_NAME, len)?;
        map.fill(0);
        let ring = Self {
            words: Words::Shared(map),
            capacity: WORLD_STEPS,
        };
        ring.init();
        Ok(ring)
    }

    fn init(&self) {
        let w = self.words.as_slice();
        w[CAPACITY_AT].store(self.capacity as u64, Ordering::Relaxed);
        w[0].store(MAGIC, Ordering::Release);
    }

    /// Writes the truth of `step`, over the slot of step `step − capacity`.
    pub fn write(&self, step: u32, state: &State) {
        let w = self.words.as_slice();
        let slot = slot_at(step, self.capacity);
        // Even at rest; a writer killed mid-write may have left it odd.
        let seq = w[slot].load(Ordering::Relaxed) | 1;
        w[slot].store(seq, Ordering::Relaxed);
        // The odd sequence is seen before any word of the new state.
        fence(Ordering::Release);
        w[slot + 1].store(u64::from(step), Ordering::Relaxed);
        for (i, x) in state.iter().enumerate() {
            w[slot + 2 + i].store(x.to_bits(), Ordering::Relaxed);
        }
        w[slot].store(seq.wrapping_add(1), Ordering::Release);
        w[LATEST_AT].fetch_max(u64::from(step), Ordering::Release);
    }
}

/// A sensor's side: reads, never writes.
pub struct TruthReader {
    words: Words,
    capacity: usize,
}

impl TruthReader {
    /// Maps run `run`'s ring read-only. The launcher (or the host's agent)
    /// creates it before it starts any sensor.
    pub fn open(run: &RunId) -> std::io::Result<Self> {
        let path = crate::iceoryx::run_memory_path(run, FILE_NAME);
        let file = std::fs::File::open(&path)?;
        let len = file.metadata()?.len() as usize;
        let bad = |what: String| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("{}: {what}", path.display()),
            )
        };
        if len < HEADER_WORDS * 8 || !len.is_multiple_of(8) {
            return Err(bad(format!("{len} bytes is not a world ring")));
        }
        // SAFETY: the run's own file, which its writer never shrinks; read
        // only through atomics (see `Words::as_slice`).
        let map = unsafe { memmap2::MmapOptions::new().len(len).map(&file) }?;
        let words = Words::SharedReadOnly(map);
        let w = words.as_slice();
        if w[0].load(Ordering::Acquire) != MAGIC {
            return Err(bad("not a world ring (bad magic)".into()));
        }
        let capacity = w[CAPACITY_AT].load(Ordering::Relaxed) as usize;
        if capacity == 0 || words_for(capacity) > w.len() {
            return Err(bad(format!("a capacity of {capacity} steps does not fit")));
        }
        Ok(Self { words, capacity })
    }

    fn latest(&self) -> u32 {
        self.words.as_slice()[LATEST_AT].load(Ordering::Acquire) as u32
    }
}

impl WorldView for TruthReader {
    fn truth(&self, step: u32) -> Result<State, TruthMissing> {
        let (sequence, held, state) = self
            .read_slot(slot_at(step, self.capacity))
            .ok_or(TruthMissing::Torn { step })?;
        match (sequence, held) {
            (0, _) => Err(self.not_yet(step)),
            (_, h) if h == step => Ok(state),
            (_, h) if h < step => Err(self.not_yet(step)),
            _ => Err(TruthMissing::Overwritten {
                step,
                latest: self.latest(),
                held: self.capacity,
            }),
        }
    }
}

impl TruthReader {
    /// The slot at word `slot` as one writer left it: its sequence (0 if
    /// never written), its step and its state. `None` if a writer held it
    /// through every retry.
    fn read_slot(&self, slot: usize) -> Option<(u64, u32, State)> {
        let w = self.words.as_slice();
        for _ in 0..TORN_RETRIES {
            let before = w[slot].load(Ordering::Acquire);
            if before & 1 == 1 {
                std::thread::yield_now();
                continue;
            }
            let held = w[slot + 1].load(Ordering::Relaxed) as u32;
            let state =
                State::from_fn(|i, _| f64::from_bits(w[slot + 2 + i].load(Ordering::Relaxed)));
            // The words above are read before the sequence is read again.
            fence(Ordering::Acquire);
            if w[slot].load(Ordering::Relaxed) == before {
                return Some((before, held, state));
            }
        }
        None
    }

    fn not_yet(&self, step: u32) -> TruthMissing {
        TruthMissing::NotYetWritten {
            step,
            latest: self.latest(),
        }
    }
}

/// The first word of step `step`'s slot.
fn slot_at(step: u32, capacity: usize) -> usize {
    HEADER_WORDS + (step as usize % capacity) * SLOT_WORDS
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(step: u32) -> State {
        let s = f64::from(step);
        State::new(s, -s, 0.5 * s, 1e-3 * s)
    }

    #[test]
    fn a_step_written_is_read_back_exactly() {
        let (ring, reader) = TruthRing::on_heap(8);
        for step in 1..=5 {
            ring.write(step, &state(step));
        }
        for step in 1..=5 {
            assert_eq!(reader.truth(step), Ok(state(step)));
        }
    }

    #[test]
    fn a_step_not_written_or_overwritten_is_refused_not_stale() {
        let (ring, reader) = TruthRing::on_heap(4);
        assert_eq!(
            reader.truth(1),
            Err(TruthMissing::NotYetWritten { step: 1, latest: 0 })
        );
        for step in 1..=6 {
            ring.write(step, &state(step));
        }
        // Slot of step 7 holds step 3: older, so 7 is not written yet.
        assert_eq!(
            reader.truth(7),
            Err(TruthMissing::NotYetWritten { step: 7, latest: 6 })
        );
        // Slot of step 2 holds step 6: 2 is gone.
        assert_eq!(
            reader.truth(2),
            Err(TruthMissing::Overwritten {
                step: 2,
                latest: 6,
                held: 4
            })
        );
        assert_eq!(reader.truth(3), Ok(state(3)));
    }

    /// A reader racing a writer that rewrites the same slot sees only
    /// whole states: every state read is the one written with its step.
    #[test]
    fn a_reader_never_sees_a_torn_state() {
        let (ring, reader) = TruthRing::on_heap(1);
        let ring = Arc::new(ring);
        let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let writer = {
            let (ring, done) = (ring.clone(), done.clone());
            std::thread::spawn(move || {
                let mut step = 1u32;
                while !done.load(Ordering::Relaxed) {
                    ring.write(step, &state(step));
                    step += 1;
                }
                step
            })
        };
        // Until the reader has seen a thousand different writes come and go.
        let (mut distinct, mut last) = (0, 0);
        while distinct < 1000 {
            if let Some((sequence, held, s)) = reader.read_slot(slot_at(0, 1)) {
                if sequence != 0 {
                    assert_eq!(s, state(held), "a torn read at step {held}");
                    distinct += usize::from(held != last);
                    last = held;
                }
            }
        }
        done.store(true, Ordering::Relaxed);
        assert!(writer.join().unwrap() > 1000);
    }

    #[test]
    fn a_slot_left_mid_write_is_reported_not_waited_on_forever() {
        let (ring, reader) = TruthRing::on_heap(2);
        ring.write(1, &state(1));
        // A writer killed between its two sequence stores.
        let w = ring.words.as_slice();
        w[slot_at(1, 2)].fetch_add(1, Ordering::Relaxed);
        assert_eq!(reader.truth(1), Err(TruthMissing::Torn { step: 1 }));
    }

    #[test]
    fn a_shared_ring_is_read_by_another_mapping() {
        let run = RunId::new(&format!("world-test-{}", std::process::id())).unwrap();
        let ring = TruthRing::create(&run).unwrap();
        ring.write(3, &state(3));
        let reader = TruthReader::open(&run).unwrap();
        assert_eq!(reader.truth(3), Ok(state(3)));
        assert!(matches!(
            reader.truth(4),
            Err(TruthMissing::NotYetWritten { step: 4, latest: 3 })
        ));
        drop((ring, reader));
        std::fs::remove_file(crate::iceoryx::run_memory_path(&run, FILE_NAME)).unwrap();
    }

    #[test]
    fn a_file_that_is_not_a_ring_is_refused_by_name() {
        let run = RunId::new(&format!("world-bad-{}", std::process::id())).unwrap();
        let path = crate::iceoryx::run_memory_path(&run, FILE_NAME);
        std::fs::write(&path, [7u8; 128]).unwrap();
        let e = TruthReader::open(&run).err().unwrap();
        std::fs::remove_file(&path).unwrap();
        assert!(e.to_string().contains("bad magic"), "{e}");
        assert!(TruthReader::open(&run).is_err(), "a missing ring opened");
    }
}
