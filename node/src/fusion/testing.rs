//! A virtual clock for fusion protocols alone: every node's protocol, the
//! messages between them carried with the latency a rule chooses (or
//! dropped), and the clock jumping to the next delivery or timeout. Only
//! live nodes (`view`) start or receive; a dead one's messages never arrive.

use std::time::Duration;

use fusion_graph::ActorId;
use wire::{Message, Payload};

use super::FusionProtocol;

/// What happens to one message on its way from one node to another.
pub enum Fate {
    Deliver(Duration),
    Drop,
}

/// Runs one step (step 1) of `nodes` from the values `value(r)` until every
/// live node has its result and nothing is in flight. Panics if that takes
/// longer than `limit` of virtual time: a protocol that hangs fails its test.
pub fn drive<P: FusionProtocol>(
    mut nodes: Vec<P>,
    value: impl Fn(u16) -> P::Value,
    view: &[bool],
    mut fate: impl FnMut(u16, u16, &Payload) -> Fate,
    limit: Duration,
) -> Vec<Option<P::Output>> {
    let mut now = Duration::ZERO;
    let mut results: Vec<Option<P::Output>> = nodes.iter().map(|_| None).collect();
    // (due, to, message)
    let mut in_flight: Vec<(Duration, u16, Message)> = Vec::new();
    let mut out = Vec::new();
    let mut post = |out: &mut Vec<crate::Outgoing>,
                    now: Duration,
                    in_flight: &mut Vec<(Duration, u16, Message)>| {
        for o in out.drain(..) {
            let ActorId::Node(from) = o.message.header.sender else {
                continue;
            };
            for to in o.receivers {
                let ActorId::Node(to) = to else { continue };
                if !view[to as usize] {
                    continue;
                }
                if let Fate::Deliver(latency) = fate(from, to, &o.message.payload) {
                    in_flight.push((now + latency, to, o.message.clone()));
                }
            }
        }
    };
    for (r, node) in nodes.iter_mut().enumerate() {
        if view[r] {
            node.expect_step(1);
            node.start(1, value(r as u16), view, now, &mut out);
            post(&mut out, now, &mut in_flight);
        }
    }
    loop {
        for (r, node) in nodes.iter_mut().enumerate() {
            if view[r] && results[r].is_none() {
                results[r] = node.poll_result();
            }
        }
        let done = (0..nodes.len()).all(|r| !view[r] || results[r].is_some());
        if done && in_flight.is_empty() {
            return results;
        }
        let next_delivery = in_flight.iter().map(|(due, _, _)| *due).min();
        let next_timeout = nodes
            .iter()
            .enumerate()
            .filter(|(r, _)| view[*r])
            .filter_map(|(_, n)| n.poll_timeout())
            .min();
        let Some(next) = next_delivery.into_iter().chain(next_timeout).min() else {
            return results;
        };
        now = now.max(next);
        assert!(now <= limit, "still running at {now:?}");
        let (due, later): (Vec<_>, Vec<_>) = in_flight.drain(..).partition(|(d, _, _)| *d <= now);
        in_flight = later;
        for (_, to, message) in due {
            nodes[to as usize].handle(&message, now, &mut out);
            post(&mut out, now, &mut in_flight);
        }
        for (r, node) in nodes.iter_mut().enumerate() {
            if view[r] && node.poll_timeout().is_some_and(|t| t <= now) {
                node.handle_timeout(now, &mut out);
                post(&mut out, now, &mut in_flight);
            }
        }
    }
}
