//! The dissertation's ch. 6: a static target at the origin, located from
//! quantized amplitudes by sensors spread uniformly at density λ, for the
//! Gaussian-like decay (α = 1) and the power law (n = 4), σ = 1,
//! P₀ = 10⁴ (40 dB). Three parts, each a CSV and an SVG:
//!
//! - `location-crlb`: the exact FIM of random deployments against the
//!   closed form as λ grows (Figs. 6.6–6.11), with M = 1 bit for the
//!   Gaussian law and M = 4 for the power law, as the chapter has them;
//! - `location-thresholds`: the CRLB of optimal, sub-optimal (eq. 6.46)
//!   and uniform thresholds against bits (Figs. 6.2, 6.3, 6.12, 6.13);
//! - `location-ml`: the ML estimate's RMSE against the CRLB and the
//!   analog CRLB at λ = 2 (Figs. 6.4, 6.5).
//!
//! Where the chapter does not say: the thresholds of the density and ML
//! parts are the sub-optimal ones (the optimal ones need each
//! deployment's positions); the
//! optimal thresholds are optimized on the sensors within 5 (Gaussian) or
//! 10 (power law) of the target, beyond which a sensor's β is below 10⁻⁸
//! of the nearest ones'; the squares' sides are 18 (the Gaussian signal's
//! power falls to about 10⁻³⁵ P₀ at their edges, as in section 6.7.3) and
//! 40 (the power law's to 6·10⁻⁶ P₀: the chapter's 10⁻⁷ would need a side
//! of 112 and 50,000 sensors at λ = 4).

use std::fmt::Write as _;
use std::path::Path;

use bounds::fisher::Measurement;
use bounds::location::{
    closed_form_information, correlation, crlb_trace, exact_information, log_likelihood,
    ml_estimate, optimize_thresholds, relative_information_variance, uniform_quantizer, DecayLaw,
};
use bounds::Quantizer;
use plotters::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::paired::{Order, Paired};
use super::{Check, Claim, Computed, ComputedReport, Options};
use launch::results::write_atomically;

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "location-crlb",
        source: "dissertation ch. 6, Figs. 6.2-6.13",
        about: "a static target located from quantized amplitudes: the exact CRLB of random deployments against the closed form as the density grows, optimal, sub-optimal and uniform thresholds, and the ML estimate against its CRLB, for Gaussian-like and power-law decay",
        run,
    }]
}

const SIGMA: f64 = 1.0;

/// One decay law as the chapter studies it.
struct Model {
    name: &'static str,
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
const DEPLOYMENTS: usize = 20;
/// Deployments of the thresholds part: the 1-bit CRLB of one deployment
/// rests on the few sensors near the one amplitude its threshold marks, so
/// it varies most, and its optimum is a search over one threshold.
const THRESHOLD_DEPLOYMENTS: usize = 12;
const THRESHOLD_DEPLOYMENTS_MULTIBIT: usize = 4;
const BITS: [u8; 4] = [1, 2, 3, 4];
const ML_DENSITY: f64 = 2.0;
const ML_TRIALS: usize = 100;
/// The ML part's square: the power law's 40 would make each trial's grid
/// search 16 times longer for sensors that add nothing.
const ML_SIDE: f64 = 18.0;
const SEED: u64 = 6;

fn deploy(rng: &mut ChaCha8Rng, side: f64, density: f64) -> Vec<[f64; 2]> {
    let n = (density * side * side).round() as usize;
    let h = side / 2.0;
    (0..n)
        .map(|_| [rng.random_range(-h..h), rng.random_range(-h..h)])
        .collect()
}

/// The sub-optimal thresholds of eq. 6.46: those maximizing the closed
/// form, which needs no sensor's position (and not λ, which scales it).
fn sub_optimal(model: &Model, bits: u8) -> Quantizer {
    optimize_thresholds(
        bits,
        -4.0 * SIGMA,
        model.law.p0().sqrt() + 4.0 * SIGMA,
        |q| {
            closed_form_information(
                model.law,
                Measurement::Quantized(q),
                SIGMA,
                1.0,
                model.side / 2.0,
            )
        },
    )
}

/// The optimal thresholds of one deployment: those minimizing its exact
/// CRLB's trace.
fn optimal(model: &Model, bits: u8, sensors: &[[f64; 2]]) -> Quantizer {
    let near: Vec<[f64; 2]> = sensors
        .iter()
        .copied()
        .filter(|s| s[0].hypot(s[1]) < model.informative)
        .collect();
    optimize_thresholds(
        bits,
        -4.0 * SIGMA,
        model.law.p0().sqrt() + 4.0 * SIGMA,
        |q| {
            crlb_trace(&exact_information(
                model.law,
                Measurement::Quantized(q),
                SIGMA,
                &near,
                [0.0, 0.0],
            ))
            .map_or(f64::NEG_INFINITY, |t| -t)
        },
    )
}

fn trace_of(model: &Model, report: Measurement<'_>, sensors: &[[f64; 2]]) -> Option<f64> {
    crlb_trace(&exact_information(
        model.law,
        report,
        SIGMA,
        sensors,
        [0.0, 0.0],
    ))
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
    /// The 1σ of `J₁₁/c` eq. 6.36 predicts.
    predicted_sd: f64,
}

fn density_part(model: &Model, q: &Quantizer, rng: &mut ChaCha8Rng) -> Vec<DensityRow> {
    let report = Measurement::Quantized(q);
    let radius = model.side / 2.0;
    DENSITIES
        .iter()
        .map(|&density| {
            let js: Vec<_> = (0..DEPLOYMENTS)
                .map(|_| {
                    exact_information(
                        model.law,
                        report,
                        SIGMA,
                        &deploy(rng, model.side, density),
                        [0.0, 0.0],
                    )
                })
                .collect();
            let in_disc = density * std::f64::consts::PI * radius * radius;
            let (var11, _) =
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
                predicted_sd: var11.sqrt(),
            }
        })
        .collect()
}

/// The thresholds part at one bit depth: each deployment's CRLB trace with
/// each design.
struct ThresholdRow {
    bits: u8,
    optimal: Vec<f64>,
    sub_optimal: Vec<f64>,
    uniform: Vec<f64>,
}

fn threshold_part(
    model: &Model,
    designed: &[Quantizer],
    rng: &mut ChaCha8Rng,
) -> Vec<ThresholdRow> {
    let deployments: Vec<Vec<[f64; 2]>> = (0..THRESHOLD_DEPLOYMENTS)
        .map(|_| deploy(rng, model.side, model.density))
        .collect();
    BITS.iter()
        .zip(designed)
        .map(|(&bits, sub)| {
            let count = if bits == 1 {
                THRESHOLD_DEPLOYMENTS
            } else {
                THRESHOLD_DEPLOYMENTS_MULTIBIT
            };
            let deployments = &deployments[..count];
            let uni = uniform_quantizer(bits, model.law, SIGMA);
            let of = |q: &Quantizer, s: &[[f64; 2]]| {
                trace_of(model, Measurement::Quantized(q), s).unwrap_or(f64::NAN)
            };
            ThresholdRow {
                bits,
                optimal: deployments
                    .iter()
                    .map(|s| of(&optimal(model, bits, s), s))
                    .collect(),
                sub_optimal: deployments.iter().map(|s| of(sub, s)).collect(),
                uniform: deployments.iter().map(|s| of(&uni, s)).collect(),
            }
        })
        .collect()
}

/// The ML part at one bit depth: each trial's squared error, and the CRLB.
struct MlRow {
    bits: u8,
    squared_errors: Vec<f64>,
    crlb: f64,
    analog: f64,
}

fn ml_part(model: &Model, designed: &[Quantizer], rng: &mut ChaCha8Rng) -> Vec<MlRow> {
    let sensors = deploy(rng, ML_SIDE, ML_DENSITY);
    let analog = trace_of(model, Measurement::Raw, &sensors).unwrap_or(f64::NAN);
    BITS.iter()
        .zip(designed)
        .map(|(&bits, q)| {
            let crlb = trace_of(model, Measurement::Quantized(q), &sensors).unwrap_or(f64::NAN);
            let squared_errors = (0..ML_TRIALS)
                .map(|_| {
                    let cells: Vec<u32> = sensors
                        .iter()
                        .map(|s| {
                            let n: f64 = rng.sample(rand_distr::StandardNormal);
                            q.encode(model.law.amplitude(s[0].hypot(s[1])) + SIGMA * n)
                        })
                        .collect();
                    let h = ML_SIDE / 2.0;
                    let at = ml_estimate(
                        |t| log_likelihood(model.law, q, SIGMA, &sensors, &cells, t),
                        -h,
                        h,
                        0.5,
                        3,
                    );
                    at[0] * at[0] + at[1] * at[1]
                })
                .collect();
            MlRow {
                bits,
                squared_errors,
                crlb,
                analog,
            }
        })
        .collect()
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

struct Outcome {
    density: Vec<Vec<DensityRow>>,
    thresholds: Vec<Vec<ThresholdRow>>,
    ml: Vec<Vec<MlRow>>,
}

fn run(_options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let mut outcome = Outcome {
        density: Vec::new(),
        thresholds: Vec::new(),
        ml: Vec::new(),
    };
    for model in &MODELS {
        eprintln!(
            "location-crlb: {} decay, sub-optimal thresholds",
            model.name
        );
        let designed: Vec<Quantizer> = BITS.iter().map(|&b| sub_optimal(model, b)).collect();
        let q = &designed[BITS
            .iter()
            .position(|&b| b == model.bits)
            .expect("the density part's bits are among BITS")];
        eprintln!(
            "location-crlb: {} decay, density against closed form",
            model.name
        );
        outcome.density.push(density_part(model, q, &mut rng));
        eprintln!("location-crlb: {} decay, optimal thresholds", model.name);
        outcome
            .thresholds
            .push(threshold_part(model, &designed, &mut rng));
        eprintln!("location-crlb: {} decay, ML estimates", model.name);
        outcome.ml.push(ml_part(model, &designed, &mut rng));
    }
    write_atomically(
        &dir.join("location-thresholds.csv"),
        thresholds_csv(&outcome).as_bytes(),
    )?;
    write_atomically(&dir.join("location-ml.csv"), ml_csv(&outcome).as_bytes())?;
    draw_thresholds(&dir.join("location-thresholds.svg"), &outcome)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    draw_ml(&dir.join("location-ml.svg"), &outcome).map_err(|e| anyhow::anyhow!("{e}"))?;
    ComputedReport::write(
        dir,
        "location-crlb",
        &density_csv(&outcome),
        |svg| draw_density(svg, &outcome),
        check(&outcome),
        table(&outcome),
    )
}

fn check(o: &Outcome) -> Check {
    let mut claims = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &o.density[m];
        let (first, last) = (&rows[0], &rows[rows.len() - 1]);
        let ratio = |r: &DensityRow| some(r.j11.iter().map(|j| j / r.closed - 1.0));
        let at_top = Paired::of_values(&ratio(last));
        claims.push(Claim::judged(
            format!(
                "{}: the exact J11 averages the closed form at λ = {} (within ±5 %)",
                model.name, last.density
            ),
            at_top,
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
        let per_density =
            |r: &DensityRow| some(r.j11.iter().map(|j| j / r.density / (r.closed / r.density)));
        claims.push(Claim::judged(
            format!("{}: the information is linear in λ: J11/λ at λ = {} equals J11/λ at λ = 1 (within ±10 % of the closed form's)", model.name, last.density),
            Paired::of(&per_density(last), &per_density(one)),
            |p| p.verdict_within(-0.10, 0.10),
            |p| format!("{} over {} deployments", p.text(3), p.runs),
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
        let one_bit = &o.thresholds[m][0];
        // CRLBs are compared by their logarithms: one deployment's can be
        // a thousand times another's, and a ratio is what the claim is about.
        let ln = |v: &[f64]| some(v.iter().map(|x| x.ln()));
        claims.push(Claim::judged(
            format!("{}: at 1 bit the sub-optimal thresholds' CRLB is within 10 % of the optimal's (λ = {})", model.name, model.density),
            Paired::of(&ln(&one_bit.sub_optimal), &ln(&one_bit.optimal)),
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
        let ml = &o.ml[m];
        let top = &ml[ml.len() - 1];
        claims.push(Claim::judged(
            format!("{}: at {} bits the ML estimate's MSE is within ±25 % of its CRLB (λ = {ML_DENSITY})", model.name, top.bits),
            Paired::of_values(&some(top.squared_errors.iter().map(|e| e / top.crlb - 1.0))),
            |p| p.verdict_within(-0.25, 0.25),
            |p| format!("{} over {} trials", p.text(3), p.runs),
        ));
    }
    let figures = MODELS
        .iter()
        .enumerate()
        .map(|(m, model)| {
            let last = o.density[m].last().expect("densities");
            let one_bit = &o.thresholds[m][0];
            format!(
                "{}: at λ = {} J11 {:.4e} against the closed form {:.4e}; at 1 bit CRLB optimal {:.4e}, sub-optimal {:.4e}, uniform {:.4e}",
                model.name,
                last.density,
                mean(&last.j11),
                last.closed,
                mean(&one_bit.optimal),
                mean(&one_bit.sub_optimal),
                mean(&one_bit.uniform)
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
    let mut s = String::from("model,lambda,j11_mean,j22_mean,j12_mean,abs_rho_mean,closed_form,j11_over_closed_sd,j11_over_closed_sd_predicted,crlb_trace_mean,crlb_trace_closed_form\n");
    for (m, model) in MODELS.iter().enumerate() {
        for r in &o.density[m] {
            let rel: Vec<f64> = r.j11.iter().map(|j| j / r.closed).collect();
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{}",
                model.name,
                r.density,
                mean(&r.j11),
                mean(&r.j22),
                mean(&r.j12),
                mean(&r.rho.iter().map(|x| x.abs()).collect::<Vec<_>>()),
                r.closed,
                sd(&rel),
                r.predicted_sd,
                mean(&r.trace),
                2.0 / r.closed
            );
        }
    }
    s
}

fn thresholds_csv(o: &Outcome) -> String {
    let mut s = String::from(
        "model,lambda,bits,crlb_trace_optimal,crlb_trace_sub_optimal,crlb_trace_uniform\n",
    );
    for (m, model) in MODELS.iter().enumerate() {
        for r in &o.thresholds[m] {
            let _ = writeln!(
                s,
                "{},{},{},{},{},{}",
                model.name,
                model.density,
                r.bits,
                mean(&r.optimal),
                mean(&r.sub_optimal),
                mean(&r.uniform)
            );
        }
    }
    s
}

fn ml_csv(o: &Outcome) -> String {
    let mut s = String::from("model,lambda,bits,ml_rmse,crlb_rmse,analog_crlb_rmse,trials\n");
    for (m, model) in MODELS.iter().enumerate() {
        for r in &o.ml[m] {
            let _ = writeln!(
                s,
                "{},{ML_DENSITY},{},{},{},{},{}",
                model.name,
                r.bits,
                mean(&r.squared_errors).sqrt(),
                r.crlb.sqrt(),
                r.analog.sqrt(),
                r.squared_errors.len()
            );
        }
    }
    s
}

fn table(o: &Outcome) -> String {
    let mut s = String::new();
    for (m, model) in MODELS.iter().enumerate() {
        let _ = writeln!(s, "{} decay, {} bit(s): exact (mean of {DEPLOYMENTS} deployments) against closed-form FIM", model.name, model.bits);
        let _ = writeln!(
            s,
            "  {:>6} {:>12} {:>12} {:>8} {:>10} {:>10}",
            "λ", "J11", "closed", "|ρ|", "sd J11/c", "eq. 6.36"
        );
        for r in &o.density[m] {
            let rel: Vec<f64> = r.j11.iter().map(|j| j / r.closed).collect();
            let _ = writeln!(
                s,
                "  {:>6} {:>12.4e} {:>12.4e} {:>8.4} {:>10.4} {:>10.4}",
                r.density,
                mean(&r.j11),
                r.closed,
                mean(&r.rho.iter().map(|x| x.abs()).collect::<Vec<_>>()),
                sd(&rel),
                r.predicted_sd
            );
        }
        let _ = writeln!(s, "  thresholds at λ = {} (CRLB trace, mean of {THRESHOLD_DEPLOYMENTS} deployments at 1 bit, {THRESHOLD_DEPLOYMENTS_MULTIBIT} above):", model.density);
        for r in &o.thresholds[m] {
            let _ = writeln!(
                s,
                "    {} bit(s): optimal {:.4e}, sub-optimal {:.4e}, uniform {:.4e}",
                r.bits,
                mean(&r.optimal),
                mean(&r.sub_optimal),
                mean(&r.uniform)
            );
        }
        let _ = writeln!(
            s,
            "  ML at λ = {ML_DENSITY} ({ML_TRIALS} trials): RMSE against √CRLB"
        );
        for r in &o.ml[m] {
            let _ = writeln!(
                s,
                "    {} bit(s): {:.4} against {:.4} (analog {:.4})",
                r.bits,
                mean(&r.squared_errors).sqrt(),
                r.crlb.sqrt(),
                r.analog.sqrt()
            );
        }
    }
    s
}

type Series = (String, Vec<(f64, f64)>);

/// Lines over x on log–log axes, one colour each, dashed where `dashed`.
fn draw_xy(
    path: &Path,
    caption: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(Series, bool)],
) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let points = series
        .iter()
        .flat_map(|((_, v), _)| v.iter())
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
    for (x, y) in points {
        (x0, x1, y0, y1) = (x0.min(*x), x1.max(*x), y0.min(*y), y1.max(*y));
    }
    let mut chart = ChartBuilder::on(&root)
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
        let colour = Palette99::pick(i).to_rgba();
        let style = colour.stroke_width(2);
        let line: Vec<(f64, f64)> = values
            .iter()
            .copied()
            .filter(|(_, y)| y.is_finite() && *y > 0.0)
            .collect();
        if *dashed {
            chart
                .draw_series(DashedLineSeries::new(line, 6, 4, style))?
                .label(name.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        } else {
            chart
                .draw_series(LineSeries::new(line, style))?
                .label(name.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

fn draw_density(path: &Path, o: &Outcome) -> Result<(), Box<dyn std::error::Error>> {
    let mut series = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &o.density[m];
        series.push((
            (
                format!("{}, {} bit(s): exact tr J⁻¹ (mean)", model.name, model.bits),
                rows.iter().map(|r| (r.density, mean(&r.trace))).collect(),
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
        "location-crlb: CRLB trace against sensor density, exact and closed form",
        "sensor density λ",
        "tr CRLB",
        &series,
    )
}

fn draw_thresholds(path: &Path, o: &Outcome) -> Result<(), Box<dyn std::error::Error>> {
    let mut series = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &o.thresholds[m];
        let line = |f: fn(&ThresholdRow) -> &Vec<f64>| {
            rows.iter()
                .map(|r| (r.bits as f64, mean(f(r))))
                .collect::<Vec<_>>()
        };
        series.push((
            (format!("{}: optimal", model.name), line(|r| &r.optimal)),
            false,
        ));
        series.push((
            (
                format!("{}: sub-optimal (eq. 6.46)", model.name),
                line(|r| &r.sub_optimal),
            ),
            true,
        ));
        series.push((
            (format!("{}: uniform", model.name), line(|r| &r.uniform)),
            true,
        ));
    }
    draw_xy(
        path,
        "location-thresholds: CRLB trace against bits",
        "bits M",
        "tr CRLB",
        &series,
    )
}

fn draw_ml(path: &Path, o: &Outcome) -> Result<(), Box<dyn std::error::Error>> {
    let mut series = Vec::new();
    for (m, model) in MODELS.iter().enumerate() {
        let rows = &o.ml[m];
        series.push((
            (
                format!("{}: ML RMSE", model.name),
                rows.iter()
                    .map(|r| (r.bits as f64, mean(&r.squared_errors).sqrt()))
                    .collect(),
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
        "location-ml: the ML estimate against its CRLB, λ = 2",
        "bits M",
        "RMSE, √tr CRLB",
        &series,
    )
}
