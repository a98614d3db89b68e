//! What every driver of the actors does alike: run a node's heavy stages
//! and time them (the node never reads a clock), and send what an actor
//! emitted.

use std::time::{Duration, Instant};

use fusion_graph::{SendError, Transport};
use node::{Outgoing, ProcessingNode};

/// Runs the node's pending stages, each timed by the wall clock and
/// reported at the time `now` says it finished.
pub fn run_pending_work(
    node: &mut ProcessingNode,
    mut now: impl FnMut() -> Duration,
    out: &mut Vec<Outgoing>,
) {
    while let Some(work) = node.poll_work() {
        let started = Instant::now();
        node.run_work(work);
        node.work_done(work, started.elapsed(), now(), out);
    }
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
