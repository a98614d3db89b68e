//! `cqnet sim --runs N`: independent runs with seeds seed, seed+1, …, spread
//! over worker threads, each writing its own folder, and a summary that
//! averages over runs.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Mutex;

use fusion_graph::scenario::Scenario;
use fusion_graph::Topology;
use serde::{Deserialize, Serialize};

use crate::results::{Estimates, ResultsWriter, StepSeries, AVERAGE_FROM_STEP};
use crate::sim::run_in_process_until;
use crate::summary::{StepMeans, Summary};

/// Means over runs of each run's averages.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct MonteCarloSummary {
    pub runs: u32,
    /// Each figure the mean over runs of that run's figure (a run's RMSE is
    /// over its nodes and steps; these are not pooled over runs).
    pub estimates: Estimates,
    pub bound_bytes_cq_dpcrlb: f64,
    pub bound_bytes_auxiliary_fim: Option<f64>,
    pub steps_per_second_per_run: f64,
    pub wall_seconds: f64,
    pub per_run: Vec<Summary>,
    /// Per-step sums over every run's nodes, for figures over time.
    #[serde(skip)]
    pub series: StepSeries,
    /// Each run's per-step means over its nodes, in run order: what an
    /// interval over runs at each step is taken from.
    #[serde(skip)]
    pub per_run_series: Vec<Vec<StepMeans>>,
}

fn mean_of(values: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = values.collect::<Option<Vec<f64>>>()?;
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Runs `runs` seeds over `threads` workers; `on_run_done` hears the
/// number of runs finished so far, after each.
pub fn run_monte_carlo(
    scenario: &Scenario,
    topology: &Topology,
    out: &Path,
    runs: u32,
    threads: usize,
    centralized: bool,
    on_run_done: &(dyn Fn(u32) + Sync),
) -> anyhow::Result<MonteCarloSummary> {
    run_monte_carlo_until(
        scenario,
        topology,
        out,
        runs,
        threads,
        centralized,
        on_run_done,
        &AtomicBool::new(false),
    )
}

/// [`run_monte_carlo`] that a caller can stop by setting `stop`: each
/// worker stops its run between steps and starts no other, and it fails
/// saying so.
#[allow(clippy::too_many_arguments)]
pub fn run_monte_carlo_until(
    scenario: &Scenario,
    topology: &Topology,
    out: &Path,
    runs: u32,
    threads: usize,
    centralized: bool,
    on_run_done: &(dyn Fn(u32) + Sync),
    stop: &AtomicBool,
) -> anyhow::Result<MonteCarloSummary> {
    let started = std::time::Instant::now();
    let next = AtomicU32::new(0);
    let done = AtomicU32::new(0);
    let results: Mutex<Vec<Option<anyhow::Result<Summary>>>> =
        Mutex::new((0..runs).map(|_| None).collect());
    // Each run's sums, merged in run order once all are done: merged as
    // they finished, the sums' rounding (and a mean's last digit) would
    // change from one invocation to the next.
    let run_sums: Mutex<Vec<Option<StepSeries>>> = Mutex::new(vec![None; runs as usize]);
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1).min(runs as usize) {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                if i >= runs || stop.load(Ordering::Relaxed) {
                    return;
                }
                let mut s = scenario.clone();
                s.seed = scenario.seed.wrapping_add(i as u64);
                let mut run_series = StepSeries::default();
                let result =
                    ResultsWriter::create(&out.join(format!("run-{i:03}"))).and_then(|mut w| {
                        run_in_process_until(
                            &s,
                            topology,
                            &mut w,
                            centralized,
                            |_, rows| rows.iter().for_each(|r| run_series.add(r)),
                            stop,
                        )
                    });
                if result.is_ok() {
                    run_sums
                        .lock()
                        .expect("no worker panics while holding the lock")[i as usize] =
                        Some(run_series);
                }
                results
                    .lock()
                    .expect("no worker panics while holding the lock")[i as usize] = Some(result);
                on_run_done(done.fetch_add(1, Ordering::SeqCst) + 1);
            });
        }
    });
    if stop.load(Ordering::Relaxed) {
        anyhow::bail!(
            "interrupted; the runs' results so far are in {}",
            out.display()
        );
    }
    let run_sums = run_sums.into_inner().expect("workers finished");
    let mut series = StepSeries::default();
    for run in run_sums.iter().flatten() {
        series.merge(run);
    }
    let per_run_series: Vec<Vec<StepMeans>> = run_sums
        .iter()
        .map(|run| run.as_ref().map(StepSeries::means).unwrap_or_default())
        .collect();
    let per_run: Vec<Summary> = results
        .into_inner()
        .expect("workers finished")
        .into_iter()
        .map(|r| r.expect("every run ran"))
        .collect::<anyhow::Result<_>>()?;
    let e = |f: fn(&Summary) -> Option<f64>| mean_of(per_run.iter().map(f));
    let estimates = Estimates {
        from_step: AVERAGE_FROM_STEP,
        rmse: e(|s| s.estimates.rmse),
        mean_bound: e(|s| s.estimates.mean_bound),
        mean_local_bound: e(|s| s.estimates.mean_local_bound),
        mean_aux_bound: e(|s| s.estimates.mean_aux_bound),
        centralized_rmse: e(|s| s.estimates.centralized_rmse),
        mean_centralized_bound: e(|s| s.estimates.mean_centralized_bound),
    };
    Ok(MonteCarloSummary {
        runs,
        estimates,
        bound_bytes_cq_dpcrlb: per_run
            .iter()
            .map(|s| s.bound_traffic.cq_dpcrlb_bytes as f64)
            .sum::<f64>()
            / runs as f64,
        bound_bytes_auxiliary_fim: mean_of(
            per_run
                .iter()
                .map(|s| s.bound_traffic.auxiliary_fim_bytes.map(|b| b as f64)),
        ),
        steps_per_second_per_run: per_run.iter().map(|s| s.steps_per_second).sum::<f64>()
            / runs as f64,
        wall_seconds: started.elapsed().as_secs_f64(),
        per_run,
        series,
        per_run_series,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two threads finish their runs in whatever order the machine lets
    /// them; the summary and the per-step series must be the ones a single
    /// thread gives, to the bit.
    #[test]
    fn the_summary_does_not_depend_on_the_threads() {
        let sets = ["steps=6".to_string(), "sensors.per_cell=[2, 2]".to_string()];
        let scenario =
            Scenario::from_toml(fusion_graph::scenario::DEFAULT_SCENARIO, "default", &sets)
                .unwrap();
        let topology = Topology::from_scenario(&scenario, "default").unwrap();
        let dir = std::env::temp_dir().join(format!("cqnet-montecarlo-{}", std::process::id()));
        let run = |threads: usize| {
            let out = dir.join(format!("threads-{threads}"));
            let stop = AtomicBool::new(false);
            run_monte_carlo_until(
                &scenario,
                &topology,
                &out,
                12,
                threads,
                true,
                &|_| {},
                &stop,
            )
            .unwrap()
        };
        let (one, two) = (run(1), run(2));
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(one.series, two.series);
        assert_eq!(one.per_run_series, two.per_run_series);
        assert_eq!(one.estimates, two.estimates);
    }
}
