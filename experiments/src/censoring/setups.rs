//! The dissertation's three setups of Tables 3.1-3.3, and the two feedback
//! schemes they are run under.

use bounds::dynamics::{CoordinatedTurn, ProcessNoise};
use bounds::{Mat4, ObservationModel, SensorLaw, State};

/// What the node feeds back to its sensors at the start of a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Feedback {
    /// Nothing: each sensor runs its own Kalman filter on its own
    /// measurements and censors against its own prediction (Props. 3.3, 3.8).
    None,
    /// CFwMD: the predicted estimate; each sensor normalizes by its own
    /// Kalman covariance.
    Estimate,
    /// CFwMD2: the predicted estimate and the filter's covariance.
    EstimateAndCovariance,
}

/// How the centre reads a sensor that did not send.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Silence {
    /// CFoMD: as if the sensor did not exist this step.
    Ignored,
    /// CFwMD: as a measurement, its likelihood the probability of silence.
    Weighed,
    /// Without feedback, weighed as if the centre knew each sensor's own
    /// prediction: an oracle no centre has, the most a silence can say.
    WeighedKnowingPredictions,
}

/// What a censoring sensor thresholds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Rule {
    /// Its normalized innovation squared, `νᵀ S⁻¹ ν ≥ η` (eq. 3.4).
    Nis,
    /// The divergence of its Kalman update from prior to posterior
    /// (eq. 3.29), or its symmetric sum (eq. 3.35), thresholded at its
    /// value on the NIS boundary: the same budget.
    Divergence { symmetric: bool },
}

/// One arm of the chapter's comparisons: how the sensors choose what to
/// send, and how the centre reads what did not come.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Arm {
    /// Every sensor sends every step.
    AllSend,
    /// Each sensor sends with probability l/N whatever it measured, so
    /// what is missing is missing at random and the centre ignores it.
    Random,
    /// Each sensor censors its measurement.
    Censored {
        feedback: Feedback,
        silence: Silence,
        rule: Rule,
    },
}

impl Arm {
    pub(super) const fn cfwmd(feedback: Feedback) -> Self {
        Arm::Censored {
            feedback,
            silence: Silence::Weighed,
            rule: Rule::Nis,
        }
    }

    pub(super) const fn cfomd(feedback: Feedback) -> Self {
        Arm::Censored {
            feedback,
            silence: Silence::Ignored,
            rule: Rule::Nis,
        }
    }
}

/// The tables' two schemes: CFwMD and CFwMD2.
pub(super) const SCHEMES: [Arm; 2] = [
    Arm::cfwmd(Feedback::Estimate),
    Arm::cfwmd(Feedback::EstimateAndCovariance),
];

/// One of the dissertation's setups. States are cqnet's `[p_x, p_y, v_x, v_y]`;
/// the one-dimensional setups leave y unobserved.
#[derive(Clone)]
pub(super) struct Setup {
    pub(super) table: &'static str,
    pub(super) title: &'static str,
    pub(super) dynamics: CoordinatedTurn,
    /// Each sensor's measurement, one scalar model per component.
    pub(super) sensors: Vec<Vec<ObservationModel>>,
    pub(super) prior_mean: State,
    pub(super) prior_cov: Mat4,
    /// The truth starts at the prior mean (3.1, 3.2) or is drawn from the
    /// prior (3.3).
    pub(super) random_start: bool,
    /// 1: the target moves along x only (y and v_y stay 0); 2: in the plane.
    pub(super) axes: usize,
    pub(super) steps: u32,
    pub(super) particles: usize,
    pub(super) trials: u32,
    /// (l, the dissertation's l̄ for CFwMD, for CFwMD2).
    pub(super) theirs: &'static [(f64, f64, f64)],
}

/// Draws per step for the two-dimensional silence probability (Table 3.2).
pub(super) const SILENCE_DRAWS: usize = 100;
/// Draws per step for the joint silence of sensors without feedback.
pub(super) const JOINT_SILENCE_DRAWS: usize = 200;
pub(super) const SEED: u64 = 3;

pub(super) fn setups() -> Vec<Setup> {
    // 1-D constant velocity along x, D = 1 s, σ² = 4 (§3.7.1).
    let line = CoordinatedTurn {
        process_noise: ProcessNoise::Discrete,
        ..CoordinatedTurn::constant_velocity(1.0, 2.0)
    };
    let position = |r| SensorLaw::Linear {
        h: [1.0, 0.0, 0.0, 0.0],
        r,
    };
    let velocity = |r| SensorLaw::Linear {
        h: [0.0, 0.0, 1.0, 0.0],
        r,
    };
    // The dissertation gives x0 = [0, 10] and no prior; ours is N(x0, I)
    // in (x, ẋ), and y known to be still at 0.
    let line_prior = Mat4::from_diagonal(&State::new(1.0, 1e-9, 1.0, 1e-9));
    // 9 amplitude sensors on a 20 m grid over [−10, 10]² (§3.7.3); the
    // corner layout is ours, the text does not place them.
    let grid: Vec<[f64; 2]> = (0..9)
        .map(|i| [-10.0 + 10.0 * (i % 3) as f64, -10.0 + 10.0 * (i / 3) as f64])
        .collect();
    let amplitude = SensorLaw::Amplitude {
        p0: 1000.0,
        alpha: 1.0,
        exponent: 2.0,
        sigma: 1.0,
    };
    vec![
        Setup {
            table: "3.1",
            title: "1-D, scalar position, N = 4, σ² = 4, r = 1",
            dynamics: line,
            sensors: vec![vec![position(1.0).at([0.0, 0.0])]; 4],
            prior_mean: State::new(0.0, 0.0, 10.0, 0.0),
            prior_cov: line_prior,
            random_start: false,
            axes: 1,
            steps: 20,
            particles: 1000,
            trials: 1000,
            theirs: &[
                (1.0, 1.0625, 1.0530),
                (1.2, 1.1709, 1.2230),
                (1.5, 1.3536, 1.4992),
                (2.0, 1.7399, 2.0002),
                (3.0, 2.7838, 3.0095),
            ],
        },
        Setup {
            table: "3.2",
            title: "1-D, H = I, R = diag(2, 4), N = 4",
            dynamics: line,
            sensors: vec![vec![position(2.0).at([0.0, 0.0]), velocity(4.0).at([0.0, 0.0])]; 4],
            prior_mean: State::new(0.0, 0.0, 10.0, 0.0),
            prior_cov: line_prior,
            random_start: false,
            axes: 1,
            steps: 20,
            particles: 1000,
            trials: 200,
            theirs: &[
                (1.0, 0.9296, 1.0069),
                (2.0, 1.7573, 2.0035),
                (3.0, 2.8029, 3.0151),
            ],
        },
        Setup {
            table: "3.3",
            title: "2-D amplitude, 9 sensors, σ² = 0.1, D = 0.5 s, Np = 10⁴",
            dynamics: CoordinatedTurn {
                process_noise: ProcessNoise::Discrete,
                ..CoordinatedTurn::constant_velocity(0.5, 0.1_f64.sqrt())
            },
            sensors: grid.iter().map(|p| vec![amplitude.at(*p)]).collect(),
            prior_mean: State::new(-8.0, -8.0, 2.0, 2.0),
            prior_cov: Mat4::from_diagonal(&State::new(9.0, 9.0, 4.0, 4.0)),
            random_start: true,
            axes: 2,
            steps: 20,
            particles: 10_000,
            trials: 600,
            theirs: &[
                (2.0, 1.5978, 1.8970),
                (4.0, 3.3480, 3.8775),
                (6.0, 5.4835, 5.9533),
            ],
        },
    ]
}

/// The setups at the experiment's size: run small, a few trials of a few
/// hundred particles each.
pub(super) fn sized_setups(options: &crate::Options) -> Vec<Setup> {
    let mut all = setups();
    if options.small {
        for s in &mut all {
            s.trials = 4;
            s.particles = s.particles.min(300);
        }
    }
    all
}

impl Setup {
    /// The state's components that move: `[p_x, v_x]` on the line, all
    /// four in the plane.
    pub(super) fn active(&self) -> &'static [usize] {
        if self.axes == 1 {
            &[0, 2]
        } else {
            &[0, 1, 2, 3]
        }
    }

    /// Q and its factor, without the y axis's noise when the target moves
    /// along x only.
    pub(super) fn process_noise(&self) -> (Mat4, Mat4) {
        let (mut q, mut factor) = (
            self.dynamics.process_noise(),
            self.dynamics.process_noise_factor(),
        );
        if self.axes == 1 {
            for i in [1, 3] {
                q.row_mut(i).fill(0.0);
                q.column_mut(i).fill(0.0);
                factor.row_mut(i).fill(0.0);
            }
        }
        (q, factor)
    }
}

/// The arm's name as the chapter spells it.
pub(super) fn name(arm: Arm) -> &'static str {
    use {Feedback as F, Rule as R, Silence as S};
    match arm {
        Arm::AllSend => "all-send",
        Arm::Random => "random selection",
        Arm::Censored {
            feedback,
            silence,
            rule,
        } => match (feedback, silence, rule) {
            (F::Estimate, S::Weighed, R::Nis) => "CFwMD",
            (F::EstimateAndCovariance, S::Weighed, R::Nis) => "CFwMD2",
            (F::None, S::Weighed, R::Nis) => "CFwMD without feedback",
            (F::Estimate, S::Ignored, R::Nis) => "CFoMD",
            (F::EstimateAndCovariance, S::Ignored, R::Nis) => "CFoMD, covariance fed back",
            (F::None, S::Ignored, R::Nis) => "CFoMD without feedback",
            (_, S::WeighedKnowingPredictions, R::Nis) => "CFwMD knowing the sensors' predictions",
            (_, _, R::Divergence { symmetric: false }) => "CFwMD by divergence",
            (_, _, R::Divergence { symmetric: true }) => "CFwMD by symmetric divergence",
        },
    }
}

/// A number of the setup's own, so that its trials draw apart from the others'.
pub(super) fn table_key(setup: &Setup) -> u64 {
    setup
        .table
        .bytes()
        .fold(0, |h, b| h.wrapping_mul(131).wrapping_add(b as u64))
}
