//! How actors exchange messages. One trait, two implementations sharing one
//! contract: in memory (the in-process driver) and iceoryx2 (the real
//! multi-process runtime).

use std::time::Duration;

use fusion_graph::shaper::{Admission, LinkShaper, Tampering};
use wire::{ActorId, Message, MessageKind, WireFormat};

pub mod accounting;
mod bridge_ends;
pub mod counters;
mod error;
pub mod futex;
pub mod iceoryx;
mod inbox;
pub mod ledger;
pub mod limits;
pub mod memory;
mod resources;
mod wake;
pub mod world_memory;

pub use accounting::{Accounting, Counters};
pub use bridge_ends::{BridgeInlet, BridgeOutlet};
pub use error::{BackendError, ReceiveError, SendError, SetupError, TransportError, WaitError};
pub use fusion_graph::channel::{Channel, RunId};
pub use iceoryx::{DeadNodeSweep, IceoryxTransport};
pub use memory::{MemoryBus, MemoryTransport};

/// The transport contract: setup, then send, receive and wait. Accounting:
/// `send` records one sent message per intended receiver; `receive` records
/// received, dropped-by-fault and malformed messages per link. A backend
/// implements it with [`Outbound`] and [`Inbound`], which hold everything
/// but the moving of bytes, so that every backend encodes, shapes and counts
/// alike.
pub trait Transport {
    fn me(&self) -> ActorId;

    /// Becomes the publisher of one of this actor's own channels.
    fn publish_on(&mut self, channel: Channel) -> Result<(), SetupError>;

    /// Receives what is published on `channel` from now on.
    fn subscribe(&mut self, channel: Channel) -> Result<(), SetupError>;

    /// Prepares to wake `actor` after sending to it.
    fn notify(&mut self, actor: ActorId) -> Result<(), SetupError>;

    /// Connects this actor's publishers to subscribers that appeared since.
    fn update_connections(&mut self) {}

    /// Publishes `message` on `channel` (one of this actor's own) for
    /// `receivers`, and wakes them.
    fn send(
        &mut self,
        channel: Channel,
        message: &Message,
        receivers: &[ActorId],
    ) -> Result<(), SendError> {
        self.send_waking(channel, message, receivers, receivers)
    }

    /// Publishes `message` for `receivers` but wakes only `wake`; the others
    /// find it in their queue when something else wakes them. A wake-up is a
    /// process switch: a consensus round reaches every neighbour but wakes
    /// only those it still waits for.
    fn send_waking(
        &mut self,
        channel: Channel,
        message: &Message,
        receivers: &[ActorId],
        wake: &[ActorId],
    ) -> Result<(), SendError>;

    /// Appends every message due at `now` (time since the transport was
    /// created) to `out`: drains the subscriptions, applies link faults,
    /// decodes, and counts and drops what does not decode.
    fn receive(&mut self, now: Duration, out: &mut Vec<Message>) -> Result<(), ReceiveError>;

    /// Sleeps until this actor is woken or `timeout` passes.
    fn wait(&mut self, timeout: Duration) -> Result<(), WaitError>;

    /// Takes the wake-ups that have already come, without sleeping, and says
    /// whether there were any: a `wait` that cannot block. A backend with
    /// nothing to wait for has none.
    fn poll_wake(&mut self) -> Result<bool, WaitError> {
        Ok(false)
    }

    /// Time since the transport was created, the clock `receive` expects.
    fn now(&self) -> Duration;

    fn accounting(&self) -> &Accounting;

    /// For what the actor counts beside its messages: a sensor's failed
    /// reads of the world.
    fn accounting_mut(&mut self) -> &mut Accounting;

    fn shaper(&mut self) -> &mut LinkShaper;
}

/// The send path every backend shares: the publisher check, encoding, and
/// accounting once the backend has moved the bytes.
pub struct Outbound<'a> {
    pub me: ActorId,
    pub format: &'a WireFormat,
    pub accounting: &'a mut Accounting,
    /// Reused between messages: sending allocates nothing.
    pub buffer: &'a mut Vec<u8>,
}

impl Outbound<'_> {
    /// Encodes `message`, counts it once per receiver, and hands the bytes
    /// to `publish`. Counted first: an actor killed in between has sent
    /// what no one receives, which is a loss, never a receipt of something
    /// unsent. A failed publish takes the count back.
    /// A backend checks the receivers first ([`check_receivers`]).
    pub fn send(
        &mut self,
        channel: Channel,
        message: &Message,
        receivers: &[ActorId],
        publish: impl FnOnce(&[u8]) -> Result<(), BackendError>,
    ) -> Result<(), SendError> {
        if channel.publisher() != self.me {
            return Err(SendError::NotPublisher {
                channel: channel.service_suffix(),
                actor: self.me.to_string(),
            });
        }
        self.buffer.clear();
        message.encode(self.format, self.buffer);
        let (kind, len) = (message.header.kind, self.buffer.len());
        self.accounting
            .record_sent_to(self.me, receivers, kind, len);
        publish(self.buffer).map_err(|source| {
            self.accounting
                .unrecord_sent_to(self.me, receivers, kind, len);
            SendError::Backend {
                channel: channel.service_suffix(),
                source,
            }
        })
    }
}

/// Whether a message on `channel` for `receivers` reaches them and no one
/// else: every actor that reads a channel gets every message on it, so
/// the receivers must be its `readers`, all of them, and may include
/// those that `may_read` it (the launcher's centralized reference on an
/// observation channel, in a run that has one). Otherwise a reader would
/// receive what was never counted as sent to it, and the link's count of
/// what was lost would go negative: the send is refused instead.
pub fn check_receivers(
    channel: Channel,
    receivers: &[ActorId],
    readers: &[ActorId],
    may_read: &[ActorId],
) -> Result<(), SendError> {
    let every_reader = readers.iter().all(|r| receivers.contains(r));
    let only_readers = receivers
        .iter()
        .all(|r| readers.contains(r) || may_read.contains(r));
    if every_reader && only_readers {
        return Ok(());
    }
    Err(SendError::Receivers {
        channel: channel.service_suffix(),
        receivers: actor_list(receivers),
        readers: actor_list(readers),
    })
}

fn actor_list(actors: &[ActorId]) -> String {
    if actors.is_empty() {
        return "no one".into();
    }
    actors
        .iter()
        .map(ActorId::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// The receive path every backend shares: link fault, then decode, then
/// accounting. A malformed message is counted and dropped with a warning.
pub struct Inbound<'a> {
    pub me: ActorId,
    pub format: &'a WireFormat,
    pub accounting: &'a mut Accounting,
    pub shaper: &'a mut LinkShaper,
}
impl Inbound<'_> {
    /// A message arriving now from `from`.
    pub fn arrive(&mut self, from: ActorId, bytes: &[u8], now: Duration, out: &mut Vec<Message>) {
        match self.shaper.admit(from, bytes, now) {
            Admission::Deliver => self.deliver(from, bytes, Tampering::default(), out),
            // Copies with no delay are due at once.
            Admission::Held => self.release(now, out),
            Admission::Dropped => {
                let kind = Message::decode(bytes, self.format)
                    .map_or(wire::MessageKind::Malformed, |m| m.header.kind);
                self.accounting
                    .record_dropped(from, self.me, kind, bytes.len());
            }
        }
    }

    /// Held messages whose time has come.
    pub fn release(&mut self, now: Duration, out: &mut Vec<Message>) {
        let mut due = Vec::new();
        self.shaper
            .release_due(now, |from, bytes, t| due.push((from, bytes, t)));
        for (from, bytes, tampering) in due {
            self.deliver(from, &bytes, tampering, out);
        }
    }

    fn deliver(
        &mut self,
        from: ActorId,
        bytes: &[u8],
        tampering: Tampering,
        out: &mut Vec<Message>,
    ) {
        let decoded = Message::decode(bytes, self.format);
        let kind = match &decoded {
            Ok(m) => m.header.kind,
            Err(_) => tampering
                .corrupted_kind
                .and_then(|k| MessageKind::from_code(k, self.format.payloads))
                .unwrap_or(MessageKind::Malformed),
        };
        if tampering.duplicate {
            self.accounting
                .record_duplicated(from, self.me, kind, bytes.len());
        }
        let link = || format!("{from}->{}", self.me);
        match decoded {
            Ok(m) if m.header.sender == from => {
                self.accounting
                    .record_received(from, self.me, kind, bytes.len());
                out.push(m);
            }
            Ok(m) => {
                tracing::warn!(link = %link(), claimed = %m.header.sender, "message claims a sender other than its channel's publisher; dropped");
                self.accounting
                    .record_malformed(from, self.me, kind, bytes.len());
            }
            Err(e) => {
                // An injected corruption is expected; anything else is news.
                if tampering.corrupted_kind.is_some() {
                    tracing::debug!(link = %link(), error = %e, "corrupted message dropped");
                } else {
                    tracing::warn!(link = %link(), error = %e, len = bytes.len(), "malformed message dropped");
                }
                self.accounting
                    .record_malformed(from, self.me, kind, bytes.len());
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod contract {
    //! The contract every transport must meet, run against each one.
    use super::*;
    use fusion_graph::shaper::LinkRule;
    use wire::{MessageKind, Payload};

    pub const FORMAT: WireFormat = WireFormat {
        cell_bytes: 1,
        activation_bytes: 4,
        payloads: wire::payloads::Payloads::NONE,
    };

    pub fn obs(sensor: u16, step: u32) -> Message {
        Message::new(
            ActorId::Sensor(sensor),
            step,
            0,
            Payload::Observation { cell: step % 256 },
        )
    }

    /// Receives until `n` messages arrived or a second passed.
    pub fn receive_n<T: Transport>(t: &mut T, n: usize) -> Vec<Message> {
        let mut out = Vec::new();
        let start = std::time::Instant::now();
        while out.len() < n && start.elapsed() < Duration::from_secs(1) {
            let now = t.now();
            t.receive(now, &mut out).unwrap();
            if out.len() < n {
                t.wait(Duration::from_millis(5)).unwrap();
            }
        }
        out
    }

    /// A sensor sends 20 observations to a node; delivery, order and byte
    /// counts on both sides.
    pub fn delivers_and_counts<T: Transport>(sensor: &mut T, node: &mut T) {
        for step in 1..=20 {
            sensor
                .send(Channel::Observation(0), &obs(0, step), &[node.me()])
                .unwrap();
        }
        let got = receive_n(node, 20);
        assert_eq!(got.len(), 20);
        assert!(got
            .iter()
            .enumerate()
            .all(|(i, m)| m.header.step == i as u32 + 1));
        let sent = sensor
            .accounting()
            .get(sensor.me(), node.me(), MessageKind::Observation);
        let recv = node
            .accounting()
            .get(sensor.me(), node.me(), MessageKind::Observation);
        assert_eq!((sent.sent_messages, sent.sent_bytes), (20, 20 * 14));
        assert_eq!((recv.received_messages, recv.received_bytes), (20, 20 * 14));
    }

    /// A pairwise message reaches its one addressee, and is counted for it
    /// alone, while a consensus message reaches every subscribed neighbour.
    /// `a` is node 0, publishing on `Pair {0, 1}` and `Consensus(0)`; `b`,
    /// node 1, subscribes to both; `c`, node 2, to the consensus only.
    pub fn a_pairwise_message_reaches_only_its_addressee<T: Transport>(
        a: &mut T,
        b: &mut T,
        c: &mut T,
    ) {
        let request = Message::new(a.me(), 1, 1, Payload::ExchangeRequest);
        let kl = Message::new(
            a.me(),
            1,
            1,
            Payload::KlConsensus(wire::GaussianInformation {
                eta: [1.0; 4],
                lambda: [2.0; 10],
            }),
        );
        a.send(Channel::Pair { from: 0, to: 1 }, &request, &[b.me()])
            .unwrap();
        a.send(Channel::Consensus(0), &kl, &[b.me(), c.me()])
            .unwrap();
        let at_b = receive_n(b, 2);
        let kinds: Vec<MessageKind> = at_b.iter().map(|m| m.header.kind).collect();
        assert!(
            kinds.contains(&MessageKind::ExchangeRequest)
                && kinds.contains(&MessageKind::KlConsensus),
            "{kinds:?}"
        );
        let at_c = receive_n(c, 2);
        assert_eq!(at_c.len(), 1);
        assert_eq!(at_c[0].header.kind, MessageKind::KlConsensus);
        let to_b = a
            .accounting()
            .get(a.me(), b.me(), MessageKind::ExchangeRequest);
        let to_c = a
            .accounting()
            .get(a.me(), c.me(), MessageKind::ExchangeRequest);
        assert_eq!((to_b.sent_messages, to_b.sent_bytes), (1, 13));
        assert_eq!(to_c.sent_messages, 0);
        let got = b
            .accounting()
            .get(a.me(), b.me(), MessageKind::ExchangeRequest);
        assert_eq!((got.received_messages, got.received_bytes), (1, 13));
    }

    /// A message on a channel every one of whose readers gets it cannot be
    /// sent to some of them alone: the send is refused, naming the
    /// readers, and nothing is counted or delivered. (`b` and `c` both
    /// read `a`'s consensus channel.)
    pub fn a_send_to_some_of_a_channels_readers_is_refused<T: Transport>(
        a: &mut T,
        b: &mut T,
        c: &mut T,
    ) {
        let value = Message::new(
            a.me(),
            1,
            1,
            Payload::KlConsensus(wire::GaussianInformation {
                eta: [1.0; 4],
                lambda: [2.0; 10],
            }),
        );
        let ActorId::Node(n) = a.me() else {
            panic!("a node publishes a consensus channel")
        };
        let consensus = Channel::Consensus(n);
        let sent = |a: &T| {
            a.accounting()
                .get(a.me(), b.me(), MessageKind::KlConsensus)
                .sent_messages
        };
        let before = sent(a);
        let refused = a.send(consensus, &value, &[b.me()]);
        match refused {
            Err(SendError::Receivers { readers, .. }) => {
                assert!(readers.contains(&c.me().to_string()), "{readers}")
            }
            other => panic!("not refused: {other:?}"),
        }
        assert_eq!(sent(a), before, "a refused message is not counted");
        assert!(receive_n(c, 1).is_empty());
    }

    /// Loss on the link drops roughly its probability, and is counted.
    pub fn loss_is_applied_and_counted<T: Transport>(sensor: &mut T, node: &mut T) {
        node.shaper().set_rule(
            sensor.me(),
            LinkRule {
                loss: 0.5,
                ..Default::default()
            },
        );
        for step in 1..=400 {
            sensor
                .send(Channel::Observation(0), &obs(0, step), &[node.me()])
                .unwrap();
            if step % 50 == 0 {
                let now = node.now();
                let mut sink = Vec::new();
                node.receive(now, &mut sink).unwrap();
            }
        }
        let mut got = Vec::new();
        let now = node.now();
        node.receive(now, &mut got).unwrap();
        let c = node
            .accounting()
            .get(sensor.me(), node.me(), MessageKind::Observation);
        assert_eq!(c.received_messages + c.dropped_messages, 400, "{c:?}");
        assert!((150..=250).contains(&c.dropped_messages), "{c:?}");
        node.shaper().clear_rules();
    }
}
