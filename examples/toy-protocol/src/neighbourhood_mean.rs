//! A fusion protocol: `rounds` rounds of plain averaging over each node's
//! closed neighbourhood (itself and the live neighbours heard, all weighed
//! alike), then the network's sums taken as N_f times the result.
//!
//! Unlike Metropolis weights, equal weights are not doubly stochastic, so
//! the nodes do not converge to the network's average: a toy, to show what
//! adding a protocol takes. Its value travels in a message kind of its own.

use fusion_graph::{MetropolisWeights, WireError};
use node::fusion::{
    At, Fused, InformationFusion, InformationVector, RoundEngine, RoundRule, RoundsDone,
};
use node::parts::{ParamError, Setup};
use wire::payloads::{finite_numbers, put_numbers, PayloadKind, ProtocolPayload};
use wire::{Packed, Payload};

/// One round's value on the wire: δη, δΛ and ΔL (24 numbers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeighbourhoodValue {
    pub delta_eta: [f64; 4],
    pub delta_lambda: Packed,
    pub delta_l: Packed,
}

impl ProtocolPayload for NeighbourhoodValue {
    const NAME: &'static str = "neighbourhood_mean";
    const LEN: usize = 24 * 8;
    /// ΔL, 10 numbers of the 24: what the bound is computed from.
    const BOUND_BYTES: usize = 10 * 8;

    fn encode(&self, out: &mut Vec<u8>) {
        let v = self;
        put_numbers(
            v.delta_eta.iter().chain(&v.delta_lambda).chain(&v.delta_l),
            out,
        );
    }

    fn decode(body: &[u8]) -> Result<Self, WireError> {
        let numbers: [f64; 24] = finite_numbers(body)?;
        Ok(Self {
            delta_eta: numbers[..4].try_into().expect("4"),
            delta_lambda: numbers[4..14].try_into().expect("10"),
            delta_l: numbers[14..].try_into().expect("10"),
        })
    }
}

/// The round rule: the mean of the closed neighbourhood's values. It
/// carries the estimate's parts and ΔL only; the node hands it vectors
/// without ΔL_late, and refuses the auxiliary FIM for it.
pub struct NeighbourhoodMean {
    /// The kind the program gave [`NeighbourhoodValue`].
    kind: PayloadKind<NeighbourhoodValue>,
}

impl RoundRule for NeighbourhoodMean {
    type Input = InformationVector;
    type Value = InformationVector;
    type Output = Fused;
    type Pieces = Option<InformationVector>;

    fn begin(&self, _: u32, input: InformationVector) -> InformationVector {
        input
    }

    fn payloads(&self, _: At, v: &InformationVector, out: &mut Vec<Payload>) {
        let value = NeighbourhoodValue {
            delta_eta: v.delta_eta,
            delta_lambda: v.delta_lambda,
            delta_l: v.delta_l,
        };
        out.push(self.kind.payload(&value));
    }

    fn absorb(&self, pieces: &mut Option<InformationVector>, payload: &Payload) -> bool {
        let Some(v) = self.kind.read(payload) else {
            return false;
        };
        *pieces = Some(InformationVector::new(
            v.delta_eta,
            v.delta_lambda,
            v.delta_l,
        ));
        true
    }

    fn assemble(&self, pieces: &Option<InformationVector>) -> Option<InformationVector> {
        *pieces
    }

    fn combine(
        &self,
        own: &InformationVector,
        heard: &[(u16, InformationVector)],
        _: &MetropolisWeights,
    ) -> InformationVector {
        let w = 1.0 / (1 + heard.len()) as f64;
        let mut next = own.scaled(w);
        for (_, v) in heard {
            next.add_scaled(w, v);
        }
        next
    }

    fn finish(&self, done: RoundsDone<InformationVector>) -> Fused {
        Fused {
            sums: done.value.scaled(done.component_size as f64).to_sums(),
            stats: done.stats,
        }
    }
}

/// `consensus.rounds` rounds a step, each closing at the scenario's
/// `consensus.round_timeout_ms`; no parameters of its own.
pub fn build(setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
    setup.params.only(&[])?;
    let rule = NeighbourhoodMean {
        kind: setup.payload::<NeighbourhoodValue>()?,
    };
    Ok(Box::new(RoundEngine::new(
        rule,
        setup.node,
        setup.topology,
        setup.rounds(),
        setup.round_timeout(),
    )))
}
