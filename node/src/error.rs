//! Why a node cannot be built.

use bounds::BoundError;
use fusion_graph::scenario::ConsensusProtocol;
use fusion_graph::ScenarioError;

/// A node that cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error("node-{node}: {source}")]
    Filter { node: u16, source: BoundError },
    #[error("the centralized reference: {0}")]
    Reference(BoundError),
    #[error(
        "consensus.protocol \"{}\" is one of the random-exchange and KL trackers, not the CF/DPF",
        .0.name()
    )]
    NotCfDpf(ConsensusProtocol),
    #[error(transparent)]
    Param(#[from] crate::parts::ParamError),
    #[error("consensus.protocol = \"exact\" needs the exact-sum oracle of one process (`cqnet sim`): real processes have no exact network sum")]
    NoExactSums,
}
