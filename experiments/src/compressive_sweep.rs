//! Where the chapter 4 claims hold: `cs-sensor-management`'s arms over the
//! receiver's noise ε (0.01 to 10) and the amplitude's decay exponent n (1
//! to 4), the two choices the chapter leaves unstated, with each Fig. 4.1
//! claim judged for each design in every cell.

use std::fmt::Write as _;
use std::path::Path;

use fusion_graph::scenario::COMPRESSIVE_SCENARIO;
use plotters::prelude::*;

use super::compressive::{figure_4_1_claims, promise_claim, whole_run_rmse, ARMS, CURVES, DESIGNS};
use super::paired::{Order, Paired};
use super::{
    Check, Claim, Computed, ComputedReport, Experiment, Figure, Options, Outcome, Verdict,
};

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "cs-design-sweep",
        source: "Zheng (dissertation), ch. 4, Fig. 4.1's claims over the chapter's unstated choices",
        about: "cs-sensor-management's arms over the receiver's noise epsilon (0.01, 0.1, 1, 10) and the decay exponent n (1 to 4), paired over --runs runs in each cell: each Fig. 4.1 claim for the chapter's design (eq. 4.19) and for the design that counts a repeated sensor once, and each design's promised bound against its drawn matrix's",
        run,
    }]
}

const EPSILONS: [f64; 4] = [0.01, 0.1, 1.0, 10.0];
const EXPONENTS: [f64; 4] = [1.0, 2.0, 3.0, 4.0];

/// One (ε, n) cell's outcome.
struct Cell {
    epsilon: f64,
    exponent: f64,
    outcome: Outcome,
}

fn run(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let mut cells = Vec::new();
    for exponent in EXPONENTS {
        for epsilon in EPSILONS {
            // Run small, the grid's two corners exercise every part.
            let corner = (epsilon, exponent) == (EPSILONS[0], EXPONENTS[0])
                || (epsilon, exponent) == (EPSILONS[3], EXPONENTS[3]);
            if options.small && !corner {
                continue;
            }
            eprintln!("  ε = {epsilon}, n = {exponent}");
            cells.push(Cell {
                epsilon,
                exponent,
                outcome: measure(options, dir, epsilon, exponent)?,
            });
        }
    }
    let mut csv = String::from(
        "epsilon,exponent,design,claim,paired_difference,half_width_95,runs,verdict\n",
    );
    let mut table = String::from("ε      n   design          claims that hold\n");
    for c in &cells {
        for (design, arms) in DESIGNS {
            let mut claims = figure_4_1_claims(&c.outcome, design, arms);
            claims.push(promise_claim(&c.outcome, design, arms[2]));
            let holds: Vec<String> = claims
                .iter()
                .enumerate()
                .filter(|(_, k)| k.verdict == Verdict::Holds)
                .map(|(i, _)| (i + 1).to_string())
                .collect();
            let _ = writeln!(
                table,
                "{:<6} {:<3} {:<15} {} of {} ({})",
                c.epsilon,
                c.exponent,
                design,
                holds.len(),
                claims.len(),
                holds.join(" ")
            );
            for k in &claims {
                let _ = writeln!(
                    csv,
                    "{},{},{},\"{}\",{},{},{},{}",
                    c.epsilon,
                    c.exponent,
                    design,
                    k.claim.replace('"', "'"),
                    k.paired.map_or(String::new(), |p| p.mean.to_string()),
                    k.paired.map_or(String::new(), |p| p.half_width.to_string()),
                    k.paired.map_or(0, |p| p.runs),
                    k.verdict.label()
                );
            }
        }
    }
    let _ = writeln!(
        table,
        "claims: 1 M = 6 beats random; 2 M = 6 beats every sensor alike in 6 slots; 3 M = 6 nearer all-send than random; 4 M = 3 beats M = 1; 5 M = 6 beats M = 3; 6 promise within 10 %"
    );
    let check = check(&cells);
    writeln!(table, "{}", check.statement)?;
    ComputedReport::write(
        dir,
        "cs-design-sweep",
        &csv,
        |svg| draw(svg, &cells),
        check,
        table,
    )
}

/// `cs-sensor-management`'s arms with the cell's ε and n.
fn measure(options: &Options, dir: &Path, epsilon: f64, exponent: f64) -> anyhow::Result<Outcome> {
    // An experiment's name and base are static: 16 cells' worth of short
    // strings, kept for the process's life, which is the experiment's.
    let leak = |s: String| -> &'static str { Box::leak(s.into_boxed_str()) };
    let base: &'static [&'static str] = Box::leak(Box::new([
        leak(format!("channel.receiver_noise={epsilon}")),
        leak(format!("observation.exponent={exponent}")),
    ]));
    let experiment = Experiment {
        name: leak(format!("cs-eps{epsilon}-n{exponent}")),
        source: "Zheng (dissertation), ch. 4",
        about: "one cell of cs-design-sweep",
        scenario: COMPRESSIVE_SCENARIO,
        base,
        arms: &ARMS,
        figure: Figure::OverTime {
            y_label: "position RMSE, m",
            curves: &CURVES,
        },
        // Judged in the sweep's own table.
        check: |_| Check {
            verdict: Verdict::Holds,
            statement: "not judged alone: cs-design-sweep judges each cell".into(),
            claims: Vec::new(),
        },
    };
    let sub = Options {
        runs: options.runs,
        steps: options.sized(None, options.steps),
        threads: options.threads,
        out: dir.to_path_buf(),
        trajectories: options.trajectories,
        stop: options.stop.clone(),
        small: options.small,
    };
    Ok(super::runner::run(&experiment, &sub, &|_, _| {})?.outcome)
}

/// The sweep's own claims: the corrected design keeps its promise in every
/// cell, and at M = 6 it tracks better than the chapter's in every cell.
fn check(cells: &[Cell]) -> Check {
    let (design, arms) = DESIGNS[1];
    let broken: Vec<String> = cells
        .iter()
        .filter(|c| promise_claim(&c.outcome, design, arms[2]).verdict != Verdict::Holds)
        .map(|c| format!("ε = {}, n = {}", c.epsilon, c.exponent))
        .collect();
    let mut claims = vec![Claim::exact(
        format!(
            "counted once, M = 6: the promised bound is within 10 % of the drawn Φ's in every cell{}",
            if broken.is_empty() { String::new() } else { format!(" (not in: {})", broken.join("; ")) }
        ),
        broken.is_empty(),
    )];
    for c in cells {
        let ours = whole_run_rmse(c.outcome.arm(arms[2]));
        let chapter = whole_run_rmse(c.outcome.arm(DESIGNS[0].1[2]));
        claims.push(Claim::judged(
            format!(
                "ε = {}, n = {}: counted once at M = 6 tracks better than eq. 4.19 at M = 6",
                c.epsilon, c.exponent
            ),
            Paired::of(&ours, &chapter),
            |p| p.verdict(Order::Lower),
            |p| format!("{} m over {} runs", p.text(3), p.runs),
        ));
    }
    Check::of_claims(claims, format!("{} cells", cells.len()))
}

/// Whole-run RMSE over the runs, root mean square.
fn rmse_of(outcome: &Outcome, arm: &str) -> Option<f64> {
    let v: Vec<f64> = whole_run_rmse(outcome.arm(arm))
        .into_iter()
        .flatten()
        .collect();
    (!v.is_empty()).then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
}

/// A panel per n: RMSE against ε (log) for the baselines and each design
/// at M = 6.
fn draw(path: &Path, cells: &[Cell]) -> Result<(), Box<dyn std::error::Error>> {
    let lines: [(&str, &str); 5] = [
        ("all send", "all send"),
        ("random", "random, a channel each"),
        ("uniform, M = 6", "every sensor alike, M = 6"),
        (DESIGNS[0].1[2], "eq. 4.19 design, M = 6"),
        (DESIGNS[1].1[2], "counted once, M = 6"),
    ];
    let root = SVGBackend::new(path, (1600, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let panels = root.split_evenly((1, EXPONENTS.len()));
    let all: Vec<f64> = cells
        .iter()
        .flat_map(|c| lines.iter().filter_map(|(a, _)| rmse_of(&c.outcome, a)))
        .collect();
    let hi = all.iter().copied().fold(0.1, f64::max) * 1.2;
    for (panel, n) in panels.iter().zip(EXPONENTS) {
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("n = {n}"), ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d((0.005f64..20.0).log_scale(), 0.0..hi)?;
        chart
            .configure_mesh()
            .x_desc("receiver noise ε")
            .y_desc("position RMSE, m")
            .draw()?;
        for (i, (arm, label)) in lines.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let points: Vec<(f64, f64)> = cells
                .iter()
                .filter(|c| c.exponent == n)
                .filter_map(|c| rmse_of(&c.outcome, arm).map(|r| (c.epsilon, r)))
                .collect();
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))?
                .label(*label)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour));
            chart.draw_series(points.iter().map(|p| Circle::new(*p, 3, colour.filled())))?;
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
