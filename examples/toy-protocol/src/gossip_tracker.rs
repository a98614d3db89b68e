//! A tracker of our own: the random-exchange paper's tracker node (one
//! particle filter per node, weighed with its closed neighbourhood's
//! measurements, summarized as a Gaussian), whose posteriors are fused by
//! push-sum gossip on their natural parameters rather than by KL fusion's
//! Metropolis rounds.
//!
//! Push-sum on (Λμ, Λ) with weights converges to the network's average of
//! the natural parameters, the same point KL fusion's consensus reaches,
//! but each round a node sends to one neighbour only, over the pair's
//! channel. The weighing and the adoption of the fused Gaussian are
//! cqnet's ([`KlCooperation`] around our protocol); the fusion is ours, the
//! same push-sum rule as the CF/DPF's ([`Gossip`]) on another [`Mass`].

use fusion_graph::vocabulary::Shape;
use fusion_graph::WireError;
use node::fusion::{KlFused, NaturalGaussian, RoundEngine, RoundsDone};
use node::nodes::trackers::KlCooperation;
use node::parts::{BuildNode, Setup};
use node::{AnyNode, NodeError, ProcessingNode, Start, TrackerNode};
use wire::payloads::{finite_numbers, put_numbers, ProtocolPayload};
use wire::{pack_mat4, unpack_mat4};

use crate::push_sum::{Gossip, Mass};

/// Half a node's natural parameters and weight, on their way to one
/// neighbour: Λμ (4), Λ's upper triangle (10) and the weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PosteriorShare {
    pub eta: [f64; 4],
    pub lambda: [f64; 10],
    pub weight: f64,
}

impl ProtocolPayload for PosteriorShare {
    const NAME: &'static str = "posterior_share";
    const LEN: usize = 15 * 8;

    fn encode(&self, out: &mut Vec<u8>) {
        put_numbers(
            self.eta.iter().chain(&self.lambda).chain([&self.weight]),
            out,
        );
    }

    fn decode(body: &[u8]) -> Result<Self, WireError> {
        let n: [f64; 15] = finite_numbers(body)?;
        if n[14] <= 0.0 {
            return Err(WireError::NonFinite);
        }
        Ok(Self {
            eta: n[..4].try_into().expect("4"),
            lambda: n[4..14].try_into().expect("10"),
            weight: n[14],
        })
    }
}

impl Mass for PosteriorShare {
    fn halved(&self) -> Self {
        Self {
            eta: self.eta.map(|x| x / 2.0),
            lambda: self.lambda.map(|x| x / 2.0),
            weight: self.weight / 2.0,
        }
    }

    fn add(&mut self, other: &Self) {
        for (a, b) in self.eta.iter_mut().zip(&other.eta) {
            *a += b;
        }
        for (a, b) in self.lambda.iter_mut().zip(&other.lambda) {
            *a += b;
        }
        self.weight += other.weight;
    }
}

/// The step's posterior in natural parameters, weight 1.
fn begin(g: NaturalGaussian) -> PosteriorShare {
    PosteriorShare {
        eta: g.eta.into(),
        lambda: pack_mat4(&g.lambda),
        weight: 1.0,
    }
}

/// The network's average of the natural parameters, x / w.
fn end(done: RoundsDone<PosteriorShare>) -> KlFused {
    let v = done.value;
    let w = v.weight;
    KlFused {
        fused: NaturalGaussian {
            eta: v.eta.map(|x| x / w).into(),
            lambda: unpack_mat4(&v.lambda.map(|x| x / w)),
        },
        stats: done.stats,
    }
}

/// `consensus.protocol = "gossip_tracker"`: `consensus.rounds` rounds of
/// push-sum a step over pair channels, after weighing the closed
/// neighbourhood's measurements; no parameters of its own.
pub fn factory() -> (Shape, BuildNode) {
    (Shape::Tracker { pairs: true }, build)
}

fn build(setup: &Setup<'_>, _: Start) -> Result<AnyNode, NodeError> {
    setup.params.only(&[])?;
    let rule = Gossip {
        node: setup.node,
        topology: setup.topology.clone(),
        seed: setup.scenario.seed,
        kind: setup.payload::<PosteriorShare>()?,
        begin,
        end,
    };
    let rounds = RoundEngine::new(
        rule,
        setup.node,
        setup.topology,
        setup.rounds(),
        setup.round_timeout(),
    );
    let node = TrackerNode::new(
        setup.scenario,
        setup.topology,
        setup.node,
        KlCooperation::new(true),
        rounds,
    )?;
    Ok(Box::new(ProcessingNode::new(node)))
}
