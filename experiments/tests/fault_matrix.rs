//! The fault matrix: every fault kind at two scopes, on the
//! virtual clock, each cell against the run with no fault. Each cell must
//! complete, account for every message, and bring the RMSE back to within
//! `RECOVERY_FACTOR` of the no-fault run's after the fault ends; it prints
//! its time to recover. Every arm runs with the innovation gate on (see
//! `faults::GATE`): without it, 30% stuck or Byzantine sensors leave the
//! fused estimate 20 m off and its particles sure of it, and honest
//! bearings take far more than the 25 steps left to pull it back
//! (`the_innovation_gate_holds_off_byzantine_sensors` measures the
//! Byzantine case both ways).
//! Real processes add nothing here that
//! `tests/network.rs` does not already show for kills and link faults.

use experiments::{self as experiment, faults, Options};

fn run(name: &str, runs: u32) -> experiment::Report {
    let out = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("{name}-{}", std::process::id()));
    let options = Options {
        runs,
        steps: None,
        threads: 2,
        out: out.clone(),
        trajectories: 0,
        stop: Default::default(),
        small: false,
    };
    let report = experiment::run(&experiment::find(name).unwrap(), &options, &|_, _| {}).unwrap();
    assert!(std::fs::read_to_string(&report.svg)
        .unwrap()
        .contains("</svg>"));
    let _ = std::fs::remove_dir_all(&out);
    report
}

#[test]
fn every_fault_kind_at_both_scopes_completes_balances_and_recovers() {
    // One seed per arm: sim is deterministic, and the cells' margins (see
    // the printed table) are wide; each cell's claim is exact.
    let report = run("fault-matrix", 1);
    let cells = faults::cells(&report.outcome);
    assert_eq!(cells.len(), faults::MATRIX.len() - 1);
    for c in &cells {
        eprintln!(
            "{:<30} during {:>6.1} m  after {:>6.1} m (no fault {:>5.1} m)  recovered after {:?} steps  unaccounted {}",
            c.label,
            c.rmse_during.unwrap_or(f64::NAN),
            c.rmse_after.unwrap_or(f64::NAN),
            c.reference_after.unwrap_or(f64::NAN),
            c.recovered_after,
            c.unaccounted_messages
        );
    }
    // The no-fault run balances too, or the cells' zeros would mean nothing.
    assert_eq!(report.outcome.arms[0].unaccounted_messages, 0);
    for c in &cells {
        assert_eq!(c.unaccounted_messages, 0, "{}", c.label);
        assert!(c.passes(), "{c:#?}");
    }
}

#[test]
fn the_innovation_gate_holds_off_byzantine_sensors() {
    // Three seeds: the claims compare the arms run by run, and need an
    // interval.
    let report = run("byzantine", 3);
    eprintln!("{}", report.check.statement);
    assert!(report.check.verdict.holds(), "{}", report.check.statement);
}
