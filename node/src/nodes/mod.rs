//! The processing nodes, by kind: the CF/DPF node ([`CfDpfNode`]), the
//! random-exchange paper's trackers ([`TrackerNode`](trackers::TrackerNode)), a static target's
//! locator ([`LocatorNode`](locator::LocatorNode)), as the scenario's `consensus.protocol` says,
//! or a fusion centre behind a multiple-access channel ([`MacCentre`]),
//! when the scenario has one. What every kind shares (the step guard, the
//! membership view, late and overrun bookkeeping, activation and
//! collection, the report) is the [`NodeCore`] each holds; a kind holds
//! only its algorithm beside it. A kind is a [`NodeKind`]; made a
//! [`ProcessingNode`], it is an [`Actor`] and a [`Node`], and the drivers
//! hold any of them as an [`AnyNode`].

pub mod cfdpf;
pub mod core;
pub mod locator;
pub mod mac_centre;
pub mod report;
pub mod trackers;

pub use self::core::{NodeCore, NodeKind, ProcessingNode};
pub use report::Report;

use std::time::Duration;

use fusion_graph::{Scenario, Topology};

use crate::{Actor, CfDpfNode, MacCentre, NodeError, Work};

/// What a processing node is beyond an actor of the network (every
/// [`NodeKind`] is one).
pub trait Node: Actor<Work = Work> {
    /// Between steps: nothing collected, fused or waiting.
    fn is_idle(&mut self) -> bool;
}

/// A processing node of any kind.
pub type AnyNode = Box<dyn Node>;

/// How a node process starts, beside what the scenario says.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Start {
    /// Started in the middle of a run (a restart): a CF/DPF node rejoins
    /// from a neighbour's fused posterior. A random-exchange node starts
    /// from the prior and is pulled back by its exchanges or fusion.
    pub rejoin: bool,
    /// In real time, the step's period: a CF/DPF node closes its waiting
    /// stages in time for it ([`CfDpfNode::bound_steps_by`]). The trackers
    /// bound their steps by their own listening windows.
    pub step_period: Option<Duration>,
}

/// Node `index` as the scenario describes it.
pub fn processing_node(
    scenario: &Scenario,
    topology: &Topology,
    index: u16,
    start: Start,
) -> Result<AnyNode, NodeError> {
    if scenario.channel.is_some() {
        let centre = MacCentre::new(scenario, topology, index)?;
        return Ok(Box::new(ProcessingNode::new(centre)));
    }
    if let Some(node) = crate::parts::node_of_its_own(scenario, topology, index, start)? {
        return Ok(node);
    }
    let node = CfDpfNode::new(scenario, topology, index)?;
    Ok(Box::new(ProcessingNode::new(node.starting(start))))
}
