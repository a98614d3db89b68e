//! A fusion protocol: `rounds` rounds of plain averaging over each node's
//! closed neighbourhood (itself and the live neighbours heard, all weighed
//! alike), then the network's sums taken as N_f times the result.
//!
//! Unlike Metropolis weights, equal weights are not doubly stochastic, so
//! the nodes do not converge to the network's average: a toy, to show what
//! adding a protocol takes. Its value travels in a message kind of its own.

use std::time::Duration;

use fusion_graph::{MetropolisWeights, WireError};
use node::fusion::{
    Fused, InformationFusion, InformationVector, RoundEngine, RoundRule, RoundsDone,
};
use node::registry::{ParamError, Setup};
use wire::payloads::ProtocolPayload;
use wire::{Packed, Payload};

/// One round's value on the wire: δη, δΛ and ΔL (24 numbers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeighbourhoodValue {
    pub delta_eta: [f64; 4],
    pub delta_lambda: Packed,
    pub delta_l: Packed,
}

impl ProtocolPayload for NeighbourhoodValue {
    const KIND: u8 = 200;
    const NAME: &'static str = "neighbourhood_mean";
    const LEN: usize = 24 * 8;
    /// ΔL, 10 numbers of the 24: what the bound is computed from.
    const BOUND_BYTES: usize = 10 * 8;

    fn encode(&self, out: &mut Vec<u8>) {
        let numbers = self
            .delta_eta
            .iter()
            .chain(&self.delta_lambda)
            .chain(&self.delta_l);
        for v in numbers {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }

    fn decode(body: &[u8]) -> Result<Self, WireError> {
        let mut numbers = [0.0; 24];
        for (v, bytes) in numbers.iter_mut().zip(body.chunks_exact(8)) {
            *v = f64::from_le_bytes(bytes.try_into().map_err(|_| WireError::Truncated)?);
            if !v.is_finite() {
                return Err(WireError::NonFinite);
            }
        }
        Ok(Self {
            delta_eta: numbers[..4].try_into().expect("4"),
            delta_lambda: numbers[4..14].try_into().expect("10"),
            delta_l: numbers[14..].try_into().expect("10"),
        })
    }
}

/// The round rule: the mean of the closed neighbourhood's values.
pub struct NeighbourhoodMean;

impl RoundRule for NeighbourhoodMean {
    type Value = InformationVector;
    type Output = Fused;
    type Pieces = Option<InformationVector>;

    fn payloads(&self, v: &InformationVector, out: &mut Vec<Payload>) {
        let value = NeighbourhoodValue {
            delta_eta: v.delta_eta,
            delta_lambda: v.delta_lambda,
            delta_l: v.delta_l,
        };
        out.push(value.to_payload());
    }

    fn absorb(&self, pieces: &mut Option<InformationVector>, payload: &Payload) -> bool {
        let Some(v) = NeighbourhoodValue::from_payload(payload) else {
            return false;
        };
        *pieces = Some(InformationVector {
            delta_eta: v.delta_eta,
            delta_lambda: v.delta_lambda,
            delta_l: v.delta_l,
            // A toy: it does not carry ΔL_late, so its bound does not
            // credit observations that arrive a step late.
            delta_l_late: [0.0; 10],
            s_obs: None,
        });
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
        // Its payload has no ΔL_late (see `absorb`): none of it is mixed.
        next.delta_l_late = [0.0; 10];
        next
    }

    fn finish(&self, done: RoundsDone<InformationVector>) -> Fused {
        Fused {
            sums: done.value.scaled(done.component_size as f64).to_sums(),
            stats: done.stats,
        }
    }
}

/// `consensus.params.rounds` (1 to 50, default 1); each round closes at the
/// scenario's `consensus.round_timeout_ms`.
pub fn build(setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
    let params = setup.params;
    params.only(&["rounds"])?;
    let rounds = params.integer("rounds", 1..=50, 1)?;
    if setup.scenario.consensus.auxiliary_fim {
        return Err(ParamError {
            key: "consensus.auxiliary_fim".into(),
            expected: "false: neighbourhood_mean carries no S_obs".into(),
            got: "true".into(),
        });
    }
    let timeout = Duration::from_secs_f64(setup.scenario.consensus.round_timeout_ms / 1e3);
    Ok(Box::new(RoundEngine::new(
        NeighbourhoodMean,
        setup.node,
        setup.topology,
        rounds as u16,
        timeout,
    )))
}
