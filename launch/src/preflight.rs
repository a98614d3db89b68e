//! Before `cqnet run` spawns anything: will the network fit this machine?
//! A run that cannot fit should fail at once, with what to change, rather
//! than after a partial start (processes killed by the OOM killer, `fork`
//! refused at the 2,000th child, or a full `/dev/shm` at the 900th).

use anyhow::bail;
use fusion_graph::{Scenario, Topology};
use nix::sys::resource::{getrlimit, setrlimit, Resource};
use transport::limits::Footprint;

/// Bytes a particle costs in one particle filter: particles, scratch,
/// weights, uniform weights and log-likelihoods (`node::filter`).
const BYTES_PER_PARTICLE: u64 = 32 + 32 + 8 + 8 + 8;
/// What a child process costs besides its particles (measured: 2.4 MB of
/// PSS per child in the default run); rounded up.
const BYTES_PER_PROCESS: u64 = 4 << 20;
/// File descriptors the launcher holds per child, and for itself.
/// Measured in the default run (`ls /proc/<launcher>/fd`): 1,528 for 234
/// children without the centralized reference, 6.5 each; 2,653 with it,
/// 5 more per sensor. Per child: its output pipe and its pidfd; the port
/// tag and the service's dynamic configuration of the notifier that wakes
/// it; its connection to the lifecycle's or its control channel's
/// publisher. The centralized reference
/// subscribes to every sensor: a port tag, a dynamic configuration, a
/// connection, the sensor's data segment, and its observation service.
const FDS_PER_CHILD: u64 = 7;
const FDS_PER_OBSERVED_SENSOR: u64 = 5;
const FDS_BASE: u64 = 256;

/// The descriptors the launcher will hold at once.
pub fn descriptors_needed(topology: &Topology, centralized: bool) -> u64 {
    let children = topology.actors().count() as u64;
    let observed = if centralized {
        topology.sensors() as u64
    } else {
        0
    };
    FDS_BASE + FDS_PER_CHILD * children + FDS_PER_OBSERVED_SENSOR * observed
}

/// The run's estimated memory, in bytes: every process's base, and the
/// particle filters (two per node, one more in the launcher for the
/// centralized reference).
pub fn estimated_memory(scenario: &Scenario, topology: &Topology, centralized: bool) -> u64 {
    let processes = (topology.actors().count() + 1) as u64;
    let filters = 2 * topology.nodes() as u64 + u64::from(centralized);
    processes * BYTES_PER_PROCESS + filters * scenario.filter.particles as u64 * BYTES_PER_PARTICLE
}

/// Refuses, naming what to change, a run whose memory estimate exceeds
/// what the machine has available, or whose process count or file
/// descriptors exceed this user's limits (the descriptor limit is raised
/// first, as far as the process may: see `raise_descriptor_limit`).
pub fn check(scenario: &Scenario, topology: &Topology, centralized: bool) -> anyhow::Result<()> {
    let children = topology.actors().count() as u64;
    let needed = estimated_memory(scenario, topology, centralized);
    if let Some(available) = available_memory() {
        if needed > available {
            bail!(
                "the network needs about {} of memory ({} processes; {} particle filters of \
                 filter.particles = {}) and this machine has {} available: lower \
                 filter.particles or the number of nodes and sensors",
                gib(needed),
                children + 1,
                2 * topology.nodes() + usize::from(centralized),
                scenario.filter.particles,
                gib(available)
            );
        }
    }
    if let Ok((soft, _)) = getrlimit(Resource::RLIMIT_NPROC) {
        if children > soft {
            bail!(
                "the network has {children} child processes and this user may run {soft} \
                 (ulimit -u): raise the limit or shrink the network"
            );
        }
    }
    check_footprint(&footprint(scenario, topology, centralized), &machine_room())?;
    let fds = descriptors_needed(topology, centralized);
    raise_descriptor_limit(fds).map_err(|hard| {
        let hint = if centralized {
            " (reference.centralized = false, or --no-central, saves 5 per sensor)"
        } else {
            ""
        };
        anyhow::anyhow!(
            "the launcher needs about {fds} file descriptors for {children} children \
             and may open at most {hard} (ulimit -Hn): raise the hard limit (as root, or in \
             /etc/security/limits.conf) or shrink the network{hint}"
        )
    })
}

/// What the run's iceoryx2 services and shared tables will take of the
/// machine (`transport::limits`).
pub fn footprint(scenario: &Scenario, topology: &Topology, centralized: bool) -> Footprint {
    let pairs = scenario.talks_in_pairs();
    let tables = bounds::table_memory::shared_table_bytes() as u64;
    Footprint::of(topology, pairs, centralized, tables)
}

/// What this machine offers a run's shared memory and its launcher; `None`
/// where it cannot be read (nothing is checked against it then).
#[derive(Debug, Clone, Copy, Default)]
pub struct MachineRoom {
    /// Bytes free in `/dev/shm`.
    pub shm_bytes: Option<u64>,
    /// Files that may still be made in `/dev/shm`.
    pub shm_files: Option<u64>,
    /// `vm.max_map_count`: memory maps a process may hold.
    pub max_maps: Option<u64>,
}

pub fn machine_room() -> MachineRoom {
    let shm = nix::sys::statvfs::statvfs("/dev/shm").ok();
    MachineRoom {
        shm_bytes: shm
            .as_ref()
            .map(|v| v.blocks_available() * v.fragment_size()),
        // tmpfs mounted with nr_inodes=0 reports no inode limit at all.
        shm_files: shm
            .as_ref()
            .filter(|v| v.files() > 0)
            .map(|v| v.files_available()),
        max_maps: std::fs::read_to_string("/proc/sys/vm/max_map_count")
            .ok()
            .and_then(|t| t.trim().parse().ok()),
    }
}

/// Refuses a run whose shared memory, files in `/dev/shm` or launcher's
/// memory maps would exceed what the machine offers, naming the limit and
/// how to raise it.
pub fn check_footprint(need: &Footprint, room: &MachineRoom) -> anyhow::Result<()> {
    if let Some(free) = room.shm_bytes.filter(|free| need.shared_bytes > *free) {
        bail!(
            "the network needs about {} MB of shared memory in /dev/shm and it has {} MB free: \
             enlarge /dev/shm (in a container, `docker run --shm-size=…`; otherwise \
             `mount -o remount,size=… /dev/shm`) or shrink the network (its shared memory \
             grows with its actors and links)",
            need.shared_bytes.div_ceil(1 << 20),
            free >> 20
        );
    }
    if let Some(free) = room.shm_files.filter(|free| need.files > *free) {
        bail!(
            "the network needs about {} files in /dev/shm and it may make {free} more: \
             remount /dev/shm with more inodes (`mount -o remount,nr_inodes=… /dev/shm`) or \
             shrink the network",
            need.files
        );
    }
    if let Some(max) = room.max_maps.filter(|max| need.launcher_maps > *max) {
        bail!(
            "the launcher would hold about {} memory maps and vm.max_map_count is {max}: \
             raise it (`sysctl -w vm.max_map_count=…`, as root) or shrink the network",
            need.launcher_maps
        );
    }
    Ok(())
}

/// Raises the soft descriptor limit to `needed`, and the hard one too when
/// the process may (root, or CAP_SYS_RESOURCE: up to `fs.nr_open`). Fails
/// with the hard limit when it stays below `needed`.
fn raise_descriptor_limit(needed: u64) -> Result<(), u64> {
    let Ok((soft, hard)) = getrlimit(Resource::RLIMIT_NOFILE) else {
        return Ok(()); // nothing to check against
    };
    if needed <= soft {
        return Ok(());
    }
    if needed > hard && setrlimit(Resource::RLIMIT_NOFILE, needed, needed).is_ok() {
        return Ok(());
    }
    let _ = setrlimit(Resource::RLIMIT_NOFILE, needed.min(hard), hard);
    if needed > hard {
        Err(hard)
    } else {
        Ok(())
    }
}

/// `MemAvailable` from /proc/meminfo, in bytes.
fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn gib(bytes: u64) -> String {
    format!("{:.1} GiB", bytes as f64 / (1u64 << 30) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn default() -> (Scenario, Topology) {
        let s = Scenario::default_scenario();
        let t = Topology::from_scenario(&s, "default").unwrap();
        (s, t)
    }

    /// The default network: 235 processes and 19 filters of 1000 particles,
    /// about 0.9 GiB by the estimate (0.57 GiB of PSS measured).
    #[test]
    fn the_default_network_is_estimated_within_a_factor_of_two_of_what_it_uses() {
        let (s, t) = default();
        let estimate = estimated_memory(&s, &t, true) as f64;
        let measured = 569.0 * (1u64 << 20) as f64;
        assert!(
            estimate > measured && estimate < 2.0 * measured,
            "{estimate}"
        );
        assert!(check(&s, &t, true).is_ok());
    }

    /// Against `ls /proc/<launcher>/fd | wc -l` in the default run: 1,528
    /// without the centralized reference, 2,653 with it. And the 2,600-process
    /// network fits the 20,000 descriptors of this machine's hard limit
    /// without it (16,724 measured at start-up), not with it.
    #[test]
    fn descriptors_are_estimated_above_what_the_launcher_holds() {
        let (mut s, t) = default();
        for (centralized, measured) in [(false, 1528.0), (true, 2653.0)] {
            let estimate = descriptors_needed(&t, centralized) as f64;
            assert!(
                estimate >= measured && estimate < 1.3 * measured,
                "{centralized}: {estimate}"
            );
        }
        s.nodes.grid = Some([10, 10]);
        s.region.width = 5000.0;
        s.region.height = 5000.0;
        let large = Topology::from_scenario(&s, "large").unwrap();
        assert_eq!(large.nodes() + large.sensors(), 2600);
        assert!(descriptors_needed(&large, false) < 20_000);
        assert!(descriptors_needed(&large, true) > 20_000);
    }

    /// Each limit refuses on its own, naming itself and what to change;
    /// the default network fits a machine of 64 MB of /dev/shm (a
    /// container's default), the 2,601-process one does not.
    #[test]
    fn a_footprint_beyond_the_machine_is_refused_naming_the_limit() {
        let (s, t) = default();
        let need = footprint(&s, &t, true);
        let docker = MachineRoom {
            shm_bytes: Some(64 << 20),
            shm_files: Some(1 << 20),
            max_maps: Some(65_530),
        };
        assert!(check_footprint(&need, &docker).is_ok(), "{need:?}");
        let mut large = s.clone();
        large.nodes.grid = Some([10, 10]);
        large.region.width = 5000.0;
        large.region.height = 5000.0;
        let big = Topology::from_scenario(&large, "large").unwrap();
        let e = check_footprint(&footprint(&large, &big, false), &docker)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("MB of shared memory in /dev/shm") && e.contains("--shm-size"),
            "{e}"
        );
        let few_files = MachineRoom {
            shm_files: Some(1000),
            ..docker
        };
        let e = check_footprint(&need, &few_files).unwrap_err().to_string();
        assert!(
            e.contains("files in /dev/shm") && e.contains("nr_inodes"),
            "{e}"
        );
        let few_maps = MachineRoom {
            max_maps: Some(500),
            ..docker
        };
        let e = check_footprint(&need, &few_maps).unwrap_err().to_string();
        assert!(e.contains("vm.max_map_count is 500"), "{e}");
        assert!(check_footprint(&need, &MachineRoom::default()).is_ok());
    }

    #[test]
    fn a_network_too_large_for_the_memory_is_refused_naming_the_particles() {
        let (mut s, t) = default();
        s.filter.particles = 2_000_000_000;
        let e = check(&s, &t, true).unwrap_err().to_string();
        assert!(
            e.contains("filter.particles = 2000000000") && e.contains("GiB"),
            "{e}"
        );
    }
}
