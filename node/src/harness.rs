//! A virtual-clock network of a few nodes for the node's unit tests, in the
//! manner of quinn-proto's `Pair`: the harness plays the launcher and the
//! sensors, carries every message with a latency it chooses (or drops it),
//! runs the nodes' work, and jumps the clock to the next delivery or timeout.

use std::time::Duration;

use bounds::State;
use fusion_graph::{stream_rng, ActorId, Scenario, Stream, Topology};
use wire::{BitMask, Control, Message, Payload, Telemetry};

use crate::{processing_node, Actor, AnyNode, Outgoing, SensingModel, Start};

/// Three nodes in a line (0 — 1 — 2), three sensors each, 300 particles.
pub const LINE: &str = r#"
name = "line"
seed = 5
steps = 20
[region]
width = 1500.0
height = 500.0
[nodes]
positions = [[250.0, 250.0], [750.0, 250.0], [1250.0, 250.0]]
[sensors]
positions = [[100.0, 100.0], [250.0, 400.0], [400.0, 100.0], [600.0, 100.0], [750.0, 400.0], [900.0, 100.0], [1100.0, 100.0], [1250.0, 400.0], [1400.0, 100.0]]
active_per_node = 3
[fusion_graph]
radius = 550.0
[target]
position = [700.0, 200.0]
course_deg = 90.0
speed = 10.0
[dynamics]
period = 1.0
maneuver_accel = 0.0
sigma_v = 0.05
[observation]
kind = "bearing"
sigma_theta = 0.02
d0 = 500.0
[quantizer]
bits = 8
[filter]
particles = 300
prior_std = [20.0, 20.0, 2.0, 2.0]
[consensus]
rounds = 6
protocol = "average"
round_timeout_ms = 50.0
[clock]
mode = "lockstep"
step_period_ms = 100.0
step_timeout_ms = 2000.0
"#;

/// What the harness does with one message on its way to `to`.
pub enum Fate {
    Deliver,
    Delay(Duration),
    Drop,
}

type Rule = Box<dyn FnMut(&Message, ActorId) -> Fate>;

pub struct Net {
    pub scenario: Scenario,
    pub topology: Topology,
    pub nodes: Vec<Option<AnyNode>>,
    pub now: Duration,
    model: SensingModel,
    truth: State,
    /// (due, to, message), in the order sent.
    in_flight: Vec<(Duration, ActorId, Message)>,
    pub telemetry: Vec<(u16, u32, Telemetry)>,
    /// Every node-to-node message sent, with its receivers.
    pub sent: Vec<Outgoing>,
    /// (node, step, sensors activated), in the order sent.
    pub activations: Vec<(u16, u32, Vec<u16>)>,
    rule: Rule,
}

impl Net {
    pub fn line() -> Self {
        Self::line_with(&[])
    }

    /// The line with `--set`-style overrides (`sensors.manager=pcrlb`).
    pub fn line_with(overrides: &[&str]) -> Self {
        Self::of(LINE, overrides)
    }

    /// The random-exchange paper's lattice of 25 nodes, with overrides.
    pub fn random_exchange_with(overrides: &[&str]) -> Self {
        Self::of(fusion_graph::scenario::RANDOM_EXCHANGE_SCENARIO, overrides)
    }

    /// The network a scenario describes, its nodes as the scenario says.
    fn of(text: &str, overrides: &[&str]) -> Self {
        let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
        let scenario = Scenario::from_toml(text, "harness", &overrides).unwrap();
        let topology = Topology::from_scenario(&scenario, "harness").unwrap();
        let nodes = (0..topology.nodes() as u16)
            .map(|i| Some(processing_node(&scenario, &topology, i, Start::default()).unwrap()))
            .collect();
        Self {
            model: SensingModel::from_scenario(&scenario, &topology).unwrap(),
            truth: scenario.true_initial_state(),
            scenario,
            topology,
            nodes,
            now: Duration::ZERO,
            in_flight: Vec::new(),
            telemetry: Vec::new(),
            sent: Vec::new(),
            activations: Vec::new(),
            rule: Box::new(|_, _| Fate::Deliver),
        }
    }

    /// Builds every node afresh, started as `start` says.
    pub fn start_nodes(&mut self, start: Start) {
        for (i, n) in self.nodes.iter_mut().enumerate() {
            *n = Some(processing_node(&self.scenario, &self.topology, i as u16, start).unwrap());
        }
    }

    /// Decides each message's fate from now on.
    pub fn set_rule(&mut self, rule: impl FnMut(&Message, ActorId) -> Fate + 'static) {
        self.rule = Box::new(rule);
    }

    /// Starts `step` at every live node, telling each the membership `view`.
    /// The target moves at constant velocity.
    pub fn begin_step(&mut self, step: u32, view: &[bool]) {
        let period = self.scenario.dynamics.period;
        self.truth += State::new(self.truth[2] * period, self.truth[3] * period, 0.0, 0.0);
        for n in 0..self.nodes.len() as u16 {
            if self.nodes[n as usize].is_none() || !view[n as usize] {
                continue;
            }
            for payload in [
                Payload::Control(Control::Membership {
                    alive: BitMask::from_bools(view),
                }),
                Payload::Control(Control::BeginStep),
            ] {
                self.post(
                    ActorId::Node(n),
                    Message::new(ActorId::Launcher, step, 0, payload),
                );
            }
        }
    }

    /// Runs until nothing is in flight and no node waits for a timeout, or
    /// `limit` of virtual time has passed.
    pub fn run(&mut self, limit: Duration) {
        let end = self.now + limit;
        loop {
            if let Some(i) = (0..self.in_flight.len())
                .filter(|i| self.in_flight[*i].0 <= self.now)
                .min_by_key(|i| self.in_flight[*i].0)
            {
                let (_, to, m) = self.in_flight.remove(i);
                self.deliver(to, m);
                continue;
            }
            let next_delivery = self.in_flight.iter().map(|f| f.0).min();
            let next_timeout = self
                .nodes
                .iter()
                .flatten()
                .filter_map(|n| n.poll_timeout())
                .min();
            let Some(next) = [next_delivery, next_timeout].into_iter().flatten().min() else {
                return;
            };
            if next > end {
                return;
            }
            self.now = self.now.max(next);
            if next_delivery.is_none_or(|d| d > self.now) {
                for i in 0..self.nodes.len() {
                    let mut out = Vec::new();
                    if let Some(n) = self.nodes[i].as_mut() {
                        n.handle_timeout(self.now, &mut out);
                    }
                    self.after(i, out);
                }
            }
        }
    }

    fn deliver(&mut self, to: ActorId, m: Message) {
        let ActorId::Node(i) = to else {
            return;
        };
        let mut out = Vec::new();
        if let Some(n) = self.nodes[i as usize].as_mut() {
            n.handle(&m, self.now, &mut out);
        }
        self.after(i as usize, out);
    }

    /// Runs node `i`'s work (untimed), then routes what it sent.
    fn after(&mut self, i: usize, mut out: Vec<Outgoing>) {
        if let Some(n) = self.nodes[i].as_mut() {
            while let Some(work) = n.poll_work() {
                n.run_work(work);
                n.work_done(work, Duration::ZERO, self.now, &mut out);
            }
        }
        for o in out {
            match &o.message.payload {
                Payload::Telemetry(t) => {
                    self.telemetry
                        .push((i as u16, o.message.header.step, t.clone()))
                }
                // The harness's sensors always send: censoring is tested
                // with the real sensor actors, in `sim`. The same activation
                // goes to each active sensor on its own channel: the step's
                // first copy stands for them all.
                Payload::Activate { mask } | Payload::ActivateWithFeedback { mask, .. } => {
                    let step = o.message.header.step;
                    if self
                        .activations
                        .iter()
                        .any(|a| a.0 == i as u16 && a.1 == step)
                    {
                        continue;
                    }
                    let own = &self.topology.node_sensors[i];
                    let active = (0..own.len())
                        .filter(|k| mask.contains(*k))
                        .map(|k| own[k])
                        .collect();
                    self.activations
                        .push((i as u16, o.message.header.step, active));
                    self.sense(i as u16, o.message.header.step, mask)
                }
                _ => {
                    for to in &o.receivers {
                        self.post(*to, o.message.clone());
                    }
                    self.sent.push(o);
                }
            }
        }
    }

    /// The active sensors of node `n` measure the truth and report.
    fn sense(&mut self, n: u16, step: u32, mask: &BitMask) {
        let own = self.topology.node_sensors[n as usize].clone();
        for (_, s) in own
            .iter()
            .enumerate()
            .filter(|(slot, _)| mask.contains(*slot))
        {
            let mut rng = stream_rng(
                self.scenario.seed,
                ActorId::Sensor(*s),
                step,
                Stream::SensorNoise,
            );
            let z = self.model.sensors[*s as usize].sample(&self.truth, &mut rng);
            let payload = match &self.model.quantizer {
                Some(q) => Payload::Observation { cell: q.encode(z) },
                None => Payload::RawObservation { value: z },
            };
            let m = Message::new(ActorId::Sensor(*s), step, 0, payload);
            self.post(ActorId::Node(n), m);
        }
    }

    /// Sends `m` to `to` through the harness's rule, now.
    pub fn post(&mut self, to: ActorId, m: Message) {
        match (self.rule)(&m, to) {
            Fate::Deliver => self.in_flight.push((self.now, to, m)),
            Fate::Delay(d) => self.in_flight.push((self.now + d, to, m)),
            Fate::Drop => {}
        }
    }

    /// The target's true state now.
    pub fn truth(&self) -> State {
        self.truth
    }

    /// Node `n`'s telemetry for `step`.
    pub fn report(&self, n: u16, step: u32) -> Option<&Telemetry> {
        self.telemetry
            .iter()
            .find(|(m, s, _)| *m == n && *s == step)
            .map(|(_, _, t)| t)
    }
}
