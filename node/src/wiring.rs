//! What either processing node (the CF/DPF's [`NodeActor`](crate::NodeActor)
//! or the random-exchange paper's [`DiffusionNode`](crate::DiffusionNode)) reads, publishes
//! on and wakes, and the messages both send alike: the activation of their
//! sensors and the step's telemetry.

use std::time::Duration;

use bounds::State;
use fusion_graph::Channel;
use fusion_graph::{ActorId, Topology};
use wire::{BitMask, Message, Payload, Telemetry};

use crate::Outgoing;

/// The channels node `index` reads: its control, its sensors' observations
/// and its neighbours' consensus channels.
pub(crate) fn subscriptions(topology: &Topology, index: u16) -> Vec<Channel> {
    let mut v = vec![Channel::Control(ActorId::Node(index))];
    v.extend(
        topology.node_sensors[index as usize]
            .iter()
            .map(|s| Channel::Observation(*s)),
    );
    v.extend(
        topology.neighbours[index as usize]
            .iter()
            .map(|m| Channel::Consensus(*m)),
    );
    v
}

/// The channels node `index` publishes on: an activation channel to each
/// of its sensors, its consensus channel and its telemetry.
pub(crate) fn publications(topology: &Topology, index: u16) -> Vec<Channel> {
    let mut v: Vec<Channel> = topology.activation_channels(index).collect();
    v.push(Channel::Consensus(index));
    v.push(Channel::Telemetry(index));
    v
}

/// The actors node `index` sends to (to wake them): its sensors, its
/// neighbours, the launcher.
pub(crate) fn peers(topology: &Topology, index: u16) -> Vec<ActorId> {
    let mut v: Vec<ActorId> = topology.node_sensors[index as usize]
        .iter()
        .map(|s| ActorId::Sensor(*s))
        .collect();
    v.extend(
        topology.neighbours[index as usize]
            .iter()
            .map(|m| ActorId::Node(*m)),
    );
    v.push(ActorId::Launcher);
    v
}

/// Whether a `BeginStep` for `step` moves a node on: only a later step of
/// this run does. A repeated, past or impossible step (a corrupted or
/// forged message) is dropped: coasting to step 4·10⁹ would hang the node
/// for good.
pub(crate) fn is_next_step(step: u32, steps: u32, last: Option<u32>) -> bool {
    step != 0 && step <= steps && last.is_none_or(|l| step > l)
}

/// The activation of `picks` (positions in `own`, the node's sensors): the
/// same message to each active sensor on its own channel, so that a sensor
/// not active receives nothing and sleeps.
pub(crate) fn activate(
    out: &mut Vec<Outgoing>,
    node: u16,
    step: u32,
    own: &[u16],
    picks: &[usize],
    payload: Payload,
) {
    let message = Message::new(ActorId::Node(node), step, 0, payload);
    let active = picks.iter().map(|&i| ActorId::Sensor(own[i]));
    out.extend(to_each(node, &message, active));
}

/// Node `node`'s `message` to each of `receivers` (its sensors, or its
/// multiple-access channel), each on its own activation channel.
pub(crate) fn to_each<'a>(
    node: u16,
    message: &'a Message,
    receivers: impl IntoIterator<Item = ActorId> + 'a,
) -> impl Iterator<Item = Outgoing> + 'a {
    receivers.into_iter().map(move |to| Outgoing {
        channel: Channel::Activation { node, to },
        message: message.clone(),
        receivers: vec![to],
        wake: None,
    })
}

/// The mask of `picks` for an activation's payload.
pub(crate) fn mask(picks: &[usize]) -> BitMask {
    BitMask::from_indices(picks.iter().copied())
}

/// A node's telemetry for `step`, to the launcher.
pub(crate) fn telemetry(node: u16, step: u32, telemetry: Telemetry) -> Outgoing {
    Outgoing {
        channel: Channel::Telemetry(node),
        message: Message::new(ActorId::Node(node), step, 0, Payload::Telemetry(telemetry)),
        receivers: vec![ActorId::Launcher],
        wake: None,
    }
}

/// A stage's time for telemetry: whole microseconds, saturating.
pub(crate) fn micros(d: Duration) -> u32 {
    d.as_micros().min(u32::MAX as u128) as u32
}

/// An estimate for telemetry: a component that is not finite is sent as 0
/// (the wire carries no NaN the launcher would have to guard against).
pub(crate) fn reported_estimate(estimate: &State) -> [f64; 4] {
    std::array::from_fn(|i| {
        if estimate[i].is_finite() {
            estimate[i]
        } else {
            0.0
        }
    })
}
