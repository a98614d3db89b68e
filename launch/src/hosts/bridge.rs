//! A host's bridge: iceoryx2 on the host, Zenoh between hosts.
//!
//! Two threads, one per direction, because an iceoryx2 port belongs to the
//! thread that made it and each direction blocks on its own source:
//! - **out**: sleeps on the host's bridge wake-up service. An actor that
//!   sends to another host wakes it, naming the far receiver; it then takes
//!   every waiting message on the channels other hosts read and sends one
//!   batch per destination host: the samples, then the wake-ups.
//! - **in**: blocks on its Zenoh subscription; publishes each sample of a
//!   batch on the host, then wakes the receivers named.
//!
//! A batch is bytes from another process: one that does not decode, or a
//! sample on a channel this host does not take in, is counted and dropped.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;
use fusion_graph::hosts::{BridgeCounts, HostConfig, Placement};
use fusion_graph::{ActorId, Topology};
use serde::{Deserialize, Serialize};
use transport::world_memory::TruthRing;
use transport::{BridgeInlet, BridgeOutlet, Channel, RunId};
use zenoh::Wait;

use super::{bridge_key, decode, encode};

/// How long each direction sleeps before checking whether to stop. The out
/// side also drains its channels then: a message sent to another host
/// without waking anyone there (a consensus round's message to a neighbour
/// it no longer waits for) leaves at the latest now.
const POLL: Duration = Duration::from_millis(20);

/// One item of a batch between hosts.
#[derive(Debug, Clone, Serialize, Deserialize)]
enum Frame {
    /// A message's bytes as published on `channel`, untouched.
    Sample { channel: Channel, bytes: Vec<u8> },
    /// Wake this actor (after the samples before it are published).
    Wake(ActorId),
}

/// A running bridge: its two threads and their counts.
pub struct Bridge {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    counts: Arc<Mutex<CountsLedger>>,
}

/// The bridge's counts, mirrored in a file that outlives its agent, as
/// the actors' ledgers outlive them: an agent killed with SIGKILL and
/// started again for the same run goes on counting from where the file
/// says. Two slots and a sequence number: a slot is written whole before
/// the number names it, so a kill mid-write leaves the slot before.
pub struct CountsLedger {
    map: memmap2::MmapMut,
    counts: BridgeCounts,
}

/// Bytes of one slot: a `BridgeCounts` in bincode's fixed-width form.
const SLOT_BYTES: usize = 256;

impl CountsLedger {
    /// The ledger at `path`, with the counts it holds (none if new).
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .with_context(|| format!("opening {}", path.display()))?;
        let len = (8 + 2 * SLOT_BYTES) as u64;
        if file.metadata()?.len() < len {
            file.set_len(len)?;
        }
        // SAFETY: the file is this agent's own, under its run's folder; no
        // other process maps it while the agent lives.
        let map = unsafe { memmap2::MmapMut::map_mut(&file) }?;
        let counts = Self::read(&map).unwrap_or_default();
        Ok(Self { map, counts })
    }

    fn read(map: &[u8]) -> Option<BridgeCounts> {
        let seq = u64::from_le_bytes(map[..8].try_into().ok()?);
        if seq == 0 {
            return None;
        }
        let at = 8 + (seq % 2) as usize * SLOT_BYTES;
        bincode::serde::decode_from_slice(&map[at..at + SLOT_BYTES], fixed())
            .ok()
            .map(|(c, _)| c)
    }

    /// Adds `c` and writes the total down.
    pub fn add(&mut self, c: &BridgeCounts) {
        self.counts.add(c);
        let seq = u64::from_le_bytes(self.map[..8].try_into().expect("8 bytes")) + 1;
        let at = 8 + (seq % 2) as usize * SLOT_BYTES;
        if bincode::serde::encode_into_slice(
            self.counts,
            &mut self.map[at..at + SLOT_BYTES],
            fixed(),
        )
        .is_ok()
        {
            self.map[..8].copy_from_slice(&seq.to_le_bytes());
        }
    }

    pub fn counts(&self) -> BridgeCounts {
        self.counts
    }
}

fn fixed() -> bincode::config::Configuration<bincode::config::LittleEndian, bincode::config::Fixint>
{
    bincode::config::standard().with_fixed_int_encoding()
}

/// The world on a host other than the launcher's: its sensors cannot map
/// the launcher's memory, so the agent computes the truth itself, from the
/// scenario's seed as the launcher does, and writes it into its host's
/// ring. It writes a step before it delivers the first of the launcher's
/// messages of that step (a node's `BeginStep`): no node on this host can
/// activate a sensor for a step the ring does not hold yet.
pub struct HostWorld {
    ring: TruthRing,
    world: crate::world::World,
    written: u32,
    /// The scenario's last step: a message naming a later one (forged or
    /// damaged) moves the world no further.
    last: u32,
}

impl HostWorld {
    pub fn create(domain: &RunId, scenario: &fusion_graph::Scenario) -> anyhow::Result<Self> {
        Ok(Self {
            ring: TruthRing::create(domain).context("making this host's world memory")?,
            world: crate::world::World::new(scenario)?,
            written: 0,
            last: scenario.steps,
        })
    }

    /// Writes every step up to `step` not written yet.
    fn advance_to(&mut self, step: u32) {
        while self.written < step.min(self.last) {
            self.written += 1;
            let truth = self.world.advance();
            self.ring.write(self.written, &truth);
        }
    }
}

/// Where a bridge stands, which both its directions need to know: the
/// run, this host's domain and place among the hosts, and the network.
#[derive(Clone)]
pub struct Setting {
    pub run: String,
    pub domain: RunId,
    pub placement: Placement,
    pub host: usize,
    pub topology: Topology,
}

impl Bridge {
    /// Opens host `setting.host`'s ports in its domain and starts both
    /// directions; returns once both are ready, or with the first one's
    /// error. `world`: this host's world, when it is not the launcher's.
    pub fn start(
        session: &zenoh::Session,
        setting: Setting,
        ledger: &Path,
        world: Option<HostWorld>,
    ) -> anyhow::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let counts = Arc::new(Mutex::new(CountsLedger::open(ledger)?));
        let (ready_tx, ready_rx) = mpsc::channel::<anyhow::Result<()>>();
        let mut threads = Vec::new();
        let mut world = Some(world);
        for direction in ["out", "in"] {
            let (setting, session, stop, counts, ready) = (
                setting.clone(),
                session.clone(),
                stop.clone(),
                counts.clone(),
                ready_tx.clone(),
            );
            let world = if direction == "in" {
                world.take().flatten()
            } else {
                None
            };
            let thread = std::thread::Builder::new()
                .name(format!("bridge-{direction}"))
                .spawn(move || {
                    let result = if direction == "out" {
                        run_out(&setting, &session, &stop, &counts, &ready)
                    } else {
                        run_in(&setting, &session, &stop, &counts, &ready, world)
                    };
                    if let Err(e) = result {
                        tracing::error!(error = %format!("{e:#}"), "bridge {direction} stopped");
                        let _ = ready.send(Err(e));
                    }
                })
                .context("starting a bridge thread")?;
            threads.push(thread);
        }
        let bridge = Self {
            stop,
            threads,
            counts,
        };
        for _ in 0..2 {
            ready_rx
                .recv()
                .context("a bridge thread ended before it was ready")??;
        }
        Ok(bridge)
    }

    /// The counts so far, with the agent's TCP sockets read now.
    pub fn counts(&self) -> BridgeCounts {
        let mut c = self.counts.lock().expect("bridge counts").counts();
        let tcp = tcp_totals();
        c.tcp_bytes_acked = tcp.0;
        c.tcp_bytes_received = tcp.1;
        c.tcp_segments_out = tcp.2;
        c
    }

    pub fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn run_out(
    s: &Setting,
    session: &zenoh::Session,
    stop: &AtomicBool,
    counts: &Mutex<CountsLedger>,
    ready: &mpsc::Sender<anyhow::Result<()>>,
) -> anyhow::Result<()> {
    let outlet = BridgeOutlet::open(&s.domain, &s.placement, s.host, &s.topology)?;
    let far: HashMap<Channel, Vec<usize>> = s
        .placement
        .outgoing(s.host, &s.topology)
        .into_iter()
        .collect();
    let hosts = s.placement.hosts();
    let mut publishers = HashMap::new();
    for (g, host) in hosts.iter().enumerate().filter(|(g, _)| *g != s.host) {
        let p = session
            .declare_publisher(bridge_key(&s.run, &host.name))
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .express(true)
            .wait()
            .map_err(|e| {
                anyhow::anyhow!("declaring the bridge's publisher to {}: {e}", host.name)
            })?;
        publishers.insert(g, p);
    }
    await_far_subscribers(&publishers, hosts);
    let _ = ready.send(Ok(()));
    let mut woken = Vec::new();
    let mut batches: Vec<Vec<Frame>> = vec![Vec::new(); hosts.len()];
    let mut sent = BridgeCounts::default();
    while !stop.load(Ordering::Relaxed) {
        outlet.wait(POLL, &mut woken)?;
        outlet.drain(|channel, bytes| {
            for g in far.get(&channel).into_iter().flatten() {
                batches[*g].push(Frame::Sample {
                    channel,
                    bytes: bytes.to_vec(),
                });
                sent.messages_sent += 1;
                sent.message_bytes_sent += bytes.len() as u64;
            }
        })?;
        // After the samples: a receiver woken finds its message there.
        for actor in woken.drain(..) {
            let g = s.placement.host_of(actor);
            if g != s.host {
                batches[g].push(Frame::Wake(actor));
                sent.wakes_sent += 1;
            }
        }
        for (g, batch) in batches.iter_mut().enumerate() {
            if batch.is_empty() {
                continue;
            }
            let bytes = encode(batch);
            sent.batches_sent += 1;
            sent.batch_bytes_sent += bytes.len() as u64;
            publishers[&g]
                .put(bytes)
                .wait()
                .map_err(|e| anyhow::anyhow!("sending a batch to {}: {e}", hosts[g].name))?;
            batch.clear();
        }
        counts
            .lock()
            .expect("bridge counts")
            .add(&std::mem::take(&mut sent));
    }
    Ok(())
}

/// How long a bridge waits for the other hosts' bridges to be heard
/// subscribing before it says it is ready all the same.
const FAR_SUBSCRIBERS_AT_MOST: Duration = Duration::from_secs(10);

/// Waits until every other host's bridge is known to subscribe to what
/// this one publishes, or [`FAR_SUBSCRIBERS_AT_MOST`] has passed. Zenoh
/// drops a put that no subscriber it knows of matches, and another host's
/// subscription reaches this session only after its link's delay: a bridge
/// that said it was ready at once lost the first messages to a host behind
/// a slow link (the step's `BeginStep`, so that host's nodes coasted
/// through the step and every figure after it differed).
fn await_far_subscribers(
    publishers: &HashMap<usize, zenoh::pubsub::Publisher<'_>>,
    hosts: &[HostConfig],
) {
    let until = std::time::Instant::now() + FAR_SUBSCRIBERS_AT_MOST;
    for (g, p) in publishers {
        while !p.matching_status().wait().is_ok_and(|m| m.matching()) {
            if std::time::Instant::now() >= until {
                tracing::warn!(host = %hosts[*g].name, "no bridge heard subscribing there; going on");
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

fn run_in(
    s: &Setting,
    session: &zenoh::Session,
    stop: &AtomicBool,
    counts: &Mutex<CountsLedger>,
    ready: &mpsc::Sender<anyhow::Result<()>>,
    mut world: Option<HostWorld>,
) -> anyhow::Result<()> {
    let inlet = BridgeInlet::open(&s.domain, &s.placement, s.host, &s.topology)?;
    let me = &s.placement.hosts()[s.host].name;
    let subscriber = session
        .declare_subscriber(bridge_key(&s.run, me))
        .wait()
        .map_err(|e| anyhow::anyhow!("subscribing to the bridge's key: {e}"))?;
    let _ = ready.send(Ok(()));
    while !stop.load(Ordering::Relaxed) {
        let sample = match subscriber.recv_timeout(POLL) {
            Ok(Some(sample)) => sample,
            Ok(None) => continue,
            Err(e) => anyhow::bail!("the bridge's subscription ended: {e}"),
        };
        let bytes = sample.payload().to_bytes();
        let got = deliver(&inlet, &bytes, world.as_mut());
        counts.lock().expect("bridge counts").add(&got);
    }
    Ok(())
}

/// Publishes one batch on this host and wakes whom it names; a message of
/// the launcher's first moves this host's world on to its step.
fn deliver(inlet: &BridgeInlet, bytes: &[u8], mut world: Option<&mut HostWorld>) -> BridgeCounts {
    let mut c = BridgeCounts {
        batches_received: 1,
        batch_bytes_received: bytes.len() as u64,
        ..Default::default()
    };
    let Some(frames) = decode::<Vec<Frame>>(bytes) else {
        tracing::warn!(
            len = bytes.len(),
            "a batch from another host did not decode; dropped"
        );
        c.malformed_batches = 1;
        return c;
    };
    for frame in frames {
        let taken = match frame {
            Frame::Sample { channel, bytes } => {
                if let (Some(w), ActorId::Launcher) = (world.as_deref_mut(), channel.publisher()) {
                    if let Some(step) = wire::peek_step(&bytes) {
                        w.advance_to(step);
                    }
                }
                let ok = inlet.takes(channel) && inlet.publish(channel, &bytes).is_ok();
                if ok {
                    c.messages_received += 1;
                    c.message_bytes_received += bytes.len() as u64;
                }
                ok
            }
            Frame::Wake(actor) => inlet.wake(actor),
        };
        if !taken {
            c.refused_frames += 1;
        }
    }
    c
}

/// Bytes acknowledged and received, and segments sent, over every TCP
/// socket of this process (Zenoh's links): `TCP_INFO` of each.
fn tcp_totals() -> (u64, u64, u64) {
    let mut total = (0, 0, 0);
    let Ok(fds) = std::fs::read_dir("/proc/self/fd") else {
        return total;
    };
    for entry in fds.flatten() {
        let is_socket = std::fs::read_link(entry.path())
            .is_ok_and(|t| t.to_string_lossy().starts_with("socket:"));
        let Some(fd) = entry
            .file_name()
            .to_str()
            .and_then(|f| f.parse::<i32>().ok())
        else {
            continue;
        };
        if !is_socket {
            continue;
        }
        // SAFETY: tcp_info is plain data; the kernel writes at most `len`
        // bytes and fails on a socket that is not TCP.
        let mut info: libc::tcp_info = unsafe { std::mem::zeroed() };
        let mut len = std::mem::size_of::<libc::tcp_info>() as libc::socklen_t;
        let r = unsafe {
            libc::getsockopt(
                fd,
                libc::IPPROTO_TCP,
                libc::TCP_INFO,
                (&mut info as *mut libc::tcp_info).cast(),
                &mut len,
            )
        };
        if r == 0 {
            total.0 += info.tcpi_bytes_acked;
            total.1 += info.tcpi_bytes_received;
            total.2 += u64::from(info.tcpi_segs_out);
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_round_trips_and_garbage_does_not_decode() {
        let batch = vec![
            Frame::Sample {
                channel: Channel::Consensus(3),
                bytes: vec![1, 2, 3],
            },
            Frame::Wake(ActorId::Node(4)),
        ];
        let bytes = encode(&batch);
        let back: Vec<Frame> = decode(&bytes).unwrap();
        assert!(
            matches!(back[0], Frame::Sample { channel: Channel::Consensus(3), ref bytes } if bytes == &[1, 2, 3])
        );
        assert!(matches!(back[1], Frame::Wake(ActorId::Node(4))));
        assert!(decode::<Vec<Frame>>(&[0xff; 7]).is_none());
    }
}
