//! The fusion centre of the censoring tables: the node's particle filter
//! weighing what each sensor sent, or its silence, over many trials.

use bounds::censoring::{CensoringRule, VectorSilence};
use bounds::{Mat4, ObservationModel, State};
use nalgebra::{Matrix2, SMatrix, Vector2};
use node::filter::{Gaussian, ParticleFilter};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::setups::{table_key, Feedback, Setup, SEED, SILENCE_DRAWS};
use crate::parallel::indexed_with;

#[derive(Debug, Clone, Default)]
pub(super) struct Measured {
    pub(super) mean: f64,
    pub(super) stderr: f64,
    pub(super) rmse: f64,
    /// Each trial's position MSE over its steps, in trial order: the two
    /// schemes' trials share their trajectories and noise, so they pair.
    pub(super) per_trial_mse: Vec<f64>,
}

/// The trials of one row, spread over threads; each trial's randomness
/// depends on its index alone, and they are summed in index order, so the
/// result does not depend on `threads` or on which thread ran what, and
/// both schemes see the same trajectories and noise. (Summed in finishing
/// order, the means, multiples of 1/(20 · trials), fell on the printed
/// tables' rounding boundary and changed from run to run.)
pub(super) fn measure(
    setup: &Setup,
    rule: &CensoringRule,
    scheme: Feedback,
    threads: usize,
) -> Measured {
    let trials: Vec<Trial> = indexed_with(
        setup.trials as usize,
        threads,
        || TrialFilter::new(setup),
        |filter, trial| filter.run(setup, rule, scheme, trial as u32),
    );
    let n = trials.len() as f64;
    // l̄ per trial (the mean over its steps) as the sample, so the standard
    // error respects the correlation between a trial's steps.
    let per_trial: Vec<f64> = trials
        .iter()
        .map(|t| t.sent as f64 / setup.steps as f64)
        .collect();
    let mean = per_trial.iter().sum::<f64>() / n;
    let var = per_trial.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    let squared: f64 = trials.iter().map(|t| t.squared_error).sum();
    Measured {
        mean,
        stderr: (var / n).sqrt(),
        rmse: (squared / (n * setup.steps as f64)).sqrt(),
        per_trial_mse: trials
            .iter()
            .map(|t| t.squared_error / setup.steps as f64)
            .collect(),
    }
}

struct Trial {
    sent: u32,
    /// Σ over steps of the squared position error.
    squared_error: f64,
}

/// A fusion centre's particle filter, the node's ([`ParticleFilter`]), with
/// the step's sensor reports, reused over trials so that the steps allocate
/// little. It predicts with the setups' own process noise, singular along
/// an axis the target does not move on ([`ParticleFilter::predict_linear`]),
/// and weighs in one untempered stage: the dissertation's tables come from
/// the textbook filter, and the node's tempering and regularization would
/// change them.
struct TrialFilter {
    filter: ParticleFilter,
    reports: Vec<Report>,
}

/// What the centre learnt from one sensor this step.
enum Report {
    /// Its measurement.
    Received { sensor: usize, z: Vector2<f64> },
    /// Its silence: the prediction `g` it was measured against, S and R.
    Silent {
        sensor: usize,
        g: Vector2<f64>,
        s: Matrix2<f64>,
        r: Matrix2<f64>,
        /// For a two-component sensor, the Monte Carlo of its silence.
        vector: Option<VectorSilence>,
    },
}

impl Report {
    /// `ln p(report | x)`.
    fn ln_likelihood(
        &self,
        sensors: &[Vec<ObservationModel>],
        rule: &CensoringRule,
        x: &State,
    ) -> f64 {
        match self {
            Report::Received { sensor, z } => sensors[*sensor]
                .iter()
                .enumerate()
                .map(|(c, model)| {
                    let e = model.evaluate(x);
                    -0.5 * (z[c] - e.g).powi(2) / e.r
                })
                .sum(),
            Report::Silent {
                sensor,
                g,
                s,
                r,
                vector: None,
            } => {
                let mu = sensors[*sensor][0].evaluate(x).g - g[0];
                rule.ln_silence_probability(mu, s[(0, 0)], r[(0, 0)])
            }
            Report::Silent {
                sensor,
                g,
                vector: Some(silence),
                ..
            } => {
                let sensor = &sensors[*sensor];
                let m = Vector2::new(
                    sensor[0].evaluate(x).g - g[0],
                    sensor[1].evaluate(x).g - g[1],
                );
                // Half a draw keeps a particle no draw supports from a weight
                // of zero, which one silent sensor could otherwise give them all.
                let p = (silence.probability(&m) * SILENCE_DRAWS as f64 + 0.5)
                    / (SILENCE_DRAWS as f64 + 1.0);
                p.ln()
            }
        }
    }
}

impl TrialFilter {
    fn new(setup: &Setup) -> Self {
        let prior = Gaussian {
            mean: setup.prior_mean,
            cov: setup.prior_cov,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        Self {
            filter: ParticleFilter::from_gaussian(setup.particles, &prior, &mut rng)
                .expect("every setup's prior is positive definite"),
            reports: Vec::with_capacity(setup.sensors.len()),
        }
    }

    fn run(&mut self, setup: &Setup, rule: &CensoringRule, scheme: Feedback, trial: u32) -> Trial {
        let mut rng = ChaCha8Rng::seed_from_u64(SEED ^ ((trial as u64) << 20) ^ table_key(setup));
        let f = setup.dynamics.jacobian(&State::zeros());
        let (q, q_factor) = setup.process_noise();
        let prior = Gaussian {
            mean: setup.prior_mean,
            cov: setup.prior_cov,
        };
        let prior_factor = cholesky_or_diagonal(&setup.prior_cov);
        let gaussian =
            |rng: &mut ChaCha8Rng| State::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal));
        let mut truth = if setup.random_start {
            setup.prior_mean + prior_factor * gaussian(&mut rng)
        } else {
            setup.prior_mean
        };
        self.filter
            .reset_gaussian(&prior, &mut rng)
            .expect("every setup's prior is positive definite");
        // The node's posterior (what it feeds back) and each sensor's own
        // Kalman covariance (CFwMD).
        let (mut estimate, mut estimate_cov) = (setup.prior_mean, setup.prior_cov);
        let mut local_cov = vec![setup.prior_cov; setup.sensors.len()];
        let mut out = Trial {
            sent: 0,
            squared_error: 0.0,
        };
        let mut silence_rng = ChaCha8Rng::seed_from_u64(SEED.wrapping_add(trial as u64));
        for _ in 0..setup.steps {
            truth = f * truth + q_factor * gaussian(&mut rng);
            self.filter.predict_linear(&f, &q_factor, &mut rng);
            let predicted = f * estimate;
            let predicted_cov = f * estimate_cov * f.transpose() + q;
            self.reports.clear();
            for (i, sensor) in setup.sensors.iter().enumerate() {
                let local = f * local_cov[i] * f.transpose() + q;
                let (g, s, r) = innovation_statistics(
                    sensor,
                    &predicted,
                    match scheme {
                        Feedback::Estimate => &local,
                        Feedback::EstimateAndCovariance => &predicted_cov,
                    },
                );
                local_cov[i] = kalman_update(&local, sensor, &predicted);
                let z = measure_sensor(sensor, &truth, &mut rng);
                let nu = z - g;
                let s_inv = s
                    .try_inverse()
                    .expect("S = G P Gᵀ + R is positive definite");
                if rule.sends(nu.dot(&(s_inv * nu))) {
                    out.sent += 1;
                    self.reports.push(Report::Received { sensor: i, z });
                } else {
                    let vector = (sensor.len() > 1).then(|| {
                        VectorSilence::new(rule, &s, &r, SILENCE_DRAWS, &mut silence_rng)
                            .expect("S and R are positive definite")
                    });
                    self.reports.push(Report::Silent {
                        sensor: i,
                        g,
                        s,
                        r,
                        vector,
                    });
                }
            }
            let reports = &self.reports;
            self.filter.update_untempered(|particles, out| {
                for (l, x) in out.iter_mut().zip(particles) {
                    *l = reports
                        .iter()
                        .map(|report| report.ln_likelihood(&setup.sensors, rule, x))
                        .sum();
                }
            });
            let posterior = self.filter.summary();
            out.squared_error += (0..setup.axes)
                .map(|a| (posterior.mean[a] - truth[a]).powi(2))
                .sum::<f64>();
            (estimate, estimate_cov) = (posterior.mean, posterior.cov);
            self.filter.resample(&mut rng);
        }
        out
    }
}

/// The predicted measurement `g(x̂)`, its innovation covariance
/// `S = G P Gᵀ + R` (G at x̂) and R. A scalar sensor uses the first slot
/// only; the second is padded so that S stays invertible.
pub(super) fn innovation_statistics(
    sensor: &[ObservationModel],
    predicted: &State,
    cov: &Mat4,
) -> (Vector2<f64>, Matrix2<f64>, Matrix2<f64>) {
    let (gain, g, r) = linearize(sensor, predicted);
    let mut s = gain * cov * gain.transpose() + r;
    if sensor.len() == 1 {
        s[(1, 1)] = 1.0;
    }
    (g, s, r)
}

/// G (rows ∇g of each component, zero for a missing second), g(x) and R.
fn linearize(
    sensor: &[ObservationModel],
    x: &State,
) -> (SMatrix<f64, 2, 4>, Vector2<f64>, Matrix2<f64>) {
    let mut gain = SMatrix::<f64, 2, 4>::zeros();
    let mut g = Vector2::zeros();
    let mut r = Matrix2::identity();
    for (c, model) in sensor.iter().enumerate() {
        let e = model.evaluate(x);
        gain.set_row(c, &e.grad_g.transpose());
        g[c] = e.g;
        r[(c, c)] = e.r;
    }
    (gain, g, r)
}

/// The sensor's own Kalman (EKF) covariance update, linearized at the fed
/// back prediction, as if it used its measurement every step.
pub(super) fn kalman_update(predicted_cov: &Mat4, sensor: &[ObservationModel], at: &State) -> Mat4 {
    let (gain, _, r) = linearize(sensor, at);
    let rows = sensor.len();
    let gain = gain.rows(0, rows).into_owned();
    let r = r.view((0, 0), (rows, rows)).into_owned();
    let s = &gain * predicted_cov * gain.transpose() + r;
    let k = predicted_cov * gain.transpose() * s.try_inverse().expect("S > 0");
    let updated = predicted_cov - &k * &gain * predicted_cov;
    0.5 * (updated + updated.transpose())
}

fn measure_sensor(
    sensor: &[ObservationModel],
    truth: &State,
    rng: &mut ChaCha8Rng,
) -> Vector2<f64> {
    let mut z = Vector2::zeros();
    for (c, model) in sensor.iter().enumerate() {
        z[c] = model.sample(truth, rng);
    }
    z
}

fn cholesky_or_diagonal(cov: &Mat4) -> Mat4 {
    cov.cholesky()
        .map(|c| c.l())
        .unwrap_or_else(|| Mat4::from_diagonal(&cov.diagonal().map(f64::sqrt)))
}
