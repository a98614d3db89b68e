//! What an experiment is (its arms, figure and metrics) and what it
//! measured (each arm's outcome, the RMSE's bands over runs).

use launch::results::{StepMeans, AVERAGE_FROM_STEP};

use crate::claims::Check;
use crate::diagnostics;
use crate::paired;

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
    /// Curves over time as [`Figure::OverTime`], and for each `(arm,
    /// suffix)` of `designs` a figure `<name>-<suffix>.svg` with its CSV:
    /// a fusion centre's transmission probabilities over the field at
    /// `steps`, in that arm's first run.
    OverTimeAndDesign {
        y_label: &'static str,
        curves: &'static [Curve],
        designs: &'static [(usize, &'static str)],
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
