//! The dissertation's three setups of Tables 3.1-3.3, and the two feedback
//! schemes they are run under.

use bounds::dynamics::{CoordinatedTurn, ProcessNoise};
use bounds::{Mat4, ObservationModel, SensorLaw, State};

/// What the node feeds back to its sensors at the start of a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Feedback {
    /// CFwMD: the predicted estimate; each sensor normalizes by its own
    /// Kalman covariance.
    Estimate,
    /// CFwMD2: the predicted estimate and the filter's covariance.
    EstimateAndCovariance,
}

pub(super) const SCHEMES: [Feedback; 2] = [Feedback::Estimate, Feedback::EstimateAndCovariance];

/// One of the dissertation's setups. States are cqnet's `[p_x, p_y, v_x, v_y]`;
/// the one-dimensional setups leave y unobserved.
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
            trials: 100,
            theirs: &[
                (2.0, 1.5978, 1.8970),
                (4.0, 3.3480, 3.8775),
                (6.0, 5.4835, 5.9533),
            ],
        },
    ]
}

impl Setup {
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

pub(super) fn name(scheme: Feedback) -> &'static str {
    match scheme {
        Feedback::Estimate => "CFwMD",
        Feedback::EstimateAndCovariance => "CFwMD2",
    }
}

/// A number of the setup's own, so that its trials draw apart from the others'.
pub(super) fn table_key(setup: &Setup) -> u64 {
    setup
        .table
        .bytes()
        .fold(0, |h, b| h.wrapping_mul(131).wrapping_add(b as u64))
}
