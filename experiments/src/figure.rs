//! An experiment's outcome as CSV and as an SVG figure (plotters).

use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;

use super::{ArmOutcome, Experiment, Figure, Outcome, Series};

const SIZE: (u32, u32) = (900, 560);

/// Over time: `step` and one column per curve. Bars: `bar,value`.
pub fn csv(experiment: &Experiment, outcome: &Outcome) -> String {
    let mut out = String::new();
    match &experiment.figure {
        Figure::OverTime { curves, .. } | Figure::OverTimeAndDesign { curves, .. } => {
            out.push_str("step");
            for c in *curves {
                out.push_str(&format!(",{}", quoted(c.label)));
            }
            out.push('\n');
            let columns: Vec<Vec<Option<f64>>> = curves
                .iter()
                .map(|c| outcome.arms[c.arm].series(c.series))
                .collect();
            for step in 0..outcome.steps as usize {
                out.push_str(&(step + 1).to_string());
                for column in &columns {
                    out.push(',');
                    if let Some(v) = column.get(step).copied().flatten() {
                        out.push_str(&v.to_string());
                    }
                }
                out.push('\n');
            }
        }
        Figure::Panels { .. } => {
            out.push_str("step");
            for a in &outcome.arms {
                out.push_str(&format!(
                    ",{},{}",
                    quoted(&format!("{} rmse", a.label)),
                    quoted(&format!("{} bound", a.label))
                ));
            }
            out.push('\n');
            let columns: Vec<[Vec<Option<f64>>; 2]> = outcome
                .arms
                .iter()
                .map(|a| [a.series(Series::Rmse), a.series(Series::Bound)])
                .collect();
            for step in 0..outcome.steps as usize {
                out.push_str(&(step + 1).to_string());
                for column in columns.iter().flatten() {
                    out.push(',');
                    if let Some(v) = column.get(step).copied().flatten() {
                        out.push_str(&v.to_string());
                    }
                }
                out.push('\n');
            }
        }
        Figure::Bars { bars, .. } => {
            out.push_str("bar,value\n");
            for b in *bars {
                let v = outcome.arms[b.arm].metric(b.metric);
                out.push_str(&format!(
                    "{},{}\n",
                    quoted(b.label),
                    v.map_or(String::new(), |v| v.to_string())
                ));
            }
        }
    }
    out
}

/// Each arm's bytes per step, whole network: the sensor selection's
/// messages, the activations and the bound information in consensus.
pub fn bytes_csv(outcome: &Outcome) -> String {
    let mut out = String::from(
        "arm,selection_bytes_per_step,activation_bytes_per_step,observation_bytes_per_step,observations_per_step,bound_bytes_per_step\n",
    );
    for a in &outcome.arms {
        out.push_str(&format!(
            "{},{},{},{},{},{}\n",
            quoted(&a.label),
            a.selection_bytes_per_step,
            a.activation_bytes_per_step,
            a.observation_bytes_per_step,
            a.observations_per_step,
            a.bound_bytes_per_step
        ));
    }
    out
}

fn quoted(label: &str) -> String {
    if label.contains([',', '"']) {
        format!("\"{}\"", label.replace('"', "\"\""))
    } else {
        label.to_string()
    }
}

pub fn svg(experiment: &Experiment, outcome: &Outcome, path: &Path) -> anyhow::Result<()> {
    let title = format!(
        "{}: {} ({} runs)",
        experiment.name, experiment.source, outcome.runs
    );
    let size = match &experiment.figure {
        Figure::Panels { .. } => (PANEL.0 * PANEL_COLUMNS, PANEL.1 * panel_rows(outcome)),
        _ => SIZE,
    };
    let root = SVGBackend::new(path, size).into_drawing_area();
    let drawn = match &experiment.figure {
        Figure::OverTime { y_label, curves }
        | Figure::OverTimeAndDesign {
            y_label, curves, ..
        } => {
            let lines: Vec<Line> = curves
                .iter()
                .map(|c| {
                    let arm = &outcome.arms[c.arm];
                    let points = arm
                        .series(c.series)
                        .into_iter()
                        .enumerate()
                        .filter_map(|(i, v)| v.filter(|v| *v > 0.0).map(|v| (i as u32 + 1, v)))
                        .collect();
                    // The RMSE is a Monte Carlo estimate: its band is the
                    // 95 % interval over runs. The bounds have none drawn.
                    let band = match c.series {
                        Series::Rmse => arm
                            .rmse_band()
                            .into_iter()
                            .enumerate()
                            .filter_map(|(i, b)| b.map(|(lo, hi)| (i as u32 + 1, lo, hi)))
                            .collect(),
                        _ => Vec::new(),
                    };
                    Line {
                        label: c.label,
                        points,
                        band,
                    }
                })
                .collect();
            over_time(&root, &title, y_label, outcome.steps, &lines)
        }
        Figure::Bars { y_label, bars } => {
            let values: Vec<(&str, f64)> = bars
                .iter()
                .map(|b| (b.label, outcome.arms[b.arm].metric(b.metric).unwrap_or(0.0)))
                .collect();
            bar_chart(&root, &title, y_label, &values)
        }
        Figure::Panels {
            y_label,
            reference,
            window,
        } => panels(&root, &title, y_label, outcome, *reference, *window),
    };
    drawn.map_err(|e| anyhow::anyhow!("{e}"))?;
    root.present()
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("writing {}", path.display()))
}

type DrawResult = Result<(), Box<dyn std::error::Error>>;

/// `<stem>.csv` (every run's probabilities at `steps`, a row per
/// run and step) and
/// `<stem>.svg` (the first run's, one panel a step): each sensor a
/// circle whose area is its transmission probability, the truth a cross.
pub fn design(
    dir: &Path,
    stem: &str,
    arm: &ArmOutcome,
    steps: &[u32],
    sensors: &[[f64; 2]],
) -> anyhow::Result<()> {
    let records: Vec<_> = arm
        .diagnostics
        .designs
        .iter()
        .filter(|d| steps.contains(&d.step))
        .collect();
    // A row per run and step, a column per sensor (named by where it
    // stands): most probabilities are 0, and a row per sensor was 25
    // times the lines.
    let mut csv = String::from("run,step,truth_x,truth_y");
    for [x, y] in sensors {
        csv.push_str(&format!(",p at ({x} {y})"));
    }
    csv.push('\n');
    for d in &records {
        csv.push_str(&format!(
            "{},{},{},{}",
            d.run, d.step, d.truth[0], d.truth[1]
        ));
        for p in &d.probabilities {
            csv.push_str(&format!(",{p}"));
        }
        csv.push('\n');
    }
    crate::write_atomically(&dir.join(format!("{stem}.csv")), csv.as_bytes())?;
    let path = dir.join(format!("{stem}.svg"));
    let first: Vec<_> = records.iter().filter(|d| d.run == 0).collect();
    let root = SVGBackend::new(&path, (440 * steps.len().max(1) as u32, 480)).into_drawing_area();
    let drawn = (|| -> DrawResult {
        root.fill(&WHITE)?;
        let (xs, ys): (Vec<f64>, Vec<f64>) = sensors.iter().map(|p| (p[0], p[1])).unzip();
        let span = |v: &[f64]| {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (lo - 4.0)..(hi + 4.0)
        };
        let (x_range, y_range) = (span(&xs), span(&ys));
        for (area, step) in root.split_evenly((1, steps.len().max(1))).iter().zip(steps) {
            let mut chart = ChartBuilder::on(area)
                .caption(
                    format!("{stem}: probabilities at step {step}, run 0"),
                    ("sans-serif", 16),
                )
                .margin(12)
                .x_label_area_size(30)
                .y_label_area_size(36)
                .build_cartesian_2d(x_range.clone(), y_range.clone())?;
            chart
                .configure_mesh()
                .x_desc("x, m")
                .y_desc("y, m")
                .draw()?;
            let Some(d) = first.iter().find(|d| d.step == *step) else {
                continue;
            };
            chart.draw_series(sensors.iter().zip(&d.probabilities).map(|(s, p)| {
                Circle::new((s[0], s[1]), 2.0 + 22.0 * p.sqrt(), BLUE.mix(0.6).filled())
            }))?;
            chart.draw_series(
                sensors
                    .iter()
                    .zip(&d.probabilities)
                    .filter(|(_, p)| **p >= 0.01)
                    .map(|(s, p)| {
                        Text::new(
                            format!("{p:.3}"),
                            (s[0] + 0.8, s[1] + 0.8),
                            ("sans-serif", 13),
                        )
                    }),
            )?;
            chart.draw_series(std::iter::once(Cross::new(
                (d.truth[0], d.truth[1]),
                7,
                RED.stroke_width(2),
            )))?;
        }
        Ok(())
    })();
    drawn.map_err(|e| anyhow::anyhow!("{e}"))?;
    root.present()
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("writing {}", path.display()))
}

const PANEL: (u32, u32) = (300, 230);
const PANEL_COLUMNS: u32 = 4;

fn panel_rows(outcome: &Outcome) -> u32 {
    (outcome.arms.len().saturating_sub(1) as u32).div_ceil(PANEL_COLUMNS) + 1
}

fn positive_points(values: Vec<Option<f64>>) -> Vec<(u32, f64)> {
    values
        .into_iter()
        .enumerate()
        .filter_map(|(i, v)| v.filter(|v| *v > 0.0).map(|v| (i as u32 + 1, v)))
        .collect()
}

/// A panel per arm: its RMSE (red) and bound (blue) over the reference's
/// RMSE (grey), the fault window shaded; the same log axis in every panel.
fn panels(
    root: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    title: &str,
    y_label: &str,
    outcome: &Outcome,
    reference: usize,
    window: (u32, u32),
) -> DrawResult {
    root.fill(&WHITE)?;
    let (top, body) = root.split_vertically(PANEL.1 / 2);
    top.draw(&Text::new(
        format!("{title}: {y_label}; red RMSE, blue CQ/dPCRLB, grey the no-fault RMSE, shaded the fault"),
        (10, 10),
        ("sans-serif", 18),
    ))?;
    let all = |a: &ArmOutcome| {
        positive_points(a.series(Series::Rmse))
            .into_iter()
            .chain(positive_points(a.series(Series::Bound)))
            .map(|(_, v)| v)
            .collect::<Vec<_>>()
    };
    let values: Vec<f64> = outcome.arms.iter().flat_map(all).collect();
    let lo = values
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        .max(1e-3)
        * 0.9;
    let hi = values.iter().copied().fold(1.0, f64::max) * 1.1;
    let steps = outcome.steps.max(2);
    let rows = panel_rows(outcome) as usize - 1;
    let areas = body.split_evenly((rows.max(1), PANEL_COLUMNS as usize));
    let reference_rmse = positive_points(outcome.arms[reference].series(Series::Rmse));
    let arms = outcome
        .arms
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != reference);
    for (area, (_, arm)) in areas.iter().zip(arms) {
        let mut chart = ChartBuilder::on(area)
            .caption(&arm.label, ("sans-serif", 14))
            .margin(6)
            .x_label_area_size(22)
            .y_label_area_size(36)
            .build_cartesian_2d(1..steps, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .y_labels(5)
            .x_labels(4)
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        chart.draw_series(std::iter::once(Rectangle::new(
            [(window.0, lo), (window.1, hi)],
            RGBColor(255, 200, 0).mix(0.25).filled(),
        )))?;
        chart.draw_series(LineSeries::new(
            reference_rmse.iter().copied(),
            RGBColor(150, 150, 150).stroke_width(2),
        ))?;
        chart.draw_series(LineSeries::new(
            positive_points(arm.series(Series::Bound)),
            BLUE.stroke_width(1),
        ))?;
        chart.draw_series(LineSeries::new(
            positive_points(arm.series(Series::Rmse)),
            RED.stroke_width(2),
        ))?;
    }
    Ok(())
}

/// A curve over time, with the 95 % band around it when it has one.
struct Line<'a> {
    label: &'a str,
    points: Vec<(u32, f64)>,
    /// (step, low, high); empty: no band.
    band: Vec<(u32, f64, f64)>,
}

fn over_time(
    root: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    title: &str,
    y_label: &str,
    steps: u32,
    lines: &[Line<'_>],
) -> DrawResult {
    root.fill(&WHITE)?;
    let values = lines.iter().flat_map(|l| l.points.iter().map(|(_, v)| *v));
    let (lo, hi) = values.fold((f64::INFINITY, 0.0_f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    // plotters labels a log axis at powers of ten and their multiples: a
    // range between two powers (1.2 to 5.3 m) got no label at all, so such
    // a range starts at the power of ten below it.
    let (lo, hi) = if lo.is_finite() {
        let (lo, hi) = (lo * 0.9, hi * 1.1);
        let below = 10f64.powf(lo.log10().floor());
        if below * 10.0 > hi {
            (below, hi)
        } else {
            (lo, hi)
        }
    } else {
        (0.1, 10.0)
    };
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(1..steps.max(2), (lo..hi).log_scale())?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc(y_label)
        .y_labels(16)
        .y_label_formatter(&|v| format!("{v:.2}"))
        .draw()?;
    for (i, line) in lines.iter().enumerate() {
        if line.band.len() < 2 {
            continue;
        }
        let colour = Palette99::pick(i).to_rgba();
        // The band's outline: the high ends forward, the low ends back,
        // kept inside the chart's range (a low end of 0 has no place on a
        // log scale).
        let clamp = |v: f64| v.clamp(lo, hi);
        let outline: Vec<(u32, f64)> = line
            .band
            .iter()
            .map(|(s, _, h)| (*s, clamp(*h)))
            .chain(line.band.iter().rev().map(|(s, l, _)| (*s, clamp(*l))))
            .collect();
        chart.draw_series(std::iter::once(Polygon::new(
            outline,
            colour.mix(0.15).filled(),
        )))?;
    }
    for (i, line) in lines.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(
                line.points.iter().copied(),
                colour.stroke_width(2),
            ))?
            .label(line.label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    Ok(())
}

fn bar_chart(
    root: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    title: &str,
    y_label: &str,
    values: &[(&str, f64)],
) -> DrawResult {
    root.fill(&WHITE)?;
    let top = values.iter().map(|(_, v)| *v).fold(1.0_f64, f64::max) * 1.15;
    let n = values.len() as u32;
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        // A segmented range 0..m has m + 1 segments.
        .build_cartesian_2d((0..n.saturating_sub(1)).into_segmented(), 0.0..top)?;
    let labels: Vec<String> = values.iter().map(|(l, _)| l.to_string()).collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(values.len())
        .x_label_formatter(&|x| match x {
            SegmentValue::CenterOf(i) => labels.get(*i as usize).cloned().unwrap_or_default(),
            _ => String::new(),
        })
        .y_label_formatter(&|v| format!("{v:.0}"))
        .y_desc(y_label)
        .draw()?;
    for (i, (_, v)) in values.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let i = i as u32;
        chart.draw_series(std::iter::once(Rectangle::new(
            [
                (SegmentValue::Exact(i), 0.0),
                (SegmentValue::Exact(i + 1), *v),
            ],
            colour.filled(),
        )))?;
        chart.draw_series(std::iter::once(Text::new(
            format!("{v:.0} B"),
            (SegmentValue::CenterOf(i), *v * 1.03),
            ("sans-serif", 16),
        )))?;
    }
    Ok(())
}
