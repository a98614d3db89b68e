//! What every driver of the actors does alike: run a node's heavy stages
//! and time them (the node never reads a clock), let a sensor look at the
//! world, and send what an actor emitted.

use std::time::Instant;

use fusion_graph::world::WorldView;
use fusion_graph::{ActorId, Message};
use node::{Outgoing, ProcessingNode, Work};
use sensor::SensorActor;
use transport::{SendError, Transport};

/// Runs the node's pending stages, each timed by the wall clock and
/// reported at the transport's time when it finished, and sends what each
/// stage emitted before the next begins: the telemetry of a step goes out
/// before the node scores its sensors for the next.
pub fn run_pending_work<T: Transport + ?Sized>(
    node: &mut ProcessingNode,
    transport: &mut T,
    out: &mut Vec<Outgoing>,
) -> Result<(), SendError> {
    run_pending_work_with(node, transport, out, |_| {})
}

/// [`run_pending_work`], calling `before` with each stage before it runs
/// (where a process driver gives way to other processes).
pub fn run_pending_work_with<T: Transport + ?Sized>(
    node: &mut ProcessingNode,
    transport: &mut T,
    out: &mut Vec<Outgoing>,
    before: impl Fn(Work),
) -> Result<(), SendError> {
    send_all(transport, out)?;
    while let Some(work) = node.poll_work() {
        before(work);
        let started = Instant::now();
        node.run_work(work);
        node.work_done(work, started.elapsed(), transport.now(), out);
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

/// Hands a sensor one message and sends the observation it answers with,
/// to `receivers`. A step the world does not hold is counted (the summary
/// reports it) and logged; the sensor stays silent for that step.
pub fn sensor_handles<T: Transport + ?Sized>(
    sensor: &mut SensorActor,
    transport: &mut T,
    message: &Message,
    world: &dyn WorldView,
    receivers: &[ActorId],
) -> Result<(), SendError> {
    match sensor.handle(message, world) {
        Ok(Some(observation)) => transport.send(sensor.publication(), &observation, receivers),
        Ok(None) => Ok(()),
        Err(missing) => {
            tracing::warn!(sensor = %sensor.id(), error = %missing, "no observation this step");
            transport.accounting_mut().record_world_miss();
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::{Scenario, Topology};
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
        let mut sensor = SensorActor::new(&s, &t, 0).unwrap();
        transport.publish_on(sensor.publication()).unwrap();
        let (truths, world) = TruthRing::on_heap(4);
        truths.write(1, &bounds::State::new(1000.0, 900.0, -6.0, -7.0));
        let to = [sensor.reports_to()];
        for step in [1, 2] {
            let activation = Message::new(
                ActorId::Node(0),
                step,
                0,
                Payload::Activate {
                    mask: BitMask::from_indices([0]),
                },
            );
            sensor_handles(&mut sensor, &mut transport, &activation, &world, &to).unwrap();
        }
        assert_eq!(transport.accounting().world_misses(), 1);
        let mut got = Vec::new();
        node.receive(node.now(), &mut got).unwrap();
        let steps: Vec<u32> = got.iter().map(|m| m.header.step).collect();
        assert_eq!(steps, vec![1], "only the step the world held is observed");
    }
}
