//! The random-exchange paper's tracker node as an I/O-free state machine:
//! one particle filter ([`DiffusionTracker`]) summarized as a Gaussian,
//! cooperating by random exchange (RndEx-PF, `exchange.rs`) or by KL
//! fusion (`kl.rs`), each a [`Cooperation`].
//!
//! A step: the launcher's `BeginStep` → the node activates its sensors
//! (and, in RndEx-PF, starts the exchange with its posterior of the step
//! before) → **own**: its sensors' measurements, until all arrived or the
//! listening deadline → with local cooperation, it relays them to its
//! neighbours (`neighbour_observation`) and waits for theirs, until every
//! live neighbour's arrived or a second deadline → [`Work::Weigh`]: predict
//! and weigh (RndEx-PF: from the exchanged posterior) → KL fusion only: K_max
//! rounds on the natural parameters, then [`Work::Adopt`] → telemetry.
//!
//! It is driven exactly as [`CfDpfNode`](crate::CfDpfNode) is, so the same
//! drivers run it (see [`processing_node`](crate::processing_node)).

use std::time::Duration;

use fusion_graph::scenario::Scenario;
use fusion_graph::Channel;
use fusion_graph::{stream_rng, ActorId, Stream, Topology};
use rand_chacha::ChaCha8Rng;
use wire::{Message, Payload, Stage};

use crate::collector::{Collector, Offer};
use crate::diffusion::DiffusionTracker;
use crate::estimator::{Observation, ObservedValue, SensingModel};
use crate::filter::Gaussian;
use crate::fusion::{FusionProtocol, RoundStats};
use crate::sensor_manager::{SensorManager, UniformRandom};
use crate::{NodeError, Outgoing, Work};

use super::core::mask;
use super::{NodeCore, NodeKind, Report};

mod exchange;
mod kl;

pub use exchange::ExchangeCooperation;
pub use kl::{kl_fusion_rounds, KlCooperation, PosteriorFusion};

/// How a tracker node cooperates with its neighbours, beside the step
/// every tracker shares (its sensors, its neighbours' relays, its
/// report): when its protocol runs and what the node makes of its result.
/// RndEx-PF's exchange ([`ExchangeCooperation`]) or KL fusion
/// ([`KlCooperation`]), or a program's own: a node factory
/// ([`crate::parts::NodeFactory`]) builds a [`TrackerNode`] around one
/// and its protocol. The node holds the protocol and hands it its
/// messages and timeouts; the cooperation starts it, takes its result and
/// ends it.
pub trait Cooperation {
    /// The fusion protocol it runs with the neighbours.
    type Protocol: FusionProtocol;

    /// Whether the node relays its measurements and weighs its
    /// neighbours'.
    fn uses_neighbourhood(&self) -> bool;

    /// The step begins, its measurements still to come.
    fn begin(
        &mut self,
        protocol: &mut Self::Protocol,
        filter: &TrackerFilter,
        at: StepAt<'_>,
        out: &mut Vec<Outgoing>,
    );

    /// Takes the protocol's result, if it has one.
    fn poll(&mut self, protocol: &mut Self::Protocol);

    /// The step's rounds, for its report.
    fn stats(&self) -> RoundStats;

    /// The heavy stage waiting, given whether the step's measurements are
    /// all in.
    fn pending(&self, measured: bool) -> Option<Work>;

    /// Runs `work` on the node's filter with the step's measurements.
    fn run(&mut self, work: Work, filter: &mut TrackerFilter, observations: &[Observation]);

    /// `work` is done, after `elapsed`: what comes next. By default the
    /// step is reported: a cooperation whose protocol ran before the
    /// weighing (an exchange) has nothing left to do.
    fn done(
        &mut self,
        _protocol: &mut Self::Protocol,
        _work: Work,
        _elapsed: Duration,
        _at: StepAt<'_>,
        _out: &mut Vec<Outgoing>,
    ) -> Next {
        Next::Report {
            adopt_time: Duration::ZERO,
        }
    }

    /// Ends what the protocol still waits for, with what it has; false if
    /// nothing was left that could finish the step.
    fn finish_now(
        &mut self,
        protocol: &mut Self::Protocol,
        filter: &TrackerFilter,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) -> bool;
}

/// Where a tracker's step stands when its cooperation is told of it.
#[derive(Debug, Clone, Copy)]
pub struct StepAt<'a> {
    pub step: u32,
    /// The live nodes the node can reach.
    pub view: &'a [bool],
    pub now: Duration,
}

/// What a tracker's step does after a stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    /// Waits for its protocol.
    Wait,
    /// Reports, the adoption of a fused posterior having taken `adopt_time`.
    Report { adopt_time: Duration },
}

/// A tracker node's particle filter, with what it weighs by and draws from.
pub struct TrackerFilter {
    pub tracker: DiffusionTracker,
    pub model: SensingModel,
    pub rng: ChaCha8Rng,
    /// The node, for its logs.
    pub node: u16,
}

impl TrackerFilter {
    /// The particles weighed with `observations`: the node's local
    /// posterior, summarized.
    pub fn local_posterior(&mut self, observations: &[Observation]) -> Gaussian {
        self.tracker
            .local_posterior(&self.model, observations, &mut self.rng)
    }

    /// Predicts from `from` (a neighbour's posterior, say) and weighs with
    /// `observations`; the node's own particles instead, with an error in
    /// the log, if `from` cannot be drawn from.
    pub fn assimilate_from(&mut self, from: &Gaussian, observations: &[Observation]) {
        let (model, rng) = (&self.model, &mut self.rng);
        if let Err(e) = self.tracker.assimilate_from(from, model, observations, rng) {
            tracing::error!(node = self.node, error = %e, "cannot draw from the exchanged posterior; weighing the node's own particles");
            self.tracker.local_posterior(model, observations, rng);
        }
    }

    /// The particles redrawn from `fused`; kept, with an error in the log,
    /// if it cannot be drawn from.
    pub fn adopt(&mut self, fused: &Gaussian) {
        if let Err(e) = self.tracker.adopt(fused, &mut self.rng) {
            tracing::error!(node = self.node, error = %e, "keeping the local particles");
        }
    }
}

/// One step, from `BeginStep` to its telemetry.
struct Stepping {
    step: u32,
    /// The node's own sensors, while it still listens to them.
    collector: Option<Collector>,
    /// The step's measurements: the node's own, then its neighbours'.
    observations: Vec<Observation>,
    /// The neighbours' relays are all in, or their deadline passed (or the
    /// protocol wants none).
    relays_closed: bool,
    relay_deadline: Duration,
    weigh_time: Duration,
}

pub struct TrackerNode<C: Cooperation> {
    core: NodeCore,
    filter: TrackerFilter,
    manager: UniformRandom,
    cooperation: C,
    protocol: C::Protocol,
    /// Sensors each node activates per step: how many relays to expect.
    active_per_node: usize,
    listen: Duration,
    stepping: Option<Box<Stepping>>,
    /// Neighbours' relayed measurements of the running step or a later one:
    /// (step, neighbour, measurement).
    relayed: Vec<(u32, u16, Observation)>,
}

pub(crate) fn round_timeout(scenario: &Scenario) -> Duration {
    Duration::from_secs_f64(scenario.consensus.round_timeout_ms / 1e3)
}

impl<C: Cooperation> TrackerNode<C> {
    /// Node `index` of a tracker network, cooperating with its neighbours
    /// over `protocol` as `cooperation` says.
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
        cooperation: C,
        protocol: C::Protocol,
    ) -> Result<Self, NodeError> {
        let models = scenario.models()?;
        let model = SensingModel::new(&models, topology);
        let prior = scenario.network_prior(&models);
        let id = ActorId::Node(index);
        let mut rng = stream_rng(scenario.seed, id, 0, Stream::LocalFilter);
        let tracker = DiffusionTracker::new(scenario.filter.particles as usize, &prior, &mut rng)
            .map_err(|_| NodeError::Filter {
                node: index,
                source: bounds::BoundError::NotPositiveDefinite("the prior covariance"),
            })?
            .with_resampling(scenario.filter.resampler);
        Ok(Self {
            core: NodeCore::new(scenario, topology, index, models.quantizer.as_ref()),
            filter: TrackerFilter {
                tracker,
                model,
                rng,
                node: index,
            },
            manager: UniformRandom::for_scenario(scenario),
            cooperation,
            protocol,
            active_per_node: scenario.sensors.active_per_node as usize,
            listen: round_timeout(scenario),
            stepping: None,
            relayed: Vec::new(),
        })
    }

    fn neighbours(&self) -> &[u16] {
        self.core.neighbours()
    }

    /// The collector of the step's own observations, while it listens.
    fn collecting(&self) -> Option<&Collector> {
        self.stepping.as_ref().and_then(|s| s.collector.as_ref())
    }

    /// The node's own sensors are done: relay their measurements (with
    /// local cooperation) and take in any neighbour's that came first.
    fn close_own(&mut self, out: &mut Vec<Outgoing>) {
        let relay = self.cooperation.uses_neighbourhood();
        let neighbours: Vec<u16> = self.neighbours().to_vec();
        let me = self.core.id();
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        let Some(collector) = s.collector.take() else {
            return;
        };
        let collected = collector.close();
        if relay {
            let receivers: Vec<ActorId> = neighbours.iter().map(|m| ActorId::Node(*m)).collect();
            let wake: Vec<ActorId> = neighbours
                .iter()
                .filter(|m| self.core.view()[**m as usize])
                .map(|m| ActorId::Node(*m))
                .collect();
            for o in &collected.observations {
                let value = match o.value {
                    ObservedValue::Raw(v) => v,
                    ObservedValue::Cell(c) => c as f64,
                };
                out.push(Outgoing {
                    channel: Channel::Consensus(self.core.index()),
                    message: Message::new(
                        me,
                        s.step,
                        0,
                        Payload::NeighbourObservation {
                            sensor: o.sensor,
                            value,
                        },
                    ),
                    receivers: receivers.clone(),
                    wake: Some(wake.clone()),
                });
            }
        }
        s.observations = collected.observations;
        self.poll_relays();
    }

    /// A neighbour's measurement: kept for its step if it is a measurement
    /// of one of that neighbour's sensors, in range.
    fn take_relay(&mut self, step: u32, from: u16, sensor: u16, value: f64) {
        let current = self.core.last_step().unwrap_or(0);
        let from_a_neighbour = self.neighbours().contains(&from)
            && self.core.topology().node_sensors[from as usize].contains(&sensor);
        let value = match &self.filter.model.quantizer {
            Some(q) if value.fract() == 0.0 && value >= 0.0 && value < q.cells() as f64 => {
                Some(ObservedValue::Cell(value as u32))
            }
            Some(_) => None,
            None if value.is_finite() => Some(ObservedValue::Raw(value)),
            None => None,
        };
        let (true, Some(value)) = (from_a_neighbour, value) else {
            tracing::warn!(
                node = self.core.index(),
                from,
                sensor,
                "a relayed measurement of no sensor of that neighbour, or out of range; dropped"
            );
            return;
        };
        let closed = self
            .stepping
            .as_ref()
            .is_none_or(|s| s.step == step && s.relays_closed);
        let duplicate = self
            .relayed
            .iter()
            .any(|(s, _, o)| *s == step && o.sensor == sensor);
        if step < current || (step == current && closed) || duplicate {
            self.core.count_late();
            return;
        }
        // One step ahead at most: a neighbour never runs further ahead.
        if step > current + 1 {
            self.core.count_late();
            return;
        }
        self.relayed
            .push((step, from, Observation { sensor, value }));
        self.poll_relays();
    }

    /// Closes the relays once every live neighbour's measurements are in.
    fn poll_relays(&mut self) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        if s.relays_closed || s.collector.is_some() {
            return;
        }
        let neighbours = self.core.neighbours();
        let all_in = neighbours
            .iter()
            .filter(|m| self.core.view()[**m as usize])
            .all(|m| {
                let expected = self.core.topology().node_sensors[*m as usize]
                    .len()
                    .min(self.active_per_node);
                let heard = self
                    .relayed
                    .iter()
                    .filter(|(step, from, _)| *step == s.step && from == m)
                    .count();
                heard >= expected
            });
        if all_in {
            self.close_relays();
        }
    }

    /// Stops waiting for relays: the step weighs the neighbours' measurements
    /// heard so far.
    fn close_relays(&mut self) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        s.relays_closed = true;
        let step = s.step;
        s.observations.extend(
            self.relayed
                .iter()
                .filter(|(st, _, _)| *st == step)
                .map(|(_, _, o)| *o),
        );
        // In sensor order, not arrival order: the likelihood sums them, and
        // floating-point sums depend on their order.
        s.observations.sort_by_key(|o| o.sensor);
        self.relayed.retain(|(st, _, _)| *st != step);
    }

    /// Takes the protocol's result, if it has one, while a step runs.
    fn poll_protocol(&mut self) {
        if self.stepping.is_some() {
            self.cooperation.poll(&mut self.protocol);
        }
    }

    /// The step's telemetry.
    fn report(&mut self, adopt_time: Duration, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.take() else {
            return;
        };
        let estimate = self.filter.tracker.estimate();
        let report = Report::of(&estimate)
            .rounds(&self.cooperation.stats())
            .observations(s.observations.len() as u16)
            .stage(Stage::Local, s.weigh_time)
            .stage(Stage::Global, adopt_time);
        out.push(self.core.report(s.step, report));
    }
}

impl<C: Cooperation> NodeKind for TrackerNode<C> {
    fn core(&mut self) -> &mut NodeCore {
        &mut self.core
    }

    /// Ends an overrun step at once with what it has: no more waiting for
    /// sensors, relays or neighbours; its stages are not timed.
    fn finish_overrun(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        if self
            .stepping
            .as_ref()
            .is_some_and(|s| s.collector.is_some())
        {
            self.close_own(out);
        }
        if self.stepping.as_ref().is_some_and(|s| !s.relays_closed) {
            self.close_relays();
        }
        while self.stepping.is_some() {
            if let Some(work) = self.poll_work() {
                self.run_work(work);
                self.work_done(work, Duration::ZERO, now, out);
                continue;
            }
            // Nothing left that could finish the step: report it as is.
            if !self
                .cooperation
                .finish_now(&mut self.protocol, &self.filter, now, out)
            {
                self.report(Duration::ZERO, out);
            }
        }
    }

    fn begin_step(&mut self, step: u32, missed: u32, now: Duration, out: &mut Vec<Outgoing>) {
        for _ in 0..missed {
            let f = &mut self.filter;
            f.tracker.coast(&f.model, &mut f.rng);
        }
        self.relayed.retain(|(s, _, _)| *s >= step);
        self.protocol.expect_step(step);
        let picks = self
            .manager
            .choose(&self.core.selection_context(step, None));
        let mask = mask(&picks);
        let collector = self.core.activate(
            step,
            &picks,
            Payload::Activate { mask },
            now + self.listen,
            out,
        );
        self.stepping = Some(Box::new(Stepping {
            step,
            collector: Some(collector),
            observations: Vec::new(),
            relays_closed: !self.cooperation.uses_neighbourhood(),
            relay_deadline: now + 2 * self.listen,
            weigh_time: Duration::ZERO,
        }));
        let at = StepAt {
            step,
            view: self.core.view(),
            now,
        };
        self.cooperation
            .begin(&mut self.protocol, &self.filter, at, out);
        // A step with no active sensor has nothing to wait for.
        if self.collecting().is_some_and(Collector::is_complete) {
            self.close_own(out);
        }
    }

    fn observe(&mut self, step: u32, sensor: u16, value: ObservedValue, out: &mut Vec<Outgoing>) {
        let collector = self.stepping.as_mut().and_then(|s| s.collector.as_mut());
        let offer = self.core.offer(collector, step, sensor, value);
        if offer == Offer::Taken && self.collecting().is_some_and(Collector::is_complete) {
            self.close_own(out);
        }
    }

    fn take(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        match (&message.payload, message.header.sender) {
            (Payload::NeighbourObservation { sensor, value }, ActorId::Node(m)) => {
                self.take_relay(message.header.step, m, *sensor, *value)
            }
            _ => {
                let handled = self.protocol.handle(message, now, out);
                if self.core.taken(handled, message) {
                    self.poll_protocol()
                }
            }
        }
    }

    fn poll_timeout(&self) -> Option<Duration> {
        let s = self.stepping.as_ref()?;
        let listening = match &s.collector {
            Some(c) => Some(c.deadline()),
            None if !s.relays_closed => Some(s.relay_deadline),
            None => None,
        };
        let protocol = self.protocol.poll_timeout();
        [listening, protocol].into_iter().flatten().min()
    }

    /// Called when the time from [`poll_timeout`](Self::poll_timeout) has come.
    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        if s.collector.as_ref().is_some_and(|c| now >= c.deadline()) {
            self.close_own(out);
        }
        if self
            .stepping
            .as_ref()
            .is_some_and(|s| s.collector.is_none() && !s.relays_closed && now >= s.relay_deadline)
        {
            self.close_relays();
        }
        self.protocol.handle_timeout(now, out);
        self.poll_protocol();
    }

    /// The heavy stage waiting to run, if any.
    fn poll_work(&self) -> Option<Work> {
        let s = self.stepping.as_ref()?;
        self.cooperation
            .pending(s.collector.is_none() && s.relays_closed)
    }

    /// Runs the pending heavy stage; the driver times it and then calls
    /// [`work_done`](Self::work_done).
    fn run_work(&mut self, work: Work) {
        let Some(s) = self.stepping.as_ref() else {
            return;
        };
        self.cooperation
            .run(work, &mut self.filter, &s.observations);
    }

    /// The driver's report that `work` finished at `now` after `elapsed`.
    fn work_done(&mut self, work: Work, elapsed: Duration, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        if work == Work::Weigh {
            s.weigh_time = elapsed;
        }
        let at = StepAt {
            step: s.step,
            view: self.core.view(),
            now,
        };
        match self
            .cooperation
            .done(&mut self.protocol, work, elapsed, at, out)
        {
            Next::Wait => {}
            Next::Report { adopt_time } => self.report(adopt_time, out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::harness::{Fate, Net};
    use wire::MessageKind;

    const ALL: [bool; 25] = [true; 25];
    const LONG: Duration = Duration::from_secs(5);
    const PROTOCOLS: [&str; 4] = [
        "random_exchange",
        "kl_consensus",
        "kl_diffusion",
        "kl_iterative",
    ];

    fn lattice(protocol: &str) -> Net {
        Net::random_exchange_with(&[
            &format!("consensus.protocol=\"{protocol}\""),
            "filter.particles=200",
        ])
    }

    fn sent_of(net: &Net, kind: MessageKind) -> Vec<&Outgoing> {
        net.sent
            .iter()
            .filter(|o| o.message.payload.kind() == kind)
            .collect()
    }

    /// With nothing lost, every node finishes every step in time, weighing
    /// its closed neighbourhood's measurements (its own only in consensus
    /// KL), and each protocol sends what it should: K_max KL messages per
    /// node and step, one relay per node and measurement.
    #[test]
    fn every_protocol_finishes_every_step_with_its_messages() {
        let steps = 3;
        for protocol in PROTOCOLS {
            let mut net = lattice(protocol);
            for step in 1..=steps {
                net.begin_step(step, &ALL);
                net.run(LONG);
            }
            for n in 0..25u16 {
                let degree = net.topology.neighbours[n as usize].len() as u16;
                for step in 1..=steps {
                    let t = net
                        .report(n, step)
                        .unwrap_or_else(|| panic!("{protocol}: node-{n} step {step}"));
                    assert!(!t.deadline_missed, "{protocol}");
                    let expected = if protocol == "kl_consensus" {
                        1
                    } else {
                        1 + degree
                    };
                    assert_eq!(t.observations, expected, "{protocol}: node-{n}");
                }
            }
            let kl = sent_of(&net, MessageKind::KlConsensus).len() as u32;
            let relays = sent_of(&net, MessageKind::NeighbourObservation).len() as u32;
            let (k_max, relayed) = match protocol {
                "random_exchange" => (0, true),
                "kl_consensus" => (10, false),
                "kl_diffusion" => (1, true),
                _ => (10, true),
            };
            assert_eq!(kl, 25 * k_max * steps, "{protocol}: KL messages");
            assert_eq!(
                relays,
                if relayed { 25 * steps } else { 0 },
                "{protocol}: relays"
            );
            for o in sent_of(&net, MessageKind::NeighbourObservation) {
                let ActorId::Node(from) = o.message.header.sender else {
                    panic!("a relay from a node")
                };
                let neighbours: Vec<ActorId> = net.topology.neighbours[from as usize]
                    .iter()
                    .map(|m| ActorId::Node(*m))
                    .collect();
                assert_eq!(o.receivers, neighbours, "a relay reaches every neighbour");
            }
        }
    }

    /// RndEx-PF: a node that paired reports one neighbour heard, and the
    /// posteriors it swapped went both ways on the pair's own channels.
    #[test]
    fn paired_nodes_swap_posteriors_on_their_pair_channels() {
        let mut net = lattice("random_exchange");
        net.begin_step(1, &ALL);
        net.run(LONG);
        let posteriors = sent_of(&net, MessageKind::ExchangePosterior);
        let paired = (0..25u16)
            .filter(|n| net.report(*n, 1).unwrap().live_neighbours == 1)
            .count();
        assert!(paired >= 10, "{paired} of 25 paired");
        assert_eq!(
            posteriors.len(),
            paired,
            "one posterior sent per paired node"
        );
        for o in posteriors {
            let ActorId::Node(from) = o.message.header.sender else {
                panic!()
            };
            let [ActorId::Node(to)] = o.receivers[..] else {
                panic!("a posterior goes to one node")
            };
            assert_eq!(o.channel, Channel::Pair { from, to });
            assert!(net.sent.iter().any(|b| b.message.payload.kind()
                == MessageKind::ExchangePosterior
                && b.message.header.sender == ActorId::Node(to)
                && b.receivers == [ActorId::Node(from)]));
        }
    }

    /// Lost requests, lost acknowledgements and lost posteriors never hang
    /// a node: each finishes within its attempts, and keeps its own
    /// posterior when it received none.
    #[test]
    fn lost_requests_replies_or_posteriors_never_hang_a_node() {
        for lost in [
            MessageKind::ExchangeRequest,
            MessageKind::ExchangeReply,
            MessageKind::ExchangePosterior,
        ] {
            let mut net = lattice("random_exchange");
            net.set_rule(move |m, _| {
                if m.payload.kind() == lost {
                    Fate::Drop
                } else {
                    Fate::Deliver
                }
            });
            let started = net.now;
            net.begin_step(1, &ALL);
            net.run(LONG);
            let attempts = bounds::diffusion::EXCHANGE_ATTEMPTS + 1;
            assert!(
                net.now - started <= Duration::from_millis(20) * attempts,
                "{lost:?}: the step took {:?}",
                net.now - started
            );
            for n in 0..25u16 {
                let t = net
                    .report(n, 1)
                    .unwrap_or_else(|| panic!("{lost:?}: node-{n}"));
                // A listener sends its posterior with its acceptance, so a
                // requester whose acknowledgement was lost may still have
                // its partner's posterior; otherwise nobody received one.
                if lost != MessageKind::ExchangeReply {
                    assert_eq!(t.live_neighbours, 0, "{lost:?}: node-{n} paired");
                }
            }
        }
    }

    /// A neighbour that died without the membership knowing yet costs its
    /// neighbours the relay deadline and the protocol's timeouts, never the
    /// step.
    #[test]
    fn a_dead_neighbour_costs_timeouts_not_the_step() {
        for protocol in PROTOCOLS {
            let mut net = lattice(protocol);
            net.nodes[12] = None;
            net.begin_step(1, &ALL);
            net.run(LONG);
            for n in net.topology.neighbours[12].clone() {
                let t = net
                    .report(n, 1)
                    .unwrap_or_else(|| panic!("{protocol}: node-{n} never finished"));
                let degree = net.topology.neighbours[n as usize].len() as u16;
                if protocol != "kl_consensus" {
                    assert_eq!(t.observations, degree, "{protocol}: all but the dead one's");
                }
            }
            assert!(
                net.now < Duration::from_secs(1),
                "{protocol}: {:?}",
                net.now
            );
        }
    }

    /// The next `BeginStep` finishes a step still waiting, with what it has.
    #[test]
    fn an_overrun_step_is_finished_by_the_next() {
        for protocol in PROTOCOLS {
            let mut net = lattice(protocol);
            // Every node-to-node message is held far past the step.
            net.set_rule(|m, to| match (m.header.sender, to) {
                (ActorId::Node(_), ActorId::Node(_)) => Fate::Delay(LONG * 2),
                _ => Fate::Deliver,
            });
            net.begin_step(1, &ALL);
            net.run(Duration::from_millis(5));
            net.begin_step(2, &ALL);
            net.run(Duration::from_millis(5));
            for n in 0..25u16 {
                let t = net
                    .report(n, 1)
                    .unwrap_or_else(|| panic!("{protocol}: node-{n}"));
                assert!(t.deadline_missed, "{protocol}");
            }
        }
    }

    /// A relay that is not a neighbour's measurement of its own sensor, or
    /// not a number, is dropped and never weighed.
    #[test]
    fn forged_relays_are_dropped() {
        let mut net = lattice("kl_diffusion");
        let forged = [
            (ActorId::Node(0), 12u16, -60.0), // node 0 is not node 12's neighbour
            (ActorId::Node(7), 3u16, -60.0),  // sensor 3 is not node 7's
            (ActorId::Node(7), 7u16, f64::NAN), // not a measurement
        ];
        for (from, sensor, value) in forged {
            net.post(
                ActorId::Node(12),
                Message::new(from, 1, 0, Payload::NeighbourObservation { sensor, value }),
            );
        }
        net.begin_step(1, &ALL);
        net.run(LONG);
        assert_eq!(net.report(12, 1).unwrap().observations, 5);
    }

    /// On the random-exchange paper's slow target every tracker converges near it: the
    /// nodes' mean position error after 15 steps is a few metres (the RSS
    /// noise is 4 dB; one node alone is about 3.4 m).
    #[test]
    fn every_tracker_follows_the_target() {
        for protocol in PROTOCOLS {
            let mut net = lattice(protocol);
            let mut squared = 0.0;
            let mut count = 0;
            for step in 1..=15 {
                net.begin_step(step, &ALL);
                net.run(LONG);
                if step > 5 {
                    let truth = net.truth();
                    for n in 0..25u16 {
                        let e = net.report(n, step).unwrap().estimate;
                        squared += (e[0] - truth[0]).powi(2) + (e[1] - truth[1]).powi(2);
                        count += 1;
                    }
                }
            }
            let rmse = (squared / count as f64).sqrt();
            assert!(rmse < 4.0, "{protocol}: RMSE {rmse} m");
        }
    }
}
