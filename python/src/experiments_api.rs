//! The papers' experiments for Python: the list, and one run as a job
//! whose outcome is its verdicts, claims and the files it wrote.

use std::path::PathBuf;

use experiments::{self as experiment, Check, Entry, Verdict};
use pyo3::prelude::*;
use serde_json::json;

use crate::jobs::{start_experiment_job, Job, Shared};
use crate::to_py_err;

/// Every experiment as (name, source, about).
#[pyfunction]
fn list_experiments() -> Vec<(&'static str, &'static str, &'static str)> {
    experiment::catalogue()
        .iter()
        .map(|e| (e.name, e.source, e.about))
        .chain(
            experiment::computed_catalogue()
                .iter()
                .map(|c| (c.name, c.source, c.about)),
        )
        .collect()
}

/// The runs that would resolve a claim not resolved, when known.
fn runs_to_resolve(v: &Verdict) -> Option<usize> {
    match v {
        Verdict::NotResolved { needed, .. } => *needed,
        _ => None,
    }
}

fn check_json(check: &Check) -> serde_json::Value {
    let claims: Vec<serde_json::Value> = check
        .claims
        .iter()
        .map(|c| {
            json!({
                "claim": c.claim,
                "verdict": c.verdict.label(),
                "runs_to_resolve": runs_to_resolve(&c.verdict),
                "mean_difference": c.paired.map(|p| p.mean),
                "half_width_95": c.paired.map(|p| p.half_width),
                "runs": c.paired.map(|p| p.runs),
                "interval": c.interval,
                "said": c.said(),
            })
        })
        .collect();
    json!({
        "verdict": check.verdict.label(),
        "verdict_words": check.verdict.words(),
        "statement": check.statement,
        "claims": claims,
    })
}

/// Starts `cqnet experiment NAME` into `out/NAME/`. The outcome: the
/// experiment's name, source, verdict, claims and the files it wrote.
#[pyfunction]
#[pyo3(signature = (name, out, runs = 20, steps = None, threads = None, trajectories = 1000))]
fn start_experiment(
    name: &str,
    out: PathBuf,
    runs: u32,
    steps: Option<u32>,
    threads: Option<usize>,
    trajectories: usize,
) -> PyResult<Job> {
    if runs == 0 {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "runs must be at least 1",
        ));
    }
    let entry = experiment::find_entry(name).map_err(|e| to_py_err(&e))?;
    let threads = threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    let folder = out.clone();
    start_experiment_job(out, move |shared| {
        let options = experiment::Options {
            runs,
            steps,
            threads,
            out: folder,
            trajectories,
            stop: shared.stop.clone(),
            small: false,
        };
        run_entry(entry, &options, shared)
    })
}

/// Runs the experiment, telling `shared` how far it has come; its outcome as JSON text.
fn run_entry(
    entry: Entry,
    options: &experiment::Options,
    shared: &Shared,
) -> anyhow::Result<String> {
    let runs = options.runs;
    match entry {
        Entry::Network(e) => {
            let total = (e.arms.len() as u64) * runs as u64;
            shared.set_runs(0, total, e.arms[0].label.to_string());
            let report = experiment::run(&e, options, &|arm, done| {
                let before = arm as u64 * runs as u64;
                shared.set_runs(before + done as u64, total, e.arms[arm].label.to_string());
            })?;
            let dir = options.out.join(e.name);
            Ok(json!({
                "name": e.name,
                "source": e.source,
                "about": e.about,
                "line": experiment::verdict_line(&e, &report.outcome, &report.check),
                "check": check_json(&report.check),
                "dir": dir,
                "csv": report.csv,
                "svg": report.svg,
                "claims_csv": dir.join("claims.csv"),
            })
            .to_string())
        }
        Entry::Computed(c) => {
            shared.set_runs(0, 1, c.name.to_string());
            let report = experiment::run_computed(&c, options)?;
            shared.set_runs(1, 1, c.name.to_string());
            let dir = options.out.join(c.name);
            Ok(json!({
                "name": c.name,
                "source": c.source,
                "about": c.about,
                "line": experiment::computed_verdict_line(&c, &report.check),
                "check": check_json(&report.check),
                "table": report.table,
                "dir": dir,
                "csv": report.csv,
                "svg": report.svg,
                "claims_csv": dir.join("claims.csv"),
            })
            .to_string())
        }
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(list_experiments, m)?)?;
    m.add_function(wrap_pyfunction!(start_experiment, m)?)?;
    Ok(())
}
