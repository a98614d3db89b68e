//! Consensus at scale: how many rounds a grid of nodes needs to track, and
//! what one round of memory saves. Average consensus and short-memory
//! consensus (`x(t+1) = (1 + α) W x(t) − α x(t−1)`, α from the graph's
//! λ₂) on 3 × 3, 6 × 6 and 10 × 10 grids, 5 to 80 rounds, paired over
//! runs: RMSE, the CQ/dPCRLB and the centralized bound against rounds,
//! with the bytes each costs; `consensus.rounds = "auto"` on the 10 × 10
//! grid; and the fault matrix run with each protocol, cell by cell.

use std::fmt::Write as _;
use std::path::Path;

use fusion_graph::scenario::{Scenario, DEFAULT_SCENARIO};
use fusion_graph::Topology;
use launch::montecarlo::MonteCarloSummary;
use launch::results::write_atomically;
use plotters::prelude::*;

use super::faults::{MATRIX, MATRIX_BASE};
use super::paired::Paired;
use super::{Check, Claim, Computed, ComputedReport, Experiment, Figure, Options, Verdict};

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "consensus-at-scale",
        source: "cqnet's consensus: Metropolis weights' λ₂, and short node memory (Oreshkin, Coates and Rabbat, IEEE TSP 2010)",
        about: "RMSE, CQ/dPCRLB and centralized bound against consensus rounds (5 to 80) on 3 × 3, 6 × 6 and 10 × 10 grids, average consensus against short memory, paired over a third of --runs runs, rounded down (at least 2; 6 at the default 20), with bytes per step; rounds = \"auto\" on 10 × 10; the fault matrix with each protocol",
        run,
    }]
}

const SIDES: [u32; 3] = [3, 6, 10];
const ROUNDS: [u32; 6] = [5, 10, 15, 20, 40, 80];
const PROTOCOLS: [&str; 2] = ["average", "short_memory"];

/// One protocol at one number of rounds on one grid.
struct Point {
    side: u32,
    protocol: &'static str,
    /// `None`: `"auto"`.
    rounds: Option<u32>,
    /// The rounds it ran (the chosen ones, for `"auto"`).
    ran: u32,
    mc: MonteCarloSummary,
    /// Node tracks, over every run, whose error at the last step was over
    /// [`LOST`]: nodes that lost the target and did not find it again.
    lost: usize,
}

/// An error at the run's last step that means a node has lost the target:
/// ten times the bound on the grids measured.
const LOST: f64 = 20.0;

/// The node tracks in the runs under `dir` whose error at their last
/// step is over [`LOST`].
fn lost_tracks(dir: &Path) -> anyhow::Result<usize> {
    let mut lost = 0;
    for run in std::fs::read_dir(dir)? {
        let ticks = std::fs::read_to_string(run?.path().join("ticks.csv"))?;
        let rows: Vec<launch::results::Tick> = ticks
            .lines()
            .skip(1)
            .filter_map(launch::results::Tick::parse)
            .collect();
        let last = rows.iter().map(|t| t.step).max().unwrap_or(0);
        lost += rows
            .iter()
            .filter(|t| t.is_node() && t.step == last && t.error > LOST)
            .count();
    }
    Ok(lost)
}

impl Point {
    fn per_run(&self, f: fn(&launch::summary::Estimates) -> Option<f64>) -> Vec<Option<f64>> {
        self.mc.per_run.iter().map(|r| f(&r.estimates)).collect()
    }

    fn rmse_runs(&self) -> Vec<Option<f64>> {
        self.per_run(|e| e.rmse)
    }

    fn bound_runs(&self) -> Vec<Option<f64>> {
        self.per_run(|e| e.mean_bound)
    }

    /// Consensus bytes a step, mean over runs.
    fn consensus_bytes_per_step(&self) -> f64 {
        let runs = self.mc.per_run.len().max(1) as f64;
        self.mc
            .per_run
            .iter()
            .flat_map(|r| r.traffic.iter())
            .filter(|t| t.kind.starts_with("consensus"))
            .map(|t| t.bytes_per_step)
            .sum::<f64>()
            / runs
    }

    /// The mean over runs of each run's mean per-step largest disagreement.
    fn disagreement(&self) -> Option<f64> {
        let d: Vec<f64> = self
            .mc
            .per_run
            .iter()
            .filter_map(|r| r.disagreement.as_ref().map(|d| d.mean_of_step_largest))
            .collect();
        (!d.is_empty()).then(|| d.iter().sum::<f64>() / d.len() as f64)
    }
}

fn grid_scenario(
    side: u32,
    protocol: &str,
    rounds: Option<u32>,
    steps: u32,
) -> anyhow::Result<Scenario> {
    let width = 500 * side;
    let rounds = rounds.map_or("\"auto\"".to_string(), |r| r.to_string());
    let sets = vec![
        format!("nodes.grid=[{side},{side}]"),
        format!("region.width={width}"),
        format!("region.height={width}"),
        format!("steps={steps}"),
        format!("consensus.protocol=\"{protocol}\""),
        format!("consensus.rounds={rounds}"),
        "reference.centralized=false".to_string(),
    ];
    let source = format!("consensus-at-scale {side}x{side} {protocol} {rounds}");
    Ok(Scenario::from_toml(DEFAULT_SCENARIO, &source, &sets)?)
}

fn measure(
    options: &Options,
    dir: &Path,
    side: u32,
    protocol: &'static str,
    rounds: Option<u32>,
    centralized: bool,
) -> anyhow::Result<Point> {
    let steps = options.steps.unwrap_or(100);
    let scenario = grid_scenario(side, protocol, rounds, steps)?;
    let topology = Topology::from_scenario(&scenario, "consensus-at-scale")?;
    let ran = scenario.consensus.rounds;
    let tag = rounds.map_or("auto".to_string(), |r| r.to_string());
    let runs_dir = dir
        .join("runs")
        .join(format!("{side}x{side}-{protocol}-{tag}"));
    let mc = options.monte_carlo(&scenario, &topology, &runs_dir, centralized)?;
    eprintln!(
        "  {side}×{side} {protocol:<12} {ran:>3} rounds: RMSE {:.3} m, CQ/dPCRLB {:.3} m",
        mc.estimates.rmse.unwrap_or(f64::NAN),
        mc.estimates.mean_bound.unwrap_or(f64::NAN)
    );
    Ok(Point {
        side,
        protocol,
        rounds,
        ran,
        mc,
        lost: lost_tracks(&runs_dir)?,
    })
}

/// The fault matrix's cells with `protocol`.
fn fault_matrix(
    options: &Options,
    dir: &Path,
    protocol: &'static str,
) -> anyhow::Result<super::Outcome> {
    const AVERAGE: [&str; 4] = [
        MATRIX_BASE[0],
        MATRIX_BASE[1],
        MATRIX_BASE[2],
        "consensus.protocol=\"average\"",
    ];
    const SHORT_MEMORY: [&str; 4] = [
        MATRIX_BASE[0],
        MATRIX_BASE[1],
        MATRIX_BASE[2],
        "consensus.protocol=\"short_memory\"",
    ];
    let base: &'static [&'static str] = match protocol {
        "average" => &AVERAGE,
        _ => &SHORT_MEMORY,
    };
    let experiment = Experiment {
        name: if protocol == "average" {
            "fault-matrix-average"
        } else {
            "fault-matrix-short-memory"
        },
        source: "cqnet's fault injection",
        about: "the fault matrix with one consensus protocol",
        scenario: DEFAULT_SCENARIO,
        base,
        arms: &MATRIX,
        figure: Figure::Panels {
            y_label: "position RMSE and bound, m",
            reference: 0,
            window: super::faults::WINDOW,
        },
        // Judged in consensus-at-scale's own claims, arm by arm against
        // the other protocol's matrix; nothing to judge alone.
        check: |_| Check {
            verdict: Verdict::Holds,
            statement:
                "not judged alone: consensus-at-scale pairs each arm with the other protocol's"
                    .into(),
            claims: Vec::new(),
        },
    };
    let sub = Options {
        runs: options.runs,
        steps: Some(60),
        threads: options.threads,
        out: dir.to_path_buf(),
        trajectories: options.trajectories,
        stop: options.stop.clone(),
        small: options.small,
    };
    eprintln!("  the fault matrix with {protocol}");
    Ok(super::runner::run(&experiment, &sub, &|_, _| {})?.outcome)
}

/// The runs of each arm: a third of `--runs`, rounded down (at least 2).
/// A run of the 10 × 10 grid is 100 node filters and their bounds for 100
/// steps, and one run of every arm costs more than two minutes of a core.
/// The default 20 gives 6, which two cores run in three turns (7 took
/// four, the last with one core idle); every claim holds at 6 with room
/// to spare (docs/experiments.md, "Consensus at scale").
fn runs(options: &Options) -> u32 {
    (options.runs / 3).max(2)
}

fn run(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let options = &Options {
        runs: runs(options),
        ..options.clone()
    };
    let mut points = Vec::new();
    for side in SIDES {
        for protocol in PROTOCOLS {
            for rounds in ROUNDS {
                // The centralized bound does not depend on the consensus:
                // one arm a grid carries it.
                let centralized = protocol == "average" && rounds == ROUNDS[0];
                points.push(measure(
                    options,
                    dir,
                    side,
                    protocol,
                    Some(rounds),
                    centralized,
                )?);
            }
        }
    }
    points.push(measure(options, dir, 10, "average", None, false)?);
    let matrices = [
        fault_matrix(options, dir, "average")?,
        fault_matrix(options, dir, "short_memory")?,
    ];
    let csv = points_csv(&points);
    let check = check(&points, &matrices);
    let mut table = print(&points);
    writeln!(table, "{}", check.statement)?;
    write_atomically(
        &dir.join("fault-cells.csv"),
        cells_csv(&matrices).as_bytes(),
    )?;
    ComputedReport::write(
        dir,
        "consensus-at-scale",
        &csv,
        |svg| draw(svg, &points),
        check,
        table,
    )
}

fn find<'a>(points: &'a [Point], side: u32, protocol: &str, rounds: Option<u32>) -> &'a Point {
    points
        .iter()
        .find(|p| p.side == side && p.protocol == protocol && p.rounds == rounds)
        .expect("every point is measured")
}

/// The margin of "no worse": a tenth of the reference's figure.
const MARGIN: f64 = 0.1;

/// "`a` no worse than `b`, within a tenth of `b`": holds when the whole
/// paired interval of `a − b` is below the margin, does not when all of
/// it is at or above, and is not resolved otherwise.
fn within_margin(p: &Paired, reference: f64) -> Verdict {
    p.verdict_within(f64::NEG_INFINITY, MARGIN * reference)
}

fn mean_of(runs: &[Option<f64>]) -> f64 {
    let v: Vec<f64> = runs.iter().flatten().copied().collect();
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// `a` against `b` run by run: no worse than `b` within a tenth of it.
fn no_worse(claim: String, a: &[Option<f64>], b: &[Option<f64>]) -> Claim {
    let reference = mean_of(b);
    Claim::judged(
        claim,
        Paired::of(a, b),
        |p| within_margin(p, reference),
        metres,
    )
}

fn metres(p: &Paired) -> String {
    format!("{} m over {} runs", p.text(3), p.runs)
}

fn check(points: &[Point], matrices: &[super::Outcome; 2]) -> Check {
    let mut claims = Vec::new();
    let forty = find(points, 10, "average", Some(40));
    let short = find(points, 10, "short_memory", Some(15));
    claims.push(no_worse(
        "10 × 10: short memory at 15 rounds tracks no worse than average consensus at 40, within 10 % (RMSE, paired)".into(),
        &short.rmse_runs(),
        &forty.rmse_runs(),
    ));
    claims.push(no_worse(
        "10 × 10: short memory at 15 rounds has a CQ/dPCRLB no worse than average consensus at 40, within 10 %".into(),
        &short.bound_runs(),
        &forty.bound_runs(),
    ));
    let twenty = find(points, 10, "short_memory", Some(20));
    claims.push(no_worse(
        "10 × 10: short memory at 20 rounds tracks no worse than average consensus at 40, within 10 % (RMSE, paired)".into(),
        &twenty.rmse_runs(),
        &forty.rmse_runs(),
    ));
    claims.push(no_worse(
        "10 × 10: short memory at 20 rounds has a CQ/dPCRLB no worse than average consensus at 40, within 10 %".into(),
        &twenty.bound_runs(),
        &forty.bound_runs(),
    ));
    let auto = find(points, 10, "average", None);
    claims.push(no_worse(
        format!(
            "10 × 10: rounds = \"auto\" ({} rounds) tracks no worse than 40 rounds, within 10 % (RMSE, paired)",
            auto.ran
        ),
        &auto.rmse_runs(),
        &forty.rmse_runs(),
    ));
    // The same messages a round: bytes per step over rounds, equal to the
    // byte for every grid and number of rounds.
    let same_bytes = SIDES.iter().all(|&side| {
        ROUNDS.iter().all(|&r| {
            let a = find(points, side, "average", Some(r)).consensus_bytes_per_step();
            let s = find(points, side, "short_memory", Some(r)).consensus_bytes_per_step();
            a == s
        })
    });
    claims.push(Claim::exact(
        "short memory sends average consensus's bytes per round on every grid at every number of rounds",
        same_bytes,
    ));
    let memory = &matrices[1];
    let cells = cell_verdicts(matrices);
    let named = |pick: fn(&Verdict) -> bool| {
        cells
            .iter()
            .filter(|(_, v)| pick(v))
            .map(|(l, _)| l.as_str())
            .collect::<Vec<_>>()
    };
    let worse = named(|v| *v == Verdict::DoesNotHold);
    let open = named(|v| matches!(v, Verdict::NotResolved { .. }));
    claims.push(Claim {
        claim: format!(
            "in every fault-matrix arm short memory tracks no worse than average consensus, within 10 % (RMSE, paired): {} of {} hold{}{}",
            cells.len() - worse.len() - open.len(),
            cells.len(),
            if worse.is_empty() { String::new() } else { format!("; worse in: {}", worse.join("; ")) },
            if open.is_empty() { String::new() } else { format!("; not resolved in: {}", open.join("; ")) },
        ),
        paired: None,
        interval: String::new(),
        verdict: Verdict::all(cells.iter().map(|(_, v)| *v)),
    });
    // Worse beyond the paired interval: its whole interval above zero.
    let beyond: Vec<&str> = matrices[1]
        .arms
        .iter()
        .zip(&matrices[0].arms)
        .filter(|(a, b)| {
            Paired::of(&a.per_run_rmse, &b.per_run_rmse)
                .is_none_or(|p| p.order() == super::paired::Order::Higher)
        })
        .map(|(a, _)| a.label.as_str())
        .collect();
    claims.push(Claim::exact(
        format!(
            "in no fault-matrix arm is short memory's RMSE worse than average consensus's beyond the paired interval{}",
            if beyond.is_empty() { String::new() } else { format!(" (worse in: {})", beyond.join("; ")) }
        ),
        beyond.is_empty(),
    ));
    let complete = memory
        .arms
        .iter()
        .all(|a| a.unaccounted_messages == 0 && a.per_run_rmse.iter().all(Option::is_some));
    claims.push(Claim::exact(
        "every fault-matrix cell with short memory completes every run with every message accounted for",
        complete,
    ));
    let figures = SIDES
        .iter()
        .map(|&side| {
            let r = |protocol, rounds| find(points, side, protocol, Some(rounds)).mc.estimates.rmse.unwrap_or(f64::NAN);
            format!(
                "{side}×{side}: RMSE at 10 rounds {:.2} m (average) / {:.2} m (short memory), at 40 {:.2} / {:.2}",
                r("average", 10),
                r("short_memory", 10),
                r("average", 40),
                r("short_memory", 40)
            )
        })
        .collect::<Vec<_>>()
        .join("; ");
    Check::of_claims(claims, figures)
}

fn points_csv(points: &[Point]) -> String {
    let mut out = String::from(
        "grid,protocol,rounds,auto,runs,rmse,bound,centralized_bound,disagreement,lost_tracks,consensus_bytes_per_step,consensus_bytes_per_round\n",
    );
    let v = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x}"));
    for p in points {
        let bytes = p.consensus_bytes_per_step();
        let _ = writeln!(
            out,
            "{0}x{0},{1},{2},{3},{4},{5},{6},{7},{8},{9},{10},{11}",
            p.side,
            p.protocol,
            p.ran,
            p.rounds.is_none(),
            p.mc.per_run.len(),
            v(p.mc.estimates.rmse),
            v(p.mc.estimates.mean_bound),
            v(p.mc.estimates.mean_centralized_bound),
            v(p.disagreement()),
            p.lost,
            bytes,
            bytes / f64::from(p.ran)
        );
    }
    out
}

/// Each fault-matrix arm's verdict: short memory no worse than average
/// consensus within a tenth of its RMSE, run by run.
fn cell_verdicts(matrices: &[super::Outcome; 2]) -> Vec<(String, Verdict)> {
    matrices[1]
        .arms
        .iter()
        .zip(&matrices[0].arms)
        .map(|(a, b)| {
            let verdict = Paired::of(&a.per_run_rmse, &b.per_run_rmse)
                .map_or(Verdict::DoesNotHold, |p| {
                    within_margin(&p, mean_of(&b.per_run_rmse))
                });
            (a.label.clone(), verdict)
        })
        .collect()
}

fn cells_csv(matrices: &[super::Outcome; 2]) -> String {
    let mut out = String::from(
        "arm,rmse_average,rmse_short_memory,paired_difference,half_width_95,runs,verdict,unaccounted_short_memory\n",
    );
    let verdicts = cell_verdicts(matrices);
    for ((a, b), (_, verdict)) in matrices[1].arms.iter().zip(&matrices[0].arms).zip(verdicts) {
        let p = Paired::of(&a.per_run_rmse, &b.per_run_rmse);
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{}",
            a.label.replace(',', ";"),
            mean_of(&b.per_run_rmse),
            mean_of(&a.per_run_rmse),
            p.map_or(String::new(), |p| p.mean.to_string()),
            p.map_or(String::new(), |p| p.half_width.to_string()),
            p.map_or(0, |p| p.runs),
            verdict.label(),
            a.unaccounted_messages
        );
    }
    out
}

fn print(points: &[Point]) -> String {
    let mut out = String::from(
        "grid    protocol      rounds   RMSE, m   CQ/dPCRLB, m   centralized, m   disagreement   lost   consensus B/step\n",
    );
    let v = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{x:.3}"));
    for p in points {
        let _ = writeln!(
            out,
            "{:<7} {:<13} {:>6}{} {:>9} {:>14} {:>16} {:>13} {:>6} {:>18.0}",
            format!("{0}x{0}", p.side),
            p.protocol,
            p.ran,
            if p.rounds.is_none() { "*" } else { " " },
            v(p.mc.estimates.rmse),
            v(p.mc.estimates.mean_bound),
            v(p.mc.estimates.mean_centralized_bound),
            p.disagreement()
                .map_or("-".to_string(), |d| format!("{:.1} %", 100.0 * d)),
            p.lost,
            p.consensus_bytes_per_step()
        );
    }
    out.push_str("* rounds = \"auto\" at the default consensus.accuracy\n");
    let _ = writeln!(
        out,
        "lost: node tracks, over the runs, more than {LOST} m off at the last step"
    );
    out
}

/// A panel a grid: RMSE (solid) and CQ/dPCRLB (dashed) against rounds for
/// each protocol, the centralized bound as a level line, on log axes.
fn draw(path: &Path, points: &[Point]) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (1500, 520)).into_drawing_area();
    root.fill(&WHITE)?;
    let panels = root.split_evenly((1, SIDES.len()));
    for (panel, side) in panels.iter().zip(SIDES) {
        let of = |protocol: &str, f: fn(&Point) -> Option<f64>| -> Vec<(f64, f64)> {
            ROUNDS
                .iter()
                .filter_map(|&r| {
                    let p = find(points, side, protocol, Some(r));
                    f(p).filter(|v| *v > 0.0).map(|v| (f64::from(r), v))
                })
                .collect()
        };
        let rmse = |p: &Point| p.mc.estimates.rmse;
        let bound = |p: &Point| p.mc.estimates.mean_bound;
        let central = find(points, side, "average", Some(ROUNDS[0]))
            .mc
            .estimates
            .mean_centralized_bound;
        let values: Vec<f64> = PROTOCOLS
            .iter()
            .flat_map(|p| of(p, rmse).into_iter().chain(of(p, bound)))
            .map(|(_, v)| v)
            .chain(central)
            .collect();
        let lo = values
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
            .max(1e-3)
            * 0.8;
        let hi = values.iter().copied().fold(0.0, f64::max).max(lo * 2.0) * 1.25;
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{side} × {side} nodes"), ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((4.0f64..100.0).log_scale(), (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("consensus rounds")
            .y_desc("position RMSE and bound, m")
            .draw()?;
        for (i, protocol) in PROTOCOLS.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            chart
                .draw_series(LineSeries::new(of(protocol, rmse), colour.stroke_width(2)))?
                .label(format!("{protocol}: RMSE"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                });
            chart
                .draw_series(DashedLineSeries::new(
                    of(protocol, bound),
                    6,
                    4,
                    colour.stroke_width(1),
                ))?
                .label(format!("{protocol}: CQ/dPCRLB"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(1))
                });
        }
        if let Some(c) = central {
            chart
                .draw_series(LineSeries::new(
                    [(4.0, c), (100.0, c)],
                    BLACK.stroke_width(1),
                ))?
                .label("centralized bound")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1))
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
    }
    root.present()?;
    Ok(())
}
