//! Sensor managers: which of its sensors a node activates each step
//! (Stone Soup's name for the role). The choice goes out as an activation
//! message, counted like any other, never as a shared random draw.
//!
//! - [`UniformRandom`]: the CQ/dPCRLB paper's policy, uniformly at random within the
//!   node's own sensors, honouring a network-wide cap;
//! - [`Closest`]: the sensors nearest the predicted target, network-wide;
//! - [`PcrlbSelection`]: greedy selection by the conditional PCRLB, or by
//!   Tichavsky's recursion run at the estimate, made once at the centre of
//!   the fusion graph on every node's candidates. It exchanges messages, so it is a protocol the node
//!   drives rather than a [`SensorManager`];
//! - [`OfflinePcrlb`]: greedy on the offline (non-conditional) PCRLB, a
//!   schedule every node computes alike before the run.

mod closest;
mod offline;
mod pcrlb;
mod random;

pub use closest::Closest;
pub use offline::{OfflineError, OfflinePcrlb, OFFLINE_TRAJECTORIES};
pub use pcrlb::{PcrlbSelection, Scoring, Selected, SelectionInputs};
pub use random::UniformRandom;

use fusion_graph::{Scenario, Topology};

use crate::estimator::{FusionFilter, SensingModel};
use crate::fusion::FusionProtocol;
use bounds::BoundError;

use bounds::{Mat4, State};

/// What a node knows when it chooses.
#[derive(Debug, Clone, Copy)]
pub struct SelectionContext<'a> {
    pub step: u32,
    pub node: u16,
    /// The node's own sensors, in increasing order; choices index into it.
    pub own_sensors: &'a [u16],
    /// The live nodes this node can reach (`view[i]` for node i).
    pub view: &'a [bool],
    /// The fusion filter's predicted particles for this step (the global
    /// predictive density), when the manager asked for them with
    /// [`SensorManager::needs_prediction`].
    pub predicted: Option<&'a [State]>,
    /// Every sensor's position, by sensor id.
    pub sensor_positions: &'a [[f64; 2]],
    /// Each node's sensors, by node.
    pub node_sensors: &'a [Vec<u16>],
}

/// How a node chooses its sensors.
pub enum Manager {
    /// On its own, from what it knows.
    Alone(Box<dyn SensorManager>),
    /// With the other nodes, by exchanging messages.
    Negotiated(Box<dyn NegotiatedManager>),
}

/// A sensor manager that chooses with the other nodes, by messages (the
/// PCRLB selection, gathered along a spanning tree, is one): a protocol
/// from what the node's fusion filter knows to the step's choice, which
/// the CF/DPF node runs before it activates its sensors.
pub trait NegotiatedManager: FusionProtocol<Value = SelectionInputs, Output = Selected> {
    /// What the node brings to the step's negotiation, from its fusion
    /// filter (before it predicts) and its sensors' models.
    fn inputs(
        &self,
        fusion: &mut FusionFilter,
        model: &SensingModel,
        own: &[u16],
    ) -> Result<SelectionInputs, BoundError>;
}

impl From<Box<dyn SensorManager>> for Manager {
    fn from(m: Box<dyn SensorManager>) -> Self {
        Manager::Alone(m)
    }
}

impl<M: SensorManager + 'static> From<Box<M>> for Manager {
    fn from(m: Box<M>) -> Self {
        Manager::Alone(m)
    }
}

/// The PCRLB selection scored by `scoring`, for node `node`: greedy, agreed
/// with the other nodes along a spanning tree.
pub fn negotiated(
    scenario: &Scenario,
    topology: &Topology,
    node: u16,
    scoring: Scoring,
) -> Manager {
    // The prior's covariance is diagonal (filter.prior_std, validated
    // positive): its information is the reciprocal diagonal.
    let prior_cov = scenario
        .models()
        .map(|m| m.prior_cov)
        .unwrap_or_else(|_| Mat4::identity());
    let prior_information = Mat4::from_diagonal(&prior_cov.diagonal().map(|v| 1.0 / v));
    Manager::Negotiated(Box::new(PcrlbSelection::for_scenario(
        scenario,
        topology,
        node,
        scoring,
        prior_information,
    )))
}

pub trait SensorManager {
    /// Whether [`choose`](Self::choose) scores candidates on the predicted
    /// particles: the node then predicts before it activates anyone.
    fn needs_prediction(&self) -> bool {
        false
    }

    /// The sensors to activate this step, as increasing positions in
    /// `context.own_sensors`.
    fn choose(&mut self, context: &SelectionContext<'_>) -> Vec<usize>;
}
