//! Average consensus with Metropolis weights (docs/equations.md, "Average consensus"):
//! `v ← W_ll v + Σ_m W_lm v_m` for N_c rounds; the network sum is N_f times
//! the average, N_f the size of the node's live component.

use std::time::Duration;

use fusion_graph::{MetropolisWeights, Topology};
use wire::Payload;

use super::information::InformationPieces;
use super::rounds::{weighted, At};
use super::{Fused, InformationVector, RoundEngine, RoundRule, RoundsDone};

/// The round rule of average consensus on the information vector.
pub struct Metropolis {
    with_aux: bool,
}

impl RoundRule for Metropolis {
    type Input = InformationVector;
    type Value = InformationVector;
    type Output = Fused;
    type Pieces = InformationPieces;

    fn begin(&self, _: u32, input: InformationVector) -> InformationVector {
        input
    }

    fn payloads(&self, _: At, value: &InformationVector, out: &mut Vec<Payload>) {
        value.payloads(out);
    }

    fn absorb(&self, pieces: &mut InformationPieces, payload: &Payload) -> bool {
        pieces.absorb(payload)
    }

    fn assemble(&self, pieces: &InformationPieces) -> Option<InformationVector> {
        pieces.assemble(self.with_aux)
    }

    fn combine(
        &self,
        own: &InformationVector,
        heard: &[(u16, InformationVector)],
        weights: &MetropolisWeights,
    ) -> InformationVector {
        let mut next = own.scaled(weights.own);
        for (w, v) in weighted(heard, weights) {
            next.add_scaled(w, v);
        }
        next
    }

    /// The network sums: N_f times the average.
    fn finish(&self, done: RoundsDone<InformationVector>) -> Fused {
        Fused {
            sums: done.value.scaled(done.component_size as f64).to_sums(),
            stats: done.stats,
        }
    }

    fn disagreement(&self, own: &InformationVector, heard: &InformationVector) -> Option<f64> {
        Some(own.disagreement(heard))
    }
}

/// N_c rounds of average consensus on the information vector.
pub type AverageConsensus = RoundEngine<Metropolis>;

/// `rounds` rounds per step, each closing at `round_timeout` with the
/// neighbours heard; `with_aux` also mixes `S_obs`.
pub fn average_consensus(
    node: u16,
    topology: &Topology,
    rounds: u16,
    round_timeout: Duration,
    with_aux: bool,
) -> AverageConsensus {
    RoundEngine::new(
        Metropolis { with_aux },
        node,
        topology,
        rounds,
        round_timeout,
    )
}
