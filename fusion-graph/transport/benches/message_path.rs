//! The CPU one consensus round costs the transport, without a context
//! switch: every node of the 10 × 10 grid lives in this one process with
//! its own transport, wired as a node process wires itself (its
//! neighbours' consensus channels, which are its inbox, its launcher
//! control channel, an iceoryx2 service, its wake-ups, a ledger under every
//! count), and one iteration is one round: each node publishes
//! its values to its neighbours, waking them, then each node takes its
//! wake-ups and reads what came. Only the nodes' turns are timed.
//!
//! It runs three ways. With the caches warm, as nothing else ran between
//! two turns of a node. Then as in a network of processes, where some 50
//! others run on a core between two turns of one node: "caches cold"
//! writes a line of every 64 bytes of 16 MiB before each turn, and "TLB
//! cold" one of every 4 KiB page, which empties the TLB and leaves most of
//! the caches. The gap between warm and cold is what `cqnet run` pays per
//! round that `sim` does not, beyond the switch itself.
//!
//! `cargo bench -p transport --bench message_path`

use std::time::{Duration, Instant};

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, BenchmarkGroup, Criterion, Throughput};
use fusion_graph::scenario::{Scenario, DEFAULT_SCENARIO};
use fusion_graph::{ActorId, Topology};
use transport::iceoryx::remove_run_resources;
use transport::{Channel, IceoryxTransport, RunId, Transport};
use wire::Message;

#[path = "common/consensus.rs"]
mod common;
use common::consensus_message;

fn grid() -> (Scenario, Topology) {
    let sets: Vec<String> = [
        "nodes.grid=[10,10]",
        "region.width=5000",
        "region.height=5000",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let s = Scenario::from_toml(DEFAULT_SCENARIO, "bench", &sets).unwrap();
    let t = Topology::from_scenario(&s, "bench").unwrap();
    (s, t)
}

struct Network {
    run: RunId,
    nodes: Vec<(IceoryxTransport, Vec<ActorId>)>,
    ledgers: std::path::PathBuf,
}

impl Drop for Network {
    fn drop(&mut self) {
        self.nodes.clear();
        let _ = remove_run_resources(&self.run);
        let _ = std::fs::remove_dir_all(&self.ledgers);
    }
}

fn network(scenario: &Scenario, topology: &Topology) -> Network {
    let format = scenario.wire_format(topology);
    let run = RunId::new(&format!("bench-mp-{}", std::process::id())).unwrap();
    let ledgers = std::env::temp_dir().join(format!("cqnet-message-path-{}", std::process::id()));
    std::fs::create_dir_all(&ledgers).unwrap();
    let mut nodes = Vec::new();
    for n in 0..topology.nodes() as u16 {
        let me = ActorId::Node(n);
        let mut t = IceoryxTransport::new(&run, me, topology, format, u64::from(n)).unwrap();
        t.keep_counts_in(&ledgers.join(format!("node-{n}.ledger")))
            .unwrap();
        t.publish_on(Channel::Consensus(n)).unwrap();
        t.subscribe(Channel::Control(me)).unwrap();
        let readers = topology.readers(Channel::Consensus(n));
        for m in &readers {
            let ActorId::Node(m) = *m else { unreachable!() };
            t.subscribe(Channel::Consensus(m)).unwrap();
            t.notify(ActorId::Node(m)).unwrap();
        }
        nodes.push((t, readers));
    }
    for (t, _) in &mut nodes {
        t.update_connections();
    }
    Network {
        run,
        nodes,
        ledgers,
    }
}

/// What a round needs of a network of nodes: that node `n` send its
/// values to its neighbours, and read what came.
trait Exchange {
    fn nodes(&self) -> usize;
    fn send(&mut self, n: usize, message: &Message);
    /// Returns how many messages were read.
    fn receive(&mut self, n: usize, out: &mut Vec<Message>) -> usize;
}

impl Exchange for Network {
    fn nodes(&self) -> usize {
        self.nodes.len()
    }

    fn send(&mut self, n: usize, message: &Message) {
        let (t, readers) = &mut self.nodes[n];
        t.send_waking(Channel::Consensus(n as u16), message, readers, readers)
            .unwrap();
    }

    fn receive(&mut self, n: usize, out: &mut Vec<Message>) -> usize {
        let (t, _) = &mut self.nodes[n];
        t.poll_wake().unwrap();
        let now = t.now();
        t.receive(now, out).unwrap();
        out.len()
    }
}

/// One round: every node sends, then every node reads, each node's turn
/// preceded by `between` (the other processes of its core, in a real
/// network). Returns the messages read and the time the turns took.
fn round(
    net: &mut impl Exchange,
    step: u32,
    r: u16,
    inbox: &mut Vec<Message>,
    mut between: impl FnMut(),
) -> (usize, Duration) {
    let mut took = Duration::ZERO;
    for n in 0..net.nodes() {
        between();
        let started = Instant::now();
        net.send(n, &consensus_message(n as u16, step, r));
        took += started.elapsed();
    }
    let mut read = 0;
    for n in 0..net.nodes() {
        between();
        let started = Instant::now();
        inbox.clear();
        read += net.receive(n, inbox);
        took += started.elapsed();
    }
    (read, took)
}

/// For comparison: the same round through a bare inbox per node, one
/// shared page of slots, one slot per neighbour and no ring, that the
/// neighbours write their encoded values into, and no wake-ups. cqnet's
/// own layer stays as it is (encoding, the link shaper, decoding, the
/// accounting and its ledger). The gap to the transport's round is what
/// its wake-ups, its control channel and the rest of its bookkeeping cost.
mod inbox {
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::time::{Duration, Instant};

    use fusion_graph::shaper::LinkShaper;
    use fusion_graph::{ActorId, Topology};
    use transport::ledger::Ledger;
    use transport::{Accounting, Channel, Inbound, Outbound};
    use wire::{Message, WireFormat};

    const SLOT_BYTES: usize = 448;
    const SLOTS: usize = 8;

    #[repr(C, align(64))]
    struct Slot {
        sequence: AtomicU32,
        len: AtomicU32,
        bytes: [u8; SLOT_BYTES],
    }

    /// One node's inbox: a page of its own, as a shared mapping would be.
    struct Page(*mut [Slot; SLOTS]);

    impl Page {
        fn new() -> Self {
            // SAFETY: a fresh anonymous shared mapping of one page, zeroed,
            // which a `[Slot; 8]` of atomics and bytes may be read as.
            let p = unsafe {
                libc::mmap(
                    std::ptr::null_mut(),
                    std::mem::size_of::<[Slot; SLOTS]>(),
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_SHARED | libc::MAP_ANONYMOUS,
                    -1,
                    0,
                )
            };
            assert_ne!(p, libc::MAP_FAILED);
            Page(p.cast())
        }

        fn slot(&self, k: usize) -> &Slot {
            // SAFETY: the mapping lives as long as the page.
            unsafe { &(*self.0)[k] }
        }
    }

    pub struct Node {
        me: u16,
        readers: Vec<ActorId>,
        /// Where this node writes: (neighbour, its slot in their inbox).
        writes: Vec<(usize, usize)>,
        /// Who writes each slot of this node's inbox, and what it read last.
        senders: Vec<(u16, u32)>,
        accounting: Accounting,
        shaper: LinkShaper,
        buffer: Vec<u8>,
    }

    pub struct Inboxes {
        pages: Vec<Page>,
        nodes: Vec<Node>,
        format: WireFormat,
        start: Instant,
    }

    impl Inboxes {
        pub fn new(topology: &Topology, format: WireFormat, ledgers: &std::path::Path) -> Self {
            let n = topology.nodes();
            let pages = (0..n).map(|_| Page::new()).collect();
            let mut nodes: Vec<Node> = (0..n as u16)
                .map(|me| {
                    let path = ledgers.join(format!("inbox-{me}.ledger"));
                    let ledger = Ledger::open_or_create(&path, 64, format.payloads).unwrap();
                    Node {
                        me,
                        readers: topology.readers(Channel::Consensus(me)),
                        writes: Vec::new(),
                        senders: Vec::new(),
                        accounting: Accounting::backed_by(ledger),
                        shaper: LinkShaper::new(u64::from(me)),
                        buffer: Vec::with_capacity(512),
                    }
                })
                .collect();
            for me in 0..n {
                for r in nodes[me].readers.clone() {
                    let ActorId::Node(r) = r else { unreachable!() };
                    let slot = nodes[r as usize].senders.len();
                    assert!(slot < SLOTS, "more neighbours than slots");
                    nodes[r as usize].senders.push((me as u16, 0));
                    nodes[me].writes.push((r as usize, slot));
                }
            }
            Self {
                pages,
                nodes,
                format,
                start: Instant::now(),
            }
        }
    }

    impl super::Exchange for Inboxes {
        fn nodes(&self) -> usize {
            self.nodes.len()
        }

        fn send(&mut self, n: usize, message: &Message) {
            let Self {
                pages,
                nodes,
                format,
                ..
            } = self;
            let node = &mut nodes[n];
            let writes = &node.writes;
            Outbound {
                me: ActorId::Node(node.me),
                format,
                accounting: &mut node.accounting,
                buffer: &mut node.buffer,
            }
            .send(
                Channel::Consensus(node.me),
                message,
                &node.readers,
                |bytes| {
                    for &(to, k) in writes {
                        let slot = pages[to].slot(k);
                        // SAFETY: one writer per slot, and its reader reads the
                        // bytes only after the sequence below.
                        let dst = slot.bytes.as_ptr().cast_mut();
                        unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), dst, bytes.len()) };
                        slot.len.store(bytes.len() as u32, Ordering::Relaxed);
                        slot.sequence.fetch_add(1, Ordering::Release);
                    }
                    Ok(())
                },
            )
            .unwrap();
        }

        fn receive(&mut self, n: usize, out: &mut Vec<Message>) -> usize {
            let now: Duration = self.start.elapsed();
            let node = &mut self.nodes[n];
            let page = &self.pages[n];
            let mut inbound = Inbound {
                me: ActorId::Node(node.me),
                format: &self.format,
                accounting: &mut node.accounting,
                shaper: &mut node.shaper,
            };
            for (k, (from, seen)) in node.senders.iter_mut().enumerate() {
                let slot = page.slot(k);
                let sequence = slot.sequence.load(Ordering::Acquire);
                if sequence == *seen {
                    continue;
                }
                *seen = sequence;
                let len = slot.len.load(Ordering::Relaxed) as usize;
                inbound.arrive(ActorId::Node(*from), &slot.bytes[..len], now, out);
            }
            out.len()
        }
    }
}

/// Writes a byte of every `stride` bytes of `memory`: with a stride of a
/// cache line, what the other processes of a core do to its caches and
/// TLB between two turns of one node; with a stride of a page, to its TLB
/// alone (and a few cache sets).
fn evict(memory: &mut [u8], stride: usize) {
    for line in memory.iter_mut().step_by(stride) {
        *line = line.wrapping_add(1);
    }
    std::hint::black_box(memory);
}

/// Keeps `memory` in 4 KiB pages where transparent huge pages are on, so
/// that a page stride takes a TLB entry per page, as other processes do.
fn small_pages(memory: &mut [u8]) {
    let page = 4096;
    let start = (memory.as_ptr() as usize).next_multiple_of(page);
    let end = (memory.as_ptr() as usize + memory.len()) / page * page;
    // SAFETY: advice on whole pages inside the vector's own allocation.
    unsafe {
        libc::madvise(
            start as *mut libc::c_void,
            end - start,
            libc::MADV_NOHUGEPAGE,
        )
    };
}

/// More than a core's 1 MiB second-level cache and its TLB's reach, and
/// half the shared third level: 100 nodes on two cores touch some 10 MiB
/// between two turns of one (50 processes of 100–300 KiB each).
const OTHERS_TOUCH: usize = 16 << 20;

/// The three ways a round runs: with nothing between two turns of a
/// node, or with the other processes' writes at a stride of a cache line
/// or of a page.
const BETWEEN_TURNS: [(&str, Option<usize>); 3] = [
    ("caches warm", None),
    ("caches cold", Some(64)),
    ("TLB cold", Some(4096)),
];

/// Each round of a run a new (step, round) on the wire.
struct RoundNumbers {
    step: u32,
    round: u16,
}

impl RoundNumbers {
    fn next(&mut self) -> (u32, u16) {
        self.round = self.round.wrapping_add(1);
        if self.round == 0 {
            self.step += 1;
        }
        (self.step, self.round)
    }
}

/// Times `net`'s rounds each of the three ways.
fn bench_rounds(
    g: &mut BenchmarkGroup<'_, WallTime>,
    what: &str,
    net: &mut impl Exchange,
    numbers: &mut RoundNumbers,
    inbox: &mut Vec<Message>,
    others: &mut [u8],
) {
    for (name, stride) in BETWEEN_TURNS {
        g.bench_function(format!("{what}, 100 nodes, {name}"), |b| {
            b.iter_custom(|iterations| {
                let mut took = Duration::ZERO;
                for _ in 0..iterations {
                    let (step, r) = numbers.next();
                    took += round(net, step, r, inbox, || {
                        if let Some(stride) = stride {
                            evict(others, stride)
                        }
                    })
                    .1;
                }
                took
            })
        });
    }
}

fn bench(c: &mut Criterion) {
    let (scenario, topology) = grid();
    let mut net = network(&scenario, &topology);
    let mut boxes = inbox::Inboxes::new(&topology, scenario.wire_format(&topology), &net.ledgers);
    let mut inbox = Vec::new();
    let (per_round, _) = round(&mut net, 0, 0, &mut inbox, || {});
    let expected: usize = net.nodes.iter().map(|(_, r)| r.len()).sum();
    assert_eq!(per_round, expected, "a round lost messages");
    let (read, _) = round(&mut boxes, 0, 0, &mut inbox, || {});
    assert_eq!(read, per_round, "an inbox round lost messages");
    println!("a round of the 10 × 10 grid: {per_round} messages received");
    let mut others = vec![0u8; OTHERS_TOUCH];
    small_pages(&mut others);
    let mut numbers = RoundNumbers { step: 1, round: 0 };
    let mut g = c.benchmark_group("message_path");
    g.throughput(Throughput::Elements(per_round as u64));
    g.measurement_time(Duration::from_secs(5));
    bench_rounds(
        &mut g,
        "consensus round",
        &mut net,
        &mut numbers,
        &mut inbox,
        &mut others,
    );
    bench_rounds(
        &mut g,
        "inbox round",
        &mut boxes,
        &mut numbers,
        &mut inbox,
        &mut others,
    );
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
