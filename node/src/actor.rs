//! The processing node as an I/O-free state machine.
//!
//! Each step: the launcher's `BeginStep` → activate sensors → collect their
//! observations until all arrived or a deadline → local filter and local
//! bound → N_c rounds of average consensus on (δη, δΛ, ΔL [, S_obs]) with
//! the neighbours heard from → fusion filter and global CQ/dPCRLB →
//! telemetry. Inputs are decoded messages and the passing of deadlines;
//! outputs are messages to send. Time is given, never read, except to
//! report how long each stage took.

use std::time::{Duration, Instant};

use bounds::{CoordinatedTurn, Dynamics, Mat4, State};
use fusion_graph::scenario::{ConsensusProtocol, Scenario};
use fusion_graph::transport::Channel;
use fusion_graph::wire::{
    pack_symmetric, unpack_symmetric, ConsensusValues, Control, Message, Packed, Payload,
    StateTransfer, Telemetry, WireFormat,
};
use fusion_graph::{ActorId, Topology};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sensor::{observation_model, quantizer, stream_seed};

use crate::estimator::{
    Contribution, FusionFilter, LocalFilter, LocalUpdate, NetworkSums, Observation, ObservedValue,
    SensingModel,
};
use crate::filter::Gaussian;

/// Streams of randomness, one per purpose (see [`stream_seed`]).
const ACTIVATION_STREAM: u64 = 2;
const LOCAL_FILTER_STREAM: u64 = 3;
const FUSION_FILTER_STREAM: u64 = 4;
const PRIOR_STREAM: u64 = 5;

/// A message to publish.
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    pub channel: Channel,
    pub message: Message,
    pub receivers: Vec<ActorId>,
    /// Whom to wake, when not every receiver: the activation reaches all of
    /// a node's sensors but wakes only the active ones.
    pub wake: Option<Vec<ActorId>>,
}

/// The dynamics of a scenario.
pub fn dynamics(s: &Scenario) -> Dynamics {
    let d = &s.dynamics;
    Dynamics::new(CoordinatedTurn {
        period: d.period,
        maneuver_accel: d.maneuver_accel,
        min_speed: d.min_speed,
        sigma_v: d.sigma_v,
    })
    .expect("validated with the scenario")
}

/// The estimators' models for a scenario: dynamics, every sensor, the quantizer.
pub fn sensing_model(s: &Scenario, t: &Topology) -> SensingModel {
    SensingModel {
        dynamics: dynamics(s),
        sensors: t
            .sensor_positions
            .iter()
            .map(|p| observation_model(&s.observation, *p))
            .collect(),
        quantizer: quantizer(s),
    }
}

/// The prior every filter starts from: `N(m_0, P_0)` with `m_0` drawn once per
/// run from `N(x_true(0), P_0)` (math.md's default scenario).
pub fn network_prior(s: &Scenario) -> Gaussian {
    let sd = s.filter.prior_std;
    let cov = Mat4::from_diagonal(&State::new(
        sd[0] * sd[0],
        sd[1] * sd[1],
        sd[2] * sd[2],
        sd[3] * sd[3],
    ));
    let truth = State::from(s.target.initial_state());
    let mut rng =
        ChaCha8Rng::seed_from_u64(stream_seed(s.seed, ActorId::Launcher, 0, PRIOR_STREAM));
    let noise =
        State::from_fn(|_, _| rand::Rng::sample::<f64, _>(&mut rng, rand_distr::StandardNormal));
    Gaussian {
        mean: truth + State::new(sd[0], sd[1], sd[2], sd[3]).component_mul(&noise),
        cov,
    }
}

/// The wire sizes a scenario fixes.
pub fn wire_format(s: &Scenario, t: &Topology) -> WireFormat {
    let max_sensors = t.node_sensors.iter().map(Vec::len).max().unwrap_or(1);
    WireFormat {
        cell_bytes: (s.quantizer.bits as usize).div_ceil(8),
        activation_bytes: max_sensors.div_ceil(8).max(1),
    }
}

/// Consensus values: δη (4), δΛ (10), ΔL (10), S_obs (10).
type Values = [f64; 34];

fn pack(c: &Contribution) -> Values {
    let mut v = [0.0; 34];
    v[..4].copy_from_slice(c.delta_eta.as_slice());
    v[4..14].copy_from_slice(&pack_matrix(&c.delta_lambda));
    v[14..24].copy_from_slice(&pack_matrix(&c.delta_l));
    v[24..].copy_from_slice(&pack_matrix(&c.s_obs));
    v
}

fn unpack(v: &Values) -> Contribution {
    Contribution {
        delta_eta: State::from_column_slice(&v[..4]),
        delta_lambda: unpack_matrix(v[4..14].try_into().expect("10")),
        delta_l: unpack_matrix(v[14..24].try_into().expect("10")),
        s_obs: unpack_matrix(v[24..].try_into().expect("10")),
    }
}

pub fn pack_matrix(m: &Mat4) -> Packed {
    pack_symmetric(&std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])))
}

pub fn unpack_matrix(p: &Packed) -> Mat4 {
    let a = unpack_symmetric(p);
    Mat4::from_fn(|r, c| a[r][c])
}

/// A neighbour's value for one round, possibly still missing its aux part.
#[derive(Debug, Clone)]
struct Heard {
    step: u32,
    round: u16,
    from: u16,
    main: Option<[f64; 24]>,
    aux: Option<Packed>,
}

#[derive(Debug, Clone)]
enum Phase {
    Idle,
    Collecting {
        step: u32,
        active: Vec<u16>,
        received: Vec<Observation>,
        deadline: Duration,
    },
    Consensus(Round),
    /// The checking mode: waiting for the driver's exact network sums.
    AwaitingExact {
        step: u32,
        local: LocalUpdate,
        local_micros: u32,
    },
}

#[derive(Debug, Clone)]
struct Round {
    step: u32,
    /// 1..=N_c: the round whose values are being gathered.
    round: u16,
    value: Values,
    deadline: Duration,
    local: LocalUpdate,
    local_micros: u32,
    consensus_started: Instant,
    /// When round 1 completed.
    first_round_done: Option<Instant>,
    /// Neighbours heard in the last completed round.
    live_neighbours: u16,
}

/// How long consensus took, for telemetry.
#[derive(Debug, Clone, Copy, Default)]
struct ConsensusTiming {
    total_micros: u32,
    /// From the end of round 1 to the end of the last round.
    later_rounds_micros: u32,
}

/// Per-step counters reported in telemetry.
#[derive(Debug, Clone, Copy, Default)]
struct StepFlags {
    deadline_missed: bool,
    observations: u16,
}

pub struct NodeActor {
    index: u16,
    seed: u64,
    rounds: u16,
    round_timeout: Duration,
    protocol: ConsensusProtocol,
    with_aux: bool,
    active_per_node: usize,
    format: WireFormat,
    topology: Topology,
    model: SensingModel,
    local: LocalFilter,
    fusion: FusionFilter,
    alive: Vec<bool>,
    phase: Phase,
    heard: Vec<Heard>,
    flags: StepFlags,
    /// Set when this node restarted mid-run: it takes the first fused
    /// posterior a neighbour offers instead of starting from the prior.
    needs_state: bool,
    last_step: Option<u32>,
    late_messages: u64,
    /// `late_messages` as of the last telemetry.
    late_reported: u64,
}

impl NodeActor {
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
    ) -> Result<Self, bounds::BoundError> {
        let prior = network_prior(scenario);
        let n = scenario.filter.particles as usize;
        let id = ActorId::Node(index);
        let local = LocalFilter::new(
            n,
            &prior,
            ChaCha8Rng::seed_from_u64(stream_seed(scenario.seed, id, 0, LOCAL_FILTER_STREAM)),
        )?;
        let fusion = FusionFilter::new(
            n,
            &prior,
            scenario.consensus.auxiliary_fim,
            ChaCha8Rng::seed_from_u64(stream_seed(scenario.seed, id, 0, FUSION_FILTER_STREAM)),
        )?;
        Ok(Self {
            index,
            seed: scenario.seed,
            rounds: scenario.consensus.rounds as u16,
            round_timeout: Duration::from_secs_f64(scenario.consensus.round_timeout_ms / 1e3),
            protocol: scenario.consensus.protocol,
            with_aux: scenario.consensus.auxiliary_fim,
            active_per_node: scenario.sensors.active_per_node as usize,
            format: wire_format(scenario, topology),
            topology: topology.clone(),
            model: sensing_model(scenario, topology),
            local,
            fusion,
            alive: topology.all_alive(),
            phase: Phase::Idle,
            heard: Vec::new(),
            flags: StepFlags::default(),
            needs_state: false,
            last_step: None,
            late_messages: 0,
            late_reported: 0,
        })
    }

    pub fn id(&self) -> ActorId {
        ActorId::Node(self.index)
    }

    /// Marks a node started in the middle of a run (a restart): it rejoins
    /// from a neighbour's fused posterior.
    pub fn expect_rejoin(&mut self) {
        self.needs_state = true;
    }

    /// The channels this node reads.
    pub fn subscriptions(&self) -> Vec<Channel> {
        let mut v = vec![Channel::Control(self.id())];
        v.extend(
            self.topology.node_sensors[self.index as usize]
                .iter()
                .map(|s| Channel::Observation(*s)),
        );
        v.extend(
            self.topology.neighbours[self.index as usize]
                .iter()
                .map(|m| Channel::Consensus(*m)),
        );
        v
    }

    /// The channels this node publishes on.
    pub fn publications(&self) -> Vec<Channel> {
        vec![
            Channel::Activation(self.index),
            Channel::Consensus(self.index),
            Channel::Telemetry(self.index),
        ]
    }

    /// Actors this node sends to (to wake them).
    pub fn peers(&self) -> Vec<ActorId> {
        let mut v: Vec<ActorId> = self.topology.node_sensors[self.index as usize]
            .iter()
            .map(|s| ActorId::Sensor(*s))
            .collect();
        v.extend(
            self.topology.neighbours[self.index as usize]
                .iter()
                .map(|m| ActorId::Node(*m)),
        );
        v.push(ActorId::Launcher);
        v
    }

    pub fn is_idle(&self) -> bool {
        matches!(self.phase, Phase::Idle)
    }

    /// Messages that arrived after their round or step had passed.
    pub fn late_messages(&self) -> u64 {
        self.late_messages
    }

    /// When [`handle_deadline`](Self::handle_deadline) should next be called.
    pub fn next_deadline(&self) -> Option<Duration> {
        match &self.phase {
            Phase::Collecting { deadline, .. } => Some(*deadline),
            Phase::Consensus(r) => Some(r.deadline),
            _ => None,
        }
    }

    pub fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        let step = message.header.step;
        match (&message.payload, message.header.sender) {
            (Payload::Control(Control::BeginStep), ActorId::Launcher) => {
                self.begin_step(step, now, out)
            }
            (Payload::Control(Control::Membership { alive }), ActorId::Launcher) => {
                self.update_membership(alive, out)
            }
            (Payload::Observation { cell }, ActorId::Sensor(s)) => {
                self.observe(step, s, ObservedValue::Cell(*cell), now, out)
            }
            (Payload::RawObservation { value }, ActorId::Sensor(s)) => {
                self.observe(step, s, ObservedValue::Raw(*value), now, out)
            }
            (Payload::Consensus(v), ActorId::Node(m)) => {
                let mut main = [0.0; 24];
                main[..4].copy_from_slice(&v.delta_eta);
                main[4..14].copy_from_slice(&v.delta_lambda);
                main[14..].copy_from_slice(&v.delta_l);
                self.hear(step, message.header.round, m, Some(main), None, now, out);
            }
            (Payload::ConsensusAux { s_obs }, ActorId::Node(m)) => {
                self.hear(step, message.header.round, m, None, Some(*s_obs), now, out)
            }
            (Payload::StateTransfer(s), ActorId::Node(_)) => self.take_state(s),
            (p, from) => {
                tracing::debug!(node = self.index, kind = ?p.kind(), %from, "ignored a message not meant for a node")
            }
        }
    }

    /// Called when the time from [`next_deadline`](Self::next_deadline) has come.
    pub fn handle_deadline(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        match &self.phase {
            Phase::Collecting { deadline, .. } if now >= *deadline => {
                self.finish_collecting(now, out)
            }
            Phase::Consensus(r) if now >= r.deadline => self.complete_round(now, out),
            _ => {}
        }
    }

    fn begin_step(&mut self, step: u32, now: Duration, out: &mut Vec<Outgoing>) {
        // Missed steps (a lost BeginStep, or SIGSTOP and SIGCONT): the filters
        // and bounds coast through them so that they are at the right time.
        if let Some(last) = self.last_step {
            for _ in last + 1..step {
                if let Err(e) = self
                    .local
                    .coast(&self.model)
                    .and_then(|_| self.fusion.coast(&self.model))
                {
                    tracing::error!(node = self.index, error = %e, "coasting through a missed step failed");
                }
            }
        }
        self.last_step = Some(step);
        if !self.is_idle() {
            // The previous step overran: finish it with what we have.
            self.flags.deadline_missed = true;
            self.force_finish(now, out);
        }
        self.heard.retain(|h| h.step >= step);
        let own = &self.topology.node_sensors[self.index as usize];
        let mut rng =
            ChaCha8Rng::seed_from_u64(stream_seed(self.seed, self.id(), step, ACTIVATION_STREAM));
        let k = self.active_per_node.min(own.len());
        let mut picks: Vec<usize> = rand::seq::index::sample(&mut rng, own.len(), k).into_vec();
        picks.sort_unstable();
        let mut mask = vec![0u8; self.format.activation_bytes];
        for &i in &picks {
            mask[i / 8] |= 1 << (i % 8);
        }
        let receivers = own.iter().map(|s| ActorId::Sensor(*s)).collect();
        let active: Vec<u16> = picks.iter().map(|&i| own[i]).collect();
        out.push(Outgoing {
            channel: Channel::Activation(self.index),
            message: Message::new(self.id(), step, 0, Payload::Activate { mask }),
            receivers,
            wake: Some(active.iter().map(|s| ActorId::Sensor(*s)).collect()),
        });
        self.phase = Phase::Collecting {
            step,
            active,
            received: Vec::new(),
            deadline: now + self.round_timeout,
        };
    }

    fn observe(
        &mut self,
        step: u32,
        sensor: u16,
        value: ObservedValue,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let Phase::Collecting {
            step: current,
            active,
            received,
            ..
        } = &mut self.phase
        else {
            self.late_messages += 1;
            return;
        };
        if step != *current
            || !active.contains(&sensor)
            || received.iter().any(|o| o.sensor == sensor)
        {
            self.late_messages += 1;
            return;
        }
        if let (ObservedValue::Cell(c), Some(q)) = (value, &self.model.quantizer) {
            if c as usize >= q.cells() {
                tracing::warn!(
                    node = self.index,
                    sensor,
                    cell = c,
                    "observation outside the quantizer's cells dropped"
                );
                return;
            }
        }
        received.push(Observation { sensor, value });
        if received.len() == active.len() {
            self.finish_collecting(now, out);
        }
    }

    fn finish_collecting(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Phase::Collecting {
            step, mut received, ..
        } = std::mem::replace(&mut self.phase, Phase::Idle)
        else {
            return;
        };
        received.sort_by_key(|o| o.sensor);
        self.flags.observations = received.len() as u16;
        let timer = Instant::now();
        let local = match self.local.step(&self.model, &received, self.with_aux) {
            Ok(l) => l,
            Err(e) => {
                tracing::error!(node = self.index, error = %e, "local filter step failed; contributing nothing");
                LocalUpdate {
                    contribution: Contribution::zero(),
                    estimate: State::zeros(),
                    bound: None,
                }
            }
        };
        let local_micros = timer.elapsed().as_micros() as u32;
        match self.protocol {
            ConsensusProtocol::Exact => {
                self.phase = Phase::AwaitingExact {
                    step,
                    local,
                    local_micros,
                }
            }
            ConsensusProtocol::Average => {
                let round = Round {
                    step,
                    round: 1,
                    value: pack(&local.contribution),
                    deadline: now + self.round_timeout,
                    local,
                    local_micros,
                    consensus_started: Instant::now(),
                    first_round_done: None,
                    live_neighbours: 0,
                };
                self.send_round(&round, out);
                self.phase = Phase::Consensus(round);
                self.try_complete_round(now, out);
            }
        }
    }

    fn live_neighbours(&self) -> Vec<u16> {
        self.topology.neighbours[self.index as usize]
            .iter()
            .copied()
            .filter(|m| self.alive[*m as usize])
            .collect()
    }

    fn send_round(&self, r: &Round, out: &mut Vec<Outgoing>) {
        let receivers: Vec<ActorId> = self
            .live_neighbours()
            .into_iter()
            .map(ActorId::Node)
            .collect();
        let v = &r.value;
        let values = ConsensusValues {
            delta_eta: v[..4].try_into().expect("4"),
            delta_lambda: v[4..14].try_into().expect("10"),
            delta_l: v[14..24].try_into().expect("10"),
        };
        out.push(Outgoing {
            channel: Channel::Consensus(self.index),
            message: Message::new(self.id(), r.step, r.round, Payload::Consensus(values)),
            receivers: receivers.clone(),
            wake: None,
        });
        if self.with_aux {
            out.push(Outgoing {
                channel: Channel::Consensus(self.index),
                message: Message::new(
                    self.id(),
                    r.step,
                    r.round,
                    Payload::ConsensusAux {
                        s_obs: v[24..].try_into().expect("10"),
                    },
                ),
                receivers,
                wake: None,
            });
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn hear(
        &mut self,
        step: u32,
        round: u16,
        from: u16,
        main: Option<[f64; 24]>,
        aux: Option<Packed>,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        if !self.topology.neighbours[self.index as usize].contains(&from)
            || round == 0
            || round > self.rounds
        {
            self.late_messages += 1;
            return;
        }
        let stale = match &self.phase {
            Phase::Consensus(r) => step < r.step || (step == r.step && round < r.round),
            Phase::Collecting { step: s, .. } | Phase::AwaitingExact { step: s, .. } => step < *s,
            Phase::Idle => false,
        };
        if stale {
            self.late_messages += 1;
            return;
        }
        match self
            .heard
            .iter_mut()
            .find(|h| h.step == step && h.round == round && h.from == from)
        {
            Some(h) => {
                h.main = h.main.or(main);
                h.aux = h.aux.or(aux);
            }
            None => self.heard.push(Heard {
                step,
                round,
                from,
                main,
                aux,
            }),
        }
        self.try_complete_round(now, out);
    }

    fn is_complete(&self, h: &Heard) -> bool {
        h.main.is_some() && (!self.with_aux || h.aux.is_some())
    }

    /// Completes the current round if every live neighbour has been heard.
    fn try_complete_round(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Phase::Consensus(r) = &self.phase else {
            return;
        };
        let all_heard = self.live_neighbours().iter().all(|m| {
            self.heard.iter().any(|h| {
                h.step == r.step && h.round == r.round && h.from == *m && self.is_complete(h)
            })
        });
        if all_heard {
            self.complete_round(now, out);
        }
    }

    /// `v ← W_ll v + Σ W_lm v_m` over the neighbours heard this round, with
    /// Metropolis weights recomputed over them.
    fn complete_round(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Phase::Consensus(mut r) = std::mem::replace(&mut self.phase, Phase::Idle) else {
            return;
        };
        let mut present = self.alive.clone();
        let mut values: Vec<(u16, Values)> = Vec::new();
        for m in self.live_neighbours() {
            match self.heard.iter().find(|h| {
                h.step == r.step && h.round == r.round && h.from == m && self.is_complete(h)
            }) {
                Some(h) => {
                    let mut v = [0.0; 34];
                    v[..24].copy_from_slice(&h.main.expect("complete"));
                    if let Some(a) = h.aux {
                        v[24..].copy_from_slice(&a);
                    }
                    values.push((m, v));
                }
                None => present[m as usize] = false,
            }
        }
        let weights = self.topology.metropolis_weights(self.index, &present);
        let mut next = r.value.map(|x| x * weights.own);
        for (m, w) in &weights.neighbours {
            let v = &values
                .iter()
                .find(|(n, _)| n == m)
                .expect("weights only over heard neighbours")
                .1;
            for (a, b) in next.iter_mut().zip(v) {
                *a += w * b;
            }
        }
        self.heard
            .retain(|h| !(h.step == r.step && h.round == r.round));
        r.value = next;
        r.live_neighbours = values.len() as u16;
        if r.round == 1 {
            r.first_round_done = Some(Instant::now());
        }
        if r.round < self.rounds {
            r.round += 1;
            r.deadline = now + self.round_timeout;
            self.send_round(&r, out);
            self.phase = Phase::Consensus(r);
            self.try_complete_round(now, out);
        } else {
            let component = self.topology.component_size(self.index, &self.alive).max(1) as f64;
            let sums = unpack(&r.value.map(|x| x * component));
            let timing = ConsensusTiming {
                total_micros: r.consensus_started.elapsed().as_micros() as u32,
                later_rounds_micros: r
                    .first_round_done
                    .map_or(0, |t| t.elapsed().as_micros() as u32),
            };
            self.finish_step(
                r.step,
                &r.local,
                &sums,
                r.local_micros,
                timing,
                self.rounds,
                r.live_neighbours,
                out,
            );
        }
    }

    /// Checking mode: this step's contribution, for the driver to sum exactly.
    pub fn pending_contribution(&self) -> Option<Contribution> {
        match &self.phase {
            Phase::AwaitingExact { local, .. } => Some(local.contribution),
            _ => None,
        }
    }

    /// Checking mode: finishes the step with the exact network sums.
    pub fn apply_exact_sums(&mut self, sums: &NetworkSums, out: &mut Vec<Outgoing>) {
        let Phase::AwaitingExact {
            step,
            local,
            local_micros,
        } = std::mem::replace(&mut self.phase, Phase::Idle)
        else {
            return;
        };
        let live = self.live_neighbours().len() as u16;
        self.finish_step(
            step,
            &local,
            sums,
            local_micros,
            ConsensusTiming::default(),
            0,
            live,
            out,
        );
    }

    #[allow(clippy::too_many_arguments)]
    fn finish_step(
        &mut self,
        step: u32,
        local: &LocalUpdate,
        sums: &NetworkSums,
        local_micros: u32,
        consensus: ConsensusTiming,
        rounds: u16,
        live: u16,
        out: &mut Vec<Outgoing>,
    ) {
        let timer = Instant::now();
        let fused = match self.fusion.step(&self.model, sums) {
            Ok(f) => Some(f),
            Err(e) => {
                tracing::error!(node = self.index, error = %e, "fusion filter step failed");
                None
            }
        };
        let fusion_micros = timer.elapsed().as_micros() as u32;
        let finite = |v: Option<f64>| v.filter(|x| x.is_finite());
        let estimate = fused.map_or(local.estimate, |f| f.estimate);
        let telemetry = Telemetry {
            estimate: std::array::from_fn(|i| {
                if estimate[i].is_finite() {
                    estimate[i]
                } else {
                    0.0
                }
            }),
            bound: finite(fused.and_then(|f| f.bound)),
            local_bound: finite(local.bound),
            aux_bound: finite(fused.and_then(|f| f.aux_bound)),
            rounds_completed: rounds,
            live_neighbours: live,
            observations: self.flags.observations,
            deadline_missed: self.flags.deadline_missed,
            late_messages: (self.late_messages - self.late_reported) as u32,
            stage_micros: [
                local_micros,
                fusion_micros,
                consensus.later_rounds_micros,
                consensus.total_micros,
            ],
        };
        self.flags = StepFlags::default();
        self.late_reported = self.late_messages;
        out.push(Outgoing {
            channel: Channel::Telemetry(self.index),
            message: Message::new(self.id(), step, 0, Payload::Telemetry(telemetry)),
            receivers: vec![ActorId::Launcher],
            wake: None,
        });
    }

    /// Runs every remaining stage at once, without waiting for anyone.
    fn force_finish(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        for _ in 0..=self.rounds as usize + 1 {
            match &self.phase {
                Phase::Idle => return,
                Phase::Collecting { .. } => self.finish_collecting(now, out),
                Phase::Consensus(_) => self.complete_round(now, out),
                Phase::AwaitingExact { local, .. } => {
                    let own = local.contribution;
                    self.apply_exact_sums(&own, out);
                }
            }
        }
    }

    fn update_membership(&mut self, alive: &[u8], out: &mut Vec<Outgoing>) {
        let before = self.alive.clone();
        for (i, a) in self.alive.iter_mut().enumerate() {
            *a = alive.get(i / 8).is_some_and(|b| b & (1 << (i % 8)) != 0);
        }
        self.alive[self.index as usize] = true;
        // A neighbour that came back gets our fused posterior to rejoin from.
        let returned: Vec<u16> = self
            .live_neighbours()
            .into_iter()
            .filter(|m| !before[*m as usize])
            .collect();
        if let (false, Some(step), false) = (returned.is_empty(), self.last_step, self.needs_state)
        {
            let p = self.fusion.posterior();
            let state = StateTransfer {
                mean: std::array::from_fn(|i| p.mean[i]),
                covariance: pack_matrix(&p.cov),
                information: pack_matrix(self.fusion.information()),
                aux_information: self.fusion.aux_information().map_or([0.0; 10], pack_matrix),
            };
            let receivers = returned.into_iter().map(ActorId::Node).collect();
            out.push(Outgoing {
                channel: Channel::Consensus(self.index),
                message: Message::new(self.id(), step, 0, Payload::StateTransfer(state)),
                receivers,
                wake: None,
            });
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
        tracing::info!(
            node = self.index,
            "rejoined from a neighbour's fused posterior"
        );
    }
}
