//! Command-line arguments and loading the scenario they name.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use fusion_graph::scenario::{
    Scenario, COMPRESSIVE_SCENARIO, DEFAULT_SCENARIO, LOCATION_SCENARIO, RANDOM_EXCHANGE_SCENARIO,
    SENSOR_SELECTION_SCENARIO,
};
use fusion_graph::vocabulary::Vocabulary;
use fusion_graph::Topology;

#[derive(Debug, Parser)]
#[command(
    name = "cqnet",
    version,
    about = "Run a decentralized sensor network and compute its CQ/dPCRLB while it runs"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run a scenario in one process (in-memory transport, virtual clock).
    Sim(SimArgs),
    /// Run a scenario as a network of processes over iceoryx2.
    Run(RunArgs),
    /// Run a paper's experiment: Monte Carlo, CSV, SVG figure and a check in words
    /// (without a name: list them).
    Experiment(ExperimentArgs),
    /// Replay a finished run in the live view's page.
    View(ViewArgs),
    /// A long real-time run with periodic kills and restarts, sampling
    /// memory, file descriptors and shared-memory entries (all must stay flat).
    Soak(SoakArgs),
    /// Throw generated inputs at everything that reads outside input (wire
    /// bytes, scenario files, --set, messages a node handles) and count panics.
    Fuzz(FuzzArgs),
    /// Remove the shared memory of runs whose launcher is gone (killed with
    /// SIGKILL, say); runs still going are left alone.
    Clean,
    /// Print a built-in scenario to copy and edit.
    Scenario {
        /// The sensor-selection scenario (25 bearing sensors a cell, at most
        /// 4 active per node and 18 in all) instead of the default.
        #[arg(long, conflicts_with_all = ["random_exchange", "location", "compressive"])]
        sensor_selection: bool,
        /// The random-exchange network of 25 RSS nodes instead of the default.
        #[arg(long, conflicts_with_all = ["location", "compressive"])]
        random_exchange: bool,
        /// A static target located by 4 nodes from 64 amplitude sensors'
        /// quantized reports instead of the default.
        #[arg(long, conflicts_with = "compressive")]
        location: bool,
        /// One fusion centre hearing 25 amplitude sensors through a
        /// multiple-access channel, designing who transmits, instead of the
        /// default.
        #[arg(long)]
        compressive: bool,
    },
    /// Internal: one actor of a `cqnet run` network.
    #[command(hide = true)]
    Actor(launch::actor_process::ActorArgs),
    /// Serve one host of a multi-host scenario (its `[[hosts]]`): start
    /// this host's actors and bridge when a launcher asks.
    #[cfg(feature = "zenoh")]
    Agent(launch::hosts::agent::AgentArgs),
    /// What several hosts need to trust each other.
    #[cfg(feature = "zenoh")]
    #[command(subcommand)]
    Hosts(HostsCommand),
}

/// `cqnet hosts …`.
#[cfg(feature = "zenoh")]
#[derive(Debug, Subcommand)]
pub enum HostsCommand {
    /// Make an authority (unless DIR has one) and, signed by it, a key and
    /// certificate for each host named and for the launcher. Every file is
    /// its owner's only. Give each host `authority.pem` and its own pair;
    /// keep `authority.key` to add hosts later.
    Keys {
        /// The keys folder (a scenario's `[trust] keys`).
        dir: PathBuf,
        /// The hosts' names, as in the scenario's `[[hosts]]`.
        #[arg(required = true)]
        hosts: Vec<String>,
    },
}

#[derive(Debug, Args, Clone)]
pub struct ScenarioArgs {
    /// Scenario file (TOML); the built-in default when omitted.
    pub scenario: Option<PathBuf>,
    /// Override a scenario value, e.g. `--set quantizer.bits=4`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

#[derive(Debug, Args)]
pub struct SimArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Output folder.
    #[arg(long, default_value = "out/sim")]
    pub out: PathBuf,
    /// Monte Carlo runs with seeds seed, seed+1, …, in parallel.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub runs: u32,
    /// Worker threads for Monte Carlo runs (default: every core).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Leave out the centralized reference (also `reference.centralized = false`).
    #[arg(long)]
    pub no_central: bool,
}

#[derive(Debug, Args)]
pub struct RunArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Output folder.
    #[arg(long, default_value = "out/run")]
    pub out: PathBuf,
    /// Start each step as soon as every live node reported (or a timeout).
    #[arg(long)]
    pub lockstep: bool,
    /// Run id (a-z, 0-9, -); a fresh one when omitted.
    #[arg(long)]
    pub run_id: Option<String>,
    /// Leave out the centralized reference (also `reference.centralized = false`).
    #[arg(long)]
    pub no_central: bool,
    /// Serve a live view of the run on 127.0.0.1 (the URL is printed).
    #[arg(long)]
    pub view: bool,
    /// The view's port (0: any free port).
    #[arg(long, default_value_t = 0, requires = "view")]
    pub view_port: u16,
    /// A scenario with `[[hosts]]`: start every host's agent on this
    /// machine (simulated hosts) instead of reaching agents already running.
    #[arg(long)]
    pub local_agents: bool,
    /// Place each node with its sensors on one core, by parts of the fusion
    /// graph, when there are at least 16 nodes a core (`auto`); or leave
    /// every process to the kernel (`off`).
    #[arg(long, value_enum, default_value_t = launch::cores::Cores::Auto)]
    pub cores: launch::cores::Cores,
}

#[derive(Debug, Args)]
pub struct SoakArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Steps to run (replaces the scenario's).
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u32).range(1..))]
    pub steps: u32,
    /// Every this many steps, SIGKILL the next node and a sensor.
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u32).range(1..))]
    pub kill_every: u32,
    /// Steps a killed actor stays down before its restart.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..))]
    pub down: u32,
    /// Seconds between samples.
    #[arg(long, default_value_t = 5.0, value_parser = parse_speed)]
    pub sample_every: f64,
    /// Output folder (the run's results and soak.csv).
    #[arg(long, default_value = "out/soak")]
    pub out: PathBuf,
}

#[derive(Debug, Args)]
pub struct FuzzArgs {
    /// Targets (all when none is given).
    #[arg(long = "target", value_enum)]
    pub targets: Vec<crate::fuzz::Target>,
    /// Generated inputs per target.
    #[arg(long, default_value_t = 10_000_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub inputs: u64,
    /// Seed of the generator (the same seed, threads and corpus make the same inputs).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Threads (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=256))]
    pub threads: Option<u16>,
    /// Corpus folder: seeds are read from `<DIR>/<target>/`; inputs with new
    /// outcomes, and any that panic (under `crashes/`), are saved there.
    #[arg(long, default_value = "fuzz/corpus")]
    pub corpus: PathBuf,
}

#[derive(Debug, Args)]
pub struct ViewArgs {
    /// The output folder of a finished `cqnet run` or `cqnet sim`.
    pub out_dir: PathBuf,
    /// Port on 127.0.0.1 (0: any free port).
    #[arg(long, default_value_t = 0)]
    pub port: u16,
    /// Replay speed: 1 is the scenario's step period, 10 ten times faster.
    #[arg(long, default_value_t = 1.0, value_parser = parse_speed)]
    pub speed: f64,
}

fn parse_speed(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{s:?} is not a positive speed (1 is real time)")),
    }
}

#[derive(Debug, Args)]
pub struct ExperimentArgs {
    /// Experiment names, or `all`; none lists them.
    pub names: Vec<String>,
    /// Monte Carlo runs per arm (seeds seed, seed+1, …).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub runs: u32,
    /// Steps per run (the scenario's 100 when omitted).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub steps: Option<u32>,
    /// Output folder: each experiment writes `<OUT>/<name>/`.
    #[arg(long, default_value = "out/experiments")]
    pub out: PathBuf,
    /// Worker threads (default: every core).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub threads: Option<u32>,
    /// Trajectories for the non-conditional PCRLB.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub trajectories: u32,
}

/// The scenario the arguments name, validated, with its topology.
/// `vocabulary`: the program's parts, which the scenario may name.
pub fn load_scenario(
    args: &ScenarioArgs,
    vocabulary: Vocabulary,
) -> anyhow::Result<(Scenario, Topology)> {
    let (scenario, source) = match &args.scenario {
        Some(path) => (
            Scenario::load_in(vocabulary, path, &args.overrides)?,
            path.display().to_string(),
        ),
        None => (
            Scenario::from_toml_in(
                vocabulary,
                DEFAULT_SCENARIO,
                "<built-in default>",
                &args.overrides,
            )?,
            "<built-in default>".to_string(),
        ),
    };
    let topology = Topology::from_scenario(&scenario, &source)?;
    say_how_far_consensus_gets(&scenario, &topology);
    Ok((scenario, topology))
}

/// Before a run: the rounds `"auto"` chose, or a warning when the
/// scenario's rounds leave more of the disagreement than its
/// `consensus.accuracy` (both for the graph with every node alive).
fn say_how_far_consensus_gets(scenario: &Scenario, topology: &Topology) {
    if let Some(c) = scenario.consensus.chosen {
        eprintln!(
            "consensus.rounds = \"auto\": {} rounds, leaving at most {:.1} % of the nodes' \
             disagreement on this fusion graph (λ₂ = {:.4}; consensus.accuracy = {})",
            c.rounds,
            100.0 * c.left,
            c.slem,
            scenario.consensus.accuracy
        );
    } else if let Some(advice) = scenario.rounds_advice(topology) {
        eprintln!("warning: {advice}");
    }
}

pub fn builtin_scenario(
    sensor_selection: bool,
    random_exchange: bool,
    location: bool,
    compressive: bool,
) -> &'static str {
    match (sensor_selection, random_exchange, location, compressive) {
        (true, ..) => SENSOR_SELECTION_SCENARIO,
        (_, true, ..) => RANDOM_EXCHANGE_SCENARIO,
        (_, _, true, _) => LOCATION_SCENARIO,
        (.., true) => COMPRESSIVE_SCENARIO,
        _ => DEFAULT_SCENARIO,
    }
}
