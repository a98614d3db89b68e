//! What every driver of the actors does alike: run a node's heavy stages
//! and time them (the node never reads a clock), let a sensor look at the
//! world, and send what an actor emitted.

use std::time::Instant;

use fusion_graph::world_memory::WorldView;
use fusion_graph::{ActorId, Message, SendError, Transport};
use node::{Outgoing, ProcessingNode};
use sensor::SensorActor;

/// Runs the node's pending stages, each timed by the wall clock and
/// reported at the transport's time when it finished, and sends what each
/// stage emitted before the next begins: the telemetry of a step goes out
/// before the node scores its sensors for the next.
pub fn run_pending_work<T: Transport + ?Sized>(
    node: &mut ProcessingNode,
    transport: &mut T,
    out: &mut Vec<Outgoing>,
) -> Result<(), SendError> {
    send_all(transport, out)?;
    while let Some(work) = node.poll_work() {
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
