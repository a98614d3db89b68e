//! What a part is built from ([`Setup`]); how it reads its own parameters,
//! [`Params`], is the scenario's (`fusion_graph::params`), since a law or
//! a motion model reads its own as the scenario is read.

pub use fusion_graph::params::{ParamError, Params};
use fusion_graph::{Scenario, Topology};

/// What a part is built from: the run's scenario and topology, the node
/// it serves, and its own parameters.
pub struct Setup<'a> {
    pub scenario: &'a Scenario,
    pub topology: &'a Topology,
    pub node: u16,
    pub params: Params<'a>,
}

impl<'a> Setup<'a> {
    /// `consensus.rounds`: the rounds a step every protocol of rounds runs
    /// (a part's own parameters are for what only it has).
    pub fn rounds(&self) -> u16 {
        self.scenario.consensus.rounds as u16
    }

    /// `consensus.round_timeout_ms`: how long a round waits for a
    /// neighbour it expects.
    pub fn round_timeout(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.scenario.consensus.round_timeout_ms / 1e3)
    }

    /// The kind the program gave payload `P`; an error, naming it, if the
    /// program did not declare it.
    pub fn payload<P: wire::payloads::ProtocolPayload>(
        &self,
    ) -> Result<wire::payloads::PayloadKind<P>, ParamError> {
        self.scenario
            .vocabulary
            .payloads()
            .of::<P>()
            .ok_or_else(|| ParamError {
                key: "consensus.protocol".into(),
                expected: format!("a program that declares payload {:?}", P::NAME),
                got: "a program without it".into(),
            })
    }
}
