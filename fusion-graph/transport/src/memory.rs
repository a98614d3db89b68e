//! The in-memory transport: every actor in one process, messages passed
//! through a shared bus, deterministic for a given seed. Time is whatever the
//! driver says it is.

use std::cell::RefCell;
use std::collections::{HashMap, VecDeque};
use std::rc::Rc;
use std::time::Duration;

use super::{Channel, Inbound, Outbound, Transport};
use crate::accounting::Accounting;
use crate::{ReceiveError, SendError, SetupError, WaitError};
use fusion_graph::shaper::LinkShaper;
use wire::ActorId;
use wire::{Message, WireFormat};

/// A message's bytes, shared by every inbox it is in: a message to n
/// readers is one allocation and one copy, not n.
type Bytes = Rc<[u8]>;

/// One actor's queue of arrived messages, shared between the bus (which
/// writes it) and the actor's transport (which reads it), so that neither
/// a send nor a receive looks the actor up.
type Inbox = Rc<RefCell<VecDeque<(ActorId, Bytes)>>>;

/// A channel's readers, with their inboxes in the same order.
#[derive(Debug, Default)]
struct Readers {
    actors: Vec<ActorId>,
    inboxes: Vec<Inbox>,
}

/// The shared medium: who subscribes to what, and each actor's inbox.
#[derive(Debug, Default)]
pub struct MemoryBus {
    subscribers: HashMap<Channel, Readers>,
    inboxes: HashMap<ActorId, Inbox>,
    /// The driver's clock.
    now: Duration,
}

impl MemoryBus {
    pub fn new() -> Rc<RefCell<Self>> {
        Rc::new(RefCell::new(Self::default()))
    }

    fn inbox(&mut self, actor: ActorId) -> Inbox {
        self.inboxes.entry(actor).or_default().clone()
    }

    pub fn subscribe(&mut self, actor: ActorId, channel: Channel) {
        let inbox = self.inbox(actor);
        let readers = self.subscribers.entry(channel).or_default();
        if !readers.actors.contains(&actor) {
            readers.actors.push(actor);
            readers.inboxes.push(inbox);
        }
    }

    pub fn set_now(&mut self, now: Duration) {
        self.now = now;
    }

    /// Forgets whatever waits for `actor` (it died; its successor starts clean).
    pub fn clear_inbox(&mut self, actor: ActorId) {
        if let Some(inbox) = self.inboxes.get(&actor) {
            inbox.borrow_mut().clear();
        }
    }

    /// Writes raw bytes as if `channel`'s publisher had sent them: for
    /// testing how receivers cope with garbage.
    pub fn inject_raw(&mut self, channel: Channel, bytes: &[u8]) {
        let bytes: Bytes = bytes.into();
        if let Some(readers) = self.subscribers.get(&channel) {
            for inbox in &readers.inboxes {
                inbox
                    .borrow_mut()
                    .push_back((channel.publisher(), bytes.clone()));
            }
        }
    }
}

pub struct MemoryTransport {
    me: ActorId,
    bus: Rc<RefCell<MemoryBus>>,
    format: WireFormat,
    accounting: Accounting,
    shaper: LinkShaper,
    buffer: Vec<u8>,
    inbox: Inbox,
    /// What a receive takes from the inbox, kept between receives so that
    /// receiving allocates nothing.
    arrived: VecDeque<(ActorId, Bytes)>,
}

impl MemoryTransport {
    pub fn new(me: ActorId, bus: Rc<RefCell<MemoryBus>>, format: WireFormat, seed: u64) -> Self {
        let inbox = bus.borrow_mut().inbox(me);
        Self {
            me,
            bus,
            inbox,
            format,
            accounting: Accounting::default(),
            shaper: LinkShaper::new(seed),
            buffer: Vec::with_capacity(512),
            arrived: VecDeque::new(),
        }
    }
}

impl Transport for MemoryTransport {
    fn me(&self) -> ActorId {
        self.me
    }

    fn publish_on(&mut self, channel: Channel) -> Result<(), SetupError> {
        channel.check_publisher(self.me)?;
        Ok(())
    }

    fn subscribe(&mut self, channel: Channel) -> Result<(), SetupError> {
        self.bus.borrow_mut().subscribe(self.me, channel);
        Ok(())
    }

    /// Nothing sleeps in one process: there is no one to wake.
    fn notify(&mut self, _actor: ActorId) -> Result<(), SetupError> {
        Ok(())
    }

    /// Nothing sleeps in one process, so `wake` does not matter here.
    fn send_waking(
        &mut self,
        channel: Channel,
        message: &Message,
        receivers: &[ActorId],
        _wake: &[ActorId],
    ) -> Result<(), SendError> {
        let mut outbound = Outbound {
            me: self.me,
            format: &self.format,
            accounting: &mut self.accounting,
            buffer: &mut self.buffer,
        };
        let me = self.me;
        let bus = self.bus.borrow();
        let readers = bus.subscribers.get(&channel);
        let (actors, inboxes) = readers.map_or((&[][..], &[][..]), |r| {
            (r.actors.as_slice(), r.inboxes.as_slice())
        });
        crate::check_receivers(channel, receivers, actors, &[])?;
        outbound.send(channel, message, receivers, |bytes| {
            let bytes: Bytes = bytes.into();
            for inbox in inboxes {
                inbox.borrow_mut().push_back((me, bytes.clone()));
            }
            Ok(())
        })
    }

    fn receive(&mut self, now: Duration, out: &mut Vec<Message>) -> Result<(), ReceiveError> {
        // The inbox and the empty queue trade places: the inbox keeps
        // the capacity the last receive left.
        std::mem::swap(&mut *self.inbox.borrow_mut(), &mut self.arrived);
        // Most actors, most of the time, have nothing: a sensor between
        // its activations is passed over at the cost of two checks.
        if self.arrived.is_empty() && self.shaper.held_count() == 0 {
            return Ok(());
        }
        let mut inbound = Inbound {
            me: self.me,
            format: &self.format,
            accounting: &mut self.accounting,
            shaper: &mut self.shaper,
        };
        for (from, bytes) in self.arrived.drain(..) {
            inbound.arrive(from, &bytes, now, out);
        }
        inbound.release(now, out);
        Ok(())
    }

    /// Nothing to wait for in one process: the driver decides when things happen.
    fn wait(&mut self, _timeout: Duration) -> Result<(), WaitError> {
        Ok(())
    }

    fn now(&self) -> Duration {
        self.bus.borrow().now
    }

    fn accounting(&self) -> &Accounting {
        &self.accounting
    }

    fn accounting_mut(&mut self) -> &mut Accounting {
        &mut self.accounting
    }

    fn shaper(&mut self) -> &mut LinkShaper {
        &mut self.shaper
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contract::{self, FORMAT};
    use wire::MessageKind;

    fn pair() -> (MemoryTransport, MemoryTransport, Rc<RefCell<MemoryBus>>) {
        let bus = MemoryBus::new();
        let sensor = MemoryTransport::new(ActorId::Sensor(0), bus.clone(), FORMAT, 1);
        let mut node = MemoryTransport::new(ActorId::Node(0), bus.clone(), FORMAT, 2);
        node.subscribe(Channel::Observation(0)).unwrap();
        (sensor, node, bus)
    }

    #[test]
    fn contract_delivery_and_counts() {
        let (mut s, mut n, _) = pair();
        contract::delivers_and_counts(&mut s, &mut n);
    }

    #[test]
    fn contract_pairwise() {
        let bus = MemoryBus::new();
        let node = |i| MemoryTransport::new(ActorId::Node(i), bus.clone(), FORMAT, 10 + i as u64);
        let (mut a, mut b, mut c) = (node(0), node(1), node(2));
        b.subscribe(Channel::Pair { from: 0, to: 1 }).unwrap();
        b.subscribe(Channel::Consensus(0)).unwrap();
        c.subscribe(Channel::Consensus(0)).unwrap();
        contract::a_pairwise_message_reaches_only_its_addressee(&mut a, &mut b, &mut c);
    }

    #[test]
    fn contract_some_readers_alone() {
        let bus = MemoryBus::new();
        let node = |i| MemoryTransport::new(ActorId::Node(i), bus.clone(), FORMAT, 10 + i as u64);
        let (mut a, mut b, mut c) = (node(0), node(1), node(2));
        b.subscribe(Channel::Consensus(0)).unwrap();
        c.subscribe(Channel::Consensus(0)).unwrap();
        contract::a_send_to_some_of_a_channels_readers_is_refused(&mut a, &mut b, &mut c);
    }

    #[test]
    fn contract_loss() {
        let (mut s, mut n, _) = pair();
        contract::loss_is_applied_and_counted(&mut s, &mut n);
    }

    #[test]
    fn garbage_is_counted_as_malformed_and_dropped() {
        let (_, mut n, bus) = pair();
        bus.borrow_mut()
            .inject_raw(Channel::Observation(0), &[1, 2, 3, 4, 5]);
        let mut out = Vec::new();
        n.receive(Duration::ZERO, &mut out).unwrap();
        assert!(out.is_empty());
        assert_eq!(
            n.accounting()
                .get(ActorId::Sensor(0), ActorId::Node(0), MessageKind::Malformed)
                .malformed_messages,
            1
        );
    }

    #[test]
    fn only_the_publisher_may_send_on_a_channel() {
        let (mut s, _, _) = pair();
        assert!(s
            .send(Channel::Observation(1), &contract::obs(0, 1), &[])
            .is_err());
    }
}
