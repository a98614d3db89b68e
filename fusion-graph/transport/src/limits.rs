//! How large every iceoryx2 service of a run is, derived from the topology
//! in one place: the publishers, subscribers and nodes each channel's
//! service admits, its queues and its largest message; the notifiers and
//! event ids of each wake-up service. The transport opens its services with
//! these numbers, and [`Footprint`] adds up what they take of the machine
//! (shared memory, files in it, the launcher's memory maps), so that a run
//! too large for the machine is refused before anything starts.

use fusion_graph::hosts::{wake_id, Placement};
use fusion_graph::topology::Topology;
use wire::ActorId;
use wire::HEADER_BYTES;

use super::Channel;

/// The depth of every subscriber's queue: what a receiver that does not
/// run may fall behind by before its oldest messages are overwritten. A
/// full queue overwrites rather than blocks the sender, so that a stopped
/// receiver cannot stall the network; such losses show as
/// sent-but-unaccounted messages in the results. Seen with iceoryx2 0.10: a
/// burst larger than the queue, sent before the subscriber's first receive,
/// lost the whole burst rather than only the oldest samples.
pub const QUEUE_DEPTH: usize = 64;

/// The queue of the launcher's lifecycle channel, which carries one
/// message in a run: the stop.
const LIFECYCLE_QUEUE: usize = 2;

/// Wake-up notifiers beyond an actor's peers: tools and tests.
const WAKE_SLACK: usize = 4;

/// iceoryx2's defaults for what a subscriber may hold and a publisher may
/// loan at once; each adds samples to the publisher's data segment.
const BORROWED_PER_SUBSCRIBER: usize = 2;
const LOANED_PER_PUBLISHER: usize = 2;

/// The limits of one channel's publish-subscribe service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelLimits {
    pub publishers: usize,
    pub subscribers: usize,
    /// Processes that may open the service.
    pub nodes: usize,
    /// Each subscriber's queue.
    pub queue: usize,
    /// The largest message, header included.
    pub message_bytes: usize,
}

impl ChannelLimits {
    pub fn of(topology: &Topology, channel: Channel) -> Self {
        // +1 subscriber: on a host of several, the bridge reads what leaves it.
        let subscribers = topology.subscribers(channel) + 1;
        Self {
            // +1 publisher: a test may inject raw bytes through a second one.
            publishers: 2,
            subscribers,
            nodes: subscribers + 3,
            queue: if channel == Channel::Lifecycle {
                LIFECYCLE_QUEUE
            } else {
                QUEUE_DEPTH
            },
            message_bytes: max_message_len(channel, topology),
        }
    }

    /// Samples in each publisher's data segment, as iceoryx2 sizes it: room
    /// for every subscriber's full queue and borrowed samples, and the
    /// publisher's own loans.
    pub fn samples(&self) -> usize {
        self.subscribers * (self.queue + BORROWED_PER_SUBSCRIBER) + LOANED_PER_PUBLISHER
    }

    /// A publisher's data segment. A sample is the message rounded up to 8
    /// bytes and iceoryx2's 52 bytes of header and alignment (measured: a
    /// segment of 61-byte messages is 116 bytes a sample).
    pub fn segment_bytes(&self) -> u64 {
        let sample = self.message_bytes.div_ceil(8) * 8 + 52;
        (self.samples() * sample) as u64
    }
}

/// Largest message each channel carries, which sizes its shared memory.
/// The channels between nodes also make room for the longest payload the
/// program declared for its own protocols: every process of a run is the
/// same program, so all open the services alike. A message longer than
/// its channel's room could not be sent at all.
pub(crate) fn max_message_len(channel: Channel, topology: &Topology) -> usize {
    let protocols = topology.payloads.longest_body();
    HEADER_BYTES
        + match channel {
            Channel::Lifecycle => 16,
            // A sensor's transmissions on a multiple-access channel: its
            // slots, a value each.
            Channel::Observation(_) if topology.macs => {
                4 + 8 * fusion_graph::scenario::MAX_MAC_SLOTS as usize
            }
            Channel::Observation(_) => 48,
            // The mask, and either the censoring feedback (an estimate and
            // its packed covariance) or a quantizer's thresholds.
            // A channel's schedule: a column for each sensor that transmits.
            Channel::Activation { .. } if topology.macs => {
                3 + wire::SLOT_COLUMN_BYTES * topology.most_sensors_per_node()
            }
            Channel::Activation { .. } => 48 + (32 + 80).max(1 + 8 * wire::MAX_THRESHOLDS),
            Channel::Consensus(_) => 300.max(protocols),
            // A posterior swapped in a random exchange: mean and covariance.
            Channel::Pair { .. } => 120.max(protocols),
            Channel::Control(_) | Channel::Telemetry(_) => 240,
            // Every slot's sum.
            Channel::MacOutput(_) => 1 + 8 * fusion_graph::scenario::MAX_MAC_SLOTS as usize,
        }
}

/// The limits of one wake-up (event) service: one listener, the actors
/// that may wake it, and the event ids they use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WakeLimits {
    pub notifiers: usize,
    pub listeners: usize,
    pub nodes: usize,
    pub max_event_id: usize,
}

impl WakeLimits {
    fn with_wakers(wakers: usize, max_event_id: usize) -> Self {
        Self {
            notifiers: wakers,
            listeners: 2,
            nodes: wakers + 2,
            max_event_id,
        }
    }

    /// An actor's wake-up service. Only its peers wake it (a node's sensors
    /// and neighbours and the launcher; a sensor's node and the launcher),
    /// and a few more for tools and tests. Sized for everyone, the services'
    /// shared memory and set-up grew with the square of the network: 2,600
    /// processes did not start in 400 s.
    pub fn of_actor(topology: &Topology, actor: ActorId) -> Self {
        Self::with_wakers(
            topology.peers(actor) + WAKE_SLACK,
            max_wake_id(topology, actor),
        )
    }

    /// A host bridge's wake-up service: every actor of the host that sends
    /// to another host notifies it, with the far receiver's wake id.
    pub fn of_bridge(placement: &Placement, host: usize, topology: &Topology) -> Self {
        // The host's actors, and the launcher's on the first host.
        let wakers = placement.actors_on(host, topology).len() + 1 + WAKE_SLACK;
        let ids = wake_id(ActorId::Launcher, topology)
            + topology.nodes()
            + topology.sensors()
            + topology.mac_count();
        Self::with_wakers(wakers, ids)
    }
}

/// The largest event id of an actor's wake-up service, in the numbering
/// of `wake.rs`'s `WakeIds`: 0, 1 and 2 for a waker that does not say who
/// it is, a node and the launcher, then one for each sensor the actor
/// reads (a node's own, every sensor for the launcher).
fn max_wake_id(topology: &Topology, actor: ActorId) -> usize {
    2 + match actor {
        ActorId::Node(n) | ActorId::Mac(n) => topology.node_sensors[n as usize].len(),
        ActorId::Launcher => topology.sensors(),
        ActorId::Sensor(_) => 0,
    }
}

/// Every channel a run on one host opens: the pair channels only when its
/// protocol exchanges in pairs, the control channels of the nodes.
pub fn channels(topology: &Topology, pairs: bool) -> Vec<Channel> {
    let nodes = topology.nodes() as u16;
    let mut v = vec![Channel::Lifecycle];
    for n in 0..nodes {
        v.extend(topology.activation_channels(n));
        v.push(Channel::Consensus(n));
        v.push(Channel::Control(ActorId::Node(n)));
        v.push(Channel::Telemetry(n));
        if topology.macs {
            v.push(Channel::MacOutput(n));
        }
        if pairs {
            for &m in &topology.neighbours[n as usize] {
                v.push(Channel::Pair { from: n, to: m });
            }
        }
    }
    v.extend((0..topology.sensors() as u16).map(Channel::Observation));
    v
}

/// What a run's services take of the machine, added up from the limits
/// above: an estimate kept above what a run was measured to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Footprint {
    /// Bytes in `/dev/shm`: data segments, connections, the services'
    /// and processes' own files, and the table rows the nodes share.
    pub shared_bytes: u64,
    /// Files in `/dev/shm`.
    pub files: u64,
    /// Memory maps the launcher holds.
    pub launcher_maps: u64,
}

/// A connection between a publisher and one subscriber: a byte for each
/// sample of the publisher's segment, and 1,292 bytes (measured: 16,804
/// bytes for a broadcast channel's 15,512 samples, 172,960 for 171,668).
/// So a channel every actor reads costs the square of the network: such a
/// channel (the truth, once a message to every sensor) took 432 MB of the
/// 611 MB at 2,601 processes. The one left, the lifecycle's, keeps a
/// short queue.
const CONNECTION_BYTES: u64 = 1_400;
/// A service's static and dynamic files: at most 6.1 kB measured (a
/// broadcast's dynamic configuration, which lists every subscriber), most
/// under 2.5 kB.
const SERVICE_BYTES: u64 = 4 << 10;
/// A process's iceoryx2 node files (its details and monitor): 2.1 kB.
const PROCESS_BYTES: u64 = 3 << 10;
/// Files of a process (its node's details, monitor, monitor's lock and
/// context, and its directory), of a service (static and dynamic), and of
/// a port (its tag and its service tag).
const FILES_PER_PROCESS: u64 = 5;
const FILES_PER_SERVICE: u64 = 2;
const FILES_PER_PORT: u64 = 2;
/// The launcher's maps besides its children's (its own libraries, heap,
/// its node), and per child (the wake-up service it notifies, the
/// connection of the lifecycle's or a control channel's publisher), and
/// per sensor whose observations it reads (a connection, the sensor's data
/// segment, the service's dynamic configuration). Fitted to 583 maps
/// measured in the default run and 5,947 at 2,601 processes, about 2.3 a
/// child between them, and kept above both.
const LAUNCHER_BASE_MAPS: u64 = 64;
const LAUNCHER_MAPS_PER_CHILD: u64 = 3;
const LAUNCHER_MAPS_PER_OBSERVED_SENSOR: u64 = 4;

impl Footprint {
    /// A one-host run of `topology`: `pairs` when its protocol exchanges in
    /// pairs, `centralized` when the launcher reads every observation, and
    /// `table_bytes` of table rows the nodes share. The channels between
    /// nodes are the nodes' inboxes there, a file each (`inbox.rs`).
    pub fn of(topology: &Topology, pairs: bool, centralized: bool, table_bytes: u64) -> Self {
        let children = topology.actors().count() as u64;
        let processes = children + 1;
        let channels: Vec<Channel> = channels(topology, pairs)
            .into_iter()
            .filter(|c| !crate::inbox::carries(*c))
            .collect();
        let inbox_bytes: u64 = (0..topology.nodes() as u16)
            .map(|n| crate::inbox::Layout::of(topology, n).len() as u64)
            .sum();
        let mut segments = 0u64;
        let mut connections = 0u64;
        let mut connection_bytes = 0u64;
        for &c in &channels {
            let limits = ChannelLimits::of(topology, c);
            segments += limits.segment_bytes();
            let mut readers = topology.subscribers(c) as u64;
            if !centralized && matches!(c, Channel::Observation(_)) {
                readers -= 1;
            }
            connections += readers;
            connection_bytes += readers * (limits.samples() as u64 + CONNECTION_BYTES);
        }
        // Every process listens on its wake-up service and notifies its peers.
        let wake_services = processes;
        let notifiers: u64 = topology
            .actors()
            .map(|a| topology.peers(a) as u64)
            .sum::<u64>();
        let services = channels.len() as u64 + wake_services;
        let publishers = channels.len() as u64;
        let ports = publishers + connections + wake_services + notifiers;
        let observed = if centralized {
            topology.sensors() as u64
        } else {
            0
        };
        Self {
            shared_bytes: segments
                + connection_bytes
                + services * SERVICE_BYTES
                + processes * PROCESS_BYTES
                + inbox_bytes
                + table_bytes,
            files: processes * FILES_PER_PROCESS
                + services * FILES_PER_SERVICE
                + ports * FILES_PER_PORT
                + publishers
                + connections
                + wake_services
                + topology.nodes() as u64,
            launcher_maps: LAUNCHER_BASE_MAPS
                + LAUNCHER_MAPS_PER_CHILD * children
                + LAUNCHER_MAPS_PER_OBSERVED_SENSOR * observed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::scenario::Scenario;

    fn topology(overrides: &[&str]) -> Topology {
        let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
        let s =
            Scenario::from_toml(fusion_graph::scenario::DEFAULT_SCENARIO, "t", &overrides).unwrap();
        Topology::from_scenario(&s, "t").unwrap()
    }

    /// The table rows' file in the runs measured below (8,579,712 bytes).
    const TABLE_BYTES: u64 = 8_579_712;

    /// Against `/dev/shm` (`du -sb`, `find -type f | wc -l`) and
    /// `/proc/<launcher>/maps` while the network ran without the
    /// centralized reference (the largest of once a second over the run):
    /// 26,242,967 bytes, 7,985 files and 582 maps for the default network
    /// of 235 processes; 231,490,012 bytes, 88,737 files and 5,860 maps
    /// for 2,601. The estimate stays above, within half again as much.
    #[test]
    fn the_footprint_is_estimated_above_what_runs_were_measured_to_use() {
        let cases = [
            (topology(&[]), [26_242_967.0, 7_985.0, 582.0]),
            (
                topology(&[
                    "nodes.grid=[10,10]",
                    "region.width=5000",
                    "region.height=5000",
                ]),
                [231_490_012.0, 88_737.0, 5_860.0],
            ),
        ];
        for (t, measured) in cases {
            let f = Footprint::of(&t, false, false, TABLE_BYTES);
            let estimate = [
                f.shared_bytes as f64,
                f.files as f64,
                f.launcher_maps as f64,
            ];
            for ((e, m), what) in estimate
                .iter()
                .zip(measured)
                .zip(["bytes", "files", "maps"])
            {
                assert!(
                    *e >= m && *e < 1.5 * m,
                    "{} processes, {what}: estimated {e}, measured {m}",
                    t.nodes() + t.sensors() + 1
                );
            }
        }
    }

    #[test]
    fn a_publishers_segment_holds_every_subscribers_queue() {
        let t = topology(&[]);
        // The stop, to 225 sensors (and a bridge): a short queue each.
        let lifecycle = ChannelLimits::of(&t, Channel::Lifecycle);
        assert_eq!(lifecycle.subscribers, 226);
        assert_eq!(lifecycle.samples(), 226 * 4 + 2);
        // An activation: one sensor (and a bridge), a full queue.
        let activation = ChannelLimits::of(
            &t,
            Channel::Activation {
                node: 4,
                to: ActorId::Sensor(100),
            },
        );
        assert_eq!(activation.subscribers, 2);
        assert_eq!(activation.samples(), 2 * 66 + 2);
        // Measured: the old broadcast tick's data segment, 235 subscribers
        // of 61-byte messages, was 1,799,542 bytes in the default run: the
        // samples and a segment header.
        let tick_like = ChannelLimits {
            subscribers: 235,
            message_bytes: 61,
            ..activation
        };
        assert!(tick_like.segment_bytes().abs_diff(1_799_542) < 1024);
    }

    #[test]
    fn a_wake_up_service_admits_its_peers_and_their_event_ids() {
        let t = topology(&[]);
        let node = WakeLimits::of_actor(&t, ActorId::Node(4));
        // 25 sensors, 4 neighbours and the launcher, and the slack.
        assert_eq!(node.notifiers, 25 + 4 + 1 + WAKE_SLACK);
        assert_eq!(node.max_event_id, 2 + 25);
        let sensor = WakeLimits::of_actor(&t, ActorId::Sensor(0));
        assert_eq!((sensor.notifiers, sensor.max_event_id), (2 + WAKE_SLACK, 2));
    }
}
