//! Fusion protocols: how nodes combine what each brings into what the
//! network knows. Each is a sans-IO state machine in the manner of
//! quinn-proto's congestion controllers: it starts a step with the node's
//! value and membership view, takes messages and timeouts at the times it is
//! given, says when it next needs waking, and yields a result, pushing the
//! messages it wants sent (with their receivers) as it goes.
//!
//! - [`AverageConsensus`]: N_c rounds of Metropolis average consensus on the
//!   information vector (δη, δΛ, ΔL [, S_obs]); the network sums are N_f
//!   times the average (docs/equations.md, "Average consensus").
//! - [`ExactSums`]: the exact network sums from an oracle the in-process
//!   driver shares between its nodes; a checking mode of `sim`.
//! - [`RandomExchange`]: the random-exchange paper's RndEx-PF exchange, a posterior swapped
//!   with one random neighbour by request and acknowledgement.
//! - [`KlFusion`]: the random-exchange paper's KL fusion, K_max rounds of consensus on the
//!   natural parameters of the nodes' Gaussian posteriors.
//! - [`VectorSum`]: average consensus on a vector of any length, in pieces,
//!   for its network sum (a static target's locator).
//!
//! The round-based ones are a [`RoundEngine`], which keeps the round
//! numbering, early and late messages, timeouts and lost neighbours, and
//! implements [`FusionProtocol`] once; a [`RoundRule`] says what a value
//! looks like on the wire, how a round combines it with the neighbours', and
//! what the last round yields.

mod average;
mod exact;
mod exchange;
pub(crate) mod information;
mod kl;
mod rounds;
mod short_memory;
#[cfg(test)]
pub(crate) mod testing;
mod vector_sum;

pub use average::{average_consensus, AverageConsensus};
pub use exact::{ExactSumOracle, ExactSums};
pub use exchange::{Exchanged, RandomExchange};
pub use information::InformationVector;
pub use kl::{kl_fusion, KlFused, KlFusion, KlRule, NaturalGaussian};
pub use rounds::{At, RoundEngine, RoundRule, RoundsDone, To};
pub use short_memory::{short_memory_consensus, Remembered, ShortMemory, ShortMemoryConsensus};
pub use vector_sum::{vector_sum, Summed, VectorSum, VectorSumRule};

use std::time::Duration;

use wire::Message;

use crate::estimator::NetworkSums;
use crate::Outgoing;

/// What a protocol made of a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Handled {
    /// Used now or kept for a round still to come.
    Taken,
    /// Meant for this protocol but for a round or step already past.
    Late,
    /// Not a message of this protocol.
    NotMine,
}

/// How a step's fusion went, for telemetry.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RoundStats {
    pub rounds_completed: u16,
    /// Neighbours heard in the last round.
    pub neighbours_heard: u16,
    /// Neighbours the protocol expected to hear in the last round, dead
    /// ones included: every neighbour for average consensus, the partner
    /// for random exchange, those whose gossip targets the node for a
    /// push-sum. Hearing fewer is what a fault cost the step.
    pub neighbours_expected: u16,
    /// Rounds that ended at their deadline without the value of a
    /// neighbour they awaited. Each makes the step's result depend on
    /// when messages arrived: `run --lockstep` equals `sim` only without
    /// them.
    pub short_rounds: u16,
    /// From the start to the result.
    pub total: Duration,
    /// From the end of round 1 to the result: the rounds' own latency, once
    /// every neighbour is exchanging (round 1 also waits for the slowest
    /// neighbour's local filter).
    pub later_rounds: Duration,
    /// How far the node still was from the neighbours it heard in the last
    /// round: the largest relative difference of their values from its
    /// own ([`RoundRule::disagreement`](rounds::RoundRule::disagreement)),
    /// from values it holds anyway; `None` if the protocol does not say or
    /// it heard nobody.
    pub disagreement: Option<f64>,
}

/// What an information-fusion protocol yields for a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fused {
    /// `Σδη`, `ΣδΛ`, `S = ΣΔL` and `S_obs` over the node's live component.
    pub sums: NetworkSums,
    pub stats: RoundStats,
}

/// A fusion protocol as a state machine with no I/O and no clock.
pub trait FusionProtocol {
    /// What each node brings to a step.
    type Value;
    /// What the protocol yields.
    type Output;

    /// A new step began: messages of earlier steps are late from now on.
    fn expect_step(&mut self, step: u32);

    /// Starts `step` with this node's value, given the live nodes this node
    /// can reach (`view[i]` for node i, itself included).
    fn start(
        &mut self,
        step: u32,
        value: Self::Value,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    );

    /// Takes one message from a neighbour.
    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) -> Handled;

    /// When [`handle_timeout`](Self::handle_timeout) should next be called.
    fn poll_timeout(&self) -> Option<Duration>;

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>);

    /// The step's result, once; `None` while it is still running.
    fn poll_result(&mut self) -> Option<Self::Output>;

    /// Ends the running step at once with what it has (the node must move
    /// on to the next step); `None` if no step is running.
    fn finish_now(&mut self, now: Duration, out: &mut Vec<Outgoing>) -> Option<Self::Output>;
}

/// The protocol a node fuses its information with.
pub type InformationFusion = Box<dyn FusionProtocol<Value = InformationVector, Output = Fused>>;
