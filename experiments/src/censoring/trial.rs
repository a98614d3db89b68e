//! The fusion centre of the censoring tables: the node's particle filter
//! weighing what each sensor sent, or its silence, over many trials.

use bounds::batch::CHUNK;
use bounds::censoring::{CensoringRule, VectorSilence};
use bounds::local_predictions::{update_divergence, LocalPredictions};
use bounds::{Mat4, ObservationModel, State};
use nalgebra::{DMatrix, DVector, Matrix2, SMatrix, Vector2};
use node::filter::{Gaussian, ParticleFilter};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::setups::{
    table_key, Arm, Feedback, Rule, Setup, Silence, JOINT_SILENCE_DRAWS, SEED, SILENCE_DRAWS,
};
use crate::parallel::indexed_with;

#[derive(Debug, Clone, Default)]
pub(super) struct Measured {
    pub(super) mean: f64,
    pub(super) stderr: f64,
    pub(super) rmse: f64,
    /// Each trial's position MSE over its steps, in trial order: every
    /// arm's trials share their trajectories and noise, so they pair.
    pub(super) per_trial_mse: Vec<f64>,
    /// Per step, the position and velocity MSE over the trials with their
    /// standard errors: the chapter's curves.
    pub(super) steps: Vec<StepError>,
    /// The first trial's true track, `(p_x, p_y)` per step.
    pub(super) first_path: Vec<[f64; 2]>,
    /// Sensor-steps where a divergence rule decided otherwise than NIS
    /// would have (Theorem 3.4 says none, for scalar measurements).
    pub(super) disagreements: u64,
    /// Per trial, the steps on which no sensor sent although none had sent
    /// the step before either: runs of silence, which the dissertation
    /// blames for CFwMD2's loss at l = 1.
    pub(super) per_trial_silent_runs: Vec<f64>,
}

/// One step's mean squared errors over the trials, each with its standard
/// error.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StepError {
    pub(super) position: (f64, f64),
    pub(super) velocity: (f64, f64),
}

/// The trials of one row, spread over threads; each trial's randomness
/// depends on its index alone, and they are summed in index order, so the
/// result does not depend on `threads` or on which thread ran what, and
/// every arm sees the same trajectories and noise. (Summed in finishing
/// order, the means, multiples of 1/(20 · trials), fell on the printed
/// tables' rounding boundary and changed from run to run.)
pub(super) fn measure(setup: &Setup, l: f64, arm: Arm, threads: usize) -> Measured {
    let rule = CensoringRule::for_budget(l, setup.sensors.len(), setup.sensors[0].len() as u32)
        .expect("every setup's budget lies within its sensors");
    let budget = Budget {
        rule,
        send_probability: l / setup.sensors.len() as f64,
    };
    let trials: Vec<Trial> = indexed_with(
        setup.trials as usize,
        threads,
        || TrialFilter::new(setup),
        |filter, trial| filter.run(setup, &budget, arm, trial as u32),
    );
    let n = trials.len() as f64;
    // l̄ per trial (the mean over its steps) as the sample, so the standard
    // error respects the correlation between a trial's steps.
    let per_trial: Vec<f64> = trials
        .iter()
        .map(|t| t.sent as f64 / setup.steps as f64)
        .collect();
    let (mean, stderr) = mean_and_stderr(per_trial.iter().copied());
    let per_trial_mse: Vec<f64> = trials
        .iter()
        .map(|t| t.position.iter().sum::<f64>() / setup.steps as f64)
        .collect();
    let steps = (0..setup.steps as usize)
        .map(|k| StepError {
            position: mean_and_stderr(trials.iter().map(|t| t.position[k])),
            velocity: mean_and_stderr(trials.iter().map(|t| t.velocity[k])),
        })
        .collect();
    Measured {
        mean,
        stderr,
        rmse: (per_trial_mse.iter().sum::<f64>() / n).sqrt(),
        per_trial_mse,
        steps,
        first_path: trials.first().map(|t| t.path.clone()).unwrap_or_default(),
        disagreements: trials.iter().map(|t| t.disagreements as u64).sum(),
        per_trial_silent_runs: trials.iter().map(|t| t.silent_runs as f64).collect(),
    }
}

impl Measured {
    /// Each trial's own position RMSE over its steps, in trial order.
    pub(super) fn per_trial_rmse(&self) -> Vec<f64> {
        self.per_trial_mse.iter().map(|v| v.sqrt()).collect()
    }
}

fn mean_and_stderr(values: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = values.clone().count() as f64;
    let mean = values.clone().sum::<f64>() / n;
    let var = values.map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt())
}

/// The row's budget: the NIS threshold for censoring arms, the send
/// probability l/N for random selection.
struct Budget {
    rule: CensoringRule,
    send_probability: f64,
}

struct Trial {
    sent: u32,
    /// Per step, the squared position and velocity errors.
    position: Vec<f64>,
    velocity: Vec<f64>,
    path: Vec<[f64; 2]>,
    disagreements: u32,
    silent_runs: u32,
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
    silent: Vec<usize>,
    /// Each report's silence at a batch of particles (scalar silent
    /// sensors only).
    silences: Vec<[f64; CHUNK]>,
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
    /// A scalar sensor's silence at a batch of states (at most [`CHUNK`];
    /// the lanes past them are not to be read), as
    /// [`ln_likelihood`](Self::ln_likelihood) gives it at each; nothing
    /// for any other report.
    fn ln_silence_batch(
        &self,
        sensors: &[Vec<ObservationModel>],
        rule: &CensoringRule,
        states: &[State],
        out: &mut [f64; CHUNK],
    ) {
        if let Report::Silent {
            sensor,
            g,
            s,
            r,
            vector: None,
        } = self
        {
            let mut mu = [0.0; CHUNK];
            for (m, x) in mu.iter_mut().zip(states) {
                *m = sensors[*sensor][0].mean_and_variance(x).0 - g[0];
            }
            rule.ln_silence_probability_batch(&mu, s[(0, 0)], &[r[(0, 0)]; CHUNK], out);
        }
    }

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
                    let (g, r) = model.mean_and_variance(x);
                    -0.5 * (z[c] - g).powi(2) / r
                })
                .sum(),
            Report::Silent {
                sensor,
                g,
                s,
                r,
                vector: None,
            } => {
                let mu = sensors[*sensor][0].mean_and_variance(x).0 - g[0];
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
                    sensor[0].mean_and_variance(x).0 - g[0],
                    sensor[1].mean_and_variance(x).0 - g[1],
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

/// Each sensor's own filter: with feedback only its covariance (CFwMD
/// normalizes by it), without feedback its estimate too.
struct Sensors {
    mean: Vec<State>,
    cov: Vec<Mat4>,
    /// Without feedback, weighing silence: the joint law of the state and
    /// the sensors' predictions the centre integrates over.
    law: Option<LocalPredictions>,
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
            silent: Vec::with_capacity(setup.sensors.len()),
            silences: Vec::with_capacity(setup.sensors.len()),
        }
    }

    fn run(&mut self, setup: &Setup, budget: &Budget, arm: Arm, trial: u32) -> Trial {
        let rule = &budget.rule;
        let mut rng = ChaCha8Rng::seed_from_u64(SEED ^ ((trial as u64) << 20) ^ table_key(setup));
        // Random selection draws from a stream of its own, so that every
        // arm's truth and noise are the same draws.
        let mut selection_rng = ChaCha8Rng::seed_from_u64(SEED.wrapping_mul(7) ^ trial as u64);
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
        let (feedback, silence, divergence) = match arm {
            Arm::Censored {
                feedback,
                silence,
                rule,
            } => (
                feedback,
                silence,
                match rule {
                    Rule::Nis => None,
                    Rule::Divergence { symmetric } => Some(symmetric),
                },
            ),
            Arm::AllSend | Arm::Random => (Feedback::Estimate, Silence::Ignored, None),
        };
        // The node's posterior (what it feeds back) and each sensor's own filter.
        let (mut estimate, mut estimate_cov) = (setup.prior_mean, setup.prior_cov);
        let mut own = Sensors {
            mean: vec![setup.prior_mean; setup.sensors.len()],
            cov: vec![setup.prior_cov; setup.sensors.len()],
            law: (feedback == Feedback::None && silence == Silence::Weighed)
                .then(|| local_law(setup)),
        };
        let steps = setup.steps as usize;
        let mut out = Trial {
            sent: 0,
            position: Vec::with_capacity(steps),
            velocity: Vec::with_capacity(steps),
            path: Vec::with_capacity(steps),
            disagreements: 0,
            silent_runs: 0,
        };
        let mut silent_before = false;
        let mut silence_rng = ChaCha8Rng::seed_from_u64(SEED.wrapping_add(trial as u64));
        for _ in 0..steps {
            truth = f * truth + q_factor * gaussian(&mut rng);
            self.filter.predict_linear(&f, &q_factor, &mut rng);
            let predicted = f * estimate;
            let predicted_cov = f * estimate_cov * f.transpose() + q;
            if let Some(law) = &mut own.law {
                law.predict();
            }
            self.reports.clear();
            self.silent.clear();
            let sent_before = out.sent;
            for (i, sensor) in setup.sensors.iter().enumerate() {
                // The sensor's prediction, and the covariance it normalizes by.
                let own_predicted = f * own.cov[i] * f.transpose() + q;
                let centre = match feedback {
                    Feedback::None => f * own.mean[i],
                    _ => predicted,
                };
                let cov = match feedback {
                    Feedback::EstimateAndCovariance => predicted_cov,
                    _ => own_predicted,
                };
                let (g, s, r) = innovation_statistics(sensor, &centre, &cov);
                let z = measure_sensor(sensor, &truth, &mut rng);
                let nu = z - g;
                let s_inv = s
                    .try_inverse()
                    .expect("S = G P Gᵀ + R is positive definite");
                let nis = nu.dot(&(s_inv * nu));
                let (sends, disagreed) = decide(
                    arm,
                    budget,
                    divergence,
                    nis,
                    &mut selection_rng,
                    |symmetric| {
                        divergence_sends(
                            setup,
                            sensor,
                            &centre,
                            &cov,
                            rule,
                            s[(0, 0)],
                            z[0],
                            symmetric,
                        )
                    },
                );
                out.disagreements += u32::from(disagreed);
                // The sensor's own filter takes its measurement, sent or not.
                match feedback {
                    Feedback::None => {
                        (own.mean[i], own.cov[i]) = kalman_step(&centre, &own_predicted, sensor, &z)
                    }
                    _ => own.cov[i] = kalman_update(&own_predicted, sensor, &predicted),
                }
                if sends {
                    out.sent += 1;
                    self.reports.push(Report::Received { sensor: i, z });
                    continue;
                }
                self.hear_silence(
                    i,
                    sensor,
                    silence,
                    feedback,
                    rule,
                    (g, s, r),
                    &mut silence_rng,
                );
            }
            let silent_now = out.sent == sent_before;
            out.silent_runs += u32::from(silent_now && silent_before);
            silent_before = silent_now;
            // Without feedback the silences are weighed together: the
            // sensors' predictions, which the centre does not know, are
            // correlated through the state they all track.
            let joint = match (&own.law, self.silent.is_empty()) {
                (Some(law), false) => Some(
                    law.silence(&self.silent, rule, JOINT_SILENCE_DRAWS, &mut silence_rng)
                        .expect("the joint law is positive definite"),
                ),
                _ => None,
            };
            let reports = &self.reports;
            let silences = &mut self.silences;
            silences.resize(reports.len(), [0.0; CHUNK]);
            let active = setup.active();
            self.filter.update_untempered(|particles, out| {
                for (states, out) in particles.chunks(CHUNK).zip(out.chunks_mut(CHUNK)) {
                    // The scalar silences a batch of particles at a time;
                    // each particle then sums its reports in their order.
                    for (report, batch) in reports.iter().zip(silences.iter_mut()) {
                        report.ln_silence_batch(&setup.sensors, rule, states, batch);
                    }
                    for (i, (l, x)) in out.iter_mut().zip(states).enumerate() {
                        *l = reports
                            .iter()
                            .zip(silences.iter())
                            .map(|(report, batch)| match report {
                                Report::Silent { vector: None, .. } => batch[i],
                                _ => report.ln_likelihood(&setup.sensors, rule, x),
                            })
                            .sum();
                        if let Some(joint) = &joint {
                            let mut at = [0.0; 4];
                            for (a, &c) in at.iter_mut().zip(active) {
                                *a = x[c];
                            }
                            *l += joint.ln_probability(&at[..active.len()]);
                        }
                    }
                }
            });
            if let Some(law) = &mut own.law {
                law.update();
            }
            let posterior = self.filter.summary();
            let squared = |first: usize| {
                (first..first + setup.axes)
                    .map(|a| (posterior.mean[a] - truth[a]).powi(2))
                    .sum::<f64>()
            };
            out.position.push(squared(0));
            out.velocity.push(squared(2));
            out.path.push([truth[0], truth[1]]);
            (estimate, estimate_cov) = (posterior.mean, posterior.cov);
            self.filter.resample(&mut rng);
        }
        out
    }
}

/// Whether a sensor with this NIS sends under the arm, and whether a
/// divergence rule (`by_divergence(symmetric)`) decided otherwise than NIS
/// would have.
fn decide(
    arm: Arm,
    budget: &Budget,
    divergence: Option<bool>,
    nis: f64,
    selection_rng: &mut ChaCha8Rng,
    by_divergence: impl FnOnce(bool) -> bool,
) -> (bool, bool) {
    match arm {
        Arm::AllSend => (true, false),
        Arm::Random => (
            selection_rng.random::<f64>() < budget.send_probability,
            false,
        ),
        Arm::Censored { .. } => match divergence {
            None => (budget.rule.sends(nis), false),
            Some(symmetric) => {
                let sends = by_divergence(symmetric);
                (sends, sends != budget.rule.sends(nis))
            }
        },
    }
}

impl TrialFilter {
    /// What the centre makes of a sensor that did not send: nothing
    /// (CFoMD), a silence to weigh alone (with feedback, or knowing the
    /// sensor's prediction), or one of the step's silences weighed together
    /// (without feedback). `(g, s, r)`: the prediction the sensor measured
    /// against, the covariance it normalized by, and its noise.
    #[allow(clippy::too_many_arguments)]
    fn hear_silence(
        &mut self,
        i: usize,
        sensor: &[ObservationModel],
        silence: Silence,
        feedback: Feedback,
        rule: &CensoringRule,
        (g, s, r): (Vector2<f64>, Matrix2<f64>, Matrix2<f64>),
        silence_rng: &mut ChaCha8Rng,
    ) {
        match (silence, feedback) {
            (Silence::Ignored, _) => {}
            (Silence::Weighed, Feedback::None) => self.silent.push(i),
            (Silence::Weighed | Silence::WeighedKnowingPredictions, _) => {
                let vector = (sensor.len() > 1).then(|| {
                    VectorSilence::new(rule, &s, &r, SILENCE_DRAWS, silence_rng)
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
    }
}

/// The joint law of the state and the sensors' own predictions, over the
/// setup's moving components (a linear setup: every sensor's rows are
/// constant).
fn local_law(setup: &Setup) -> LocalPredictions {
    let active = setup.active();
    let pick =
        |m: &Mat4| DMatrix::from_fn(active.len(), active.len(), |i, j| m[(active[i], active[j])]);
    let f = setup.dynamics.jacobian(&State::zeros());
    let (q, _) = setup.process_noise();
    let sensors = setup
        .sensors
        .iter()
        .map(|sensor| {
            let (gain, _, r) = linearize(sensor, &setup.prior_mean);
            let rows = sensor.len();
            let h = DMatrix::from_fn(rows, active.len(), |i, j| gain[(i, active[j])]);
            let r = DMatrix::from_fn(rows, rows, |i, j| r[(i, j)]);
            (h, r)
        })
        .collect();
    LocalPredictions::new(
        pick(&f),
        pick(&q),
        sensors,
        DVector::from_iterator(active.len(), active.iter().map(|&c| setup.prior_mean[c])),
        pick(&setup.prior_cov),
    )
}

/// Whether a scalar sensor sends by the divergence of its Kalman update
/// (eq. 3.29 or 3.35), its threshold the divergence on the NIS boundary
/// `|ν| = √(η s)`: the rule that spends the same budget.
#[allow(clippy::too_many_arguments)]
fn divergence_sends(
    setup: &Setup,
    sensor: &[ObservationModel],
    centre: &State,
    cov: &Mat4,
    rule: &CensoringRule,
    s: f64,
    z: f64,
    symmetric: bool,
) -> bool {
    assert_eq!(
        sensor.len(),
        1,
        "the divergence rule is built for scalar sensors"
    );
    let active = setup.active();
    let (gain, g, r) = linearize(sensor, centre);
    let m = DVector::from_iterator(active.len(), active.iter().map(|&c| centre[c]));
    let p = DMatrix::from_fn(active.len(), active.len(), |i, j| {
        cov[(active[i], active[j])]
    });
    let h = DMatrix::from_fn(1, active.len(), |_, j| gain[(0, active[j])]);
    let r = DMatrix::from_element(1, 1, r[(0, 0)]);
    let divergence = |value: f64| {
        update_divergence(&m, &p, &h, &r, &DVector::from_element(1, value), symmetric)
            .expect("the sensor's covariances are positive definite")
    };
    divergence(z) >= divergence(g[0] + (rule.threshold * s).sqrt())
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

/// A Kalman step of a linear sensor's own filter: the prediction
/// `(m, P)` updated with its measurement.
fn kalman_step(
    m: &State,
    p: &Mat4,
    sensor: &[ObservationModel],
    z: &Vector2<f64>,
) -> (State, Mat4) {
    let (gain, g, r) = linearize(sensor, m);
    let rows = sensor.len();
    let gain = gain.rows(0, rows).into_owned();
    let r = r.view((0, 0), (rows, rows)).into_owned();
    let s = &gain * p * gain.transpose() + r;
    let k = p * gain.transpose() * s.try_inverse().expect("S > 0");
    let innovation = (z - g).rows(0, rows).into_owned();
    let updated = p - &k * &gain * p;
    (m + &k * innovation, 0.5 * (updated + updated.transpose()))
}

/// The sensor's own Kalman (EKF) covariance update, linearized at the fed
/// back prediction, as if it used its measurement every step.
pub(super) fn kalman_update(predicted_cov: &Mat4, sensor: &[ObservationModel], at: &State) -> Mat4 {
    // The covariance does not depend on the measurement.
    kalman_step(at, predicted_cov, sensor, &Vector2::zeros()).1
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
