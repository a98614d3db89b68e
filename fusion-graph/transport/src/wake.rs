//! Wake-up services: an event service per actor whose event ids say who
//! woke it, what a wake-up tells the woken about which channels to read, and
//! a host bridge's wake-up service for actors on other hosts.

use iceoryx2::prelude::*;

use super::futex;
use super::Channel;
use crate::SetupError;
use fusion_graph::channel::RunId;
use fusion_graph::hosts::Placement;
use fusion_graph::topology::Topology;
use wire::ActorId;

use super::limits::WakeLimits;
use super::resources::{retry, setup, RunResources};

/// The event ids of one actor's wake-up service: who woke it, as far as it
/// needs to know.
///
/// - `ANONYMOUS` (0): a wake-up that does not say whose message it brings
///   (a host's bridge); the woken read everything.
/// - `OTHER` (1): a node, whose channels are read at every receive anyway,
///   or a sensor whose observations the actor does not read.
/// - `LAUNCHER` (2): the launcher, whose channels to an actor (its control
///   channel, the lifecycle) are read when it woke the actor.
/// - `3 + k`: the k-th sensor whose observations the actor reads (a node's
///   own sensors in topology order; every sensor for the launcher).
///
/// Ids are numbered per receiver, not per network: iceoryx2 drains a
/// listener by swapping every id's counter, so a wait costs a locked
/// instruction per id the service has. A node's service has 28 (its 25
/// sensors), not the 2,600 of a network-wide numbering at the largest size.
pub(crate) struct WakeIds {
    /// The sensors, in id order.
    pub(crate) sensors: Vec<u16>,
}

impl WakeIds {
    pub(crate) const ANONYMOUS: usize = 0;
    pub(crate) const OTHER: usize = 1;
    pub(crate) const LAUNCHER: usize = 2;
    const FIRST_SENSOR: usize = 3;

    pub(crate) fn of(receiver: ActorId, topology: &Topology) -> Self {
        Self {
            sensors: match receiver {
                // A channel reads its node's sensors, as the node does
                // without one.
                ActorId::Node(n) | ActorId::Mac(n) => topology.node_sensors[n as usize].clone(),
                ActorId::Launcher => (0..topology.sensors() as u16).collect(),
                ActorId::Sensor(_) => Vec::new(),
            },
        }
    }

    /// The largest id (`limits::WakeLimits` sizes the service for it).
    #[cfg(test)]
    pub(crate) fn max(&self) -> usize {
        Self::LAUNCHER + self.sensors.len()
    }

    /// The id wake-ups from `waker` carry.
    pub(crate) fn id_of(&self, waker: ActorId) -> usize {
        match waker {
            ActorId::Sensor(s) => self
                .sensors
                .iter()
                .position(|&x| x == s)
                .map_or(Self::OTHER, |k| Self::FIRST_SENSOR + k),
            ActorId::Launcher => Self::LAUNCHER,
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
/// heard. The launcher's channels likewise: it wakes every receiver of
/// what it sends, and a node that polled its control channel at every
/// wake-up paid for the subscriber's pages at every consensus round (in
/// `benches/message_path.rs` with caches cold, a round with no control
/// channel at all took 1.81 and 1.90 ms against 2.52 with it polled).
/// Every other channel is read at every `receive`: their publishers
/// wake only some receivers (a node's activation wakes its active sensors,
/// its consensus its live neighbours), and the rest must still find the
/// message when something else wakes them. A wake-up that does not say who
/// sent it, or a wait that ends without one (a timeout, or a wake-up whose
/// notification failed), reads everything.
pub(crate) struct Heard {
    pub(crate) ids: WakeIds,
    /// Whether each sensor (by sensor index) woke us.
    pub(crate) sensors: Vec<bool>,
    /// Whether the launcher woke us.
    pub(crate) launcher: bool,
    pub(crate) everything: bool,
    /// Whether a wait took the wake-ups since the last `receive`; if not,
    /// `receive` takes them itself (a system call), unless no subscription
    /// is read selectively.
    pub(crate) waited: bool,
    pub(crate) selective: bool,
}

impl Heard {
    pub(crate) fn new(me: ActorId, topology: &Topology) -> Self {
        Self {
            ids: WakeIds::of(me, topology),
            sensors: vec![false; topology.sensors()],
            launcher: false,
            everything: true,
            waited: false,
            selective: false,
        }
    }

    /// A wake-up carrying event id `id`.
    pub(crate) fn hear(&mut self, id: usize) {
        match id {
            // The nodes' channels are read anyway.
            WakeIds::OTHER => {}
            WakeIds::LAUNCHER => self.launcher = true,
            k if k >= WakeIds::FIRST_SENSOR
                && k - WakeIds::FIRST_SENSOR < self.ids.sensors.len() =>
            {
                let sensor = self.ids.sensors[k - WakeIds::FIRST_SENSOR];
                if let Some(heard) = self.sensors.get_mut(sensor as usize) {
                    *heard = true;
                }
            }
            _ => self.everything = true,
        }
    }

    pub(crate) fn everything(&mut self) {
        self.everything = true;
    }

    pub(crate) fn may_have_data(&self, channel: Channel) -> bool {
        match channel {
            Channel::Observation(s) => {
                self.everything || self.sensors.get(s as usize).copied().unwrap_or(true)
            }
            Channel::Control(_) | Channel::Lifecycle => self.everything || self.launcher,
            _ => true,
        }
    }

    pub(crate) fn clear(&mut self) {
        self.everything = false;
        self.launcher = false;
        self.waited = false;
        self.sensors.fill(false);
    }
}

pub(crate) fn open_wake(
    node: &Node<futex::Service>,
    run: &RunId,
    actor: ActorId,
    topology: &Topology,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<futex::Service>, SetupError> {
    let name = run.service_name(&format!("wake/{actor}"))?;
    open_event(
        node,
        &name,
        WakeLimits::of_actor(topology, actor),
        "wake event",
    )
}

/// Opens or creates an event service with `limits`.
pub(crate) fn open_event(
    node: &Node<futex::Service>,
    name: &ServiceName,
    limits: WakeLimits,
    what: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<futex::Service>, SetupError> {
    retry(|| {
        node.service_builder(name)
            .event()
            .max_notifiers(limits.notifiers)
            .max_listeners(limits.listeners)
            .max_nodes(limits.nodes)
            .event_id_max_value(limits.max_event_id)
            .open_or_create()
    })
    .map_err(|e| setup(what, e))
}

/// A host bridge's wake-up service: every actor of the host that sends to
/// another host notifies it, with the far receiver's wake id.
pub(crate) fn open_bridge_wake(
    node: &Node<futex::Service>,
    run: &RunId,
    placement: &Placement,
    host: usize,
    topology: &Topology,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<futex::Service>, SetupError> {
    let name = run.service_name("wake/bridge")?;
    let limits = WakeLimits::of_bridge(placement, host, topology);
    open_event(node, &name, limits, "bridge wake event")
}
