//! The random-exchange paper's bounds (its Fig. 1 without the trackers' curves): the
//! RndEx-PF PCRLB and the centralized PCRLB of `random-exchange.toml`'s 25-node RSS
//! network, and how the RndEx bound moves with its Monte Carlo sizes N_T
//! (trajectories) and N_f (paths).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use bounds::diffusion::{diffusion_bounds, DiffusionBounds, MonteCarloSize};
use bounds::fisher::Measurement;
use bounds::{ObservationModel, SensorTerm, State};
use fusion_graph::scenario::{Scenario, RANDOM_EXCHANGE_SCENARIO};
use fusion_graph::Topology;
use plotters::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::{Check, Claim, Computed, ComputedReport, Options, Verdict};

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "random-exchange-bounds",
        source: "the RndEx-PF PCRLB paper, Fig. 1 (bounds)",
        about: "the RndEx-PF PCRLB (Fisher matrices conditioned on random-exchange paths, eqs. 4-16) and the centralized PCRLB of random-exchange.toml's 25 RSS nodes over 100 s, at the paper's N_T = 10^4, N_f = 10^3 and at smaller sizes",
        run,
    }]
}

/// The paper's sizes first; the others show how the bound settles with
/// N_T (at N_f = 100, which moves it by under 1 %).
const SIZES: [MonteCarloSize; 5] = [
    MonteCarloSize {
        trajectories: 10_000,
        paths: 1000,
    },
    MonteCarloSize {
        trajectories: 10_000,
        paths: 100,
    },
    MonteCarloSize {
        trajectories: 1000,
        paths: 100,
    },
    MonteCarloSize {
        trajectories: 100,
        paths: 100,
    },
    MonteCarloSize {
        trajectories: 100_000,
        paths: 100,
    },
];
const SEED: u64 = 4;

/// A size run small: a few trajectories and paths, enough to exercise the
/// computation.
pub(super) fn small(size: MonteCarloSize) -> MonteCarloSize {
    MonteCarloSize {
        trajectories: size.trajectories.min(100),
        paths: size.paths.min(10),
    }
}
/// Steps printed in the table.
const SHOWN: [usize; 6] = [1, 5, 10, 25, 50, 100];

fn run(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let steps: Vec<String> = options
        .steps
        .filter(|_| options.small)
        .map(|s| vec![format!("steps={s}")])
        .unwrap_or_default();
    let scenario = Scenario::from_toml(RANDOM_EXCHANGE_SCENARIO, "random-exchange.toml", &steps)?;
    let curves: Vec<Curves> = SIZES
        .iter()
        .map(|&size| Curves::compute(&scenario, options.sized(size, small(size))))
        .collect::<anyhow::Result<_>>()?;
    ComputedReport::write(
        dir,
        "random-exchange-bounds",
        &to_csv(&curves),
        |svg| draw(svg, &curves),
        check(&curves),
        print(&curves),
    )
}

/// Both bounds, metres, from step 0 to the last.
pub(super) struct Curves {
    pub rndex: Vec<f64>,
    /// The paths' bounds averaged, `sqrt(mean_r E_paths tr_pos J⁻¹)`.
    pub rndex_paths: Vec<f64>,
    pub centralized: Vec<f64>,
}

impl Curves {
    /// The RndEx-PF and centralized PCRLB of a random-exchange scenario (one RSS
    /// sensor per node, raw measurements) over its steps, at `size`.
    pub(super) fn compute(scenario: &Scenario, size: MonteCarloSize) -> anyhow::Result<Self> {
        let topology = Topology::from_scenario(scenario, &scenario.name)?;
        let models = scenario.models()?;
        let sensors: Vec<ObservationModel> = topology
            .node_sensors
            .iter()
            .map(|own| {
                let s = own
                    .first()
                    .context("a random-exchange scenario gives every node its sensor")?;
                Ok(models.law.at(topology.sensor_positions[*s as usize]))
            })
            .collect::<anyhow::Result<_>>()?;
        let terms: Vec<SensorTerm> = sensors
            .iter()
            .map(|model| SensorTerm {
                model,
                measurement: Measurement::Raw,
            })
            .collect();
        let neighbours: Vec<Vec<usize>> = topology
            .neighbours
            .iter()
            .map(|ns| ns.iter().map(|&n| n as usize).collect())
            .collect();
        let steps = scenario.steps as usize;
        let mut rng = ChaCha8Rng::seed_from_u64(SEED);
        let bounds = diffusion_bounds(
            &models.dynamics,
            &terms,
            &neighbours,
            &State::from(scenario.target.initial_state()),
            &models.prior_cov,
            steps,
            size,
            &mut rng,
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(Self::of(&bounds, steps))
    }

    fn of(b: &DiffusionBounds, steps: usize) -> Self {
        let nan = f64::NAN;
        Self {
            rndex: (0..=steps)
                .map(|n| b.rndex_position_bound(n).unwrap_or(nan))
                .collect(),
            rndex_paths: (0..=steps)
                .map(|n| b.rndex_path_averaged_bound(n).unwrap_or(nan))
                .collect(),
            centralized: (0..=steps)
                .map(|n| b.centralized_position_bound(n).unwrap_or(nan))
                .collect(),
        }
    }
}

fn label(size: &MonteCarloSize) -> String {
    format!("N_T={} N_f={}", size.trajectories, size.paths)
}

fn to_csv(curves: &[Curves]) -> String {
    let mut out = String::from("# random-exchange.toml; bounds in metres, sqrt of the mean over nodes of tr_pos(J*^-1); rndex_paths_averaged: sqrt of the mean over nodes of E_paths tr_pos(J^-1) at the paper's sizes\nstep,centralized,rndex_paths_averaged");
    for size in &SIZES {
        let _ = write!(out, ",rndex_T{}_f{}", size.trajectories, size.paths);
    }
    out.push('\n');
    for n in 0..curves[0].rndex.len() {
        let _ = write!(
            out,
            "{n},{:.6},{:.6}",
            curves[0].centralized[n], curves[0].rndex_paths[n]
        );
        for c in curves {
            let _ = write!(out, ",{:.6}", c.rndex[n]);
        }
        out.push('\n');
    }
    out
}

fn print(curves: &[Curves]) -> String {
    let mut out = String::from("the RndEx-PF and centralized bounds on random-exchange.toml, metres (the paper's Fig. 1 gives curves, no figures to compare); 'paths avg' averages each path's bound rather than its information (the Jensen gap of eq. 15)\n  step  centralized  paths avg");
    for size in &SIZES {
        let _ = write!(out, "  {:>20}", format!("RndEx {}", label(size)));
    }
    out.push('\n');
    for &n in SHOWN.iter().filter(|&&n| n < curves[0].centralized.len()) {
        let _ = write!(
            out,
            "  {n:>4}  {:>11.3}  {:>9.3}",
            curves[0].centralized[n], curves[0].rndex_paths[n]
        );
        for c in curves {
            let _ = write!(out, "  {:>20.3}", c.rndex[n]);
        }
        out.push('\n');
    }
    out
}

/// Largest relative gap between two curves over steps 1 onward.
fn largest_gap(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .skip(1)
        .map(|(x, y)| (x / y - 1.0).abs())
        .fold(0.0, f64::max)
}

fn check(curves: &[Curves]) -> Check {
    let paper = &curves[0];
    let below = paper
        .centralized
        .iter()
        .zip(&paper.rndex)
        .skip(1)
        .all(|(c, r)| c < r);
    let ratio_end = paper.rndex.last().copied().unwrap_or(f64::NAN)
        / paper.centralized.last().copied().unwrap_or(f64::NAN);
    let gaps: Vec<String> = curves[1..]
        .iter()
        .zip(&SIZES[1..])
        .map(|(c, size)| {
            format!(
                "{} within {:.2} %",
                label(size),
                100.0 * largest_gap(&c.rndex, &paper.rndex)
            )
        })
        .collect();
    Check {
        verdict: Verdict::of(below),
        claims: vec![Claim::exact(
            "the centralized PCRLB is below the RndEx-PF PCRLB at every step (both computed, at the paper's sizes)",
            below,
        )],
        statement: format!(
            "the centralized PCRLB is below the RndEx-PF PCRLB at every step{} (at 100 s: {:.3} m against {:.3} m, ×{ratio_end:.2}); against the paper's N_T = 10^4, N_f = 10^3 the smaller sizes give the RndEx curve {}",
            if below { "" } else { " NOT" },
            paper.centralized.last().copied().unwrap_or(f64::NAN),
            paper.rndex.last().copied().unwrap_or(f64::NAN),
            gaps.join(", ")
        ),
    }
}

fn draw(path: &Path, curves: &[Curves]) -> Result<(), Box<dyn std::error::Error>> {
    let mut lines: Vec<(String, &[f64])> =
        vec![("centralized PCRLB".into(), &curves[0].centralized[..])];
    for (c, size) in curves.iter().zip(&SIZES) {
        lines.push((format!("RndEx-PF PCRLB, {}", label(size)), &c.rndex[..]));
    }
    draw_lines(
        path,
        "random-exchange-bounds: RndEx-PF and centralized PCRLB, 25 RSS nodes",
        "position bound, m",
        &lines,
        &[],
    )
}

/// Curves over steps 1.. (step 0, the prior's 7 m, would flatten the
/// rest), one colour each, with a legend; `bands[i]`, where given, is line
/// i's 95 % band at steps 1, 2, …, drawn shaded in its colour.
pub(super) fn draw_lines(
    path: &Path,
    caption: &str,
    y_desc: &str,
    lines: &[(String, &[f64])],
    bands: &[&[Option<(f64, f64)>]],
) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let steps = lines.iter().map(|(_, v)| v.len()).max().unwrap_or(1).max(2) - 1;
    let top = lines
        .iter()
        .flat_map(|(_, v)| v.iter().skip(1))
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(1..steps, 0.0..top * 1.05)?;
    chart
        .configure_mesh()
        .x_desc("time, s")
        .y_desc(y_desc)
        .draw()?;
    for (i, band) in bands.iter().enumerate() {
        let steps: Vec<(usize, f64, f64)> = band
            .iter()
            .enumerate()
            .filter_map(|(k, b)| b.map(|(lo, hi)| (k + 1, lo, hi.min(top * 1.05))))
            .collect();
        if steps.len() < 2 {
            continue;
        }
        let outline: Vec<(usize, f64)> = steps
            .iter()
            .map(|(s, _, h)| (*s, *h))
            .chain(steps.iter().rev().map(|(s, l, _)| (*s, *l)))
            .collect();
        let colour = Palette99::pick(i).to_rgba();
        chart.draw_series(std::iter::once(Polygon::new(
            outline,
            colour.mix(0.15).filled(),
        )))?;
    }
    for (i, (name, values)) in lines.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(
                (1..values.len()).map(|n| (n, values[n])),
                colour.stroke_width(2),
            ))?
            .label(name.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}
