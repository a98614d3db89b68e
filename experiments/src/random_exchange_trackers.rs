//! The random-exchange paper's trackers, run: its Fig. 1 (the four trackers' RMS position
//! error over time beside the RndEx-PF and centralized PCRLB, a Monte Carlo
//! in `sim`) and its Table I (each tracker's communication and processing
//! cost, measured on a real network of processes in real time).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use bounds::diffusion::MonteCarloSize;
use fusion_graph::scenario::{Scenario, RANDOM_EXCHANGE_SCENARIO};
use fusion_graph::RunId;
use fusion_graph::{ActorId, Topology};
use plotters::prelude::*;
use transport::accounting::Accounting;
use wire::MessageKind;

use super::diagnostics::run_ticks;
use super::paired::{Order, Paired};
use super::random_exchange_bounds::{draw_lines, Curves};
use super::{Check, Claim, Computed, ComputedReport, Options};
use launch::results::AVERAGE_FROM_STEP;

pub fn experiments() -> Vec<Computed> {
    vec![
        Computed {
            name: "random-exchange-trackers",
            source: "the RndEx-PF PCRLB paper, Fig. 1",
            about: "RMS position error over time of RndEx-PF and the three KL fusion trackers on random-exchange.toml's 25 RSS nodes (a Monte Carlo of --runs runs in sim), with the RndEx-PF PCRLB (the paper's N_T = 10^4, N_f = 10^3), its paths' bounds averaged, and the centralized PCRLB",
            run: fig1,
        },
        Computed {
            name: "random-exchange-trackers-on-sensor",
            source: "the RndEx-PF PCRLB paper, Fig. 1, with the truth on a sensor",
            about: "the same with the truth starting exactly on node 12's sensor (target.start = fixed) and the RSS law without its near field (observation.near_field = 0.001 m): the setting in which the estimators beat the centralized PCRLB",
            run: fig1_on_sensor,
        },
        Computed {
            name: "random-exchange-cost",
            source: "the RndEx-PF PCRLB paper, Table I",
            about: "each tracker run as a real network of 50 processes in real time, paced at ten steps a second (--steps steps, 20 by default), a quarter of --runs times (at least 2) with the trackers of a run sharing their seed: RX and TX bytes per node between nodes per paper step (1 s), from the accounting, and the duty cycle, the node processes' CPU time a step over the paper's 1 s step",
            run: table,
        },
    ]
}

/// A tracker: its `consensus.protocol` and the paper's name for it.
#[derive(Debug, Clone, Copy)]
struct Tracker {
    protocol: &'static str,
    label: &'static str,
    /// Table I's figures: RX B/s, TX B/s, duty cycle %.
    paper: (f64, f64, f64),
}

/// In the paper's order of Table I.
const TRACKERS: [Tracker; 4] = [
    Tracker {
        protocol: "random_exchange",
        label: "RndEx-PF",
        paper: (148.0, 132.0, 2.9),
    },
    Tracker {
        protocol: "kl_diffusion",
        label: "non-iterative KL",
        paper: (317.0, 64.0, 2.6),
    },
    Tracker {
        protocol: "kl_iterative",
        label: "iterative KL",
        paper: (2900.0, 604.0, 2.7),
    },
    Tracker {
        protocol: "kl_consensus",
        label: "consensus KL",
        paper: (2900.0, 600.0, 1.0),
    },
];

/// The paper's Fig. 1 with the truth on a sensor, and RSS
/// information growing as 1/d² down to a millimetre.
const ON_SENSOR: [&str; 2] = ["target.start=\"fixed\"", "observation.near_field=0.001"];

fn scenario_of(tracker: &Tracker, extra: &[String]) -> anyhow::Result<(Scenario, Topology)> {
    let mut overrides = vec![format!("consensus.protocol=\"{}\"", tracker.protocol)];
    overrides.extend_from_slice(extra);
    let scenario =
        Scenario::from_toml(RANDOM_EXCHANGE_SCENARIO, "random-exchange.toml", &overrides)?;
    let topology = Topology::from_scenario(&scenario, "random-exchange.toml")?;
    Ok((scenario, topology))
}

// ---------------------------------------------------------------- Fig. 1

/// Per-step RMS position error of each tracker, the centralized filter's,
/// and the two bounds, from step 0 (the bounds) or 1 (the errors; NaN at 0).
struct Fig1 {
    name: &'static str,
    rmse: Vec<Vec<f64>>,
    /// Each tracker's 95 % band of the RMSE at each step (from step 1),
    /// and the centralized filter's last.
    bands: Vec<Vec<Option<(f64, f64)>>>,
    /// Each tracker's RMSE of each run from step 10 (the runs share their
    /// seeds across trackers, so they compare in pairs).
    per_run: Vec<Vec<Option<f64>>>,
    /// Each tracker's per-run RMSE over the nodes within [`NEAR`] of the
    /// truth, and beyond.
    by_distance: Vec<ByDistance>,
    centralized_rmse: Vec<f64>,
    bounds: Curves,
    size: MonteCarloSize,
    runs: u32,
}

fn fig1(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    fig1_in("random-exchange-trackers", &[], options, dir)
}

fn fig1_on_sensor(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let extra = ON_SENSOR.map(String::from);
    fig1_in("random-exchange-trackers-on-sensor", &extra, options, dir)
}

fn fig1_in(
    name: &'static str,
    extra: &[String],
    options: &Options,
    dir: &Path,
) -> anyhow::Result<ComputedReport> {
    let mut steps: Vec<String> = options
        .steps
        .map(|s| vec![format!("steps={s}")])
        .unwrap_or_default();
    steps.extend_from_slice(extra);
    let mut rmse = Vec::new();
    let mut bands = Vec::new();
    let mut centralized_band = Vec::new();
    let mut per_run = Vec::new();
    let mut by_distance = Vec::new();
    let mut centralized_rmse = Vec::new();
    for (i, tracker) in TRACKERS.iter().enumerate() {
        let (scenario, topology) = scenario_of(tracker, &steps)?;
        // The truth and the measurements come from the same streams for
        // every tracker: one centralized filter serves them all.
        let centralized = i == 0;
        eprintln!("{name}: {} ({} runs)", tracker.label, options.runs);
        let runs_dir = dir.join("runs").join(name).join(tracker.protocol);
        let mc = options.monte_carlo(&scenario, &topology, &runs_dir, centralized)?;
        let means = mc.series.means();
        per_run.push(mc.per_run.iter().map(|r| r.estimates.rmse).collect());
        bands.push(crate::rmse_bands_of(&mc.per_run_series, |m| m.rmse));
        by_distance.push(ByDistance::read(&runs_dir, &topology, options.runs)?);
        if centralized {
            centralized_band = crate::rmse_bands_of(&mc.per_run_series, |m| m.centralized_rmse);
        }
        let nan = f64::NAN;
        rmse.push(
            std::iter::once(nan)
                .chain(means.iter().map(|m| m.rmse.unwrap_or(nan)))
                .collect(),
        );
        if centralized {
            centralized_rmse = std::iter::once(nan)
                .chain(means.iter().map(|m| m.centralized_rmse.unwrap_or(nan)))
                .collect();
        }
    }
    let (scenario, _) = scenario_of(&TRACKERS[0], &steps)?;
    // The paper's sizes: a few seconds, and smaller N_T is far off
    // (random-exchange-bounds).
    let paper = MonteCarloSize {
        trajectories: 10_000,
        paths: 1000,
    };
    let size = options.sized(paper, super::random_exchange_bounds::small(paper));
    bands.push(centralized_band);
    let fig = Fig1 {
        name,
        rmse,
        bands,
        per_run,
        by_distance,
        centralized_rmse,
        bounds: Curves::compute(&scenario, size)?,
        size,
        runs: options.runs,
    };
    let mut lines: Vec<(String, &[f64])> = TRACKERS
        .iter()
        .zip(&fig.rmse)
        .map(|(t, r)| (format!("{} RMSE", t.label), &r[..]))
        .collect();
    lines.push(("centralized PF RMSE".into(), &fig.centralized_rmse[..]));
    lines.push(("RndEx-PF PCRLB".into(), &fig.bounds.rndex[..]));
    lines.push((
        "RndEx-PF paths' bounds averaged".into(),
        &fig.bounds.rndex_paths[..],
    ));
    lines.push(("centralized PCRLB".into(), &fig.bounds.centralized[..]));
    ComputedReport::write(
        dir,
        name,
        &fig1_csv(&fig),
        |svg| {
            // The four trackers' and the centralized filter's bands, in
            // the order of their lines.
            let bands: Vec<&[Option<(f64, f64)>]> = fig.bands.iter().map(|b| &b[..]).collect();
            draw_lines(
                svg,
                &format!("{name}: RMS position error, 25 RSS nodes"),
                "position error, m",
                &lines,
                &bands,
            )
        },
        fig1_check(&fig),
        fig1_table(&fig),
    )
}

/// Nodes within this distance of the truth are near it.
const NEAR: f64 = 30.0;

/// A figure of each run, in seed order (`None` where the run has none).
type PerRun = Vec<Option<f64>>;

/// One tracker's RMSE from step [`AVERAGE_FROM_STEP`] split by the node's
/// distance from the truth: over the node-steps within [`NEAR`] of it and
/// over the others, run by run, read back from the runs' `ticks.csv`.
struct ByDistance {
    near: PerRun,
    far: PerRun,
    /// Node-steps near and far, over every run.
    node_steps: [usize; 2],
}

impl ByDistance {
    fn read(runs_dir: &Path, topology: &Topology, runs: u32) -> anyhow::Result<Self> {
        let mut split = Self {
            near: Vec::new(),
            far: Vec::new(),
            node_steps: [0; 2],
        };
        for run in 0..runs {
            let mut sums = [(0.0, 0usize); 2];
            for tick in run_ticks(runs_dir, run)? {
                let Some(node) = tick
                    .node
                    .strip_prefix("node-")
                    .and_then(|i| i.parse::<usize>().ok())
                    .filter(|i| *i < topology.nodes())
                else {
                    continue;
                };
                if tick.step < AVERAGE_FROM_STEP || !tick.error.is_finite() {
                    continue;
                }
                let [x, y] = topology.node_positions[node];
                let far = usize::from((tick.truth[0] - x).hypot(tick.truth[1] - y) >= NEAR);
                sums[far].0 += tick.error * tick.error;
                sums[far].1 += 1;
            }
            let rms = |(sq, n): (f64, usize)| (n > 0).then(|| (sq / n as f64).sqrt());
            split.near.push(rms(sums[0]));
            split.far.push(rms(sums[1]));
            split.node_steps[0] += sums[0].1;
            split.node_steps[1] += sums[1].1;
        }
        Ok(split)
    }
}

fn fig1_csv(fig: &Fig1) -> String {
    let mut out = format!(
        "# {}, {} runs; metres; RndEx-PF PCRLB at N_T={} N_f={}; each RMSE's 95 % band as _lo, _hi\nstep",
        fig.name, fig.runs, fig.size.trajectories, fig.size.paths
    );
    let names: Vec<&str> = TRACKERS
        .iter()
        .map(|t| t.protocol)
        .chain(["centralized"])
        .collect();
    for n in &names {
        let _ = write!(out, ",rmse_{n},rmse_{n}_lo,rmse_{n}_hi");
    }
    out.push_str(",pcrlb_rndex,pcrlb_rndex_paths_averaged,pcrlb_centralized\n");
    let rmse: Vec<&Vec<f64>> = fig.rmse.iter().chain([&fig.centralized_rmse]).collect();
    for n in 1..fig.bounds.rndex.len() {
        let _ = write!(out, "{n}");
        for (r, band) in rmse.iter().zip(&fig.bands) {
            let (lo, hi) = band
                .get(n - 1)
                .copied()
                .flatten()
                .unwrap_or((f64::NAN, f64::NAN));
            let _ = write!(out, ",{:.6},{lo:.6},{hi:.6}", r[n]);
        }
        let _ = writeln!(
            out,
            ",{:.6},{:.6},{:.6}",
            fig.bounds.rndex[n], fig.bounds.rndex_paths[n], fig.bounds.centralized[n]
        );
    }
    out
}

/// The mean from step [`AVERAGE_FROM_STEP`] on, past the prior's transient.
fn settled(values: &[f64]) -> f64 {
    let tail: Vec<f64> = values
        .iter()
        .skip(AVERAGE_FROM_STEP as usize)
        .copied()
        .collect();
    tail.iter().sum::<f64>() / tail.len().max(1) as f64
}

fn fig1_table(fig: &Fig1) -> String {
    let mut out = format!(
        "the random-exchange paper's Fig. 1 ({}), {} runs: RMS position error and bounds, metres (mean from step {AVERAGE_FROM_STEP}; the paper gives curves, no figures)\n",
        fig.name, fig.runs
    );
    let mut row = |name: &str, v: &[f64]| {
        let _ = writeln!(out, "  {name:<24} {:>7.3}", settled(v));
    };
    for (t, r) in TRACKERS.iter().zip(&fig.rmse) {
        row(t.label, r);
    }
    row("centralized PF", &fig.centralized_rmse);
    row("RndEx-PF PCRLB", &fig.bounds.rndex);
    row("RndEx paths' bounds avg", &fig.bounds.rndex_paths);
    row("centralized PCRLB", &fig.bounds.centralized);
    out
}

/// The steps (from 1) at which an estimator's whole 95 % band lies below
/// the centralized PCRLB, for each of the four trackers and the
/// centralized filter: where a lower bound is beaten beyond the noise.
fn below_the_bound(fig: &Fig1) -> Vec<(String, Vec<usize>)> {
    let labels = TRACKERS.iter().map(|t| t.label).chain(["centralized PF"]);
    labels
        .zip(&fig.bands)
        .map(|(label, band)| {
            let steps = band
                .iter()
                .enumerate()
                .filter_map(|(i, b)| {
                    let bound = fig.bounds.centralized.get(i + 1)?;
                    b.filter(|(_, hi)| hi < bound).map(|_| i + 1)
                })
                .collect();
            (label.to_string(), steps)
        })
        .collect()
}

/// The paper's reading of its Fig. 1, each part checked on ours: two
/// trackers by their per-run RMSE in the same runs, a tracker against a
/// bound by its per-run RMSE against the bound (the same in every run);
/// each with its 95 % interval and one of the three verdicts.
fn fig1_check(fig: &Fig1) -> Check {
    let [rndex, non_iterative, iterative, consensus] = [0, 1, 2, 3].map(|i| settled(&fig.rmse[i]));
    let rndex_bound = settled(&fig.bounds.rndex);
    let central_bound = settled(&fig.bounds.centralized);
    let runs = |i: usize| &fig.per_run[i][..];
    let level = |i: usize, bound: f64| vec![Some(bound); fig.per_run[i].len()];
    let claim = |what: &str, a: &[Option<f64>], b: &[Option<f64>], expected: Order| {
        Claim::judged(
            what,
            Paired::of(a, b),
            |p| p.verdict(expected),
            |p| format!("{} m", p.text(3)),
        )
    };
    let mut claims = vec![
        claim(
            "RndEx-PF's RMSE is above its PCRLB",
            runs(0),
            &level(0, rndex_bound),
            Order::Higher,
        ),
        claim(
            "RndEx-PF beats consensus KL",
            runs(0),
            runs(3),
            Order::Lower,
        ),
        claim(
            "non-iterative KL beats RndEx-PF",
            runs(1),
            runs(0),
            Order::Lower,
        ),
        claim(
            "iterative KL beats non-iterative KL",
            runs(2),
            runs(1),
            Order::Lower,
        ),
        claim(
            "iterative KL is below the RndEx-PF PCRLB",
            runs(2),
            &level(2, rndex_bound),
            Order::Lower,
        ),
    ];
    for (i, t) in TRACKERS.iter().enumerate() {
        claims.push(claim(
            &format!("{} is above the centralized PCRLB", t.label),
            runs(i),
            &level(i, central_bound),
            Order::Higher,
        ));
    }
    // Step by step: a one-sided 95 % band misses a true bound at about
    // 2.5 % of steps by chance, so a few isolated steps are expected.
    let below = below_the_bound(fig);
    let crossings: usize = below.iter().map(|(_, s)| s.len()).sum();
    let checked = below.len() * fig.bounds.centralized.len().saturating_sub(1);
    let allowed = (0.025 * checked as f64).ceil() as usize;
    claims.push(Claim::exact(
        format!(
            "no estimator's 95 % band is below the centralized PCRLB at more steps than chance allows ({crossings} of {checked} step-estimates, {allowed} allowed)"
        ),
        crossings <= allowed,
    ));
    let listed = below
        .iter()
        .filter(|(_, s)| !s.is_empty())
        .map(|(label, s)| format!("{label} at steps {s:?}"))
        .collect::<Vec<_>>();
    let paths = settled(&fig.bounds.rndex_paths);
    // Where RndEx-PF loses to consensus KL: near the target or far from it.
    let [rndex_split, consensus_split] = [&fig.by_distance[0], &fig.by_distance[3]];
    let split = |a: &PerRun, b: &PerRun| {
        Paired::of(a, b).map_or("-".to_string(), |p| format!("{} m", p.text(3)))
    };
    let [near_steps, far_steps] = rndex_split.node_steps;
    Check::of_claims(
        claims,
        format!(
            "per-run RMSE from step 10, paired over {} runs; mean from step {AVERAGE_FROM_STEP}: RndEx-PF {rndex:.2} m, non-iterative KL {non_iterative:.2} m, iterative KL {iterative:.2} m, consensus KL {consensus:.2} m; RndEx-PF PCRLB {rndex_bound:.2} m (its paths' bounds averaged: {paths:.2} m, the Jensen gap of eq. 15), centralized PCRLB {central_bound:.2} m; RndEx-PF minus consensus KL at the nodes within {NEAR} m of the target {}, beyond {} ({} of {} node-steps from step {AVERAGE_FROM_STEP} beyond); bands below the centralized PCRLB: {}",
            fig.runs,
            split(&rndex_split.near, &consensus_split.near),
            split(&rndex_split.far, &consensus_split.far),
            far_steps,
            near_steps + far_steps,
            if listed.is_empty() { "none".to_string() } else { listed.join("; ") }
        ),
    )
}

// ---------------------------------------------------------------- Table I

/// The paper's step, 1 s of its dynamics: its rates are per second, and
/// its duty cycle the processor's share of that second.
const PAPER_STEP_S: f64 = 1.0;
/// The networks' pace, ten steps a second. A node's bytes and CPU time a
/// step do not depend on the pace (a step costs a node about a millisecond,
/// a hundredth of this period), and are reported per paper step; a slower
/// pace would only add the idle node's wake-ups between steps, and minutes.
const TABLE_PERIOD_MS: f64 = 100.0;
const TABLE_STEPS: u32 = 20;

/// One tracker's cost, per node, averaged over the nodes.
#[derive(Debug, Clone, Copy)]
struct Cost {
    /// Bytes per second received from other nodes.
    rx: f64,
    /// Bytes per second sent to other nodes, one count per receiving link.
    tx_per_link: f64,
    /// The same with a message published on a node's consensus channel
    /// (which reaches every neighbour) counted once, as a radio broadcast.
    tx_broadcast: f64,
    /// CPU time over the step period, %.
    duty: f64,
    cpu_ms_per_step: f64,
    rmse: Option<f64>,
}

/// Messages that go to one neighbour on a pair channel; every other
/// node-to-node kind is published on the sender's consensus channel.
fn is_pairwise(kind: MessageKind) -> bool {
    matches!(
        kind,
        MessageKind::ExchangeRequest | MessageKind::ExchangeReply | MessageKind::ExchangePosterior
    )
}

/// Per node and second, from the run's accounting.
fn traffic(accounting: &Accounting, topology: &Topology, seconds: f64) -> (f64, f64, f64) {
    let (mut rx, mut tx, mut broadcast) = (0.0, 0.0, 0.0);
    for ((from, to, kind), c) in accounting.iter() {
        let (ActorId::Node(f), ActorId::Node(_)) = (from, to) else {
            continue;
        };
        rx += c.received_bytes as f64;
        tx += c.sent_bytes as f64;
        broadcast += if is_pairwise(*kind) {
            c.sent_bytes as f64
        } else {
            c.sent_bytes as f64 / topology.neighbours[*f as usize].len().max(1) as f64
        };
    }
    let per = topology.nodes() as f64 * seconds;
    (rx / per, tx / per, broadcast / per)
}

/// Each run of Table I is the four trackers one after the other in real
/// time, so a run is a quarter of `--runs` (5 at the default 20).
fn table_runs(options: &Options) -> u32 {
    options.runs.div_ceil(4).max(2)
}

fn table(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let steps = options.steps.unwrap_or(TABLE_STEPS);
    let runs = table_runs(options);
    // Run r of every tracker has the seed 1 + r: the trackers of a run
    // track the same target through the same noise, one after the other
    // on the same machine, so their costs pair run by run.
    let mut per_run: Vec<[Cost; 4]> = Vec::new();
    for run in 0..runs {
        let mut costs = Vec::new();
        for tracker in &TRACKERS {
            let extra = vec![
                format!("steps={steps}"),
                format!("clock.step_period_ms={}", TABLE_PERIOD_MS),
                "clock.mode=\"realtime\"".to_string(),
                "reference.centralized=false".to_string(),
                format!("seed={}", 1 + run),
            ];
            let (scenario, topology) = scenario_of(tracker, &extra)?;
            let out = dir.join("runs").join(format!("{}-{run}", tracker.protocol));
            eprintln!(
                "random-exchange-cost: run {} of {runs}, {} as {} processes, {steps} steps, one every {} s",
                run + 1,
                tracker.label,
                topology.actors().count(),
                TABLE_PERIOD_MS / 1e3
            );
            costs.push(measure(&scenario, &topology, &out)?);
        }
        per_run.push(costs.try_into().expect("four trackers"));
    }
    let mean = mean_costs(&per_run);
    ComputedReport::write(
        dir,
        "random-exchange-cost",
        &table_csv(&mean, &per_run),
        |svg| draw_table(svg, &mean),
        table_check(&per_run, &mean),
        table_text(&mean, steps, runs, TABLE_PERIOD_MS),
    )
}

/// Each tracker's costs averaged over the runs.
fn mean_costs(per_run: &[[Cost; 4]]) -> Vec<Cost> {
    let n = per_run.len() as f64;
    (0..TRACKERS.len())
        .map(|t| {
            let sum = |f: fn(&Cost) -> f64| per_run.iter().map(|r| f(&r[t])).sum::<f64>() / n;
            let rmses: Vec<f64> = per_run.iter().filter_map(|r| r[t].rmse).collect();
            Cost {
                rx: sum(|c| c.rx),
                tx_per_link: sum(|c| c.tx_per_link),
                tx_broadcast: sum(|c| c.tx_broadcast),
                duty: sum(|c| c.duty),
                cpu_ms_per_step: sum(|c| c.cpu_ms_per_step),
                rmse: (!rmses.is_empty()).then(|| {
                    (rmses.iter().map(|r| r * r).sum::<f64>() / rmses.len() as f64).sqrt()
                }),
            }
        })
        .collect()
}

/// Runs one tracker's network and reads its costs back.
fn measure(scenario: &Scenario, topology: &Topology, out: &Path) -> anyhow::Result<Cost> {
    let options = launch::network::RunOptions {
        out: out.to_path_buf(),
        lockstep: false,
        run_id: RunId::generate(),
        centralized: false,
        view: None,
        local_agents: false,
        stop: None,
        cores: launch::cores::Cores::Auto,
    };
    let summary = launch::network::run_network(scenario, topology, options, |_| {})?;
    let links = links_csv(out);
    let text =
        std::fs::read_to_string(&links).with_context(|| format!("reading {}", links.display()))?;
    let accounting = Accounting::from_csv(&text, wire::payloads::Payloads::NONE)
        .with_context(|| format!("{} is not an accounting table", links.display()))?;
    let (rx, tx_per_link, tx_broadcast) =
        traffic(&accounting, topology, summary.steps as f64 * PAPER_STEP_S);
    let cpu: Vec<f64> = (0..topology.nodes() as u16)
        .filter_map(|n| launch::actor_process::read_cpu_per_step(out, ActorId::Node(n)))
        .collect();
    anyhow::ensure!(
        cpu.len() == topology.nodes(),
        "{} of {} nodes wrote their CPU time",
        cpu.len(),
        topology.nodes()
    );
    let cpu_per_step = cpu.iter().sum::<f64>() / cpu.len() as f64;
    Ok(Cost {
        rx,
        tx_per_link,
        tx_broadcast,
        duty: 100.0 * cpu_per_step / PAPER_STEP_S,
        cpu_ms_per_step: cpu_per_step * 1e3,
        rmse: summary.estimates.rmse,
    })
}

fn links_csv(out: &Path) -> PathBuf {
    out.join("links.csv")
}

fn table_csv(mean: &[Cost], per_run: &[[Cost; 4]]) -> String {
    let mut out = String::from("run,protocol,rx_bytes_per_s,tx_bytes_per_s_per_link,tx_bytes_per_s_broadcast,duty_cycle_percent,cpu_ms_per_step,rmse_m,paper_rx,paper_tx,paper_duty\n");
    let rows = per_run
        .iter()
        .enumerate()
        .flat_map(|(r, costs)| {
            costs
                .iter()
                .enumerate()
                .map(move |(t, c)| (r.to_string(), t, *c))
        })
        .chain(
            mean.iter()
                .enumerate()
                .map(|(t, c)| ("mean".to_string(), t, *c)),
        );
    for (run, t, c) in rows {
        let tracker = &TRACKERS[t];
        let _ = writeln!(
            out,
            "{run},{},{:.1},{:.1},{:.1},{:.3},{:.3},{},{},{},{}",
            tracker.protocol,
            c.rx,
            c.tx_per_link,
            c.tx_broadcast,
            c.duty,
            c.cpu_ms_per_step,
            c.rmse.map_or(String::new(), |r| format!("{r:.3}")),
            tracker.paper.0,
            tracker.paper.1,
            tracker.paper.2
        );
    }
    out
}

fn table_text(costs: &[Cost], steps: u32, runs: u32, period_ms: f64) -> String {
    let mut out = format!(
        "the random-exchange paper's Table I: {runs} runs of {steps} steps per tracker, paced at one step every {} s, 25 node processes and 25 sensor processes; per node and paper step (1 s), between nodes, mean over the runs\n  {:<18} {:>9} {:>11} {:>11} {:>7} {:>10} {:>7}   paper: {:>8} {:>8} {:>6}\n",
        period_ms / 1e3,
        "tracker",
        "RX B/s",
        "TX B/s",
        "TX bcast",
        "duty",
        "CPU/step",
        "RMSE",
        "RX",
        "TX",
        "duty"
    );
    for (t, c) in TRACKERS.iter().zip(costs) {
        let _ = writeln!(
            out,
            "  {:<18} {:>9.0} {:>11.0} {:>11.0} {:>6.2}% {:>8.2}ms {:>6}m   paper: {:>6.0}B/s {:>6.0}B/s {:>5.1}%",
            t.label,
            c.rx,
            c.tx_per_link,
            c.tx_broadcast,
            c.duty,
            c.cpu_ms_per_step,
            c.rmse.map_or("-".into(), |r| format!("{r:.2}")),
            t.paper.0,
            t.paper.1,
            t.paper.2
        );
    }
    out.push_str("  TX counts a message once per receiving link (shared memory has no broadcast); TX bcast counts a consensus-channel message once, as the paper's radio does.\n");
    out
}

/// The paper's orderings and ratios, each judged run by run: the runs'
/// log-ratios of one tracker's figure to another's, with their 95 %
/// interval.
fn table_check(per_run: &[[Cost; 4]], mean: &[Cost]) -> Check {
    const RNDEX: usize = 0;
    const NON_ITERATIVE: usize = 1;
    const ITERATIVE: usize = 2;
    const CONSENSUS: usize = 3;
    let ln_ratio = |f: fn(&Cost) -> f64, a: usize, b: usize, against: f64| -> Option<Paired> {
        let d: Vec<Option<f64>> = per_run
            .iter()
            .map(|r| Some((f(&r[a]) / f(&r[b])).ln() - against.ln()))
            .collect();
        Paired::of_values(&d)
    };
    let ratio_text = |against: f64| {
        move |p: &Paired| {
            format!(
                "ratio ×{:.3} (×{:.3} to ×{:.3}) over {} runs",
                against * p.mean.exp(),
                against * (p.mean - p.half_width).exp(),
                against * (p.mean + p.half_width).exp(),
                p.runs
            )
        }
    };
    type Figure = fn(&Cost) -> f64;
    let (rx, tx, cpu): (Figure, Figure, Figure) =
        (|c| c.rx, |c| c.tx_broadcast, |c| c.cpu_ms_per_step);
    let order = |claim: &str, f, a, b, expected| {
        Claim::judged(
            claim,
            ln_ratio(f, a, b, 1.0),
            move |p| p.verdict(expected),
            ratio_text(1.0),
        )
    };
    // Within ±25 % of the paper's ratio.
    let near = |claim: &str, f, a, b, ratio: f64| {
        Claim::judged(
            claim,
            ln_ratio(f, a, b, ratio),
            |p| p.verdict_within(0.75_f64.ln(), 1.25_f64.ln()),
            ratio_text(ratio),
        )
    };
    let claims = vec![
        order(
            "RX: RndEx-PF below non-iterative KL (the paper: half)",
            rx,
            RNDEX,
            NON_ITERATIVE,
            Order::Lower,
        ),
        order(
            "RX: non-iterative KL below iterative KL",
            rx,
            NON_ITERATIVE,
            ITERATIVE,
            Order::Lower,
        ),
        Claim::judged(
            "RX: consensus KL at least 5x RndEx-PF (the paper: an order of magnitude)",
            ln_ratio(rx, CONSENSUS, RNDEX, 5.0),
            |p| p.verdict(Order::Higher),
            ratio_text(5.0),
        ),
        order(
            "TX (broadcast): non-iterative KL below RndEx-PF",
            tx,
            NON_ITERATIVE,
            RNDEX,
            Order::Lower,
        ),
        order(
            "TX (broadcast): RndEx-PF below consensus KL",
            tx,
            RNDEX,
            CONSENSUS,
            Order::Lower,
        ),
        order(
            "TX (broadcast): consensus KL slightly below iterative KL",
            tx,
            CONSENSUS,
            ITERATIVE,
            Order::Lower,
        ),
        order(
            "processing: consensus KL below RndEx-PF",
            cpu,
            CONSENSUS,
            RNDEX,
            Order::Lower,
        ),
        near(
            "processing: consensus KL about a third of RndEx-PF (ratio 1/3, ±25 %)",
            cpu,
            CONSENSUS,
            RNDEX,
            1.0 / 3.0,
        ),
        near(
            "processing: iterative KL 170 % above consensus KL (ratio 2.7, ±25 %)",
            cpu,
            ITERATIVE,
            CONSENSUS,
            2.7,
        ),
        near(
            "processing: non-iterative KL similar to RndEx-PF (ratio 1, ±25 %)",
            cpu,
            NON_ITERATIVE,
            RNDEX,
            1.0,
        ),
    ];
    let figures: Vec<String> = TRACKERS
        .iter()
        .zip(mean)
        .map(|(t, c)| {
            format!(
                "{} RX {:.0} B/s, TX {:.0} B/s broadcast, CPU {:.2} ms a step",
                t.label, c.rx, c.tx_broadcast, c.cpu_ms_per_step
            )
        })
        .collect();
    Check::of_claims(claims, figures.join("; "))
}

fn draw_table(path: &Path, costs: &[Cost]) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let top = costs
        .iter()
        .map(|c| c.rx.max(c.tx_broadcast))
        .fold(0.0, f64::max)
        * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "random-exchange-cost: bytes per second per node between nodes, real processes",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..TRACKERS.len() as f64, 0.0..top.max(1.0))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(TRACKERS.len() * 2 + 1)
        .x_label_formatter(&|x| {
            let i = x.floor() as usize;
            if (x - i as f64 - 0.5).abs() < 0.26 && i < TRACKERS.len() {
                TRACKERS[i].label.to_string()
            } else {
                String::new()
            }
        })
        .y_desc("B/s per node")
        .draw()?;
    type Bar = (&'static str, fn(&Cost) -> f64, usize);
    let bars: [Bar; 2] = [
        ("RX", |c| c.rx, 0),
        ("TX, one per broadcast", |c| c.tx_broadcast, 1),
    ];
    for (name, value, k) in bars {
        let colour = Palette99::pick(k).to_rgba();
        chart
            .draw_series(costs.iter().enumerate().map(|(i, c)| {
                let left = i as f64 + 0.1 + 0.4 * k as f64;
                Rectangle::new([(left, 0.0), (left + 0.38, value(c))], colour.filled())
            }))?
            .label(name)
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], colour.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}
