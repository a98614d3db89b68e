//! Which core each process of a network runs on.
//!
//! A network with many more nodes than the machine has cores
//! ([`NODES_PER_CORE`] a core) is placed by parts
//! of its fusion graph (`Topology::core_parts`): each node and its sensors
//! (and its multiple-access channel) on one core, neighbours mostly on the
//! same one, so that a consensus round's wake-ups seldom cross between
//! cores, and each a batch task there ([`settle_on`]). The launcher
//! decides; each actor settles itself at start (`--core`).

use std::sync::Arc;

use fusion_graph::topology::Topology;
use fusion_graph::ActorId;

/// Nodes a core must have for the network to be placed. With fewer, the
/// parts' sizes differ by a larger share (a 9-node network on two cores
/// puts 5 nodes' filters on one and 4 on the other) and the kernel's
/// balancing is worth more than the wake-ups kept on one core: the default
/// 9-node network ran 21 ± 43 steps/s slower placed than not (five
/// alternated pairs of `run --lockstep --no-central --set steps=100`, not
/// resolved), a 36-node one the same (three pairs), a 100-node one 1.41 ±
/// 1.06 steps/s faster (eleven pairs, about 1.19×).
pub const NODES_PER_CORE: usize = 16;

/// Whether a run places its processes on cores.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Cores {
    /// By parts of the fusion graph when there are at least
    /// [`NODES_PER_CORE`] nodes a core.
    #[default]
    Auto,
    /// Leave every process to the kernel's scheduler.
    Off,
}

/// The core of each node, and through it of each sensor and channel.
#[derive(Debug, Clone)]
pub struct CorePlacement {
    node_core: Vec<usize>,
    sensor_owner: Arc<[u16]>,
}

impl CorePlacement {
    /// The placement of `topology` on the cores this process may run on;
    /// none when `cores` is off, when there is only one core, or when there
    /// are fewer than [`NODES_PER_CORE`] nodes a core.
    pub fn for_network(topology: &Topology, cores: Cores) -> Option<Self> {
        if cores == Cores::Off {
            return None;
        }
        let allowed = allowed_cores();
        if allowed.len() < 2 || topology.nodes() < NODES_PER_CORE * allowed.len() {
            return None;
        }
        let node_core = topology
            .core_parts(allowed.len())
            .into_iter()
            .map(|part| allowed[part])
            .collect();
        Some(Self {
            node_core,
            sensor_owner: topology.sensor_owner.clone(),
        })
    }

    pub fn core_of(&self, actor: ActorId) -> Option<usize> {
        let node = match actor {
            ActorId::Node(n) | ActorId::Mac(n) => n,
            ActorId::Sensor(s) => *self.sensor_owner.get(s as usize)?,
            ActorId::Launcher => return None,
        };
        self.node_core.get(node as usize).copied()
    }
}

/// The cores this process may run on (its affinity), in increasing order.
pub fn allowed_cores() -> Vec<usize> {
    // SAFETY: an all-zero cpu_set_t is the empty set; sched_getaffinity
    // writes at most its size.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    let got = unsafe { libc::sched_getaffinity(0, std::mem::size_of_val(&set), &mut set) };
    if got != 0 {
        return Vec::new();
    }
    (0..libc::CPU_SETSIZE as usize)
        // SAFETY: CPU_ISSET reads the set within its size.
        .filter(|&c| unsafe { libc::CPU_ISSET(c, &set) })
        .collect()
}

/// Pins the calling thread (and every thread it starts after, so an
/// actor's whole process when called first) to `core`, and makes it a
/// batch task there (`SCHED_BATCH`): a node that wakes a neighbour on its
/// own core then goes on to the rest of its round (its other neighbours'
/// wake-ups, its own wait) instead of being preempted by the woken one.
/// 100 nodes at 40 rounds, eight alternated pairs of `run --lockstep`
/// (60 steps), both placed: 12.3, 13.1, 12.8, 12.1, 12.1, 12.2, 12.3, 12.6
/// steps/s as batch tasks against 12.9, 11.9, 11.4, 10.7, 11.4, 11.3,
/// 11.8, 12.1 not, +0.75 ± 0.55 paired; round p99 lower in seven of
/// eight. At 10 Hz, two pairs: 1,326 and 1,348 deadline misses against
/// 1,538 and 1,633.
pub fn settle_on(core: usize) -> std::io::Result<()> {
    pin_to(core)?;
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: sched_setscheduler reads `param` only during the call.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_BATCH, &param) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Pins the calling thread (and every thread it starts after) to `core`.
fn pin_to(core: usize) -> std::io::Result<()> {
    if core >= libc::CPU_SETSIZE as usize {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "core {core} is beyond the {} a CPU set holds",
                libc::CPU_SETSIZE
            ),
        ));
    }
    // SAFETY: as in `allowed_cores`; CPU_SET writes within the set.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    unsafe { libc::CPU_SET(core, &mut set) };
    if unsafe { libc::sched_setaffinity(0, std::mem::size_of_val(&set), &set) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::scenario::{Scenario, DEFAULT_SCENARIO};

    fn topology(sets: &[&str]) -> Topology {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let s = Scenario::from_toml(DEFAULT_SCENARIO, "test", &sets).unwrap();
        Topology::from_scenario(&s, "test").unwrap()
    }

    #[test]
    fn off_places_nothing_nor_does_a_small_network() {
        let grid = [
            "nodes.grid=[10,10]",
            "region.width=5000",
            "region.height=5000",
        ];
        assert!(CorePlacement::for_network(&topology(&grid), Cores::Off).is_none());
        // The default network's 9 nodes are too few for two cores or more.
        assert!(CorePlacement::for_network(&topology(&[]), Cores::Auto).is_none());
    }

    /// Every actor of a node is on its node's core, and the cores are the
    /// ones this process may use.
    #[test]
    fn a_nodes_sensors_share_its_core() {
        let t = topology(&[
            "nodes.grid=[6,6]",
            "region.width=3000",
            "region.height=3000",
        ]);
        let allowed = allowed_cores();
        let Some(p) = CorePlacement::for_network(&t, Cores::Auto) else {
            // One core, or too few nodes a core: nothing to place.
            assert!(allowed.len() < 2 || t.nodes() < NODES_PER_CORE * allowed.len());
            return;
        };
        for n in 0..t.nodes() as u16 {
            let core = p.core_of(ActorId::Node(n)).unwrap();
            assert!(allowed.contains(&core));
            assert_eq!(p.core_of(ActorId::Mac(n)), Some(core));
            for &s in &t.node_sensors[n as usize] {
                assert_eq!(p.core_of(ActorId::Sensor(s)), Some(core));
            }
        }
        assert_eq!(p.core_of(ActorId::Launcher), None);
    }

    /// Affinity and policy are per thread on Linux: a thread of the test
    /// settles on a core and sees only it, as a batch task, the rest of
    /// the test process untouched.
    #[test]
    fn a_pinned_thread_runs_on_its_core_alone() {
        let allowed = allowed_cores();
        // SAFETY: reads this thread's policy.
        let policy_before = unsafe { libc::sched_getscheduler(0) };
        let core = *allowed.last().expect("at least one core");
        let (seen, policy) = std::thread::spawn(move || {
            settle_on(core).unwrap();
            // SAFETY: reads this thread's policy.
            (allowed_cores(), unsafe { libc::sched_getscheduler(0) })
        })
        .join()
        .unwrap();
        assert_eq!(seen, vec![core]);
        assert_eq!(policy, libc::SCHED_BATCH);
        assert_eq!(allowed_cores(), allowed);
        // SAFETY: as above.
        assert_eq!(unsafe { libc::sched_getscheduler(0) }, policy_before);
    }

    #[test]
    fn a_core_beyond_the_set_is_an_error() {
        assert!(pin_to(usize::MAX).is_err());
    }
}
