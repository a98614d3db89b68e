//! `cqnet run`: the launcher's side of a multi-process network. The world
//! thread owns the launcher's iceoryx2 ports (they are not `Send`): it ticks
//! the world, applies the fault schedule, collects telemetry and the
//! centralized reference, and writes results. The supervisor (tokio, on the
//! main thread) owns the processes.

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use fusion_graph::accounting::read_ledger;
use fusion_graph::accounting::Accounting;
use fusion_graph::faults::{FaultSchedule, ProcessEvent};
use fusion_graph::hosts::Placement;
use fusion_graph::ledger::LedgerError;
use fusion_graph::registered::Shape;
use fusion_graph::scenario::{ClockMode, Scenario, Signal};
use fusion_graph::transport::iceoryx::{remove_run_resources, sweep_abandoned_runs, RunLease};
use fusion_graph::transport::{Channel, IceoryxTransport, RunId, Transport};
use fusion_graph::wire::{Control, Message, Payload};
use fusion_graph::{link_fault_seed, ActorId, Topology};
use node::CentralizedReference;
use tokio::sync::mpsc::UnboundedSender;

use crate::actor_process::{ledger_path, memory_path, stop_message};
use crate::feed::{link_bytes_per_step, setup_event, step_event, Hub, NodeEstimate, ViewEvent};
use crate::results::{write_atomically, Recorder, ResultsWriter, RunFacts, TickRow};
use crate::sim::central_telemetry;
use crate::summary::{AppliedFault, ChildrenMemory, Summary};
use crate::supervisor::{supervise, ChildSpec, Command, Event};
use crate::world::World;

/// How long children get to start and say `ready`.
const START_TIMEOUT: Duration = Duration::from_secs(120);

pub struct RunOptions {
    pub out: PathBuf,
    pub lockstep: bool,
    pub run_id: RunId,
    pub centralized: bool,
    /// Where to publish the live view's events, if it is served.
    pub view: Option<Arc<Hub>>,
    /// A scenario with `[[hosts]]`: start every host's agent here.
    pub local_agents: bool,
}

/// What the launcher tells its caller as the run goes.
pub enum RunProgress<'a> {
    /// `ready` of the `of` processes have started and said so.
    Starting { ready: usize, of: usize },
    /// Every process is up; the steps begin.
    Running,
    /// A step is over, with the reports that came in time for it.
    Step { step: u32, rows: &'a [TickRow] },
}

/// Runs the network: spawns every actor, runs the steps, stops and reaps
/// every child and removes the run's shared memory, pass or fail.
pub fn run_network(
    scenario: &Scenario,
    topology: &Topology,
    options: RunOptions,
    mut progress: impl FnMut(RunProgress<'_>) + Send + 'static,
) -> anyhow::Result<Summary> {
    if scenario.consensus.protocol.shape() == Shape::ExactSums {
        bail!("consensus.protocol = \"exact\" is a checking mode of `cqnet sim` only: real processes have no exact network sum");
    }
    node::registry::check(scenario, topology)?;
    crate::preflight::check(scenario, topology, options.centralized)?;
    // Runs whose launcher was SIGKILLed left their shared memory behind:
    // clear those (and only those) before adding ours.
    match sweep_abandoned_runs() {
        Ok(runs) if !runs.is_empty() => tracing::warn!(
            runs = runs.len(),
            "removed the shared memory of runs whose launcher is gone"
        ),
        Ok(_) => {}
        Err(e) => tracing::warn!(error = %e, "could not sweep abandoned runs"),
    }
    if let Err(e) = fusion_graph::transport::iceoryx::remove_stale_node_directories() {
        tracing::warn!(error = %e, "could not remove empty iceoryx2 node directories");
    }
    // Without a lease (a registry another user owns, say) the run still
    // goes; only `cqnet clean` could not find it after a SIGKILL.
    let _lease = RunLease::acquire(&options.run_id)
        .map_err(|e| tracing::warn!(error = %e, "could not register the run for `cqnet clean`"))
        .ok();
    std::fs::create_dir_all(options.out.join("logs"))?;
    // Ledgers continue what they find (a restarted actor's predecessor's
    // counts): an earlier run's in the same directory must not be found.
    match std::fs::remove_dir_all(options.out.join("accounting")) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).context("clearing the previous run's accounting");
        }
        _ => {}
    }
    std::fs::create_dir_all(options.out.join("accounting"))?;
    let scenario_file = options.out.join("scenario.toml");
    write_atomically(&scenario_file, scenario.to_toml().as_bytes())?;
    let placement = Placement::from_scenario(scenario, topology, "", options.centralized)?;
    if placement.is_some() && !cfg!(feature = "zenoh") {
        bail!(
            "this scenario has [[hosts]]: several hosts need cqnet built with `--features zenoh`"
        );
    }
    if placement.is_none() && options.local_agents {
        bail!("--local-agents: the scenario has no [[hosts]] to start agents for");
    }
    let spec = ChildSpec {
        executable: std::env::current_exe().context("finding the cqnet executable")?,
        run_id: options.run_id.as_str().to_string(),
        scenario_file,
        log_dir: options.out.join("logs"),
        centralized: options.centralized,
    };
    let (command_tx, command_rx) = tokio::sync::mpsc::unbounded_channel();
    let (event_tx, event_rx) = std::sync::mpsc::channel();
    let options_local_agents = options.local_agents;
    #[cfg_attr(not(feature = "zenoh"), allow(unused_variables))]
    let out = options.out.clone();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;

    let world_scenario = scenario.clone();
    let world_topology = topology.clone();
    let run_id = options.run_id.clone();
    let world_placement = placement.clone();
    let world = std::thread::Builder::new()
        .name("world".into())
        .spawn(move || {
            let result = world_thread(
                &world_scenario,
                &world_topology,
                world_placement.as_ref(),
                &options,
                &command_tx,
                &event_rx,
                &mut progress,
            );
            // Whatever happened, every child is told to go and is reaped.
            let _ = command_tx.send(Command::Shutdown);
            let reaped = wait_for(&event_rx, Duration::from_secs(30), |e| {
                matches!(e, Event::AllReaped)
            });
            (result, reaped)
        })
        .context("starting the world thread")?;
    // Children are spawned from this (the main) thread, which lives until
    // they are all reaped: their parent-death signal is tied to it.
    match &placement {
        None => runtime.block_on(supervise(spec, command_rx, event_tx)),
        #[cfg(feature = "zenoh")]
        Some(placement) => {
            let hosts = crate::hosts::remote::HostsRun {
                placement: placement.clone(),
                topology: topology.clone(),
                run: run_id.as_str().into(),
                scenario: scenario.to_toml(),
                centralized: spec.centralized,
            };
            let agents = options_local_agents
                .then(|| {
                    crate::hosts::remote::LocalAgents::start(placement, &spec.scenario_file, &out)
                })
                .transpose()?;
            let supervised =
                crate::hosts::remote::supervise_hosts(hosts, command_rx, event_tx.clone());
            if let Err(e) = &supervised {
                tracing::error!(error = %format!("{e:#}"), "could not reach the hosts");
                let _ = event_tx.send(Event::AllReaped);
            }
            if let Some(agents) = agents {
                agents.reap(Duration::from_secs(10));
            }
        }
        #[cfg(not(feature = "zenoh"))]
        Some(_) => unreachable!("refused above"),
    }
    let (result, _) = world
        .join()
        .map_err(|_| anyhow::anyhow!("the world thread panicked"))?;
    // On several hosts, the launcher's host's domain holds the launcher's
    // own ports, so its agent leaves it to us; local agents' domains are on
    // this machine too, and removed whatever became of their agents.
    let domains: Vec<RunId> = match &placement {
        None => vec![run_id.clone()],
        Some(p) => (0..p.hosts().len())
            .filter(|h| *h == p.host_of(ActorId::Launcher) || options_local_agents)
            .map(|h| p.domain(&run_id, h))
            .collect(),
    };
    for domain in &domains {
        remove_run_resources(domain).context("removing the run's shared memory")?;
    }
    result
}

/// Waits until an event matches, or the timeout passes.
fn wait_for(
    events: &Receiver<Event>,
    timeout: Duration,
    mut matches: impl FnMut(&Event) -> bool,
) -> bool {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match events.recv_timeout(left) {
            Ok(e) if matches(&e) => return true,
            Ok(_) => {}
            Err(_) => return false,
        }
    }
}

struct WorldState<'a> {
    transport: IceoryxTransport,
    commands: &'a UnboundedSender<Command>,
    events: &'a Receiver<Event>,
    alive: Vec<bool>,
    sensors_alive: Vec<bool>,
    /// Actors we killed on purpose (their exit is not an error).
    expected_exits: HashSet<ActorId>,
    unexpected_exits: Vec<String>,
    /// Actors that died on their own, and the step the launcher noticed:
    /// faults of the run, and respawned (not continued) at a scheduled restart.
    crashed: Vec<(ActorId, u32, String)>,
    /// Of those, the ones not started again yet.
    dead: HashSet<ActorId>,
    /// The step being run.
    step: u32,
    interrupted: bool,
    /// The membership view each node was last told.
    views: Vec<Vec<bool>>,
    /// Actors of a lost host whose agent is back, to start again.
    returning: Vec<ActorId>,
}

/// The world thread: the launcher's network side, from spawning to results.
fn world_thread(
    scenario: &Scenario,
    topology: &Topology,
    placement: Option<&Placement>,
    options: &RunOptions,
    commands: &UnboundedSender<Command>,
    events: &Receiver<Event>,
    progress: &mut dyn FnMut(RunProgress<'_>),
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    let mut writer = ResultsWriter::create(&options.out)?;
    let mut recorder = Recorder::new(&mut writer, scenario, topology);
    let transport = launcher_transport(scenario, topology, placement, options)?;
    let mut w = WorldState::new(transport, topology, commands, events);
    let view = options.view.as_deref();
    if let Some(hub) = view {
        hub.publish(&setup_event(scenario, topology, "live"));
    }
    w.start_everyone(topology, view, progress)?;
    let startup_seconds = started.elapsed().as_secs_f64();
    let lockstep = options.lockstep || scenario.clock.mode == ClockMode::Lockstep;
    let (steps_done, wall_steps) = run_steps(
        scenario,
        topology,
        options,
        lockstep,
        &mut w,
        &mut recorder,
        progress,
    )?;
    tracing::info!(
        steps = steps_done,
        seconds = started.elapsed().as_secs_f64(),
        "steps done"
    );
    w.stop_everyone(topology, steps_done, started);
    let mut accounting = merge_accounting(&options.out, topology, w.transport.accounting());
    if let Some(p) = placement {
        let bridges = w.collect_host_counts(&mut accounting);
        write_hosts_report(&options.out, p, &accounting, &bridges)?;
    }
    let summary = recorder.finish(
        &accounting,
        RunFacts {
            command: if lockstep {
                "run --lockstep".into()
            } else {
                "run".into()
            },
            run_id: options.run_id.to_string(),
            steps_done,
            wall_seconds: started.elapsed().as_secs_f64(),
            steps_per_second: steps_done as f64 / wall_steps,
            processes: topology.nodes() + topology.sensors() + 1,
            startup_seconds: Some(startup_seconds),
            children_memory_kb: children_memory(&options.out, topology),
            real_time_rounds: true,
            unscheduled_faults: w
                .crashed
                .iter()
                .map(|(actor, step, status)| crash_fault(*actor, *step, status))
                .collect(),
        },
    )?;
    if let Some(hub) = view {
        hub.publish(&ViewEvent::End { steps: steps_done });
    }
    if w.interrupted {
        bail!(
            "interrupted at step {steps_done}; results so far are in {}",
            options.out.display()
        );
    }
    for e in &w.unexpected_exits {
        tracing::warn!("{e}");
    }
    Ok(summary)
}

/// The launcher's own ports: it creates the services everyone shares
/// before anyone else opens them. On several hosts they are in its host's
/// domain, and it wakes the actors of the others through that host's bridge.
fn launcher_transport(
    scenario: &Scenario,
    topology: &Topology,
    placement: Option<&Placement>,
    options: &RunOptions,
) -> anyhow::Result<IceoryxTransport> {
    let domain = match placement {
        Some(p) => p.domain(&options.run_id, p.host_of(ActorId::Launcher)),
        None => options.run_id.clone(),
    };
    let mut t = IceoryxTransport::new(
        &domain,
        ActorId::Launcher,
        topology,
        scenario.wire_format(topology),
        link_fault_seed(scenario.seed, ActorId::Launcher),
    )?;
    if let Some(p) = placement {
        t.place_on(p, p.host_of(ActorId::Launcher));
    }
    t.publish_on(Channel::Tick)?;
    for n in 0..topology.nodes() as u16 {
        t.publish_on(Channel::Control(ActorId::Node(n)))?;
        t.subscribe(Channel::Telemetry(n))?;
    }
    if options.centralized {
        for s in 0..topology.sensors() as u16 {
            t.subscribe(Channel::Observation(s))?;
        }
    }
    for a in topology.actors() {
        t.notify(a)?;
    }
    Ok(t)
}

/// The steps, from the first to the scenario's last or an interruption:
/// each ticks the world, applies the faults, gathers the nodes' reports
/// (and the centralized reference's observations) until every live node
/// reported (lockstep) or the step's time is up. Returns the steps done
/// and the seconds they took.
fn run_steps(
    scenario: &Scenario,
    topology: &Topology,
    options: &RunOptions,
    lockstep: bool,
    w: &mut WorldState<'_>,
    recorder: &mut Recorder<'_>,
    progress: &mut dyn FnMut(RunProgress<'_>),
) -> anyhow::Result<(u32, f64)> {
    let view = options.view.as_deref();
    let mut world = World::new(scenario)?;
    let mut reports = StepReports {
        central: options
            .centralized
            .then(|| CentralizedReference::new(scenario, topology))
            .transpose()
            .context("centralized reference")?,
        truths: BTreeMap::new(),
        inbox: Vec::new(),
        rows: Vec::new(),
        active_sensors: std::collections::BTreeSet::new(),
    };
    let schedule = FaultSchedule::new(&scenario.faults);
    let period = Duration::from_secs_f64(scenario.clock.step_period_ms / 1e3);
    let step_timeout = Duration::from_secs_f64(scenario.clock.step_timeout_ms / 1e3);
    let run_start = Instant::now();
    let mut steps_done = 0;
    let mut crashes_shown = 0;

    for step in 1..=scenario.steps {
        w.step = step;
        w.poll_events();
        let returned = w.restart_returning()?;
        let process_faults = w.apply_process_faults(&schedule, step)? || returned;
        schedule.apply_link_faults(step, &mut w.transport, topology);
        let views = schedule.membership_views(step, topology, &w.alive);
        let truth = world.advance();
        reports.remember_truth(step, truth.into());
        recorder.begin_step(step);
        crate::world::begin_step(
            &mut w.transport,
            step,
            truth,
            &w.sensors_alive,
            &views,
            &w.views,
            process_faults,
        )?;
        w.views = views;
        let step_start = Instant::now();
        let step_end = if lockstep {
            step_start + step_timeout
        } else {
            run_start + period * step
        };
        loop {
            let all_in = recorder.reports(step) >= w.alive.iter().filter(|a| **a).count();
            if (lockstep && all_in) || Instant::now() >= step_end || w.interrupted {
                break;
            }
            let left = step_end.saturating_duration_since(Instant::now());
            w.transport.wait(left.min(Duration::from_millis(50)))?;
            let rows = reports.take(&mut w.transport, step)?;
            publish_late_rows(view, &rows, step);
            reports
                .rows
                .extend(rows.iter().filter(|r| r.step == step).cloned());
            recorder.record(rows)?;
            w.poll_events();
        }
        if let Some(c) = reports.central.as_mut() {
            let update = c.finish_step().context("centralized reference")?;
            let row = TickRow {
                step,
                node: "central".into(),
                truth: truth.into(),
                telemetry: central_telemetry(update.estimate, update.bound),
            };
            reports.rows.push(row.clone());
            recorder.record(vec![row])?;
        }
        steps_done = step;
        if let Some(hub) = view {
            let dead: Vec<u16> = (0..topology.nodes() as u16)
                .filter(|n| !w.alive[*n as usize])
                .collect();
            hub.publish(&step_event(
                &schedule,
                topology,
                step,
                [truth[0], truth[1]],
                &reports.active_sensors,
                &dead,
            ));
            hub.publish(&ViewEvent::Estimates {
                step,
                rows: reports.rows.iter().map(NodeEstimate::of).collect(),
            });
            for (actor, at, status) in &w.crashed[crashes_shown..] {
                hub.publish(&ViewEvent::Fault(crash_fault(*actor, *at, status)));
            }
            crashes_shown = w.crashed.len();
        }
        progress(RunProgress::Step {
            step,
            rows: &reports.rows,
        });
        reports.rows.clear();
        reports.active_sensors.clear();
        if w.interrupted {
            break;
        }
    }
    Ok((steps_done, run_start.elapsed().as_secs_f64()))
}

/// What the launcher hears in a step: the nodes' reports, and the
/// observations the centralized reference weighs.
struct StepReports {
    central: Option<CentralizedReference>,
    /// The true state of each step still within the late-report horizon.
    truths: BTreeMap<u32, [f64; 4]>,
    inbox: Vec<Message>,
    /// This step's reports, for the progress and the view.
    rows: Vec<TickRow>,
    /// The sensors heard this step, for the view.
    active_sensors: std::collections::BTreeSet<u16>,
}

impl StepReports {
    /// Keeps `step`'s truth; reports later than the horizon are left out,
    /// so their truths go.
    fn remember_truth(&mut self, step: u32, truth: [f64; 4]) {
        self.truths.insert(step, truth);
        while let Some(oldest) = self.truths.first_entry() {
            if *oldest.key() + crate::results::LATE_ROW_HORIZON >= step {
                break;
            }
            oldest.remove();
        }
    }

    /// Takes what has arrived: the nodes' reports as rows (of this step or
    /// a late one), the observations into the centralized reference.
    fn take(
        &mut self,
        transport: &mut IceoryxTransport,
        step: u32,
    ) -> anyhow::Result<Vec<TickRow>> {
        self.inbox.clear();
        let now = transport.now();
        transport.receive(now, &mut self.inbox)?;
        let mut rows = Vec::new();
        for m in self.inbox.drain(..) {
            match (m.payload, m.header.sender) {
                (Payload::Telemetry(tel), ActorId::Node(n)) => {
                    let Some(truth) = self.truths.get(&m.header.step) else {
                        continue;
                    };
                    rows.push(TickRow {
                        step: m.header.step,
                        node: format!("node-{n}"),
                        truth: *truth,
                        telemetry: tel,
                    });
                }
                (
                    payload @ (Payload::Observation { .. } | Payload::RawObservation { .. }),
                    sender,
                ) => {
                    if let (ActorId::Sensor(s), true) = (sender, m.header.step == step) {
                        self.active_sensors.insert(s);
                    }
                    if let Some(c) = self.central.as_mut() {
                        c.observe(&Message {
                            header: m.header,
                            payload,
                        });
                    }
                }
                _ => {}
            }
        }
        Ok(rows)
    }
}

impl<'a> WorldState<'a> {
    fn new(
        transport: IceoryxTransport,
        topology: &Topology,
        commands: &'a UnboundedSender<Command>,
        events: &'a Receiver<Event>,
    ) -> Self {
        Self {
            transport,
            commands,
            events,
            alive: vec![true; topology.nodes()],
            sensors_alive: vec![true; topology.sensors()],
            expected_exits: HashSet::new(),
            unexpected_exits: Vec::new(),
            crashed: Vec::new(),
            dead: HashSet::new(),
            step: 0,
            interrupted: false,
            views: Vec::new(),
            returning: Vec::new(),
        }
    }

    /// Spawns every actor and waits until each said it is ready, showing
    /// how many are.
    fn start_everyone(
        &mut self,
        topology: &Topology,
        view: Option<&Hub>,
        progress: &mut dyn FnMut(RunProgress<'_>),
    ) -> anyhow::Result<()> {
        let started = Instant::now();
        let actors: Vec<ActorId> = topology.actors().collect();
        for a in &actors {
            self.commands.send(Command::Spawn {
                actor: *a,
                rejoin: false,
            })?;
        }
        let of = actors.len();
        self.await_ready(&actors, &mut |ready| {
            progress(RunProgress::Starting { ready, of });
            if let Some(hub) = view {
                hub.publish(&ViewEvent::Starting { ready, of });
            }
        })?;
        progress(RunProgress::Running);
        self.transport.update_connections();
        tracing::info!(
            actors = actors.len(),
            seconds = started.elapsed().as_secs_f64(),
            "every actor is ready"
        );
        Ok(())
    }

    /// Tells every actor to stop after step `last`, and waits (10 s at
    /// most) until the live ones have exited, so that their byte counts
    /// are final.
    fn stop_everyone(&mut self, topology: &Topology, last: u32, started: Instant) {
        for n in 0..topology.nodes() as u16 {
            let to = ActorId::Node(n);
            let _ = self.transport.send(
                Channel::Control(to),
                &Message::new(ActorId::Launcher, last, 0, Payload::Control(Control::Stop)),
                &[to],
            );
        }
        let sensors: Vec<ActorId> = (0..topology.sensors() as u16)
            .map(ActorId::Sensor)
            .collect();
        let _ = self
            .transport
            .send(Channel::Tick, &stop_message(last), &sensors);
        let mut exited: HashSet<ActorId> = HashSet::new();
        let live: HashSet<ActorId> = topology.actors().filter(|a| self.is_alive(*a)).collect();
        let deadline = Instant::now() + Duration::from_secs(10);
        while !live.is_subset(&exited) && Instant::now() < deadline {
            match self.events.recv_timeout(Duration::from_millis(50)) {
                Ok(Event::Exited { actor, .. }) => {
                    exited.insert(actor);
                }
                Ok(_) | Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
        }
        tracing::info!(
            exited = exited.len(),
            of = live.len(),
            seconds = started.elapsed().as_secs_f64(),
            "actors stopped"
        );
    }

    fn is_alive(&self, a: ActorId) -> bool {
        match a {
            ActorId::Node(i) => self.alive[i as usize],
            ActorId::Sensor(i) => self.sensors_alive[i as usize],
            ActorId::Launcher => true,
        }
    }

    /// Waits for every listed actor's `ready`; a child that exits first ends
    /// the run with its name and the end of its stderr.
    fn await_ready(
        &mut self,
        actors: &[ActorId],
        on_ready: &mut dyn FnMut(usize),
    ) -> anyhow::Result<()> {
        let mut waiting: HashSet<ActorId> = actors.iter().copied().collect();
        let deadline = Instant::now() + START_TIMEOUT;
        while !waiting.is_empty() {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.events.recv_timeout(left) {
                Ok(Event::Ready(a)) => {
                    waiting.remove(&a);
                    on_ready(actors.len() - waiting.len());
                }
                Ok(Event::Exited {
                    actor,
                    status,
                    stderr_tail,
                }) if waiting.contains(&actor) => {
                    bail!("{actor} exited ({status}) before it was ready; the end of its stderr:\n{stderr_tail}");
                }
                // Another actor died while a restarted one was starting: a
                // fault of the run like any other, not a failed start.
                Ok(e @ (Event::Exited { .. } | Event::HostBack(_))) => self.handle_event(e),
                Ok(Event::Counts { .. }) => {}
                Ok(Event::Interrupted) => bail!("interrupted while starting"),
                Ok(Event::AllReaped) => bail!("the supervisor stopped"),
                Err(_) => {
                    let mut late: Vec<ActorId> = waiting.into_iter().collect();
                    late.sort();
                    bail!(
                        "{} of {} actors were not ready after {:?}: {}",
                        late.len(),
                        actors.len(),
                        START_TIMEOUT,
                        name_some(&late, 10)
                    );
                }
            }
        }
        Ok(())
    }

    /// Handles exits and interrupts reported since the last call.
    fn poll_events(&mut self) {
        while let Ok(e) = self.events.try_recv() {
            self.handle_event(e);
        }
    }

    fn handle_event(&mut self, e: Event) {
        match e {
            Event::Exited {
                actor,
                status,
                stderr_tail,
            } if !self.expected_exits.contains(&actor) => {
                self.unexpected_exits.push(format!(
                    "{actor} exited unexpectedly ({status}); its stderr ended with:\n{stderr_tail}"
                ));
                self.crashed.push((actor, self.step, status));
                self.dead.insert(actor);
                self.set_alive(actor, false);
            }
            Event::Interrupted => self.interrupted = true,
            Event::HostBack(actors) => self.returning.extend(actors),
            _ => {}
        }
    }

    /// Starts again the actors of a host that came back, as a scheduled
    /// restart would: rejoining, and in the membership from this step.
    fn restart_returning(&mut self) -> anyhow::Result<bool> {
        let actors = std::mem::take(&mut self.returning);
        if actors.is_empty() {
            return Ok(false);
        }
        for a in &actors {
            self.dead.remove(a);
            self.expected_exits.remove(a);
            self.commands.send(Command::Spawn {
                actor: *a,
                rejoin: true,
            })?;
        }
        self.await_ready(&actors, &mut |_| {})?;
        self.transport.update_connections();
        for a in actors {
            self.set_alive(a, true);
        }
        Ok(true)
    }

    /// Several hosts: every host's actors' counts, merged into `total`, and
    /// each bridge's own counts.
    fn collect_host_counts(
        &mut self,
        total: &mut Accounting,
    ) -> Vec<(String, fusion_graph::hosts::BridgeCounts)> {
        if self.commands.send(Command::Collect).is_err() {
            return Vec::new();
        }
        let deadline = Instant::now() + Duration::from_secs(15);
        while Instant::now() < deadline {
            match self.events.recv_timeout(Duration::from_millis(50)) {
                Ok(Event::Counts {
                    accounting_csv,
                    bridges,
                }) => {
                    match Accounting::from_csv(&accounting_csv) {
                        Some(a) => total.merge(&a),
                        None => tracing::warn!("the hosts' byte counts did not parse"),
                    }
                    return bridges;
                }
                Ok(e) => self.handle_event(e),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
        }
        tracing::warn!("no byte counts from the hosts");
        Vec::new()
    }

    fn apply_process_faults(
        &mut self,
        schedule: &FaultSchedule,
        step: u32,
    ) -> anyhow::Result<bool> {
        let mut changed = false;
        for event in schedule.process_events(step) {
            match event {
                ProcessEvent::Kill { actor, signal } => {
                    if signal != Signal::Stop {
                        self.expected_exits.insert(actor);
                    }
                    self.commands.send(Command::Signal { actor, signal })?;
                    self.set_alive(actor, false);
                    changed = true;
                }
                ProcessEvent::Restart { actor, signal } => {
                    // A stopped actor that died meanwhile is started afresh.
                    if signal == Signal::Stop && !self.dead.remove(&actor) {
                        self.commands.send(Command::Continue { actor })?;
                    } else {
                        // The old process must be reaped before its successor
                        // opens the same services (iceoryx2 cleans up dead nodes then).
                        self.expected_exits.remove(&actor);
                        self.dead.remove(&actor);
                        self.commands.send(Command::Spawn {
                            actor,
                            rejoin: true,
                        })?;
                        self.await_ready(&[actor], &mut |_| {})?;
                        self.transport.update_connections();
                    }
                    self.set_alive(actor, true);
                    changed = true;
                }
            }
        }
        Ok(changed)
    }

    fn set_alive(&mut self, actor: ActorId, alive: bool) {
        match actor {
            ActorId::Node(i) => self.alive[i as usize] = alive,
            ActorId::Sensor(i) => self.sensors_alive[i as usize] = alive,
            ActorId::Launcher => {}
        }
    }
}

fn crash_fault(actor: ActorId, step: u32, status: &str) -> AppliedFault {
    AppliedFault::new(step, None, format!("{actor} died unexpectedly ({status})"))
}

/// Reports of earlier steps that arrived late go to the view at once.
fn publish_late_rows(view: Option<&Hub>, rows: &[TickRow], step: u32) {
    let Some(hub) = view else { return };
    let mut late: BTreeMap<u32, Vec<NodeEstimate>> = BTreeMap::new();
    for r in rows.iter().filter(|r| r.step < step) {
        late.entry(r.step).or_default().push(NodeEstimate::of(r));
    }
    for (step, rows) in late {
        hub.publish(&ViewEvent::Estimates { step, rows });
    }
}

/// The live view's once-a-second look at the link traffic: each node's
/// ledger as it stands, over the steps run so far.
pub fn traffic_poller(hub: Arc<Hub>, topology: Topology, out: PathBuf) -> crate::feed::Poll {
    Box::new(move || {
        let mut accounting = Accounting::default();
        for n in 0..topology.nodes() as u16 {
            if let Ok(acc) = read_ledger(&ledger_path(&out, ActorId::Node(n))) {
                accounting.merge(&acc);
            }
        }
        let steps = hub.latest_step().max(1) as f64;
        let bytes_per_step = link_bytes_per_step(&topology, &accounting, |_| steps);
        if bytes_per_step.iter().any(|b| *b > 0.0) {
            hub.publish(&ViewEvent::Traffic {
                step: hub.latest_step(),
                bytes_per_step,
            });
        }
    })
}

/// `hosts.json`: the bytes of cqnet's messages between hosts, by pair of
/// hosts (from the actors' own counts), and what each bridge moved and its
/// TCP sockets carried.
fn write_hosts_report(
    out: &Path,
    placement: &Placement,
    accounting: &Accounting,
    bridges: &[(String, fusion_graph::hosts::BridgeCounts)],
) -> anyhow::Result<()> {
    let mut pairs = Vec::new();
    let name = |a: ActorId| placement.hosts()[placement.host_of(a)].name.clone();
    let mut by_pair: BTreeMap<(String, String), [u64; 4]> = BTreeMap::new();
    for ((from, to, _), c) in accounting.iter() {
        if placement.crosses(*from, *to) {
            let e = by_pair.entry((name(*from), name(*to))).or_default();
            e[0] += c.sent_messages;
            e[1] += c.sent_bytes;
            e[2] += c.received_messages;
            e[3] += c.received_bytes;
        }
    }
    for ((from, to), [sm, sb, rm, rb]) in by_pair {
        pairs.push(serde_json::json!({
            "from": from, "to": to,
            "sent_messages": sm, "sent_bytes": sb,
            "received_messages": rm, "received_bytes": rb,
        }));
    }
    let report = serde_json::json!({
        "hosts": placement.hosts().iter().map(|h| serde_json::json!({
            "name": h.name, "endpoint": h.endpoint, "nodes": h.nodes,
        })).collect::<Vec<_>>(),
        "between_hosts": pairs,
        "bridges": bridges.iter().map(|(h, c)| serde_json::json!({ "host": h, "counts": c })).collect::<Vec<_>>(),
    });
    write_atomically(
        &out.join("hosts.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    Ok(())
}

/// The children's memory, as each last wrote it.
fn children_memory(out: &Path, topology: &Topology) -> Option<ChildrenMemory> {
    let read = |a| -> Option<(u64, u64)> {
        let text = std::fs::read_to_string(memory_path(out, a)).ok()?;
        let mut f = text.split_whitespace().map(|v| v.parse::<u64>().ok());
        Some((f.next()??, f.next()??))
    };
    let all: Vec<(u64, u64)> = topology.actors().filter_map(read).collect();
    (!all.is_empty()).then(|| ChildrenMemory {
        largest_peak_rss: all.iter().map(|m| m.0).max().unwrap_or(0),
        total_pss: all.iter().map(|m| m.1).sum(),
    })
}

/// Every actor's byte counts, from the ledgers they leave (whatever ended
/// them), plus the launcher's own. An actor that never started has none; a
/// ledger that cannot be read is said, not silently dropped.
fn merge_accounting(out: &Path, topology: &Topology, launcher: &Accounting) -> Accounting {
    let mut total = launcher.clone();
    for a in topology.actors() {
        let path = ledger_path(out, a);
        match read_ledger(&path) {
            Ok(acc) => total.merge(&acc),
            Err(LedgerError::Io { source, .. })
                if source.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!(actor = %a, error = %e, "byte counts lost"),
        }
    }
    total
}

/// The first `shown` names, and how many more: 2,358 names in one error
/// line hide the message.
fn name_some(actors: &[ActorId], shown: usize) -> String {
    let names: Vec<String> = actors.iter().take(shown).map(ActorId::to_string).collect();
    match actors.len().saturating_sub(shown) {
        0 => names.join(", "),
        more => format!("{} and {more} more", names.join(", ")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_list_of_actors_is_cut_short() {
        let actors: Vec<ActorId> = (0..2358).map(ActorId::Sensor).collect();
        assert_eq!(
            name_some(&actors, 3),
            "sensor-0, sensor-1, sensor-2 and 2355 more"
        );
        assert_eq!(name_some(&actors[..2], 3), "sensor-0, sensor-1");
    }
}
