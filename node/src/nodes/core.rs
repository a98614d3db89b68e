//! What every processing node keeps alike, whatever its algorithm: who it
//! is in the topology and what it reads, publishes and wakes; its view of
//! who is alive; the step guard; the late messages and overrun steps it
//! reports; which of its sensors ever answered; the activation of its
//! sensors and the collection of their observations; and the step's
//! report ([`Report`]). A node kind holds a [`NodeCore`] and its own
//! algorithm.

use std::time::Duration;

use bounds::Quantizer;
use fusion_graph::{Actor, ActorId, Channel, Scenario, Topology, Wiring};
use wire::{BitMask, Control, Message, Payload};

use crate::collector::{Collector, Offer, SensorAnswers};
use crate::estimator::ObservedValue;
use crate::fusion::Handled;
use crate::sensor_manager::SelectionContext;
use crate::{Node, Outgoing, Work};

use super::report::Report;

/// A node kind's algorithm as the core hands it the inputs every node gets
/// alike: the step that passed the step guard, its sensors' observations,
/// a new membership view; the rest of its messages are its own.
pub trait NodeKind {
    /// The core the kind holds.
    fn core(&mut self) -> &mut NodeCore;

    /// Between steps: nothing collected, fused or waiting. By default, the
    /// last step begun has been reported; a kind that can end a step
    /// without a report says otherwise.
    fn is_idle(&mut self) -> bool {
        !self.core().in_step()
    }

    /// The step before is still running when the next begins: finish it at
    /// once with what it has (its report says it overran).
    fn finish_overrun(&mut self, now: Duration, out: &mut Vec<Outgoing>);

    /// The launcher's `BeginStep` for `step`, the next step of the run,
    /// `missed` steps after the last one begun (a lost `BeginStep`, or
    /// SIGSTOP and SIGCONT), which the kind's filters coast through.
    fn begin_step(&mut self, step: u32, missed: u32, now: Duration, out: &mut Vec<Outgoing>);

    /// An own sensor's observation of `step`.
    fn observe(&mut self, step: u32, sensor: u16, value: ObservedValue, out: &mut Vec<Outgoing>);

    /// The membership view changed from `before` ([`NodeCore::view`] has
    /// the new one).
    fn view_changed(&mut self, _before: &[bool], _out: &mut Vec<Outgoing>) {}

    /// Any other message: the kind's protocol's, a neighbour's.
    fn take(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>);

    /// What the node reads, publishes and wakes: by default the core's
    /// (its sensors, its neighbours, the launcher). Asked once, when the
    /// node is made an actor ([`ProcessingNode::new`]).
    fn wiring(&mut self) -> Wiring {
        self.core().wiring()
    }

    /// When [`handle_timeout`](Self::handle_timeout) should next be
    /// called, if a stage waits ([`Actor::poll_timeout`]).
    fn poll_timeout(&self) -> Option<Duration>;

    /// The time from [`poll_timeout`](Self::poll_timeout) has come.
    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>);

    /// The heavy stage waiting to run, if any ([`Actor::poll_work`]).
    fn poll_work(&self) -> Option<Work>;

    /// Runs `work`, with no I/O and no clock.
    fn run_work(&mut self, work: Work);

    /// `work` finished at `now` after `elapsed`.
    fn work_done(&mut self, work: Work, elapsed: Duration, now: Duration, out: &mut Vec<Outgoing>);

    /// Whether a driver sharing cores should give its core away before
    /// `work` ([`Actor::gives_way_before`]).
    fn gives_way_before(&self, _work: Work) -> bool {
        false
    }

    /// Hands one message to the kind by what it is: the one dispatch of
    /// every node kind's [`Actor::handle`].
    fn dispatch(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        let step = message.header.step;
        match (&message.payload, message.header.sender) {
            (Payload::Control(Control::BeginStep), ActorId::Launcher) => {
                if self.core().is_next_step(step) {
                    if !self.is_idle() {
                        self.core().overran();
                        self.finish_overrun(now, out);
                    }
                    let missed = self.core().enter_step(step);
                    self.begin_step(step, missed, now, out)
                }
            }
            (Payload::Control(Control::Membership { alive }), ActorId::Launcher) => {
                let before = self.core().take_view(alive);
                self.view_changed(&before, out)
            }
            (Payload::Observation { cell }, ActorId::Sensor(s)) => {
                self.observe(step, s, ObservedValue::Cell(*cell), out)
            }
            (Payload::RawObservation { value }, ActorId::Sensor(s)) => {
                self.observe(step, s, ObservedValue::Raw(*value), out)
            }
            _ => self.take(message, now, out),
        }
    }
}

/// A node kind as an actor of the network: the wiring the kind gave when
/// it was made one, the one dispatch of its messages
/// ([`NodeKind::dispatch`]), and the kind's own stages. Every node kind is
/// driven through it, so that the [`Actor`] of a processing node is
/// written once.
pub struct ProcessingNode<K> {
    wiring: Wiring,
    kind: K,
}

impl<K: NodeKind> ProcessingNode<K> {
    pub fn new(mut kind: K) -> Self {
        Self {
            wiring: kind.wiring(),
            kind,
        }
    }

    /// The node's kind, with its algorithm's state.
    pub fn kind(&self) -> &K {
        &self.kind
    }
}

impl<K: NodeKind> Actor for ProcessingNode<K> {
    type Work = Work;

    fn wiring(&self) -> Wiring {
        self.wiring.clone()
    }

    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        self.kind.dispatch(message, now, out)
    }

    fn poll_timeout(&self) -> Option<Duration> {
        self.kind.poll_timeout()
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        self.kind.handle_timeout(now, out)
    }

    fn poll_work(&self) -> Option<Work> {
        self.kind.poll_work()
    }

    fn run_work(&mut self, work: Work) {
        self.kind.run_work(work)
    }

    fn work_done(&mut self, work: Work, elapsed: Duration, now: Duration, out: &mut Vec<Outgoing>) {
        self.kind.work_done(work, elapsed, now, out)
    }

    fn gives_way_before(&self, work: Work) -> bool {
        self.kind.gives_way_before(work)
    }
}

impl<K: NodeKind> Node for ProcessingNode<K> {
    fn is_idle(&mut self) -> bool {
        self.kind.is_idle()
    }
}

pub struct NodeCore {
    index: u16,
    topology: Topology,
    /// The live nodes this node can reach, itself always among them.
    view: Vec<bool>,
    /// The scenario's last step: a step beyond it is not of this run.
    steps: u32,
    last_step: Option<u32>,
    /// The last step begun is not reported yet.
    in_step: bool,
    late_messages: u64,
    /// `late_messages` as of the last report.
    late_reported: u64,
    /// The step being reported began before the one before it finished.
    deadline_missed: bool,
    /// Which own sensors ever answered an activation.
    answers: SensorAnswers,
    /// The quantizer's cell count (`None`: raw observations).
    cells: Option<usize>,
    /// Its protocol talks to one neighbour at a time, over a channel per
    /// pair of neighbours.
    pairs: bool,
}

impl NodeCore {
    /// Node `index`, whose sensors report cells of `quantizer` (`None`:
    /// raw values, or none reach the node itself).
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
        quantizer: Option<&Quantizer>,
    ) -> Self {
        let cells = quantizer.map(Quantizer::cells);
        Self {
            index,
            topology: topology.clone(),
            view: topology.all_alive(),
            steps: scenario.steps,
            last_step: None,
            in_step: false,
            late_messages: 0,
            late_reported: 0,
            deadline_missed: false,
            answers: SensorAnswers::new(&topology.node_sensors[index as usize]),
            cells,
            pairs: scenario.talks_in_pairs(),
        }
    }

    pub fn index(&self) -> u16 {
        self.index
    }

    pub fn id(&self) -> ActorId {
        ActorId::Node(self.index)
    }

    pub fn topology(&self) -> &Topology {
        &self.topology
    }

    pub fn own_sensors(&self) -> &[u16] {
        &self.topology.node_sensors[self.index as usize]
    }

    pub fn neighbours(&self) -> &[u16] {
        &self.topology.neighbours[self.index as usize]
    }

    /// The live nodes this node can reach (`view()[i]` for node i).
    pub fn view(&self) -> &[bool] {
        &self.view
    }

    /// The scenario's last step.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// The last step begun.
    pub fn last_step(&self) -> Option<u32> {
        self.last_step
    }

    /// A node's wiring: what it reads, publishes on and wakes.
    pub fn wiring(&self) -> Wiring {
        Wiring {
            actor: self.id(),
            reads: self.subscriptions(),
            publishes: self.publications(),
            wakes: self.peers(),
        }
    }

    /// The channels a node reads: its control, its sensors' observations
    /// and its neighbours' consensus channels (and, when its protocol
    /// talks in pairs, each neighbour's channel to it).
    fn subscriptions(&self) -> Vec<Channel> {
        let me = self.index;
        let mut v = vec![Channel::Control(self.id())];
        v.extend(self.own_sensors().iter().map(|s| Channel::Observation(*s)));
        v.extend(self.neighbours().iter().map(|m| Channel::Consensus(*m)));
        if self.pairs {
            v.extend(
                self.neighbours()
                    .iter()
                    .map(|&m| Channel::Pair { from: m, to: me }),
            );
        }
        v
    }

    /// The channels a node publishes on: an activation channel to each of
    /// its sensors, its consensus channel (and, in pairs, one to each
    /// neighbour) and its telemetry.
    fn publications(&self) -> Vec<Channel> {
        let me = self.index;
        let mut v: Vec<Channel> = self.topology.activation_channels(me).collect();
        v.push(Channel::Consensus(me));
        if self.pairs {
            v.extend(
                self.neighbours()
                    .iter()
                    .map(|&to| Channel::Pair { from: me, to }),
            );
        }
        v.push(Channel::Telemetry(me));
        v
    }

    /// The actors a node sends to (to wake them): its sensors, its
    /// neighbours, the launcher.
    fn peers(&self) -> Vec<ActorId> {
        let mut v: Vec<ActorId> = self
            .own_sensors()
            .iter()
            .map(|s| ActorId::Sensor(*s))
            .collect();
        v.extend(self.neighbours().iter().map(|m| ActorId::Node(*m)));
        v.push(ActorId::Launcher);
        v
    }

    /// The step guard: whether a `BeginStep` for `step` moves the node on
    /// (asked by [`NodeKind::dispatch`]).
    /// Only a later step of this run does; a repeated, past or impossible
    /// step (a corrupted or forged message) is logged and dropped: coasting
    /// to step 4·10⁹ would hang the node for good.
    pub fn is_next_step(&self, step: u32) -> bool {
        let next = step != 0 && step <= self.steps && self.last_step.is_none_or(|l| step > l);
        if !next {
            tracing::warn!(node = self.index, step, last = ?self.last_step, "BeginStep out of order or beyond the run; dropped");
        }
        next
    }

    /// Enters `step` (past [`is_next_step`](Self::is_next_step)); returns
    /// the steps missed since the last one.
    fn enter_step(&mut self, step: u32) -> u32 {
        let missed = self.last_step.map_or(0, |l| step.saturating_sub(l + 1));
        self.last_step = Some(step);
        self.in_step = true;
        missed
    }

    /// The last step begun has not been reported yet.
    pub fn in_step(&self) -> bool {
        self.in_step
    }

    /// The step before overran: its report says so.
    fn overran(&mut self) {
        self.deadline_missed = true;
    }

    /// The launcher's membership view; the node is always in its own.
    /// Returns the view it replaces.
    pub fn take_view(&mut self, alive: &BitMask) -> Vec<bool> {
        let mut view = alive.to_bools(self.topology.nodes());
        view[self.index as usize] = true;
        std::mem::replace(&mut self.view, view)
    }

    /// A message that arrived after its round or step had passed.
    pub fn count_late(&mut self) {
        self.late_messages += 1;
    }

    /// What a sensor manager choosing for `step` is told.
    pub fn selection_context<'a>(
        &'a self,
        step: u32,
        predicted: Option<&'a [bounds::State]>,
    ) -> SelectionContext<'a> {
        SelectionContext {
            step,
            node: self.index,
            own_sensors: self.own_sensors(),
            view: &self.view,
            predicted,
            sensor_positions: &self.topology.sensor_positions,
            node_sensors: &self.topology.node_sensors,
        }
    }

    /// Activates `picks` (positions in the node's own sensor list) for
    /// `step` with `payload`, the same message to each on its own channel
    /// so that a sensor not active receives nothing and sleeps; returns
    /// the collector of their observations until `deadline`.
    pub fn activate(
        &mut self,
        step: u32,
        picks: &[usize],
        payload: Payload,
        deadline: Duration,
        out: &mut Vec<Outgoing>,
    ) -> Collector {
        let own = self.own_sensors();
        let active: Vec<u16> = picks.iter().map(|&i| own[i]).collect();
        let message = Message::new(self.id(), step, 0, payload);
        out.extend(self.to_each(&message, active.iter().map(|s| ActorId::Sensor(*s))));
        self.answers.activated(&active);
        Collector::new(step, active, deadline, self.cells)
    }

    /// The node's `message` to each of `receivers` (its sensors, or its
    /// multiple-access channel), each on its own activation channel.
    pub fn to_each<'a>(
        &self,
        message: &'a Message,
        receivers: impl IntoIterator<Item = ActorId> + 'a,
    ) -> impl Iterator<Item = Outgoing> + 'a {
        let node = self.index;
        receivers.into_iter().map(move |to| Outgoing {
            channel: Channel::Activation { node, to },
            message: message.clone(),
            receivers: vec![to],
            wake: None,
        })
    }

    /// A sensor's observation, offered to the step's collector if one
    /// listens: the sensor has answered; a late one is counted, one outside
    /// the quantizer's cells dropped with a warning.
    pub fn offer(
        &mut self,
        collector: Option<&mut Collector>,
        step: u32,
        sensor: u16,
        value: ObservedValue,
    ) -> Offer {
        self.answers.answered(sensor);
        let offer = collector.map_or(Offer::Late, |c| c.offer(step, sensor, value));
        self.note(offer, sensor);
        offer
    }

    /// Counts a late observation and warns of an invalid one.
    pub fn note(&mut self, offer: Offer, sensor: u16) {
        match offer {
            Offer::Taken => {}
            Offer::Late => self.late_messages += 1,
            Offer::Invalid => tracing::warn!(
                node = self.index,
                sensor,
                "observation outside the quantizer's cells dropped"
            ),
        }
    }

    /// What the node's protocol made of `message`: a late one is counted,
    /// one not meant for the node logged; true if it was taken.
    pub fn taken(&mut self, handled: Handled, message: &Message) -> bool {
        match handled {
            Handled::Taken => return true,
            Handled::Late => self.late_messages += 1,
            Handled::NotMine => tracing::debug!(
                node = self.index,
                kind = ?message.header.kind,
                from = %message.header.sender,
                "ignored a message not meant for this node"
            ),
        }
        false
    }

    /// A sensor answered (what it said is the node's to file).
    pub fn answered(&mut self, sensor: u16) {
        self.answers.answered(sensor);
    }

    /// The step's telemetry to the launcher: `report`, with what the core
    /// keeps (the late messages since the last report, whether the step
    /// overran, and, unless the report says otherwise, the sensors that
    /// never answered).
    pub fn report(&mut self, step: u32, report: Report) -> Outgoing {
        let unanswered = self.answers.unanswered();
        let telemetry = report.finish(
            (self.late_messages - self.late_reported) as u32,
            self.deadline_missed,
            unanswered,
        );
        self.deadline_missed = false;
        self.late_reported = self.late_messages;
        if Some(step) == self.last_step {
            self.in_step = false;
        }
        Outgoing {
            channel: Channel::Telemetry(self.index),
            message: Message::new(self.id(), step, 0, Payload::Telemetry(telemetry)),
            receivers: vec![ActorId::Launcher],
            wake: None,
        }
    }
}

/// The mask of `picks` for an activation's payload.
pub fn mask(picks: &[usize]) -> BitMask {
    BitMask::from_indices(picks.iter().copied())
}
