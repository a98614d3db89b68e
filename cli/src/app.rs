//! The `cqnet` program as a value, [`App`]: cqnet's parts and a program's
//! own, behind cqnet's command line. `cqnet` itself is `App::new().main()`;
//! a program with a protocol of its own adds it before `main`, and its
//! binary is then the launcher and every actor of its runs.

use std::sync::Arc;

use anyhow::Context;
use clap::Parser;

use crate::cli::{
    builtin_scenario, load_scenario, Cli, Command, ExperimentArgs, FuzzArgs, SoakArgs, ViewArgs,
};
use crate::view::replay::{replay, FinishedRun};
use crate::view::server::ViewServer;
use experiments::{self as experiment, Entry, Experiment, Verdict};
use launch::feed::Hub;
use launch::montecarlo::run_monte_carlo;
use launch::network::RunProgress;
use launch::progress::{step_message, Progress};
use launch::results::{write_atomically, ResultsWriter};
use launch::summary::print_table;
use node::parts::{
    LawFactory, ManagerFactory, MotionFactory, NodeFactory, Parts, PartsError, ProtocolFactory,
};
use wire::payloads::ProtocolPayload;

pub use fusion_graph::vocabulary::Vocabulary;

/// A program built on cqnet: the parts its scenarios may name (cqnet's own
/// and those it adds) and cqnet's command line over them.
///
/// ```no_run
/// # use cqnet::App;
/// fn main() -> std::process::ExitCode {
///     App::new()
///         // .payload::<MyValue>()
///         // .protocol("my_protocol", my_protocol::build)
///         // .manager("my_manager", my_manager::build)
///         // .law("range", my_laws::range)
///         // .motion("ornstein_uhlenbeck", my_models::ou)
///         .main()
/// }
/// ```
///
/// Every process of a run is the same program, so every actor gets the
/// same parts, and the same kind bytes for the same payloads. Nothing is
/// registered anywhere: a test may build several `App`s in one process.
#[derive(Default)]
pub struct App {
    parts: Parts,
}

impl App {
    /// cqnet's own parts.
    pub fn new() -> Self {
        Self::default()
    }

    /// A fusion protocol of the CF/DPF (see [`node::parts::ProtocolFactory`]).
    pub fn protocol(self, name: &'static str, factory: impl ProtocolFactory) -> Self {
        Self {
            parts: self.parts.protocol(name, factory),
        }
    }

    /// A node of a kind of its own: a tracker, a locator (see
    /// [`node::parts::NodeFactory`]).
    pub fn node(self, name: &'static str, factory: impl NodeFactory) -> Self {
        Self {
            parts: self.parts.node(name, factory),
        }
    }

    /// A sensor manager (see [`node::parts::ManagerFactory`]).
    pub fn manager(self, name: &'static str, factory: impl ManagerFactory) -> Self {
        Self {
            parts: self.parts.manager(name, factory),
        }
    }

    /// An observation law, chosen by `[observation] kind = "name"` (see
    /// [`node::parts::LawFactory`]).
    pub fn law(self, name: &'static str, factory: impl LawFactory) -> Self {
        Self {
            parts: self.parts.law(name, factory),
        }
    }

    /// A motion model, chosen by `[dynamics] kind = "name"` (see
    /// [`node::parts::MotionFactory`]).
    pub fn motion(self, name: &'static str, factory: impl MotionFactory) -> Self {
        Self {
            parts: self.parts.motion(name, factory),
        }
    }

    /// A payload the program's protocols send, given the next kind byte.
    pub fn payload<P: ProtocolPayload>(self) -> Self {
        Self {
            parts: self.parts.payload::<P>(),
        }
    }

    /// What the program's scenarios are read in, or the first mistake in
    /// its list of parts.
    pub fn vocabulary(&self) -> Result<Vocabulary, PartsError> {
        self.parts.vocabulary()
    }

    /// The program's `main`: cqnet's command line over its parts.
    pub fn main(self) -> std::process::ExitCode {
        self.main_with(std::env::args_os())
    }

    /// The same over the given arguments, the first being the program's
    /// name: what a program that carries cqnet as a library (the Python
    /// package's `cqnet` command, and its actors' processes) calls.
    pub fn main_with<I, T>(self, args: I) -> std::process::ExitCode
    where
        I: IntoIterator<Item = T>,
        T: Into<std::ffi::OsString> + Clone,
    {
        let vocabulary = match self.vocabulary() {
            Ok(v) => v,
            Err(e) => {
                eprintln!("cqnet: error: the program's parts: {e}");
                return std::process::ExitCode::FAILURE;
            }
        };
        main_in(vocabulary, args)
    }
}

fn main_in<I, T>(vocabulary: Vocabulary, args: I) -> std::process::ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let args: Vec<std::ffi::OsString> = args.into_iter().map(Into::into).collect();
    let cli = Cli::parse_from(args);
    let actor_name = match &cli.command {
        Command::Actor(a) => Some(a.actor.clone()),
        _ => None,
    };
    // A fuzzing campaign makes millions of bad inputs on purpose: their
    // warnings would bury its report.
    let quiet = matches!(cli.command, Command::Fuzz(_));
    init_logging(actor_name.as_deref(), quiet);
    match run(cli, vocabulary) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cqnet: error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn init_logging(actor: Option<&str>, quiet: bool) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(if quiet { "off" } else { "warn" }));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        // A program that carries cqnet as a library may have set its own.
        .try_init()
        .ok();
    if let Some(name) = actor {
        // A span held for the whole process names the actor on every line.
        let span = tracing::error_span!("actor", name = %name);
        std::mem::forget(span.entered());
    }
}

fn run(cli: Cli, vocabulary: Vocabulary) -> anyhow::Result<()> {
    match cli.command {
        Command::Scenario {
            sensor_selection,
            random_exchange,
            location,
            compressive,
        } => {
            print!(
                "{}",
                builtin_scenario(sensor_selection, random_exchange, location, compressive)
            );
            Ok::<(), anyhow::Error>(())
        }
        Command::Sim(args) => {
            let (scenario, topology) = load_scenario(&args.scenario, vocabulary)?;
            if args.runs == 1 {
                let mut writer = ResultsWriter::create(&args.out)?;
                let progress = Progress::new("sim", "steps", scenario.steps as u64);
                let summary = launch::sim::run_in_process(
                    &scenario,
                    &topology,
                    &mut writer,
                    scenario.reference.centralized && !args.no_central,
                    |s, rows| progress.set(s as u64, step_message(rows)),
                )?;
                progress.finish();
                print_table(&summary);
                println!("results in {}", args.out.display());
            } else {
                let threads = args
                    .threads
                    .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
                let progress = Progress::new("sim", "runs", args.runs as u64);
                let mc = run_monte_carlo(
                    &scenario,
                    &topology,
                    &args.out,
                    args.runs,
                    threads,
                    scenario.reference.centralized && !args.no_central,
                    &|done| progress.set(done as u64, ""),
                )?;
                progress.finish();
                write_atomically(
                    &args.out.join("summary.json"),
                    serde_json::to_string_pretty(&mc)?.as_bytes(),
                )?;
                let m = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.3}"));
                println!(
                    "cqnet sim — {} runs of `{}`, averages over steps {}..{}",
                    mc.runs, scenario.name, mc.estimates.from_step, scenario.steps
                );
                println!(
                    "  RMSE {} m, {} {} m, local {} m, aux-FIM {} m",
                    m(mc.estimates.rmse),
                    launch::summary::bound_name(&scenario),
                    m(mc.estimates.mean_bound),
                    m(mc.estimates.mean_local_bound),
                    m(mc.estimates.mean_aux_bound)
                );
                println!(
                    "  centralized: RMSE {} m, bound {} m",
                    m(mc.estimates.centralized_rmse),
                    m(mc.estimates.mean_centralized_bound)
                );
                if let Some(line) = intervals(&mc, launch::summary::bound_name(&scenario)) {
                    println!("  {line}");
                }
                println!(
                    "  {:.1} steps/s per run, {:.1} s wall; results in {}",
                    mc.steps_per_second_per_run,
                    mc.wall_seconds,
                    args.out.display()
                );
            }
            Ok(())
        }
        Command::Run(args) => {
            let (scenario, topology) = load_scenario(&args.scenario, vocabulary)?;
            let run_id = match &args.run_id {
                Some(id) => fusion_graph::RunId::new(id)?,
                None => fusion_graph::RunId::generate(),
            };
            let options = launch::network::RunOptions {
                out: args.out.clone(),
                lockstep: args.lockstep,
                run_id,
                centralized: scenario.reference.centralized && !args.no_central,
                view: None,
                local_agents: args.local_agents,
                stop: None,
                cores: args.cores,
            };
            let view = args
                .view
                .then(|| start_live_view(&scenario, &topology, &args.out, args.view_port))
                .transpose()?;
            let options = launch::network::RunOptions {
                view: view.as_ref().map(|(hub, _)| hub.clone()),
                ..options
            };
            let steps = scenario.steps as u64;
            let processes = topology.actors().count() as u64;
            let progress = Progress::new("run", "processes ready", processes);
            let summary =
                launch::network::run_network(&scenario, &topology, options, move |p| match p {
                    RunProgress::Starting { ready, .. } => progress.set(ready as u64, ""),
                    RunProgress::Running => {
                        progress.set_total(steps);
                        progress.set_unit("steps");
                        progress.set(0, "");
                    }
                    RunProgress::Step { step, rows } => {
                        progress.set(step as u64, step_message(rows))
                    }
                })?;
            drop(view);
            print_table(&summary);
            println!("results in {}", args.out.display());
            Ok(())
        }
        Command::Experiment(args) => run_experiments(&args),
        Command::Clean => {
            let cleaned =
                transport::iceoryx::sweep_abandoned_runs().context("sweeping abandoned runs")?;
            let directories = transport::iceoryx::remove_stale_node_directories()
                .context("removing empty iceoryx2 node directories")?;
            if cleaned.is_empty() && directories == 0 {
                println!("no abandoned run: nothing to remove");
            }
            for run in cleaned {
                println!("removed the shared memory of run {}", run.as_str());
            }
            if directories > 0 {
                println!(
                    "removed {directories} empty iceoryx2 node directories left by earlier runs"
                );
            }
            Ok(())
        }
        Command::View(args) => view_finished_run(&args, vocabulary),
        Command::Fuzz(args) => fuzz(&args),
        Command::Soak(args) => soak(&args, vocabulary),
        Command::Actor(args) => launch::actor_process::run_actor(&args, vocabulary),
        #[cfg(feature = "zenoh")]
        Command::Agent(args) => launch::hosts::agent::run_agent(&args, vocabulary),
        #[cfg(feature = "zenoh")]
        Command::Hosts(crate::cli::HostsCommand::Keys { dir, hosts }) => {
            let written = launch::hosts::trust::make_keys(&dir, &hosts)?;
            for f in &written {
                println!("wrote {}", f.display());
            }
            if written.is_empty() {
                println!("{} already holds keys for every host named", dir.display());
            }
            Ok(())
        }
    }
    .context("cqnet")
}

/// `cqnet soak`: the scenario for `--steps` real-time steps with periodic
/// kills, its footprint sampled throughout, and how each figure moved.
fn soak(args: &SoakArgs, vocabulary: Vocabulary) -> anyhow::Result<()> {
    use std::sync::atomic::{AtomicU32, Ordering};
    let (mut scenario, topology) = load_scenario(&args.scenario, vocabulary)?;
    scenario.steps = args.steps;
    crate::soak::add_periodic_kills(&mut scenario, &topology, args.kill_every, args.down);
    let topology = fusion_graph::Topology::from_scenario(&scenario, "soak")?;
    let run_id = fusion_graph::RunId::generate();
    let step = Arc::new(AtomicU32::new(0));
    let sampler = crate::soak::Sampler::start(
        run_id.clone(),
        step.clone(),
        std::time::Duration::from_secs_f64(args.sample_every),
    );
    let progress = Progress::new("soak", "steps", args.steps as u64);
    let options = launch::network::RunOptions {
        out: args.out.clone(),
        lockstep: false,
        run_id,
        centralized: false,
        view: None,
        local_agents: false,
        stop: None,
        cores: launch::cores::Cores::Auto,
    };
    let result = launch::network::run_network(&scenario, &topology, options, move |p| {
        if let RunProgress::Step { step: s, rows } = p {
            step.store(s, Ordering::Relaxed);
            progress.set(s as u64, step_message(rows));
        }
    });
    let samples = sampler.finish();
    std::fs::create_dir_all(&args.out)?;
    crate::soak::write_samples(&crate::soak::samples_path(&args.out), &samples)?;
    let summary = result?;
    print_table(&summary);
    println!(
        "{} samples, {} kills; how each figure moved (steps 10-20 % vs the last 10 %):",
        samples.len(),
        scenario.faults.len()
    );
    type Figure = fn(&crate::soak::Sample) -> f64;
    let figures: [(&str, Figure); 6] = [
        ("RSS, all processes (kB)", |s| s.rss_kb as f64),
        ("  of which private (kB)", |s| s.private_kb as f64),
        ("  the launcher's private (kB)", |s| {
            s.launcher_private_kb as f64
        }),
        ("open file descriptors", |s| s.fds as f64),
        ("/dev/shm + iceoryx2 entries", |s| s.shm_entries as f64),
        ("processes", |s| s.processes as f64),
    ];
    for (name, f) in figures {
        match crate::soak::trend(&samples, args.steps, f) {
            Some(t) => println!(
                "  {name:<30} {:>12.0} -> {:>12.0}   slope {:>+10.1} per 1000 steps",
                t.early, t.late, t.per_1000_steps
            ),
            None => println!("  {name:<30} too few samples"),
        }
    }
    println!(
        "samples in {}",
        crate::soak::samples_path(&args.out).display()
    );
    Ok(())
}

/// `cqnet fuzz`: one campaign per target, a line each, and failure if any
/// input panicked.
fn fuzz(args: &FuzzArgs) -> anyhow::Result<()> {
    use crate::fuzz::{Campaign, Target};
    let targets = if args.targets.is_empty() {
        Target::ALL.to_vec()
    } else {
        args.targets.clone()
    };
    let threads = args.threads.map_or_else(
        || std::thread::available_parallelism().map_or(1, |n| n.get()),
        usize::from,
    );
    let mut panics = 0;
    for target in targets {
        let progress = Progress::new(format!("fuzz {}", target.name()), "inputs", args.inputs);
        let report = crate::fuzz::run(
            &Campaign {
                target,
                inputs: args.inputs,
                seed: args.seed,
                threads,
                corpus: Some(args.corpus.clone()),
                save: true,
            },
            |done, _| progress.set(done, ""),
        )?;
        progress.finish();
        println!(
            "{:<9} {:>11} inputs in {:>7.1} s ({:>9.0}/s): {} panics, {} outcomes, corpus {}",
            target.name(),
            report.inputs,
            report.seconds,
            report.inputs_per_second(),
            report.panics,
            report.outcomes,
            report.corpus_size
        );
        for (what, n) in &report.panic_kinds {
            println!("    {n} × {what}");
        }
        panics += report.panics;
    }
    anyhow::ensure!(
        panics == 0,
        "{panics} inputs panicked; they are under {}/<target>/crashes",
        args.corpus.display()
    );
    Ok(())
}

/// Serves the live view of a run about to start, and prints where.
fn start_live_view(
    scenario: &fusion_graph::Scenario,
    topology: &fusion_graph::Topology,
    out: &std::path::Path,
    port: u16,
) -> anyhow::Result<(Arc<Hub>, ViewServer)> {
    let hub = Arc::new(Hub::default());
    let poll = launch::network::traffic_poller(hub.clone(), topology.clone(), out.to_path_buf());
    let server = ViewServer::start(hub.clone(), port, Some(poll))?;
    eprintln!(
        "cqnet: live view of `{}` at {}",
        scenario.name,
        server.url()
    );
    Ok((hub, server))
}

/// `cqnet view OUT_DIR`: replays a finished run in the view until Ctrl-C.
fn view_finished_run(args: &ViewArgs, vocabulary: Vocabulary) -> anyhow::Result<()> {
    let run = FinishedRun::read(&args.out_dir, vocabulary)?;
    let hub = Arc::new(Hub::default());
    let server = ViewServer::start(hub.clone(), args.port, None)?;
    println!(
        "replaying {} ({} steps) at {} (Ctrl-C to stop)",
        args.out_dir.display(),
        run.summary.steps,
        server.url()
    );
    let period = std::time::Duration::from_secs_f64(
        run.summary.scenario.clock.step_period_ms / 1e3 / args.speed,
    );
    replay(&run, &hub, period);
    println!("replayed; a page opened now gets the whole run at once");
    loop {
        std::thread::park();
    }
}

/// `cqnet experiment`: lists the catalogue, or runs the named experiments
/// one after another, each with a progress bar over all its runs.
fn run_experiments(args: &ExperimentArgs) -> anyhow::Result<()> {
    if args.names.is_empty() {
        println!("experiments (run one with `cqnet experiment NAME`, or `all`):");
        for e in experiment::catalogue() {
            println!("  {:<18} {}: {}", e.name, e.source, e.about);
        }
        // Each says in its own words what it runs: some only compute, some
        // run networks of their own (bit-depth-delay's sweep, random-exchange-cost).
        for c in experiment::computed_catalogue() {
            println!("  {:<18} {}: {}", c.name, c.source, c.about);
        }
        return Ok(());
    }
    let chosen: Vec<Entry> = if args.names.iter().any(|n| n == "all") {
        experiment::catalogue()
            .into_iter()
            .map(Entry::Network)
            .chain(
                experiment::computed_catalogue()
                    .into_iter()
                    .map(Entry::Computed),
            )
            .collect()
    } else {
        args.names
            .iter()
            .map(|n| experiment::find_entry(n))
            .collect::<anyhow::Result<_>>()?
    };
    let options = experiment::Options {
        runs: args.runs,
        steps: args.steps,
        threads: args
            .threads
            .map(|t| t as usize)
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
        out: args.out.clone(),
        trajectories: args.trajectories as usize,
        stop: Default::default(),
        small: false,
    };
    stop_on_interrupt(options.stop.clone());
    let mut failed = Vec::new();
    let mut open = Vec::new();
    let all_started = std::time::Instant::now();
    for entry in &chosen {
        let started = std::time::Instant::now();
        let (name, verdict) = match entry {
            Entry::Network(e) => {
                let bar = ExperimentProgress::new(e, args.runs);
                let report = experiment::run(e, &options, &|arm, done| bar.update(arm, done))?;
                bar.finish();
                println!(
                    "{}",
                    experiment::verdict_line(e, &report.outcome, &report.check)
                );
                print_claims(&report.check);
                println!("  {} and {}", report.csv.display(), report.svg.display());
                (e.name, report.check.verdict)
            }
            Entry::Computed(c) => {
                let report = experiment::run_computed(c, &options)?;
                print!("{}", report.table);
                println!("{}", experiment::computed_verdict_line(c, &report.check));
                print_claims(&report.check);
                println!("  {} and {}", report.csv.display(), report.svg.display());
                (c.name, report.check.verdict)
            }
        };
        println!("  {name} took {}", elapsed(started));
        match verdict {
            Verdict::Holds => {}
            Verdict::DoesNotHold => failed.push(name),
            Verdict::NotResolved { .. } => open.push(name),
        }
    }
    if chosen.len() > 1 {
        println!("{} experiments took {}", chosen.len(), elapsed(all_started));
    }
    if !failed.is_empty() {
        println!("the papers' result did not hold in: {}", failed.join(", "));
    }
    if !open.is_empty() {
        println!(
            "not resolved at these runs (more runs would say): {}",
            open.join(", ")
        );
    }
    Ok(())
}

/// How long an interrupted experiment has to stop by itself: a Monte Carlo
/// stops at its next step and a network within the supervisor's grace, but
/// a computed experiment may not look at `stop` at all.
const INTERRUPT_GRACE: std::time::Duration = std::time::Duration::from_secs(20);

/// Ctrl-C, SIGTERM and SIGHUP stop the experiments: the first sets `stop`,
/// which ends the running Monte Carlo between steps (and a network run
/// stops and reaps its processes, hearing the same signal), and ends the
/// process if the experiment has not stopped within [`INTERRUPT_GRACE`];
/// a second ends it at once. Listening here, rather than leaving the
/// signals' default, keeps them working after a network experiment: its
/// supervisor's listener, once dropped, would otherwise leave them
/// swallowed for the rest of the process.
fn stop_on_interrupt(stop: Arc<std::sync::atomic::AtomicBool>) {
    use tokio::signal::unix::{signal, SignalKind};
    let listen = move || -> std::io::Result<()> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        runtime.block_on(async {
            let mut terminate = signal(SignalKind::terminate())?;
            let mut hangup = signal(SignalKind::hangup())?;
            let mut heard = 0;
            loop {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = terminate.recv() => {}
                    _ = hangup.recv() => {}
                }
                heard += 1;
                if heard > 1 {
                    std::process::exit(130);
                }
                eprintln!(
                    "interrupted: stopping the experiment (at its next step, or in {} s); interrupt again to end now",
                    INTERRUPT_GRACE.as_secs()
                );
                stop.store(true, std::sync::atomic::Ordering::SeqCst);
                std::thread::spawn(|| {
                    std::thread::sleep(INTERRUPT_GRACE);
                    eprintln!("the experiment did not stop in time: ending it");
                    std::process::exit(130);
                });
            }
        })
    };
    std::thread::spawn(move || {
        if let Err(e) = listen() {
            tracing::warn!("cannot listen for interrupts: {e}");
        }
    });
}

/// Wall time since `started`, as minutes and seconds.
fn elapsed(started: std::time::Instant) -> String {
    let s = started.elapsed().as_secs();
    format!("{} min {:02} s", s / 60, s % 60)
}

/// A bar over every run of every arm, saying which arm is running.
struct ExperimentProgress {
    progress: Progress,
    runs: u32,
    arms: Vec<&'static str>,
}

impl ExperimentProgress {
    fn new(e: &Experiment, runs: u32) -> Self {
        Self {
            progress: Progress::new(e.name, "runs", runs as u64 * e.arms.len() as u64),
            runs,
            arms: e.arms.iter().map(|a| a.label).collect(),
        }
    }

    fn update(&self, arm: usize, done: u32) {
        self.progress.set(
            arm as u64 * self.runs as u64 + done as u64,
            format!("arm {}/{}: {}", arm + 1, self.arms.len(), self.arms[arm]),
        );
    }

    fn finish(self) {
        self.progress.finish();
    }
}

/// The 95 % intervals over runs of the RMSE and the bound, and of their
/// difference run by run: what a figure of `sim --runs` can claim.
fn intervals(mc: &launch::montecarlo::MonteCarloSummary, bound_name: &str) -> Option<String> {
    use experiments::paired::{rmse_interval, Paired};
    let rmse: Vec<f64> = mc.per_run.iter().filter_map(|r| r.estimates.rmse).collect();
    let (lo, hi) = rmse_interval(&rmse)?;
    let per_run = |f: fn(&launch::summary::Estimates) -> Option<f64>| {
        mc.per_run
            .iter()
            .map(|r| f(&r.estimates))
            .collect::<Vec<_>>()
    };
    let bound = Paired::of_values(&per_run(|e| e.mean_bound));
    let gap = Paired::of(&per_run(|e| e.rmse), &per_run(|e| e.mean_bound));
    let mut line = format!("95 % over {} runs: RMSE {lo:.3} to {hi:.3} m", rmse.len());
    if let (Some(b), Some(g)) = (bound, gap) {
        line.push_str(&format!(
            ", {bound_name} {:.3} ± {:.3} m, RMSE minus {bound_name} {} m (run by run)",
            b.mean,
            b.half_width,
            g.text(3)
        ));
    }
    Some(line)
}

/// Each claim of a check on its own line: what it says, its interval (or
/// that it is exact) and its verdict.
fn print_claims(check: &experiments::Check) {
    for claim in &check.claims {
        println!("  - {}", claim.said());
    }
}
