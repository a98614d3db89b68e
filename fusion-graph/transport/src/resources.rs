//! A run's files: where iceoryx2 and the run keep them, what they are
//! named (every one under the prefix `cqnet_<run>_`), the lease a launcher
//! holds on them, and the sweeps that remove what a killed launcher left.

use std::os::unix::fs::OpenOptionsExt;
use std::time::Duration;

use iceoryx2::prelude::*;

use crate::SetupError;
use fusion_graph::channel::RunId;

/// Where iceoryx2 keeps its files besides `/dev/shm`.
/// Where iceoryx2 keeps a run's service and node files: on tmpfs beside the
/// shared memory. On the default `/tmp/iceoryx2` (ext4 here) a fifth of the
/// start-up CPU of 936 processes went to the file system allocating inodes
/// among the many that earlier runs created and deleted.
pub(crate) const ICEORYX_ROOT: &str = "/dev/shm/cqnet-iceoryx2/";
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
/// Expired connections a subscriber keeps (see [`RunResources::config`]):
/// at least the samples it may borrow, as iceoryx2 asks.
const EXPIRED_CONNECTIONS: usize = 4;

/// What iceoryx2 makes of a run's id: the configuration that keeps its
/// resources apart from every other run's, and its services' names.
pub(crate) trait RunResources {
    fn config(&self, sweep: DeadNodeSweep) -> Result<Config, SetupError>;
    fn service_name(&self, suffix: &str) -> Result<ServiceName, SetupError>;
}

impl RunResources for RunId {
    fn config(&self, sweep: DeadNodeSweep) -> Result<Config, SetupError> {
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
        // Each subscriber keeps room for the connections of publishers
        // gone with samples unread: 128 by default, a table its process
        // zeroes page by page at start-up, for every channel it reads
        // (7 % of a 2,601-process network's start-up). Every channel here
        // has one publisher, whose restart leaves one such connection, and
        // a receive borrows one sample at a time.
        config
            .defaults
            .publish_subscribe
            .subscriber_expired_connection_buffer = EXPIRED_CONNECTIONS;
        Ok(config)
    }

    fn service_name(&self, suffix: &str) -> Result<ServiceName, SetupError> {
        ServiceName::new(&format!("cqnet/{}/{suffix}", self.as_str())).map_err(|e| setup(suffix, e))
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
    let path = run_memory_path(run, name);
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .mode(OWNER_ONLY)
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

/// What a run's files may be: its owner's, read and write, no one else's.
pub(crate) const OWNER_ONLY: u32 = 0o600;
/// How the name iceoryx2 (0.10.0) gives a domain's one global segment
/// ends. Between the domain's prefix and this, its storage puts a hash of
/// the segment's type, which this code does not compute.
const GLOBAL_SEGMENT: &str = "node.0_10_0.global_mgmt";

/// iceoryx2 makes a domain's global segment (its node counter) readable
/// and writable by every user of the machine; a run's is its owner's
/// only. The domain's first process calls this once its node is made (the
/// segment then exists): the launcher, or on a host of several, that
/// host's bridge, each before it spawns an actor. The actors do not: this
/// reads the whole of `/dev/shm`, which holds thousands of a large run's
/// files, and with every actor reading it, start-up grew as the square of
/// the network.
pub(crate) fn keep_global_segment_private(run: &RunId) {
    let prefix = run.prefix();
    let Ok(entries) = std::fs::read_dir(SHARED_MEMORY) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let name = name.to_string_lossy();
        // Every match: a run over hosts on one machine has one domain per
        // host, whose prefixes all begin with the run's.
        if name.starts_with(&prefix) && name.ends_with(GLOBAL_SEGMENT) {
            keep_private(&e.path());
        }
    }
}

/// This process's effective user.
fn euid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// Takes group's and others' rights off `path`, if this process owns it.
fn keep_private(path: &std::path::Path) {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let Ok(m) = std::fs::metadata(path) else {
        return;
    };
    if m.uid() == euid() && m.mode() & 0o077 != 0 {
        let _ = std::fs::set_permissions(path, std::fs::Permissions::from_mode(OWNER_ONLY));
    }
}

/// The file of run `run`'s shared memory called `name`; it goes with the
/// run's other resources.
pub fn run_memory_path(run: &RunId, name: &str) -> std::path::PathBuf {
    std::path::Path::new(SHARED_MEMORY).join(format!("{}{name}", run.prefix()))
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
        use std::io::Write;
        use std::os::unix::fs::PermissionsExt;
        if !std::path::Path::new(RUN_REGISTRY).is_dir() {
            std::fs::create_dir_all(RUN_REGISTRY)?;
            // Like /tmp: every user registers runs, none removes another's.
            std::fs::set_permissions(RUN_REGISTRY, std::fs::Permissions::from_mode(0o1777))?;
        }
        let pid = std::process::id();
        let started = process_start_time(pid).unwrap_or_default();
        let path = std::path::Path::new(RUN_REGISTRY).join(run.as_str());
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .mode(OWNER_ONLY)
            .open(&path)?;
        f.write_all(format!("{pid} {started}\n").as_bytes())?;
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
        // Another user's run is theirs to sweep (and its lease unreadable).
        let mine = entry
            .metadata()
            .is_ok_and(|m| std::os::unix::fs::MetadataExt::uid(&m) == euid());
        if !mine {
            continue;
        }
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

/// Opens or creates, retrying while another process is half-way through
/// creating the same service (a known race at start-up).
pub(crate) fn retry<T, E: std::fmt::Debug>(mut f: impl FnMut() -> Result<T, E>) -> Result<T, E> {
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

pub(crate) fn setup<E: std::error::Error + Send + Sync + 'static>(what: &str, e: E) -> SetupError {
    SetupError::Backend {
        what: what.into(),
        source: Box::new(e),
    }
}

/// Whether creating (and dropping) an iceoryx2 node, and opening a service,
/// first sweep the resources of dead nodes of the run. Both sweeps are
/// linear in the network, so with every actor starting at once they made
/// start-up quadratic:
/// - the node sweep lists every node of the run, and the processes queued
///   on the node directory's lock (936 processes took 110 s);
/// - the service sweep reads the details of every node attached to the
///   service, and every sensor opens the lifecycle service, to which all of
///   them are attached (2,600 processes: a fifth of all CPU time in
///   start-up, 240 ready after 120 s, when every actor opened a broadcast).
///
/// At a run's first start nothing has died yet, and the launcher removes
/// everything at the end; an actor restarted after a kill still sweeps, so
/// that its dead predecessor's ports do not hold places it needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeadNodeSweep {
    On,
    Off,
}
