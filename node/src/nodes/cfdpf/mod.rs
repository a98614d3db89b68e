//! The processing node as an I/O-free state machine.
//!
//! Each step: the launcher's `BeginStep` → the sensor manager chooses, the
//! activation goes out → **Collecting** the observations until all arrived
//! or a deadline → **Fusing**: the local filter and local bound (work the
//! driver runs), the fusion protocol on (δη, δΛ, ΔL [, S_obs]), the fusion
//! filter and the global CQ/dPCRLB (work again), telemetry → **Idle**.
//!
//! Inputs are decoded messages and the passing of timeouts, each with the
//! time it happens at; outputs are messages to send. The node never reads a
//! clock: the heavy stages are [`Work`] the driver runs with
//! [`run_work`](CfDpfNode::run_work) and reports back, timed, with
//! [`work_done`](CfDpfNode::work_done).

use std::time::Duration;

use bounds::State;
use fusion_graph::scenario::{CensoringPolicy, Scenario};
use fusion_graph::vocabulary::Shape;
use fusion_graph::Channel;
use fusion_graph::{stream_rng, ActorId, Stream, Topology};
use wire::{Message, Payload, Stage, StateTransfer};

use crate::censoring::NodeCensoring;
use crate::collector::{Collected, Collector, Lagging, Offer};
use crate::estimator::{
    Contribution, Evidence, FusionFilter, FusionUpdate, LocalFilter, LocalUpdate, Observation,
    ObservedValue, SensingModel,
};
use crate::filter::Gaussian;
use crate::fusion::information::{pack_matrix, unpack_matrix};
use crate::fusion::{Fused, Handled, InformationFusion, InformationVector};
use crate::sensor_manager::Manager;
use crate::{NodeError, Outgoing, Work};

use super::core::mask;
use super::{NodeCore, NodeKind, Report};

mod selection;

use selection::{ScoredAhead, Selecting};

#[derive(Debug)]
enum Phase {
    Idle,
    /// The PCRLB selection of a step: scoring, then agreeing with the other nodes.
    Selecting(Selecting),
    Collecting(Collector),
    Fusing(Box<Fusing>),
}

/// One step from the closing of its collection to its telemetry.
#[derive(Debug)]
struct Fusing {
    step: u32,
    /// The step's observations, until the local filter takes them.
    collected: Option<Collected>,
    /// The step before's observations that came after it closed.
    lagged: Vec<Observation>,
    local: Option<LocalUpdate>,
    /// The protocol's result, until the fusion filter takes it.
    fused: Option<Fused>,
    /// The fusion filter's result and the protocol's figures, until reported.
    finished: Option<(Option<FusionUpdate>, Fused)>,
    local_time: Duration,
}

impl Fusing {
    fn pending_work(&self) -> Option<Work> {
        if self.collected.is_some() {
            Some(Work::LocalFilter)
        } else if self.fused.is_some() {
            Some(Work::FusionFilter)
        } else {
            None
        }
    }
}

pub struct CfDpfNode {
    core: NodeCore,
    with_aux: bool,
    /// How long a step's collection waits for its active sensors: the
    /// round timeout, or with censoring the sensors' listening slot.
    listen: Duration,
    model: SensingModel,
    local: LocalFilter,
    fusion: FusionFilter,
    manager: Manager,
    protocol: InformationFusion,
    phase: Phase,
    /// Observations used this step, deadline missed: reported in telemetry.
    observations: u16,
    /// The innovation gate's threshold, if the scenario sets one.
    gate: Option<f64>,
    /// Observations the gate left out this step.
    gated: u16,
    lagged: u16,
    /// Set when this node restarted mid-run: it takes the first fused
    /// posterior a neighbour offers instead of starting from the prior.
    needs_state: bool,
    /// NIS censoring at this node's sensors, if the scenario asks for it.
    censoring: Option<NodeCensoring>,
    /// Observations that missed their step's collection.
    lagging: Lagging,
    /// From `BeginStep` to the activation, this step.
    selection_time: Duration,
    /// The selection's scoring this step, wherever it ran.
    scoring_time: Duration,
    /// The negotiated selection's choice did not reach this node this step.
    without_choice: bool,
    /// The next step's selection scores, once the last step reported.
    ahead: Option<ScoredAhead>,
    /// The sensors activated this step, reported with its telemetry.
    active: Vec<u16>,
    /// In real time, the step's period ([`bound_steps_by`](Self::bound_steps_by)).
    step_period: Option<Duration>,
    /// When this step's waiting stages are closed with what they have.
    step_deadline: Option<Duration>,
}

/// The share of a step's period its waiting stages (the selection's rounds,
/// the collection, the fusion rounds) may take; the rest is the fusion
/// filter's and the report's.
const WAITING_SHARE_OF_STEP: f64 = 0.9;

impl CfDpfNode {
    /// The node as the scenario describes it: its sensor manager and fusion
    /// protocol are what the scenario's names build (`crate::parts`).
    pub fn new(scenario: &Scenario, topology: &Topology, index: u16) -> Result<Self, NodeError> {
        let protocol = scenario.consensus.protocol;
        match protocol.shape() {
            Shape::ExactSums => return Err(NodeError::NoExactSums),
            Shape::Tracker { .. } | Shape::Locator => return Err(NodeError::NotCfDpf(protocol)),
            Shape::Rounds { .. } => {}
        }
        let protocol = crate::parts::information_fusion(scenario, topology, index)?
            .expect("a protocol of rounds has a builder");
        let manager = crate::parts::manager(scenario, topology, index)?;
        Self::with_parts(scenario, topology, index, manager, protocol)
    }

    /// The node with a sensor manager and a fusion protocol of the caller's choice.
    pub fn with_parts(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
        manager: impl Into<Manager>,
        protocol: InformationFusion,
    ) -> Result<Self, NodeError> {
        let models = scenario.models()?;
        let model = SensingModel::new(&models, topology);
        let prior = scenario.network_prior(&models);
        let n = scenario.filter.particles as usize;
        let id = ActorId::Node(index);
        let filter_error = |source| NodeError::Filter {
            node: index,
            source,
        };
        let local = LocalFilter::new(
            n,
            &prior,
            stream_rng(scenario.seed, id, 0, Stream::LocalFilter),
        )
        .map_err(filter_error)?
        .with_resampling(scenario.filter.resampler);
        let fusion = FusionFilter::new(
            n,
            &prior,
            scenario.consensus.auxiliary_fim,
            stream_rng(scenario.seed, id, 0, Stream::FusionFilter),
        )
        .map_err(filter_error)?
        .with_resampling(scenario.filter.resampler);
        Ok(Self {
            core: NodeCore::new(scenario, topology, index, models.quantizer.as_ref()),
            with_aux: scenario.consensus.auxiliary_fim,
            listen: if scenario.censoring.policy == CensoringPolicy::Off {
                Duration::from_secs_f64(scenario.consensus.round_timeout_ms / 1e3)
            } else {
                Duration::from_secs_f64(scenario.censoring.listen_ms / 1e3)
            },
            model,
            local,
            fusion,
            manager: manager.into(),
            protocol,
            phase: Phase::Idle,
            observations: 0,
            gate: (scenario.filter.gate > 0.0).then_some(scenario.filter.gate),
            gated: 0,
            lagged: 0,
            needs_state: false,
            censoring: NodeCensoring::for_scenario(scenario, &models, topology, index)?,
            lagging: Lagging::new(models.quantizer.as_ref().map(|q| q.cells())),
            selection_time: Duration::ZERO,
            scoring_time: Duration::ZERO,
            without_choice: false,
            ahead: None,
            active: Vec::new(),
            step_period: None,
            step_deadline: None,
        })
    }

    /// Bounds every step by its period, as in real time: whatever still
    /// waits at 90 % of the period after `BeginStep` (the selection's
    /// rounds, the collection, the fusion rounds) is closed with what has
    /// arrived, so that no wait for a slow neighbour or sensor can carry
    /// the node past its deadline. The rounds cut short are reported as not
    /// completed. Without it (`sim`, lockstep), a step waits as long as its
    /// timeouts say.
    pub fn bound_steps_by(&mut self, period: Duration) {
        self.step_period = Some(period);
    }

    /// The node as a process starts it: rejoining, bounded in time, or neither.
    pub fn starting(mut self, start: crate::Start) -> Self {
        if start.rejoin {
            self.expect_rejoin();
        }
        if let Some(period) = start.step_period {
            self.bound_steps_by(period);
        }
        self
    }

    /// Marks a node started in the middle of a run (a restart): it rejoins
    /// from a neighbour's fused posterior.
    pub fn expect_rejoin(&mut self) {
        self.needs_state = true;
    }

    fn own_sensors(&self) -> &[u16] {
        self.core.own_sensors()
    }

    fn neighbours(&self) -> &[u16] {
        self.core.neighbours()
    }

    /// When the stage that waits next times out, if a stage waits.
    fn stage_timeout(&self) -> Option<Duration> {
        match &self.phase {
            Phase::Selecting(s) if s.scored => match &self.manager {
                Manager::Negotiated(selection) => selection.poll_timeout(),
                Manager::Alone(_) => None,
            },
            Phase::Collecting(c) => Some(c.deadline()),
            Phase::Fusing(f) if f.pending_work().is_none() && f.finished.is_none() => {
                self.protocol.poll_timeout()
            }
            _ => None,
        }
    }

    /// Takes the protocol's result, if it has one.
    fn poll_protocol(&mut self) {
        if let Phase::Fusing(f) = &mut self.phase {
            if f.local.is_some() && f.fused.is_none() && f.finished.is_none() {
                f.fused = self.protocol.poll_result();
            }
        }
    }

    /// Sends the activation of `picks` (positions in the node's own sensor
    /// list) and starts collecting their observations.
    fn activate(&mut self, step: u32, picks: Vec<usize>, now: Duration, out: &mut Vec<Outgoing>) {
        let own = self.core.own_sensors();
        self.active = picks.iter().map(|&i| own[i]).collect();
        let mask = mask(&picks);
        let payload = match &mut self.censoring {
            None => Payload::Activate { mask },
            Some(c) => c.activate(step, &picks, own, &self.model, mask),
        };
        let collector = self
            .core
            .activate(step, &picks, payload, now + self.listen, out);
        let nothing_to_hear = self.active.is_empty();
        self.phase = Phase::Collecting(collector);
        // A node that activated no sensor has nothing to wait for. Waiting
        // out the listening window made it start its rounds a round timeout
        // late, just when its neighbours' first round timed out without it.
        if nothing_to_hear {
            self.close_collection();
        }
    }

    fn close_collection(&mut self) {
        let Phase::Collecting(c) = std::mem::replace(&mut self.phase, Phase::Idle) else {
            return;
        };
        let collected = c.close();
        // The last step's stragglers go with this step; this step's silent
        // sensors may still report, a step late.
        let lagged =
            self.lagging
                .close(collected.step, &collected.silent, self.censoring.is_none());
        self.observations = collected.observations.len() as u16;
        self.lagged = lagged.len() as u16;
        self.gated = 0;
        self.phase = Phase::Fusing(Box::new(Fusing {
            step: collected.step,
            collected: Some(collected),
            lagged,
            local: None,
            fused: None,
            finished: None,
            local_time: Duration::ZERO,
        }));
    }

    /// The step's telemetry, once the fusion filter is done.
    fn report(&mut self, fusion_time: Duration, out: &mut Vec<Outgoing>) {
        let Phase::Fusing(f) = std::mem::replace(&mut self.phase, Phase::Idle) else {
            return;
        };
        let (Some(local), Some((update, fused))) = (f.local, f.finished) else {
            return;
        };
        let estimate = update.map_or(local.estimate, |u| u.estimate);
        if let (Some(c), Some(u)) = (self.censoring.as_mut(), update) {
            c.fed_back = u.posterior;
        }
        let report = Report::of(&estimate)
            .bound(update.and_then(|u| u.bound))
            .local_bound(local.bound)
            .aux_bound(update.and_then(|u| u.aux_bound))
            .rounds(&fused.stats)
            .observations(self.observations)
            .gated(self.gated)
            .lagged(self.lagged)
            .stage(Stage::Local, f.local_time)
            .stage(Stage::Global, fusion_time)
            .stage(Stage::Selection, self.selection_time)
            .stage(Stage::Scoring, self.scoring_time)
            // With censoring, a sensor's silence is its answer.
            .silence_answers(self.censoring.is_some())
            .spread(update.map(|u| u.spread))
            .active(std::mem::take(&mut self.active))
            .without_choice(self.without_choice);
        self.observations = 0;
        self.selection_time = Duration::ZERO;
        self.scoring_time = Duration::ZERO;
        self.without_choice = false;
        out.push(self.core.report(f.step, report));
        if matches!(self.manager, Manager::Negotiated(_)) && f.step < self.core.steps() {
            let due = self.step_deadline.unwrap_or(Duration::ZERO);
            self.ahead = Some(ScoredAhead {
                step: f.step + 1,
                due,
                inputs: None,
                scoring_time: Duration::ZERO,
                released: self.step_deadline.is_none(),
            });
        }
    }

    /// The step's deadline has come while a stage waits: it closes with
    /// what has arrived, and the step goes on to its heavy stages, which
    /// the driver runs and times as usual. A selection not agreed by now
    /// activates no one (too late for observations this step).
    fn close_at_deadline(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        match &mut self.phase {
            Phase::Selecting(s) => {
                let step = s.step;
                if let Manager::Negotiated(selection) = &mut self.manager {
                    let _ = selection.finish_now(now, out);
                    self.without_choice = true;
                }
                let cells = self.model.quantizer.as_ref().map(|q| q.cells());
                self.phase = Phase::Collecting(Collector::new(step, Vec::new(), now, cells));
                self.close_collection();
            }
            Phase::Collecting(_) => self.close_collection(),
            Phase::Fusing(f) => {
                if f.local.is_some() && f.fused.is_none() && f.finished.is_none() {
                    f.fused = self.protocol.finish_now(now, out);
                }
            }
            Phase::Idle => {}
        }
    }

    fn take_state(&mut self, s: &StateTransfer) {
        if !self.needs_state {
            return;
        }
        let posterior = Gaussian {
            mean: State::from(s.mean),
            cov: unpack_matrix(&s.covariance),
        };
        let info = unpack_matrix(&s.information);
        self.fusion.reset(
            &posterior,
            info,
            self.with_aux.then(|| unpack_matrix(&s.aux_information)),
        );
        self.local.reset(&posterior, info);
        self.needs_state = false;
        // Scored on the filter just replaced.
        self.ahead = None;
        tracing::info!(
            node = self.core.index(),
            "rejoined from a neighbour's fused posterior"
        );
    }
}

impl NodeKind for CfDpfNode {
    fn core(&mut self) -> &mut NodeCore {
        &mut self.core
    }

    /// A step whose local filter left nothing to fuse ends unreported.
    fn is_idle(&mut self) -> bool {
        matches!(self.phase, Phase::Idle)
    }

    /// Runs every remaining stage at once, without waiting for anyone; the
    /// stages of an overrun step are not timed.
    fn finish_overrun(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        if let Phase::Selecting(Selecting { step, .. }) = self.phase {
            // Too late to activate anyone for this step: it is fused with
            // no observations of this node's.
            if let Manager::Negotiated(selection) = &mut self.manager {
                let _ = selection.finish_now(now, out);
                self.without_choice = true;
            }
            let cells = self.model.quantizer.as_ref().map(|q| q.cells());
            self.phase = Phase::Collecting(Collector::new(step, Vec::new(), now, cells));
        }
        if let Phase::Collecting(_) = self.phase {
            self.close_collection();
        }
        while let Phase::Fusing(f) = &self.phase {
            if let Some(work) = f.pending_work() {
                self.run_work(work);
                self.work_done(work, Duration::ZERO, now, out);
            } else if f.finished.is_some() {
                self.report(Duration::ZERO, out);
            } else {
                let fused = self.protocol.finish_now(now, out);
                let Phase::Fusing(f) = &mut self.phase else {
                    unreachable!("matched above")
                };
                match fused {
                    Some(fused) => f.fused = Some(fused),
                    // Nothing ran (the local filter's result is missing): drop the step.
                    None => self.phase = Phase::Idle,
                }
            }
        }
    }

    fn begin_step(&mut self, step: u32, missed: u32, now: Duration, out: &mut Vec<Outgoing>) {
        // The filters and bounds coast through missed steps so that they
        // are at the right time (after an overrun step is finished at its own).
        for _ in 0..missed {
            if let Err(e) = self
                .local
                .coast(&self.model)
                .and_then(|_| self.fusion.coast(&self.model))
            {
                tracing::error!(node = self.core.index(), error = %e, "coasting through a missed step failed");
            }
        }
        self.step_deadline = self
            .step_period
            .map(|p| now + p.mul_f64(WAITING_SHARE_OF_STEP));
        self.protocol.expect_step(step);
        match &self.manager {
            Manager::Alone(_) => {
                let picks = self.choose_alone(step);
                self.activate(step, picks, now, out);
            }
            Manager::Negotiated(_) => {
                // Scores made for this step, taken by value.
                let (inputs, scoring_time) = match self.ahead.take() {
                    Some(a) if a.step == step => (a.inputs, a.scoring_time),
                    _ => (None, Duration::ZERO),
                };
                let scored = inputs.is_some();
                self.phase = Phase::Selecting(Selecting {
                    step,
                    inputs,
                    scored,
                    scoring_time: Duration::ZERO,
                    rounds_started: now,
                });
                if scored {
                    self.start_selection(scoring_time, true, now, out);
                }
            }
        }
    }

    fn observe(&mut self, step: u32, sensor: u16, value: ObservedValue, _: &mut Vec<Outgoing>) {
        self.core.answered(sensor);
        let (offer, complete) = match &mut self.phase {
            Phase::Collecting(c) => {
                let offer = c.offer(step, sensor, value);
                (offer, offer == Offer::Taken && c.is_complete())
            }
            _ => (Offer::Late, false),
        };
        if complete {
            self.close_collection();
        }
        let offer = match offer {
            Offer::Late => self.lagging.offer(step, sensor, value),
            other => other,
        };
        self.core.note(offer, sensor);
    }

    fn view_changed(&mut self, before: &[bool], out: &mut Vec<Outgoing>) {
        // A neighbour that came back gets our fused posterior to rejoin from.
        let returned: Vec<ActorId> = self
            .neighbours()
            .iter()
            .filter(|m| self.core.view()[**m as usize] && !before[**m as usize])
            .map(|m| ActorId::Node(*m))
            .collect();
        if let (false, Some(step), false) =
            (returned.is_empty(), self.core.last_step(), self.needs_state)
        {
            let p = self.fusion.posterior();
            let state = StateTransfer {
                mean: p.mean.into(),
                covariance: pack_matrix(&p.cov),
                information: pack_matrix(self.fusion.information()),
                aux_information: self.fusion.aux_information().map_or([0.0; 10], pack_matrix),
            };
            // Every neighbour's queue gets it (it is our channel), so it is
            // counted as sent to each; only the returned are woken for it.
            out.push(Outgoing {
                channel: Channel::Consensus(self.core.index()),
                message: Message::new(self.core.id(), step, 0, Payload::StateTransfer(state)),
                receivers: self
                    .neighbours()
                    .iter()
                    .map(|m| ActorId::Node(*m))
                    .collect(),
                wake: Some(returned),
            });
        }
    }

    fn take(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        match (&message.payload, message.header.sender) {
            (Payload::StateTransfer(s), ActorId::Node(_)) => self.take_state(s),
            (Payload::SelectionReport(_) | Payload::SelectionChoice(_), ActorId::Node(_)) => {
                let handled = match &mut self.manager {
                    Manager::Negotiated(selection) => selection.handle(message, now, out),
                    Manager::Alone(_) => Handled::NotMine,
                };
                match handled {
                    Handled::Taken => self.poll_selection(now, out),
                    Handled::Late => self.core.count_late(),
                    Handled::NotMine => {}
                }
            }
            _ => {
                let handled = self.protocol.handle(message, now, out);
                if self.core.taken(handled, message) {
                    self.poll_protocol()
                }
            }
        }
    }

    /// Its neighbours may still be in their last rounds, which every node
    /// waits for; the fusion filter (tens of microseconds) is on this
    /// node's report alone.
    fn gives_way_before(&self, work: Work) -> bool {
        work == Work::FusionFilter
    }

    /// When [`handle_timeout`](Self::handle_timeout) should next be called.
    fn poll_timeout(&self) -> Option<Duration> {
        if let Some(due) = self.ahead_due() {
            return Some(due);
        }
        let waiting = self.stage_timeout()?;
        Some(self.step_deadline.map_or(waiting, |d| waiting.min(d)))
    }

    /// Called when the time from [`poll_timeout`](Self::poll_timeout) has come.
    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        if self.ahead_due().is_some_and(|due| now >= due) {
            if let Some(a) = self.ahead.as_mut() {
                a.released = true;
            }
        }
        if self.step_deadline.is_some_and(|d| now >= d) && self.stage_timeout().is_some() {
            return self.close_at_deadline(now, out);
        }
        match &self.phase {
            Phase::Selecting(s) if s.scored => {
                if let Manager::Negotiated(selection) = &mut self.manager {
                    selection.handle_timeout(now, out);
                }
                self.poll_selection(now, out);
            }
            Phase::Collecting(c) if now >= c.deadline() => self.close_collection(),
            Phase::Fusing(_) => {
                self.protocol.handle_timeout(now, out);
                self.poll_protocol();
            }
            _ => {}
        }
    }

    /// The heavy stage waiting to run, if any.
    fn poll_work(&self) -> Option<Work> {
        match &self.phase {
            Phase::Selecting(s) if !s.scored => Some(Work::SelectionScores),
            Phase::Idle if self.ahead.as_ref().is_some_and(ScoredAhead::wants_scoring) => {
                Some(Work::SelectionScores)
            }
            Phase::Fusing(f) => f.pending_work(),
            _ => None,
        }
    }

    /// Runs the pending heavy stage; the driver times it and then calls
    /// [`work_done`](Self::work_done).
    fn run_work(&mut self, work: Work) {
        if work == Work::SelectionScores {
            return self.score_selection();
        }
        let Phase::Fusing(f) = &mut self.phase else {
            return;
        };
        match work {
            Work::SelectionScores | Work::Weigh | Work::Adopt => {}
            Work::GridLikelihood | Work::Design | Work::WeighDelivery => {}
            Work::LocalFilter => {
                let Some(mut collected) = f.collected.take() else {
                    return;
                };
                if let Some(threshold) = self.gate {
                    match self
                        .local
                        .gate(&self.model, &collected.observations, threshold)
                    {
                        Ok((kept, gated)) => {
                            collected.observations = kept;
                            self.gated = gated;
                            self.observations = collected.observations.len() as u16;
                        }
                        Err(e) => {
                            tracing::error!(node = self.core.index(), error = %e, "innovation gate failed; using every observation")
                        }
                    }
                }
                let (silent, censored) = self.censoring.as_ref().map_or_else(
                    || (Vec::new(), Vec::new()),
                    |c| {
                        let step = collected.step;
                        (c.silences(step, &collected.silent), c.active(step))
                    },
                );
                let evidence = Evidence {
                    received: &collected.observations,
                    lagged: &f.lagged,
                    silent: &silent,
                    censored: &censored,
                };
                let update = self
                    .local
                    .update(&self.model, &evidence, self.with_aux)
                    .and_then(|mut update| {
                        let c = &mut update.contribution;
                        (c.delta_l, c.delta_l_late) = self
                            .fusion
                            .observation_information(&self.model, &evidence)?;
                        Ok(update)
                    })
                    .unwrap_or_else(|e| {
                        tracing::error!(node = self.core.index(), error = %e, "local filter step failed; contributing nothing");
                        LocalUpdate {
                            contribution: Contribution::zero(),
                            estimate: State::zeros(),
                            bound: None,
                        }
                    });
                f.local = Some(update);
            }
            Work::FusionFilter => {
                let Some(fused) = f.fused.take() else {
                    return;
                };
                let update = match self.fusion.step(&self.model, &fused.sums) {
                    Ok(u) => Some(u),
                    Err(e) => {
                        tracing::error!(node = self.core.index(), error = %e, "fusion filter step failed");
                        None
                    }
                };
                f.finished = Some((update, fused));
            }
        }
    }

    /// The driver's report that `work` finished at `now` after `elapsed`:
    /// the step goes on (the fusion protocol starts after the local filter;
    /// telemetry goes out after the fusion filter).
    fn work_done(&mut self, work: Work, elapsed: Duration, now: Duration, out: &mut Vec<Outgoing>) {
        if work == Work::SelectionScores {
            if let (Phase::Idle, Some(ahead)) = (&self.phase, self.ahead.as_mut()) {
                ahead.scoring_time = elapsed;
                return;
            }
            return self.start_selection(elapsed, false, now, out);
        }
        let Phase::Fusing(f) = &mut self.phase else {
            return;
        };
        match work {
            Work::SelectionScores | Work::Weigh | Work::Adopt => {}
            Work::GridLikelihood | Work::Design | Work::WeighDelivery => {}
            Work::LocalFilter => {
                f.local_time = elapsed;
                let Some(local) = f.local else {
                    return;
                };
                let value =
                    InformationVector::from_contribution(&local.contribution, self.with_aux);
                let step = f.step;
                self.protocol.start(step, value, self.core.view(), now, out);
                self.poll_protocol();
            }
            Work::FusionFilter => self.report(elapsed, out),
        }
    }
}

#[cfg(test)]
mod tests {
    //! The node on the virtual-clock harness: three nodes in a line.
    use super::*;
    use crate::harness::{Fate, Net};
    use crate::{ProcessingNode, Start};
    use wire::Control;

    const ALL: [bool; 3] = [true; 3];
    const LONG: Duration = Duration::from_secs(5);

    #[test]
    fn a_step_completes_every_round_with_every_neighbour() {
        let mut net = Net::line();
        for step in 1..=3 {
            net.begin_step(step, &ALL);
            net.run(LONG);
            for (n, degree) in [(0, 1), (1, 2), (2, 1)] {
                let t = net.report(n, step).expect("a report every step");
                assert_eq!((t.rounds_completed, t.live_neighbours), (6, degree));
                assert_eq!((t.observations, t.deadline_missed), (3, false));
                assert!(t.bound.is_some_and(|b| b > 0.0 && b < 20.0), "{t:?}");
            }
        }
        // No timeout was needed: the step took no virtual time at all.
        assert_eq!(net.now, Duration::ZERO);
        // Rounds of 205-byte consensus messages: 6 per step per directed link.
        let consensus = net
            .sent
            .iter()
            .filter(|o| matches!(o.message.payload, Payload::Consensus(_)))
            .map(|o| o.receivers.len())
            .sum::<usize>();
        assert_eq!(consensus, 3 * 6 * 4);
    }

    /// The PCRLB manager on the line: every step, exactly N_max sensors
    /// network-wide, within each node's cap, gathered at the centre and told
    /// back: each end node's 3 candidates in one report, one choice.
    #[test]
    fn the_pcrlb_manager_activates_n_max_within_the_caps_every_step() {
        for (manager, aux) in [
            ("pcrlb", false),
            ("pcrlb_at_estimate", false),
            ("pcrlb_aux", true),
        ] {
            let mut net = Net::line_with(&[
                &format!("sensors.manager={manager}"),
                "sensors.active_per_node=2",
                "sensors.max_active_total=4",
                &format!("consensus.auxiliary_fim={aux}"),
            ]);
            for step in 1..=3 {
                net.begin_step(step, &ALL);
                net.run(LONG);
                let this_step: Vec<&(u16, u32, Vec<u16>)> =
                    net.activations.iter().filter(|a| a.1 == step).collect();
                // A node that activates none sends nothing.
                assert!(this_step.len() <= 3, "{manager}: one activation per node");
                assert!(
                    this_step.iter().all(|a| a.2.len() <= 2),
                    "{manager}: {this_step:?}"
                );
                let total: usize = this_step.iter().map(|a| a.2.len()).sum();
                assert_eq!(total, 4, "{manager}: {this_step:?}");
                for n in 0..3 {
                    let t = net.report(n, step).expect("a report every step");
                    assert_eq!(t.rounds_completed, 6);
                }
            }
            let selection_messages = net
                .sent
                .iter()
                .filter(|o| {
                    matches!(
                        o.message.payload,
                        Payload::SelectionReport(_) | Payload::SelectionChoice(_)
                    )
                })
                .count();
            assert_eq!(
                selection_messages,
                3 * (2 + 1),
                "{manager}: steps × (two reports and a choice)"
            );
            assert_eq!(net.now, Duration::ZERO, "{manager}: no one waited");
        }
    }

    fn begin(step: u32) -> Message {
        Message::new(
            ActorId::Launcher,
            step,
            0,
            Payload::Control(Control::BeginStep),
        )
    }

    fn sends_a_report(out: &[Outgoing]) -> bool {
        out.iter()
            .any(|o| matches!(o.message.payload, Payload::SelectionReport(_)))
    }

    /// A negotiating node scores the next step's candidates once it has
    /// reported a step: that step begins with its report sent at once. A
    /// step begun after a missed one drops those scores (the filter coasts
    /// through the missed step) and scores anew.
    #[test]
    fn the_next_steps_candidates_are_scored_before_it_begins() {
        let mut net = Net::line_with(&[
            "sensors.manager=pcrlb",
            "sensors.active_per_node=2",
            "sensors.max_active_total=4",
        ]);
        net.begin_step(1, &ALL);
        net.run(LONG);
        let now = net.now;
        // Node 0, a leaf under node 1, reports as the step begins.
        let leaf = net.nodes[0].as_mut().unwrap();
        assert!(leaf.is_idle() && leaf.poll_work().is_none());
        let mut out = Vec::new();
        leaf.handle(&begin(2), now, &mut out);
        assert!(leaf.poll_work().is_none(), "scored before the step");
        assert!(sends_a_report(&out));
        // Node 2 misses step 2: its scores were for it.
        let other = net.nodes[2].as_mut().unwrap();
        let mut out = Vec::new();
        other.handle(&begin(3), now, &mut out);
        assert_eq!(other.poll_work(), Some(Work::SelectionScores));
        assert!(!sends_a_report(&out));
    }

    /// Without the root's choice (node 1's choices lost), the two other
    /// nodes activate nothing and say so in their telemetry; the root,
    /// which made the choice, activates its own.
    #[test]
    fn a_node_the_choice_does_not_reach_reports_it() {
        let mut net = Net::line_with(&["sensors.manager=pcrlb"]);
        net.set_rule(|m, _| match (&m.payload, m.header.sender) {
            (Payload::SelectionChoice(_), ActorId::Node(1)) => Fate::Drop,
            _ => Fate::Deliver,
        });
        net.begin_step(1, &ALL);
        net.run(LONG);
        for (n, without) in [(0, true), (1, false), (2, true)] {
            let t = net.report(n, 1).expect("a report");
            assert_eq!(t.without_choice, without, "node {n}");
            assert_eq!(t.active.is_empty(), without, "node {n}: {t:?}");
        }
    }

    /// In real time the next step's scoring waits for the step's deadline
    /// (90 % of the period), when every node's waits have closed.
    #[test]
    fn in_real_time_the_scoring_waits_for_the_steps_deadline() {
        let mut net = Net::line_with(&["sensors.manager=pcrlb"]);
        net.start_nodes(Start {
            rejoin: false,
            step_period: Some(Duration::from_millis(100)),
        });
        net.begin_step(1, &ALL);
        net.run(Duration::from_millis(89));
        assert_eq!(net.telemetry.len(), 3, "every node reported");
        let now = net.now;
        let node = net.nodes[0].as_mut().unwrap();
        assert!(node.poll_work().is_none(), "not before the deadline");
        assert_eq!(node.poll_timeout(), Some(Duration::from_millis(90)));
        let mut out = Vec::new();
        node.handle_timeout(Duration::from_millis(90), &mut out);
        assert_eq!(node.poll_work(), Some(Work::SelectionScores));
        assert!(now < Duration::from_millis(90));
    }

    /// The conditional manager picks, on its first iteration, the sensor
    /// with by far the most information: the one beside the target.
    #[test]
    fn the_pcrlb_manager_picks_the_sensor_beside_the_target_first() {
        // Sensor 3 is at (600, 100): 22 m from the target, against 200 m
        // and more for every other sensor, and still the nearest over the
        // whole 20 m prior cloud.
        let mut net = Net::line_with(&[
            "sensors.manager=pcrlb",
            "sensors.active_per_node=1",
            "sensors.max_active_total=1",
            "target.position=[610.0, 120.0]",
        ]);
        net.begin_step(1, &ALL);
        net.run(LONG);
        let chosen: Vec<u16> = net.activations.iter().flat_map(|a| a.2.clone()).collect();
        assert_eq!(chosen, vec![3]);
    }

    #[test]
    fn an_early_message_is_kept_and_a_late_one_counted() {
        let mut net = Net::line();
        // Node 0's observations come 20 ms late (inside the 50 ms deadline):
        // its neighbour's round-1 value reaches it while it still collects.
        net.set_rule(|m, to| match (m.header.sender, to) {
            (ActorId::Sensor(_), ActorId::Node(0)) => Fate::Delay(Duration::from_millis(20)),
            _ => Fate::Deliver,
        });
        net.begin_step(1, &ALL);
        net.run(LONG);
        let t = net.report(0, 1).unwrap();
        assert_eq!(
            (t.rounds_completed, t.live_neighbours, t.observations),
            (6, 1, 3)
        );
        // A copy of node 1's round-2 message arrives during step 2: late.
        let stale = net
            .sent
            .iter()
            .find(|o| o.message.header.round == 2 && o.message.header.sender == ActorId::Node(1))
            .unwrap()
            .message
            .clone();
        net.set_rule(|_, _| Fate::Deliver);
        net.begin_step(2, &ALL);
        net.post(ActorId::Node(0), stale);
        net.run(LONG);
        assert_eq!(net.report(0, 2).unwrap().late_messages, 1);
        assert_eq!(net.report(1, 2).unwrap().late_messages, 0);
    }

    #[test]
    fn a_silent_sensor_closes_the_collection_at_its_deadline() {
        let mut net = Net::line();
        let silent = net.topology.node_sensors[1][0];
        net.set_rule(move |m, _| match m.header.sender {
            ActorId::Sensor(s) if s == silent => Fate::Drop,
            _ => Fate::Deliver,
        });
        net.begin_step(1, &ALL);
        net.run(LONG);
        let t = net.report(1, 1).unwrap();
        assert_eq!((t.observations, t.rounds_completed), (2, 6));
        assert_eq!(
            net.now,
            Duration::from_millis(50),
            "one collection deadline"
        );
        assert_eq!(net.report(0, 1).unwrap().observations, 3);
    }

    #[test]
    fn a_neighbour_lost_mid_consensus_costs_one_timeout_not_the_step() {
        let mut net = Net::line();
        // Node 2 falls silent after its third round.
        net.set_rule(|m, _| match m.header.sender {
            ActorId::Node(2) if m.header.round > 3 => Fate::Drop,
            _ => Fate::Deliver,
        });
        net.begin_step(1, &ALL);
        net.run(LONG);
        let t = net.report(1, 1).unwrap();
        assert_eq!((t.rounds_completed, t.live_neighbours), (6, 1));
        assert!(t.bound.is_some());
        // Round 4 waited out its timeout, round 5 only the grace of a
        // neighbour on probation (10 ms), and round 6 not at all
        // (`RoundEngine::stop_awaiting_the_late`).
        assert_eq!(net.now, Duration::from_millis(60));
        // Node 0, two hops from node 2, waited at most for node 1's
        // one timeout, and finishes the step with all its rounds.
        let t0 = net.report(0, 1).unwrap();
        assert_eq!(t0.rounds_completed, 6);
        assert!(t0.bound.is_some());
    }

    #[test]
    fn a_membership_change_moves_consensus_to_the_live_component() {
        let mut net = Net::line();
        let view = [true, true, false];
        net.begin_step(1, &view);
        net.run(LONG);
        let t = net.report(1, 1).unwrap();
        assert_eq!((t.rounds_completed, t.live_neighbours), (6, 1));
        assert!(net.report(2, 1).is_none(), "node 2 was not started");
        assert_eq!(net.now, Duration::ZERO, "no one waited for node 2");
        // Node 2 was woken for nothing, though every message on node 1's
        // channel reaches its queue and is counted so.
        let node1 = net
            .sent
            .iter()
            .filter(|o| o.channel == Channel::Consensus(1))
            .collect::<Vec<_>>();
        assert!(!node1.is_empty());
        assert!(node1.iter().all(|o| o.receivers.contains(&ActorId::Node(2))
            && !o.wake.as_ref().unwrap().contains(&ActorId::Node(2))));
    }

    /// A BeginStep the launcher could not have sent (past, repeated, or
    /// beyond the run's last step) changes nothing: the fuzzer found that
    /// step 4·10⁹ made a node coast through four billion steps.
    #[test]
    fn an_impossible_begin_step_is_dropped() {
        let mut net = Net::line();
        net.begin_step(1, &ALL);
        net.run(LONG);
        let last = net.scenario.steps;
        for step in [0, 1, last + 1] {
            net.begin_step(step, &ALL);
            net.run(LONG);
        }
        let steps_run = |net: &Net| {
            let mut s: Vec<u32> = net
                .telemetry
                .iter()
                .filter(|t| t.0 == 1)
                .map(|t| t.1)
                .collect();
            s.dedup();
            s
        };
        assert_eq!(steps_run(&net), vec![1]);
        // Before the check, this one never returned.
        net.begin_step(u32::MAX, &ALL);
        net.run(LONG);
        net.begin_step(2, &ALL);
        net.run(LONG);
        assert_eq!(steps_run(&net), vec![1, 2]);
    }

    #[test]
    fn a_restarted_node_rejoins_from_a_neighbours_posterior() {
        let mut net = Net::line();
        for step in 1..=4 {
            net.begin_step(step, &ALL);
            net.run(LONG);
        }
        // Node 2 dies at step 5 and comes back, empty, at step 7.
        net.nodes[2] = None;
        for step in 5..=6 {
            net.begin_step(step, &[true, true, false]);
            net.run(LONG);
        }
        let mut fresh = CfDpfNode::new(&net.scenario, &net.topology, 2).unwrap();
        fresh.expect_rejoin();
        net.nodes[2] = Some(Box::new(ProcessingNode::new(fresh)));
        net.begin_step(7, &ALL);
        net.run(LONG);
        assert!(
            net.sent
                .iter()
                .any(|o| matches!(o.message.payload, Payload::StateTransfer(_))
                    && o.wake == Some(vec![ActorId::Node(2)])),
            "node 1 offers its posterior"
        );
        net.begin_step(8, &ALL);
        net.run(LONG);
        let (e1, e2) = (
            net.report(1, 8).unwrap().estimate,
            net.report(2, 8).unwrap().estimate,
        );
        let gap = (e1[0] - e2[0]).hypot(e1[1] - e2[1]);
        assert!(
            gap < 5.0,
            "the rejoined node tracks with the others: {gap} m apart"
        );
    }
}
