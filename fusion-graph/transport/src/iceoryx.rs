//! The iceoryx2 transport: zero-copy shared-memory publish/subscribe between
//! processes on one machine, one service per channel named
//! `cqnet/<run>/<channel>`, and one event service per actor
//! (`cqnet/<run>/wake/<actor>`) so an idle actor sleeps instead of polling.
//! On a host of its own, the channels from node to node go through the
//! nodes' inboxes instead (`inbox.rs`), and only their wake-ups through
//! iceoryx2.
//!
//! Every resource of a run lives under the prefix `cqnet_<run>_`, so two runs
//! never see each other and cleanup is removing that prefix's files.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

use super::futex;
use super::inbox::{self, Inboxes};
pub use super::limits::QUEUE_DEPTH;
use super::limits::{max_message_len, ChannelLimits};
use super::{Channel, Inbound, Outbound, Transport};
use crate::accounting::Accounting;
use crate::ledger::Ledger;
use crate::{BackendError, ReceiveError, SendError, SetupError, WaitError};
use fusion_graph::channel::RunId;
use fusion_graph::hosts::{wake_id, Placement};
use fusion_graph::shaper::LinkShaper;
use fusion_graph::topology::Topology;
use wire::ActorId;
use wire::{Message, MessageKind, WireFormat};

pub(crate) use super::resources::RunResources;
pub use super::resources::{
    map_run_memory, remove_run_resources, remove_stale_node_directories, run_memory_path,
    run_resources, sweep_abandoned_runs, DeadNodeSweep, RunLease,
};
use super::resources::{retry, setup};
use super::wake::{open_bridge_wake, open_wake, Heard, WakeIds};

/// The shortest wait handed to iceoryx2's timed wait; shorter ones poll.
const MIN_TIMED_WAIT: Duration = Duration::from_micros(1);

pub(crate) type Sub = Subscriber<futex::Service, [u8], ()>;
pub(crate) type Pub = Publisher<futex::Service, [u8], ()>;
pub(crate) type PortFactory =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<futex::Service, [u8], ()>;

/// Opens (or creates) a channel's service, sized by [`ChannelLimits`] the
/// same way by every actor and by a host's bridge.
pub(crate) fn open_channel(
    node: &Node<futex::Service>,
    run: &RunId,
    topology: &Topology,
    channel: Channel,
) -> Result<PortFactory, SetupError> {
    let name = run.service_name(&channel.service_suffix())?;
    let limits = ChannelLimits::of(topology, channel);
    retry(|| {
        node.service_builder(&name)
            .publish_subscribe::<[u8]>()
            .max_publishers(limits.publishers)
            .max_subscribers(limits.subscribers)
            .max_nodes(limits.nodes)
            .subscriber_max_buffer_size(limits.queue)
            .history_size(0)
            .open_or_create()
    })
    .map_err(|e| setup(&channel.service_suffix(), e))
}

/// How an actor wakes actors of other hosts: through its own host's
/// bridge, whose wake-up service takes the far actor's
/// [`wake_id`](fusion_graph::hosts::wake_id) as the event id.
struct FarWakes {
    placement: Placement,
    host: usize,
    bridge: Option<Notifier<futex::Service>>,
    ids: HashMap<ActorId, EventId>,
}

/// Where a subscribed channel's messages wait.
enum Subscription {
    Service(Sub),
    /// A slot of this node's inbox.
    Inbox(usize),
}

pub struct IceoryxTransport {
    me: ActorId,
    run: RunId,
    topology: Topology,
    format: WireFormat,
    start: Instant,
    node: Node<futex::Service>,
    /// Each channel this actor publishes on, with who reads it: a send's
    /// receivers must be them all. No publisher: the channel goes through
    /// `inboxes`.
    publishers: HashMap<Channel, (Option<Pub>, Vec<ActorId>)>,
    /// In the order subscribed, which is the order `receive` reads them.
    subscribers: Vec<(Channel, Subscription)>,
    inboxes: Inboxes,
    /// Which subscriptions were heard from since the last `receive`: see
    /// [`Heard`].
    heard: Heard,
    listener: Listener<futex::Service>,
    /// Each receiver's notifier, with the event id our wake-ups carry in
    /// its service ([`WakeIds`]).
    notifiers: HashMap<ActorId, (Notifier<futex::Service>, EventId)>,
    /// Second publishers used by [`inject_raw`](Self::inject_raw).
    raw_publishers: HashMap<Channel, Pub>,
    /// On a host of several: how actors of the other hosts are woken.
    far: Option<FarWakes>,
    accounting: Accounting,
    shaper: LinkShaper,
    buffer: Vec<u8>,
}

impl IceoryxTransport {
    /// Creates this actor's iceoryx2 node and its wake-up listener.
    pub fn new(
        run: &RunId,
        me: ActorId,
        topology: &Topology,
        format: WireFormat,
        seed: u64,
    ) -> Result<Self, SetupError> {
        Self::with_sweep(run, me, topology, format, seed, DeadNodeSweep::On)
    }

    /// [`new`](Self::new), saying whether to sweep dead nodes first.
    pub fn with_sweep(
        run: &RunId,
        me: ActorId,
        topology: &Topology,
        format: WireFormat,
        seed: u64,
        sweep: DeadNodeSweep,
    ) -> Result<Self, SetupError> {
        let config = run.config(sweep)?;
        let name = NodeName::new(&me.to_string()).map_err(|e| setup("node name", e))?;
        let node = NodeBuilder::new()
            .config(&config)
            .name(&name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<futex::Service>()
            .map_err(|e| setup("node", e))?;
        if me == ActorId::Launcher {
            // The launcher's node is its domain's first: the segment is
            // made private before any actor exists (see the function).
            crate::resources::keep_global_segment_private(run);
        }
        let mut t = Self {
            me,
            run: run.clone(),
            topology: topology.clone(),
            format,
            start: Instant::now(),
            listener: open_wake(&node, run, me, topology)?
                .listener_builder()
                .create()
                .map_err(|e| setup("listener", e))?,
            node,
            publishers: HashMap::new(),
            subscribers: Vec::new(),
            inboxes: Inboxes::new(run, topology, me),
            heard: Heard::new(me, topology),
            notifiers: HashMap::new(),
            raw_publishers: HashMap::new(),
            far: None,
            accounting: Accounting::default(),
            shaper: LinkShaper::new(seed),
            buffer: Vec::with_capacity(512),
        };
        t.start = Instant::now();
        Ok(t)
    }

    fn open_channel(&self, channel: Channel) -> Result<PortFactory, SetupError> {
        open_channel(&self.node, &self.run, &self.topology, channel)
    }

    /// Whether `channel` goes through the nodes' inboxes: a channel from
    /// node to node, in a run on one host. (On a host of several, the
    /// bridges relay iceoryx2's services to the other hosts.)
    fn through_inboxes(&self, channel: Channel) -> bool {
        self.far.is_none() && inbox::carries(channel)
    }

    fn add_publisher(&mut self, channel: Channel) -> Result<(), SetupError> {
        let publisher = if self.through_inboxes(channel) {
            self.inboxes.publish_on(channel)?;
            None
        } else {
            let service = self.open_channel(channel)?;
            let publisher = service
                .publisher_builder()
                .initial_max_slice_len(max_message_len(channel, &self.topology))
                .create()
                .map_err(|e| setup("publisher", e))?;
            Some(publisher)
        };
        let readers = self.topology.readers(channel);
        self.publishers.insert(channel, (publisher, readers));
        Ok(())
    }

    /// Publishes raw bytes on `channel` through a second publisher, bypassing
    /// encoding: fault injection for tests of the malformed-message path.
    /// A channel that goes through inboxes has one writer per slot, so the
    /// bytes are written as its publisher, which must not be sending too.
    pub fn inject_raw(&mut self, channel: Channel, bytes: &[u8]) -> Result<(), SendError> {
        let backend = |source| SendError::Backend {
            channel: channel.service_suffix(),
            source,
        };
        if self.through_inboxes(channel) {
            self.inboxes
                .publish_on(channel)
                .map_err(|e| backend(Box::new(e)))?;
            return self.inboxes.send(channel, bytes).map_err(backend);
        }
        if !self.raw_publishers.contains_key(&channel) {
            let p = self
                .open_channel(channel)
                .and_then(|service| {
                    service
                        .publisher_builder()
                        .initial_max_slice_len(max_message_len(channel, &self.topology))
                        .create()
                        .map_err(|e| setup("publisher", e))
                })
                .map_err(|e| SendError::Backend {
                    channel: channel.service_suffix(),
                    source: Box::new(e),
                })?;
            // Kept: a publisher's samples vanish with it.
            self.raw_publishers.insert(channel, p);
        }
        let p = &self.raw_publishers[&channel];
        let _ = p.update_connections();
        publish(p, bytes).map_err(|source| SendError::Backend {
            channel: channel.service_suffix(),
            source,
        })
    }

    /// Takes the wake-ups that come within `timeout` (none: a poll), noting
    /// whom they came from in `heard`, and says whether there were any.
    fn take_wake_ups(&mut self, timeout: Duration) -> Result<bool, WaitError> {
        let mut woken = false;
        let heard = &mut self.heard;
        listen(&self.listener, timeout, |activation| {
            woken = true;
            heard.hear(activation.id.as_value());
        })?;
        Ok(woken)
    }

    pub fn run(&self) -> &RunId {
        &self.run
    }

    /// Mirrors every count into the ledger at `path` from now on, continuing
    /// what an earlier incarnation of this actor left there, so that a
    /// SIGKILL loses nothing counted (see [`crate::ledger`]). Call it before
    /// the first message.
    pub fn keep_counts_in(&mut self, path: &std::path::Path) -> Result<(), SetupError> {
        // Every (from, to, kind) the actor can count: each peer, both ways,
        // every kind and the malformed.
        let kinds = (0..=u8::MAX)
            .filter_map(|k| MessageKind::from_code(k, self.format.payloads))
            .count()
            + 1;
        let capacity = self.topology.peers(self.me) * 2 * kinds;
        let ledger = Ledger::open_or_create(path, capacity, self.format.payloads)
            .map_err(|e| setup("ledger", e))?;
        self.accounting = Accounting::backed_by(ledger);
        Ok(())
    }

    /// Tells the transport that its actor runs on `host` of `placement`:
    /// from now on [`notify`](Transport::notify) of an actor elsewhere
    /// wakes this host's bridge instead, and the channels between nodes are
    /// iceoryx2's services, which the bridges relay. Call it before the
    /// first `publish_on`, `subscribe` or `notify`.
    pub fn place_on(&mut self, placement: &Placement, host: usize) {
        debug_assert!(
            self.publishers.is_empty() && self.subscribers.is_empty(),
            "placed after its channels were set up"
        );
        self.far = Some(FarWakes {
            placement: placement.clone(),
            host,
            bridge: None,
            ids: HashMap::new(),
        });
    }
}

impl Transport for IceoryxTransport {
    fn me(&self) -> ActorId {
        self.me
    }

    /// Becomes the publisher of one of this actor's channels.
    fn publish_on(&mut self, channel: Channel) -> Result<(), SetupError> {
        channel.check_publisher(self.me)?;
        self.add_publisher(channel)
    }

    fn subscribe(&mut self, channel: Channel) -> Result<(), SetupError> {
        let subscription = if self.through_inboxes(channel) {
            Subscription::Inbox(self.inboxes.subscribe(channel)?)
        } else {
            let service = self.open_channel(channel)?;
            let sub = service
                .subscriber_builder()
                .create()
                .map_err(|e| setup("subscriber", e))?;
            Subscription::Service(sub)
        };
        self.subscribers.push((channel, subscription));
        self.heard.selective |= matches!(
            channel,
            Channel::Observation(_) | Channel::Control(_) | Channel::Lifecycle
        );
        Ok(())
    }

    /// Prepares to wake `actor` after sending to it.
    fn notify(&mut self, actor: ActorId) -> Result<(), SetupError> {
        if let Some(far) = self
            .far
            .as_mut()
            .filter(|f| f.placement.host_of(actor) != f.host)
        {
            if far.bridge.is_none() {
                let bridge = open_bridge_wake(
                    &self.node,
                    &self.run,
                    &far.placement,
                    far.host,
                    &self.topology,
                )?
                .notifier_builder()
                .create()
                .map_err(|e| setup("bridge notifier", e))?;
                far.bridge = Some(bridge);
            }
            far.ids
                .insert(actor, EventId::new(wake_id(actor, &self.topology)));
            return Ok(());
        }
        if !self.notifiers.contains_key(&actor) {
            let n = open_wake(&self.node, &self.run, actor, &self.topology)?
                .notifier_builder()
                .create()
                .map_err(|e| setup("notifier", e))?;
            let id = WakeIds::of(actor, &self.topology).id_of(self.me);
            self.notifiers.insert(actor, (n, EventId::new(id)));
        }
        Ok(())
    }

    /// Connects publishers to subscribers that appeared since they were made.
    fn update_connections(&mut self) {
        for p in self.publishers.values().filter_map(|(p, _)| p.as_ref()) {
            let _ = p.update_connections();
        }
    }

    fn send_waking(
        &mut self,
        channel: Channel,
        message: &Message,
        receivers: &[ActorId],
        wake: &[ActorId],
    ) -> Result<(), SendError> {
        let (publisher, readers) =
            self.publishers
                .get(&channel)
                .ok_or_else(|| SendError::NotPublisher {
                    channel: channel.service_suffix(),
                    actor: self.me.to_string(),
                })?;
        // The launcher's centralized reference, in a run that has one,
        // reads every observation channel; the topology does not say.
        let may_read: &[ActorId] = if matches!(channel, Channel::Observation(_)) {
            &[ActorId::Launcher]
        } else {
            &[]
        };
        crate::check_receivers(channel, receivers, readers, may_read)?;
        let inboxes = &self.inboxes;
        Outbound {
            me: self.me,
            format: &self.format,
            accounting: &mut self.accounting,
            buffer: &mut self.buffer,
        }
        .send(channel, message, receivers, |bytes| match publisher {
            Some(publisher) => publish(publisher, bytes),
            None => inboxes.send(channel, bytes),
        })?;
        let inboxes = publisher.is_none();
        for w in wake {
            if inboxes && !self.inboxes.may_sleep(*w) {
                // Awake, it finds the message in its inbox.
                continue;
            }
            // A failed wake-up only delays the receiver until its timeout.
            if let Some((n, id)) = self.notifiers.get(w) {
                let _ = n.notify_with_custom_event_id(*id);
            } else if let Some(far) = &self.far {
                if let (Some(bridge), Some(id)) = (&far.bridge, far.ids.get(w)) {
                    let _ = bridge.notify_with_custom_event_id(*id);
                }
            }
        }
        Ok(())
    }

    fn receive(&mut self, now: Duration, out: &mut Vec<Message>) -> Result<(), ReceiveError> {
        if !self.heard.waited && self.heard.selective {
            // Called without a wait since the last receive: take the
            // wake-ups that came in meanwhile without sleeping.
            self.take_wake_ups(Duration::ZERO)
                .map_err(|e| ReceiveError {
                    channel: "wake".into(),
                    source: e.source,
                })?;
        }
        let Self {
            me,
            format,
            accounting,
            shaper,
            subscribers,
            inboxes,
            start,
            ..
        } = self;
        let mut inbound = Inbound {
            me: *me,
            format,
            accounting,
            shaper,
        };
        let heard = &mut self.heard;
        for (channel, subscription) in subscribers.iter() {
            if !heard.may_have_data(*channel) {
                continue;
            }
            let sub = match subscription {
                Subscription::Service(sub) => sub,
                Subscription::Inbox(slot) => {
                    inboxes.drain(*slot, |bytes| {
                        let arrived = now.max(start.elapsed());
                        inbound.arrive(channel.publisher(), bytes, arrived, out)
                    });
                    continue;
                }
            };
            loop {
                match sub.receive() {
                    Ok(Some(sample)) => {
                        // Stamped when taken, not when the caller read its
                        // clock: a receiver descheduled in between would
                        // otherwise start a delayed message's hold early.
                        let arrived = now.max(start.elapsed());
                        inbound.arrive(channel.publisher(), sample.payload(), arrived, out)
                    }
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
        heard.clear();
        inbound.release(now, out);
        Ok(())
    }

    fn wait(&mut self, timeout: Duration) -> Result<(), WaitError> {
        // A held (delayed) message may fall due before anyone wakes us.
        let timeout = match self.shaper.next_due() {
            Some(due) => timeout.min(due.saturating_sub(self.now())),
            None => timeout,
        };
        // A node whose neighbour wrote its inbox while it was awake was not
        // woken for it (`inbox.rs`): it looks before it sleeps.
        let woken = if self.inboxes.sleep() {
            self.take_wake_ups(Duration::ZERO).map(|_| true)
        } else {
            self.take_wake_ups(timeout)
        };
        self.inboxes.wake();
        let woken = woken?;
        self.heard.waited = true;
        if !woken {
            // A timeout, or a wake-up that came without its event.
            self.heard.everything();
        }
        Ok(())
    }

    fn poll_wake(&mut self) -> Result<bool, WaitError> {
        // A polling node is not woken for what its neighbours write in its
        // inbox: it looks.
        let woken = self.take_wake_ups(Duration::ZERO)? | self.inboxes.unread();
        // Nothing heard leaves `receive` to take the wake-ups itself.
        self.heard.waited |= woken;
        Ok(woken)
    }

    fn now(&self) -> Duration {
        self.start.elapsed()
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

/// Sleeps on `listener` until notified or `timeout` passes, handing each
/// event to `heard`. iceoryx2 passes the timeout to SO_RCVTIMEO as whole
/// microseconds, and a zero timeval means "block forever": a wait of less
/// than a microsecond (a held message falling due just now) would never
/// return, so it is a poll.
pub(crate) fn listen(
    listener: &Listener<futex::Service>,
    timeout: Duration,
    heard: impl FnMut(EventActivation),
) -> Result<(), WaitError> {
    let waited = if timeout < MIN_TIMED_WAIT {
        listener.try_wait(heard)
    } else {
        listener.timed_wait(heard, timeout)
    };
    match waited {
        // A signal cut the wait short: SIGCONT after SIGSTOP does, with no
        // handler installed. It is a spurious wake-up; every caller loops,
        // receiving and waiting again, so returning is the retry.
        Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(()),
        Err(e) => Err(WaitError {
            source: Box::new(e),
        }),
    }
}

/// Moves one message's bytes into shared memory.
pub(crate) fn publish(publisher: &Pub, bytes: &[u8]) -> Result<(), BackendError> {
    let sample = publisher.loan_slice_uninit(bytes.len())?;
    sample.write_from_slice(bytes).send()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    //! The transport contract (`transport::contract`), run here with both
    //! ends in this process; `tests/iceoryx_processes.rs` runs the same
    //! checks across two processes.
    use super::*;
    use crate::contract::{self, FORMAT};
    use fusion_graph::scenario::Scenario;

    struct Pair {
        run: RunId,
        sensor: Option<IceoryxTransport>,
        node: Option<IceoryxTransport>,
    }

    impl Drop for Pair {
        fn drop(&mut self) {
            self.sensor.take();
            self.node.take();
            let _ = remove_run_resources(&self.run);
        }
    }

    fn pair(tag: &str) -> Pair {
        let run = RunId::new(&format!("u{}-{tag}", std::process::id())).unwrap();
        let topology = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
        let mut node = IceoryxTransport::new(&run, ActorId::Node(0), &topology, FORMAT, 2).unwrap();
        node.subscribe(Channel::Observation(0)).unwrap();
        let mut sensor =
            IceoryxTransport::new(&run, ActorId::Sensor(0), &topology, FORMAT, 1).unwrap();
        sensor.publish_on(Channel::Observation(0)).unwrap();
        sensor.notify(ActorId::Node(0)).unwrap();
        sensor.update_connections();
        Pair {
            run,
            sensor: Some(sensor),
            node: Some(node),
        }
    }

    /// Which subscriptions a receive reads, from the wake-ups heard; the
    /// ids are numbered per receiver.
    #[test]
    fn observation_channels_are_read_when_their_sensor_woke_us() {
        let topology = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
        let node = ActorId::Node(4);
        let own = &topology.node_sensors[4];
        let (mine, other) = (own[3], topology.node_sensors[0][0]);
        let ids = WakeIds::of(node, &topology);
        assert_eq!(
            ids.max(),
            2 + own.len(),
            "a node's service: its sensors, and three more"
        );
        assert_eq!(WakeIds::of(ActorId::Sensor(0), &topology).max(), 2);
        assert_eq!(
            WakeIds::of(ActorId::Launcher, &topology).max(),
            2 + topology.sensors()
        );
        // The services are sized for the same ids.
        for a in [node, ActorId::Sensor(0), ActorId::Launcher] {
            let sized = crate::limits::WakeLimits::of_actor(&topology, a).max_event_id;
            assert_eq!(sized, WakeIds::of(a, &topology).max(), "{a}");
        }
        let mut heard = Heard::new(node, &topology);
        // Before anything is known, everything is read.
        assert!(heard.may_have_data(Channel::Observation(mine)));
        heard.clear();
        assert!(!heard.may_have_data(Channel::Observation(mine)));
        assert!(heard.may_have_data(Channel::Consensus(1)));
        assert!(!heard.may_have_data(Channel::Control(node)));
        heard.hear(ids.id_of(ActorId::Sensor(mine)));
        assert!(heard.may_have_data(Channel::Observation(mine)));
        assert!(!heard.may_have_data(Channel::Observation(own[4])));
        heard.clear();
        // A node waking us says nothing about sensors or the launcher, and
        // neither does a sensor that is not ours.
        for waker in [ActorId::Node(1), ActorId::Sensor(other)] {
            assert_eq!(ids.id_of(waker), WakeIds::OTHER);
            heard.hear(ids.id_of(waker));
        }
        assert!(!heard.may_have_data(Channel::Observation(mine)));
        assert!(!heard.may_have_data(Channel::Control(node)));
        // The launcher's wake-up reads its channels, and no sensor's.
        assert_eq!(ids.id_of(ActorId::Launcher), WakeIds::LAUNCHER);
        heard.hear(WakeIds::LAUNCHER);
        assert!(heard.may_have_data(Channel::Control(node)));
        assert!(heard.may_have_data(Channel::Lifecycle));
        assert!(!heard.may_have_data(Channel::Observation(mine)));
        // A wake-up that does not say whose message it brings reads all.
        heard.hear(WakeIds::ANONYMOUS);
        assert!(heard.may_have_data(Channel::Observation(mine)));
        heard.clear();
        heard.everything();
        assert!(heard.may_have_data(Channel::Observation(200)));
    }

    /// An observation published without its wake-up is still read once a
    /// wait times out; one with its wake-up, as soon as the wait returns.
    #[test]
    fn an_observation_without_its_wake_up_is_read_after_a_timeout() {
        let mut p = pair("heard");
        let Pair { sensor, node, .. } = &mut p;
        let (sensor, node) = (sensor.as_mut().unwrap(), node.as_mut().unwrap());
        let mut got = Vec::new();
        node.receive(node.now(), &mut got).unwrap();
        assert!(got.is_empty());
        sensor
            .send_waking(
                Channel::Observation(0),
                &contract::obs(0, 1),
                &[node.me()],
                &[],
            )
            .unwrap();
        node.wait(Duration::from_millis(2)).unwrap();
        node.receive(node.now(), &mut got).unwrap();
        assert_eq!(got.len(), 1, "read after the wait timed out");
        sensor
            .send(Channel::Observation(0), &contract::obs(0, 2), &[node.me()])
            .unwrap();
        let started = Instant::now();
        node.wait(Duration::from_secs(5)).unwrap();
        assert!(
            started.elapsed() < Duration::from_secs(4),
            "woken, not timed out"
        );
        node.receive(node.now(), &mut got).unwrap();
        assert_eq!(got.len(), 2);
        assert_eq!(got[1].header.step, 2);
    }

    /// `poll_wake` takes a wake-up that came, and one only: it says nothing
    /// came when nothing did, and the message is read selectively after it.
    #[test]
    fn a_poll_takes_a_wake_up_without_sleeping() {
        let mut p = pair("poll");
        let Pair { sensor, node, .. } = &mut p;
        let (sensor, node) = (sensor.as_mut().unwrap(), node.as_mut().unwrap());
        let mut got = Vec::new();
        node.receive(node.now(), &mut got).unwrap();
        assert!(!node.poll_wake().unwrap(), "nothing came");
        sensor
            .send(Channel::Observation(0), &contract::obs(0, 1), &[node.me()])
            .unwrap();
        assert!(node.poll_wake().unwrap(), "the sensor's wake-up");
        assert!(!node.heard.everything, "a wake-up that names its sensor");
        assert!(node.heard.may_have_data(Channel::Observation(0)));
        node.receive(node.now(), &mut got).unwrap();
        assert_eq!(got.len(), 1);
        assert!(!node.poll_wake().unwrap(), "taken once");
    }

    #[test]
    fn contract_delivery_and_counts() {
        let mut p = pair("deliver");
        let Pair { sensor, node, .. } = &mut p;
        contract::delivers_and_counts(sensor.as_mut().unwrap(), node.as_mut().unwrap());
    }

    /// Removes a run's resources when dropped: after the test's transports
    /// (declared after it, so dropped before it), pass or fail.
    struct Cleanup(RunId);

    impl Drop for Cleanup {
        fn drop(&mut self) {
            let _ = remove_run_resources(&self.0);
        }
    }

    #[test]
    fn contract_pairwise() {
        let run = RunId::new(&format!("u{}-pairwise", std::process::id())).unwrap();
        let _cleanup = Cleanup(run.clone());
        let topology = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
        let node = |i| {
            IceoryxTransport::new(&run, ActorId::Node(i), &topology, FORMAT, 10 + i as u64).unwrap()
        };
        // Node 0's neighbours on the default 3 × 3 grid: 1 and 3.
        assert_eq!(topology.neighbours[0], [1, 3]);
        let (mut a, mut b, mut c) = (node(0), node(1), node(3));
        b.subscribe(Channel::Pair { from: 0, to: 1 }).unwrap();
        b.subscribe(Channel::Consensus(0)).unwrap();
        c.subscribe(Channel::Consensus(0)).unwrap();
        a.publish_on(Channel::Pair { from: 0, to: 1 }).unwrap();
        a.publish_on(Channel::Consensus(0)).unwrap();
        a.notify(ActorId::Node(1)).unwrap();
        a.notify(ActorId::Node(3)).unwrap();
        a.update_connections();
        contract::a_pairwise_message_reaches_only_its_addressee(&mut a, &mut b, &mut c);
        contract::a_send_to_some_of_a_channels_readers_is_refused(&mut a, &mut b, &mut c);
    }

    #[test]
    fn contract_loss() {
        let mut p = pair("loss");
        let Pair { sensor, node, .. } = &mut p;
        contract::loss_is_applied_and_counted(sensor.as_mut().unwrap(), node.as_mut().unwrap());
    }

    /// A wait shorter than a microsecond once became a zero SO_RCVTIMEO,
    /// which blocks forever: it hung CI whenever a held message fell due
    /// within a microsecond of the wait. Each wait runs on its own thread,
    /// so a hang fails the test instead of hanging it.
    #[test]
    fn waits_shorter_than_a_microsecond_return() {
        for nanos in [0, 1, 999] {
            let (done, finished) = std::sync::mpsc::channel();
            std::thread::spawn(move || {
                let mut p = pair(&format!("short-wait-{nanos}"));
                let node = p.node.as_mut().unwrap();
                node.wait(Duration::from_nanos(nanos)).unwrap();
                // Cleaned up before telling the test, which may end the
                // process as soon as it hears.
                drop(p);
                let _ = done.send(());
            });
            assert!(
                finished.recv_timeout(Duration::from_secs(10)).is_ok(),
                "a wait of {nanos} ns did not return"
            );
        }
    }

    #[test]
    fn run_ids_are_validated() {
        assert!(RunId::new("ok-run-1").is_ok());
        assert!(RunId::new("Bad Id").is_err());
        assert!(RunId::new("").is_err());
    }

    /// Every sweep of dead nodes is linear in the network; at a first
    /// start they made start-up quadratic (2,600 processes: 240 ready after
    /// 120 s with the service sweep on, all in 20 s with it off). A restart
    /// keeps all three, to clear its dead predecessor's ports.
    #[test]
    fn a_first_start_sweeps_nothing_and_a_restart_sweeps_all() {
        let run = RunId::new("sweep-config").unwrap();
        let first = run.config(DeadNodeSweep::Off).unwrap();
        assert!(!first.global.node.cleanup_dead_nodes_on_creation);
        assert!(!first.global.node.cleanup_dead_nodes_on_destruction);
        assert!(!first.global.service.cleanup_dead_nodes_on_open);
        let restart = run.config(DeadNodeSweep::On).unwrap();
        assert!(restart.global.node.cleanup_dead_nodes_on_creation);
        assert!(restart.global.node.cleanup_dead_nodes_on_destruction);
        assert!(restart.global.service.cleanup_dead_nodes_on_open);
    }
}
