//! Min-consensus (docs/equations.md, "Average and min consensus"): `v ← min over the closed
//! neighbourhood`. After as many rounds as the fusion graph's diameter every
//! node of a connected component holds its smallest proposal. Sensor
//! selection (the selection paper) agrees on the network's best (node, sensor) with it.

use std::cmp::Ordering;
use std::time::Duration;

use fusion_graph::wire::{Payload, Proposal};
use fusion_graph::{MetropolisWeights, Topology};

use super::{RoundEngine, RoundRule, RoundsDone};

/// Smallest cost first; ties to the smaller node, then the smaller sensor:
/// the order of [`bounds::selection::proposal_order`], so that the
/// distributed selection agrees with the greedy reference.
pub fn proposal_order(a: &Proposal, b: &Proposal) -> Ordering {
    bounds::selection::proposal_order((a.cost, a.node, a.sensor), (b.cost, b.node, b.sensor))
}

pub struct Minimum;

impl RoundRule for Minimum {
    type Value = Proposal;
    type Output = Proposal;
    type Pieces = Option<Proposal>;

    fn payloads(&self, value: &Proposal, out: &mut Vec<Payload>) {
        out.push(Payload::MinConsensus(*value));
    }

    fn absorb(&self, pieces: &mut Option<Proposal>, payload: &Payload) -> bool {
        match payload {
            Payload::MinConsensus(p) => {
                *pieces = Some(*p);
                true
            }
            _ => false,
        }
    }

    fn assemble(&self, pieces: &Option<Proposal>) -> Option<Proposal> {
        *pieces
    }

    fn combine(
        &self,
        own: &Proposal,
        heard: &[(u16, Proposal)],
        _weights: &MetropolisWeights,
    ) -> Proposal {
        heard.iter().map(|(_, p)| *p).fold(*own, |best, p| {
            if proposal_order(&p, &best) == Ordering::Less {
                p
            } else {
                best
            }
        })
    }

    fn finish(&self, done: RoundsDone<Proposal>) -> Proposal {
        done.value
    }
}

/// Min-consensus on proposals.
pub type MinConsensus = RoundEngine<Minimum>;

/// `rounds` should be at least the fusion graph's diameter.
pub fn min_consensus(
    node: u16,
    topology: &Topology,
    rounds: u16,
    round_timeout: Duration,
) -> MinConsensus {
    RoundEngine::new(Minimum, node, topology, rounds, round_timeout)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::FusionProtocol;
    use fusion_graph::{ActorId, Scenario};

    /// Three nodes in a line, each proposing; messages carried at once.
    fn agree(costs: [f64; 3], view: [bool; 3], rounds: u16) -> Vec<Option<Proposal>> {
        let s = Scenario::from_toml(crate::harness::LINE, "line", &[]).unwrap();
        let t = Topology::from_scenario(&s, "line").unwrap();
        let mut nodes: Vec<MinConsensus> = (0..3)
            .map(|i| min_consensus(i, &t, rounds, Duration::from_millis(50)))
            .collect();
        let mut queue = Vec::new();
        for i in 0..3u16 {
            if view[i as usize] {
                let p = Proposal {
                    cost: costs[i as usize],
                    node: i,
                    sensor: 10 + i,
                    information: [i as f64; 3],
                };
                nodes[i as usize].start(1, p, &view, Duration::ZERO, &mut queue);
            }
        }
        while let Some(o) = queue.pop() {
            for to in o.receivers {
                // Outside the view is dead or across a partition: never handled.
                let ActorId::Node(n) = to else { continue };
                if !view[n as usize] {
                    continue;
                }
                let mut out = Vec::new();
                nodes[n as usize].handle(&o.message, Duration::ZERO, &mut out);
                queue.extend(out);
            }
        }
        nodes.iter_mut().map(|n| n.poll_result()).collect()
    }

    #[test]
    fn reaches_the_network_minimum_in_diameter_rounds() {
        // Node 0's proposal must cross two links to reach node 2.
        let got = agree([1.0, 3.0, 2.0], [true; 3], 2);
        assert!(
            got.iter()
                .all(|p| p.is_some_and(|p| p.node == 0 && p.cost == 1.0)),
            "{got:?}"
        );
        // One round is not enough: node 2 has heard only node 1 and keeps its own.
        let short = agree([1.0, 3.0, 2.0], [true; 3], 1);
        assert_eq!(short[2].unwrap().node, 2);
    }

    #[test]
    fn after_a_node_dies_the_survivors_agree_on_their_own_minimum() {
        let got = agree([1.0, 3.0, 2.0], [false, true, true], 2);
        assert!(got[0].is_none());
        assert!(
            got[1..].iter().all(|p| p.is_some_and(|p| p.node == 2)),
            "{got:?}"
        );
    }

    #[test]
    fn ties_go_to_the_smaller_node() {
        let got = agree([2.0, 2.0, 2.0], [true; 3], 2);
        assert!(got.iter().all(|p| p.is_some_and(|p| p.node == 0)));
    }
}
