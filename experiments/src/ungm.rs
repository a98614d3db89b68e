//! The dissertation's ch. 7 (Figs. 7.1, 7.2, §7.4): the conditional bounds
//! on the univariate non-stationary growth model against the conditional
//! MSE, in its highly and weakly nonlinear cases; one run's truth and
//! particle-filter estimate (Fig. 7.1(a)); and what each bound costs a
//! step, counted and timed (§7.4).
//!
//! Each run tracks one true trajectory with a bootstrap particle filter
//! (1000 particles, resampled every step). At every step k it computes,
//! from the filter's particles:
//!
//! - the A-CPCRLB (eq. 7.13), cqnet's recursion: `L(k+1) = B22 −
//!   B21(B11 + L(k))⁻¹B12`, B over the posterior at k and the prediction;
//! - Zuo et al.'s CPCRLB (eqs. 7.3, 7.9), through the auxiliary FIM
//!   `L_A(k) = S22 − S21(S11 + L_A(k−1))⁻¹S12`, with S11 and S12 over x(k−1)
//!   as the posterior at k has it (its particles' ancestors: the smoothed
//!   form the dissertation takes) and, beside it, over the posterior at
//!   k−1 (the filtered form cqnet's auxiliary-FIM baseline takes);
//! - the conditional MSE of x(k+1) given z(1:k): 1000 draws of x(k+1) from
//!   the prediction and of z(k+1) from it, each weighed by the filter's
//!   predicted particles, as section 7.5 describes;
//!
//! and, once per case, the offline PCRLB over 10⁴ trajectories.
//!
//! §7.4 counts flops per step: the A-CPCRLB needs the B terms alone, the
//! CPCRLB the B terms and the S terms of its auxiliary FIM, each a pass
//! over the particles of the same form (`bounds::ungm::step_terms`). Here
//! each run counts the per-particle evaluations of f′ and of the
//! measurement information each bound makes, and times them. The
//! D-CPCRLB of the chapter's reference [103] is not computed: the chapter
//! does not define it. The chapter does not give the prior either: here
//! x(0) ~ N(0, 1).

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use bounds::ungm::{offline_pcrlb, step_terms, Ungm};
use plotters::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::paired::{Order, Paired};
use super::random_exchange_bounds::draw_lines;
use super::{Check, Claim, Computed, ComputedReport, Options};
use launch::results::write_atomically;

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "ungm-bounds",
        source: "dissertation ch. 7, Figs. 7.1 and 7.2, section 7.4",
        about: "the A-CPCRLB, the CPCRLB with its auxiliary FIM (smoothed and filtered) and the offline PCRLB against the conditional MSE on the univariate non-stationary growth model, highly and weakly nonlinear",
        run,
    }]
}

const STEPS: u32 = 50;
const PARTICLES: usize = 1000;
const DRAWS: usize = 1000;
const RUNS: usize = 20;
const TRAJECTORIES: usize = 10_000;
const PRIOR_VARIANCE: f64 = 1.0;
const SEED: u64 = 7;

const CASES: [(&str, Ungm); 2] = [
    ("highly nonlinear", Ungm::HIGHLY_NONLINEAR),
    ("weakly nonlinear", Ungm::WEAKLY_NONLINEAR),
];

/// One run's series at steps 1..=STEPS, as variances (the bounds' 1/L).
#[derive(Default)]
struct RunSeries {
    conditional_mse: Vec<f64>,
    a_cpcrlb: Vec<f64>,
    cpcrlb_smoothed: Vec<f64>,
    cpcrlb_filtered: Vec<f64>,
    squared_error: Vec<f64>,
    /// The true state and the filter's estimate after each step's update.
    truth: Vec<f64>,
    estimate: Vec<f64>,
    /// Seconds spent on each bound's terms over the run: the A-CPCRLB's B
    /// terms; the CPCRLB's B terms and the S terms of its auxiliary FIM.
    a_cpcrlb_seconds: f64,
    cpcrlb_seconds: f64,
    /// Per-particle evaluations (of f′ or of the measurement information)
    /// each bound made over the run.
    a_cpcrlb_evaluations: usize,
    cpcrlb_evaluations: usize,
}

/// One pass of `step_terms` evaluates f′ twice (for B11 and B12) over the
/// `from` particles and the measurement information once over `to`.
fn evaluations(from: usize, to: usize) -> usize {
    2 * from + to
}

/// Systematic resampling: the indices of the particles drawn.
fn resample(weights: &[f64], rng: &mut ChaCha8Rng) -> Vec<usize> {
    let n = weights.len();
    let total: f64 = weights.iter().sum();
    let u0: f64 = rng.random::<f64>() / n as f64;
    let mut out = Vec::with_capacity(n);
    let (mut cumulative, mut i) = (weights[0] / total, 0);
    for m in 0..n {
        let u = u0 + m as f64 / n as f64;
        while u > cumulative && i + 1 < n {
            i += 1;
            cumulative += weights[i] / total;
        }
        out.push(i);
    }
    out
}

/// Normalized weights from log-likelihoods.
fn normalized(ln: &[f64]) -> Vec<f64> {
    let top = ln.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = ln.iter().map(|l| (l - top).exp()).collect();
    let total: f64 = w.iter().sum();
    w.iter().map(|x| x / total).collect()
}

/// The weighted mean of `states` under weights `exp(ln)`, normalized, in
/// two passes over `ln` and no allocation: the estimate each of the
/// conditional MSE's draws asks for.
fn weighted_estimate(ln: &[f64], states: &[f64]) -> f64 {
    let top = ln.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let (mut total, mut sum) = (0.0, 0.0);
    for (l, x) in ln.iter().zip(states) {
        let w = (l - top).exp();
        total += w;
        sum += w * x;
    }
    sum / total
}

fn one_run(model: &Ungm, rng: &mut ChaCha8Rng) -> RunSeries {
    let n = PARTICLES;
    let uniform = vec![1.0 / n as f64; n];
    let sd0 = PRIOR_VARIANCE.sqrt();
    let mut truth = sd0 * rng.sample::<f64, _>(rand_distr::StandardNormal);
    let mut x: Vec<f64> = (0..n)
        .map(|_| sd0 * rng.sample::<f64, _>(rand_distr::StandardNormal))
        .collect();
    let mut w = uniform.clone();
    // The posterior at k−1, and each particle's ancestor at k−1.
    let (mut previous, mut previous_w, mut ancestors): (Option<Vec<f64>>, Vec<f64>, Vec<f64>) =
        (None, uniform.clone(), x.clone());
    let prior_information = 1.0 / PRIOR_VARIANCE;
    let (mut l_a, mut aux_smoothed, mut aux_filtered) =
        (prior_information, prior_information, prior_information);
    let mut out = RunSeries::default();
    for k in 0..STEPS {
        // The auxiliary FIM at k, from the pair (x(k−1), x(k)).
        let mut s_seconds = 0.0;
        if let Some(prev) = &previous {
            let started = Instant::now();
            let smoothed = step_terms(model, &ancestors, &w, &x, &w);
            aux_smoothed = smoothed.advance(aux_smoothed);
            s_seconds = started.elapsed().as_secs_f64();
            out.cpcrlb_evaluations += evaluations(ancestors.len(), x.len());
            let filtered = step_terms(model, prev, &previous_w, &x, &w);
            aux_filtered = filtered.advance(aux_filtered);
        }
        // The prediction: resample, then move each particle.
        let picks = resample(&w, rng);
        let parents: Vec<f64> = picks.iter().map(|&i| x[i]).collect();
        let predicted: Vec<f64> = parents
            .iter()
            .map(|p| model.propagate(*p, k, rng))
            .collect();
        let started = Instant::now();
        let terms = step_terms(model, &x, &w, &predicted, &uniform);
        l_a = terms.advance(l_a);
        let b_seconds = started.elapsed().as_secs_f64();
        out.a_cpcrlb_seconds += b_seconds;
        out.cpcrlb_seconds += b_seconds + s_seconds;
        let b = evaluations(x.len(), predicted.len());
        out.a_cpcrlb_evaluations += b;
        out.cpcrlb_evaluations += b;
        out.a_cpcrlb.push(1.0 / l_a);
        out.cpcrlb_smoothed.push(1.0 / terms.advance(aux_smoothed));
        out.cpcrlb_filtered.push(1.0 / terms.advance(aux_filtered));
        // The conditional MSE of x(k+1) given z(1:k).
        let mut ln = vec![0.0; n];
        let mse = (0..DRAWS)
            .map(|_| {
                let from = parents[rng.random_range(0..n)];
                let state = model.propagate(from, k, rng);
                let z = model.measure(state, rng);
                for (l, p) in ln.iter_mut().zip(&predicted) {
                    *l = model.ln_likelihood(z, *p);
                }
                (state - weighted_estimate(&ln, &predicted)).powi(2)
            })
            .sum::<f64>()
            / DRAWS as f64;
        out.conditional_mse.push(mse);
        // The truth moves and is measured; the filter updates.
        truth = model.propagate(truth, k, rng);
        let z = model.measure(truth, rng);
        let ln: Vec<f64> = predicted
            .iter()
            .map(|p| model.ln_likelihood(z, *p))
            .collect();
        previous = Some(std::mem::replace(&mut x, predicted));
        previous_w = std::mem::replace(&mut w, normalized(&ln));
        ancestors = parents;
        let estimate: f64 = w.iter().zip(&x).map(|(w, p)| w * p).sum();
        out.squared_error.push((estimate - truth).powi(2));
        out.truth.push(truth);
        out.estimate.push(estimate);
    }
    out
}

struct Case {
    name: &'static str,
    runs: Vec<RunSeries>,
    offline: Vec<f64>,
}

fn run(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let (runs, trajectories) = options.sized((RUNS, TRAJECTORIES), (2, 200));
    let cases: Vec<Case> = CASES
        .iter()
        .map(|(name, model)| {
            eprintln!("ungm-bounds: {name}, {runs} runs");
            let offline = offline_pcrlb(model, 0.0, PRIOR_VARIANCE, STEPS, trajectories, &mut rng)
                .iter()
                .skip(1)
                .map(|j| 1.0 / j)
                .collect();
            Case {
                name,
                runs: (0..runs).map(|_| one_run(model, &mut rng)).collect(),
                offline,
            }
        })
        .collect();
    let weak = dir.join("ungm-bounds-weakly-nonlinear.svg");
    draw(&weak, &cases[1]).map_err(|e| anyhow::anyhow!("{e}"))?;
    draw_tracking(&dir.join("ungm-bounds-tracking.svg"), &cases[0])
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    write_atomically(
        &dir.join("ungm-bounds-cost.csv"),
        cost_csv(&cases).as_bytes(),
    )?;
    ComputedReport::write(
        dir,
        "ungm-bounds",
        &csv(&cases),
        |svg| draw(svg, &cases[0]),
        check(&cases),
        table(&cases),
    )
}

fn mean_over_runs(case: &Case, of: fn(&RunSeries) -> &Vec<f64>) -> Vec<f64> {
    (0..STEPS as usize)
        .map(|k| case.runs.iter().map(|r| of(r)[k]).sum::<f64>() / case.runs.len() as f64)
        .collect()
}

/// A run's mean over steps of |ln(a/b)|: how far one curve strays from
/// another, as a ratio.
fn log_distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a / b).ln().abs())
        .sum::<f64>()
        / a.len() as f64
}

fn check(cases: &[Case]) -> Check {
    let mut claims = Vec::new();
    let mut figures = Vec::new();
    for case in cases {
        let per_run = |f: &dyn Fn(&RunSeries) -> f64| -> Vec<Option<f64>> {
            case.runs.iter().map(|r| Some(f(r))).collect()
        };
        let a = per_run(&|r| log_distance(&r.a_cpcrlb, &r.conditional_mse));
        let off = per_run(&|r| log_distance(&case.offline, &r.conditional_mse));
        claims.push(Claim::judged(
            format!("{}: the A-CPCRLB follows the conditional MSE more faithfully than the offline PCRLB (mean |ln(bound/MSE)| over steps)", case.name),
            Paired::of(&a, &off),
            |p| p.verdict(Order::Lower),
            |p| format!("{} over {} runs", p.text(3), p.runs),
        ));
        let overlap = per_run(&|r| log_distance(&r.a_cpcrlb, &r.cpcrlb_smoothed));
        claims.push(Claim::judged(
            format!("{}: the CPCRLB and the A-CPCRLB almost overlap (within 10 %: mean |ln ratio| < ln 1.1)", case.name),
            Paired::of_values(&overlap),
            |p| p.verdict_within(-(1.1f64.ln()), 1.1f64.ln()),
            |p| format!("{} over {} runs", p.text(4), p.runs),
        ));
        let forms = per_run(&|r| log_distance(&r.cpcrlb_filtered, &r.cpcrlb_smoothed));
        claims.push(Claim::judged(
            format!("{}: S11, S12 over the filtered posterior at k−1 give the smoothed form's CPCRLB within 5 %", case.name),
            Paired::of_values(&forms),
            |p| p.verdict_within(-(1.05f64.ln()), 1.05f64.ln()),
            |p| format!("{:.2e} ± {:.2e} over {} runs", p.mean, p.half_width, p.runs),
        ));
        // §7.4: the A-CPCRLB spares the auxiliary FIM's pass. Timed per
        // run, compared by the ratio of the two times in the same run.
        claims.push(Claim::judged(
            format!("{}: the A-CPCRLB costs less time a step than the CPCRLB with its auxiliary FIM (§7.4)", case.name),
            Paired::of_values(&per_run(&|r| (r.a_cpcrlb_seconds / r.cpcrlb_seconds).ln())),
            |p| p.verdict(Order::Lower),
            |p| {
                format!(
                    "A-CPCRLB/CPCRLB time ×{:.2} (95 %: ×{:.2} to ×{:.2}) over {} runs",
                    p.mean.exp(),
                    (p.mean - p.half_width).exp(),
                    (p.mean + p.half_width).exp(),
                    p.runs
                )
            },
        ));
        let [mse, a, smoothed, filtered, offline, _] = columns(case);
        figures.push(format!(
            "{}: over steps, conditional MSE {:.3}, A-CPCRLB {:.3}, CPCRLB {:.3} (filtered {:.3}), offline PCRLB {:.3} (means)",
            case.name,
            mean(&mse),
            mean(&a),
            mean(&smoothed),
            mean(&filtered),
            mean(&offline)
        ));
    }
    Check::of_claims(claims, figures.join("; "))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// §7.4's comparison per case: evaluations and time per step of each
/// bound, means over runs.
fn cost_csv(cases: &[Case]) -> String {
    let mut s = String::from("case,particles,a_cpcrlb_evaluations_per_step,cpcrlb_evaluations_per_step,a_cpcrlb_microseconds_per_step,cpcrlb_microseconds_per_step\n");
    for case in cases {
        let per_step = |f: &dyn Fn(&RunSeries) -> f64| {
            case.runs.iter().map(f).sum::<f64>() / (case.runs.len() as f64 * STEPS as f64)
        };
        let _ = writeln!(
            s,
            "{},{PARTICLES},{},{},{:.2},{:.2}",
            case.name,
            per_step(&|r| r.a_cpcrlb_evaluations as f64),
            per_step(&|r| r.cpcrlb_evaluations as f64),
            1e6 * per_step(&|r| r.a_cpcrlb_seconds),
            1e6 * per_step(&|r| r.cpcrlb_seconds),
        );
    }
    s
}

/// Fig. 7.1(a): the true state and the particle filter's estimate over
/// one run.
fn draw_tracking(path: &Path, case: &Case) -> Result<(), Box<dyn std::error::Error>> {
    let run = &case.runs[0];
    let root = SVGBackend::new(path, (900, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let reach = run
        .truth
        .iter()
        .chain(&run.estimate)
        .fold(1.0f64, |m, v| m.max(v.abs()))
        * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!(
                "ungm-bounds: {}, the true state and its estimate (Fig. 7.1(a))",
                case.name
            ),
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(1..STEPS, -reach..reach)?;
    chart
        .configure_mesh()
        .x_desc("step k")
        .y_desc("x(k)")
        .draw()?;
    for (i, (name, values)) in [
        ("true state", &run.truth),
        ("particle filter's estimate", &run.estimate),
    ]
    .into_iter()
    .enumerate()
    {
        let colour = Palette99::pick(i).to_rgba();
        let points: Vec<(u32, f64)> = (1..=STEPS).zip(values.iter().copied()).collect();
        chart
            .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))?
            .label(name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart.draw_series(points.iter().map(|p| Circle::new(*p, 3, colour.filled())))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

/// A case's curves at steps 1..=STEPS, in the CSV's order: the
/// conditional MSE, the A-CPCRLB, the CPCRLB smoothed and filtered (means
/// over runs), the offline PCRLB, and the filter's MSE.
fn columns(case: &Case) -> [Vec<f64>; 6] {
    [
        mean_over_runs(case, |r| &r.conditional_mse),
        mean_over_runs(case, |r| &r.a_cpcrlb),
        mean_over_runs(case, |r| &r.cpcrlb_smoothed),
        mean_over_runs(case, |r| &r.cpcrlb_filtered),
        case.offline.clone(),
        mean_over_runs(case, |r| &r.squared_error),
    ]
}

fn csv(cases: &[Case]) -> String {
    let mut s = String::from(
        "case,step,conditional_mse,a_cpcrlb,cpcrlb_smoothed,cpcrlb_filtered,offline_pcrlb,pf_mse\n",
    );
    for case in cases {
        let series = columns(case);
        for k in 0..STEPS as usize {
            let _ = write!(s, "{},{}", case.name, k + 1);
            for v in &series {
                let _ = write!(s, ",{}", v[k]);
            }
            s.push('\n');
        }
    }
    s
}

fn table(cases: &[Case]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "cost a step (§7.4; means over runs):");
    for line in cost_csv(cases).lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let _ = writeln!(
            s,
            "  {}: {} particles; evaluations A-CPCRLB {}, CPCRLB {}; time A-CPCRLB {} µs, CPCRLB {} µs",
            f[0], f[1], f[2], f[3], f[4], f[5]
        );
    }
    for case in cases {
        let _ = writeln!(s, "{} (means over {} runs): step, conditional MSE, A-CPCRLB, CPCRLB smoothed, filtered, offline PCRLB", case.name, case.runs.len());
        let cols = columns(case);
        for k in [0usize, 4, 9, 19, 29, 39, 49] {
            let _ = writeln!(
                s,
                "  {:>3} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>9.4}",
                k + 1,
                cols[0][k],
                cols[1][k],
                cols[2][k],
                cols[3][k],
                cols[4][k]
            );
        }
    }
    s
}

fn draw(path: &Path, case: &Case) -> Result<(), Box<dyn std::error::Error>> {
    let names = [
        "conditional MSE (mean of runs)",
        "A-CPCRLB",
        "CPCRLB, smoothed S",
        "CPCRLB, filtered S",
        "offline PCRLB",
    ];
    // draw_lines plots from index 1: a leading NaN stands for step 0.
    let lines: Vec<Vec<f64>> = columns(case)
        .into_iter()
        .take(names.len())
        .map(|v| std::iter::once(f64::NAN).chain(v).collect())
        .collect();
    let refs: Vec<(String, &[f64])> = names
        .iter()
        .zip(&lines)
        .map(|(n, v)| (n.to_string(), &v[..]))
        .collect();
    draw_lines(
        path,
        &format!("ungm-bounds: {}, bounds and conditional MSE", case.name),
        "variance of x(k)",
        &refs,
        &[],
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn systematic_resampling_draws_each_particle_in_proportion_to_its_weight() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let weights = [0.5, 0.0, 0.25, 0.125, 0.125];
        let picks = resample(&[0.5, 0.0, 0.25, 0.125, 0.125].repeat(200), &mut rng);
        let mut counts = [0usize; 5];
        for i in picks {
            counts[i % 5] += 1;
        }
        for (c, w) in counts.iter().zip(weights) {
            // Systematic resampling is within one draw of n·w per particle.
            assert!((*c as f64 - 1000.0 * w).abs() <= 200.0, "{counts:?}");
        }
        assert_eq!(counts[1], 0);
    }

    #[test]
    fn the_weighted_estimate_is_the_normalized_weights_mean() {
        let ln = [-1e6, -1e6 - 1.0, -1e6 - 2.0, -1e6 - 0.5];
        let states = [1.0, -2.0, 3.5, 0.25];
        let by_weights: f64 = normalized(&ln)
            .iter()
            .zip(&states)
            .map(|(w, x)| w * x)
            .sum();
        assert!((weighted_estimate(&ln, &states) - by_weights).abs() < 1e-14);
    }

    #[test]
    fn normalized_weights_sum_to_one_far_into_the_tails() {
        let w = normalized(&[-1e6, -1e6 - 1.0, -1e6 - 2.0]);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(w[0] > w[1] && w[1] > w[2]);
    }
}
