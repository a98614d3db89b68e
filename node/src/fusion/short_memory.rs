//! Average consensus with one round of memory (docs/equations.md, "Short
//! memory"): `x(t+1) = (1 + α) W x(t) − α x(t−1)`, the first round plain,
//! with `α = 2 / (1 + √(1 − λ₂²)) − 1` from the fusion graph's λ₂
//! (Oreshkin, Coates and Rabbat, IEEE Trans. Signal Processing, 2010).
//! Where average consensus leaves λ₂ of the disagreement a round, this
//! leaves about √α: on the 10 × 10 grid 0.82 rather than 0.98, so a
//! hundredth of the disagreement takes about 23 rounds rather than 222.
//!
//! The messages are average consensus's, one value a round: the memory is
//! the node's own last value, kept, never sent. With every neighbour
//! heard the weights are symmetric and doubly stochastic, and the update
//! keeps the network's average (its two terms are averages of averages),
//! so the sums at the end are N_f times the average, as for average
//! consensus.
//!
//! The memory holds only while the round's weights are the last round's:
//! a round that heard a different number of neighbours (a message lost,
//! a neighbour gone quiet) is a plain round, and so is the next, after
//! which the memory is valid again. A step starts without memory, so a
//! restarted node or a new view costs nothing more than average
//! consensus would.

use std::time::Duration;

use fusion_graph::{MetropolisWeights, Topology};
use wire::Payload;

use super::information::InformationPieces;
use super::rounds::{weighted, At};
use super::{Fused, InformationVector, RoundEngine, RoundRule, RoundsDone};

/// A node's value with its memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Remembered {
    pub now: InformationVector,
    /// The value of the round before, and how many neighbours that round
    /// heard; `None` in the first round.
    before: Option<(InformationVector, usize)>,
}

impl Remembered {
    fn fresh(now: InformationVector) -> Self {
        Self { now, before: None }
    }
}

/// The round rule of short-memory consensus on the information vector.
pub struct ShortMemory {
    /// α, in [0, 1).
    alpha: f64,
    with_aux: bool,
}

impl ShortMemory {
    /// One round plain, then `x(t+1) = (1 + alpha) W x(t) − alpha x(t−1)`.
    pub fn new(alpha: f64, with_aux: bool) -> Self {
        Self {
            alpha: alpha.clamp(0.0, 0.999),
            with_aux,
        }
    }
}

impl RoundRule for ShortMemory {
    type Input = InformationVector;
    type Value = Remembered;
    type Output = Fused;
    type Pieces = InformationPieces;

    fn begin(&self, _: u32, input: InformationVector) -> Remembered {
        Remembered::fresh(input)
    }

    fn payloads(&self, _: At, value: &Remembered, out: &mut Vec<Payload>) {
        value.now.payloads(out);
    }

    fn absorb(&self, pieces: &mut InformationPieces, payload: &Payload) -> bool {
        pieces.absorb(payload)
    }

    fn assemble(&self, pieces: &InformationPieces) -> Option<Remembered> {
        pieces.assemble(self.with_aux).map(Remembered::fresh)
    }

    fn combine(
        &self,
        own: &Remembered,
        heard: &[(u16, Remembered)],
        weights: &MetropolisWeights,
    ) -> Remembered {
        let mut mixed = own.now.scaled(weights.own);
        for (w, v) in weighted(heard, weights) {
            mixed.add_scaled(w, &v.now);
        }
        let now = match &own.before {
            Some((before, count)) if *count == heard.len() => {
                let mut next = mixed.scaled(1.0 + self.alpha);
                next.add_scaled(-self.alpha, before);
                next
            }
            // The weights changed: the memory is of another matrix.
            _ => mixed,
        };
        Remembered {
            now,
            before: Some((own.now, heard.len())),
        }
    }

    /// The network sums: N_f times the average.
    fn finish(&self, done: RoundsDone<Remembered>) -> Fused {
        Fused {
            sums: done.value.now.scaled(done.component_size as f64).to_sums(),
            stats: done.stats,
        }
    }

    fn disagreement(&self, own: &Remembered, heard: &Remembered) -> Option<f64> {
        Some(own.now.disagreement(&heard.now))
    }
}

/// Short-memory consensus on the information vector.
pub type ShortMemoryConsensus = RoundEngine<ShortMemory>;

/// `rounds` rounds per step with memory weight `alpha`, each closing at
/// `round_timeout` with the neighbours heard; `with_aux` also mixes
/// `S_obs`.
pub fn short_memory_consensus(
    node: u16,
    topology: &Topology,
    rounds: u16,
    round_timeout: Duration,
    alpha: f64,
    with_aux: bool,
) -> ShortMemoryConsensus {
    RoundEngine::new(
        ShortMemory::new(alpha, with_aux),
        node,
        topology,
        rounds,
        round_timeout,
    )
}
