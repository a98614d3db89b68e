//! The iceoryx2 ends of a host's bridge: the outlet reads what leaves the
//! host, the inlet publishes what arrives from other hosts. Bytes only:
//! nothing that crosses is decoded or counted here.

use std::collections::HashMap;
use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

use super::futex;
use super::Channel;
use crate::{ReceiveError, SendError, SetupError, WaitError};
use fusion_graph::channel::RunId;
use fusion_graph::hosts::{actor_of_wake_id, Placement};
use fusion_graph::topology::Topology;
use wire::ActorId;

use super::iceoryx::{listen, open_channel, publish, Pub, Sub};
use super::limits::max_message_len;
use super::resources::DeadNodeSweep;
use super::resources::{setup, RunResources};
use super::wake::{open_bridge_wake, open_wake, WakeIds};

/// A node for one side of a host's bridge.
fn bridge_node(run: &RunId, side: &str) -> Result<Node<futex::Service>, SetupError> {
    let config = run.config(DeadNodeSweep::On)?;
    let name = NodeName::new(&format!("bridge-{side}")).map_err(|e| setup("node name", e))?;
    let node = NodeBuilder::new()
        .config(&config)
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<futex::Service>()
        .map_err(|e| setup("node", e))?;
    crate::resources::keep_global_segment_private(run);
    Ok(node)
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
                .initial_max_slice_len(max_message_len(channel, topology))
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
