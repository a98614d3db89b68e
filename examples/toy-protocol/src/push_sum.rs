//! Push-sum gossip (Kempe, Dobra and Gehrke, "Gossip-based computation of
//! aggregate information", FOCS 2003) on the CF/DPF's information vector.
//!
//! Each node holds a value x and a weight w, starting from its own vector
//! and 1. Each round it keeps half of both and sends the other half to one
//! neighbour, drawn anew each round; it adds what it receives. The sums of
//! x and of w over the network never change, so every node's x / w tends
//! to the network's average, whatever the graph, without the doubly
//! stochastic weights average consensus needs. The network's sums are
//! N_f · x / w.
//!
//! Sends are point to point: the factory says it needs pairs, and each
//! round's value crosses only the link to the neighbour drawn. Every node
//! can draw any node's target ([`gossip_target`]), so a node waits in a
//! round for exactly the neighbours that send to it, and a round that
//! hears fewer than those is what a fault cost the step.

use fusion_graph::{MetropolisWeights, Topology, WireError};
use node::fusion::{
    At, Fused, InformationFusion, InformationVector, RoundEngine, RoundRule, RoundsDone, To,
};
use node::parts::{Needs, ParamError, ProtocolFactory, Setup};
use wire::payloads::{finite_numbers, put_numbers, PayloadKind, ProtocolPayload};
use wire::Payload;

/// Half a node's value and weight, on its way to one neighbour: δη, δΛ,
/// ΔL (24 numbers) and the weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PushSumValue {
    pub value: InformationVector,
    pub weight: f64,
}

impl ProtocolPayload for PushSumValue {
    const NAME: &'static str = "push_sum";
    const LEN: usize = 25 * 8;
    /// ΔL, 10 numbers of the 25: what the bound is computed from.
    const BOUND_BYTES: usize = 10 * 8;

    fn encode(&self, out: &mut Vec<u8>) {
        let v = &self.value;
        let numbers = v.delta_eta.iter().chain(&v.delta_lambda).chain(&v.delta_l);
        put_numbers(numbers.chain([&self.weight]), out);
    }

    fn decode(body: &[u8]) -> Result<Self, WireError> {
        let n: [f64; 25] = finite_numbers(body)?;
        if n[24] <= 0.0 {
            // A weight is a share of a node's 1: never zero or less.
            return Err(WireError::NonFinite);
        }
        Ok(Self {
            value: InformationVector::new(
                n[..4].try_into().expect("4"),
                n[4..14].try_into().expect("10"),
                n[14..24].try_into().expect("10"),
            ),
            weight: n[24],
        })
    }
}

/// The neighbour node `node` sends to in `at`, drawn from the scenario's
/// `seed` by a hash every node computes alike.
pub fn gossip_target(topology: &Topology, seed: u64, node: u16, at: At) -> u16 {
    let neighbours = &topology.neighbours[node as usize];
    let key = seed ^ (u64::from(at.step) << 32) ^ (u64::from(at.round) << 16) ^ u64::from(node);
    neighbours[(splitmix64(key) % neighbours.len() as u64) as usize]
}

/// SplitMix64's finalizer: a well-mixed 64-bit hash of `x`.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A value push-sum can carry: its weight inside, split in halves and
/// summed. Both the CF/DPF's information vector ([`PushSumValue`]) and a
/// tracker's posterior (`PosteriorShare`) are.
pub trait Mass: ProtocolPayload + Copy {
    /// The half that leaves (and the half that stays).
    fn halved(&self) -> Self;
    /// `self += other`.
    fn add(&mut self, other: &Self);
}

/// Push-sum's round rule over any [`Mass`]: a node's input becomes its
/// first value by `begin`, and its last round's value the protocol's
/// output by `end` (which divides by the weight).
pub struct Gossip<I, V, O> {
    pub node: u16,
    pub topology: Topology,
    pub seed: u64,
    pub kind: PayloadKind<V>,
    pub begin: fn(I) -> V,
    pub end: fn(RoundsDone<V>) -> O,
}

impl<I, V: Mass, O> RoundRule for Gossip<I, V, O> {
    type Input = I;
    type Value = V;
    type Output = O;
    type Pieces = Option<V>;

    fn begin(&self, _: u32, input: I) -> V {
        (self.begin)(input)
    }

    /// The half that leaves.
    fn payloads(&self, _: At, own: &V, out: &mut Vec<Payload>) {
        out.push(self.kind.payload(&own.halved()));
    }

    fn to(&self, at: At) -> To {
        if self.topology.neighbours[self.node as usize].is_empty() {
            return To::Nobody;
        }
        To::Neighbour(gossip_target(&self.topology, self.seed, self.node, at))
    }

    fn expects(&self, at: At, from: u16) -> bool {
        gossip_target(&self.topology, self.seed, from, at) == self.node
    }

    fn absorb(&self, pieces: &mut Option<V>, payload: &Payload) -> bool {
        let Some(v) = self.kind.read(payload) else {
            return false;
        };
        *pieces = Some(v);
        true
    }

    fn assemble(&self, pieces: &Option<V>) -> Option<V> {
        *pieces
    }

    /// The half kept, plus the halves received.
    fn combine(&self, own: &V, heard: &[(u16, V)], _: &MetropolisWeights) -> V {
        let alone = self.topology.neighbours[self.node as usize].is_empty();
        let mut next = if alone { *own } else { own.halved() };
        for (_, v) in heard {
            next.add(v);
        }
        next
    }

    fn finish(&self, done: RoundsDone<V>) -> O {
        (self.end)(done)
    }
}

impl Mass for PushSumValue {
    fn halved(&self) -> Self {
        PushSumValue {
            value: self.value.scaled(0.5),
            weight: self.weight / 2.0,
        }
    }

    fn add(&mut self, other: &Self) {
        self.value.add_scaled(1.0, &other.value);
        self.weight += other.weight;
    }
}

/// Push-sum's factory: `consensus.rounds` rounds a step, each closing at
/// `consensus.round_timeout_ms`; no parameters of its own; sends to one
/// neighbour at a time.
pub struct PushSum;

impl ProtocolFactory for PushSum {
    fn needs(&self) -> Needs {
        Needs::POINT_TO_POINT
    }

    fn build(&self, setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
        setup.params.only(&[])?;
        let rule = Gossip {
            node: setup.node,
            topology: setup.topology.clone(),
            seed: setup.scenario.seed,
            kind: setup.payload::<PushSumValue>()?,
            begin: |value| PushSumValue { value, weight: 1.0 },
            // The network's sums: N_f times the average, x / w.
            end: |done| Fused {
                sums: done
                    .value
                    .value
                    .scaled(done.component_size as f64 / done.value.weight)
                    .to_sums(),
                stats: done.stats,
            },
        };
        Ok(Box::new(RoundEngine::new(
            rule,
            setup.node,
            setup.topology,
            setup.rounds(),
            setup.round_timeout(),
        )))
    }
}
