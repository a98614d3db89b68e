//! Dissertation ch. 5: the bit allocation over two sensors with controlled
//! noise injected at the fusion centre, Tables 5.1 (R = 20) and 5.2
//! (R = 12), computed from the chapter's formulas and printed beside the
//! dissertation's figures, and Fig. 5.3, the information of one sensor
//! against the injected noise. No network: the problem is one scalar
//! observed once by two sensors. The estimators' MSEs of Table 5.2 are
//! Monte Carlo over draws every allocation shares (the same θ and the
//! same noise, sensor by sensor), so allocations compare draw by draw.

use std::fmt::Write as _;
use std::path::Path;

use bounds::bit_allocation::{
    dissertation_problem, estimator_squared_errors, smallest_injected_std,
    smeared_gaussian_information, Allocation, Problem,
};
use plotters::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::paired::{Order, Paired};
use super::parallel::indexed;
use super::{Check, Claim, Computed, ComputedReport, Options, Verdict};
use launch::results::write_atomically;

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "bit-allocation",
        source: "dissertation ch. 5, Tables 5.1 and 5.2, Fig. 5.3",
        about: "R bits over two sensors (noise 0.6 and 3) with Gaussian noise injected at the fusion centre: J of every feasible allocation, the optimum, and for R = 12 the MMSE and LMMSE estimators' MSEs by Monte Carlo over draws the allocations share; and one sensor's J against the injected noise",
        run,
    }]
}

/// Table 5.1 (R = 20): (bits of sensor 1, bits of sensor 2), J.
const TABLE_5_1: [((u32, u32), f64); 13] = [
    ((20, 0), 3.0231),
    ((16, 4), 3.1062),
    ((15, 5), 3.1318),
    ((14, 6), 3.1331),
    ((13, 7), 3.1366),
    ((12, 8), 3.1385),
    ((11, 9), 3.1313),
    ((10, 10), 3.1376),
    ((9, 11), 3.1172),
    ((8, 12), 3.1204),
    ((7, 13), 3.0492),
    ((6, 14), 2.7506),
    ((0, 20), 0.3610),
];

/// Table 5.2 (R = 12): bits, J, PCRLB, MSE1 (MMSE), MSE2 (LMMSE), MSE3 (5.18).
const TABLE_5_2: [((u32, u32), [f64; 5]); 5] = [
    ((12, 0), [3.0276, 0.3303, 0.3351, 0.3353, 0.3303]),
    ((8, 4), [3.0883, 0.3238, 0.3312, 0.3310, 0.3238]),
    ((7, 5), [3.0519, 0.3277, 0.3374, 0.3375, 0.3277]),
    ((6, 6), [2.7492, 0.3637, 0.3686, 0.3685, 0.3637]),
    ((0, 12), [0.3610, 2.7698, 2.7780, 2.7756, 2.7692]),
];

/// Draws for MSE1 and MSE2: the dissertation's 1000 leave a Monte Carlo
/// error of √(2/1000) ≈ 4.5 % on an MSE, more than the differences between
/// allocations. Shared draws cancel most of it from a comparison; what is
/// left, the draws where the allocations' quantizers part, takes these to
/// resolve the nearest allocations.
const DRAWS: usize = 40_000;
const SEED: u64 = 1;

/// A dissertation J counts as reproduced within this (its four decimals,
/// rounded or truncated).
const SAME: f64 = 2e-4;
/// A dissertation J this far below what the LMMSE already achieves is not
/// a matter of rounding.
const DEPARTS: f64 = 1e-3;

/// One row of a reproduced table.
struct Row {
    ours: Allocation,
    theirs: Option<f64>,
    /// Each draw's squared errors of the MMSE and LMMSE estimates, where
    /// the table has MSEs.
    errors: Option<Vec<(f64, f64)>>,
}

impl Row {
    /// MSE1 and MSE2.
    fn mses(&self) -> Option<(f64, f64)> {
        let e = self.errors.as_ref()?;
        let n = e.len() as f64;
        Some((
            e.iter().map(|x| x.0).sum::<f64>() / n,
            e.iter().map(|x| x.1).sum::<f64>() / n,
        ))
    }

    /// One estimator's squared errors (0: MMSE, 1: LMMSE), draw by draw.
    fn squared(&self, estimator: usize) -> Vec<Option<f64>> {
        self.errors.as_ref().map_or(Vec::new(), |e| {
            e.iter()
                .map(|x| Some(if estimator == 0 { x.0 } else { x.1 }))
                .collect()
        })
    }
}

fn run(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let problem = dissertation_problem();
    let r20 = rows(&problem, 20, |b| lookup(&TABLE_5_1, b).copied());
    let mut r12 = rows(&problem, 12, |b| lookup(&TABLE_5_2, b).map(|t| t[0]));
    let draws = options.sized(DRAWS, 500);
    for row in &mut r12 {
        eprintln!(
            "bit-allocation: ({}, {}), {draws} draws",
            row.ours.bits[0], row.ours.bits[1]
        );
        row.errors = Some(indexed(draws, options.threads, |k| {
            let mut rng = ChaCha8Rng::seed_from_u64((SEED << 32) | k as u64);
            estimator_squared_errors(&problem, &row.ours, &mut rng)
        }));
    }
    let curve = injected_noise_curve();
    write_atomically(
        &dir.join("bit-allocation-injected-noise.csv"),
        curve_csv(&curve).as_bytes(),
    )?;
    draw_curve(&dir.join("bit-allocation-injected-noise.svg"), &curve)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let tables = [(20, &r20[..]), (12, &r12[..])];
    ComputedReport::write(
        dir,
        "bit-allocation",
        &table_csv(&tables),
        |svg| draw(svg, &tables),
        check(&problem, &r20, &r12, &curve),
        format!("{}\n{}", print_5_1(&r20), print_5_2(&r12)),
    )
}

/// Fig. 5.3's sensor (Experiment 1): σn = 1, q = 0.3, σθ² = 4.
const CURVE_NOISE: f64 = 1.0;
const CURVE_STEP: f64 = 0.3;
const CURVE_PRIOR_VAR: f64 = 4.0;

/// `(σ_d, J)` over σ_d from 0.01 to 3 on a logarithmic grid:
/// `J = 1/σθ² + J̃(q, √(σn² + σ_d²))` (eqs. 5.9, 5.10).
fn injected_noise_curve() -> Vec<(f64, f64)> {
    const POINTS: usize = 61;
    (0..POINTS)
        .map(|k| {
            let sd = 0.01 * 300f64.powf(k as f64 / (POINTS - 1) as f64);
            let spread = (CURVE_NOISE * CURVE_NOISE + sd * sd).sqrt();
            (
                sd,
                1.0 / CURVE_PRIOR_VAR + smeared_gaussian_information(CURVE_STEP, spread),
            )
        })
        .collect()
}

fn curve_csv(curve: &[(f64, f64)]) -> String {
    let mut out = String::from("injected_std,fisher\n");
    for (sd, j) in curve {
        let _ = writeln!(out, "{sd},{j}");
    }
    out
}

/// Fig. 5.3: J against the injected noise, with the smallest noise whose
/// pass band stays clear of the first replica (Remark 1).
fn draw_curve(path: &Path, curve: &[(f64, f64)]) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let (lo, hi) = curve
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "bit-allocation: J against the injected noise σd (Fig. 5.3; σn = 1, q = 0.3, σθ² = 4)",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d((0.009..3.3).log_scale(), (lo - 0.02)..(hi + 0.02))?;
    chart
        .configure_mesh()
        .x_desc("injected noise σd")
        .y_desc("Fisher information J")
        .draw()?;
    let colour = Palette99::pick(0).to_rgba();
    chart
        .draw_series(LineSeries::new(
            curve.iter().copied(),
            colour.stroke_width(2),
        ))?
        .label("J = 1/σθ² + J̃(q, √(σn² + σd²))")
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
    let smallest = smallest_injected_std(CURVE_STEP, CURVE_NOISE);
    chart
        .draw_series(DashedLineSeries::new(
            [(smallest, lo - 0.02), (smallest, hi + 0.02)],
            6,
            4,
            BLACK.stroke_width(1),
        ))?
        .label(format!("smallest σd clear of the replica ({smallest:.3})"))
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

fn rows(problem: &Problem, budget: u32, theirs: impl Fn((u32, u32)) -> Option<f64>) -> Vec<Row> {
    problem
        .allocations(budget)
        .into_iter()
        .map(|ours| Row {
            theirs: theirs((ours.bits[0], ours.bits[1])),
            ours,
            errors: None,
        })
        .collect()
}

fn lookup<T>(table: &[((u32, u32), T)], bits: (u32, u32)) -> Option<&T> {
    table.iter().find(|(b, _)| *b == bits).map(|(_, t)| t)
}

/// `J ≥ 1/MSE3`: the LMMSE's MSE is at least the MMSE, which is at least
/// `1/J` (the Bayesian CRB). A table entry below that, beyond rounding,
/// cannot be the Fisher information of its allocation, whatever the
/// quadrature.
fn below_lmmse_information(row: &Row) -> bool {
    row.theirs
        .is_some_and(|j| j < 1.0 / row.ours.lmmse_mse - DEPARTS)
}

fn check(problem: &Problem, r20: &[Row], r12: &[Row], curve: &[(f64, f64)]) -> Check {
    let best = |r: u32| problem.optimal(r).map(|a| (a.bits[0], a.bits[1]));
    let (b20, b12) = (best(20), best(12));
    let listed_alike =
        |rows: &[Row], n: usize| rows.len() == n && rows.iter().all(|r| r.theirs.is_some());
    let table_5_2_alike = r12
        .iter()
        .all(|r| r.theirs.is_some_and(|j| (r.ours.fisher - j).abs() < SAME));
    let within = |tolerance: f64| {
        r20.iter()
            .filter(|r| {
                r.theirs
                    .is_some_and(|j| (r.ours.fisher - j).abs() < tolerance)
            })
            .count()
    };
    let impossible: Vec<String> = r20
        .iter()
        .filter(|r| below_lmmse_information(r))
        .map(|r| pair(&r.ours))
        .collect();
    let holds = b20 == Some((12, 8))
        && b12 == Some((8, 4))
        && listed_alike(r20, TABLE_5_1.len())
        && listed_alike(r12, TABLE_5_2.len())
        && table_5_2_alike;
    let show = |b: Option<(u32, u32)>| b.map_or("none".into(), |(x, y)| format!("({x}, {y})"));
    // Computed from the formulas, not estimated: each claim is exact.
    let claims = vec![
        Claim::exact(
            format!("the optimum for R = 20 is (12, 8) (ours {})", show(b20)),
            b20 == Some((12, 8)),
        ),
        Claim::exact(
            format!("the optimum for R = 12 is (8, 4) (ours {})", show(b12)),
            b12 == Some((8, 4)),
        ),
        Claim::exact(
            "the feasible allocations are the dissertation's",
            listed_alike(r20, TABLE_5_1.len()) && listed_alike(r12, TABLE_5_2.len()),
        ),
        Claim::exact("Table 5.2's J to its four decimals", table_5_2_alike),
        Claim::exact(
            format!(
                "Fig. 5.3: J falls monotonically as the injected noise grows (σd from {} to {}: J from {:.4} to {:.4})",
                curve[0].0,
                curve[curve.len() - 1].0,
                curve[0].1,
                curve[curve.len() - 1].1
            ),
            curve.windows(2).all(|w| w[1].1 < w[0].1),
        ),
    ];
    let mut claims = claims;
    claims.extend(estimator_claims(r12));
    let verdict =
        Verdict::all(std::iter::once(Verdict::of(holds)).chain(claims.iter().map(|c| c.verdict)));
    Check {
        verdict,
        claims,
        statement: format!(
            "optimum {} for R = 20 and {} for R = 12 (dissertation: (12, 8) and (8, 4)); the same feasible allocations; Table 5.2's J {} to its four decimals; Table 5.1's J in {} of {} rows to four decimals and {} within {DEPARTS}; {} rows ({}) lie below 1/MSE3 of their allocation by more than {DEPARTS}, which no Fisher information can",
            show(b20),
            show(b12),
            if table_5_2_alike { "reproduced" } else { "NOT reproduced" },
            within(SAME),
            r20.len(),
            within(DEPARTS),
            impossible.len(),
            impossible.join(", ")
        ),
    }
}

/// Table 5.2's claims about its estimators, judged draw by draw: the
/// optimum (8, 4) gives the least MSE; the LMMSE's MSE is close to the
/// MMSE's and to eq. 5.18's; and no estimator beats the PCRLB.
fn estimator_claims(r12: &[Row]) -> Vec<Claim> {
    let Some(best) = r12.iter().find(|r| r.ours.bits == [8, 4]) else {
        return vec![Claim::exact("Table 5.2 has the allocation (8, 4)", false)];
    };
    let names = ["MMSE (MSE1)", "LMMSE (MSE2)"];
    let mut claims = Vec::new();
    for (e, name) in names.iter().enumerate() {
        for other in r12.iter().filter(|r| r.ours.bits != [8, 4]) {
            claims.push(Claim::judged(
                format!(
                    "Table 5.2: (8, 4) gives a lower {name} than {}",
                    pair(&other.ours)
                ),
                Paired::of(&best.squared(e), &other.squared(e)),
                |p| p.verdict(Order::Lower),
                |p| format!("{} over {} draws", p.text(5), p.runs),
            ));
        }
    }
    let relative = |row: &Row, f: &dyn Fn(&(f64, f64)) -> f64, scale: f64| -> Vec<Option<f64>> {
        row.errors.as_ref().map_or(Vec::new(), |e| {
            e.iter().map(|x| Some(f(x) / scale - 1.0)).collect()
        })
    };
    claims.push(Claim::judged(
        "Table 5.2: the LMMSE's MSE is within 2 % of the MMSE's at (8, 4)",
        Paired::of(
            &relative(best, &|x| x.1, best.mses().map_or(f64::NAN, |m| m.0)),
            &relative(best, &|x| x.0, best.mses().map_or(f64::NAN, |m| m.0)),
        ),
        |p| p.verdict_within(-0.02, 0.02),
        |p| {
            format!(
                "{:+.2} ± {:.2} % over {} draws",
                100.0 * p.mean,
                100.0 * p.half_width,
                p.runs
            )
        },
    ));
    for row in r12 {
        claims.push(Claim::judged(
            format!(
                "Table 5.2: at {} the LMMSE's MSE is eq. 5.18's (within ±3 %)",
                pair(&row.ours)
            ),
            Paired::of_values(&relative(row, &|x| x.1, row.ours.lmmse_mse)),
            |p| p.verdict_within(-0.03, 0.03),
            |p| {
                format!(
                    "{:+.2} ± {:.2} % over {} draws",
                    100.0 * p.mean,
                    100.0 * p.half_width,
                    p.runs
                )
            },
        ));
        // A theorem (the Bayesian CRB), which runs can only refute: it
        // fails when the MSE lies below the PCRLB beyond its interval.
        claims.push(Claim::judged(
            format!(
                "Table 5.2: at {} the MMSE's MSE is not below the PCRLB beyond its interval",
                pair(&row.ours)
            ),
            Paired::of_values(&relative(row, &|x| x.0, row.ours.pcrlb())),
            |p| Verdict::of(p.mean + p.half_width >= 0.0),
            |p| {
                format!(
                    "{:+.2} ± {:.2} % over {} draws",
                    100.0 * p.mean,
                    100.0 * p.half_width,
                    p.runs
                )
            },
        ));
    }
    claims
}

fn pair(a: &Allocation) -> String {
    format!("({}, {})", a.bits[0], a.bits[1])
}

fn table_csv(tables: &[(u32, &[Row])]) -> String {
    let mut out = String::from(
        "budget,bits_1,bits_2,step_1,step_2,injected_std_1,injected_std_2,fisher,dissertation_fisher,pcrlb,lmmse_mse,mmse_mc,lmmse_mc\n",
    );
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    for (budget, rows) in tables {
        for r in rows.iter() {
            let d = |i: usize| r.ours.designs[i];
            let _ = writeln!(
                out,
                "{budget},{},{},{},{},{},{},{:.6},{},{:.6},{:.6},{},{}",
                r.ours.bits[0],
                r.ours.bits[1],
                opt(d(0).map(|d| d.step)),
                opt(d(1).map(|d| d.step)),
                opt(d(0).map(|d| d.injected_std)),
                opt(d(1).map(|d| d.injected_std)),
                r.ours.fisher,
                opt(r.theirs),
                r.ours.pcrlb(),
                r.ours.lmmse_mse,
                opt(r.mses().map(|m| m.0)),
                opt(r.mses().map(|m| m.1)),
            );
        }
    }
    out
}

fn print_5_1(rows: &[Row]) -> String {
    let mut out =
        String::from("Table 5.1, R = 20: J\n  bits        ours    dissertation   1/MSE3\n");
    for r in rows {
        let _ = writeln!(
            out,
            "  ({:>2}, {:>2})  {:.4}  {:>10}     {:.4}{}",
            r.ours.bits[0],
            r.ours.bits[1],
            r.ours.fisher,
            r.theirs.map_or("-".into(), |j| format!("{j:.4}")),
            1.0 / r.ours.lmmse_mse,
            if below_lmmse_information(r) {
                "   the dissertation's is below 1/MSE3: impossible"
            } else {
                ""
            }
        );
    }
    out
}

fn print_5_2(rows: &[Row]) -> String {
    let draws = rows
        .iter()
        .find_map(|r| r.errors.as_ref().map(|e| e.len()))
        .unwrap_or(0);
    let mut out = format!(
        "Table 5.2, R = 12 (ours / dissertation; MSE1, MSE2 from {draws} draws)\n  bits      J                PCRLB            MSE1             MSE2             MSE3\n"
    );
    for r in rows {
        let theirs = lookup(&TABLE_5_2, (r.ours.bits[0], r.ours.bits[1]));
        let pair = |ours: f64, i: usize| {
            format!(
                "{ours:.4} / {}",
                theirs.map_or("-".into(), |t| format!("{:.4}", t[i]))
            )
        };
        let (m1, m2) = r.mses().unwrap_or((f64::NAN, f64::NAN));
        let _ = writeln!(
            out,
            "  ({:>2}, {:>2})  {}  {}  {}  {}  {}",
            r.ours.bits[0],
            r.ours.bits[1],
            pair(r.ours.fisher, 0),
            pair(r.ours.pcrlb(), 1),
            pair(m1, 2),
            pair(m2, 3),
            pair(r.ours.lmmse_mse, 4),
        );
    }
    out
}

/// J against the first sensor's bits, ours as lines and the dissertation's
/// as points, one series per budget.
fn draw(path: &Path, tables: &[(u32, &[Row])]) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let feasible: Vec<(u32, &Row)> = tables
        .iter()
        .flat_map(|(b, rows)| rows.iter().map(move |r| (*b, r)))
        .filter(|(_, r)| r.ours.bits.iter().all(|&b| b > 0))
        .collect();
    let low = feasible
        .iter()
        .flat_map(|(_, r)| [Some(r.ours.fisher), r.theirs].into_iter().flatten())
        .fold(f64::INFINITY, f64::min);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "bit-allocation: dissertation ch. 5, Tables 5.1 and 5.2 (both sensors active)",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(5u32..17u32, (low - 0.02)..3.16)?;
    chart
        .configure_mesh()
        .x_desc("bits to sensor 1 (σn = 0.6); the rest to sensor 2 (σn = 3)")
        .y_desc("Fisher information J")
        .draw()?;
    for (i, (budget, _)) in tables.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let ours: Vec<(u32, f64)> = feasible
            .iter()
            .filter(|(b, _)| b == budget)
            .map(|(_, r)| (r.ours.bits[0], r.ours.fisher))
            .collect();
        let theirs: Vec<(u32, f64)> = feasible
            .iter()
            .filter(|(b, _)| b == budget)
            .filter_map(|(_, r)| r.theirs.map(|j| (r.ours.bits[0], j)))
            .collect();
        chart
            .draw_series(LineSeries::new(ours.clone(), colour.stroke_width(2)))?
            .label(format!("R = {budget}, ours"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart.draw_series(ours.iter().map(|p| Circle::new(*p, 3, colour.filled())))?;
        chart
            .draw_series(
                theirs
                    .iter()
                    .map(|p| Cross::new(*p, 6, colour.stroke_width(2))),
            )?
            .label(format!("R = {budget}, dissertation"))
            .legend(move |(x, y)| Cross::new((x + 10, y), 6, colour.stroke_width(2)));
    }
    // The allocation that sounds obvious: every bit to the better sensor.
    if let Some((_, alone)) = tables
        .iter()
        .flat_map(|(b, rows)| rows.iter().map(move |r| (*b, r)))
        .find(|(_, r)| r.ours.bits[1] == 0)
    {
        let j = alone.ours.fisher;
        chart
            .draw_series(DashedLineSeries::new(
                [(5u32, j), (17u32, j)],
                6,
                4,
                BLACK.stroke_width(1),
            ))?
            .label(format!("every bit to sensor 1 ({j:.4})"))
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()?;
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dissertations_tables_list_what_its_constraint_allows() {
        let problem = dissertation_problem();
        for (budget, table) in [
            (20, TABLE_5_1.iter().map(|(b, _)| *b).collect::<Vec<_>>()),
            (12, TABLE_5_2.iter().map(|(b, _)| *b).collect()),
        ] {
            let ours: Vec<(u32, u32)> = problem
                .allocations(budget)
                .iter()
                .map(|a| (a.bits[0], a.bits[1]))
                .collect();
            assert_eq!(ours, table, "R = {budget}");
        }
    }

    #[test]
    fn table_5_1s_largest_departures_are_below_what_the_lmmse_already_achieves() {
        let problem = dissertation_problem();
        let rows = rows(&problem, 20, |b| lookup(&TABLE_5_1, b).copied());
        let impossible: Vec<(u32, u32)> = rows
            .iter()
            .filter(|r| below_lmmse_information(r))
            .map(|r| (r.ours.bits[0], r.ours.bits[1]))
            .collect();
        // (20, 0): 3.0231, where one sensor alone at 20 bits is the
        // unquantized 1/4 + 1/0.36 = 3.0278 to four decimals.
        assert!(impossible.contains(&(20, 0)), "{impossible:?}");
        assert!(impossible.contains(&(9, 11)), "{impossible:?}");
        for r in &rows {
            // Ours never is: J ≥ 1/MSE3 is a theorem, so this checks the quadrature.
            assert!(
                r.ours.fisher >= 1.0 / r.ours.lmmse_mse - 1e-9,
                "{:?}",
                r.ours.bits
            );
        }
    }
}
