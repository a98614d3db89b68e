//! Average consensus on a vector of any length, for the network's sum of
//! it: each round `v ← W_ll v_l + Σ W_lm v_m` with Metropolis weights, and
//! the sum taken as N_f times the result (docs/equations.md, "Average
//! consensus"). A static target's locator sums its nodes'
//! log-likelihoods over a shared grid with it, and their Fisher
//! information.
//!
//! A value longer than one message travels in pieces of
//! [`LOCATION_CHUNK`] numbers, each with its index; a neighbour's value
//! counts for a round once every piece is in.

use std::time::Duration;

use fusion_graph::{MetropolisWeights, Topology};
use wire::{Payload, LOCATION_CHUNK};

use super::rounds::{weighted, At};
use super::{RoundEngine, RoundRule, RoundStats, RoundsDone};

/// The network's sum of the nodes' vectors, as one node's consensus has it.
#[derive(Debug, Clone, PartialEq)]
pub struct Summed {
    pub sums: Vec<f64>,
    /// N_f: the nodes of the live component the sum is over.
    pub component_size: usize,
    pub stats: RoundStats,
}

/// The round rule for vectors of `len` numbers.
pub struct VectorSumRule {
    len: usize,
}

impl VectorSumRule {
    /// The messages one round's value takes.
    pub fn pieces(&self) -> usize {
        self.len.div_ceil(LOCATION_CHUNK)
    }
}

impl RoundRule for VectorSumRule {
    type Input = Vec<f64>;
    type Value = Vec<f64>;
    type Output = Summed;
    /// Each piece once it is in.
    type Pieces = Vec<Option<[f64; LOCATION_CHUNK]>>;

    fn begin(&self, _: u32, input: Vec<f64>) -> Vec<f64> {
        input
    }

    fn payloads(&self, _: At, value: &Vec<f64>, out: &mut Vec<Payload>) {
        for (chunk, part) in value.chunks(LOCATION_CHUNK).enumerate() {
            let mut values = [0.0; LOCATION_CHUNK];
            values[..part.len()].copy_from_slice(part);
            out.push(Payload::LocationConsensus {
                chunk: chunk as u16,
                values,
            });
        }
    }

    fn absorb(&self, pieces: &mut Self::Pieces, payload: &Payload) -> bool {
        let Payload::LocationConsensus { chunk, values } = payload else {
            return false;
        };
        if pieces.is_empty() {
            pieces.resize(self.pieces(), None);
        }
        // A piece past the value's end is not of this rule's vectors: it
        // is dropped, and the value stays incomplete without it.
        if let Some(slot) = pieces.get_mut(*chunk as usize) {
            *slot = Some(*values);
        }
        true
    }

    fn assemble(&self, pieces: &Self::Pieces) -> Option<Vec<f64>> {
        if pieces.len() != self.pieces() {
            return None;
        }
        let mut value = Vec::with_capacity(self.pieces() * LOCATION_CHUNK);
        for piece in pieces {
            value.extend_from_slice(piece.as_ref()?);
        }
        value.truncate(self.len);
        Some(value)
    }

    fn combine(
        &self,
        own: &Vec<f64>,
        heard: &[(u16, Vec<f64>)],
        weights: &MetropolisWeights,
    ) -> Vec<f64> {
        let mut next: Vec<f64> = own.iter().map(|v| v * weights.own).collect();
        for (w, v) in weighted(heard, weights) {
            for (n, x) in next.iter_mut().zip(v) {
                *n += w * x;
            }
        }
        next
    }

    fn finish(&self, done: RoundsDone<Vec<f64>>) -> Summed {
        let n = done.component_size as f64;
        Summed {
            sums: done.value.iter().map(|v| v * n).collect(),
            component_size: done.component_size,
            stats: done.stats,
        }
    }
}

/// Rounds of average consensus on vectors of one length.
pub type VectorSum = RoundEngine<VectorSumRule>;

/// `rounds` rounds a step on vectors of `len` numbers.
pub fn vector_sum(
    node: u16,
    topology: &Topology,
    len: usize,
    rounds: u16,
    round_timeout: Duration,
) -> VectorSum {
    RoundEngine::new(VectorSumRule { len }, node, topology, rounds, round_timeout)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::testing::{drive, Fate};
    use fusion_graph::Scenario;

    /// On the 3 × 3 grid, 200 rounds give every node the network's sum of
    /// vectors 70 long (three pieces, the last partly filled) to 1e-9
    /// relative (40 rounds leave 4e-6).
    #[test]
    fn every_node_reaches_the_network_sum() {
        let s = Scenario::default_scenario();
        let t = Topology::from_scenario(&s, "d").unwrap();
        let n = t.nodes();
        let len = 70;
        let value = |node: u16| -> Vec<f64> {
            (0..len)
                .map(|i| (node as usize * 31 + i * 7) as f64 - 1000.0)
                .collect()
        };
        let expected: Vec<f64> = (0..len)
            .map(|i| (0..n as u16).map(|node| value(node)[i]).sum())
            .collect();
        let protocols: Vec<VectorSum> = (0..n as u16)
            .map(|node| vector_sum(node, &t, len, 200, Duration::from_millis(50)))
            .collect();
        let mut pieces = 0;
        let results = drive(
            protocols,
            value,
            &vec![true; n],
            |_, _, p| {
                assert!(matches!(p, Payload::LocationConsensus { .. }));
                pieces += 1;
                Fate::Deliver(Duration::from_millis(1))
            },
            Duration::from_secs(10),
        );
        // Three pieces a round to each neighbour: 24 directed links.
        assert_eq!(pieces, 3 * 200 * 24);
        for r in results {
            let r = r.expect("finished");
            assert_eq!(r.component_size, n);
            assert_eq!(r.stats.rounds_completed, 200);
            for (got, want) in r.sums.iter().zip(&expected) {
                assert!((got - want).abs() <= 1e-9 * want.abs(), "{got} vs {want}");
            }
        }
    }
}
