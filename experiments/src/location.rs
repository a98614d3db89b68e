//! The dissertation's ch. 6: a static target at the origin, located from
//! quantized amplitudes by sensors spread uniformly at density λ, for the
//! Gaussian-like decay (α = 1) and the power law (n = 4), σ = 1,
//! P₀ = 10⁴ (40 dB). `location-crlb` computes every figure of the chapter,
//! each a CSV and an SVG:
//!
//! - the signal's contours over a deployment (Fig. 6.1);
//! - the CRLB of optimal, sub-optimal (eq. 6.46) and uniform thresholds
//!   against bits, 1 to 6 (Figs. 6.2, 6.3, 6.12, 6.13);
//! - the ML estimate's RMSE against the CRLB and the analog CRLB at λ = 2
//!   (Figs. 6.4, 6.5), with the estimate's bias gradient where it beats
//!   the bound;
//! - the exact FIM of random deployments against the closed form as λ
//!   grows: its elements and ρ (Figs. 6.6, 6.9), the CRLB's trace (Figs.
//!   6.7, 6.10) and the relative FIM with eqs. 6.36–6.37's 1σ (Figs. 6.8,
//!   6.11), with M = 1 bit for the Gaussian law and M = 4 for the power
//!   law, as the chapter has them.
//!
//! As §6.7.1 says, the density and ML parts use the optimal quantizer: the
//! ML part's is optimized on its own deployment; the density part's is
//! the one found on the thresholds part's first deployment ("the optimal
//! quantizer that we find"), since a design per deployment would make the
//! closed form a different curve for each. Where the chapter does not say:
//! the optimal thresholds are optimized on the sensors within 5 (Gaussian)
//! or 10 (power law) of the target, beyond which a sensor's β is below
//! 10⁻⁸ of the nearest ones', starting from the sub-optimal design; the
//! squares' sides are 18 (the Gaussian signal's power falls to about
//! 10⁻³⁵ P₀ at their edges, as in section 6.7.3) and 40 (the power law's
//! to 6·10⁻⁶ P₀: the chapter's 10⁻⁷ would need a side of 112 and 50,000
//! sensors at λ = 4); the ML search grid is offset from the target by a
//! random fraction of its step in each trial, so that no lattice the search
//! walks holds the truth.

use std::fmt::Write as _;
use std::path::Path;

use bounds::fisher::Measurement;
use bounds::location::{
    closed_form_information, correlation, crlb_trace, exact_information, log_likelihood,
    ml_estimate, optimize_weighed_thresholds, relative_information_variance, uniform_quantizer,
    DecayLaw, WeighedAmplitudes,
};
use bounds::Quantizer;
use nalgebra::Matrix2;
use plotters::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::paired::{Order, Paired};
use super::parallel::indexed;
use super::{Check, Claim, Computed, ComputedReport, Options};
use launch::results::write_atomically;

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "location-crlb",
        source: "dissertation ch. 6, Figs. 6.1-6.13",
        about: "a static target located from quantized amplitudes: the exact CRLB of random deployments against the closed form as the density grows, optimal, sub-optimal and uniform thresholds, and the ML estimate against its CRLB, for Gaussian-like and power-law decay",
        run,
    }]
}

const SIGMA: f64 = 1.0;

/// One decay law as the chapter studies it.
struct Model {
    name: &'static str,
    /// The law's name in file names.
    key: &'static str,
    law: DecayLaw,
    /// The density part's bits.
    bits: u8,
    /// The square the sensors are spread over, centred on the target.
    side: f64,
    /// Sensors beyond this carry no information worth optimizing on.
    informative: f64,
    /// The thresholds part's density.
    density: f64,
}

const MODELS: [Model; 2] = [
    Model {
        name: "Gaussian",
        key: "gaussian",
        law: DecayLaw::Gaussian {
            p0: 1e4,
            alpha: 1.0,
        },
        bits: 1,
        side: 18.0,
        informative: 5.0,
        density: 6.0,
    },
    Model {
        name: "power law",
        key: "power-law",
        law: DecayLaw::PowerLaw {
            p0: 1e4,
            exponent: 4.0,
        },
        bits: 4,
        side: 40.0,
        informative: 10.0,
        density: 4.0,
    },
];

const DENSITIES: [f64; 6] = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0];
/// Deployments at each density of the density part. One deployment's J₁₁
/// strays from the closed form by eq. 6.36's 1σ (for the Gaussian law at
/// 1 bit 118 % at λ = 1 and 29 % at λ = 16; for the power law at 4 bits
/// 54 % and 14 %), and the variance of that spread is itself the claim of
/// eq. 6.36: pinning it within ±20 % takes thousands. Each costs one FIM.
const DEPLOYMENTS: usize = 2000;
const BITS: [u8; 6] = [1, 2, 3, 4, 5, 6];
/// Deployments of the thresholds part for the uniform and sub-optimal
/// designs, which cost one FIM each: the 1-bit CRLB of one deployment
/// rests on the few sensors near the one amplitude its threshold marks, so
/// it varies by orders of magnitude between deployments.
const CHEAP_DEPLOYMENTS: usize = 400;

/// Deployments on which the optimal thresholds are searched at a depth:
/// the search costs a few thousand FIMs per threshold.
fn optimal_deployments(bits: u8) -> usize {
    match bits {
        1 => 12,
        2..=4 => 4,
        _ => 2,
    }
}

const ML_DENSITY: f64 = 2.0;
const ML_TRIALS: usize = 100;
/// The depth whose ML claim is judged, with more trials.
const ML_CLAIM_BITS: u8 = 4;
const ML_CLAIM_TRIALS: usize = 400;
/// The ML part's square: the power law's 40 would make each trial's grid
/// search 16 times longer for sensors that add nothing.
const ML_SIDE: f64 = 18.0;
const ML_STEP: f64 = 0.5;
const ML_STARTS: usize = 3;

/// How much of each part to compute, and on how many threads: the full
/// sizes above, or a few of each when the experiment is run small.
#[derive(Debug, Clone, Copy)]
struct Work {
    threads: usize,
    deployments: usize,
    cheap_deployments: usize,
    ml_trials: usize,
    ml_claim_trials: usize,
    /// At most this many deployments for the optimal search at a depth.
    optimal_limit: usize,
    /// Whether the designs are searched for (the sub-optimal design of
    /// eq. 6.46 and the optimal one); run small, the uniform thresholds
    /// stand in for both.
    search: bool,
}

impl Work {
    /// The optimal thresholds for `sensors`, searched from `start`.
    fn optimal(&self, model: &Model, start: &Quantizer, sensors: &[[f64; 2]]) -> Quantizer {
        if self.search {
            optimal(model, start, sensors)
        } else {
            start.clone()
        }
    }

    fn of(options: &Options) -> Self {
        let full = Self {
            threads: options.threads.max(1),
            deployments: DEPLOYMENTS,
            cheap_deployments: CHEAP_DEPLOYMENTS,
            ml_trials: ML_TRIALS,
            ml_claim_trials: ML_CLAIM_TRIALS,
            optimal_limit: usize::MAX,
            search: true,
        };
        options.sized(
            full,
            Self {
                deployments: 20,
                cheap_deployments: 8,
                ml_trials: 3,
                ml_claim_trials: 4,
                optimal_limit: 1,
                search: false,
                ..full
            },
        )
    }
}
/// The depths at which the ML estimate's bias gradient is measured (with
/// the optimal thresholds): one where its MSE misses the CRLB, one where
/// it meets it.
const BIAS_BITS: [u8; 2] = [2, 4];
const SEED: u64 = 6;

/// What a random stream serves: every deployment and trial draws from its
/// own, so a result depends neither on the threads nor on how many
/// deployments another part makes.
#[derive(Clone, Copy)]
enum Stream {
    Density(usize),
    Thresholds,
    MlDeployment,
    MlTrial,
    Contours,
}

fn rng(stream: Stream, model: usize, index: usize) -> ChaCha8Rng {
    let tag = match stream {
        Stream::Density(d) => 1 + d as u64,
        Stream::Thresholds => 100,
        Stream::MlDeployment => 101,
        Stream::MlTrial => 102,
        Stream::Contours => 103,
    };
    ChaCha8Rng::seed_from_u64(SEED ^ (tag << 48) ^ ((model as u64) << 40) ^ index as u64)
}

fn deploy(rng: &mut ChaCha8Rng, side: f64, density: f64) -> Vec<[f64; 2]> {
    let n = (density * side * side).round() as usize;
    let h = side / 2.0;
    (0..n)
        .map(|_| [rng.random_range(-h..h), rng.random_range(-h..h)])
        .collect()
}

/// The thresholds' search range, `[−4σ, √P₀ + 4σ]`, as §6.7.1 sets the
/// uniform quantizer's.
fn range(model: &Model) -> (f64, f64) {
    (-4.0 * SIGMA, model.law.p0().sqrt() + 4.0 * SIGMA)
}

/// The sub-optimal thresholds of eq. 6.46: those maximizing the closed
/// form, which needs no sensor's position (and not λ, which scales it).
fn sub_optimal(model: &Model, bits: u8) -> Quantizer {
    let (lo, hi) = range(model);
    let start = Quantizer::uniform(bits, lo, hi).expect("valid bits and range");
    let nodes = WeighedAmplitudes::of_closed_form(model.law, 1.0, model.side / 2.0);
    optimize_weighed_thresholds(&start, lo, hi, &nodes, SIGMA, |j| j[(0, 0)])
}

/// The optimal thresholds of one deployment: those minimizing its exact
/// CRLB's trace, searched from the sub-optimal design `start`.
fn optimal(model: &Model, start: &Quantizer, sensors: &[[f64; 2]]) -> Quantizer {
    let near: Vec<[f64; 2]> = sensors
        .iter()
        .copied()
        .filter(|s| s[0].hypot(s[1]) < model.informative)
        .collect();
    let (lo, hi) = range(model);
    let points = WeighedAmplitudes::of_deployment(model.law, &near, [0.0, 0.0]);
    optimize_weighed_thresholds(start, lo, hi, &points, SIGMA, |j| {
        crlb_trace(j).map_or(f64::NEG_INFINITY, |t| -t)
    })
}

fn information(model: &Model, report: Measurement<'_>, sensors: &[[f64; 2]]) -> Matrix2<f64> {
    exact_information(model.law, report, SIGMA, sensors, [0.0, 0.0])
}

fn trace_of(model: &Model, report: Measurement<'_>, sensors: &[[f64; 2]]) -> Option<f64> {
    crlb_trace(&information(model, report, sensors))
}

/// The density part at one λ: each deployment's J and the closed form.
struct DensityRow {
    density: f64,
    j11: Vec<f64>,
    j22: Vec<f64>,
    j12: Vec<f64>,
    rho: Vec<f64>,
    trace: Vec<f64>,
    closed: f64,
    /// The 1σ of `J₁₁/c` and of `J₁₂/c` eqs. 6.36 and 6.37 predict.
    predicted_sd: (f64, f64),
}

fn density_part(m: usize, q: &Quantizer, work: &Work) -> Vec<DensityRow> {
    let model = &MODELS[m];
    let report = Measurement::Quantized(q);
    let radius = model.side / 2.0;
    DENSITIES
        .iter()
        .enumerate()
        .map(|(d, &density)| {
            let js = indexed(work.deployments, work.threads, |i| {
                let sensors = deploy(&mut rng(Stream::Density(d), m, i), model.side, density);
                information(model, report, &sensors)
            });
            let in_disc = density * std::f64::consts::PI * radius * radius;
            let (var11, var12) =
                relative_information_variance(model.law, report, SIGMA, radius, in_disc);
            DensityRow {
                density,
                j11: js.iter().map(|j| j[(0, 0)]).collect(),
                j22: js.iter().map(|j| j[(1, 1)]).collect(),
                j12: js.iter().map(|j| j[(0, 1)]).collect(),
                rho: js.iter().map(correlation).collect(),
                trace: js
                    .iter()
                    .map(|j| crlb_trace(j).unwrap_or(f64::NAN))
                    .collect(),
                closed: closed_form_information(model.law, report, SIGMA, density, radius),
                predicted_sd: (var11.sqrt(), var12.sqrt()),
            }
        })
        .collect()
}

/// The thresholds part at one bit depth: each deployment's CRLB trace with
/// each design (the optimal one on the first deployments only).
struct ThresholdRow {
    bits: u8,
    optimal: Vec<f64>,
    sub_optimal: Vec<f64>,
    uniform: Vec<f64>,
    /// Sensors a deployment has within 2σ of a threshold, on average: the
    /// optimal design's over its deployments, the others' over all.
    ring: [f64; 3],
}

/// How many of a deployment's sensors have a noiseless amplitude within 2σ
/// of one of the quantizer's thresholds: the sensors whose reports tell
/// about the target (one far from every threshold reports the same cell
/// wherever the target is near).
fn near_a_threshold(model: &Model, q: &Quantizer, sensors: &[[f64; 2]]) -> usize {
    let thresholds: Vec<f64> = (1..q.cells()).map(|i| q.cell_edges(i as u32).0).collect();
    sensors
        .iter()
        .filter(|s| {
            let a = model.law.amplitude(s[0].hypot(s[1]));
            thresholds.iter().any(|t| (a - t).abs() < 2.0 * SIGMA)
        })
        .count()
}

/// The thresholds part, and the optimal quantizer of its first deployment
/// at each depth.
fn threshold_part(
    m: usize,
    designed: &[Quantizer],
    work: &Work,
) -> (Vec<ThresholdRow>, Vec<Quantizer>) {
    let model = &MODELS[m];
    let deployments: Vec<Vec<[f64; 2]>> = (0..work.cheap_deployments)
        .map(|i| {
            deploy(
                &mut rng(Stream::Thresholds, m, i),
                model.side,
                model.density,
            )
        })
        .collect();
    let of = |q: &Quantizer, s: &[[f64; 2]]| {
        trace_of(model, Measurement::Quantized(q), s).unwrap_or(f64::NAN)
    };
    // Every (depth, deployment) search as one task, the costly ones first.
    let tasks: Vec<(usize, usize)> = (0..BITS.len())
        .rev()
        .flat_map(|b| {
            (0..optimal_deployments(BITS[b]).min(work.optimal_limit)).map(move |i| (b, i))
        })
        .collect();
    let found = indexed(tasks.len(), work.threads, |t| {
        let (b, i) = tasks[t];
        let q = work.optimal(model, &designed[b], &deployments[i]);
        let near = near_a_threshold(model, &q, &deployments[i]);
        (of(&q, &deployments[i]), q, near)
    });
    let mut first = Vec::new();
    let rows = BITS
        .iter()
        .enumerate()
        .map(|(b, &bits)| {
            let mine: Vec<&(f64, Quantizer, usize)> = tasks
                .iter()
                .zip(&found)
                .filter(|((tb, _), _)| *tb == b)
                .map(|(_, f)| f)
                .collect();
            first.push(mine[0].1.clone());
            let uni = uniform_quantizer(bits, model.law, SIGMA);
            let cheap = |q: &Quantizer| {
                indexed(deployments.len(), work.threads, |i| of(q, &deployments[i]))
            };
            let ring = |q: &Quantizer| {
                deployments
                    .iter()
                    .map(|d| near_a_threshold(model, q, d) as f64)
                    .sum::<f64>()
                    / deployments.len() as f64
            };
            ThresholdRow {
                bits,
                optimal: mine.iter().map(|f| f.0).collect(),
                sub_optimal: cheap(&designed[b]),
                uniform: cheap(&uni),
                ring: [
                    mine.iter().map(|f| f.2 as f64).sum::<f64>() / mine.len() as f64,
                    ring(&designed[b]),
                    ring(&uni),
                ],
            }
        })
        .collect();
    (rows, first)
}

/// The ML part at one bit depth: each trial's squared error, the CRLB, and
/// where measured the bias gradient's diagonal, trial by trial.
struct MlRow {
    bits: u8,
    design: Design,
    squared_errors: Vec<f64>,
    crlb: f64,
    /// `[J⁻¹]₁₁` and `[J⁻¹]₂₂`.
    crlb_diagonal: [f64; 2],
    analog: f64,
    /// `∂E[x̂]/∂x` and `∂E[ŷ]/∂y` of each trial, by central differences
    /// of the estimate with the trial's noise held.
    slopes: Option<[Vec<f64>; 2]>,
}

/// One ML estimate: the cells the sensors report of a target at `target`
/// with these noise draws, and the search over a grid offset by `offset`.
fn ml_trial(
    model: &Model,
    q: &Quantizer,
    sensors: &[[f64; 2]],
    noise: &[f64],
    offset: f64,
    target: [f64; 2],
) -> [f64; 2] {
    let cells: Vec<u32> = sensors
        .iter()
        .zip(noise)
        .map(|(s, n)| {
            let d = (s[0] - target[0]).hypot(s[1] - target[1]);
            q.encode(model.law.amplitude(d) + SIGMA * n)
        })
        .collect();
    let h = ML_SIDE / 2.0;
    ml_estimate(
        |t| log_likelihood(model.law, q, SIGMA, sensors, &cells, t),
        -h - offset,
        h,
        ML_STEP,
        ML_STARTS,
    )
}

/// Which thresholds the sensors report with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Design {
    /// Optimized on the deployment itself, as §6.7 uses from §6.7.1 on.
    Optimal,
    /// Eq. 6.46's, which needs no positions.
    SubOptimal,
}

impl Design {
    fn name(self) -> &'static str {
        match self {
            Design::Optimal => "optimal",
            Design::SubOptimal => "sub-optimal",
        }
    }
}

/// The depth at which the ML estimate is also measured with the
/// sub-optimal thresholds: where, with them, its MSE fell to a third of
/// the CRLB.
const SUB_OPTIMAL_ML_BITS: u8 = 2;

fn ml_part(m: usize, designed: &[Quantizer], work: &Work) -> Vec<MlRow> {
    let model = &MODELS[m];
    let sensors = deploy(&mut rng(Stream::MlDeployment, m, 0), ML_SIDE, ML_DENSITY);
    let analog = trace_of(model, Measurement::Raw, &sensors).unwrap_or(f64::NAN);
    let mut rows: Vec<MlRow> = BITS
        .iter()
        .zip(designed)
        .map(|(&bits, start)| {
            let q = work.optimal(model, start, &sensors);
            ml_row(m, &sensors, &q, bits, Design::Optimal, analog, work)
        })
        .collect();
    let b = BITS
        .iter()
        .position(|&b| b == SUB_OPTIMAL_ML_BITS)
        .expect("a measured depth");
    rows.push(ml_row(
        m,
        &sensors,
        &designed[b],
        SUB_OPTIMAL_ML_BITS,
        Design::SubOptimal,
        analog,
        work,
    ));
    rows
}

/// The trials of one design at one depth.
fn ml_row(
    m: usize,
    sensors: &[[f64; 2]],
    q: &Quantizer,
    bits: u8,
    design: Design,
    analog: f64,
    work: &Work,
) -> MlRow {
    let model = &MODELS[m];
    let j = information(model, Measurement::Quantized(q), sensors);
    let inverse = j.try_inverse().unwrap_or(Matrix2::from_element(f64::NAN));
    let crlb = inverse[(0, 0)] + inverse[(1, 1)];
    let trials = if design == Design::Optimal && bits == ML_CLAIM_BITS {
        work.ml_claim_trials
    } else {
        work.ml_trials
    };
    let bias = design == Design::SubOptimal || BIAS_BITS.contains(&bits);
    // A shift of half the bound's per-coordinate standard deviation.
    let delta = 0.5 * (crlb / 2.0).sqrt();
    let results = indexed(trials, work.threads, |t| {
        // The same draws at every depth and design: they compare trial
        // by trial.
        let mut r = rng(Stream::MlTrial, m, t);
        let noise: Vec<f64> = (0..sensors.len())
            .map(|_| r.sample(rand_distr::StandardNormal))
            .collect();
        let offset = r.random_range(0.0..ML_STEP);
        let at = |target| ml_trial(model, q, sensors, &noise, offset, target);
        let e = at([0.0, 0.0]);
        let slopes = (bias && t < work.ml_trials).then(|| {
            [
                (at([delta, 0.0])[0] - at([-delta, 0.0])[0]) / (2.0 * delta),
                (at([0.0, delta])[1] - at([0.0, -delta])[1]) / (2.0 * delta),
            ]
        });
        (e[0] * e[0] + e[1] * e[1], slopes)
    });
    let slopes = bias.then(|| {
        let of = |k: usize| results.iter().filter_map(|r| r.1.map(|s| s[k])).collect();
        [of(0), of(1)]
    });
    MlRow {
        bits,
        design,
        squared_errors: results.iter().map(|r| r.0).collect(),
        crlb,
        crlb_diagonal: [inverse[(0, 0)], inverse[(1, 1)]],
        analog,
        slopes,
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn sd(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1).max(1) as f64).sqrt()
}

fn some(v: impl IntoIterator<Item = f64>) -> Vec<Option<f64>> {
    v.into_iter().map(Some).collect()
}

/// Each value, or none where it is not finite: the logarithm of the CRLB
/// of a deployment whose J is singular, left out of the pairs it is in.
fn finite(v: impl IntoIterator<Item = f64>) -> Vec<Option<f64>> {
    v.into_iter().map(|x| x.is_finite().then_some(x)).collect()
}

/// The geometric mean of the finite values: CRLBs of deployments span
/// orders of magnitude, and one nearly singular J would rule a mean.
fn geometric_mean(v: &[f64]) -> f64 {
    let logs: Vec<f64> = v.iter().filter(|x| x.is_finite()).map(|x| x.ln()).collect();
    if logs.is_empty() {
        return f64::NAN;
    }
    mean(&logs).exp()
}

/// The mean of the finite values (the CRLBs of deployments whose J is
/// not singular).
fn finite_mean(v: &[f64]) -> f64 {
    let kept: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    mean(&kept)
}

/// How many of these CRLBs are not finite (singular J).
fn singular(v: &[f64]) -> usize {
    v.iter().filter(|x| !x.is_finite()).count()
}

struct Outcome {
    work: Work,
    density: Vec<Vec<DensityRow>>,
    thresholds: Vec<Vec<ThresholdRow>>,
    ml: Vec<Vec<MlRow>>,
}

fn run(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let work = Work::of(options);
    let threads = work.threads;
    let mut outcome = Outcome {
        work,
        density: Vec::new(),
        thresholds: Vec::new(),
        ml: Vec::new(),
    };
    for (m, model) in MODELS.iter().enumerate() {
        eprintln!(
            "location-crlb: {} decay, sub-optimal thresholds",
            model.name
        );
        // Run small, the uniform thresholds stand in for eq. 6.46's, whose
        // search takes a minute.
        let designed = indexed(BITS.len(), threads, |b| {
            if work.search {
                sub_optimal(model, BITS[b])
            } else {
                uniform_quantizer(BITS[b], model.law, SIGMA)
            }
        });
        eprintln!("location-crlb: {} decay, optimal thresholds", model.name);
        let (rows, first) = threshold_part(m, &designed, &work);
        outcome.thresholds.push(rows);
        let q = &first[BITS
            .iter()
            .position(|&b| b == model.bits)
            .expect("the density part's bits are among BITS")];
        eprintln!(
            "location-crlb: {} decay, density against closed form",
            model.name
        );
        outcome.density.push(density_part(m, q, &work));
        eprintln!("location-crlb: {} decay, ML estimates", model.name);
        outcome.ml.push(ml_part(m, &designed, &work));
    }
    write_atomically(
        &dir.join("location-thresholds.csv"),
        thresholds_csv(&outcome).as_bytes(),
    )?;
    write_atomically(&dir.join("location-ml.csv"), ml_csv(&outcome).as_bytes())?;
    let figure = |e: Box<dyn std::error::Error>| anyhow::anyhow!("{e}");
    draw_thresholds(&dir.join("location-thresholds.svg"), &outcome).map_err(figure)?;
    draw_ml(&dir.join("location-ml.svg"), &outcome).map_err(figure)?;
    draw_signal(&dir.join("location-signal.svg")).map_err(figure)?;
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &outcome.density[m];
        draw_elements(
            &dir.join(format!("location-fim-{}.svg", model.key)),
            model,
            rows,
        )
        .map_err(figure)?;
        draw_relative(
            &dir.join(format!("location-relative-fim-{}.svg", model.key)),
            model,
            rows,
        )
        .map_err(figure)?;
    }
    ComputedReport::write(
        dir,
        "location-crlb",
        &density_csv(&outcome),
        |svg| draw_density(svg, &outcome),
        check(&outcome),
        table(&outcome),
    )
}

/// `(J/c)²/σ² − 1` of each deployment: zero on average when the
/// deployments stray from the closed form as eq. 6.36 or 6.37 says.
fn spread_ratio(values: &[f64], centre: f64, closed: f64, sd: f64) -> Vec<Option<f64>> {
    some(
        values
            .iter()
            .map(|j| ((j / closed - centre) / sd).powi(2) - 1.0),
    )
}

fn check(o: &Outcome) -> Check {
    let mut claims = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &o.density[m];
        let (first, last) = (&rows[0], &rows[rows.len() - 1]);
        let ratio = |r: &DensityRow| some(r.j11.iter().map(|j| j / r.closed - 1.0));
        claims.push(Claim::judged(
            format!(
                "{}: the exact J11 averages the closed form at λ = {} (within ±5 %)",
                model.name, last.density
            ),
            Paired::of_values(&ratio(last)),
            |p| p.verdict_within(-0.05, 0.05),
            |p| {
                format!(
                    "{:+.2} ± {:.2} % over {} deployments",
                    100.0 * p.mean,
                    100.0 * p.half_width,
                    p.runs
                )
            },
        ));
        let one = rows
            .iter()
            .find(|r| r.density == 1.0)
            .expect("λ = 1 is measured");
        let per_density = |r: &DensityRow| some(r.j11.iter().map(|j| j / r.closed));
        claims.push(Claim::judged(
            format!("{}: the information is linear in λ: J11/c at λ = {} equals J11/c at λ = 1 (within ±10 %)", model.name, last.density),
            Paired::of(&per_density(last), &per_density(one)),
            |p| p.verdict_within(-0.10, 0.10),
            |p| format!("{} over {} deployments each", p.text(3), p.runs),
        ));
        claims.push(Claim::judged(
            format!(
                "{}: |ρ| shrinks as λ grows (λ = {} against λ = {})",
                model.name, last.density, first.density
            ),
            Paired::of(
                &some(last.rho.iter().map(|r| r.abs())),
                &some(first.rho.iter().map(|r| r.abs())),
            ),
            |p| p.verdict(Order::Lower),
            |p| format!("{} over {} deployments", p.text(3), p.runs),
        ));
        for (what, values, centre, sd) in [
            ("J11/c (eq. 6.36)", &last.j11, 1.0, last.predicted_sd.0),
            ("J12/c (eq. 6.37)", &last.j12, 0.0, last.predicted_sd.1),
        ] {
            claims.push(Claim::judged(
                format!(
                    "{}: the variance of {what} over deployments is the predicted one at λ = {} (within ±20 %)",
                    model.name, last.density
                ),
                Paired::of_values(&spread_ratio(values, centre, last.closed, sd)),
                |p| p.verdict_within(-0.20, 0.20),
                |p| {
                    format!(
                        "measured/predicted {:+.1} ± {:.1} % over {} deployments",
                        100.0 * p.mean,
                        100.0 * p.half_width,
                        p.runs
                    )
                },
            ));
        }
        let thresholds = &o.thresholds[m];
        let one_bit = &thresholds[0];
        // CRLBs are compared by their logarithms: one deployment's can be
        // a thousand times another's, and a ratio is what the claim is about.
        let ln = |v: &[f64]| finite(v.iter().map(|x| x.ln()));
        let first_n = |v: &[f64], n: usize| ln(&v[..n]);
        claims.push(Claim::judged(
            format!(
                "{}: at 1 bit the optimal thresholds' CRLB is below the uniform ones' (λ = {})",
                model.name, model.density
            ),
            Paired::of(
                &ln(&one_bit.optimal),
                &first_n(&one_bit.uniform, one_bit.optimal.len()),
            ),
            |p| p.verdict(Order::Lower),
            |p| ratio_text(p, "optimal/uniform"),
        ));
        claims.push(Claim::judged(
            format!("{}: at 1 bit the sub-optimal thresholds' CRLB is within 10 % of the optimal's (λ = {})", model.name, model.density),
            Paired::of(&first_n(&one_bit.sub_optimal, one_bit.optimal.len()), &ln(&one_bit.optimal)),
            |p| p.verdict_within(-(1.1f64.ln()), 1.1f64.ln()),
            |p| ratio_text(p, "sub-optimal/optimal"),
        ));
        claims.push(Claim::judged(
            format!(
                "{}: at 1 bit the uniform thresholds' CRLB is above the sub-optimal's",
                model.name
            ),
            Paired::of(&ln(&one_bit.uniform), &ln(&one_bit.sub_optimal)),
            |p| p.verdict(Order::Higher),
            |p| ratio_text(p, "uniform/sub-optimal"),
        ));
        let top = &thresholds[thresholds.len() - 1];
        for (what, design) in [("sub-optimal", &top.sub_optimal), ("uniform", &top.uniform)] {
            claims.push(Claim::judged(
                format!(
                    "{}: at {} bits the {what} thresholds' CRLB is within 25 % of the optimal's",
                    model.name, top.bits
                ),
                Paired::of(&first_n(design, top.optimal.len()), &ln(&top.optimal)),
                |p| p.verdict_within(-(1.25f64.ln()), 1.25f64.ln()),
                |p| ratio_text(p, &format!("{what}/optimal")),
            ));
        }
        let ml = &o.ml[m];
        let claimed = ml
            .iter()
            .find(|r| r.design == Design::Optimal && r.bits == ML_CLAIM_BITS)
            .expect("the claim's depth is measured");
        claims.push(Claim::judged(
            format!("{}: at {} bits the ML estimate's MSE is within ±25 % of its CRLB (λ = {ML_DENSITY})", model.name, claimed.bits),
            Paired::of_values(&some(claimed.squared_errors.iter().map(|e| e / claimed.crlb - 1.0))),
            |p| p.verdict_within(-0.25, 0.25),
            |p| format!("{} over {} trials", p.text(3), p.runs),
        ));
        let gaps: Vec<f64> = ml
            .iter()
            .filter(|r| r.design == Design::Optimal)
            .map(|r| r.crlb / r.analog - 1.0)
            .collect();
        claims.push(Claim::exact(
            format!(
                "{}: the quantized CRLB's excess over the analog one shrinks with every bit (1 to {} bits: {})",
                model.name,
                BITS[BITS.len() - 1],
                gaps.iter()
                    .map(|g| format!("{:+.1} %", 100.0 * g))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            gaps.windows(2).all(|w| w[1] < w[0]) && gaps.iter().all(|g| *g > 0.0),
        ));
    }
    let figures = MODELS
        .iter()
        .enumerate()
        .map(|(m, model)| {
            let last = o.density[m].last().expect("densities");
            let [opt, sub, uni] = o.thresholds[m][0].paired_means();
            format!(
                "{}: at λ = {} J11 {:.4e} against the closed form {:.4e}; at 1 bit CRLB (geometric mean) optimal {opt:.4e}, sub-optimal {sub:.4e}, uniform {uni:.4e}",
                model.name,
                last.density,
                mean(&last.j11),
                last.closed,
            )
        })
        .collect::<Vec<_>>()
        .join("; ");
    Check::of_claims(claims, figures)
}

/// A paired difference of logarithms as the ratio it is: "×1.73 (95 %:
/// ×1.21 to ×2.47) sub-optimal/optimal over 12 deployments".
fn ratio_text(p: &Paired, what: &str) -> String {
    format!(
        "×{:.3} (95 %: ×{:.3} to ×{:.3}) {what} over {} deployments",
        p.mean.exp(),
        (p.mean - p.half_width).exp(),
        (p.mean + p.half_width).exp(),
        p.runs
    )
}

fn density_csv(o: &Outcome) -> String {
    let mut s = String::from("model,bits,lambda,deployments,j11_mean,j22_mean,j12_mean,abs_rho_mean,closed_form,j11_over_closed_sd,j11_over_closed_sd_predicted,j12_over_closed_sd,j12_over_closed_sd_predicted,crlb_trace_mean,crlb_trace_closed_form\n");
    for (m, model) in MODELS.iter().enumerate() {
        for r in &o.density[m] {
            let (s11, s12) = r.measured_sd();
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                model.name,
                model.bits,
                r.density,
                r.j11.len(),
                mean(&r.j11),
                mean(&r.j22),
                mean(&r.j12),
                mean(&r.rho.iter().map(|x| x.abs()).collect::<Vec<_>>()),
                r.closed,
                s11,
                r.predicted_sd.0,
                s12,
                r.predicted_sd.1,
                finite_mean(&r.trace),
                2.0 / r.closed
            );
        }
    }
    s
}

impl DensityRow {
    /// The spread of `J₁₁/c` and `J₁₂/c` over the deployments.
    fn measured_sd(&self) -> (f64, f64) {
        let rel = |v: &[f64]| v.iter().map(|j| j / self.closed).collect::<Vec<_>>();
        (sd(&rel(&self.j11)), sd(&rel(&self.j12)))
    }
}

impl ThresholdRow {
    /// The geometric means of the three designs' CRLB traces over the
    /// deployments the optimal one was searched on.
    fn paired_means(&self) -> [f64; 3] {
        let n = self.optimal.len();
        [
            geometric_mean(&self.optimal),
            geometric_mean(&self.sub_optimal[..n]),
            geometric_mean(&self.uniform[..n]),
        ]
    }
}

fn thresholds_csv(o: &Outcome) -> String {
    let mut s = String::from(
        "model,lambda,bits,optimal_deployments,optimal,sub_optimal,uniform,deployments,sub_optimal_all,uniform_all,sub_optimal_singular,uniform_singular,near_a_threshold_optimal,near_a_threshold_sub_optimal,near_a_threshold_uniform\n",
    );
    for (m, model) in MODELS.iter().enumerate() {
        for r in &o.thresholds[m] {
            let [opt, sub, uni] = r.paired_means();
            let _ = writeln!(
                s,
                "{},{},{},{},{opt},{sub},{uni},{},{},{},{},{},{},{},{}",
                model.name,
                model.density,
                r.bits,
                r.optimal.len(),
                r.uniform.len(),
                geometric_mean(&r.sub_optimal),
                geometric_mean(&r.uniform),
                singular(&r.sub_optimal),
                singular(&r.uniform),
                r.ring[0],
                r.ring[1],
                r.ring[2]
            );
        }
    }
    s
}

impl MlRow {
    fn rmse(&self) -> f64 {
        mean(&self.squared_errors).sqrt()
    }

    /// The bias gradient's diagonal (its means over trials), and the
    /// bound on a biased estimator's MSE it gives,
    /// `tr((I + ∂b/∂θ) J⁻¹ (I + ∂b/∂θ)ᵀ)` with the gradient's off-diagonal
    /// left out.
    fn biased_bound(&self) -> Option<([Paired; 2], f64)> {
        let slopes = self.slopes.as_ref()?;
        let p = |k: usize| Paired::of_values(&some(slopes[k].iter().copied()));
        let (x, y) = (p(0)?, p(1)?);
        let bound = x.mean.powi(2) * self.crlb_diagonal[0] + y.mean.powi(2) * self.crlb_diagonal[1];
        Some(([x, y], bound))
    }
}

fn ml_csv(o: &Outcome) -> String {
    let mut s = String::from("model,lambda,bits,thresholds,trials,ml_rmse,crlb_rmse,analog_crlb_rmse,slope_x,slope_x_half_width,slope_y,slope_y_half_width,biased_bound_rmse\n");
    for (m, model) in MODELS.iter().enumerate() {
        for r in &o.ml[m] {
            let bias = r.biased_bound().map_or(",,,,".to_string(), |([x, y], b)| {
                format!(
                    "{},{},{},{},{}",
                    x.mean,
                    x.half_width,
                    y.mean,
                    y.half_width,
                    b.sqrt()
                )
            });
            let _ = writeln!(
                s,
                "{},{ML_DENSITY},{},{},{},{},{},{},{bias}",
                model.name,
                r.bits,
                r.design.name(),
                r.squared_errors.len(),
                r.rmse(),
                r.crlb.sqrt(),
                r.analog.sqrt(),
            );
        }
    }
    s
}

fn table(o: &Outcome) -> String {
    let mut s = String::new();
    for (m, model) in MODELS.iter().enumerate() {
        let _ = writeln!(
            s,
            "{} decay, {} bit(s): exact (mean of {} deployments) against closed-form FIM",
            model.name, model.bits, o.work.deployments
        );
        let _ = writeln!(
            s,
            "  {:>6} {:>12} {:>12} {:>8} {:>10} {:>10} {:>10} {:>10}",
            "λ", "J11", "closed", "|ρ|", "sd J11/c", "eq. 6.36", "sd J12/c", "eq. 6.37"
        );
        for r in &o.density[m] {
            let (s11, s12) = r.measured_sd();
            let _ = writeln!(
                s,
                "  {:>6} {:>12.4e} {:>12.4e} {:>8.4} {:>10.4} {:>10.4} {:>10.4} {:>10.4}",
                r.density,
                mean(&r.j11),
                r.closed,
                mean(&r.rho.iter().map(|x| x.abs()).collect::<Vec<_>>()),
                s11,
                r.predicted_sd.0,
                s12,
                r.predicted_sd.1
            );
        }
        let _ = writeln!(s, "  thresholds at λ = {} (geometric mean of the CRLB trace over the deployments the optimal design was searched on; over all {}, with how many had a singular J):", model.density, o.work.cheap_deployments);
        for r in &o.thresholds[m] {
            let [opt, sub, uni] = r.paired_means();
            let _ = writeln!(
                s,
                "    {} bit(s), {} deployments: optimal {opt:.4e}, sub-optimal {sub:.4e}, uniform {uni:.4e}; over all: sub-optimal {:.4e} ({} singular), uniform {:.4e} ({} singular); sensors within 2σ of a threshold: optimal {:.1}, sub-optimal {:.1}, uniform {:.1}",
                r.bits,
                r.optimal.len(),
                geometric_mean(&r.sub_optimal),
                singular(&r.sub_optimal),
                geometric_mean(&r.uniform),
                singular(&r.uniform),
                r.ring[0],
                r.ring[1],
                r.ring[2]
            );
        }
        let _ = writeln!(
            s,
            "  ML at λ = {ML_DENSITY}: RMSE against √CRLB ({} trials, {} at {ML_CLAIM_BITS} bits)",
            o.work.ml_trials, o.work.ml_claim_trials
        );
        for r in &o.ml[m] {
            let bias = r.biased_bound().map_or(String::new(), |([x, y], b)| {
                format!(
                    "; bias gradient ∂x̂/∂x {} ∂ŷ/∂y {}, biased bound {:.4}",
                    x.text(3),
                    y.text(3),
                    b.sqrt()
                )
            });
            let _ = writeln!(
                s,
                "    {} bit(s), {}: {:.4} against {:.4} (analog {:.4}){bias}",
                r.bits,
                r.design.name(),
                r.rmse(),
                r.crlb.sqrt(),
                r.analog.sqrt()
            );
        }
    }
    s
}

type Series = (String, Vec<(f64, f64)>);
type Area<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;
type Figure = Result<(), Box<dyn std::error::Error>>;

/// Lines over x on log–log axes, one colour each, dashed where `dashed`.
fn draw_xy(
    path: &Path,
    caption: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(Series, bool)],
) -> Figure {
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    xy_on(&root, caption, x_desc, y_desc, series)?;
    root.present()?;
    Ok(())
}

fn xy_on(
    area: &Area<'_>,
    caption: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(Series, bool)],
) -> Figure {
    let points = series
        .iter()
        .flat_map(|((_, v), _)| v.iter())
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
    for (x, y) in points {
        (x0, x1, y0, y1) = (x0.min(*x), x1.max(*x), y0.min(*y), y1.max(*y));
    }
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(
            (x0 * 0.9..x1 * 1.1).log_scale(),
            (y0 * 0.8..y1 * 1.25).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .draw()?;
    for (i, ((name, values), dashed)) in series.iter().enumerate() {
        let line: Vec<(f64, f64)> = values
            .iter()
            .copied()
            .filter(|(_, y)| y.is_finite() && *y > 0.0)
            .collect();
        draw_line(&mut chart, i, name, line, *dashed)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// One series in colour `i`, solid or dashed, with its legend entry.
fn draw_line<DB: DrawingBackend, CT: plotters::coord::CoordTranslate<From = (f64, f64)>>(
    chart: &mut ChartContext<'_, DB, CT>,
    i: usize,
    name: &str,
    line: Vec<(f64, f64)>,
    dashed: bool,
) -> Result<(), Box<dyn std::error::Error>>
where
    DB::ErrorType: 'static,
{
    let style = Palette99::pick(i).to_rgba().stroke_width(2);
    let legend = move |(x, y): (i32, i32)| PathElement::new(vec![(x, y), (x + 20, y)], style);
    let drawn = if dashed {
        chart.draw_series(DashedLineSeries::new(line, 6, 4, style))?
    } else {
        chart.draw_series(LineSeries::new(line, style))?
    };
    // A band's second edge shares its first's legend entry.
    if !name.is_empty() {
        drawn.label(name).legend(legend);
    }
    Ok(())
}

/// Lines over a logarithmic x on a linear y.
fn semilog_on(
    area: &Area<'_>,
    caption: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(Series, bool)],
) -> Figure {
    let all: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|((_, v), _)| v.iter().copied())
        .filter(|(x, y)| *x > 0.0 && y.is_finite())
        .collect();
    let x0 = all.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
    let x1 = all.iter().map(|p| p.0).fold(0.0, f64::max);
    let y0 = all.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let y1 = all.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    let pad = 0.08 * (y1 - y0).max(1e-9);
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((x0 * 0.9..x1 * 1.1).log_scale(), y0 - pad..y1 + pad)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .draw()?;
    for (i, ((name, values), dashed)) in series.iter().enumerate() {
        draw_line(&mut chart, i, name, values.clone(), *dashed)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn draw_density(path: &Path, o: &Outcome) -> Figure {
    let mut series = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &o.density[m];
        series.push((
            (
                format!(
                    "{}, {} bit(s): exact tr J⁻¹, one deployment",
                    model.name, model.bits
                ),
                rows.iter().map(|r| (r.density, r.trace[0])).collect(),
            ),
            false,
        ));
        series.push((
            (
                format!(
                    "{}: exact tr J⁻¹, mean of {}",
                    model.name, o.work.deployments
                ),
                rows.iter()
                    .map(|r| (r.density, finite_mean(&r.trace)))
                    .collect(),
            ),
            false,
        ));
        series.push((
            (
                format!("{}: closed form 2/c", model.name),
                rows.iter().map(|r| (r.density, 2.0 / r.closed)).collect(),
            ),
            true,
        ));
    }
    draw_xy(
        path,
        "location-crlb: CRLB trace against sensor density, exact and closed form (Figs. 6.7, 6.10)",
        "sensor density λ",
        "tr CRLB",
        &series,
    )
}

/// Figs. 6.6 and 6.9: the FIM's elements against λ, one deployment's and
/// the mean, beside the closed form; and ρ (eq. 6.44).
fn draw_elements(path: &Path, model: &Model, rows: &[DensityRow]) -> Figure {
    let root = SVGBackend::new(path, (1200, 520)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(640);
    let at = |f: &dyn Fn(&DensityRow) -> f64| rows.iter().map(|r| (r.density, f(r))).collect();
    xy_on(
        &left,
        &format!(
            "{}, {} bit(s): FIM elements against λ",
            model.name, model.bits
        ),
        "sensor density λ",
        "Fisher information",
        &[
            (("J11, one deployment".into(), at(&|r| r.j11[0])), false),
            (("J22, one deployment".into(), at(&|r| r.j22[0])), false),
            (
                (
                    format!("J11, mean of {}", rows[0].j11.len()),
                    at(&|r| mean(&r.j11)),
                ),
                false,
            ),
            (("closed form c".into(), at(&|r| r.closed)), true),
        ],
    )?;
    semilog_on(
        &right,
        "ρ = J12/√(J11 J22) against λ",
        "sensor density λ",
        "ρ",
        &[
            (("ρ, one deployment".into(), at(&|r| r.rho[0])), false),
            (
                (
                    format!("|ρ|, mean of {}", rows[0].j11.len()),
                    at(&|r| mean(&r.rho.iter().map(|x| x.abs()).collect::<Vec<_>>())),
                ),
                false,
            ),
        ],
    )?;
    root.present()?;
    Ok(())
}

/// Figs. 6.8 and 6.11: J11/c and J12/c of one deployment against λ, inside
/// the 1σ region eqs. 6.36 and 6.37 predict, and the spread measured over
/// the deployments.
fn draw_relative(path: &Path, model: &Model, rows: &[DensityRow]) -> Figure {
    let root = SVGBackend::new(path, (1200, 520)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(600);
    // J₁₁/c about 1 and J₁₂/c about 0: element k of each pair.
    for (area, name, centre, k) in [(&left, "J11/c", 1.0, 0), (&right, "J12/c", 0.0, 1)] {
        let pick = |pair: (f64, f64)| if k == 0 { pair.0 } else { pair.1 };
        let value = |r: &DensityRow| pick((r.j11[0], r.j12[0])) / r.closed;
        let predicted = |r: &DensityRow| pick(r.predicted_sd);
        let measured = |r: &DensityRow| pick(r.measured_sd());
        let at = |f: &dyn Fn(&DensityRow) -> f64| rows.iter().map(|r| (r.density, f(r))).collect();
        semilog_on(
            area,
            &format!(
                "{}, {} bit(s): {name}, one deployment",
                model.name, model.bits
            ),
            "sensor density λ",
            name,
            &[
                ((format!("{name}, one deployment"), at(&value)), false),
                (
                    (
                        "predicted ±1σ (eqs. 6.36, 6.37)".into(),
                        at(&|r| centre + predicted(r)),
                    ),
                    true,
                ),
                (("".into(), at(&|r| centre - predicted(r))), true),
                (
                    (
                        format!("measured ±1σ over {}", rows[0].j11.len()),
                        at(&|r| centre + measured(r)),
                    ),
                    false,
                ),
                (("".into(), at(&|r| centre - measured(r))), false),
            ],
        )?;
    }
    root.present()?;
    Ok(())
}

/// Fig. 6.1: the signal's power contours around the target, over the
/// sensors of a deployment at λ = 2. The power falls with distance alone,
/// so each contour is a circle.
fn draw_signal(path: &Path) -> Figure {
    let root = SVGBackend::new(path, (1100, 540)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(550);
    for (m, (area, model)) in [(&left, &MODELS[0]), (&right, &MODELS[1])]
        .into_iter()
        .enumerate()
    {
        let h = model.informative;
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("{}: power g²/P₀ around the target", model.name),
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(-h..h, -h..h)?;
        chart.configure_mesh().x_desc("x").y_desc("y").draw()?;
        let sensors = deploy(&mut rng(Stream::Contours, m, 0), 2.0 * h, ML_DENSITY);
        chart.draw_series(
            sensors
                .iter()
                .map(|s| Circle::new((s[0], s[1]), 2, BLACK.filled())),
        )?;
        for (i, db) in [-3.0, -10.0, -20.0, -30.0, -40.0].into_iter().enumerate() {
            let r = model.law.reach(10f64.powf(db / 10.0));
            let circle: Vec<(f64, f64)> = (0..=180)
                .map(|k| {
                    let a = k as f64 * std::f64::consts::TAU / 180.0;
                    (r * a.cos(), r * a.sin())
                })
                .collect();
            let label = if db == -40.0 {
                format!("{db} dB (the noise power)")
            } else {
                format!("{db} dB")
            };
            draw_line(&mut chart, i, &label, circle, false)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .draw()?;
    }
    root.present()?;
    Ok(())
}

fn draw_thresholds(path: &Path, o: &Outcome) -> Figure {
    let mut series = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &o.thresholds[m];
        let line = |k: usize| {
            rows.iter()
                .map(|r| (r.bits as f64, r.paired_means()[k]))
                .collect::<Vec<_>>()
        };
        series.push(((format!("{}: optimal", model.name), line(0)), false));
        series.push((
            (format!("{}: sub-optimal (eq. 6.46)", model.name), line(1)),
            true,
        ));
        series.push(((format!("{}: uniform", model.name), line(2)), true));
    }
    draw_xy(
        path,
        "location-thresholds: CRLB trace against bits, geometric mean (Figs. 6.2, 6.3, 6.12, 6.13)",
        "bits M",
        "tr CRLB",
        &series,
    )
}

fn draw_ml(path: &Path, o: &Outcome) -> Figure {
    let mut series = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows: Vec<&MlRow> = o.ml[m]
            .iter()
            .filter(|r| r.design == Design::Optimal)
            .collect();
        series.push((
            (
                format!("{}: ML RMSE", model.name),
                rows.iter().map(|r| (r.bits as f64, r.rmse())).collect(),
            ),
            false,
        ));
        series.push((
            (
                format!("{}: √CRLB", model.name),
                rows.iter()
                    .map(|r| (r.bits as f64, r.crlb.sqrt()))
                    .collect(),
            ),
            true,
        ));
        series.push((
            (
                format!("{}: √CRLB, analog", model.name),
                rows.iter()
                    .map(|r| (r.bits as f64, r.analog.sqrt()))
                    .collect(),
            ),
            true,
        ));
    }
    draw_xy(
        path,
        "location-ml: the ML estimate against its CRLB, λ = 2 (Figs. 6.4, 6.5)",
        "bits M",
        "RMSE, √tr CRLB",
        &series,
    )
}
