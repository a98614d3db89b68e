//! The estimator of a static target's locator (`ml_location`): a node's
//! evidence about where the target is, as a log-likelihood over grids every
//! node lays out alike, and its sensors' Fisher information at a point.
//!
//! Each sensor's reports are kept as counts per cell (per value when raw),
//! which is all the likelihood of a static target needs: the node can
//! evaluate its log-likelihood anywhere, on the region's coarse grid and on
//! a fine grid around the coarse estimate alike. Summed over the network by
//! consensus, the log-likelihoods give the ML estimate of every node's
//! sensors together, and the information `J = Σ_i n_i I(g_i) ∇g_i ∇g_iᵀ`
//! (the position block, `n_i` the reports of sensor i) gives its CRLB,
//! `tr J⁻¹` (dissertation ch. 6, eqs. 6.13–6.14, with a sensor's reports
//! over several steps adding up).

use std::sync::Mutex;

use bounds::cell_sums::FisherScalars;
use bounds::location::{closed_form_information, optimize_thresholds, AmplitudeLaw, DecayLaw};
use bounds::{Measurement, ObservationModel, Quantizer, State};
use fusion_graph::scenario::Scenario;
use fusion_graph::Topology;

use crate::estimator::{Observation, ObservedValue};

/// The thresholds a locator sends its sensors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ThresholdDesign {
    /// Those maximizing the closed-form information of a dense network
    /// (eq. 6.46): they need no sensor's position. Amplitude sensors only.
    Designed,
    /// The scenario's uniform quantizer (`quantizer.lo`, `quantizer.hi`).
    Uniform,
}

/// `consensus.params` of `ml_location`, as the parts read them
/// ([`crate::parts::location_config`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LocationConfig {
    /// Points of each grid along x and y.
    pub grid: [usize; 2],
    /// Finer grids searched after the region's, each around the estimate
    /// of the one before, one spacing of it either side.
    pub refinements: usize,
    pub thresholds: ThresholdDesign,
}

/// A grid of `n[0] × n[1]` points from `origin`, `spacing` apart; point
/// `k` is column `k / n[1]`, row `k % n[1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub origin: [f64; 2],
    pub spacing: [f64; 2],
    pub n: [usize; 2],
}

impl Grid {
    /// The region's grid, its corners included: the coarse search.
    pub fn over_region(scenario: &Scenario, n: [usize; 2]) -> Self {
        let size = [scenario.region.width, scenario.region.height];
        Self {
            origin: [0.0, 0.0],
            spacing: [0, 1].map(|a| size[a] / (n[a] - 1) as f64),
            n,
        }
    }

    /// A grid of as many points over one spacing either side of `centre`:
    /// the fine search, which holds the likelihood's peak when `centre` is
    /// the coarse grid's refined best point.
    pub fn around(&self, centre: [f64; 2]) -> Self {
        let spacing = [0, 1].map(|a| 2.0 * self.spacing[a] / (self.n[a] - 1) as f64);
        Self {
            origin: [0, 1].map(|a| centre[a] - self.spacing[a]),
            spacing,
            n: self.n,
        }
    }

    /// Its points: never none, as a grid has at least 5 a side.
    pub fn len(&self) -> usize {
        self.n[0] * self.n[1]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn point(&self, k: usize) -> [f64; 2] {
        let (i, j) = (k / self.n[1], k % self.n[1]);
        [
            self.origin[0] + i as f64 * self.spacing[0],
            self.origin[1] + j as f64 * self.spacing[1],
        ]
    }

    /// The point of highest log-likelihood, moved to the vertex of the
    /// parabola through it and its two neighbours along each axis (at most
    /// half a spacing), which a likelihood near its peak resembles.
    pub fn best(&self, log_likelihood: &[f64]) -> [f64; 2] {
        let k = log_likelihood
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            .map_or(0, |(k, _)| k);
        let (i, j) = (k / self.n[1], k % self.n[1]);
        let mut p = self.point(k);
        let at = |i: usize, j: usize| log_likelihood[i * self.n[1] + j];
        if i > 0 && i + 1 < self.n[0] {
            p[0] += self.spacing[0] * vertex(at(i - 1, j), at(i, j), at(i + 1, j));
        }
        if j > 0 && j + 1 < self.n[1] {
            p[1] += self.spacing[1] * vertex(at(i, j - 1), at(i, j), at(i, j + 1));
        }
        p
    }
}

/// Where the parabola through `(−1, a)`, `(0, b)`, `(1, c)` peaks, for `b`
/// the largest, within half a step.
fn vertex(a: f64, b: f64, c: f64) -> f64 {
    let curvature = a - 2.0 * b + c;
    if curvature < 0.0 {
        (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// The quantizer a locator sends its sensors, `None` when they report raw
/// values.
pub fn sensor_quantizer(scenario: &Scenario, design: ThresholdDesign) -> Option<Quantizer> {
    if scenario.quantizer.raw {
        return None;
    }
    let uniform = scenario
        .models()
        .expect("a loaded scenario's models build")
        .quantizer;
    match (design, AmplitudeLaw::of(scenario.observation.law())) {
        (ThresholdDesign::Designed, Some(amplitude)) => {
            // g = √(P₀/(1 + α dⁿ)) is the unit power law at distance
            // α^{1/n} d, and the closed form over radius R of the first is
            // that of the second over α^{1/n} R (substitute u = α^{1/n} r).
            let radius = scenario.region.width.hypot(scenario.region.height) / 2.0;
            Some(designed_thresholds(
                amplitude.law,
                amplitude.sigma,
                scenario.quantizer.bits,
                radius * amplitude.distance_scale(),
            ))
        }
        _ => uniform,
    }
}

/// The thresholds of eq. 6.46, found once per process for each design:
/// every node of a `sim` asks for the same ones, and the search takes a
/// while.
fn designed_thresholds(law: DecayLaw, sigma: f64, bits: u8, radius: f64) -> Quantizer {
    type Key = (u64, u64, u64, u8, u64);
    static DESIGNED: Mutex<Vec<(Key, Quantizer)>> = Mutex::new(Vec::new());
    let DecayLaw::PowerLaw { p0, exponent } = law else {
        unreachable!("the locator designs for the power law")
    };
    let key = (
        p0.to_bits(),
        exponent.to_bits(),
        sigma.to_bits(),
        bits,
        radius.to_bits(),
    );
    let mut designed = DESIGNED.lock().unwrap_or_else(|p| p.into_inner());
    if let Some((_, q)) = designed.iter().find(|(k, _)| *k == key) {
        return q.clone();
    }
    let q = optimize_thresholds(bits, -4.0 * sigma, p0.sqrt() + 4.0 * sigma, |q| {
        closed_form_information(law, Measurement::Quantized(q), sigma, 1.0, radius)
    });
    designed.push((key, q.clone()));
    q
}

/// What one node knows of the target from its own sensors.
#[derive(Debug, Clone)]
pub struct LocalEvidence {
    /// The node's sensors' models, in the order of `sensors`.
    models: Vec<ObservationModel>,
    sensors: Vec<u16>,
    quantizer: Option<Quantizer>,
    /// For each own sensor, each report value heard and how many times
    /// (the cell index, or a raw value's bits).
    reports: Vec<Vec<(u64, u32)>>,
}

impl LocalEvidence {
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        node: u16,
        quantizer: Option<Quantizer>,
    ) -> Self {
        let sensors = topology.node_sensors[node as usize].clone();
        let models = sensors
            .iter()
            .map(|s| {
                scenario
                    .observation
                    .law()
                    .at(topology.sensor_positions[*s as usize])
            })
            .collect();
        Self {
            reports: vec![Vec::new(); sensors.len()],
            models,
            sensors,
            quantizer,
        }
    }

    /// Takes a step's reports in.
    pub fn add(&mut self, observations: &[Observation]) {
        for o in observations {
            let Some(slot) = self.sensors.iter().position(|s| *s == o.sensor) else {
                continue;
            };
            let key = match o.value {
                ObservedValue::Cell(c) => u64::from(c),
                ObservedValue::Raw(v) => v.to_bits(),
            };
            let counts = &mut self.reports[slot];
            match counts.iter_mut().find(|(k, _)| *k == key) {
                Some((_, n)) => *n += 1,
                None => counts.push((key, 1)),
            }
        }
    }

    /// Reports taken in so far.
    pub fn report_count(&self) -> u32 {
        self.reports.iter().flatten().map(|(_, n)| n).sum()
    }

    /// `ln p(reports | θ)` at every point of `grid`, into `out`.
    pub fn log_likelihood(&self, grid: &Grid, out: &mut Vec<f64>) {
        out.clear();
        out.extend((0..grid.len()).map(|k| self.log_likelihood_at(grid.point(k))));
    }

    fn log_likelihood_at(&self, theta: [f64; 2]) -> f64 {
        let x = State::new(theta[0], theta[1], 0.0, 0.0);
        let mut sum = 0.0;
        for (model, counts) in self.models.iter().zip(&self.reports) {
            if counts.is_empty() {
                continue;
            }
            let (mean, variance) = model.mean_and_variance(&x);
            for &(key, n) in counts {
                let ln_p = match &self.quantizer {
                    Some(q) => q.ln_probability(key as u32, mean, variance),
                    None => {
                        let z = f64::from_bits(key);
                        let e = if model.is_angular() {
                            bounds::wrap_angle(z - mean)
                        } else {
                            z - mean
                        };
                        -0.5 * (e * e / variance + (2.0 * std::f64::consts::PI * variance).ln())
                    }
                };
                sum += f64::from(n) * ln_p;
            }
        }
        sum
    }

    /// The Fisher information of the reports about the position at
    /// `theta`, as `[J_xx, J_xy, J_yy]`.
    pub fn information(&self, theta: [f64; 2]) -> [f64; 3] {
        let x = State::new(theta[0], theta[1], 0.0, 0.0);
        let mut j = [0.0; 3];
        for (model, counts) in self.models.iter().zip(&self.reports) {
            let n: u32 = counts.iter().map(|(_, n)| n).sum();
            if n == 0 {
                continue;
            }
            let e = model.evaluate(&x);
            let s = match &self.quantizer {
                Some(q) => q.fisher_scalars_exact(e.g, e.r),
                None => FisherScalars::raw(e.r),
            };
            let (gx, gy, rx, ry) = (e.grad_g[0], e.grad_g[1], e.grad_r[0], e.grad_r[1]);
            let block = [
                s.gg * gx * gx + 2.0 * s.gr * gx * rx + s.rr * rx * rx,
                s.gg * gx * gy + s.gr * (gx * ry + rx * gy) + s.rr * rx * ry,
                s.gg * gy * gy + 2.0 * s.gr * gy * ry + s.rr * ry * ry,
            ];
            // A sensor exactly at θ has no direction to it: its gradient
            // is 0/0 there, and its information about θ nil.
            if block.iter().all(|v| v.is_finite()) {
                for (t, b) in j.iter_mut().zip(block) {
                    *t += f64::from(n) * b;
                }
            }
        }
        j
    }
}

/// `sqrt(tr J⁻¹)`, metres, for `J = [J_xx, J_xy, J_yy]`; `None` when `J` is
/// singular.
pub fn position_bound(j: [f64; 3]) -> Option<f64> {
    let det = j[0] * j[2] - j[1] * j[1];
    let trace_inverse = (j[0] + j[2]) / det;
    (det > 0.0 && trace_inverse.is_finite()).then(|| trace_inverse.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounds::location::exact_information;
    use fusion_graph::scenario::LOCATION_SCENARIO;

    fn scenario(overrides: &[&str]) -> Scenario {
        let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        Scenario::from_toml(LOCATION_SCENARIO, "location.toml", &o).unwrap()
    }

    /// The scenario's amplitude law as `bounds::location`'s power law (its
    /// α is 1), its σ, and the positions of sensors `own`.
    fn power_law_and_positions(
        s: &Scenario,
        t: &Topology,
        own: &[u16],
    ) -> (DecayLaw, f64, Vec<[f64; 2]>) {
        let a = AmplitudeLaw::of(s.observation.law()).expect("amplitude sensors");
        assert_eq!(a.alpha, 1.0);
        let positions = own
            .iter()
            .map(|i| t.sensor_positions[*i as usize])
            .collect();
        (a.law, a.sigma, positions)
    }

    /// The parabola's vertex: exact for a quadratic, wherever its peak
    /// lies within half a step of the best point.
    #[test]
    fn the_grid_search_finds_a_quadratic_peak_between_points() {
        let s = scenario(&[]);
        let grid = Grid::over_region(&s, [21, 17]);
        let peak = [3.31, 4.67];
        let ll: Vec<f64> = (0..grid.len())
            .map(|k| {
                let p = grid.point(k);
                -3.0 * (p[0] - peak[0]).powi(2) - 0.5 * (p[1] - peak[1]).powi(2)
            })
            .collect();
        let best = grid.best(&ll);
        assert!((best[0] - peak[0]).abs() < 1e-9 && (best[1] - peak[1]).abs() < 1e-9);
        let fine = grid.around(best);
        assert!(fine.spacing[0] < grid.spacing[0] / 8.0);
        let centre = fine.point(fine.len() / 2);
        assert!((centre[0] - best[0]).abs() < 1e-9 && (centre[1] - best[1]).abs() < 1e-9);
    }

    /// For amplitude sensors, the information `Σ n_i I(g_i) ∇g_i ∇g_iᵀ`
    /// the node computes from its observation models is `bounds`' exact
    /// CRLB of Theorem 6.2 (its own derivation, by `g'(d)/d`), twice over
    /// for two reports each.
    #[test]
    fn the_information_is_theorem_6_2s_sum() {
        let s = scenario(&[]);
        let t = Topology::from_scenario(&s, "s").unwrap();
        let q = sensor_quantizer(&s, ThresholdDesign::Designed).unwrap();
        let mut evidence = LocalEvidence::new(&s, &t, 0, Some(q.clone()));
        let own = &t.node_sensors[0];
        let step: Vec<Observation> = own
            .iter()
            .map(|&sensor| Observation {
                sensor,
                value: ObservedValue::Cell(0),
            })
            .collect();
        evidence.add(&step);
        evidence.add(&step);
        assert_eq!(evidence.report_count(), 2 * own.len() as u32);
        let (law, sigma, positions) = power_law_and_positions(&s, &t, own);
        let theta = [5.3, 2.9];
        let expected =
            exact_information(law, Measurement::Quantized(&q), sigma, &positions, theta) * 2.0;
        let got = evidence.information(theta);
        for (g, e) in got
            .iter()
            .zip([expected[(0, 0)], expected[(0, 1)], expected[(1, 1)]])
        {
            assert!(
                (g - e).abs() <= 1e-9 * e.abs().max(1e-12),
                "{got:?} vs {expected}"
            );
        }
    }

    /// The log-likelihood is the reports' cells' log-probabilities summed,
    /// as `bounds::location::log_likelihood` computes them.
    #[test]
    fn the_log_likelihood_is_eq_6_11() {
        let s = scenario(&[]);
        let t = Topology::from_scenario(&s, "s").unwrap();
        let q = sensor_quantizer(&s, ThresholdDesign::Designed).unwrap();
        let mut evidence = LocalEvidence::new(&s, &t, 1, Some(q.clone()));
        let own = &t.node_sensors[1];
        let cells: Vec<u32> = (0..own.len() as u32)
            .map(|i| i % q.cells() as u32)
            .collect();
        let step: Vec<Observation> = own
            .iter()
            .zip(&cells)
            .map(|(&sensor, &c)| Observation {
                sensor,
                value: ObservedValue::Cell(c),
            })
            .collect();
        evidence.add(&step);
        let (law, sigma, positions) = power_law_and_positions(&s, &t, own);
        let grid = Grid::over_region(&s, [7, 7]);
        let mut ll = Vec::new();
        evidence.log_likelihood(&grid, &mut ll);
        for (k, got) in ll.iter().enumerate() {
            let expected =
                bounds::location::log_likelihood(law, &q, sigma, &positions, &cells, grid.point(k));
            assert!((got - expected).abs() <= 1e-9 * expected.abs().max(1.0));
        }
    }
}
