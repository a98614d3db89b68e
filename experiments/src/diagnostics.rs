//! What the nodes reported beside their estimates, read back from each
//! run's `ticks.csv`: the spread of the prediction the sensor manager
//! scored on, how far the sensors it activated stood from the truth, and a
//! fusion centre's transmission probabilities.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use fusion_graph::Topology;
use launch::results::Tick;

/// Per step (from 1), means over runs and nodes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Diagnostics {
    /// `sqrt(tr_pos P(k|k−1))` of the nodes' fusion filters, metres.
    pub spread: Vec<Option<f64>>,
    /// Distance from the truth of the sensors activated, metres.
    pub active_distance: Vec<Option<f64>>,
    /// Every step a fusion centre designed its channel's transmissions.
    pub designs: Vec<DesignRecord>,
}

/// A fusion centre's transmission probabilities at one step of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct DesignRecord {
    pub run: u32,
    pub step: u32,
    /// The target's true position, metres.
    pub truth: [f64; 2],
    /// Each of the centre's sensors' probability.
    pub probabilities: Vec<f64>,
}

/// The processing nodes' rows of run `run`'s `ticks.csv` under `runs_dir`
/// (the Monte Carlo's `run-000`, `run-001`, …).
pub fn run_ticks(runs_dir: &Path, run: u32) -> anyhow::Result<Vec<Tick>> {
    let path = runs_dir.join(format!("run-{run:03}")).join("ticks.csv");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    Ok(text
        .lines()
        .skip(1)
        .filter_map(Tick::parse)
        .filter(Tick::is_node)
        .collect())
}

impl Diagnostics {
    /// From the `ticks.csv` of runs `0..runs` under `runs_dir`.
    pub fn read(runs_dir: &Path, runs: u32, topology: &Topology) -> anyhow::Result<Self> {
        let mut spread: Vec<(f64, u32)> = Vec::new();
        let mut distance: Vec<(f64, u32)> = Vec::new();
        let mut designs = Vec::new();
        let add = |v: &mut Vec<(f64, u32)>, step: usize, x: f64| {
            if v.len() < step {
                v.resize(step, (0.0, 0));
            }
            v[step - 1].0 += x;
            v[step - 1].1 += 1;
        };
        for run in 0..runs {
            for tick in run_ticks(runs_dir, run)? {
                let step = tick.step as usize;
                if step == 0 {
                    continue;
                }
                if let Some(s) = tick.spread.filter(|s| s.is_finite()) {
                    add(&mut spread, step, s);
                }
                if !tick.design.is_empty() {
                    designs.push(DesignRecord {
                        run,
                        step: tick.step,
                        truth: tick.truth,
                        probabilities: tick.design.clone(),
                    });
                }
                let [x, y] = tick.truth;
                for sensor in &tick.active {
                    if let Some([sx, sy]) = topology.sensor_positions.get(*sensor as usize) {
                        add(&mut distance, step, (sx - x).hypot(sy - y));
                    }
                }
            }
        }
        let mean = |v: Vec<(f64, u32)>| {
            v.into_iter()
                .map(|(s, n)| (n > 0).then(|| s / f64::from(n)))
                .collect()
        };
        Ok(Self {
            spread: mean(spread),
            active_distance: mean(distance),
            designs,
        })
    }

    /// The mean of a per-step series over steps `from..=to`.
    pub fn window(series: &[Option<f64>], from: usize, to: usize) -> Option<f64> {
        let values: Vec<f64> = series
            .iter()
            .enumerate()
            .filter(|(i, _)| (from..=to).contains(&(i + 1)))
            .filter_map(|(_, v)| *v)
            .collect();
        (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
    }
}

/// `step,<arm>_spread,<arm>_active_distance,…`.
pub fn csv(labels: &[&str], diagnostics: &[&Diagnostics]) -> String {
    let mut out = String::from(
        "# per step, means over runs and nodes: spread = sqrt(tr_pos P(k|k-1)) of the fusion filter, m; active_distance = distance of the activated sensors from the truth, m\nstep",
    );
    for label in labels {
        let slug: String = label
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let _ = write!(out, ",{slug}_spread,{slug}_active_distance");
    }
    out.push('\n');
    let steps = diagnostics
        .iter()
        .map(|d| d.spread.len().max(d.active_distance.len()))
        .max()
        .unwrap_or(0);
    let cell = |v: Option<&Option<f64>>| {
        v.copied()
            .flatten()
            .map_or(String::new(), |x| format!("{x:.3}"))
    };
    for k in 0..steps {
        let _ = write!(out, "{}", k + 1);
        for d in diagnostics {
            let _ = write!(
                out,
                ",{},{}",
                cell(d.spread.get(k)),
                cell(d.active_distance.get(k))
            );
        }
        out.push('\n');
    }
    out
}
