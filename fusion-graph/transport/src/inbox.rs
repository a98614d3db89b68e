//! Inboxes: how nodes on one host pass values to their neighbours.
//!
//! Each node has one inbox, a file of the run's shared memory, and its
//! neighbours write their consensus values (and the messages they send it
//! alone, in pairs) straight into it. The wake-ups stay the actors'
//! wake-up services; only the bytes move this way.
//!
//! Why not a publish/subscribe service per node, as every other channel
//! has: a consensus round is a few hundred bytes to a handful of
//! neighbours, and through iceoryx2's ports it touched about 29 pages in
//! 28 mappings a node-round (the node's data segment and dynamic
//! configuration, a connection per neighbour each way, each neighbour's
//! data segment). With fifty node processes per core each turn finds the
//! TLB empty, and every page costs a walk: 23-25 µs a node-round cold
//! against 4-5 warm (`benches/message_path.rs`). An inbox round touches
//! the reader's inbox and one page of each neighbour's: a fifth off the
//! benchmark's round, though in a network of processes that alone was
//! not resolved; with the wake-ups below, it was (docs/performance.md).
//!
//! Node r's inbox has two slots per neighbour: slot `2k` carries
//! `Consensus(m)` and slot `2k + 1` carries `Pair { from: m, to: r }`,
//! where m is r's k-th neighbour. Every process computes the same layout
//! from the topology, and the file is zeroed when made, so whoever opens
//! it first (reader or writer) needs to write nothing into it. It holds a
//! head per slot, each on its own cache line (how many messages the slot's
//! writer has finished), a word that says whether the reader sleeps, then
//! a ring of [`QUEUE_DEPTH`] entries per slot: a stamp, a length, the
//! bytes.
//!
//! A writer wakes the reader (through its wake-up service) only when the
//! reader sleeps: a node that runs reads its inbox at its next receive,
//! and one that polls looks at the heads as it polls. Waking a neighbour
//! through iceoryx2's notifier touches that neighbour's event pages, and a
//! round with no wake-ups at all cost a third less with caches cold
//! (`benches/message_path.rs`). The reader says it sleeps and then looks
//! at the heads; the writer advances a head and then looks at the word;
//! both sequentially consistent, so at least one sees the other.
//!
//! Each slot has one writer, the channel's one publisher. It stamps the
//! entry odd (being written), writes it, stamps it even with the sequence,
//! and only then advances the head: a writer killed midway leaves the head
//! where it was, and its next incarnation writes the same entry again.
//! The reader reads the entries below the head and checks the stamp before
//! and after copying (a sequence lock): a writer more than a ring ahead has
//! overwritten what the reader had not read, and the reader skips to the
//! oldest entry still there, as a full subscriber queue drops its oldest.
//! A reader starts at the heads it finds, as a new subscriber gets no
//! history.
//!
//! The words are atomics, loaded and stored relaxed between the stamps'
//! acquire and release, so that a reader racing a writer reads a torn
//! entry it then throws away, never undefined memory.

use std::collections::HashMap;
use std::sync::atomic::{fence, AtomicU64, Ordering};

use fusion_graph::channel::RunId;
use fusion_graph::topology::Topology;
use wire::ActorId;

use crate::limits::{max_message_len, QUEUE_DEPTH};
use crate::resources::map_run_memory;
use crate::{BackendError, Channel, SetupError};

const LINE: usize = 64;
/// An entry's stamp and length, before its bytes.
const ENTRY_HEADER: usize = 16;
const DEPTH: u64 = QUEUE_DEPTH as u64;

/// Whether `channel` travels through inboxes on a host of its own: the
/// channels from node to node.
pub(crate) fn carries(channel: Channel) -> bool {
    matches!(channel, Channel::Consensus(_) | Channel::Pair { .. })
}

/// Where messages of `channel` land in node `reader`'s inbox, if it reads
/// them.
fn slot_of(topology: &Topology, channel: Channel, reader: u16) -> Option<usize> {
    let (from, kind) = match channel {
        Channel::Consensus(m) => (m, 0),
        Channel::Pair { from, to } if to == reader => (from, 1),
        _ => return None,
    };
    let k = topology
        .neighbours
        .get(reader as usize)?
        .iter()
        .position(|&m| m == from)?;
    Some(2 * k + kind)
}

/// Where things are in one node's inbox.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Layout {
    slots: usize,
    /// Bytes from one entry to the next: whole cache lines.
    stride: usize,
}

impl Layout {
    pub(crate) fn of(topology: &Topology, reader: u16) -> Self {
        let longest = max_message_len(Channel::Consensus(0), topology)
            .max(max_message_len(Channel::Pair { from: 0, to: 0 }, topology));
        Self {
            slots: 2 * topology.neighbours[reader as usize].len(),
            stride: (ENTRY_HEADER + longest.div_ceil(8) * 8).div_ceil(LINE) * LINE,
        }
    }

    fn heads_len(&self) -> usize {
        self.slots * LINE
    }

    /// Where the word that says the reader sleeps is: after the heads.
    fn sleeping(&self) -> usize {
        self.heads_len()
    }

    /// The heads and the sleeping word.
    fn header_len(&self) -> usize {
        self.heads_len() + LINE
    }

    /// The inbox's bytes.
    pub(crate) fn len(&self) -> usize {
        self.header_len() + self.slots * QUEUE_DEPTH * self.stride
    }

    fn capacity(&self) -> usize {
        self.stride - ENTRY_HEADER
    }

    fn entry(&self, slot: usize, sequence: u64) -> usize {
        self.header_len() + (slot * QUEUE_DEPTH + (sequence % DEPTH) as usize) * self.stride
    }
}

/// The file name (after the run's prefix) of node `n`'s inbox.
fn name(n: u16) -> String {
    format!("inbox_node-{n}")
}

/// One node's inbox, mapped.
struct Memory {
    map: memmap2::MmapMut,
    layout: Layout,
}

/// What reading one entry gave.
enum Entry {
    Read,
    /// A writer lapped the reader and wrote over it.
    Overwritten,
}

impl Memory {
    fn open(run: &RunId, topology: &Topology, n: u16) -> Result<Self, SetupError> {
        let layout = Layout::of(topology, n);
        let map = map_run_memory(run, &name(n), layout.len()).map_err(|e| SetupError::Backend {
            what: format!("the inbox of node-{n}"),
            source: Box::new(e),
        })?;
        Ok(Self { map, layout })
    }

    fn word(&self, offset: usize) -> &AtomicU64 {
        debug_assert!(offset.is_multiple_of(8) && offset + 8 <= self.map.len());
        // SAFETY: in bounds (the layout's offsets lie inside the map, which
        // is page-aligned, and are multiples of 8); every process reads and
        // writes the inbox only through such atomics; the word lives as
        // long as `self` borrows the map.
        unsafe { &*self.map.as_ptr().add(offset).cast::<AtomicU64>() }
    }

    fn head(&self, slot: usize) -> &AtomicU64 {
        self.word(slot * LINE)
    }

    fn sleeping(&self) -> &AtomicU64 {
        self.word(self.layout.sleeping())
    }

    /// Appends `bytes` to `slot`'s ring. Only the slot's writer calls it.
    fn write(&self, slot: usize, bytes: &[u8]) -> Result<(), BackendError> {
        if bytes.len() > self.layout.capacity() {
            return Err(format!(
                "a message of {} bytes is longer than an inbox entry's {}",
                bytes.len(),
                self.layout.capacity()
            )
            .into());
        }
        let head = self.head(slot);
        let sequence = head.load(Ordering::Relaxed);
        let at = self.layout.entry(slot, sequence);
        let stamp = self.word(at);
        stamp.store(2 * sequence + 1, Ordering::Relaxed);
        // The odd stamp before any byte: a reader that sees a new byte sees
        // the entry is being written.
        fence(Ordering::Release);
        self.word(at + 8)
            .store(bytes.len() as u64, Ordering::Relaxed);
        for (k, chunk) in bytes.chunks(8).enumerate() {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.word(at + ENTRY_HEADER + 8 * k)
                .store(u64::from_le_bytes(word), Ordering::Relaxed);
        }
        stamp.store(2 * sequence + 2, Ordering::Release);
        head.store(sequence + 1, Ordering::Release);
        Ok(())
    }

    /// Copies entry `sequence` of `slot` into `out`.
    fn read(&self, slot: usize, sequence: u64, out: &mut Vec<u8>) -> Entry {
        let at = self.layout.entry(slot, sequence);
        let stamp = self.word(at);
        let before = stamp.load(Ordering::Acquire);
        if before != 2 * sequence + 2 {
            return Entry::Overwritten;
        }
        // A torn length is caught by the stamp below; bounded, it cannot
        // read past the entry meanwhile.
        let len = (self.word(at + 8).load(Ordering::Relaxed) as usize).min(self.layout.capacity());
        out.clear();
        for k in 0..len.div_ceil(8) {
            let word = self.word(at + ENTRY_HEADER + 8 * k).load(Ordering::Relaxed);
            out.extend_from_slice(&word.to_le_bytes());
        }
        out.truncate(len);
        // The bytes before the second look at the stamp.
        fence(Ordering::Acquire);
        if stamp.load(Ordering::Relaxed) == before {
            Entry::Read
        } else {
            Entry::Overwritten
        }
    }
}

/// One actor's ends of the inboxes: its own, which it reads, and its
/// neighbours', which it writes.
pub(crate) struct Inboxes {
    run: RunId,
    topology: Topology,
    me: ActorId,
    own: Option<Memory>,
    /// The next sequence to read in each slot of the own inbox.
    cursors: Vec<u64>,
    /// The slots this actor reads: the others' heads are none of its
    /// business (a program's protocol might write a pair it never reads).
    subscribed: Vec<usize>,
    /// The neighbours' inboxes, with their nodes: a handful, so a send
    /// finds them by index and a wake-up by a short scan, not a hash.
    theirs: Vec<(u16, Memory)>,
    /// Each channel this actor writes: where in `theirs`, and which slot.
    routes: HashMap<Channel, Vec<(usize, usize)>>,
    /// Where `receive` copies an entry, reused.
    scratch: Vec<u8>,
}

impl Inboxes {
    pub(crate) fn new(run: &RunId, topology: &Topology, me: ActorId) -> Self {
        Self {
            run: run.clone(),
            topology: topology.clone(),
            me,
            own: None,
            cursors: Vec::new(),
            subscribed: Vec::new(),
            theirs: Vec::new(),
            routes: HashMap::new(),
            scratch: Vec::with_capacity(512),
        }
    }

    /// Reads `channel` from now on, and says which slot of the own inbox.
    pub(crate) fn subscribe(&mut self, channel: Channel) -> Result<usize, SetupError> {
        let ActorId::Node(me) = self.me else {
            return Err(not_a_reader(channel, self.me));
        };
        let slot =
            slot_of(&self.topology, channel, me).ok_or_else(|| not_a_reader(channel, self.me))?;
        if self.own.is_none() {
            let own = Memory::open(&self.run, &self.topology, me)?;
            // No history: what was written before this incarnation opened
            // its inbox is not for it.
            self.cursors = (0..own.layout.slots)
                .map(|s| own.head(s).load(Ordering::Acquire))
                .collect();
            self.own = Some(own);
        }
        if !self.subscribed.contains(&slot) {
            self.subscribed.push(slot);
        }
        Ok(slot)
    }

    /// Writes `channel` from now on: opens each reader's inbox.
    pub(crate) fn publish_on(&mut self, channel: Channel) -> Result<(), SetupError> {
        if self.routes.contains_key(&channel) {
            return Ok(());
        }
        let mut route = Vec::new();
        for reader in self.topology.readers(channel) {
            let ActorId::Node(r) = reader else {
                return Err(not_a_reader(channel, reader));
            };
            let slot =
                slot_of(&self.topology, channel, r).ok_or_else(|| not_a_reader(channel, reader))?;
            let at = match self.theirs.iter().position(|(n, _)| *n == r) {
                Some(at) => at,
                None => {
                    let memory = Memory::open(&self.run, &self.topology, r)?;
                    self.theirs.push((r, memory));
                    self.theirs.len() - 1
                }
            };
            route.push((at, slot));
        }
        self.routes.insert(channel, route);
        Ok(())
    }

    /// Puts `bytes` in the inbox of every reader of `channel`.
    pub(crate) fn send(&self, channel: Channel, bytes: &[u8]) -> Result<(), BackendError> {
        let route = self.routes.get(&channel).ok_or_else(|| {
            format!(
                "{} is not written through inboxes",
                channel.service_suffix()
            )
        })?;
        for &(at, slot) in route {
            self.theirs[at].1.write(slot, bytes)?;
        }
        Ok(())
    }

    /// Whether `reader`, whose inbox this actor writes, may be asleep and
    /// so needs waking: after a `send` to it, with [`Self::sleep`]'s
    /// ordering. An actor whose inbox this one does not write may be.
    pub(crate) fn may_sleep(&self, reader: ActorId) -> bool {
        let ActorId::Node(r) = reader else {
            return true;
        };
        let Some((_, theirs)) = self.theirs.iter().find(|(n, _)| *n == r) else {
            return true;
        };
        // The heads written before the look at the word.
        fence(Ordering::SeqCst);
        theirs.sleeping().load(Ordering::SeqCst) != 0
    }

    /// Says this actor is about to sleep, and whether a message came
    /// meanwhile (then it should not sleep). [`Self::wake`] after.
    pub(crate) fn sleep(&self) -> bool {
        let Some(own) = &self.own else { return false };
        own.sleeping().store(1, Ordering::SeqCst);
        // The word written before the look at the heads.
        fence(Ordering::SeqCst);
        self.unread()
    }

    pub(crate) fn wake(&self) {
        if let Some(own) = &self.own {
            own.sleeping().store(0, Ordering::SeqCst);
        }
    }

    /// Whether any slot this actor reads holds what it has not read.
    pub(crate) fn unread(&self) -> bool {
        let Some(own) = &self.own else { return false };
        self.subscribed
            .iter()
            .any(|&slot| own.head(slot).load(Ordering::Acquire) > self.cursors[slot])
    }

    /// Hands each message waiting in `slot` of the own inbox to `arrive`,
    /// oldest first.
    pub(crate) fn drain(&mut self, slot: usize, mut arrive: impl FnMut(&[u8])) {
        let Some(own) = &self.own else { return };
        let head = own.head(slot).load(Ordering::Acquire);
        let cursor = &mut self.cursors[slot];
        // Lapped: what was overwritten is lost, as from a full queue.
        *cursor = (*cursor).max(head.saturating_sub(DEPTH));
        while *cursor < head {
            let sequence = *cursor;
            *cursor += 1;
            if let Entry::Read = own.read(slot, sequence, &mut self.scratch) {
                arrive(&self.scratch);
            }
        }
    }
}

fn not_a_reader(channel: Channel, actor: ActorId) -> SetupError {
    SetupError::Backend {
        what: format!("the inbox of {actor}"),
        source: format!(
            "{actor} does not read channel {} in this topology",
            channel.service_suffix()
        )
        .into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::resources::remove_run_resources;
    use fusion_graph::scenario::Scenario;

    struct Run(RunId);

    impl Drop for Run {
        fn drop(&mut self) {
            let _ = remove_run_resources(&self.0);
        }
    }

    /// The default network, whose nodes 0 and 1 are neighbours.
    fn grid() -> Topology {
        let t = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
        assert!(t.neighbours[0].contains(&1));
        t
    }

    /// A node with two neighbours or more, and two of them.
    fn centre(t: &Topology) -> (u16, u16, u16) {
        let r = (0..t.nodes())
            .find(|&r| t.neighbours[r].len() >= 2)
            .unwrap();
        (r as u16, t.neighbours[r][0], t.neighbours[r][1])
    }

    fn ends(run: &RunId, topology: &Topology, me: u16) -> Inboxes {
        Inboxes::new(run, topology, ActorId::Node(me))
    }

    /// Node 0 reading node 1's consensus channel (and its slot), and node
    /// 1 writing it.
    fn one_to_zero(run: &RunId, t: &Topology) -> (Inboxes, usize, Inboxes) {
        let mut reader = ends(run, t, 0);
        let slot = reader.subscribe(Channel::Consensus(1)).unwrap();
        let mut w = ends(run, t, 1);
        w.publish_on(Channel::Consensus(1)).unwrap();
        (reader, slot, w)
    }

    fn drained(inboxes: &mut Inboxes, slot: usize) -> Vec<Vec<u8>> {
        let mut got = Vec::new();
        inboxes.drain(slot, |b| got.push(b.to_vec()));
        got
    }

    #[test]
    fn every_neighbour_has_its_own_slots() {
        let t = grid();
        for r in 0..t.nodes() as u16 {
            let mut slots: Vec<usize> = t.neighbours[r as usize]
                .iter()
                .flat_map(|&m| {
                    [
                        slot_of(&t, Channel::Consensus(m), r).unwrap(),
                        slot_of(&t, Channel::Pair { from: m, to: r }, r).unwrap(),
                    ]
                })
                .collect();
            slots.sort_unstable();
            assert_eq!(slots, (0..Layout::of(&t, r).slots).collect::<Vec<_>>());
        }
        // Not a neighbour, or a pair for someone else.
        assert_eq!(slot_of(&t, Channel::Consensus(8), 0), None);
        assert_eq!(slot_of(&t, Channel::Pair { from: 1, to: 2 }, 0), None);
    }

    #[test]
    fn messages_arrive_in_order_from_each_writer() {
        let run = Run(RunId::new("inbox-order").unwrap());
        let t = grid();
        let (r, a, b) = centre(&t);
        let mut reader = ends(&run.0, &t, r);
        let from_a = slot_of(&t, Channel::Consensus(a), r).unwrap();
        let from_b = slot_of(&t, Channel::Consensus(b), r).unwrap();
        assert_eq!(reader.subscribe(Channel::Consensus(a)).unwrap(), from_a);
        reader.subscribe(Channel::Consensus(b)).unwrap();
        let mut wa = ends(&run.0, &t, a);
        wa.publish_on(Channel::Consensus(a)).unwrap();
        let mut wb = ends(&run.0, &t, b);
        wb.publish_on(Channel::Consensus(b)).unwrap();
        wa.send(Channel::Consensus(a), b"first").unwrap();
        wb.send(Channel::Consensus(b), &[7; 300]).unwrap();
        wa.send(Channel::Consensus(a), b"second, longer than a word")
            .unwrap();
        assert_eq!(
            drained(&mut reader, from_a),
            vec![b"first".to_vec(), b"second, longer than a word".to_vec()]
        );
        assert_eq!(drained(&mut reader, from_b), vec![vec![7; 300]]);
        assert!(drained(&mut reader, from_a).is_empty());
        // Each reader of a channel gets its messages in its own inbox.
        let other = *t.neighbours[a as usize].iter().find(|&&m| m != r).unwrap();
        let mut second = ends(&run.0, &t, other);
        let slot = second.subscribe(Channel::Consensus(a)).unwrap();
        wa.send(Channel::Consensus(a), b"third").unwrap();
        assert_eq!(drained(&mut second, slot), vec![b"third".to_vec()]);
        assert_eq!(drained(&mut reader, from_a), vec![b"third".to_vec()]);
    }

    #[test]
    fn a_reader_starts_at_the_heads_it_finds() {
        let run = Run(RunId::new("inbox-history").unwrap());
        let t = grid();
        let mut w = ends(&run.0, &t, 1);
        w.publish_on(Channel::Consensus(1)).unwrap();
        w.send(Channel::Consensus(1), b"before").unwrap();
        let mut reader = ends(&run.0, &t, 0);
        let slot = reader.subscribe(Channel::Consensus(1)).unwrap();
        assert!(drained(&mut reader, slot).is_empty());
        w.send(Channel::Consensus(1), b"after").unwrap();
        assert_eq!(drained(&mut reader, slot), vec![b"after".to_vec()]);
        // A restarted reader (a new incarnation) skips what it missed.
        w.send(Channel::Consensus(1), b"missed").unwrap();
        let mut again = ends(&run.0, &t, 0);
        again.subscribe(Channel::Consensus(1)).unwrap();
        assert!(drained(&mut again, slot).is_empty());
    }

    #[test]
    fn a_restarted_writer_continues_its_sequence() {
        let run = Run(RunId::new("inbox-writer").unwrap());
        let t = grid();
        let (mut reader, slot, w) = one_to_zero(&run.0, &t);
        w.send(Channel::Consensus(1), b"a").unwrap();
        drop(w);
        let mut w = ends(&run.0, &t, 1);
        w.publish_on(Channel::Consensus(1)).unwrap();
        w.send(Channel::Consensus(1), b"b").unwrap();
        assert_eq!(
            drained(&mut reader, slot),
            vec![b"a".to_vec(), b"b".to_vec()]
        );
    }

    #[test]
    fn a_lapped_reader_keeps_the_newest_ring() {
        let run = Run(RunId::new("inbox-lapped").unwrap());
        let t = grid();
        let (mut reader, slot, w) = one_to_zero(&run.0, &t);
        let sent = QUEUE_DEPTH + 10;
        for k in 0..sent as u32 {
            w.send(Channel::Consensus(1), &k.to_le_bytes()).unwrap();
        }
        let got = drained(&mut reader, slot);
        let expected: Vec<Vec<u8>> = (10..sent as u32)
            .map(|k| k.to_le_bytes().to_vec())
            .collect();
        assert_eq!(got, expected);
    }

    #[test]
    fn a_writer_killed_midway_is_written_over() {
        let run = Run(RunId::new("inbox-torn").unwrap());
        let t = grid();
        let (mut reader, slot, w) = one_to_zero(&run.0, &t);
        // What a writer killed after stamping and before finishing leaves.
        let (_, memory) = &w.theirs[0];
        let at = memory.layout.entry(slot, 0);
        memory.word(at).store(1, Ordering::Release);
        memory
            .word(at + ENTRY_HEADER)
            .store(u64::MAX, Ordering::Relaxed);
        assert!(drained(&mut reader, slot).is_empty());
        w.send(Channel::Consensus(1), b"whole").unwrap();
        assert_eq!(drained(&mut reader, slot), vec![b"whole".to_vec()]);
    }

    #[test]
    fn an_entry_overwritten_while_read_is_dropped() {
        let run = Run(RunId::new("inbox-race").unwrap());
        let t = grid();
        let (reader, slot, w) = one_to_zero(&run.0, &t);
        w.send(Channel::Consensus(1), b"old").unwrap();
        // The writer a ring ahead has begun the entry the reader is at.
        let (_, memory) = &w.theirs[0];
        let at = memory.layout.entry(slot, DEPTH);
        memory.word(at).store(2 * DEPTH + 1, Ordering::Release);
        let own = reader.own.as_ref().unwrap();
        assert!(matches!(
            own.read(slot, 0, &mut Vec::new()),
            Entry::Overwritten
        ));
    }

    #[test]
    fn a_writer_sees_whether_its_reader_sleeps() {
        let run = Run(RunId::new("inbox-sleep").unwrap());
        let t = grid();
        let (mut reader, slot, w) = one_to_zero(&run.0, &t);
        // Awake, the reader needs no wake-up; actors whose inbox the
        // writer does not write always may.
        assert!(!w.may_sleep(ActorId::Node(0)));
        assert!(w.may_sleep(ActorId::Node(7)));
        assert!(w.may_sleep(ActorId::Launcher));
        assert!(!reader.sleep(), "nothing waits");
        assert!(w.may_sleep(ActorId::Node(0)));
        reader.wake();
        assert!(!w.may_sleep(ActorId::Node(0)));
        // What came before the reader's look keeps it from sleeping.
        w.send(Channel::Consensus(1), b"v").unwrap();
        assert!(reader.unread());
        assert!(reader.sleep());
        reader.wake();
        assert_eq!(drained(&mut reader, slot), vec![b"v".to_vec()]);
        assert!(!reader.unread());
        // A slot the reader does not read never keeps it awake.
        let mut pairs = ends(&run.0, &t, 1);
        pairs.publish_on(Channel::Pair { from: 1, to: 0 }).unwrap();
        pairs.send(Channel::Pair { from: 1, to: 0 }, b"p").unwrap();
        assert!(!reader.unread());
        assert!(!reader.sleep());
        reader.wake();
    }

    #[test]
    fn only_readers_and_writers_of_the_topology_get_inboxes() {
        let run = Run(RunId::new("inbox-refused").unwrap());
        let t = grid();
        let stranger = (1..t.nodes() as u16)
            .find(|m| !t.neighbours[0].contains(m))
            .unwrap();
        let mut not_neighbour = ends(&run.0, &t, stranger);
        assert!(not_neighbour.subscribe(Channel::Consensus(0)).is_err());
        let mut sensor = Inboxes::new(&run.0, &t, ActorId::Sensor(0));
        assert!(sensor.subscribe(Channel::Consensus(0)).is_err());
        let mut w = ends(&run.0, &t, 1);
        w.publish_on(Channel::Consensus(1)).unwrap();
        let too_long = vec![0; Layout::of(&t, 0).capacity() + 1];
        assert!(w.send(Channel::Consensus(1), &too_long).is_err());
        assert!(w.send(Channel::Consensus(2), b"not mine").is_err());
    }
}
