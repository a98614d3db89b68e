//! `cqnet experiment`: the papers' figures as commands that draw them.
//!
//! An experiment is data, not code: overrides of the default scenario, the
//! arms it runs (each a Monte Carlo of its own), the figure (which series of
//! which arm to draw) and a check that says in words whether the paper's
//! qualitative result holds. Adding one is adding an entry to a catalogue
//! (`distributed_bound.rs` is the first); the runner, the CSV, the SVG and the
//! command line are shared.

mod allocation;
mod bit_depth;
mod censoring;
mod compressive;
pub mod diagnostics;
mod distributed_bound;
pub mod faults;
mod figure;
mod location;
pub mod paired;
pub use paired::{Order, Paired, Verdict};
mod random_exchange_bounds;
mod random_exchange_trackers;
mod sensor_selection;
mod ungm;

use std::path::PathBuf;

use anyhow::Context;
use bounds::pcrlb::nonconditional_pcrlb_random_activation;
use bounds::State;
use fusion_graph::scenario::Scenario;
use fusion_graph::Topology;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use launch::montecarlo::run_monte_carlo_until;
use launch::results::{write_atomically, StepMeans, AVERAGE_FROM_STEP};

/// A named, reproducible experiment.
pub struct Experiment {
    pub name: &'static str,
    /// Where in the papers it comes from, e.g. "Mohammadi, Asif et al. (CQ/dPCRLB), Fig. 1(c)".
    pub source: &'static str,
    /// What it shows, in a sentence.
    pub about: &'static str,
    /// The scenario file's text every arm starts from.
    pub scenario: &'static str,
    /// Overrides of that scenario shared by every arm.
    pub base: &'static [&'static str],
    pub arms: &'static [Arm],
    pub figure: Figure,
    /// The paper's qualitative result, checked on the outcome.
    pub check: fn(&Outcome) -> Check,
}

/// One configuration, run as a Monte Carlo.
pub struct Arm {
    pub label: &'static str,
    pub overrides: &'static [&'static str],
}

pub enum Figure {
    /// Curves over the steps, on a logarithmic axis (the first steps from
    /// a 50 m prior are ten times the rest).
    OverTime {
        y_label: &'static str,
        curves: &'static [Curve],
    },
    /// Curves over time as [`Figure::OverTime`], and a second figure,
    /// `<name>-design.svg` with its CSV: a fusion centre's transmission
    /// probabilities over the field at `steps`, in arm `arm`'s first run.
    OverTimeAndDesign {
        y_label: &'static str,
        curves: &'static [Curve],
        arm: usize,
        steps: &'static [u32],
    },
    /// One bar per (arm, metric).
    Bars {
        y_label: &'static str,
        bars: &'static [Bar],
    },
    /// A panel per arm but the reference: its RMSE and bound over time, the
    /// reference arm's RMSE behind them, and steps `window.0..window.1` (the
    /// fault's) shaded.
    Panels {
        y_label: &'static str,
        reference: usize,
        window: (u32, u32),
    },
}

pub struct Curve {
    pub arm: usize,
    pub series: Series,
    pub label: &'static str,
}

/// A per-step figure of an arm: means over runs and nodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Series {
    /// The nodes' CQ/dPCRLB position bound (L_G).
    Bound,
    /// The auxiliary-FIM baseline's bound (needs `consensus.auxiliary_fim`).
    AuxBound,
    /// The centralized conditional PCRLB.
    CentralizedBound,
    /// Root mean square position error of the nodes' fused estimates.
    Rmse,
    CentralizedRmse,
    /// The non-conditional (Tichavsky) PCRLB, by Monte Carlo over
    /// trajectories from the prior, with the arm's random activation.
    Nonconditional,
}

pub struct Bar {
    pub arm: usize,
    pub metric: Metric,
    pub label: &'static str,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Metric {
    /// Bytes of bound information (ΔL) per step, from the accounting.
    BoundBytesPerStep,
    /// The same for the auxiliary-FIM baseline (ΔL and S_obs).
    AuxBoundBytesPerStep,
    /// Bytes of the sensor selection's messages per step.
    SelectionBytesPerStep,
}

/// Whether the paper's result holds, and the figures that say so: the
/// verdict of all its claims together, and each claim with its interval.
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    pub verdict: Verdict,
    pub statement: String,
    pub claims: Vec<Claim>,
}

/// What an experiment measured.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub runs: u32,
    pub steps: u32,
    pub arms: Vec<ArmOutcome>,
}

#[derive(Debug, Clone)]
pub struct ArmOutcome {
    pub label: String,
    pub steps: Vec<StepMeans>,
    /// Position bound of the non-conditional PCRLB at steps 1, 2, …
    pub nonconditional: Option<Vec<f64>>,
    pub bound_bytes_per_step: f64,
    pub aux_bound_bytes_per_step: Option<f64>,
    /// Whole-network bytes per step of the sensor selection's messages
    /// (the candidates' reports and the choice) and of the activations,
    /// from the accounting.
    pub selection_bytes_per_step: f64,
    /// Activations, with the censoring feedback they carry.
    pub activation_bytes_per_step: f64,
    /// Observations (quantized or raw) from sensors to their nodes.
    pub observation_bytes_per_step: f64,
    pub observations_per_step: f64,
    /// On a multiple-access channel: the sensors' transmissions per step
    /// (a unit of energy each), mean over runs; 0 without a channel.
    pub transmissions_per_step: f64,
    /// Messages sent but neither received, dropped nor malformed: the
    /// magnitudes summed over kinds and runs.
    pub unaccounted_messages: u64,
    /// Each run's position RMSE from step 10, in seed order: run k of every
    /// arm has the same seed, so arms compare run by run ([`paired`]).
    pub per_run_rmse: Vec<Option<f64>>,
    /// Each run's mean bounds from step 10, in seed order: the CQ/dPCRLB,
    /// the auxiliary-FIM baseline and the centralized conditional bound.
    pub per_run_bound: Vec<Option<f64>>,
    pub per_run_aux_bound: Vec<Option<f64>>,
    pub per_run_centralized_bound: Vec<Option<f64>>,
    /// The prediction's spread and the activated sensors' distance from
    /// the truth, per step.
    pub diagnostics: diagnostics::Diagnostics,
    /// Each run's per-step means, in seed order: the RMSE's band, and
    /// claims over a window of steps compared run by run.
    pub per_run_series: Vec<Vec<StepMeans>>,
}

/// Each step's 95 % band of an RMSE over runs, from each run's per-step
/// RMSE that `of` picks.
pub(crate) fn rmse_bands_of(
    per_run: &[Vec<launch::summary::StepMeans>],
    of: impl Fn(&launch::summary::StepMeans) -> Option<f64>,
) -> Vec<Option<(f64, f64)>> {
    let steps = per_run.iter().map(Vec::len).max().unwrap_or(0);
    (0..steps)
        .map(|k| {
            let at: Vec<f64> = per_run
                .iter()
                .filter_map(|run| run.get(k).and_then(&of))
                .collect();
            paired::rmse_interval(&at)
        })
        .collect()
}

/// A track counts as lost in a run whose RMSE is above this many times
/// its mean bound: one diverged run shows as such instead of hiding in a
/// mean.
pub const LOST_TRACK_FACTOR: f64 = 10.0;

/// One claim of a paper as the runs judge it, with the paired interval
/// behind it when it is estimated (none when it is exact).
#[derive(Debug, Clone, PartialEq)]
pub struct Claim {
    pub claim: String,
    pub paired: Option<Paired>,
    /// The interval in the claim's own unit ("+0.90 ± 0.72 % over 10
    /// runs"); empty for an exact claim.
    pub interval: String,
    pub verdict: Verdict,
}

impl Claim {
    /// A claim judged by a paired difference (`judge`), with its interval
    /// as `interval` words it; with no pairs at all it does not hold.
    pub fn judged(
        claim: impl Into<String>,
        paired: Option<Paired>,
        judge: impl Fn(&Paired) -> Verdict,
        interval: impl Fn(&Paired) -> String,
    ) -> Self {
        Self {
            claim: claim.into(),
            paired,
            interval: paired.as_ref().map_or("no paired runs".into(), interval),
            verdict: paired.as_ref().map_or(Verdict::DoesNotHold, judge),
        }
    }

    /// A claim checked exactly (a count, a budget).
    pub fn exact(claim: impl Into<String>, holds: bool) -> Self {
        Self {
            claim: claim.into(),
            paired: None,
            interval: String::new(),
            verdict: Verdict::of(holds),
        }
    }

    /// "claim: verdict (interval)", as the statement says it.
    pub fn said(&self) -> String {
        if self.interval.is_empty() {
            format!("{}: {}", self.claim, self.verdict.words())
        } else {
            format!(
                "{}: {} ({})",
                self.claim,
                self.verdict.words(),
                self.interval
            )
        }
    }

    /// The line of `claims.csv`.
    fn csv_row(&self) -> String {
        let (mean, half, runs, needed) = match self.paired {
            Some(p) => (
                format!("{}", p.mean),
                format!("{}", p.half_width),
                p.runs.to_string(),
                match self.verdict {
                    Verdict::NotResolved {
                        needed: Some(n), ..
                    } => n.to_string(),
                    _ => String::new(),
                },
            ),
            None => Default::default(),
        };
        let verdict = self.verdict.label();
        format!(
            "\"{}\",{mean},{half},{runs},{needed},{verdict}\n",
            self.claim.replace('"', "'")
        )
    }
}

impl Check {
    /// A check made of claims: their verdicts together, and a statement
    /// that says each claim, then `figures`.
    pub fn of_claims(claims: Vec<Claim>, figures: impl std::fmt::Display) -> Self {
        let said: Vec<String> = claims.iter().map(Claim::said).collect();
        Self {
            verdict: Verdict::all(claims.iter().map(|c| c.verdict)),
            statement: format!("{}; {figures}", said.join("; ")),
            claims,
        }
    }
}

/// `claims.csv`: every claim's paired difference, its 95 % half-width,
/// the runs, the runs that would resolve it, and its verdict; a check
/// with no claims of its own is one exact row.
pub fn claims_csv(check: &Check) -> String {
    let mut out =
        String::from("claim,mean_difference,half_width_95,runs,runs_to_resolve,verdict\n");
    if check.claims.is_empty() {
        let exact = Claim {
            verdict: check.verdict,
            ..Claim::exact("the experiment's check, exact", false)
        };
        out += &exact.csv_row();
    }
    for c in &check.claims {
        out += &c.csv_row();
    }
    out
}

impl ArmOutcome {
    /// At steps 1, 2, …: the 95 % interval of the RMSE over runs, drawn as
    /// a band around the RMSE curve.
    pub fn rmse_band(&self) -> Vec<Option<(f64, f64)>> {
        rmse_bands_of(&self.per_run_series, |m| m.rmse)
    }

    /// Runs whose RMSE is above [`LOST_TRACK_FACTOR`] times their bound,
    /// and the runs with both figures.
    pub fn lost_tracks(&self) -> (usize, usize) {
        let pairs = self
            .per_run_rmse
            .iter()
            .zip(&self.per_run_bound)
            .filter_map(|(r, b)| Some(((*r)?, (*b)?)));
        let (mut lost, mut of) = (0, 0);
        for (rmse, bound) in pairs {
            of += 1;
            lost += usize::from(rmse > LOST_TRACK_FACTOR * bound);
        }
        (lost, of)
    }

    /// Step 1, 2, …: the series' values.
    pub fn series(&self, series: Series) -> Vec<Option<f64>> {
        if series == Series::Nonconditional {
            let n = self.nonconditional.as_deref().unwrap_or(&[]);
            return (0..self.steps.len()).map(|i| n.get(i).copied()).collect();
        }
        self.steps
            .iter()
            .map(|m| match series {
                Series::Bound => m.bound,
                Series::AuxBound => m.aux_bound,
                Series::CentralizedBound => m.centralized_bound,
                Series::Rmse => m.rmse,
                Series::CentralizedRmse => m.centralized_rmse,
                Series::Nonconditional => unreachable!("handled above"),
            })
            .collect()
    }

    /// The series' mean over the steps the summaries average (from step
    /// 10 on, past the transient from the prior).
    pub fn mean(&self, series: Series) -> Option<f64> {
        let values: Vec<f64> = self
            .series(series)
            .into_iter()
            .skip(AVERAGE_FROM_STEP as usize - 1)
            .collect::<Option<_>>()?;
        (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
    }

    pub fn metric(&self, metric: Metric) -> Option<f64> {
        match metric {
            Metric::BoundBytesPerStep => Some(self.bound_bytes_per_step),
            Metric::AuxBoundBytesPerStep => self.aux_bound_bytes_per_step,
            Metric::SelectionBytesPerStep => Some(self.selection_bytes_per_step),
        }
    }
}

impl Outcome {
    /// The arm with this label; a catalogue entry's checks name their own arms.
    pub fn arm(&self, label: &str) -> &ArmOutcome {
        self.arms
            .iter()
            .find(|a| a.label == label)
            .unwrap_or_else(|| panic!("experiment has no arm `{label}`"))
    }
}

/// An experiment computed from a paper's formulas rather than run on a
/// network: a table reproduced beside the paper's, with its CSV and SVG.
pub struct Computed {
    pub name: &'static str,
    pub source: &'static str,
    pub about: &'static str,
    /// Computes the tables and writes the CSV and SVG into the folder.
    pub run: fn(&Options, &std::path::Path) -> anyhow::Result<ComputedReport>,
}

/// What a computed experiment wrote, and its tables as printed text.
pub struct ComputedReport {
    pub check: Check,
    pub csv: PathBuf,
    pub svg: PathBuf,
    /// Ours beside the paper's, for the terminal and `tables.txt`.
    pub table: String,
}

impl ComputedReport {
    /// Writes `<dir>/<name>.csv` and draws `<dir>/<name>.svg`: how every
    /// computed experiment ends.
    pub fn write(
        dir: &std::path::Path,
        name: &str,
        csv: &str,
        draw: impl FnOnce(&std::path::Path) -> Result<(), Box<dyn std::error::Error>>,
        check: Check,
        table: String,
    ) -> anyhow::Result<Self> {
        let csv_path = dir.join(format!("{name}.csv"));
        let svg = dir.join(format!("{name}.svg"));
        write_atomically(&csv_path, csv.as_bytes())?;
        draw(&svg)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("drawing {}", svg.display()))?;
        Ok(Self {
            check,
            csv: csv_path,
            svg,
            table,
        })
    }
}

/// Every computed experiment.
pub fn computed_catalogue() -> Vec<Computed> {
    let mut all = allocation::experiments();
    all.extend(censoring::experiments());
    all.extend(bit_depth::experiments());
    all.extend(random_exchange_bounds::experiments());
    all.extend(random_exchange_trackers::experiments());
    all.extend(location::experiments());
    all.extend(ungm::experiments());
    all
}

/// Runs a computed experiment into `<out>/<name>/`, with `tables.txt` and
/// `check.txt` beside its CSV and SVG.
pub fn run_computed(computed: &Computed, options: &Options) -> anyhow::Result<ComputedReport> {
    let dir = options.out.join(computed.name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let report = (computed.run)(options, &dir)?;
    write_atomically(&dir.join("tables.txt"), report.table.as_bytes())?;
    write_atomically(
        &dir.join("check.txt"),
        format!("{}\n", computed_verdict_line(computed, &report.check)).as_bytes(),
    )?;
    write_atomically(
        &dir.join("claims.csv"),
        claims_csv(&report.check).as_bytes(),
    )?;
    Ok(report)
}

/// "holds: …" or "does not hold: …" for a computed experiment.
pub fn computed_verdict_line(computed: &Computed, check: &Check) -> String {
    format!(
        "{} ({}): {}: {}",
        computed.name,
        computed.source,
        check.verdict.words(),
        check.statement
    )
}

/// One name of `cqnet experiment`: run on a network, or computed.
pub enum Entry {
    Network(Experiment),
    Computed(Computed),
}

/// The network experiment or computed one of that name, or an error that
/// lists every name.
pub fn find_entry(name: &str) -> anyhow::Result<Entry> {
    refuse_former_name(name)?;
    if let Some(c) = computed_catalogue().into_iter().find(|c| c.name == name) {
        return Ok(Entry::Computed(c));
    }
    find(name).map(Entry::Network)
}

/// Every experiment, in the order `cqnet experiment` lists them.
pub fn catalogue() -> Vec<Experiment> {
    let mut all = distributed_bound::experiments();
    all.extend(sensor_selection::experiments());
    all.extend(compressive::experiments());
    all.extend(censoring::network_experiments());
    all.extend(faults::experiments());
    all
}

/// Names experiments once went by, a paper's number and figure, each with
/// the name that says what it is.
const FORMER_NAMES: [(&str, &str); 4] = [
    ("seed000-fig1b", "bound-aux-fim"),
    ("seed000-fig1c", "bound-against-bits"),
    ("seed001-fig2", "sensor-selection"),
    ("seed004-fig1", "random-exchange-trackers"),
];

/// A former name is refused rather than followed, so that scripts move to
/// the name that says what the experiment is; the error names it.
fn refuse_former_name(name: &str) -> anyhow::Result<()> {
    match FORMER_NAMES.iter().find(|(former, _)| *former == name) {
        Some((former, now)) => anyhow::bail!("the experiment `{former}` is now called `{now}`"),
        None => Ok(()),
    }
}

/// The experiment of that name, or an error that lists the names.
pub fn find(name: &str) -> anyhow::Result<Experiment> {
    refuse_former_name(name)?;
    let mut all = catalogue();
    match all.iter().position(|e| e.name == name) {
        Some(i) => Ok(all.swap_remove(i)),
        None => anyhow::bail!(
            "no experiment named `{name}`; there are: {}",
            all.iter()
                .map(|e| e.name)
                .chain(computed_catalogue().iter().map(|c| c.name))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

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
    if let Figure::OverTimeAndDesign { arm, steps, .. } = experiment.figure {
        let (_, topology) = arm_scenario(experiment, &experiment.arms[arm], options.steps)?;
        figure::design(
            &dir,
            experiment.name,
            &outcome.arms[arm],
            steps,
            &topology.sensor_positions,
        )?;
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
