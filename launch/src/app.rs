//! The `cqnet` program, as a library function so that the integration tests
//! can build the very same program as their own binary.

use anyhow::Context;
use clap::Parser;

use crate::cli::{builtin_scenario, load_scenario, Cli, Command};
use crate::montecarlo::{run_monte_carlo, Progress};
use crate::results::{write_atomically, ResultsWriter};
use crate::summary::print_table;

/// `cqnet`'s `main`.
pub fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let actor_name = match &cli.command {
        Command::Actor(a) => Some(a.actor.clone()),
        _ => None,
    };
    init_logging(actor_name.as_deref());
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cqnet: error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn init_logging(actor: Option<&str>) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .init();
    if let Some(name) = actor {
        // A span held for the whole process names the actor on every line.
        let span = tracing::error_span!("actor", name = %name);
        std::mem::forget(span.entered());
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Scenario { seed001 } => {
            print!("{}", builtin_scenario(seed001));
            Ok::<(), anyhow::Error>(())
        }
        Command::Sim(args) => {
            let (scenario, topology) = load_scenario(&args.scenario)?;
            if args.runs == 1 {
                let mut writer = ResultsWriter::create(&args.out)?;
                let progress = Progress::new("step", scenario.steps);
                let summary = crate::sim::run_in_process(
                    &scenario,
                    &topology,
                    &mut writer,
                    scenario.reference.centralized && !args.no_central,
                    |s| progress.update(s),
                )?;
                print_table(&summary);
                println!("results in {}", args.out.display());
            } else {
                let threads = args
                    .threads
                    .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
                let mc = run_monte_carlo(
                    &scenario,
                    &topology,
                    &args.out,
                    args.runs,
                    threads,
                    scenario.reference.centralized && !args.no_central,
                )?;
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
                    "  RMSE {} m, CQ/dPCRLB {} m, local {} m, aux-FIM {} m",
                    m(mc.estimates.rmse),
                    m(mc.estimates.mean_bound),
                    m(mc.estimates.mean_local_bound),
                    m(mc.estimates.mean_aux_bound)
                );
                println!(
                    "  centralized: RMSE {} m, bound {} m",
                    m(mc.estimates.centralized_rmse),
                    m(mc.estimates.mean_centralized_bound)
                );
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
            let (scenario, topology) = load_scenario(&args.scenario)?;
            let run_id = match &args.run_id {
                Some(id) => fusion_graph::transport::RunId::new(id)?,
                None => fusion_graph::transport::RunId::generate(),
            };
            let options = crate::network::RunOptions {
                out: args.out.clone(),
                lockstep: args.lockstep,
                run_id,
                centralized: scenario.reference.centralized && !args.no_central,
            };
            let steps = scenario.steps;
            let progress = Progress::new("step", steps);
            let summary = crate::network::run_network(&scenario, &topology, options, move |s| {
                progress.update(s)
            })?;
            print_table(&summary);
            println!("results in {}", args.out.display());
            Ok(())
        }
        Command::Actor(args) => crate::actor_process::run_actor(&args),
    }
    .context("cqnet")
}
