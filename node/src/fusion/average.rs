//! Average consensus with Metropolis weights (math.md, "Average consensus"):
//! `v ← W_ll v + Σ_m W_lm v_m` for N_c rounds; the network sum is N_f times
//! the average, N_f the size of the node's live component.

use std::time::Duration;

use fusion_graph::wire::{Message, Payload};
use fusion_graph::{MetropolisWeights, Topology};

use super::information::InformationPieces;
use super::{Fused, FusionProtocol, Handled, InformationVector, RoundEngine, RoundRule};
use crate::Outgoing;

/// The round rule of average consensus on the information vector.
pub struct Metropolis {
    with_aux: bool,
}

impl RoundRule for Metropolis {
    type Value = InformationVector;
    type Pieces = InformationPieces;

    fn payloads(&self, value: &InformationVector, out: &mut Vec<Payload>) {
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
        for (m, w) in &weights.neighbours {
            let v = &heard
                .iter()
                .find(|(n, _)| n == m)
                .expect("weights only over heard neighbours")
                .1;
            next.add_scaled(*w, v);
        }
        next
    }
}

pub struct AverageConsensus {
    engine: RoundEngine<Metropolis>,
}

impl AverageConsensus {
    /// `rounds` rounds per step, each closing at `round_timeout` with the
    /// neighbours heard; `with_aux` also mixes `S_obs`.
    pub fn new(
        node: u16,
        topology: &Topology,
        rounds: u16,
        round_timeout: Duration,
        with_aux: bool,
    ) -> Self {
        Self {
            engine: RoundEngine::new(
                Metropolis { with_aux },
                node,
                topology,
                rounds,
                round_timeout,
            ),
        }
    }
}

impl FusionProtocol for AverageConsensus {
    type Value = InformationVector;
    type Output = Fused;

    fn expect_step(&mut self, step: u32) {
        self.engine.expect_step(step);
    }

    fn start(
        &mut self,
        step: u32,
        value: InformationVector,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        self.engine.start(step, value, view, now, out);
    }

    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) -> Handled {
        self.engine.handle(message, now, out)
    }

    fn poll_timeout(&self) -> Option<Duration> {
        self.engine.poll_timeout()
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        self.engine.handle_timeout(now, out);
    }

    fn poll_result(&mut self) -> Option<Fused> {
        self.engine.poll_result().map(into_sums)
    }

    fn finish_now(&mut self, now: Duration, out: &mut Vec<Outgoing>) -> Option<Fused> {
        self.engine.finish_now(now, out).map(into_sums)
    }
}

fn into_sums(done: super::RoundsDone<InformationVector>) -> Fused {
    Fused {
        sums: done.value.scaled(done.component_size as f64).to_sums(),
        stats: done.stats,
    }
}
