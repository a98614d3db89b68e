//! A processing node of any kind, behind one face for the drivers: the
//! CF/DPF node ([`NodeActor`]), one of the random-exchange paper's trackers
//! ([`DiffusionNode`]), a static target's locator ([`LocatorNode`]), as
//! the scenario's `consensus.protocol` says, or a fusion centre behind a
//! multiple-access channel ([`MacCentre`]), when the scenario has one.

use std::time::Duration;

use fusion_graph::Channel;
use fusion_graph::{ActorId, Scenario, Topology};
use wire::Message;

use crate::diffusion_node::DiffusionNode;
use crate::{LocatorNode, MacCentre, NodeActor, NodeError, Outgoing, Work};
use fusion_graph::registered::Shape;

pub enum ProcessingNode {
    CfDpf(Box<NodeActor>),
    Diffusion(Box<DiffusionNode>),
    Locator(Box<LocatorNode>),
    MacCentre(Box<MacCentre>),
}

impl From<MacCentre> for ProcessingNode {
    fn from(n: MacCentre) -> Self {
        Self::MacCentre(Box::new(n))
    }
}

impl From<LocatorNode> for ProcessingNode {
    fn from(n: LocatorNode) -> Self {
        Self::Locator(Box::new(n))
    }
}

impl From<NodeActor> for ProcessingNode {
    fn from(n: NodeActor) -> Self {
        Self::CfDpf(Box::new(n))
    }
}

impl From<DiffusionNode> for ProcessingNode {
    fn from(n: DiffusionNode) -> Self {
        Self::Diffusion(Box::new(n))
    }
}

/// Forwards a call to whichever node this is.
macro_rules! either {
    ($self:ident, $n:ident => $call:expr) => {
        match $self {
            ProcessingNode::CfDpf($n) => $call,
            ProcessingNode::Diffusion($n) => $call,
            ProcessingNode::Locator($n) => $call,
            ProcessingNode::MacCentre($n) => $call,
        }
    };
}

impl ProcessingNode {
    /// The node the scenario describes.
    pub fn for_scenario(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
    ) -> Result<Self, NodeError> {
        if scenario.channel.is_some() {
            return MacCentre::new(scenario, topology, index).map(Self::from);
        }
        if scenario.consensus.protocol.shape() == Shape::Locator {
            let config = crate::registry::location_config(scenario)?;
            return LocatorNode::new(scenario, topology, index, config).map(Self::from);
        }
        if let Some(cooperation) = crate::registry::cooperation(scenario, topology, index)? {
            DiffusionNode::new(scenario, topology, index, cooperation).map(Self::from)
        } else {
            NodeActor::new(scenario, topology, index).map(Self::from)
        }
    }

    pub fn id(&self) -> ActorId {
        either!(self, n => n.id())
    }

    /// Marks a node started in the middle of a run. A CF/DPF node rejoins
    /// from a neighbour's fused posterior; a random-exchange node starts from the
    /// prior and is pulled back by its exchanges or fusion.
    pub fn expect_rejoin(&mut self) {
        if let ProcessingNode::CfDpf(n) = self {
            n.expect_rejoin()
        }
    }

    /// Bounds each step's waiting stages by its period, as real time
    /// needs ([`NodeActor::bound_steps_by`]). The random-exchange trackers
    /// bound their steps by their own listening windows and ignore it.
    pub fn bound_steps_by(&mut self, period: Duration) {
        if let ProcessingNode::CfDpf(n) = self {
            n.bound_steps_by(period)
        }
    }

    pub fn subscriptions(&self) -> Vec<Channel> {
        either!(self, n => n.subscriptions())
    }

    pub fn publications(&self) -> Vec<Channel> {
        either!(self, n => n.publications())
    }

    pub fn peers(&self) -> Vec<ActorId> {
        either!(self, n => n.peers())
    }

    pub fn is_idle(&self) -> bool {
        either!(self, n => n.is_idle())
    }

    pub fn late_messages(&self) -> u64 {
        either!(self, n => n.late_messages())
    }

    pub fn poll_timeout(&self) -> Option<Duration> {
        either!(self, n => n.poll_timeout())
    }

    pub fn poll_work(&self) -> Option<Work> {
        either!(self, n => n.poll_work())
    }

    pub fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        either!(self, n => n.handle(message, now, out))
    }

    pub fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        either!(self, n => n.handle_timeout(now, out))
    }

    pub fn run_work(&mut self, work: Work) {
        either!(self, n => n.run_work(work))
    }

    pub fn work_done(
        &mut self,
        work: Work,
        elapsed: Duration,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        either!(self, n => n.work_done(work, elapsed, now, out))
    }
}
