//! Running a network experiment: every arm as a Monte Carlo, then its CSV,
//! SVG, claims and verdict.

use std::path::PathBuf;

use anyhow::Context;
use bounds::pcrlb::nonconditional_pcrlb_random_activation;
use bounds::State;
use fusion_graph::scenario::Scenario;
use fusion_graph::Topology;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use launch::montecarlo::run_monte_carlo_until;
use launch::results::write_atomically;

use crate::claims::{claims_csv, Check};
use crate::model::{Arm, ArmOutcome, Experiment, Figure, Outcome, Series, LOST_TRACK_FACTOR};
use crate::{diagnostics, faults, figure};

#[derive(Clone)]
pub struct Options {
    pub runs: u32,
    /// Steps per run; the scenario's (100) when `None`.
    pub steps: Option<u32>,
    pub threads: usize,
    /// The experiment writes into `<out>/<name>/`.
    pub out: PathBuf,
    /// Trajectories for the non-conditional PCRLB.
    pub trajectories: usize,
    /// Set by the caller to stop the experiment: each Monte Carlo stops
    /// between steps and the experiment fails saying so.
    pub stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    /// Computed experiments at a size that only exercises their machinery
    /// in seconds (the test suite's); their claims need the full size.
    pub small: bool,
}

impl Options {
    /// `full`, or `small` when the experiment is run small.
    pub fn sized<T>(&self, full: T, small: T) -> T {
        if self.small {
            small
        } else {
            full
        }
    }

    /// `--runs` seeds of `scenario` over the worker threads, into
    /// `runs_dir`, with the centralized reference if asked, stopped by
    /// [`stop`](Self::stop): an experiment's arm without a progress bar
    /// of its own.
    pub fn monte_carlo(
        &self,
        scenario: &fusion_graph::Scenario,
        topology: &fusion_graph::Topology,
        runs_dir: &std::path::Path,
        centralized: bool,
    ) -> anyhow::Result<launch::montecarlo::MonteCarloSummary> {
        launch::montecarlo::run_monte_carlo_until(
            scenario,
            topology,
            runs_dir,
            self.runs,
            self.threads,
            centralized,
            &|_| {},
            &self.stop,
        )
    }
}

/// What `run` wrote.
pub struct Report {
    pub outcome: Outcome,
    pub check: Check,
    pub csv: PathBuf,
    pub svg: PathBuf,
}

/// Runs every arm, then writes `<name>.csv`, `<name>.svg` and `check.txt`.
/// `progress` hears (arm index, runs of that arm done).
pub fn run(
    experiment: &Experiment,
    options: &Options,
    progress: &(dyn Fn(usize, u32) + Sync),
) -> anyhow::Result<Report> {
    let dir = options.out.join(experiment.name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut arms = Vec::new();
    for (index, arm) in experiment.arms.iter().enumerate() {
        let (scenario, topology) = arm_scenario(experiment, arm, options.steps)?;
        let runs_dir = dir.join("runs").join(slug(arm.label));
        let mc = run_monte_carlo_until(
            &scenario,
            &topology,
            &runs_dir,
            options.runs,
            options.threads,
            needs(
                experiment,
                index,
                &[Series::CentralizedBound, Series::CentralizedRmse],
            ),
            &|done| progress(index, done),
            &options.stop,
        )
        .with_context(|| format!("arm `{}`", arm.label))?;
        let nonconditional = needs(experiment, index, &[Series::Nonconditional])
            .then(|| nonconditional_bound(&scenario, &topology, options.trajectories))
            .transpose()
            .with_context(|| format!("non-conditional PCRLB of arm `{}`", arm.label))?;
        let per_step = |bytes: f64| bytes / scenario.steps as f64;
        let kinds_per_step = |kinds: &[&str], value: &dyn Fn(&launch::results::Traffic) -> f64| {
            mc.per_run
                .iter()
                .flat_map(|s| {
                    s.traffic
                        .iter()
                        .filter(|t| kinds.contains(&t.kind.as_str()))
                })
                .map(value)
                .fold(0.0, |a, b| a + b)
                / mc.per_run.len().max(1) as f64
        };
        const ACTIVATIONS: [&str; 4] = [
            "activate",
            "activate_feedback",
            "activate_feedback_covariance",
            "activate_slots",
        ];
        // A sensor's transmissions on a multiple-access channel are its
        // observations there.
        const OBSERVATIONS: [&str; 3] = ["observation", "raw_observation", "slot_values"];
        arms.push(ArmOutcome {
            label: arm.label.to_string(),
            steps: mc.series.means(),
            nonconditional,
            bound_bytes_per_step: per_step(mc.bound_bytes_cq_dpcrlb),
            aux_bound_bytes_per_step: mc.bound_bytes_auxiliary_fim.map(per_step),
            selection_bytes_per_step: kinds_per_step(
                &["selection_report", "selection_choice"],
                &|t| t.bytes_per_step,
            ),
            activation_bytes_per_step: kinds_per_step(&ACTIVATIONS, &|t| t.bytes_per_step),
            observation_bytes_per_step: kinds_per_step(&OBSERVATIONS, &|t| t.bytes_per_step),
            observations_per_step: kinds_per_step(&OBSERVATIONS, &|t| t.messages as f64)
                / scenario.steps as f64,
            transmissions_per_step: mc
                .per_run
                .iter()
                .map(|s| s.energy.map_or(0.0, |e| e.per_step))
                .sum::<f64>()
                / mc.per_run.len().max(1) as f64,
            unaccounted_messages: mc
                .per_run
                .iter()
                .flat_map(|s| s.traffic.iter())
                .map(|t| t.unaccounted_messages.unsigned_abs())
                .sum(),
            per_run_rmse: mc.per_run.iter().map(|s| s.estimates.rmse).collect(),
            per_run_bound: mc.per_run.iter().map(|s| s.estimates.mean_bound).collect(),
            per_run_aux_bound: mc
                .per_run
                .iter()
                .map(|s| s.estimates.mean_aux_bound)
                .collect(),
            per_run_centralized_bound: mc
                .per_run
                .iter()
                .map(|s| s.estimates.mean_centralized_bound)
                .collect(),
            diagnostics: diagnostics::Diagnostics::read(&runs_dir, options.runs, &topology)?,
            per_run_series: mc.per_run_series,
        });
    }
    let outcome = Outcome {
        runs: options.runs,
        steps: arms.first().map_or(0, |a| a.steps.len() as u32),
        arms,
    };
    let check = (experiment.check)(&outcome);
    write_atomically(
        &dir.join(format!("{}-bytes.csv", experiment.name)),
        figure::bytes_csv(&outcome).as_bytes(),
    )?;
    let labels: Vec<&str> = outcome.arms.iter().map(|a| a.label.as_str()).collect();
    let diagnostics: Vec<&diagnostics::Diagnostics> =
        outcome.arms.iter().map(|a| &a.diagnostics).collect();
    write_atomically(
        &dir.join(format!("{}-diagnostics.csv", experiment.name)),
        diagnostics::csv(&labels, &diagnostics).as_bytes(),
    )?;
    let csv = dir.join(format!("{}.csv", experiment.name));
    let svg = dir.join(format!("{}.svg", experiment.name));
    write_atomically(&csv, figure::csv(experiment, &outcome).as_bytes())?;
    figure::svg(experiment, &outcome, &svg)?;
    if let Figure::OverTimeAndDesign { designs, steps, .. } = experiment.figure {
        for &(arm, suffix) in designs {
            let (_, topology) = arm_scenario(experiment, &experiment.arms[arm], options.steps)?;
            figure::design(
                &dir,
                &format!("{}-{suffix}", experiment.name),
                &outcome.arms[arm],
                steps,
                &topology.sensor_positions,
            )?;
        }
    }
    if matches!(experiment.figure, Figure::Panels { .. }) {
        write_atomically(
            &dir.join(format!("{}-cells.csv", experiment.name)),
            faults::cells_csv(&outcome).as_bytes(),
        )?;
    }
    write_atomically(
        &dir.join("check.txt"),
        format!("{}\n", verdict_line(experiment, &outcome, &check)).as_bytes(),
    )?;
    write_atomically(&dir.join("claims.csv"), claims_csv(&check).as_bytes())?;
    Ok(Report {
        outcome,
        check,
        csv,
        svg,
    })
}

/// The verdict with the experiment's size, and the tracks lost in each
/// arm (a run whose RMSE is above ten times its bound).
pub fn verdict_line(experiment: &Experiment, outcome: &Outcome, check: &Check) -> String {
    let lost: Vec<String> = outcome
        .arms
        .iter()
        .filter_map(|a| {
            let (lost, of) = a.lost_tracks();
            (of > 0).then(|| format!("{} {lost}/{of}", a.label))
        })
        .collect();
    format!(
        "{} ({}; {} runs of {} steps): {}: {}{}{}",
        experiment.name,
        experiment.source,
        outcome.runs,
        outcome.steps,
        check.verdict.words(),
        check.statement,
        if lost.is_empty() {
            String::new()
        } else {
            format!(
                "; runs with a lost track (RMSE above {LOST_TRACK_FACTOR}× the bound): {}",
                lost.join(", ")
            )
        },
        below_the_centralized_bound(outcome)
    )
}

/// The steps at which an arm's whole 95 % RMSE band lies below the
/// centralized bound of its runs, where the arms have that bound: a lower
/// bound beaten beyond the noise. A one-sided 95 % band misses a true bound
/// at about 2.5 % of steps by chance.
fn below_the_centralized_bound(outcome: &Outcome) -> String {
    let (mut checked, mut crossed) = (0, 0);
    let mut below: Vec<String> = Vec::new();
    for a in &outcome.arms {
        let steps: Vec<u32> = a
            .steps
            .iter()
            .zip(a.rmse_band())
            .filter_map(|(m, band)| {
                let bound = m.centralized_bound?;
                checked += 1;
                band.filter(|(_, hi)| *hi < bound).map(|_| m.step)
            })
            .collect();
        if !steps.is_empty() {
            crossed += steps.len();
            below.push(format!("{} at steps {steps:?}", a.label));
        }
    }
    if checked == 0 {
        return String::new();
    }
    format!(
        "; RMSE bands wholly below the centralized bound: {crossed} of {checked} step-estimates{}",
        if below.is_empty() {
            String::new()
        } else {
            format!(" ({})", below.join("; "))
        }
    )
}

fn arm_scenario(
    experiment: &Experiment,
    arm: &Arm,
    steps: Option<u32>,
) -> anyhow::Result<(Scenario, Topology)> {
    let mut overrides: Vec<String> = experiment
        .base
        .iter()
        .chain(arm.overrides)
        .map(|s| s.to_string())
        .collect();
    if let Some(k) = steps {
        overrides.push(format!("steps={k}"));
    }
    let source = format!("experiment {} arm `{}`", experiment.name, arm.label);
    let scenario = Scenario::from_toml(experiment.scenario, &source, &overrides)?;
    let topology = Topology::from_scenario(&scenario, &source)?;
    Ok((scenario, topology))
}

/// Whether the figure draws any of `series` for arm `index`.
fn needs(experiment: &Experiment, index: usize, series: &[Series]) -> bool {
    match &experiment.figure {
        Figure::OverTime { curves, .. } | Figure::OverTimeAndDesign { curves, .. } => curves
            .iter()
            .any(|c| c.arm == index && series.contains(&c.series)),
        Figure::Bars { .. } | Figure::Panels { .. } => false,
    }
}

/// Tichavsky's PCRLB for the scenario's sensors, each active with the
/// probability the uniform random manager gives it (its node's
/// `active_per_node` over the node's sensor count), from the true initial
/// state with the prior covariance P_0. Position bound at steps 1, 2, …
fn nonconditional_bound(
    scenario: &Scenario,
    topology: &Topology,
    trajectories: usize,
) -> anyhow::Result<Vec<f64>> {
    let models = scenario.models()?;
    let sensing = node::SensingModel::new(&models, topology);
    let terms = sensing.sensor_terms();
    let activation = topology.activation_probabilities(scenario.sensors.active_per_node);
    let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
    let information = nonconditional_pcrlb_random_activation(
        &models.dynamics,
        &terms,
        &activation,
        &State::from(scenario.target.initial_state()),
        &models.prior_cov,
        scenario.steps as usize,
        trajectories,
        &mut rng,
    )?;
    information
        .iter()
        .skip(1)
        .map(|j| bounds::position_bound(j).context("the non-conditional information is singular"))
        .collect()
}

/// An arm label as a folder name.
fn slug(label: &str) -> String {
    label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect()
}
