//! `cqnet run`: the launcher's side of a multi-process network. The world
//! thread owns the launcher's iceoryx2 ports (they are not `Send`): it ticks
//! the world, applies the fault schedule, collects telemetry and the
//! centralized reference, and writes results. The supervisor (tokio, on the
//! main thread) owns the processes.

mod gather;
mod holes;
mod options;
mod processes;
mod steps;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use fusion_graph::hosts::Placement;
use fusion_graph::scenario::{ClockMode, Scenario};
use fusion_graph::vocabulary::Shape;
use fusion_graph::{link_fault_seed, ActorId, Topology};
use tokio::sync::mpsc::UnboundedSender;
use transport::iceoryx::{remove_run_resources, sweep_abandoned_runs, RunLease};
use transport::world_memory::TruthRing;
use transport::{Channel, IceoryxTransport, RunId, Transport};

use crate::feed::{setup_event, ViewEvent};
use crate::results::{write_atomically, Recorder, ResultsWriter, RunFacts};
use crate::summary::Summary;
use crate::supervisor::{supervise, ChildSpec, Command, Event};

pub use gather::traffic_poller;
use gather::{
    bring_home, children_usage, hosts_traffic_path, merge_accounting, write_hosts_report,
};
pub use options::{RunOptions, RunProgress};
use processes::{crash_fault, Processes};
use steps::run_steps;

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
    node::parts::check(scenario, topology)?;
    crate::preflight::check(scenario, topology, options.centralized)?;
    // The children read the clock's mode from the scenario they are given.
    let scenario = &clocked(scenario, options.lockstep);
    #[cfg(feature = "zenoh")]
    let scenario = &with_run_keys(scenario, &options)?;
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
    if let Err(e) = transport::iceoryx::remove_stale_node_directories() {
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
    if let Some(p) = &placement {
        p.check_domains(&options.run_id)
            .map_err(|e| anyhow::anyhow!("--run-id: {e}"))?;
    }
    if placement.is_none() && options.local_agents {
        bail!("--local-agents: the scenario has no [[hosts]] to start agents for");
    }
    let spec = ChildSpec {
        program: crate::supervisor::ActorProgram::for_this_process()?,
        run_id: options.run_id.as_str().to_string(),
        scenario_file,
        log_dir: options.out.join("logs"),
        centralized: options.centralized,
        // Over several hosts each agent starts its own actors, and leaves
        // its cores to its host.
        cores: placement
            .is_none()
            .then(|| crate::cores::CorePlacement::for_network(topology, options.cores))
            .flatten(),
    };
    let (command_tx, command_rx) = tokio::sync::mpsc::unbounded_channel();
    let (event_tx, event_rx) = std::sync::mpsc::channel();
    let _stop_watch = options
        .stop
        .clone()
        .map(|stop| StopWatch::start(stop, event_tx.clone()))
        .transpose()?;
    let options_local_agents = options.local_agents;
    #[cfg_attr(not(feature = "zenoh"), allow(unused_variables))]
    let hosts_traffic = options
        .view
        .is_some()
        .then(|| hosts_traffic_path(&options.out));
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
            if world_placement.is_none() {
                keep_descriptors_to_this_thread();
            }
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
                traffic: hosts_traffic,
                out: out.clone(),
            };
            let agents = options_local_agents
                .then(|| {
                    crate::hosts::remote::LocalAgents::start(
                        placement,
                        &spec.scenario_file,
                        &out,
                        run_id.as_str(),
                    )
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

/// Set (to anything) by a harness that applies the hosts' `link` settings
/// itself, so that the launcher does not warn they are not.
pub const HOST_LINKS_APPLIED: &str = "CQNET_HOST_LINKS_APPLIED";

/// Turns a caller's stop flag into the interrupt Ctrl-C would give, for
/// as long as the run lasts.
struct StopWatch {
    finished: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl StopWatch {
    fn start(
        stop: Arc<AtomicBool>,
        events: std::sync::mpsc::Sender<Event>,
    ) -> anyhow::Result<Self> {
        let finished = Arc::new(AtomicBool::new(false));
        let done = finished.clone();
        let thread = std::thread::Builder::new()
            .name("stop-watch".into())
            .spawn(move || {
                while !done.load(Ordering::Acquire) {
                    if stop.load(Ordering::Acquire) {
                        let _ = events.send(Event::Interrupted);
                        return;
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
            })
            .context("starting the stop watch")?;
        Ok(Self {
            finished,
            thread: Some(thread),
        })
    }
}

impl Drop for StopWatch {
    fn drop(&mut self) {
        self.finished.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The scenario as the run keeps time: `--lockstep` written into it, so
/// that the children, and `scenario.toml` in the results, say so.
/// `--local-agents` on `quic/` endpoints without keys: the run makes its
/// own authority and keys (in `out/keys`, its owner's only), since this
/// launcher starts every agent and hands each its scenario.
#[cfg(feature = "zenoh")]
fn with_run_keys(scenario: &Scenario, options: &RunOptions) -> anyhow::Result<Scenario> {
    let mut s = scenario.clone();
    if options.local_agents {
        crate::hosts::trust::add_run_keys(&mut s, &options.out.join("keys"))?;
    }
    Ok(s)
}

fn clocked(scenario: &Scenario, lockstep: bool) -> Scenario {
    let mut s = scenario.clone();
    if lockstep {
        s.clock.mode = ClockMode::Lockstep;
    }
    s
}

/// Gives the calling thread (the world thread) a descriptor table of its
/// own, so that the iceoryx2 files it opens stay out of the table the
/// supervisor spawns children from.
///
/// Why: the launcher's ports hold two or three descriptors per actor
/// (every actor's wake-up service, the lifecycle channel's connection to
/// every sensor), over 8,000 at 2,601 processes. Every spawn copies the
/// spawning thread's table into the child, and the child closes it again
/// (at exec, and in `close_inherited_descriptors`): per child, the whole
/// table twice, so start-up grew as the square of the network. A quarter
/// of a 2,601-process start-up's CPU was that closing (`perf record -a`:
/// `dnotify_flush`, `filp_flush`, `dup_fd`). The supervisor's table keeps
/// only its own: a pipe and a pidfd per child.
///
/// What makes the split safe: a descriptor the supervisor opens after it
/// is not in this thread's table, so this thread must never write to one
/// by number. It talks to the supervisor by channels whose wake-up (the
/// runtime's eventfd) exists before the split, the same open file in both
/// tables. A signal handler (tokio's, Python's) writes to a descriptor of
/// its own, made when the supervisor listens, after the split: so this
/// thread blocks every signal first, and the kernel hands them to a thread
/// of the supervisor's table. A run on several hosts keeps one table: its
/// supervisor makes Zenoh's runtime, whose wake-ups come after the split.
/// Where the kernel refuses, the thread keeps the shared table and
/// start-up is only slower.
fn keep_descriptors_to_this_thread() {
    use nix::sys::signal::{pthread_sigmask, SigSet, SigmaskHow};
    if let Err(e) = pthread_sigmask(SigmaskHow::SIG_BLOCK, Some(&SigSet::all()), None) {
        tracing::debug!(error = %e, "the world thread could not block signals; it shares the supervisor's descriptor table");
        return;
    }
    // SAFETY: unshare(CLONE_FILES) copies the calling thread's descriptor
    // table; every descriptor stays valid in both copies.
    if unsafe { libc::unshare(libc::CLONE_FILES) } != 0 {
        tracing::debug!(
            error = %std::io::Error::last_os_error(),
            "the world thread shares the supervisor's descriptor table"
        );
    }
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
    // Before any sensor starts: a sensor maps it as it starts.
    let truths = TruthRing::create(&launcher_domain(placement, options))
        .context("making the world's memory, where sensors read the truth")?;
    let mut w = Processes::new(transport, truths, topology, commands, events);
    let view = options.view.as_deref();
    if let Some(hub) = view {
        hub.publish(&setup_event(scenario, topology, "live"));
    }
    w.start_everyone(topology, view, progress)?;
    let startup_seconds = started.elapsed().as_secs_f64();
    let lockstep = options.lockstep || scenario.clock.mode == ClockMode::Lockstep;
    let (steps_done, wall_steps, gaps) = run_steps(
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
        let hosts = w.collect_host_counts(&mut accounting);
        bring_home(&options.out, &hosts.homes);
        write_hosts_report(&options.out, p, &accounting, &hosts.bridges, &hosts.homes)?;
    }
    let (children_memory_kb, children_cpu) = children_usage(&options.out, topology);
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
            processes: topology.actors().count() + 1,
            startup_seconds: Some(startup_seconds),
            children_memory_kb,
            children_cpu,
            real_time_rounds: true,
            unscheduled_faults: w
                .crashed
                .iter()
                .map(|(actor, step, status)| crash_fault(*actor, *step, status))
                .chain(gaps.as_faults(steps_done))
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
    if let Some(silent) = gaps.failure() {
        bail!("{silent}; results so far are in {}", options.out.display());
    }
    Ok(summary)
}

/// Where the launcher's resources are: its host's domain on several hosts.
fn launcher_domain(placement: Option<&Placement>, options: &RunOptions) -> RunId {
    match placement {
        Some(p) => p.domain(&options.run_id, p.host_of(ActorId::Launcher)),
        None => options.run_id.clone(),
    }
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
    let domain = launcher_domain(placement, options);
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
    t.publish_on(Channel::Lifecycle)?;
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
