//! Every experiment of `cqnet experiment` runs at a small size, so that the
//! machinery (arms, Monte Carlo, series, non-conditional bound, CSV, SVG,
//! check) cannot rot. The papers' results themselves need the full size;
//! their figures are in docs/experiments.md.

use experiments::{self as experiment, Figure, Options};

/// A folder of this test process's own, and the options that run every
/// experiment small into it: 2 runs of 12 steps, few trials and draws.
fn small(name: &str) -> (std::path::PathBuf, Options) {
    let out = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("{name}-{}", std::process::id()));
    let options = Options {
        runs: 2,
        steps: Some(12),
        threads: 2,
        out: out.clone(),
        trajectories: 50,
        stop: Default::default(),
        small: true,
    };
    (out, options)
}

#[test]
fn every_experiment_runs_small_and_writes_its_csv_svg_and_check() {
    let (out, options) = small("experiments");
    let catalogue = experiment::catalogue();
    assert!(
        catalogue.len() >= 4,
        "the CQ/dPCRLB paper's four experiments"
    );
    // The fault experiments need their 60 steps (the faults hold for steps
    // 20-34); `tests/fault_matrix.rs` runs them at that size.
    for e in catalogue
        .iter()
        .filter(|e| !matches!(e.name, "fault-matrix" | "byzantine"))
    {
        let report = experiment::run(e, &options, &|_, _| {}).unwrap();
        assert_eq!(report.outcome.runs, 2, "{}", e.name);
        assert_eq!(report.outcome.arms.len(), e.arms.len(), "{}", e.name);

        let csv = std::fs::read_to_string(&report.csv).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        match &e.figure {
            Figure::OverTime { curves, .. } | Figure::OverTimeAndDesign { curves, .. } => {
                assert_eq!(
                    lines.len(),
                    1 + 12,
                    "{}: a header and a row per step",
                    e.name
                );
                // Every curve has a value at every step: nothing the figure
                // draws is missing from the runs.
                for row in &lines[1..] {
                    let cells: Vec<&str> = row.split(',').collect();
                    assert_eq!(cells.len(), 1 + curves.len(), "{}: {row}", e.name);
                    for cell in &cells[1..] {
                        let v: f64 = cell.parse().unwrap_or_else(|_| panic!("{}: {row}", e.name));
                        assert!(v.is_finite() && v > 0.0, "{}: {row}", e.name);
                    }
                }
            }
            Figure::Bars { bars, .. } => assert_eq!(lines.len(), 1 + bars.len(), "{}", e.name),
            Figure::Panels { .. } => unreachable!("left out above"),
        }
        if let Figure::OverTimeAndDesign { steps, designs, .. } = &e.figure {
            // Both runs' probabilities at each of the figure's steps, a row
            // each with a column per sensor, and the first run's drawn;
            // for each design drawn.
            let dir = out.join(e.name);
            for (_, suffix) in designs.iter() {
                let stem = format!("{}-{suffix}", e.name);
                let design = std::fs::read_to_string(dir.join(format!("{stem}.csv"))).unwrap();
                let mut lines = design.lines();
                let columns = lines.next().unwrap().split(',').count();
                let rows: Vec<&str> = lines.collect();
                assert_eq!(rows.len(), 2 * steps.len(), "{stem}: {} rows", rows.len());
                for row in &rows {
                    let cells: Vec<&str> = row.split(',').collect();
                    assert_eq!(cells.len(), columns, "{stem}: {row}");
                    assert!(columns > 4, "{stem}: no sensor columns");
                    for cell in &cells[4..] {
                        let p: f64 = cell.parse().unwrap();
                        assert!((0.0..=1.0).contains(&p), "{stem}: {row}");
                    }
                }
                let svg = std::fs::read_to_string(dir.join(format!("{stem}.svg"))).unwrap();
                assert!(svg.contains("<circle"), "{stem}: no sensors drawn");
            }
        }
        let svg = std::fs::read_to_string(&report.svg).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.contains("</svg>"),
            "{}",
            e.name
        );
        assert!(svg.contains(e.name), "{}: the figure is titled", e.name);
        let check = std::fs::read_to_string(out.join(e.name).join("check.txt")).unwrap();
        // The verdict is stated either way; at this size it need not hold.
        let verdict = format!(": {}: ", report.check.verdict.words());
        assert!(
            check.contains(&verdict) && check.contains(&report.check.statement),
            "{}: {check}",
            e.name
        );
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// Every experiment computed from a paper's formulas, run small: a few
/// trials, deployments and draws each, so that its parts, its CSV, SVG,
/// tables and claims cannot rot. Its verdicts need the full size.
#[test]
fn every_computed_experiment_runs_small_and_writes_its_files() {
    let (out, options) = small("computed");
    let catalogue = experiment::computed_catalogue();
    assert!(
        catalogue.len() >= 10,
        "{} computed experiments",
        catalogue.len()
    );
    // random-exchange-cost runs real processes, which this test binary
    // cannot be; `tests/tests/random_exchange.rs` runs each of its
    // trackers as a real network and checks its bytes.
    for c in catalogue
        .iter()
        .filter(|c| c.name != "random-exchange-cost")
    {
        let report =
            experiment::run_computed(c, &options).unwrap_or_else(|e| panic!("{}: {e:#}", c.name));
        let csv = std::fs::read_to_string(&report.csv).unwrap();
        assert!(csv.lines().count() > 1, "{}: a header and rows", c.name);
        let svg = std::fs::read_to_string(&report.svg).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.contains("</svg>"),
            "{}",
            c.name
        );
        let dir = out.join(c.name);
        let check = std::fs::read_to_string(dir.join("check.txt")).unwrap();
        assert!(
            check.starts_with(c.name) && check.contains(report.check.verdict.words().as_str()),
            "{}: {check}",
            c.name
        );
        let claims = std::fs::read_to_string(dir.join("claims.csv")).unwrap();
        assert!(claims.starts_with("claim,"), "{}", c.name);
        assert!(!report.table.is_empty(), "{}: its tables", c.name);
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn an_unknown_experiment_is_a_clear_error_naming_the_known_ones() {
    let err = experiment::find("no-such-experiment")
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("no-such-experiment") && err.contains("bound-against-bits"),
        "{err}"
    );
}
