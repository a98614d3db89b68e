//! The iceoryx2 transport: zero-copy shared-memory publish/subscribe between
//! processes on one machine, one service per channel named
//! `cqnet/<run>/<channel>`, and one event service per actor
//! (`cqnet/<run>/wake/<actor>`) so an idle actor sleeps instead of polling.
//!
//! Every resource of a run lives under the prefix `cqnet_<run>_`, so two runs
//! never see each other and cleanup is removing that prefix's files.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

use super::futex;
use super::{Channel, Inbound, Outbound, Transport};
use crate::accounting::Accounting;
use crate::actor::ActorId;
use crate::hosts::{actor_of_wake_id, wake_id, Placement};
use crate::ledger::Ledger;
use crate::shaper::LinkShaper;
use crate::topology::Topology;
use crate::wire::{Message, MessageKind, WireFormat, HEADER_BYTES};
use crate::{BackendError, ReceiveError, SendError, SetupError, WaitError};

/// Where iceoryx2 keeps its files besides `/dev/shm`.
/// Where iceoryx2 keeps a run's service and node files: on tmpfs beside the
/// shared memory. On the default `/tmp/iceoryx2` (ext4 here) a fifth of the
/// start-up CPU of 936 processes went to the file system allocating inodes
/// among the many that earlier runs created and deleted.
const ICEORYX_ROOT: &str = "/dev/shm/cqnet-iceoryx2/";
/// The default root, where runs of earlier versions left their files.
const LEGACY_ICEORYX_ROOT: &str = "/tmp/iceoryx2";
/// Where shared memory lives: iceoryx2's segments and the run's own files
/// (`map_run_memory`).
const SHARED_MEMORY: &str = "/dev/shm";
/// What cleanup searches (recursively): the shared memory, whose tree holds
/// `ICEORYX_ROOT`, and the legacy root.
const RESOURCE_DIRS: [&str; 2] = [SHARED_MEMORY, LEGACY_ICEORYX_ROOT];
/// How often to retry opening a service that another process is creating.
const OPEN_ATTEMPTS: u32 = 100;
/// The shortest wait handed to iceoryx2's timed wait; shorter ones poll.
const MIN_TIMED_WAIT: Duration = Duration::from_micros(1);

/// A run's identity: lowercase letters, digits and `-`, at most 32 characters.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct RunId(String);

impl RunId {
    pub fn new(id: &str) -> Result<Self, SetupError> {
        let ok = !id.is_empty()
            && id.len() <= 32
            && id
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-');
        if !ok {
            return Err(SetupError::BadRunId { id: id.into() });
        }
        Ok(Self(id.into()))
    }

    /// A fresh id from the process id and the clock.
    pub fn generate() -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        Self(format!("r{}-{:x}", std::process::id(), nanos & 0xffff_ffff))
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The file-name prefix of every iceoryx2 resource of this run.
    pub fn prefix(&self) -> String {
        format!("cqnet_{}_", self.0.replace('-', "_"))
    }

    pub(crate) fn config(&self, sweep: DeadNodeSweep) -> Result<Config, SetupError> {
        let mut config = Config::default();
        config.global.prefix =
            FileName::new(self.prefix().as_bytes()).map_err(|e| setup("run prefix", e))?;
        config
            .global
            .set_root_path(&Path::new(ICEORYX_ROOT.as_bytes()).map_err(|e| setup("root path", e))?);
        let on = sweep == DeadNodeSweep::On;
        config.global.node.cleanup_dead_nodes_on_creation = on;
        config.global.node.cleanup_dead_nodes_on_destruction = on;
        config.global.service.cleanup_dead_nodes_on_open = on;
        Ok(config)
    }

    fn service_name(&self, suffix: &str) -> Result<ServiceName, SetupError> {
        ServiceName::new(&format!("cqnet/{}/{suffix}", self.0)).map_err(|e| setup(suffix, e))
    }
}

impl std::fmt::Display for RunId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// Removes every file of a run's iceoryx2 resources (shared memory and the
/// static service files). Returns how many were removed. Call it only once
/// every process of the run has exited and been reaped.
pub fn remove_run_resources(run: &RunId) -> std::io::Result<usize> {
    let prefix = run.prefix();
    let mut removed = 0;
    for dir in RESOURCE_DIRS {
        removed += remove_with_prefix(std::path::Path::new(dir), &prefix)?;
    }
    Ok(removed)
}

/// Memory the run's processes share beside iceoryx2's (the tables' rows,
/// `bounds::shared_rows`): a file on tmpfs named with the run's prefix, so
/// that [`remove_run_resources`] and the sweep of abandoned runs remove it
/// with the rest. Made `len` bytes long, zeroed, by whichever process opens
/// it first; the others map what it made.
pub fn map_run_memory(run: &RunId, name: &str, len: usize) -> std::io::Result<memmap2::MmapMut> {
    let path = std::path::Path::new(SHARED_MEMORY).join(format!("{}{name}", run.prefix()));
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)?;
    // Growing a file to the length it has already changes nothing, so two
    // processes that both find it short cannot undo each other's rows.
    if file.metadata()?.len() < len as u64 {
        file.set_len(len as u64)?;
    }
    // SAFETY: the file belongs to this run and only its processes map it;
    // none shrinks it (all grow it to the same length, at most).
    unsafe { memmap2::MmapOptions::new().len(len).map_mut(&file) }
}

/// Where launchers register their runs: one file per run id, holding the
/// launcher's pid and its start time (so a reused pid is not mistaken for it).
const RUN_REGISTRY: &str = "/tmp/cqnet-runs";

/// A launcher's claim on its run's resources, held for the run's lifetime.
/// A launcher killed with SIGKILL cannot clean up; its lease outlives it,
/// and [`sweep_abandoned_runs`] finds the run by it.
#[derive(Debug)]
pub struct RunLease {
    path: std::path::PathBuf,
}

impl RunLease {
    /// Registers `run` as this process's.
    pub fn acquire(run: &RunId) -> std::io::Result<Self> {
        std::fs::create_dir_all(RUN_REGISTRY)?;
        let pid = std::process::id();
        let started = process_start_time(pid).unwrap_or_default();
        let path = std::path::Path::new(RUN_REGISTRY).join(run.as_str());
        std::fs::write(&path, format!("{pid} {started}\n"))?;
        Ok(Self { path })
    }
}

impl Drop for RunLease {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Removes the resources of every registered run whose launcher is gone
/// (no process with its pid and start time), and their leases; runs whose
/// launcher lives are left alone. Returns the runs cleaned.
pub fn sweep_abandoned_runs() -> std::io::Result<Vec<RunId>> {
    let mut cleaned = Vec::new();
    let entries = match std::fs::read_dir(RUN_REGISTRY) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(cleaned),
        Err(e) => return Err(e),
    };
    for entry in entries.flatten() {
        let Ok(run) = RunId::new(&entry.file_name().to_string_lossy()) else {
            continue;
        };
        let lease = std::fs::read_to_string(entry.path()).unwrap_or_default();
        let mut fields = lease.split_whitespace();
        let pid = fields.next().and_then(|p| p.parse::<u32>().ok());
        let started = fields.next().and_then(|t| t.parse::<u64>().ok());
        let alive = match (pid, started) {
            (Some(pid), Some(started)) => process_start_time(pid) == Some(started),
            _ => false,
        };
        if !alive {
            remove_run_resources(&run)?;
            let _ = std::fs::remove_file(entry.path());
            cleaned.push(run);
        }
    }
    Ok(cleaned)
}

/// A process's start time in clock ticks since boot (`/proc/<pid>/stat`,
/// field 22); `None` if there is no such process.
fn process_start_time(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) is in parentheses and may hold spaces.
    let after_name = &stat[stat.rfind(')')? + 2..];
    after_name.split_whitespace().nth(19)?.parse().ok()
}

/// Files of the run that still exist (for cleanup checks).
pub fn run_resources(run: &RunId) -> Vec<std::path::PathBuf> {
    let prefix = run.prefix();
    let mut found = Vec::new();
    for dir in RESOURCE_DIRS {
        collect_with_prefix(std::path::Path::new(dir), &prefix, &mut found);
    }
    found
}

fn collect_with_prefix(dir: &std::path::Path, prefix: &str, found: &mut Vec<std::path::PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        if e.file_name().to_string_lossy().starts_with(prefix) {
            found.push(path);
        } else if path.is_dir() {
            collect_with_prefix(&path, prefix, found);
        }
    }
}

fn remove_with_prefix(dir: &std::path::Path, prefix: &str) -> std::io::Result<usize> {
    let mut found = Vec::new();
    collect_with_prefix(dir, prefix, &mut found);
    let mut n = 0;
    let mut parents = std::collections::BTreeSet::new();
    for p in found {
        let r = if p.is_dir() {
            std::fs::remove_dir_all(&p)
        } else {
            std::fs::remove_file(&p)
        };
        match r {
            Ok(()) => n += 1,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e),
        }
        if let Some(parent) = p.parent().filter(|parent| *parent != dir) {
            parents.insert(parent.to_path_buf());
        }
    }
    // iceoryx2 keeps each node's files in a directory named by the node's
    // id, without the run's prefix: the ones this removal emptied are the
    // run's. (Left behind, 15,297 had piled up on the development machine.)
    for parent in parents {
        if std::fs::remove_dir(&parent).is_ok() {
            n += 1;
        }
    }
    Ok(n)
}

/// How old an empty node directory must be before a sweep takes it: a
/// live node's directory is empty for a moment between its creation and
/// its first file.
const EMPTY_NODE_DIR_AGE: Duration = Duration::from_secs(60);

/// Removes the empty node directories older than a minute that runs from
/// before cleanup removed them left in iceoryx2's node folders. Returns
/// how many were removed.
pub fn remove_stale_node_directories() -> std::io::Result<usize> {
    let mut removed = 0;
    for root in [ICEORYX_ROOT, LEGACY_ICEORYX_ROOT] {
        let nodes = std::path::Path::new(root).join("nodes");
        let entries = match std::fs::read_dir(&nodes) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(e),
        };
        for e in entries.flatten() {
            let old_enough = e
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| t.elapsed().ok())
                .is_some_and(|age| age >= EMPTY_NODE_DIR_AGE);
            // remove_dir refuses a directory with anything in it.
            if old_enough && std::fs::remove_dir(e.path()).is_ok() {
                removed += 1;
            }
        }
    }
    Ok(removed)
}

type Sub = Subscriber<futex::Service, [u8], ()>;
type Pub = Publisher<futex::Service, [u8], ()>;
type PortFactory =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<futex::Service, [u8], ()>;

/// Opens (or creates) a channel's service, sized for its readers the same
/// way by every actor and by a host's bridge.
fn open_channel(
    node: &Node<futex::Service>,
    run: &RunId,
    topology: &Topology,
    channel: Channel,
) -> Result<PortFactory, SetupError> {
    let name = run.service_name(&channel.service_suffix())?;
    // +1 subscriber: on a host of several, the bridge reads what leaves it.
    let subs = channel.subscribers(topology) + 1;
    // +1 publisher: a test may inject raw bytes through a second one.
    retry(|| {
        node.service_builder(&name)
            .publish_subscribe::<[u8]>()
            .max_publishers(2)
            .max_subscribers(subs)
            .max_nodes(subs + 3)
            .subscriber_max_buffer_size(buffer_len(channel))
            .history_size(0)
            .open_or_create()
    })
    .map_err(|e| setup(&channel.service_suffix(), e))
}

/// How an actor wakes actors of other hosts: through its own host's
/// bridge, whose wake-up service takes the far actor's
/// [`wake_id`](crate::hosts::wake_id) as the event id.
struct FarWakes {
    placement: Placement,
    host: usize,
    bridge: Option<Notifier<futex::Service>>,
    ids: HashMap<ActorId, EventId>,
}

pub struct IceoryxTransport {
    me: ActorId,
    run: RunId,
    topology: Topology,
    format: WireFormat,
    start: Instant,
    node: Node<futex::Service>,
    publishers: HashMap<Channel, Pub>,
    subscribers: Vec<(Channel, Sub)>,
    /// Which subscriptions were heard from since the last `receive`: see
    /// [`Heard`].
    heard: Heard,
    listener: Listener<futex::Service>,
    /// Each receiver's notifier, with the event id our wake-ups carry in
    /// its service ([`WakeIds`]).
    notifiers: HashMap<ActorId, (Notifier<futex::Service>, EventId)>,
    /// Second publishers used by [`inject_raw`](Self::inject_raw).
    raw_publishers: HashMap<Channel, Pub>,
    /// On a host of several: how actors of the other hosts are woken.
    far: Option<FarWakes>,
    accounting: Accounting,
    shaper: LinkShaper,
    buffer: Vec<u8>,
}

/// Largest message each channel carries, which sizes its shared memory.
fn max_message_len(channel: Channel) -> usize {
    HEADER_BYTES
        + match channel {
            Channel::Tick | Channel::Observation(_) => 48,
            // The mask, and the censoring feedback: an estimate and its
            // packed covariance.
            Channel::Activation(_) => 48 + 32 + 80,
            Channel::Consensus(_) => 300,
            // A posterior swapped in a random exchange: mean and covariance.
            Channel::Pair { .. } => 120,
            Channel::Control(_) | Channel::Telemetry(_) => 240,
        }
}

/// Queue depth per subscriber, well above any burst the protocol produces (a
/// consensus neighbour may be a step ahead). A full queue overwrites its
/// oldest sample rather than blocking the sender, so that a stopped receiver
/// cannot stall the network; such losses show as sent-but-unaccounted
/// messages in the results. Seen here with iceoryx2 0.10: a burst larger than
/// the queue, sent before the subscriber's first receive, lost the whole
/// burst rather than only the oldest samples.
fn buffer_len(_channel: Channel) -> usize {
    QUEUE_DEPTH
}

/// The depth of every subscriber's queue ([`buffer_len`]): what a receiver
/// that does not run may fall behind by before its oldest messages are
/// overwritten.
pub const QUEUE_DEPTH: usize = 64;

/// Whether creating (and dropping) an iceoryx2 node, and opening a service,
/// first sweep the resources of dead nodes of the run. Both sweeps are
/// linear in the network, so with every actor starting at once they made
/// start-up quadratic:
/// - the node sweep lists every node of the run, and the processes queued
///   on the node directory's lock (936 processes took 110 s);
/// - the service sweep reads the details of every node attached to the
///   service, and every actor opens the tick service, to which all of them
///   are attached (2,600 processes: a fifth of all CPU time in start-up,
///   240 ready after 120 s).
///
/// At a run's first start nothing has died yet, and the launcher removes
/// everything at the end; an actor restarted after a kill still sweeps, so
/// that its dead predecessor's ports do not hold places it needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeadNodeSweep {
    On,
    Off,
}

impl IceoryxTransport {
    /// Creates this actor's iceoryx2 node and its wake-up listener.
    pub fn new(
        run: &RunId,
        me: ActorId,
        topology: &Topology,
        format: WireFormat,
        seed: u64,
    ) -> Result<Self, SetupError> {
        Self::with_sweep(run, me, topology, format, seed, DeadNodeSweep::On)
    }

    /// [`new`](Self::new), saying whether to sweep dead nodes first.
    pub fn with_sweep(
        run: &RunId,
        me: ActorId,
        topology: &Topology,
        format: WireFormat,
        seed: u64,
        sweep: DeadNodeSweep,
    ) -> Result<Self, SetupError> {
        let config = run.config(sweep)?;
        let name = NodeName::new(&me.to_string()).map_err(|e| setup("node name", e))?;
        let node = NodeBuilder::new()
            .config(&config)
            .name(&name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<futex::Service>()
            .map_err(|e| setup("node", e))?;
        let mut t = Self {
            me,
            run: run.clone(),
            topology: topology.clone(),
            format,
            start: Instant::now(),
            listener: open_wake(&node, run, me, topology)?
                .listener_builder()
                .create()
                .map_err(|e| setup("listener", e))?,
            node,
            publishers: HashMap::new(),
            subscribers: Vec::new(),
            heard: Heard::new(me, topology),
            notifiers: HashMap::new(),
            raw_publishers: HashMap::new(),
            far: None,
            accounting: Accounting::default(),
            shaper: LinkShaper::new(seed),
            buffer: Vec::with_capacity(512),
        };
        t.start = Instant::now();
        Ok(t)
    }

    fn open_channel(&self, channel: Channel) -> Result<PortFactory, SetupError> {
        open_channel(&self.node, &self.run, &self.topology, channel)
    }

    fn add_publisher(&mut self, channel: Channel) -> Result<(), SetupError> {
        let service = self.open_channel(channel)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(max_message_len(channel))
            .create()
            .map_err(|e| setup("publisher", e))?;
        self.publishers.insert(channel, publisher);
        Ok(())
    }

    /// Publishes raw bytes on `channel` through a second publisher, bypassing
    /// encoding: fault injection for tests of the malformed-message path.
    pub fn inject_raw(&mut self, channel: Channel, bytes: &[u8]) -> Result<(), SendError> {
        if !self.raw_publishers.contains_key(&channel) {
            let p = self
                .open_channel(channel)
                .and_then(|service| {
                    service
                        .publisher_builder()
                        .initial_max_slice_len(max_message_len(channel))
                        .create()
                        .map_err(|e| setup("publisher", e))
                })
                .map_err(|e| SendError::Backend {
                    channel: channel.service_suffix(),
                    source: Box::new(e),
                })?;
            // Kept: a publisher's samples vanish with it.
            self.raw_publishers.insert(channel, p);
        }
        let p = &self.raw_publishers[&channel];
        let _ = p.update_connections();
        publish(p, bytes).map_err(|source| SendError::Backend {
            channel: channel.service_suffix(),
            source,
        })
    }

    /// Takes the wake-ups that come within `timeout` (none: a poll), noting
    /// whom they came from in `heard`, and says whether there were any.
    fn take_wake_ups(&mut self, timeout: Duration) -> Result<bool, WaitError> {
        let mut woken = false;
        let heard = &mut self.heard;
        listen(&self.listener, timeout, |activation| {
            woken = true;
            heard.hear(activation.id.as_value());
        })?;
        Ok(woken)
    }

    pub fn run(&self) -> &RunId {
        &self.run
    }

    /// Mirrors every count into the ledger at `path` from now on, continuing
    /// what an earlier incarnation of this actor left there, so that a
    /// SIGKILL loses nothing counted (see [`crate::ledger`]). Call it before
    /// the first message.
    pub fn keep_counts_in(&mut self, path: &std::path::Path) -> Result<(), SetupError> {
        // Every (from, to, kind) the actor can count: each peer, both ways,
        // every kind and the malformed.
        let kinds = (0..=u8::MAX).filter_map(MessageKind::from_u8).count() + 1;
        let capacity = self.topology.peers(self.me) * 2 * kinds;
        let ledger = Ledger::open_or_create(path, capacity).map_err(|e| setup("ledger", e))?;
        self.accounting = Accounting::backed_by(ledger);
        Ok(())
    }

    /// Tells the transport that its actor runs on `host` of `placement`:
    /// from now on [`notify`](Transport::notify) of an actor elsewhere
    /// wakes this host's bridge instead. Call it before the first `notify`.
    pub fn place_on(&mut self, placement: &Placement, host: usize) {
        self.far = Some(FarWakes {
            placement: placement.clone(),
            host,
            bridge: None,
            ids: HashMap::new(),
        });
    }
}

impl Transport for IceoryxTransport {
    fn me(&self) -> ActorId {
        self.me
    }

    /// Becomes the publisher of one of this actor's channels.
    fn publish_on(&mut self, channel: Channel) -> Result<(), SetupError> {
        channel.check_publisher(self.me)?;
        self.add_publisher(channel)
    }

    fn subscribe(&mut self, channel: Channel) -> Result<(), SetupError> {
        let service = self.open_channel(channel)?;
        let sub = service
            .subscriber_builder()
            .create()
            .map_err(|e| setup("subscriber", e))?;
        self.subscribers.push((channel, sub));
        self.heard.selective |= matches!(channel, Channel::Observation(_));
        Ok(())
    }

    /// Prepares to wake `actor` after sending to it.
    fn notify(&mut self, actor: ActorId) -> Result<(), SetupError> {
        if let Some(far) = self
            .far
            .as_mut()
            .filter(|f| f.placement.host_of(actor) != f.host)
        {
            if far.bridge.is_none() {
                let bridge = open_bridge_wake(
                    &self.node,
                    &self.run,
                    &far.placement,
                    far.host,
                    &self.topology,
                )?
                .notifier_builder()
                .create()
                .map_err(|e| setup("bridge notifier", e))?;
                far.bridge = Some(bridge);
            }
            far.ids
                .insert(actor, EventId::new(wake_id(actor, &self.topology)));
            return Ok(());
        }
        if !self.notifiers.contains_key(&actor) {
            let n = open_wake(&self.node, &self.run, actor, &self.topology)?
                .notifier_builder()
                .create()
                .map_err(|e| setup("notifier", e))?;
            let id = WakeIds::of(actor, &self.topology).id_of(self.me);
            self.notifiers.insert(actor, (n, EventId::new(id)));
        }
        Ok(())
    }

    /// Connects publishers to subscribers that appeared since they were made.
    fn update_connections(&mut self) {
        for p in self.publishers.values() {
            let _ = p.update_connections();
        }
    }

    fn send_waking(
        &mut self,
        channel: Channel,
        message: &Message,
        receivers: &[ActorId],
        wake: &[ActorId],
    ) -> Result<(), SendError> {
        let publisher = self
            .publishers
            .get(&channel)
            .ok_or_else(|| SendError::NotPublisher {
                channel: channel.service_suffix(),
                actor: self.me.to_string(),
            })?;
        Outbound {
            me: self.me,
            format: &self.format,
            accounting: &mut self.accounting,
            buffer: &mut self.buffer,
        }
        .send(channel, message, receivers, |bytes| {
            publish(publisher, bytes)
        })?;
        for w in wake {
            // A failed wake-up only delays the receiver until its timeout.
            if let Some((n, id)) = self.notifiers.get(w) {
                let _ = n.notify_with_custom_event_id(*id);
            } else if let Some(far) = &self.far {
                if let (Some(bridge), Some(id)) = (&far.bridge, far.ids.get(w)) {
                    let _ = bridge.notify_with_custom_event_id(*id);
                }
            }
        }
        Ok(())
    }

    fn receive(&mut self, now: Duration, out: &mut Vec<Message>) -> Result<(), ReceiveError> {
        if !self.heard.waited && self.heard.selective {
            // Called without a wait since the last receive: take the
            // wake-ups that came in meanwhile without sleeping.
            self.take_wake_ups(Duration::ZERO)
                .map_err(|e| ReceiveError {
                    channel: "wake".into(),
                    source: e.source,
                })?;
        }
        let Self {
            me,
            format,
            accounting,
            shaper,
            subscribers,
            start,
            ..
        } = self;
        let mut inbound = Inbound {
            me: *me,
            format,
            accounting,
            shaper,
        };
        let heard = &mut self.heard;
        for (channel, sub) in subscribers.iter() {
            if !heard.may_have_data(*channel) {
                continue;
            }
            loop {
                match sub.receive() {
                    Ok(Some(sample)) => {
                        // Stamped when taken, not when the caller read its
                        // clock: a receiver descheduled in between would
                        // otherwise start a delayed message's hold early.
                        let arrived = now.max(start.elapsed());
                        inbound.arrive(channel.publisher(), sample.payload(), arrived, out)
                    }
                    Ok(None) => break,
                    Err(e) => {
                        return Err(ReceiveError {
                            channel: channel.service_suffix(),
                            source: Box::new(e),
                        })
                    }
                }
            }
        }
        heard.clear();
        inbound.release(now, out);
        Ok(())
    }

    fn wait(&mut self, timeout: Duration) -> Result<(), WaitError> {
        // A held (delayed) message may fall due before anyone wakes us.
        let timeout = match self.shaper.next_due() {
            Some(due) => timeout.min(due.saturating_sub(self.now())),
            None => timeout,
        };
        let woken = self.take_wake_ups(timeout)?;
        self.heard.waited = true;
        if !woken {
            // A timeout, or a wake-up that came without its event.
            self.heard.everything();
        }
        Ok(())
    }

    fn poll_wake(&mut self) -> Result<bool, WaitError> {
        let woken = self.take_wake_ups(Duration::ZERO)?;
        // Nothing heard leaves `receive` to take the wake-ups itself.
        self.heard.waited |= woken;
        Ok(woken)
    }

    fn now(&self) -> Duration {
        self.start.elapsed()
    }

    fn accounting(&self) -> &Accounting {
        &self.accounting
    }

    fn shaper(&mut self) -> &mut LinkShaper {
        &mut self.shaper
    }
}

/// Sleeps on `listener` until notified or `timeout` passes, handing each
/// event to `heard`. iceoryx2 passes the timeout to SO_RCVTIMEO as whole
/// microseconds, and a zero timeval means "block forever": a wait of less
/// than a microsecond (a held message falling due just now) would never
/// return, so it is a poll.
fn listen(
    listener: &Listener<futex::Service>,
    timeout: Duration,
    heard: impl FnMut(EventActivation),
) -> Result<(), WaitError> {
    let waited = if timeout < MIN_TIMED_WAIT {
        listener.try_wait(heard)
    } else {
        listener.timed_wait(heard, timeout)
    };
    match waited {
        // A signal cut the wait short: SIGCONT after SIGSTOP does, with no
        // handler installed. It is a spurious wake-up; every caller loops,
        // receiving and waiting again, so returning is the retry.
        Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(()),
        Err(e) => Err(WaitError {
            source: Box::new(e),
        }),
    }
}

/// Notifiers a wake-up service takes beyond the actor's peers.
const WAKE_SLACK: usize = 4;

/// The event ids of one actor's wake-up service: who woke it, as far as it
/// needs to know.
///
/// - `ANONYMOUS` (0): a wake-up that does not say whose message it brings
///   (a host's bridge); the woken read everything.
/// - `OTHER` (1): the launcher or a node; their channels are read at every
///   receive anyway.
/// - `2 + k`: the k-th sensor whose observations the actor reads (a node's
///   own sensors in topology order; every sensor for the launcher).
///
/// Ids are numbered per receiver, not per network: iceoryx2 drains a
/// listener by swapping every id's counter, so a wait costs a locked
/// instruction per id the service has. A node's service has 27 (its 25
/// sensors), not the 2,600 of a network-wide numbering at the largest size.
struct WakeIds {
    /// The sensors, in id order.
    sensors: Vec<u16>,
}

impl WakeIds {
    const ANONYMOUS: usize = 0;
    const OTHER: usize = 1;

    fn of(receiver: ActorId, topology: &Topology) -> Self {
        Self {
            sensors: match receiver {
                ActorId::Node(n) => topology.node_sensors[n as usize].clone(),
                ActorId::Launcher => (0..topology.sensors() as u16).collect(),
                ActorId::Sensor(_) => Vec::new(),
            },
        }
    }

    /// The largest id.
    fn max(&self) -> usize {
        Self::OTHER + self.sensors.len()
    }

    /// The id wake-ups from `waker` carry.
    fn id_of(&self, waker: ActorId) -> usize {
        match waker {
            ActorId::Sensor(s) => self
                .sensors
                .iter()
                .position(|&x| x == s)
                .map_or(Self::OTHER, |k| 2 + k),
            _ => Self::OTHER,
        }
    }
}

/// Which subscriptions may hold messages, from the wake-ups heard since the
/// last `receive`.
///
/// Polling an empty iceoryx2 subscriber touches its service's shared memory
/// and its connection's, and a node was polling 25 observation channels and
/// a handful of others at every wake-up, ten or more a step: the polls were
/// a tenth of `run`'s CPU, more than any function of the filters but one.
/// A sensor wakes every receiver of every observation it publishes, after
/// publishing it, so its channel needs reading only when its wake-up was
/// heard. Every other channel is read at every `receive`: their publishers
/// wake only some receivers (a node's activation wakes its active sensors,
/// its consensus its live neighbours), and the rest must still find the
/// message when something else wakes them. A wake-up that does not say who
/// sent it, or a wait that ends without one (a timeout, or a wake-up whose
/// notification failed), reads everything.
struct Heard {
    ids: WakeIds,
    /// Whether each sensor (by sensor index) woke us.
    sensors: Vec<bool>,
    everything: bool,
    /// Whether a wait took the wake-ups since the last `receive`; if not,
    /// `receive` takes them itself (a system call), unless no subscription
    /// is read selectively.
    waited: bool,
    selective: bool,
}

impl Heard {
    fn new(me: ActorId, topology: &Topology) -> Self {
        Self {
            ids: WakeIds::of(me, topology),
            sensors: vec![false; topology.sensors()],
            everything: true,
            waited: false,
            selective: false,
        }
    }

    /// A wake-up carrying event id `id`.
    fn hear(&mut self, id: usize) {
        match id {
            // The launcher's and nodes' channels are read anyway.
            WakeIds::OTHER => {}
            k if k >= 2 && k - 2 < self.ids.sensors.len() => {
                if let Some(heard) = self.sensors.get_mut(self.ids.sensors[k - 2] as usize) {
                    *heard = true;
                }
            }
            _ => self.everything = true,
        }
    }

    fn everything(&mut self) {
        self.everything = true;
    }

    fn may_have_data(&self, channel: Channel) -> bool {
        match channel {
            Channel::Observation(s) => {
                self.everything || self.sensors.get(s as usize).copied().unwrap_or(true)
            }
            _ => true,
        }
    }

    fn clear(&mut self) {
        self.everything = false;
        self.waited = false;
        self.sensors.fill(false);
    }
}

fn open_wake(
    node: &Node<futex::Service>,
    run: &RunId,
    actor: ActorId,
    topology: &Topology,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<futex::Service>, SetupError> {
    let name = run.service_name(&format!("wake/{actor}"))?;
    let ids = WakeIds::of(actor, topology).max();
    // Only an actor's peers wake it (a node's sensors and neighbours and
    // the launcher; a sensor's node and the launcher), and a few more for
    // tools and tests. Sized for everyone, the services' shared memory and
    // set-up grew with the square of the network: 2,600 processes did not
    // start in 400 s.
    let wakers = topology.peers(actor) + WAKE_SLACK;
    open_event(node, &name, wakers, ids, "wake event")
}

/// Opens or creates an event service for one listener and `wakers`
/// notifiers, with event ids up to `ids`.
fn open_event(
    node: &Node<futex::Service>,
    name: &ServiceName,
    wakers: usize,
    ids: usize,
    what: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<futex::Service>, SetupError> {
    retry(|| {
        node.service_builder(name)
            .event()
            .max_notifiers(wakers)
            .max_listeners(2)
            .max_nodes(wakers + 2)
            .event_id_max_value(ids)
            .open_or_create()
    })
    .map_err(|e| setup(what, e))
}

/// A host bridge's wake-up service: every actor of the host that sends to
/// another host notifies it, with the far receiver's wake id.
fn open_bridge_wake(
    node: &Node<futex::Service>,
    run: &RunId,
    placement: &Placement,
    host: usize,
    topology: &Topology,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<futex::Service>, SetupError> {
    let name = run.service_name("wake/bridge")?;
    // The host's actors, and the launcher's on the first host.
    let wakers = placement.actors_on(host, topology).len() + 1 + WAKE_SLACK;
    let ids = wake_id(ActorId::Launcher, topology) + topology.nodes() + topology.sensors();
    open_event(node, &name, wakers, ids, "bridge wake event")
}

/// A node for one side of a host's bridge.
fn bridge_node(run: &RunId, side: &str) -> Result<Node<futex::Service>, SetupError> {
    let config = run.config(DeadNodeSweep::On)?;
    let name = NodeName::new(&format!("bridge-{side}")).map_err(|e| setup("node name", e))?;
    NodeBuilder::new()
        .config(&config)
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<futex::Service>()
        .map_err(|e| setup("node", e))
}

/// The iceoryx2 side of what leaves a host through its bridge: it reads
/// every channel published on the host that another host reads, and hears
/// which far actors the host's actors want woken. Bytes only: nothing that
/// crosses is decoded or counted by the bridge, so link faults and byte
/// counts stay the receiving actor's, exactly as within one host.
pub struct BridgeOutlet {
    topology: Topology,
    outgoing: Vec<(Channel, Sub)>,
    listener: Listener<futex::Service>,
    /// Last: the ports above belong to it.
    _node: Node<futex::Service>,
}

impl BridgeOutlet {
    /// Opens host `host`'s outlet in its domain `run`. Open it before the
    /// host's actors start, so that no message leaves unread.
    pub fn open(
        run: &RunId,
        placement: &Placement,
        host: usize,
        topology: &Topology,
    ) -> Result<Self, SetupError> {
        let node = bridge_node(run, "out")?;
        let mut outgoing = Vec::new();
        for (channel, _) in placement.outgoing(host, topology) {
            let sub = open_channel(&node, run, topology, channel)?
                .subscriber_builder()
                .create()
                .map_err(|e| setup("subscriber", e))?;
            outgoing.push((channel, sub));
        }
        let listener = open_bridge_wake(&node, run, placement, host, topology)?
            .listener_builder()
            .create()
            .map_err(|e| setup("bridge listener", e))?;
        Ok(Self {
            topology: topology.clone(),
            outgoing,
            listener,
            _node: node,
        })
    }

    /// Sleeps until an actor of this host wakes the bridge or `timeout`
    /// passes; appends the far actors it asked to wake.
    pub fn wait(&self, timeout: Duration, woken: &mut Vec<ActorId>) -> Result<(), WaitError> {
        let topology = &self.topology;
        let mut heard = |e: EventActivation| {
            if let Some(a) = actor_of_wake_id(e.id.as_value(), topology) {
                woken.push(a);
            }
        };
        listen(&self.listener, timeout, &mut heard)
    }

    /// Hands every waiting message on the outgoing channels to `each`.
    pub fn drain(&self, mut each: impl FnMut(Channel, &[u8])) -> Result<(), ReceiveError> {
        for (channel, sub) in &self.outgoing {
            loop {
                match sub.receive() {
                    Ok(Some(sample)) => each(*channel, sample.payload()),
                    Ok(None) => break,
                    Err(e) => {
                        return Err(ReceiveError {
                            channel: channel.service_suffix(),
                            source: Box::new(e),
                        })
                    }
                }
            }
        }
        Ok(())
    }
}

/// The iceoryx2 side of what comes into a host through its bridge: it
/// publishes, on this host, every channel published elsewhere that this
/// host reads, and wakes this host's actors.
pub struct BridgeInlet {
    incoming: HashMap<Channel, Pub>,
    wakers: HashMap<ActorId, Notifier<futex::Service>>,
    /// The event id of a wake-up that does not say whose message it brings.
    anonymous: EventId,
    /// Last: the ports above belong to it.
    _node: Node<futex::Service>,
}

impl BridgeInlet {
    pub fn open(
        run: &RunId,
        placement: &Placement,
        host: usize,
        topology: &Topology,
    ) -> Result<Self, SetupError> {
        let node = bridge_node(run, "in")?;
        let mut incoming = HashMap::new();
        for channel in placement.incoming(host, topology) {
            let publisher = open_channel(&node, run, topology, channel)?
                .publisher_builder()
                .initial_max_slice_len(max_message_len(channel))
                .create()
                .map_err(|e| setup("publisher", e))?;
            incoming.insert(channel, publisher);
        }
        let mut local = placement.actors_on(host, topology);
        if host == placement.host_of(ActorId::Launcher) {
            local.push(ActorId::Launcher);
        }
        let mut wakers = HashMap::new();
        for actor in local {
            let n = open_wake(&node, run, actor, topology)?
                .notifier_builder()
                .create()
                .map_err(|e| setup("notifier", e))?;
            wakers.insert(actor, n);
        }
        Ok(Self {
            incoming,
            wakers,
            anonymous: EventId::new(WakeIds::ANONYMOUS),
            _node: node,
        })
    }

    /// Whether `channel` comes into this host.
    pub fn takes(&self, channel: Channel) -> bool {
        self.incoming.contains_key(&channel)
    }

    /// Publishes bytes from another host on `channel` here. A channel this
    /// host does not take in is refused.
    pub fn publish(&self, channel: Channel, bytes: &[u8]) -> Result<(), SendError> {
        let publisher = self
            .incoming
            .get(&channel)
            .ok_or_else(|| SendError::NotPublisher {
                channel: channel.service_suffix(),
                actor: "bridge".into(),
            })?;
        let _ = publisher.update_connections();
        publish(publisher, bytes).map_err(|source| SendError::Backend {
            channel: channel.service_suffix(),
            source,
        })
    }

    /// Wakes an actor of this host; `false` if it is not one.
    pub fn wake(&self, actor: ActorId) -> bool {
        self.wakers
            .get(&actor)
            .is_some_and(|n| n.notify_with_custom_event_id(self.anonymous).is_ok())
    }
}

/// Opens or creates, retrying while another process is half-way through
/// creating the same service (a known race at start-up).
fn retry<T, E: std::fmt::Debug>(mut f: impl FnMut() -> Result<T, E>) -> Result<T, E> {
    let mut attempt = 0;
    loop {
        match f() {
            Ok(v) => return Ok(v),
            Err(e) if attempt + 1 >= OPEN_ATTEMPTS => return Err(e),
            Err(_) => {
                attempt += 1;
                std::thread::sleep(Duration::from_millis(5 + (attempt as u64 % 7)));
            }
        }
    }
}

fn setup<E: std::error::Error + Send + Sync + 'static>(what: &str, e: E) -> SetupError {
    SetupError::Backend {
        what: what.into(),
        source: Box::new(e),
    }
}

/// Moves one message's bytes into shared memory.
fn publish(publisher: &Pub, bytes: &[u8]) -> Result<(), BackendError> {
    let sample = publisher.loan_slice_uninit(bytes.len())?;
    sample.write_from_slice(bytes).send()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    //! The transport contract (`transport::contract`), run here with both
    //! ends in this process; `tests/iceoryx_processes.rs` runs the same
    //! checks across two processes.
    use super::super::contract::{self, FORMAT};
    use super::*;
    use crate::scenario::Scenario;

    struct Pair {
        run: RunId,
        sensor: Option<IceoryxTransport>,
        node: Option<IceoryxTransport>,
    }

    impl Drop for Pair {
        fn drop(&mut self) {
            self.sensor.take();
            self.node.take();
            let _ = remove_run_resources(&self.run);
        }
    }

    fn pair(tag: &str) -> Pair {
        let run = RunId::new(&format!("u{}-{tag}", std::process::id())).unwrap();
        let topology = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
        let mut node = IceoryxTransport::new(&run, ActorId::Node(0), &topology, FORMAT, 2).unwrap();
        node.subscribe(Channel::Observation(0)).unwrap();
        let mut sensor =
            IceoryxTransport::new(&run, ActorId::Sensor(0), &topology, FORMAT, 1).unwrap();
        sensor.publish_on(Channel::Observation(0)).unwrap();
        sensor.notify(ActorId::Node(0)).unwrap();
        sensor.update_connections();
        Pair {
            run,
            sensor: Some(sensor),
            node: Some(node),
        }
    }

    /// Which subscriptions a receive reads, from the wake-ups heard; the
    /// ids are numbered per receiver.
    #[test]
    fn observation_channels_are_read_when_their_sensor_woke_us() {
        let topology = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
        let node = ActorId::Node(4);
        let own = &topology.node_sensors[4];
        let (mine, other) = (own[3], topology.node_sensors[0][0]);
        let ids = WakeIds::of(node, &topology);
        assert_eq!(
            ids.max(),
            1 + own.len(),
            "a node's service: its sensors, and two more"
        );
        assert_eq!(WakeIds::of(ActorId::Sensor(0), &topology).max(), 1);
        assert_eq!(
            WakeIds::of(ActorId::Launcher, &topology).max(),
            1 + topology.sensors()
        );
        let mut heard = Heard::new(node, &topology);
        // Before anything is known, everything is read.
        assert!(heard.may_have_data(Channel::Observation(mine)));
        heard.clear();
        assert!(!heard.may_have_data(Channel::Observation(mine)));
        assert!(heard.may_have_data(Channel::Consensus(1)));
        assert!(heard.may_have_data(Channel::Control(node)));
        heard.hear(ids.id_of(ActorId::Sensor(mine)));
        assert!(heard.may_have_data(Channel::Observation(mine)));
        assert!(!heard.may_have_data(Channel::Observation(own[4])));
        heard.clear();
        // A node or the launcher waking us says nothing about sensors, and
        // neither does a sensor that is not ours.
        for waker in [ActorId::Node(1), ActorId::Launcher, ActorId::Sensor(other)] {
            assert_eq!(ids.id_of(waker), WakeIds::OTHER);
            heard.hear(ids.id_of(waker));
        }
        assert!(!heard.may_have_data(Channel::Observation(mine)));
        // A wake-up that does not say whose message it brings reads all.
        heard.hear(WakeIds::ANONYMOUS);
        assert!(heard.may_have_data(Channel::Observation(mine)));
        heard.clear();
        heard.everything();
        assert!(heard.may_have_data(Channel::Observation(200)));
    }

    /// An observation published without its wake-up is still read once a
    /// wait times out; one with its wake-up, as soon as the wait returns.
    #[test]
    fn an_observation_without_its_wake_up_is_read_after_a_timeout() {
        let mut p = pair("heard");
        let Pair { sensor, node, .. } = &mut p;
        let (sensor, node) = (sensor.as_mut().unwrap(), node.as_mut().unwrap());
        let mut got = Vec::new();
        node.receive(node.now(), &mut got).unwrap();
        assert!(got.is_empty());
        sensor
            .send_waking(
                Channel::Observation(0),
                &contract::obs(0, 1),
                &[node.me()],
                &[],
            )
            .unwrap();
        node.wait(Duration::from_millis(2)).unwrap();
        node.receive(node.now(), &mut got).unwrap();
        assert_eq!(got.len(), 1, "read after the wait timed out");
        sensor
            .send(Channel::Observation(0), &contract::obs(0, 2), &[node.me()])
            .unwrap();
        let started = Instant::now();
        node.wait(Duration::from_secs(5)).unwrap();
        assert!(
            started.elapsed() < Duration::from_secs(4),
            "woken, not timed out"
        );
        node.receive(node.now(), &mut got).unwrap();
        assert_eq!(got.len(), 2);
        assert_eq!(got[1].header.step, 2);
    }

    /// `poll_wake` takes a wake-up that came, and one only: it says nothing
    /// came when nothing did, and the message is read selectively after it.
    #[test]
    fn a_poll_takes_a_wake_up_without_sleeping() {
        let mut p = pair("poll");
        let Pair { sensor, node, .. } = &mut p;
        let (sensor, node) = (sensor.as_mut().unwrap(), node.as_mut().unwrap());
        let mut got = Vec::new();
        node.receive(node.now(), &mut got).unwrap();
        assert!(!node.poll_wake().unwrap(), "nothing came");
        sensor
            .send(Channel::Observation(0), &contract::obs(0, 1), &[node.me()])
            .unwrap();
        assert!(node.poll_wake().unwrap(), "the sensor's wake-up");
        assert!(!node.heard.everything, "a wake-up that names its sensor");
        assert!(node.heard.may_have_data(Channel::Observation(0)));
        node.receive(node.now(), &mut got).unwrap();
        assert_eq!(got.len(), 1);
        assert!(!node.poll_wake().unwrap(), "taken once");
    }

    #[test]
    fn contract_delivery_and_counts() {
        let mut p = pair("deliver");
        let Pair { sensor, node, .. } = &mut p;
        contract::delivers_and_counts(sensor.as_mut().unwrap(), node.as_mut().unwrap());
    }

    #[test]
    fn contract_pairwise() {
        let run = RunId::new(&format!("u{}-pairwise", std::process::id())).unwrap();
        let topology = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
        let node = |i| {
            IceoryxTransport::new(&run, ActorId::Node(i), &topology, FORMAT, 10 + i as u64).unwrap()
        };
        let (mut a, mut b, mut c) = (node(0), node(1), node(2));
        b.subscribe(Channel::Pair { from: 0, to: 1 }).unwrap();
        b.subscribe(Channel::Consensus(0)).unwrap();
        c.subscribe(Channel::Consensus(0)).unwrap();
        a.publish_on(Channel::Pair { from: 0, to: 1 }).unwrap();
        a.publish_on(Channel::Consensus(0)).unwrap();
        a.notify(ActorId::Node(1)).unwrap();
        a.notify(ActorId::Node(2)).unwrap();
        a.update_connections();
        contract::a_pairwise_message_reaches_only_its_addressee(&mut a, &mut b, &mut c);
        drop((a, b, c));
        let _ = remove_run_resources(&run);
    }

    #[test]
    fn contract_loss() {
        let mut p = pair("loss");
        let Pair { sensor, node, .. } = &mut p;
        contract::loss_is_applied_and_counted(sensor.as_mut().unwrap(), node.as_mut().unwrap());
    }

    /// A wait shorter than a microsecond once became a zero SO_RCVTIMEO,
    /// which blocks forever: it hung CI whenever a held message fell due
    /// within a microsecond of the wait. Each wait runs on its own thread,
    /// so a hang fails the test instead of hanging it.
    #[test]
    fn waits_shorter_than_a_microsecond_return() {
        for nanos in [0, 1, 999] {
            let (done, finished) = std::sync::mpsc::channel();
            std::thread::spawn(move || {
                let mut p = pair(&format!("short-wait-{nanos}"));
                let node = p.node.as_mut().unwrap();
                node.wait(Duration::from_nanos(nanos)).unwrap();
                // Cleaned up before telling the test, which may end the
                // process as soon as it hears.
                drop(p);
                let _ = done.send(());
            });
            assert!(
                finished.recv_timeout(Duration::from_secs(10)).is_ok(),
                "a wait of {nanos} ns did not return"
            );
        }
    }

    #[test]
    fn run_ids_are_validated() {
        assert!(RunId::new("ok-run-1").is_ok());
        assert!(RunId::new("Bad Id").is_err());
        assert!(RunId::new("").is_err());
    }

    /// Every sweep of dead nodes is linear in the network; at a first
    /// start they made start-up quadratic (2,600 processes: 240 ready after
    /// 120 s with the service sweep on, all in 20 s with it off). A restart
    /// keeps all three, to clear its dead predecessor's ports.
    #[test]
    fn a_first_start_sweeps_nothing_and_a_restart_sweeps_all() {
        let run = RunId::new("sweep-config").unwrap();
        let first = run.config(DeadNodeSweep::Off).unwrap();
        assert!(!first.global.node.cleanup_dead_nodes_on_creation);
        assert!(!first.global.node.cleanup_dead_nodes_on_destruction);
        assert!(!first.global.service.cleanup_dead_nodes_on_open);
        let restart = run.config(DeadNodeSweep::On).unwrap();
        assert!(restart.global.node.cleanup_dead_nodes_on_creation);
        assert!(restart.global.node.cleanup_dead_nodes_on_destruction);
        assert!(restart.global.service.cleanup_dead_nodes_on_open);
    }
}
