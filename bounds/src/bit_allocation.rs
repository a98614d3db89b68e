//! Fusion of quantized data aided by controlled noise, and the allocation of
//! a budget of bits over sensors (dissertation ch. 5).
//!
//! A scalar `θ ~ N(0, σθ²)` is observed by sensors `zᵢ = θ + nᵢ`,
//! `nᵢ ~ N(0, σnᵢ²)`; sensor i quantizes `zᵢ` with a uniform `bᵢ`-bit
//! quantizer of step `qᵢ` and the fusion centre adds Gaussian noise
//! `dᵢ ~ N(0, σdᵢ²)` to what it receives. When `zᵢ`'s characteristic function
//! vanishes beyond `π/qᵢ` (Widrow's first theorem), the received
//! `yᵢ = zᵢ + wᵢ + dᵢ` with `wᵢ` uniform on a cell, so its likelihood is a
//! Gaussian smeared over one cell (eq. 5.6) and the Bayesian information is
//! `J = σθ⁻² + Σ J̃ᵢ` (Theorem 5.2).
//!
//! The dissertation truncates a Gaussian's characteristic function at four
//! of its standard deviations (`1/σ`), which makes the theorem's condition
//! `qᵢ ≤ πσnᵢ/4` and the smallest admissible injected noise
//! `σdᵢ = 1/(2π/(4qᵢ) − 1/σnᵢ)`: the noise's pass band just reaches the first
//! replica's edge. A sensor's range is `Lᵢ = 8√(σθ² + σnᵢ²)`, so
//! `qᵢ = Lᵢ/2^bᵢ`; a sensor given no bits is silent.

use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::normal;

/// One sensor of the problem: its observation noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoisySensor {
    pub noise_std: f64,
}

/// The estimation problem: the prior of θ and the sensors observing it.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    pub prior_var: f64,
    pub sensors: Vec<NoisySensor>,
}

/// How one sensor is quantized and what the fusion centre injects.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorDesign {
    pub bits: u32,
    /// Quantizer step `q`.
    pub step: f64,
    /// Standard deviation of the injected Gaussian noise `σd`.
    pub injected_std: f64,
}

/// One allocation of the budget and what it gives.
#[derive(Debug, Clone, PartialEq)]
pub struct Allocation {
    pub bits: Vec<u32>,
    /// `None` for a sensor given no bits.
    pub designs: Vec<Option<SensorDesign>>,
    /// `J` of eq. (5.9), the prior's information included.
    pub fisher: f64,
    /// The LMMSE estimator's MSE, eq. (5.18).
    pub lmmse_mse: f64,
}

impl Allocation {
    /// The PCRLB on θ's MSE: `1/J`.
    pub fn pcrlb(&self) -> f64 {
        1.0 / self.fisher
    }
}

impl Problem {
    /// Sensor i's quantizer range `L = 8√(σθ² + σn²)`: ±4 standard
    /// deviations of `zᵢ`.
    pub fn range(&self, sensor: usize) -> f64 {
        8.0 * (self.prior_var + self.sensors[sensor].noise_std.powi(2)).sqrt()
    }

    /// Sensor i's design at `bits` bits; `None` if no bits (silent) or if
    /// the quantizer is too coarse for Widrow's condition.
    pub fn design(&self, sensor: usize, bits: u32) -> Option<SensorDesign> {
        if bits == 0 {
            return None;
        }
        let noise_std = self.sensors[sensor].noise_std;
        let step = self.range(sensor) / 2f64.powi(bits as i32);
        widrow_holds(step, noise_std).then(|| SensorDesign {
            bits,
            step,
            injected_std: smallest_injected_std(step, noise_std),
        })
    }

    /// Whether `bits` can be allocated this way: each sensor silent or
    /// meeting Widrow's condition.
    pub fn feasible(&self, bits: &[u32]) -> bool {
        bits.iter()
            .enumerate()
            .all(|(i, &b)| b == 0 || self.design(i, b).is_some())
    }

    /// `J` and the LMMSE's MSE of an allocation; `None` if infeasible.
    pub fn evaluate(&self, bits: &[u32]) -> Option<Allocation> {
        assert_eq!(bits.len(), self.sensors.len(), "one entry per sensor");
        if !self.feasible(bits) {
            return None;
        }
        let designs: Vec<Option<SensorDesign>> = bits
            .iter()
            .enumerate()
            .map(|(i, &b)| self.design(i, b))
            .collect();
        let mut fisher = 1.0 / self.prior_var;
        let mut lmmse_information = 1.0 / self.prior_var;
        for (sensor, design) in self.sensors.iter().zip(&designs) {
            if let Some(d) = design {
                let spread = received_std(sensor.noise_std, d.injected_std);
                fisher += smeared_gaussian_information(d.step, spread);
                lmmse_information += 1.0 / total_noise_var(sensor.noise_std, d);
            }
        }
        Some(Allocation {
            bits: bits.to_vec(),
            designs,
            fisher,
            lmmse_mse: 1.0 / lmmse_information,
        })
    }

    /// Every feasible allocation of exactly `budget` bits, in the
    /// dissertation's order: the first sensor's bits descending (brute
    /// force, Remark 2: `R + 1` candidates for two sensors).
    pub fn allocations(&self, budget: u32) -> Vec<Allocation> {
        let mut out = Vec::new();
        let mut bits = vec![0; self.sensors.len()];
        self.enumerate(budget, 0, &mut bits, &mut out);
        out
    }

    fn enumerate(&self, left: u32, sensor: usize, bits: &mut Vec<u32>, out: &mut Vec<Allocation>) {
        if sensor + 1 == bits.len() {
            bits[sensor] = left;
            out.extend(self.evaluate(bits));
            return;
        }
        for b in (0..=left).rev() {
            bits[sensor] = b;
            self.enumerate(left - b, sensor + 1, bits, out);
        }
    }

    /// The feasible allocation of `budget` bits with the largest `J`.
    pub fn optimal(&self, budget: u32) -> Option<Allocation> {
        self.allocations(budget)
            .into_iter()
            .max_by(|a, b| a.fisher.total_cmp(&b.fisher))
    }
}

/// Widrow's condition with the characteristic function truncated at four of
/// its standard deviations: `π/q ≥ 4/σn`.
pub fn widrow_holds(step: f64, noise_std: f64) -> bool {
    step <= std::f64::consts::PI * noise_std / 4.0
}

/// The smallest injected noise whose pass band (4/σd) stays clear of the
/// first replica (which starts at `2π/q − 4/σn`): Remark 1 says less noise
/// is more information, so the smallest admissible one is the optimum.
pub fn smallest_injected_std(step: f64, noise_std: f64) -> f64 {
    1.0 / (2.0 * std::f64::consts::PI / (4.0 * step) - 1.0 / noise_std)
}

fn received_std(noise_std: f64, injected_std: f64) -> f64 {
    (noise_std.powi(2) + injected_std.powi(2)).sqrt()
}

/// `σg² = σn² + σd² + q²/12`, eq. (5.16).
fn total_noise_var(noise_std: f64, d: &SensorDesign) -> f64 {
    noise_std.powi(2) + d.injected_std.powi(2) + d.step.powi(2) / 12.0
}

/// Likelihood of one received value, eq. (5.6):
/// `p(y|θ) = [Φ((y−θ+q/2)/s) − Φ((y−θ−q/2)/s)]/q`.
pub fn likelihood(y: f64, theta: f64, step: f64, spread: f64) -> f64 {
    let e = y - theta;
    normal::interval_mass((e - step / 2.0) / spread, (e + step / 2.0) / spread) / step
}

/// `J̃` of eq. (5.10): the Fisher information about a location of the
/// density `N(0, s²) ∗ U(−q/2, q/2)`. It does not depend on θ, so the outer
/// expectation over the prior is the identity. Composite Simpson over
/// `|y| ≤ q/2 + 14 s` (the rest holds less than 1e-40 of the mass), with the
/// cell probability taken on the tail side so the tails keep their digits.
pub fn smeared_gaussian_information(step: f64, spread: f64) -> f64 {
    let half = step / 2.0;
    let reach = half + 14.0 * spread;
    // Resolve the finer of the two scales; an even count for Simpson.
    let h_max = step.min(spread) / 40.0;
    let n = (((reach / h_max).ceil() as usize).clamp(200, 2_000_000) + 1) & !1;
    let h = reach / n as f64;
    let integrand = |y: f64| {
        let (a, b) = ((y - half) / spread, (y + half) / spread);
        let mass = normal::interval_mass(a, b);
        if mass <= 0.0 {
            return 0.0;
        }
        let slope = normal::pdf(a) - normal::pdf(b);
        slope * slope / mass
    };
    let mut sum = integrand(0.0) + integrand(reach);
    for k in 1..n {
        sum += integrand(k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 };
    }
    // Both halves of the symmetric integrand. With p = mass/q the score is
    // (φ(a) − φ(b))/(s·mass), so p·score² = (φ(a) − φ(b))²/(q s² mass).
    2.0 * sum * h / 3.0 / (step * spread * spread)
}

/// The received values of one draw: each sensor's observation quantized by
/// its `bᵢ`-bit quantizer (cell centres, saturating at the range's ends),
/// plus the injected noise. Silent sensors give `None`. Every sensor
/// takes its two draws, its observation noise and its injected noise, in
/// order, silent or not: allocations compared over the same stream then
/// see the same noise, sensor by sensor.
pub fn receive<R: Rng + ?Sized>(
    problem: &Problem,
    allocation: &Allocation,
    theta: f64,
    rng: &mut R,
) -> Vec<Option<f64>> {
    let unit = Normal::new(0.0, 1.0).expect("unit normal");
    problem
        .sensors
        .iter()
        .enumerate()
        .zip(&allocation.designs)
        .map(|((i, sensor), design)| {
            let (n, injected): (f64, f64) = (unit.sample(rng), unit.sample(rng));
            design.map(|d| {
                let z = theta + sensor.noise_std * n;
                let cells = 2f64.powi(d.bits as i32);
                let low = -problem.range(i) / 2.0;
                let cell = ((z - low) / d.step).floor().clamp(0.0, cells - 1.0);
                low + (cell + 0.5) * d.step + d.injected_std * injected
            })
        })
        .collect()
}

/// The LMMSE estimate, eq. (5.17), with the prior mean 0.
pub fn lmmse_estimate(problem: &Problem, allocation: &Allocation, received: &[Option<f64>]) -> f64 {
    let mut information = 1.0 / problem.prior_var;
    let mut weighted = 0.0;
    for ((sensor, design), y) in problem
        .sensors
        .iter()
        .zip(&allocation.designs)
        .zip(received)
    {
        if let (Some(d), Some(y)) = (design, y) {
            let var = total_noise_var(sensor.noise_std, d);
            information += 1.0 / var;
            weighted += y / var;
        }
    }
    weighted / information
}

/// The MMSE estimate, eq. (5.8): the posterior mean under the likelihood
/// (5.6), by quadrature on `points` points. The grid spans ±12 LMMSE
/// deviations around the LMMSE estimate (the posterior is within a few
/// percent of that Gaussian when Widrow's condition holds), clipped to ±8
/// prior deviations.
pub fn mmse_estimate(
    problem: &Problem,
    allocation: &Allocation,
    received: &[Option<f64>],
    points: usize,
) -> f64 {
    let prior_reach = 8.0 * problem.prior_var.sqrt();
    let centre = lmmse_estimate(problem, allocation, received).clamp(-prior_reach, prior_reach);
    let (low, high) = (
        (centre - 12.0 * allocation.lmmse_mse.sqrt()).max(-prior_reach),
        (centre + 12.0 * allocation.lmmse_mse.sqrt()).min(prior_reach),
    );
    let h = (high - low) / (points - 1) as f64;
    // Log-weights, shifted by their maximum before exponentiating: far from
    // the prior's centre the products underflow otherwise.
    let log_weight = |theta: f64| {
        let mut w = -0.5 * theta * theta / problem.prior_var;
        for ((sensor, design), y) in problem
            .sensors
            .iter()
            .zip(&allocation.designs)
            .zip(received)
        {
            if let (Some(d), Some(y)) = (design, y) {
                let spread = received_std(sensor.noise_std, d.injected_std);
                let e = y - theta;
                w += normal::ln_interval_mass(
                    (e - d.step / 2.0) / spread,
                    (e + d.step / 2.0) / spread,
                );
            }
        }
        w
    };
    let peak = log_weight(centre);
    let (mut mass, mut first_moment) = (0.0, 0.0);
    for k in 0..points {
        let theta = low + k as f64 * h;
        let w = (log_weight(theta) - peak).exp();
        mass += w;
        first_moment += w * theta;
    }
    first_moment / mass
}

/// Monte Carlo MSEs of the MMSE and the LMMSE estimators over `runs` draws
/// of θ from its prior: (MSE1, MSE2) of Table 5.2.
pub fn estimator_mses<R: Rng + ?Sized>(
    problem: &Problem,
    allocation: &Allocation,
    runs: usize,
    rng: &mut R,
) -> (f64, f64) {
    let (mut mmse, mut lmmse) = (0.0, 0.0);
    for _ in 0..runs {
        let (a, b) = estimator_squared_errors(problem, allocation, rng);
        mmse += a;
        lmmse += b;
    }
    (mmse / runs as f64, lmmse / runs as f64)
}

/// One draw of θ from its prior and of every sensor's noise: the squared
/// errors of the MMSE and the LMMSE estimates. A stream seeded per draw
/// gives every allocation the same θ and noise, so their MSEs compare
/// draw by draw.
pub fn estimator_squared_errors<R: Rng + ?Sized>(
    problem: &Problem,
    allocation: &Allocation,
    rng: &mut R,
) -> (f64, f64) {
    let prior = Normal::new(0.0, problem.prior_var.sqrt()).expect("positive prior variance");
    let theta = prior.sample(rng);
    let received = receive(problem, allocation, theta, rng);
    (
        (mmse_estimate(problem, allocation, &received, 481) - theta).powi(2),
        (lmmse_estimate(problem, allocation, &received) - theta).powi(2),
    )
}

/// Experiment 2 of §5.5: `σθ² = 4` (Experiment 1's; the tables' (0, R) rows,
/// `J = 1/4 + 1/9`, confirm it), `σn = (0.6, 3)`.
pub fn dissertation_problem() -> Problem {
    Problem {
        prior_var: 4.0,
        sensors: vec![
            NoisySensor { noise_std: 0.6 },
            NoisySensor { noise_std: 3.0 },
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// Table 5.2 of the dissertation: (bits, J).
    const TABLE_5_2: [((u32, u32), f64); 5] = [
        ((12, 0), 3.0276),
        ((8, 4), 3.0883),
        ((7, 5), 3.0519),
        ((6, 6), 2.7492),
        ((0, 12), 0.3610),
    ];

    #[test]
    fn table_5_2_is_reproduced_allocation_by_allocation() {
        let problem = dissertation_problem();
        let rows = problem.allocations(12);
        let listed: Vec<(u32, u32)> = rows.iter().map(|a| (a.bits[0], a.bits[1])).collect();
        let expected: Vec<(u32, u32)> = TABLE_5_2.iter().map(|(b, _)| *b).collect();
        assert_eq!(listed, expected, "the feasible allocations");
        for (a, (_, j)) in rows.iter().zip(TABLE_5_2) {
            // The table's four decimals, rounded either way.
            assert!(
                (a.fisher - j).abs() < 1.5e-4,
                "{:?}: J {} against {j}",
                a.bits,
                a.fisher
            );
        }
        assert_eq!(problem.optimal(12).unwrap().bits, vec![8, 4]);
    }

    #[test]
    fn twenty_bits_are_best_split_twelve_and_eight() {
        assert_eq!(
            dissertation_problem().optimal(20).unwrap().bits,
            vec![12, 8]
        );
    }

    #[test]
    fn the_smeared_information_tends_to_the_unquantized_one_as_cells_shrink() {
        let s = 1.3;
        let mut last = 0.0;
        for bits in 1..=14 {
            let q = 8.0 / 2f64.powi(bits);
            let j = smeared_gaussian_information(q, s);
            // Between the two closed forms that bracket it: no more than the
            // unsmeared Gaussian's 1/s² (smearing never adds information),
            // no less than 1/variance (the Cramér–Rao bound on the mean).
            assert!(j <= 1.0 / (s * s) * (1.0 + 1e-9), "{bits} bits: {j}");
            assert!(
                j >= 1.0 / (s * s + q * q / 12.0) * (1.0 - 1e-9),
                "{bits} bits: {j}"
            );
            assert!(j > last, "more bits, more information");
            last = j;
        }
        assert!((last - 1.0 / (s * s)).abs() < 1e-7 / (s * s));
    }

    #[test]
    fn the_smeared_information_matches_a_monte_carlo_of_the_squared_score() {
        // The score by a central finite difference of the log-likelihood
        // (5.6), at y drawn from the model: independent of the quadrature.
        let (q, s) = (0.9, 0.7);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let n = 400_000;
        let h = 1e-5;
        let mean_square: f64 = (0..n)
            .map(|_| {
                let y = s * unit.sample(&mut rng) + q * (rng.random::<f64>() - 0.5);
                let score =
                    (likelihood(y, h, q, s).ln() - likelihood(y, -h, q, s).ln()) / (2.0 * h);
                score * score
            })
            .sum::<f64>()
            / n as f64;
        let j = smeared_gaussian_information(q, s);
        assert!(
            (mean_square - j).abs() < 0.01 * j,
            "Monte Carlo {mean_square}, quadrature {j}"
        );
    }

    #[test]
    fn the_lmmse_reaches_its_closed_form_mse_and_the_mmse_does_no_worse() {
        let problem = dissertation_problem();
        let allocation = problem.evaluate(&[8, 4]).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mmse, lmmse) = estimator_mses(&problem, &allocation, 4000, &mut rng);
        // The squared error of a Gaussian-ish estimate has relative standard
        // deviation √(2/n) ≈ 2.2%; 4 of those.
        assert!(
            (lmmse / allocation.lmmse_mse - 1.0).abs() < 0.09,
            "{lmmse} against {}",
            allocation.lmmse_mse
        );
        // Same draws: the posterior mean is no worse than the linear one
        // beyond sampling noise, and neither beats the bound by more.
        assert!(mmse < lmmse * 1.02, "{mmse} against {lmmse}");
        assert!(
            mmse > allocation.pcrlb() * 0.91,
            "{mmse} against {}",
            allocation.pcrlb()
        );
    }

    #[test]
    fn the_mmse_quadrature_matches_the_closed_form_posterior_mean() {
        // With one sensor, p(y|θ) ∝ P(θ + e ∈ [y − q/2, y + q/2]), e ~ N(0, s²),
        // so the posterior mean is E[θ | z ∈ I] with z = θ + e:
        // σθ²/(σθ² + s²) · E[z | z ∈ I], a truncated normal's mean.
        let problem = Problem {
            prior_var: 4.0,
            sensors: vec![NoisySensor { noise_std: 0.3 }],
        };
        let design = SensorDesign {
            bits: 3,
            step: 2.0,
            injected_std: 0.05,
        };
        let s2 = 0.3f64.powi(2) + 0.05f64.powi(2);
        let var = s2 + design.step.powi(2) / 12.0;
        let allocation = Allocation {
            bits: vec![3],
            designs: vec![Some(design)],
            fisher: f64::NAN,
            lmmse_mse: 1.0 / (0.25 + 1.0 / var),
        };
        let sz = (4.0 + s2).sqrt();
        for y in [-5.3, -1.0, 0.0, 0.4, 2.5, 6.1] {
            let (a, b) = ((y - 1.0) / sz, (y + 1.0) / sz);
            let truncated_mean =
                sz * (normal::pdf(a) - normal::pdf(b)) / normal::interval_mass(a, b);
            let expected = 4.0 / (4.0 + s2) * truncated_mean;
            let got = mmse_estimate(&problem, &allocation, &[Some(y)], 481);
            assert!(
                (got - expected).abs() < 1e-6,
                "y = {y}: {got} against {expected}"
            );
        }
    }

    #[test]
    fn a_silent_sensor_takes_its_draws_so_the_others_see_the_same_noise() {
        let problem = dissertation_problem();
        let silent = problem.evaluate(&[0, 8]).expect("feasible");
        let active = problem.evaluate(&[6, 8]).expect("feasible");
        for seed in 0..20 {
            let draw = |a: &Allocation| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                receive(&problem, a, 0.7, &mut rng)
            };
            let (s, a) = (draw(&silent), draw(&active));
            assert_eq!(s[0], None);
            assert!(a[0].is_some());
            assert_eq!(s[1], a[1], "seed {seed}: sensor 2 saw other noise");
        }
    }

    #[test]
    fn an_infeasible_quantizer_is_refused_and_a_silent_sensor_adds_nothing() {
        let problem = dissertation_problem();
        // Sensor 1 needs q ≤ 0.6π/4 ≈ 0.47, i.e. 6 bits of its 16.7 range.
        assert!(problem.design(0, 5).is_none());
        assert!(problem.design(0, 6).is_some());
        assert!(problem.evaluate(&[5, 7]).is_none());
        let alone = problem.evaluate(&[0, 12]).unwrap();
        let prior_and_second = 0.25
            + smeared_gaussian_information(
                alone.designs[1].unwrap().step,
                received_std(3.0, alone.designs[1].unwrap().injected_std),
            );
        assert!((alone.fisher - prior_and_second).abs() < 1e-12);
    }
}
