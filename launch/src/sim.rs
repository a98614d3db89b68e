//! The in-process driver: every actor in one process over the in-memory
//! transport, on a virtual clock, deterministic for a given seed. It runs the
//! same actor code as the multi-process runtime; it exists for Monte Carlo
//! experiments, fast tests, and the exact-sum checking mode.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use bounds::State;
use fusion_graph::faults::{FaultSchedule, ProcessEvent};
use fusion_graph::scenario::Scenario;
use fusion_graph::vocabulary::Shape;
use fusion_graph::Actor;
use fusion_graph::{link_fault_seed, ActorId, Topology};
use node::fusion::{ExactSumOracle, ExactSums};
use node::{
    processing_node, AnyNode, CentralizedReference, CfDpfNode, Outgoing, ProcessingNode, Start,
};
use sensor::mac::MacActor;
use sensor::{SensorActor, SensorInWorld};
use transport::accounting::Accounting;
use transport::world_memory::{TruthReader, TruthRing, WORLD_STEPS};
use transport::{Channel, MemoryBus, MemoryTransport, Transport};
use wire::{Message, Payload, Telemetry};

use crate::drive::{deliver, time_passes};
use crate::results::{Recorder, ResultsWriter, RunFacts, TickRow};
use crate::summary::Summary;
use crate::world::World;

/// An actor of the network with its transport. A multiple-access channel
/// is always alive: no fault stops one.
struct Slot<A> {
    actor: A,
    transport: MemoryTransport,
    /// Running: a killed or stopped (SIGSTOP) node or sensor reads nothing.
    alive: bool,
}

type SensorSlot = Slot<SensorInWorld<Rc<TruthReader>>>;
type NodeSlot = Slot<AnyNode>;

impl<A: Actor> Slot<A> {
    fn new(actor: A, transport: MemoryTransport) -> anyhow::Result<Self> {
        let mut slot = Self {
            actor,
            transport,
            alive: true,
        };
        for c in slot.actor.wiring().reads {
            slot.transport.subscribe(c)?;
        }
        Ok(slot)
    }

    /// Hands the actor everything due for it at `now`; true if anything was.
    fn pass(
        &mut self,
        now: Duration,
        inbox: &mut Vec<Message>,
        outgoing: &mut Vec<Outgoing>,
    ) -> anyhow::Result<bool> {
        inbox.clear();
        self.transport.receive(now, inbox)?;
        let progressed = !inbox.is_empty();
        for m in inbox.drain(..) {
            deliver(
                &mut self.actor,
                &mut self.transport,
                &m,
                now,
                outgoing,
                || {},
            )?;
        }
        Ok(progressed)
    }
}

pub struct InProcessNetwork {
    scenario: Scenario,
    topology: Topology,
    bus: Rc<RefCell<MemoryBus>>,
    launcher: MemoryTransport,
    sensors: Vec<SensorSlot>,
    nodes: Vec<NodeSlot>,
    macs: Vec<Slot<MacActor>>,
    central: Option<CentralizedReference>,
    world: World,
    /// The world's memory, which the launcher writes and the sensors read,
    /// here on the heap.
    truths: TruthRing,
    schedule: FaultSchedule,
    /// Accounting of actors that died, kept so their bytes still count.
    retired: Accounting,
    outgoing: Vec<Outgoing>,
    inbox: Vec<Message>,
    /// The membership view each node was last told.
    views: Vec<Vec<bool>>,
    /// The exact sums' oracle, in the checking mode.
    oracle: Option<Rc<RefCell<ExactSumOracle>>>,
}

impl InProcessNetwork {
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        centralized: bool,
    ) -> anyhow::Result<Self> {
        let format = scenario.wire_format(topology);
        let bus = MemoryBus::new();
        let transport = |actor: ActorId| {
            MemoryTransport::new(
                actor,
                bus.clone(),
                format,
                link_fault_seed(scenario.seed, actor),
            )
        };
        let mut launcher = transport(ActorId::Launcher);
        for n in 0..topology.nodes() as u16 {
            launcher.subscribe(Channel::Telemetry(n))?;
        }
        if centralized {
            for s in 0..topology.sensors() as u16 {
                launcher.subscribe(Channel::Observation(s))?;
            }
        }
        let schedule = FaultSchedule::new(&scenario.faults);
        let (truths, sensors_see) = TruthRing::on_heap(WORLD_STEPS);
        let sensors_see = Rc::new(sensors_see);
        let mut sensors = Vec::new();
        for i in 0..topology.sensors() as u16 {
            let actor =
                SensorActor::new(scenario, topology, i)?.in_world(sensors_see.clone(), centralized);
            let mut slot = Slot::new(actor, transport(ActorId::Sensor(i)))?;
            schedule.follow_link_faults(slot.transport.me(), slot.transport.shaper(), topology);
            sensors.push(slot);
        }
        let oracle =
            (scenario.consensus.protocol.shape() == Shape::ExactSums).then(ExactSumOracle::shared);
        let mut nodes = Vec::new();
        for i in 0..topology.nodes() as u16 {
            nodes.push(Self::make_node(
                scenario,
                topology,
                &bus,
                oracle.as_ref(),
                i,
                false,
            )?);
        }
        let mut macs = Vec::new();
        for i in 0..topology.mac_count() as u16 {
            let Some(actor) = MacActor::new(scenario, topology, i)? else {
                break;
            };
            let mut slot = Slot::new(actor, transport(ActorId::Mac(i)))?;
            schedule.follow_link_faults(slot.transport.me(), slot.transport.shaper(), topology);
            macs.push(slot);
        }
        let central = centralized
            .then(|| CentralizedReference::new(scenario, topology))
            .transpose()
            .context("centralized reference")?;
        Ok(Self {
            scenario: scenario.clone(),
            topology: topology.clone(),
            bus,
            launcher,
            sensors,
            nodes,
            macs,
            central,
            world: World::new(scenario)?,
            truths,
            schedule,
            retired: Accounting::default(),
            outgoing: Vec::new(),
            inbox: Vec::new(),
            views: Vec::new(),
            oracle,
        })
    }

    /// Node `i`, started at the run's start or, `rejoin`, mid-run; with
    /// the exact-sum oracle in the checking mode.
    fn make_node(
        scenario: &Scenario,
        topology: &Topology,
        bus: &Rc<RefCell<MemoryBus>>,
        oracle: Option<&Rc<RefCell<ExactSumOracle>>>,
        i: u16,
        rejoin: bool,
    ) -> anyhow::Result<NodeSlot> {
        let start = Start {
            rejoin,
            step_period: None,
        };
        let actor = match oracle {
            None => processing_node(scenario, topology, i, start),
            Some(oracle) => CfDpfNode::with_parts(
                scenario,
                topology,
                i,
                node::parts::manager(scenario, topology, i)?,
                Box::new(ExactSums::new(
                    i,
                    topology,
                    oracle.clone(),
                    Duration::from_secs_f64(scenario.consensus.round_timeout_ms / 1e3),
                )),
            )
            .map(|n| Box::new(ProcessingNode::new(n.starting(start))) as AnyNode),
        }
        .with_context(|| format!("node-{i}"))?;
        let transport = MemoryTransport::new(
            ActorId::Node(i),
            bus.clone(),
            scenario.wire_format(topology),
            link_fault_seed(scenario.seed, ActorId::Node(i)),
        );
        Slot::new(actor, transport)
    }

    /// Every byte counted by every actor, living or dead.
    pub fn accounting(&self) -> Accounting {
        let mut a = self.retired.clone();
        a.merge(self.launcher.accounting());
        for s in &self.sensors {
            a.merge(s.transport.accounting());
        }
        for n in &self.nodes {
            a.merge(n.transport.accounting());
        }
        for m in &self.macs {
            a.merge(m.transport.accounting());
        }
        a
    }

    /// Each node's membership view at `step` (see `FaultSchedule::membership_views`).
    fn membership_views(&self, step: u32) -> Vec<Vec<bool>> {
        let alive: Vec<bool> = self.nodes.iter().map(|n| n.alive).collect();
        self.schedule.membership_views(step, &self.topology, &alive)
    }

    /// Applies the kills and restarts due at `step`; true if membership changed.
    fn apply_process_faults(&mut self, step: u32) -> anyhow::Result<bool> {
        let mut changed = false;
        for event in self.schedule.process_events(step) {
            match event {
                ProcessEvent::Kill {
                    actor: ActorId::Node(i),
                    ..
                } => {
                    let slot = &mut self.nodes[i as usize];
                    slot.alive = false;
                    changed = true;
                }
                ProcessEvent::Restart {
                    actor: ActorId::Node(i),
                    signal,
                } => {
                    if signal == fusion_graph::scenario::Signal::Stop {
                        // SIGCONT: the same process resumes with its old state.
                        self.nodes[i as usize].alive = true;
                    } else {
                        self.retired
                            .merge(self.nodes[i as usize].transport.accounting());
                        self.bus.borrow_mut().clear_inbox(ActorId::Node(i));
                        self.nodes[i as usize] = Self::make_node(
                            &self.scenario,
                            &self.topology,
                            &self.bus,
                            self.oracle.as_ref(),
                            i,
                            true,
                        )?;
                    }
                    changed = true;
                }
                ProcessEvent::Kill {
                    actor: ActorId::Sensor(i),
                    ..
                } => self.sensors[i as usize].alive = false,
                ProcessEvent::Restart {
                    actor: ActorId::Sensor(i),
                    signal,
                } => {
                    // A killed sensor's successor starts with an empty queue;
                    // a stopped one reads what queued while it was stopped.
                    if signal != fusion_graph::scenario::Signal::Stop {
                        self.bus.borrow_mut().clear_inbox(ActorId::Sensor(i));
                    }
                    self.sensors[i as usize].alive = true;
                }
                _ => {}
            }
        }
        Ok(changed)
    }

    /// The nodes' link faults of `step`, as `BeginStep` puts them in place
    /// in `run`. Sensors and channels take each message under its own
    /// step's (`FaultSchedule::follow_link_faults`), as they do there.
    fn apply_link_faults(&mut self, step: u32) {
        for n in &mut self.nodes {
            self.schedule.apply_link_faults(
                step,
                n.transport.me(),
                n.transport.shaper(),
                &self.topology,
            );
        }
    }

    /// Runs one step on the virtual clock; returns the telemetry rows.
    pub fn step(&mut self, step: u32) -> anyhow::Result<Vec<TickRow>> {
        let period = Duration::from_secs_f64(self.scenario.clock.step_period_ms / 1e3);
        let start = period * (step - 1);
        self.bus.borrow_mut().set_now(start);
        let process_faults = self.apply_process_faults(step)?;
        self.apply_link_faults(step);
        let views = self.membership_views(step);
        let truth = self.world.advance();
        crate::world::begin_step(
            &mut self.launcher,
            &self.truths,
            step,
            &truth,
            &views,
            &self.views,
            process_faults,
        )?;
        self.views = views;
        let mut telemetry: Vec<(u16, Telemetry)> = Vec::new();
        let deadline = start + Duration::from_secs_f64(self.scenario.clock.step_timeout_ms / 1e3);
        let mut now = start;
        loop {
            let progressed = self.deliver_all(now, step, &mut telemetry)?;
            if progressed {
                continue;
            }
            let live = self.nodes.iter().filter(|n| n.alive).count();
            if telemetry.len() >= live {
                break;
            }
            // Nothing moves: jump the clock to the next deadline or held message.
            let next = self.next_event_time();
            match next {
                Some(t) if t <= deadline => {
                    now = now.max(t);
                    self.bus.borrow_mut().set_now(now);
                    let out = &mut self.outgoing;
                    for n in self.nodes.iter_mut().filter(|n| n.alive) {
                        time_passes(&mut n.actor, &mut n.transport, now, out, || {})?;
                    }
                    for m in &mut self.macs {
                        time_passes(&mut m.actor, &mut m.transport, now, out, || {})?;
                    }
                }
                _ => break,
            }
        }

        let mut rows: Vec<TickRow> = telemetry
            .into_iter()
            .map(|(n, t)| TickRow {
                step,
                node: format!("node-{n}"),
                truth: truth.into(),
                telemetry: t,
            })
            .collect();
        rows.sort_by(|a, b| a.node.cmp(&b.node));
        if let Some(update) = self.central.as_mut().and_then(|c| c.finish_step()) {
            rows.push(TickRow {
                step,
                node: "central".into(),
                truth: truth.into(),
                telemetry: central_telemetry(update.estimate, update.bound),
            });
        }
        Ok(rows)
    }

    fn next_event_time(&mut self) -> Option<Duration> {
        let mut next: Option<Duration> = None;
        let mut consider = |t: Option<Duration>| {
            if let Some(t) = t {
                next = Some(next.map_or(t, |n: Duration| n.min(t)));
            }
        };
        for n in self.nodes.iter_mut().filter(|n| n.alive) {
            consider(n.actor.poll_timeout());
            consider(n.transport.shaper().next_due());
        }
        for s in self.sensors.iter_mut().filter(|s| s.alive) {
            consider(s.transport.shaper().next_due());
        }
        for m in &mut self.macs {
            consider(m.actor.poll_timeout());
            consider(m.transport.shaper().next_due());
        }
        next
    }

    /// One pass over every actor: receive, handle, send. True if anything moved.
    fn deliver_all(
        &mut self,
        now: Duration,
        step: u32,
        telemetry: &mut Vec<(u16, Telemetry)>,
    ) -> anyhow::Result<bool> {
        let mut progressed = false;
        let (inbox, out) = (&mut self.inbox, &mut self.outgoing);
        // A stopped sensor reads nothing until it continues; a dead one's
        // queue is cleared when its successor starts.
        for s in self.sensors.iter_mut().filter(|s| s.alive) {
            progressed |= s.pass(now, inbox, out)?;
        }
        for mac in &mut self.macs {
            progressed |= mac.pass(now, inbox, out)?;
        }
        // A node that is down loses what reaches it meanwhile.
        for n in self.nodes.iter_mut() {
            if n.alive {
                progressed |= n.pass(now, inbox, out)?;
            } else {
                inbox.clear();
                n.transport.receive(now, inbox)?;
            }
        }
        self.inbox.clear();
        self.launcher.receive(now, &mut self.inbox)?;
        for m in self.inbox.drain(..) {
            progressed = true;
            match (&m.payload, m.header.sender) {
                (Payload::Telemetry(t), ActorId::Node(n)) if m.header.step == step => {
                    telemetry.push((n, t.clone()))
                }
                (Payload::Observation { .. } | Payload::RawObservation { .. }, _) => {
                    if let Some(c) = self.central.as_mut() {
                        c.observe(&m);
                    }
                }
                _ => {}
            }
        }
        Ok(progressed)
    }
}

/// The centralized reference's step as a telemetry row.
pub fn central_telemetry(estimate: State, bound: Option<f64>) -> Telemetry {
    Telemetry {
        bound,
        ..Telemetry::of_estimate(estimate.into())
    }
}

/// Runs a whole scenario in one process and writes its results to `writer`.
pub fn run_in_process(
    scenario: &Scenario,
    topology: &Topology,
    writer: &mut ResultsWriter,
    centralized: bool,
    on_step: impl FnMut(u32, &[TickRow]),
) -> anyhow::Result<Summary> {
    run_in_process_until(
        scenario,
        topology,
        writer,
        centralized,
        on_step,
        &AtomicBool::new(false),
    )
}

/// [`run_in_process`] that a caller can stop between steps by setting
/// `stop`: the steps done so far are written, and it fails saying where
/// it stopped.
pub fn run_in_process_until(
    scenario: &Scenario,
    topology: &Topology,
    writer: &mut ResultsWriter,
    centralized: bool,
    mut on_step: impl FnMut(u32, &[TickRow]),
    stop: &AtomicBool,
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    node::parts::check(scenario, topology)?;
    let mut net = InProcessNetwork::new(scenario, topology, centralized)?;
    let dir = writer.dir().to_path_buf();
    let mut recorder = Recorder::new(writer, scenario, topology);
    for step in 1..=scenario.steps {
        if stop.load(Ordering::Relaxed) {
            anyhow::bail!(
                "interrupted at step {}; results so far are in {}",
                step - 1,
                dir.display()
            );
        }
        let rows = net.step(step)?;
        on_step(step, &rows);
        recorder.record(rows)?;
    }
    let wall = started.elapsed().as_secs_f64();
    recorder.finish(
        &net.accounting(),
        RunFacts {
            command: "sim".into(),
            run_id: format!("sim-seed-{}", scenario.seed),
            steps_done: scenario.steps,
            wall_seconds: wall,
            steps_per_second: scenario.steps as f64 / wall,
            processes: 1,
            startup_seconds: None,
            children_memory_kb: None,
            children_cpu: None,
            real_time_rounds: false,
            unscheduled_faults: Vec::new(),
        },
    )
}
