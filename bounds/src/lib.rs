//! The estimation mathematics of cqnet. No I/O, no clocks, no processes.
//!
//! - [`dynamics`]: the clockwise coordinated turn (and constant velocity),
//!   its Jacobian and process noise;
//! - [`observation`]: bearing, RSS, amplitude and linear observation models;
//! - [`quantizer`]: N_L-bit quantizers, cell probabilities far into the tails,
//!   encoding to bytes;
//! - [`fisher`]: Fisher information of raw and quantized observations, and the
//!   observed information at a received cell;
//! - [`pcrlb`]: the conditional PCRLB recursion over particles, shared by the
//!   local bound, the distributed CQ/dPCRLB and the auxiliary-FIM baseline,
//!   plus the non-conditional PCRLB by Monte Carlo;
//! - [`selection`]: the PCRLB cost of a set of active sensors and the
//!   greedy choice of the selection paper;
//! - [`compressive`]: sensor management by compressive sensing over a
//!   multiple-access channel: the sensing matrix, the likelihood of what
//!   the channel delivers, the transmission probabilities that maximize
//!   `det J` (dissertation ch. 4);
//! - [`censoring`]: the NIS censoring rule at a sensor and the likelihood
//!   of its silence (dissertation ch. 3);
//! - [`local_predictions`]: censoring without feedback: the joint law of
//!   the state and the sensors' own Kalman predictions, the likelihood of
//!   silences under it, and the divergence metric of the information
//!   rule (dissertation ch. 3);
//! - [`bit_allocation`]: quantized data fused with injected noise, and the
//!   allocation of a budget of bits over sensors (dissertation ch. 5);
//! - [`speb`]: the bit-depth paper's squared position error bound, information
//!   against the delay of a rate-limited link;
//! - [`location`]: a static target's position from quantized amplitudes,
//!   its exact and closed-form CRLB and the thresholds that serve them
//!   (dissertation ch. 6);
//! - [`ungm`]: the offline, conditional and A-conditional PCRLB of a scalar
//!   state on the univariate non-stationary growth model (dissertation
//!   ch. 7).

pub mod batch;
pub mod bit_allocation;
pub mod cell_sums;
pub mod censoring;
pub mod chacha;
pub mod compressive;
pub mod diffusion;
pub mod dynamics;
pub mod fisher;
pub mod fisher_table;
pub mod local_predictions;
pub mod location;
pub mod mass_table;
pub mod normal;
pub mod observation;
pub mod pcrlb;
pub mod quantizer;
pub mod selection;
pub mod shared_rows;
pub mod speb;
pub mod table_memory;
pub mod ungm;
pub mod width_axis;
pub mod wrapped_table;
mod ziggurat_tables;

#[cfg(test)]
mod testing;

pub use dynamics::{CoordinatedTurn, Dynamics, Motion, MotionModel, ProcessNoise};
pub use fisher::{expected_information, observed_information, Measurement};
pub use observation::{wrap_angle, Law, ObservationLaw, ObservationModel, SensorLaw};
pub use pcrlb::{position_bound, ConditionalBound, DynamicsTerms, InformationStep, SensorTerm};
pub use quantizer::{quantized_fisher_information, try_quantized_fisher_information, Quantizer};

/// `x` modulo `p > 0`, in `[0, p)`: `rem_euclid` without `fmod`, which
/// this target compiles to a bit-by-bit software loop (4 % of a `sim` run in
/// the profile, from the angle wrap and the Fisher table's lookup). Within
/// an ulp of `x` of the exact remainder.
#[inline]
pub(crate) fn modulo(x: f64, p: f64) -> f64 {
    let r = x - floor(x / p) * p;
    if r >= p {
        r - p
    } else if r < 0.0 {
        r + p
    } else {
        r
    }
}

/// `⌊x⌋`, as `f64::floor`, which on this target (x86-64 before SSE4.1 has
/// no rounding instruction) is a call into a software routine; two
/// conversions and a compare do it inline.
#[inline]
pub(crate) fn floor(x: f64) -> f64 {
    // From 2⁵² on every f64 is an integer; this also passes NaN and ±∞.
    if x.is_nan() || x.abs() >= 4_503_599_627_370_496.0 {
        return x;
    }
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// The target state `[p_x, p_y, v_x, v_y]ᵀ`, metres and metres per second.
pub type State = nalgebra::SVector<f64, 4>;
/// A 4×4 matrix over the state: covariances, information matrices, Jacobians.
pub type Mat4 = nalgebra::SMatrix<f64, 4, 4>;

/// A Gaussian over the state: a prior, or a particle set's summary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gaussian {
    pub mean: State,
    pub cov: Mat4,
}

/// A model parameter out of its range: what the scenario must name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{parameter}` must be {expected}, got {value}")]
pub struct ParameterError {
    /// The parameter's name, as a scenario file spells it.
    pub parameter: &'static str,
    pub expected: &'static str,
    pub value: f64,
}

/// Invalid quantizer parameters or encoded cell indices.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum QuantizerError {
    #[error("quantizer bits must be between 1 and {max}, got {bits}", max = quantizer::MAX_BITS)]
    BitsOutOfRange { bits: u64 },
    #[error("quantizer range must be finite with lo < hi, got [{lo}, {hi}]")]
    EmptyRange { lo: f64, hi: f64 },
    #[error("a quantizer needs at least one threshold")]
    NoThresholds,
    #[error("threshold {index} is not finite")]
    NonFiniteThreshold { index: usize },
    #[error("threshold {index} is not greater than the one before it")]
    ThresholdsNotIncreasing { index: usize },
    #[error("sigma must be finite and positive, got {sigma}")]
    BadSigma { sigma: f64 },
    #[error("encoded cell index has {got} bytes, expected {expected}")]
    WrongLength { expected: usize, got: usize },
    #[error("cell index {index} is out of range for {cells} cells")]
    IndexOutOfRange { index: u32, cells: usize },
}

/// A bound recursion that cannot proceed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoundError {
    #[error("no particles")]
    NoParticles,
    #[error("{particles} particles but {weights} weights")]
    WeightCount { particles: usize, weights: usize },
    #[error("{0} is not positive definite")]
    NotPositiveDefinite(&'static str),
    #[error("the information matrix is not finite")]
    NonFinite,
    #[error("{sensors} sensors but {nodes} neighbourhoods")]
    NeighbourhoodCount { sensors: usize, nodes: usize },
    #[error("{sensors} sensors but {probabilities} activation probabilities")]
    ActivationCount {
        sensors: usize,
        probabilities: usize,
    },
    #[error("scoring by the auxiliary FIM, but the filter carries none (consensus.auxiliary_fim = false)")]
    NoAuxiliaryFim,
}

#[cfg(test)]
mod tests {
    /// `modulo` is `rem_euclid` to within rounding, always in `[0, p)`,
    /// across magnitudes and signs (angles of a few turns, cell offsets of
    /// thousands of cells).
    #[test]
    fn floor_is_std_floor() {
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.999_999,
            -2.000_001,
            1e15 + 0.5,
            -1e15 - 0.5,
            4.6e18,
            -4.6e18,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            assert_eq!(super::floor(x), x.floor(), "floor({x})");
        }
        assert!(super::floor(f64::NAN).is_nan());
    }

    #[test]
    fn modulo_is_rem_euclid_within_rounding() {
        let periods = [1.0, 2.0 * std::f64::consts::PI, 0.3];
        let mut x = -5_000.123_456_789_f64;
        while x < 5000.0 {
            for p in periods {
                let got = super::modulo(x, p);
                let exact = x.rem_euclid(p);
                assert!((0.0..p).contains(&got), "{x} mod {p} = {got}");
                let gap = (got - exact).abs().min(p - (got - exact).abs());
                assert!(
                    gap <= 4.0 * f64::EPSILON * x.abs().max(p),
                    "{x} mod {p}: {got} vs {exact}"
                );
            }
            x += 0.987_654_321;
        }
        assert_eq!(super::modulo(-0.0, 1.0), 0.0);
        // rem_euclid gives 1.0 here, outside [0, 1).
        assert!((0.0..1.0).contains(&super::modulo(-1e-300, 1.0)));
    }
}
