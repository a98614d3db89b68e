//! Byte counts that survive SIGKILL: an actor's accounting mirrored,
//! counter by counter, into a memory-mapped file.
//!
//! A process killed with SIGKILL runs no more code, so counts written "at
//! the end" or "every few steps" are lost back to the last write, and a
//! restarted actor used to overwrite its predecessor's file. Stores into a
//! shared file mapping are in the page cache the moment they execute, and
//! stay there when the process dies, so a ledger updated on every send and
//! receive is exact up to the one update the kill interrupted. That one is
//! rolled back on reading, from a journal written before it.
//!
//! Layout (little-endian u64 words):
//!
//! | word | meaning |
//! |---|---|
//! | 0 | magic `CQLEDG01` |
//! | 1 | capacity (slots) |
//! | 2 | slots in use |
//! | 3 | journal: slot + 1 of the update in progress, 0 when none |
//! | 4 | journal: which counter pair (0 sent, 1 received, 2 dropped, 3 malformed, 4 duplicated) |
//! | 5, 6 | journal: that pair's messages and bytes before the update |
//! | 7 | reads of the world's truth that failed (a sensor's; see `world_memory`) |
//! | 8 + 11·i | slot i: its key, then the ten [`Counters`] fields |
//!
//! Slots are handed out densely in first-use order, so a file touches only
//! as many pages as the actor has links.

use std::collections::HashMap;
use std::fs::OpenOptions;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use memmap2::MmapMut;

use crate::counters::{kind_or_malformed, Counters, LinkKey, Links, Pair};
use wire::payloads::Payloads;
use wire::ActorId;

const MAGIC: u64 = u64::from_le_bytes(*b"CQLEDG02");
const HEADER_WORDS: usize = 8;
const SLOT_WORDS: usize = 11;
const PAIRS: usize = 5;
const CAPACITY: usize = 1;
const USED: usize = 2;
const JOURNAL_SLOT: usize = 3;
const JOURNAL_PAIR: usize = 4;
const JOURNAL_MESSAGES: usize = 5;
const JOURNAL_BYTES: usize = 6;
const WORLD_MISSES: usize = 7;

/// What went wrong opening or reading a ledger.
#[derive(Debug, thiserror::Error)]
pub enum LedgerError {
    #[error("ledger {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("ledger {path} is not a cqnet ledger or is damaged: {what}")]
    Damaged { path: String, what: String },
    #[error("ledger {path} is full ({capacity} links)")]
    Full { path: String, capacity: usize },
}

/// An actor's counters in a shared file mapping, written on every update.
#[derive(Debug)]
pub struct Ledger {
    map: MmapMut,
    path: String,
    slots: HashMap<LinkKey, usize>,
    /// The program's payloads, whose kinds a slot may name.
    payloads: Payloads,
}

impl Ledger {
    /// Opens the ledger at `path`, continuing the counts of an earlier
    /// incarnation of the actor if the file holds one, or creates it with
    /// room for `capacity` links. `payloads`: the program's.
    pub fn open_or_create(
        path: &Path,
        capacity: usize,
        payloads: Payloads,
    ) -> Result<Self, LedgerError> {
        let name = path.display().to_string();
        let io = |source| LedgerError::Io {
            path: name.clone(),
            source,
        };
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .mode(crate::resources::OWNER_ONLY)
            .open(path)
            .map_err(io)?;
        let fresh = file.metadata().map_err(io)?.len() == 0;
        if fresh {
            file.set_len(((HEADER_WORDS + capacity * SLOT_WORDS) * 8) as u64)
                .map_err(io)?;
        }
        // SAFETY: the file is this actor's own; the only other process that
        // maps it (the launcher) reads it, and nobody truncates it while
        // mapped.
        let map = unsafe { MmapMut::map_mut(&file) }.map_err(io)?;
        let mut ledger = Self {
            map,
            path: name,
            slots: HashMap::new(),
            payloads,
        };
        if fresh {
            ledger.store(CAPACITY, capacity as u64);
            ledger.store(0, MAGIC);
        } else {
            // A predecessor killed mid-update left its journal: undo that
            // update here too, so that counting continues from exact values.
            let words = ledger.words();
            let recovered = decode(&snapshot(words), &ledger.path, payloads)?;
            ledger.undo_journal();
            for (i, key) in recovered.keys.into_iter().enumerate() {
                ledger.slots.insert(key, i);
            }
        }
        Ok(ledger)
    }

    fn words(&self) -> &[AtomicU64] {
        // SAFETY: the mapping is page-aligned and a whole number of words
        // long; AtomicU64 has the layout of u64.
        unsafe {
            std::slice::from_raw_parts(self.map.as_ptr() as *const AtomicU64, self.map.len() / 8)
        }
    }

    fn load(&self, i: usize) -> u64 {
        self.words()[i].load(Ordering::Relaxed)
    }

    /// Release stores keep the order the journal relies on: a reader (or
    /// the page cache after a kill) never sees a later store without the
    /// earlier ones.
    fn store(&self, i: usize, v: u64) {
        self.words()[i].store(v, Ordering::Release);
    }

    fn undo_journal(&self) {
        let slot = self.load(JOURNAL_SLOT);
        if slot == 0 {
            return;
        }
        let pair = self.load(JOURNAL_PAIR) as usize;
        let base = slot_base(slot as usize - 1) + 1 + 2 * pair;
        self.store(base, self.load(JOURNAL_MESSAGES));
        self.store(base + 1, self.load(JOURNAL_BYTES));
        self.store(JOURNAL_SLOT, 0);
    }

    /// The slot that holds `key`'s counts, given it now if it has none.
    pub fn slot(&mut self, key: LinkKey) -> Result<usize, LedgerError> {
        if let Some(s) = self.slots.get(&key) {
            return Ok(*s);
        }
        let used = self.load(USED) as usize;
        let capacity = self.load(CAPACITY) as usize;
        if used >= capacity {
            return Err(LedgerError::Full {
                path: self.path.clone(),
                capacity,
            });
        }
        // The key first, then the count that makes the slot visible: a kill
        // in between leaves an unused slot, not a slot without a key.
        self.store(slot_base(used), encode_key(key));
        self.store(USED, used as u64 + 1);
        self.slots.insert(key, used);
        Ok(used)
    }

    /// Adds `messages` and `bytes` (either may be negative, to take back a
    /// send that failed) to one counter pair of `key`.
    pub fn add(
        &mut self,
        key: LinkKey,
        pair: Pair,
        messages: i64,
        bytes: i64,
    ) -> Result<(), LedgerError> {
        let slot = self.slot(key)?;
        self.add_at(slot, pair, messages, bytes);
        Ok(())
    }

    /// [`add`](Self::add) to the link in `slot`, as [`slot`](Self::slot)
    /// gave it.
    pub fn add_at(&mut self, slot: usize, pair: Pair, messages: i64, bytes: i64) {
        debug_assert!(slot < self.load(USED) as usize, "a slot the ledger gave");
        let base = slot_base(slot) + 1 + 2 * pair as usize;
        let (m, b) = (self.load(base), self.load(base + 1));
        self.store(JOURNAL_MESSAGES, m);
        self.store(JOURNAL_BYTES, b);
        self.store(JOURNAL_PAIR, pair as u64);
        self.store(JOURNAL_SLOT, slot as u64 + 1);
        self.store(base, m.wrapping_add_signed(messages));
        self.store(base + 1, b.wrapping_add_signed(bytes));
        self.store(JOURNAL_SLOT, 0);
    }

    /// Counts one read of the world's truth that failed. One word, one
    /// writer: a kill cannot leave it half done.
    pub fn count_world_miss(&self) {
        self.store(WORLD_MISSES, self.load(WORLD_MISSES) + 1);
    }

    /// The counts as they stand.
    pub fn counts(&self) -> LedgerCounts {
        decode(&snapshot(self.words()), &self.path, self.payloads)
            .map(|d| d.counts)
            .unwrap_or_default()
    }
}

/// Reads the ledger an actor left at `path`, undoing the update a kill
/// interrupted. Safe to call while the actor still runs (the launcher's live
/// view does): the figures are then a moment's, not a final count.
pub fn read_ledger(path: &Path, payloads: Payloads) -> Result<LedgerCounts, LedgerError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| LedgerError::Io {
        path: name.clone(),
        source,
    })?;
    let words: Vec<u64> = bytes
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect();
    Ok(decode(&words, &name, payloads)?.counts)
}

/// What a ledger holds: the counts of each link, and the actor's failed
/// reads of the world.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LedgerCounts {
    pub links: Links,
    pub world_misses: u64,
}

fn snapshot(words: &[AtomicU64]) -> Vec<u64> {
    words.iter().map(|w| w.load(Ordering::Acquire)).collect()
}

fn slot_base(i: usize) -> usize {
    HEADER_WORDS + i * SLOT_WORDS
}

struct Decoded {
    counts: LedgerCounts,
    keys: Vec<LinkKey>,
}

/// The counts in `words`, with the journal's interrupted update undone.
fn decode(words: &[u64], path: &str, payloads: Payloads) -> Result<Decoded, LedgerError> {
    let damaged = |what: &str| LedgerError::Damaged {
        path: path.to_string(),
        what: what.to_string(),
    };
    if words.len() < HEADER_WORDS || words[0] != MAGIC {
        return Err(damaged("no ledger header"));
    }
    let (capacity, used) = (words[CAPACITY] as usize, words[USED] as usize);
    if used > capacity || words.len() < slot_base(capacity) {
        return Err(damaged("its slot count exceeds the file"));
    }
    let mut slots: Vec<[u64; SLOT_WORDS]> = (0..used)
        .map(|i| {
            words[slot_base(i)..slot_base(i + 1)]
                .try_into()
                .expect("a slot")
        })
        .collect();
    let journal = words[JOURNAL_SLOT] as usize;
    if journal != 0 {
        let pair = words[JOURNAL_PAIR] as usize;
        if journal > used || pair >= PAIRS {
            return Err(damaged("its journal names no slot"));
        }
        slots[journal - 1][1 + 2 * pair] = words[JOURNAL_MESSAGES];
        slots[journal - 1][2 + 2 * pair] = words[JOURNAL_BYTES];
    }
    let mut links = Links::default();
    let mut keys = Vec::with_capacity(used);
    for s in &slots {
        let key = decode_key(s[0], payloads).ok_or_else(|| damaged("a slot holds no link"))?;
        keys.push(key);
        links.add(
            key,
            &Counters {
                sent_messages: s[1],
                sent_bytes: s[2],
                received_messages: s[3],
                received_bytes: s[4],
                dropped_messages: s[5],
                dropped_bytes: s[6],
                malformed_messages: s[7],
                malformed_bytes: s[8],
                duplicated_messages: s[9],
                duplicated_bytes: s[10],
            },
        );
    }
    Ok(Decoded {
        counts: LedgerCounts {
            links,
            world_misses: words[WORLD_MISSES],
        },
        keys,
    })
}

fn encode_actor(a: ActorId) -> u64 {
    let (kind, index) = a.to_wire();
    (kind as u64) << 16 | index as u64
}

fn decode_actor(v: u64) -> Option<ActorId> {
    ActorId::from_wire((v >> 16) as u8, v as u16)
}

/// A link as one nonzero word: a marker bit, from, to and kind.
fn encode_key((from, to, kind): LinkKey) -> u64 {
    1 << 56 | encode_actor(from) << 32 | encode_actor(to) << 8 | kind.code() as u64
}

fn decode_key(v: u64, payloads: Payloads) -> Option<LinkKey> {
    if v >> 56 != 1 {
        return None;
    }
    let kind = kind_or_malformed((v & 0xff) as u8, payloads)?;
    Some((
        decode_actor((v >> 32) & 0xff_ffff)?,
        decode_actor((v >> 8) & 0xff_ffff)?,
        kind,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use wire::MessageKind;

    fn key(kind: MessageKind) -> LinkKey {
        (ActorId::Node(3), ActorId::Sensor(700), kind)
    }

    /// A ledger file of this test process's own, removed (with its folder,
    /// once empty) when the test ends, pass or fail.
    struct Temp(std::path::PathBuf);

    impl std::ops::Deref for Temp {
        type Target = std::path::Path;
        fn deref(&self) -> &std::path::Path {
            &self.0
        }
    }

    impl AsRef<std::path::Path> for Temp {
        fn as_ref(&self) -> &std::path::Path {
            &self.0
        }
    }

    impl Drop for Temp {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
            if let Some(dir) = self.0.parent() {
                let _ = std::fs::remove_dir(dir);
            }
        }
    }

    fn temp(name: &str) -> Temp {
        let dir = std::env::temp_dir().join(format!("cqnet-ledger-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        let _ = std::fs::remove_file(&p);
        Temp(p)
    }

    #[test]
    fn keys_survive_encoding() {
        for kind in [
            MessageKind::Activate,
            MessageKind::SelectionReport,
            MessageKind::Malformed,
        ] {
            let k = (ActorId::Launcher, ActorId::Node(u16::MAX), kind);
            assert_eq!(decode_key(encode_key(k), Payloads::NONE), Some(k));
            assert_eq!(
                decode_key(encode_key(key(kind)), Payloads::NONE),
                Some(key(kind))
            );
        }
        assert_eq!(decode_key(0, Payloads::NONE), None);
    }

    #[test]
    fn counts_are_read_back_and_a_reopened_ledger_continues_them() {
        let path = temp("reopen");
        let mut l = Ledger::open_or_create(&path, 8, Payloads::NONE).unwrap();
        l.add(key(MessageKind::Activate), Pair::Sent, 1, 16)
            .unwrap();
        l.add(key(MessageKind::Activate), Pair::Sent, 1, 16)
            .unwrap();
        l.add(key(MessageKind::Observation), Pair::Dropped, 1, 12)
            .unwrap();
        drop(l);
        let mut l = Ledger::open_or_create(&path, 8, Payloads::NONE).unwrap();
        l.add(key(MessageKind::Activate), Pair::Sent, 1, 16)
            .unwrap();
        l.count_world_miss();
        let read = read_ledger(&path, Payloads::NONE).unwrap();
        assert_eq!(read.world_misses, 1);
        assert_eq!(l.counts(), read);
        l.count_world_miss();
        assert_eq!(read_ledger(&path, Payloads::NONE).unwrap().world_misses, 2);
        let a = read.links;
        let c = a.get(
            ActorId::Node(3),
            ActorId::Sensor(700),
            MessageKind::Activate,
        );
        assert_eq!((c.sent_messages, c.sent_bytes), (3, 48));
        let c = a.get(
            ActorId::Node(3),
            ActorId::Sensor(700),
            MessageKind::Observation,
        );
        assert_eq!((c.dropped_messages, c.dropped_bytes), (1, 12));
    }

    /// A kill between any two stores of an update: the reader sees the
    /// counts before it or after it, never half of it.
    #[test]
    fn an_update_cut_short_is_undone_on_reading() {
        let path = temp("cut");
        let mut l = Ledger::open_or_create(&path, 4, Payloads::NONE).unwrap();
        l.add(key(MessageKind::Consensus), Pair::Received, 1, 203)
            .unwrap();
        let base = slot_base(0) + 1 + 2 * Pair::Received as usize;
        // The journal written, the messages counted, the bytes not yet.
        l.store(JOURNAL_MESSAGES, 1);
        l.store(JOURNAL_BYTES, 203);
        l.store(JOURNAL_PAIR, Pair::Received as u64);
        l.store(JOURNAL_SLOT, 1);
        l.store(base, 2);
        l.map.flush().unwrap();
        let c = read_ledger(&path, Payloads::NONE).unwrap().links.get(
            ActorId::Node(3),
            ActorId::Sensor(700),
            MessageKind::Consensus,
        );
        assert_eq!((c.received_messages, c.received_bytes), (1, 203));
        // The next incarnation continues from the undone values.
        drop(l);
        let mut l = Ledger::open_or_create(&path, 4, Payloads::NONE).unwrap();
        l.add(key(MessageKind::Consensus), Pair::Received, 1, 203)
            .unwrap();
        let c = read_ledger(&path, Payloads::NONE).unwrap().links.get(
            ActorId::Node(3),
            ActorId::Sensor(700),
            MessageKind::Consensus,
        );
        assert_eq!((c.received_messages, c.received_bytes), (2, 406));
    }

    #[test]
    fn a_full_ledger_and_a_damaged_file_are_errors() {
        let path = temp("full");
        let mut l = Ledger::open_or_create(&path, 1, Payloads::NONE).unwrap();
        l.add(key(MessageKind::Activate), Pair::Sent, 1, 1).unwrap();
        assert!(matches!(
            l.add(key(MessageKind::Control), Pair::Sent, 1, 1),
            Err(LedgerError::Full { capacity: 1, .. })
        ));
        let bad = temp("bad");
        std::fs::write(&bad, b"not a ledger at all, just text....").unwrap();
        let e = read_ledger(&bad, Payloads::NONE).unwrap_err().to_string();
        assert!(e.contains("bad") && e.contains("not a cqnet ledger"), "{e}");
    }
}
