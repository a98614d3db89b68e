//! What every driver of the actors does alike, written once over
//! [`Actor`]: hand an actor a message or the passing of its timeout, run
//! its heavy stages and time them (the actor never reads a clock), count
//! the truths a sensor could not read, and send what the actor emitted.

use std::time::{Duration, Instant};

use fusion_graph::{Actor, Message, Outgoing};
use transport::{SendError, Transport};

/// Hands `actor` one message at `now`, then runs whatever work it hands
/// out and sends everything it emitted.
pub fn deliver<A: Actor + ?Sized, T: Transport + ?Sized>(
    actor: &mut A,
    transport: &mut T,
    message: &Message,
    now: Duration,
    out: &mut Vec<Outgoing>,
    give_way: impl Fn(),
) -> Result<(), SendError> {
    actor.handle(message, now, out);
    for _ in 0..actor.take_world_misses() {
        transport.accounting_mut().record_world_miss();
    }
    run_pending_work(actor, transport, out, give_way)
}

/// Tells `actor` that `now` has come, if it waits for a time, then runs
/// its work and sends what it emitted.
pub fn time_passes<A: Actor + ?Sized, T: Transport + ?Sized>(
    actor: &mut A,
    transport: &mut T,
    now: Duration,
    out: &mut Vec<Outgoing>,
    give_way: impl Fn(),
) -> Result<(), SendError> {
    actor.handle_timeout(now, out);
    run_pending_work(actor, transport, out, give_way)
}

/// Runs the actor's pending stages, each timed by the wall clock and
/// reported at the transport's time when it finished, and sends what each
/// stage emitted before the next begins: the telemetry of a step goes out
/// before the node scores its sensors for the next. Before a stage the
/// actor asks to give way for, `give_way` runs (where a process driver
/// yields its core).
pub fn run_pending_work<A: Actor + ?Sized, T: Transport + ?Sized>(
    actor: &mut A,
    transport: &mut T,
    out: &mut Vec<Outgoing>,
    give_way: impl Fn(),
) -> Result<(), SendError> {
    send_all(transport, out)?;
    while let Some(work) = actor.poll_work() {
        if actor.gives_way_before(work) {
            give_way();
        }
        let started = Instant::now();
        actor.run_work(work);
        actor.work_done(work, started.elapsed(), transport.now(), out);
        send_all(transport, out)?;
    }
    Ok(())
}

/// Publishes every outgoing message, waking whom each asks.
pub fn send_all<T: Transport + ?Sized>(
    transport: &mut T,
    outgoing: &mut Vec<Outgoing>,
) -> Result<(), SendError> {
    for o in outgoing.drain(..) {
        let wake = o.wake.as_deref().unwrap_or(&o.receivers);
        transport.send_waking(o.channel, &o.message, &o.receivers, wake)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::{ActorId, Scenario, Topology};
    use sensor::SensorActor;
    use transport::world_memory::TruthRing;
    use transport::{Channel, MemoryBus, MemoryTransport};
    use wire::{BitMask, Payload};

    /// An activation for a step the world holds is answered; one for a step
    /// it does not hold is counted as a failed read and answered with
    /// nothing, never with another step's truth.
    #[test]
    fn a_step_the_world_does_not_hold_is_counted_not_observed() {
        let s = Scenario::default_scenario();
        let t = Topology::from_scenario(&s, "d").unwrap();
        let bus = MemoryBus::new();
        let format = s.wire_format(&t);
        let mut node = MemoryTransport::new(ActorId::Node(0), bus.clone(), format, 1);
        node.subscribe(Channel::Observation(0)).unwrap();
        let mut transport = MemoryTransport::new(ActorId::Sensor(0), bus, format, 2);
        let (truths, world) = TruthRing::on_heap(4);
        let mut sensor = SensorActor::new(&s, &t, 0).unwrap().in_world(world, false);
        for c in sensor.wiring().publishes {
            transport.publish_on(c).unwrap();
        }
        truths.write(1, &bounds::State::new(1000.0, 900.0, -6.0, -7.0));
        let mut out = Vec::new();
        for step in [1, 2] {
            let activation = Message::new(
                ActorId::Node(0),
                step,
                0,
                Payload::Activate {
                    mask: BitMask::from_indices([0]),
                },
            );
            let now = transport.now();
            deliver(
                &mut sensor,
                &mut transport,
                &activation,
                now,
                &mut out,
                || {},
            )
            .unwrap();
        }
        assert_eq!(transport.accounting().world_misses(), 1);
        let mut got = Vec::new();
        node.receive(node.now(), &mut got).unwrap();
        let steps: Vec<u32> = got.iter().map(|m| m.header.step).collect();
        assert_eq!(steps, vec![1], "only the step the world held is observed");
    }
}
