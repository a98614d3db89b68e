//! What every actor of a network is to the code that drives it: a state
//! machine with no I/O. It is handed one message at a time with the time it
//! is handled at, says when it wants to be woken, hands out the heavy work
//! it wants timed, and takes the work's result; what it wants sent comes
//! back as [`Outgoing`] messages. The in-process driver, the process
//! driver and the hosts' agent are each written once, over this trait,
//! for the sensor, the channel and every kind of processing node alike.

use std::fmt;
use std::time::Duration;

use wire::{ActorId, Message};

use crate::Channel;

/// A message an actor wants published.
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    pub channel: Channel,
    pub message: Message,
    pub receivers: Vec<ActorId>,
    /// Whom to wake, when not every receiver: a consensus round wakes only
    /// the neighbours it still waits for.
    pub wake: Option<Vec<ActorId>>,
}

/// Who an actor is and how it is connected: what its transport must open
/// for it before it runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Wiring {
    pub actor: ActorId,
    /// The channels it reads.
    pub reads: Vec<Channel>,
    /// The channels it publishes on.
    pub publishes: Vec<Channel>,
    /// The actors it sends to, whom its transport must be able to wake.
    pub wakes: Vec<ActorId>,
}

/// An actor as its drivers see it. Only [`wiring`](Actor::wiring) and
/// [`handle`](Actor::handle) are required: an actor that never waits and
/// never works leaves the rest as they are.
pub trait Actor {
    /// The heavy stages this actor hands out, which a driver runs with
    /// [`run_work`](Actor::run_work), times by its own clock and reports
    /// back with [`work_done`](Actor::work_done): the actor never reads a
    /// clock, so its results do not depend on one.
    type Work: Copy + Eq + fmt::Debug;

    fn wiring(&self) -> Wiring;

    /// Takes one message, handled at `now`.
    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>);

    /// When [`handle_timeout`](Actor::handle_timeout) should next be
    /// called, if a stage waits.
    fn poll_timeout(&self) -> Option<Duration> {
        None
    }

    /// The time from [`poll_timeout`](Actor::poll_timeout) has come (or
    /// passed: `now` says how far).
    fn handle_timeout(&mut self, _now: Duration, _out: &mut Vec<Outgoing>) {}

    /// The heavy stage waiting to run, if any.
    fn poll_work(&self) -> Option<Self::Work> {
        None
    }

    /// Runs `work`, with no I/O and no clock.
    fn run_work(&mut self, _work: Self::Work) {}

    /// `work` finished at `now` after `elapsed`; the actor goes on.
    fn work_done(
        &mut self,
        _work: Self::Work,
        _elapsed: Duration,
        _now: Duration,
        _out: &mut Vec<Outgoing>,
    ) {
    }

    /// Whether a driver that shares cores with the actor's neighbours
    /// should give its core away before `work`: the neighbours may still
    /// be in rounds that every node waits for, while `work` is on this
    /// actor's way alone.
    fn gives_way_before(&self, _work: Self::Work) -> bool {
        false
    }

    /// Steps whose truth the world did not hold when this actor looked,
    /// since it was last asked (only sensors look). A driver counts them,
    /// so that a run's summary says how many observations it never made.
    fn take_world_misses(&mut self) -> u32 {
        0
    }
}

impl<A: Actor + ?Sized> Actor for Box<A> {
    type Work = A::Work;

    fn wiring(&self) -> Wiring {
        (**self).wiring()
    }
    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        (**self).handle(message, now, out)
    }
    fn poll_timeout(&self) -> Option<Duration> {
        (**self).poll_timeout()
    }
    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        (**self).handle_timeout(now, out)
    }
    fn poll_work(&self) -> Option<Self::Work> {
        (**self).poll_work()
    }
    fn run_work(&mut self, work: Self::Work) {
        (**self).run_work(work)
    }
    fn work_done(
        &mut self,
        work: Self::Work,
        elapsed: Duration,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        (**self).work_done(work, elapsed, now, out)
    }
    fn gives_way_before(&self, work: Self::Work) -> bool {
        (**self).gives_way_before(work)
    }
    fn take_world_misses(&mut self) -> u32 {
        (**self).take_world_misses()
    }
}
