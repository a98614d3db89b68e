//! The round engine the round-based protocols share: round k's value goes
//! to every live neighbour; the round completes when every live neighbour's
//! round-k value is in, or at the round's timeout with those heard; then
//! [`RoundRule::combine`] gives round k+1's value. Values for rounds still to
//! come are kept (a neighbour may be ahead); values for rounds past are late.
//!
//! A protocol that runs the engine several times within one step (sensor
//! selection: one min-consensus per greedy iteration) starts each run at a
//! round offset, so that every run's rounds have their own numbers on the
//! wire and a neighbour one run ahead is kept, not mistaken for late.

use std::time::Duration;

use fusion_graph::transport::Channel;
use fusion_graph::wire::{Message, Payload};
use fusion_graph::{ActorId, MetropolisWeights, Topology};

use super::{FusionProtocol, Handled, RoundStats};
use crate::Outgoing;

/// What a round-based protocol's value is and how a round combines it.
pub trait RoundRule {
    type Value: Clone;
    /// What the protocol yields once its rounds are done.
    type Output;
    /// A neighbour's value as its payloads arrive (it may take more than one).
    type Pieces: Default + Clone;

    /// The payloads one round's value travels in.
    fn payloads(&self, value: &Self::Value, out: &mut Vec<Payload>);

    /// Takes `payload` into `pieces`; false if it is not one of this rule's.
    fn absorb(&self, pieces: &mut Self::Pieces, payload: &Payload) -> bool;

    /// The whole value, once every piece is in.
    fn assemble(&self, pieces: &Self::Pieces) -> Option<Self::Value>;

    /// Round k+1's value from round k's own and the neighbours heard, with
    /// Metropolis weights over those heard.
    fn combine(
        &self,
        own: &Self::Value,
        heard: &[(u16, Self::Value)],
        weights: &MetropolisWeights,
    ) -> Self::Value;

    /// The protocol's result from its last round.
    fn finish(&self, done: RoundsDone<Self::Value>) -> Self::Output;
}

/// Each heard neighbour's value with its Metropolis weight: what
/// [`RoundRule::combine`] sums with the node's own.
pub fn weighted<'a, V>(
    heard: &'a [(u16, V)],
    weights: &'a MetropolisWeights,
) -> impl Iterator<Item = (f64, &'a V)> + 'a {
    weights.neighbours.iter().map(move |(m, w)| {
        let v = &heard
            .iter()
            .find(|(n, _)| n == m)
            .expect("weights only over heard neighbours")
            .1;
        (*w, v)
    })
}

/// A step's rounds, done.
#[derive(Debug, Clone, PartialEq)]
pub struct RoundsDone<V> {
    pub value: V,
    /// N_f: the size of the node's live connected component.
    pub component_size: usize,
    pub stats: RoundStats,
}

#[derive(Debug, Clone)]
struct Heard<P> {
    step: u32,
    round: u16,
    from: u16,
    pieces: P,
}

#[derive(Debug, Clone)]
struct Running<V> {
    step: u32,
    /// 1..=rounds: the round whose values are being gathered.
    round: u16,
    value: V,
    deadline: Duration,
    view: Vec<bool>,
    started: Duration,
    first_round_done: Option<Duration>,
    neighbours_heard: u16,
    /// Round k is `offset + k` on the wire.
    offset: u16,
}

pub struct RoundEngine<R: RoundRule> {
    rule: R,
    node: u16,
    topology: Topology,
    rounds: u16,
    /// The highest round number on the wire: `rounds` unless the engine
    /// runs several times a step ([`with_last_round`](Self::with_last_round)).
    last_round: u16,
    round_timeout: Duration,
    /// Presume a neighbour gone for the rest of the step once it has missed
    /// this many rounds in a row ([`presume_gone_after`](Self::presume_gone_after)).
    gone_after: Option<u16>,
    /// Consecutive rounds each node has missed in the step `misses_step`.
    misses: Vec<u16>,
    misses_step: u32,
    /// The latest step begun: anything older is late.
    current_step: u32,
    running: Option<Running<R::Value>>,
    heard: Vec<Heard<R::Pieces>>,
    done: Option<RoundsDone<R::Value>>,
}

impl<R: RoundRule> RoundEngine<R> {
    pub fn new(
        rule: R,
        node: u16,
        topology: &Topology,
        rounds: u16,
        round_timeout: Duration,
    ) -> Self {
        Self {
            rule,
            node,
            topology: topology.clone(),
            rounds,
            last_round: rounds,
            round_timeout,
            gone_after: None,
            misses: vec![0; topology.nodes()],
            misses_step: 0,
            current_step: 0,
            running: None,
            heard: Vec::new(),
            done: None,
        }
    }

    /// Lets runs started at a round offset ([`start_at`](Self::start_at))
    /// use wire rounds up to `last_round`.
    pub fn with_last_round(mut self, last_round: u16) -> Self {
        self.last_round = last_round.max(self.rounds);
        self
    }

    /// A neighbour that misses `rounds` rounds in a row is left out of the
    /// step's remaining rounds (and runs), so that a node that died costs
    /// that many timeouts rather than one per round. One missed round is
    /// not enough: a neighbour whose own round waited out a timeout answers
    /// just after ours expires too.
    pub fn presume_gone_after(mut self, rounds: u16) -> Self {
        self.gone_after = Some(rounds.max(1));
        self
    }

    fn presumed_gone(&self, m: u16) -> bool {
        self.gone_after
            .is_some_and(|k| self.misses[m as usize] >= k)
    }

    /// Starts `step` as [`FusionProtocol::start`] does, with the run's
    /// rounds numbered from `offset + 1` on the wire.
    pub fn start_at(
        &mut self,
        step: u32,
        offset: u16,
        value: R::Value,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        self.expect_step(step);
        self.done = None;
        if step != self.misses_step {
            self.misses.iter_mut().for_each(|m| *m = 0);
            self.misses_step = step;
        }
        let mut view = view.to_vec();
        for m in 0..view.len() as u16 {
            view[m as usize] &= !self.presumed_gone(m);
        }
        view[self.node as usize] = true;
        let running = Running {
            step,
            round: 1,
            value,
            deadline: now + self.round_timeout,
            view,
            started: now,
            first_round_done: None,
            neighbours_heard: 0,
            offset,
        };
        self.send_round(&running, out);
        self.running = Some(running);
        self.try_complete_round(now, out);
    }

    /// This node's neighbours in `view`.
    fn live_neighbours<'a>(&'a self, view: &'a [bool]) -> impl Iterator<Item = u16> + 'a {
        self.topology.neighbours[self.node as usize]
            .iter()
            .copied()
            .filter(move |m| view[*m as usize])
    }

    fn send_round(&self, r: &Running<R::Value>, out: &mut Vec<Outgoing>) {
        // Published on our channel, the message reaches every neighbour's
        // queue, the ones outside our view (dead, or across a partition) too,
        // so it is counted as sent to all of them; only the live are woken.
        let receivers: Vec<ActorId> = self.topology.neighbours[self.node as usize]
            .iter()
            .map(|m| ActorId::Node(*m))
            .collect();
        let wake: Vec<ActorId> = self.live_neighbours(&r.view).map(ActorId::Node).collect();
        let mut payloads = Vec::with_capacity(2);
        self.rule.payloads(&r.value, &mut payloads);
        for payload in payloads {
            out.push(Outgoing {
                channel: Channel::Consensus(self.node),
                message: Message::new(
                    ActorId::Node(self.node),
                    r.step,
                    r.offset + r.round,
                    payload,
                ),
                receivers: receivers.clone(),
                wake: Some(wake.clone()),
            });
        }
    }

    /// A neighbour's value for the running round, if every piece is in.
    fn heard_value(&self, r: &Running<R::Value>, from: u16) -> Option<R::Value> {
        self.heard
            .iter()
            .find(|h| h.step == r.step && h.round == r.offset + r.round && h.from == from)
            .and_then(|h| self.rule.assemble(&h.pieces))
    }

    /// Completes the running round if every live neighbour has been heard.
    fn try_complete_round(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(r) = &self.running else {
            return;
        };
        if self
            .live_neighbours(&r.view)
            .all(|m| self.heard_value(r, m).is_some())
        {
            self.complete_round(now, out);
        }
    }

    /// One round's update over the neighbours heard, with Metropolis
    /// weights recomputed over them.
    fn complete_round(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(mut r) = self.running.take() else {
            return;
        };
        let mut present = r.view.clone();
        let mut values = Vec::new();
        let live: Vec<u16> = self.live_neighbours(&r.view).collect();
        for m in live {
            match self.heard_value(&r, m) {
                Some(v) => {
                    values.push((m, v));
                    self.misses[m as usize] = 0;
                }
                None => {
                    present[m as usize] = false;
                    self.misses[m as usize] += 1;
                }
            }
        }
        for m in 0..r.view.len() as u16 {
            if m != self.node && self.presumed_gone(m) {
                r.view[m as usize] = false;
            }
        }
        let weights = self.topology.metropolis_weights(self.node, &present);
        r.value = self.rule.combine(&r.value, &values, &weights);
        let wire_round = r.offset + r.round;
        self.heard
            .retain(|h| !(h.step == r.step && h.round == wire_round));
        r.neighbours_heard = values.len() as u16;
        if r.round == 1 {
            r.first_round_done = Some(now);
        }
        if r.round < self.rounds {
            r.round += 1;
            r.deadline = now + self.round_timeout;
            self.send_round(&r, out);
            self.running = Some(r);
            self.try_complete_round(now, out);
        } else {
            self.done = Some(RoundsDone {
                component_size: self.topology.component_size(self.node, &r.view).max(1),
                stats: RoundStats {
                    rounds_completed: self.rounds,
                    neighbours_heard: r.neighbours_heard,
                    total: now.saturating_sub(r.started),
                    later_rounds: r
                        .first_round_done
                        .map_or(Duration::ZERO, |t| now.saturating_sub(t)),
                },
                value: r.value,
            });
        }
    }

    /// The last run's rounds, once, with the neighbours that fell silent;
    /// `None` while it is still running.
    pub fn take_done(&mut self) -> Option<RoundsDone<R::Value>> {
        self.done.take()
    }

    fn take_result(&mut self) -> Option<R::Output> {
        let done = self.done.take()?;
        Some(self.rule.finish(done))
    }
}

/// A round-based protocol is its engine; its rule says the rest.
impl<R: RoundRule> FusionProtocol for RoundEngine<R> {
    type Value = R::Value;
    type Output = R::Output;

    fn expect_step(&mut self, step: u32) {
        self.current_step = self.current_step.max(step);
        self.heard.retain(|h| h.step >= step);
    }

    fn start(
        &mut self,
        step: u32,
        value: R::Value,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        self.start_at(step, 0, value, view, now, out);
    }

    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) -> Handled {
        let ActorId::Node(from) = message.header.sender else {
            return Handled::NotMine;
        };
        let (step, round) = (message.header.step, message.header.round);
        let mut probe = R::Pieces::default();
        if !self.rule.absorb(&mut probe, &message.payload) {
            return Handled::NotMine;
        }
        if !self.topology.neighbours[self.node as usize].contains(&from)
            || round == 0
            || round > self.last_round
        {
            return Handled::Late;
        }
        if step == self.misses_step {
            // Heard, even if late for its round: alive, not gone.
            self.misses[from as usize] = 0;
        }
        let stale = match &self.running {
            Some(r) => step < r.step || (step == r.step && round < r.offset + r.round),
            None => step < self.current_step,
        };
        if stale {
            return Handled::Late;
        }
        match self
            .heard
            .iter_mut()
            .find(|h| h.step == step && h.round == round && h.from == from)
        {
            Some(h) => {
                self.rule.absorb(&mut h.pieces, &message.payload);
            }
            None => self.heard.push(Heard {
                step,
                round,
                from,
                pieces: probe,
            }),
        }
        self.try_complete_round(now, out);
        Handled::Taken
    }

    fn poll_timeout(&self) -> Option<Duration> {
        self.running.as_ref().map(|r| r.deadline)
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        if self.running.as_ref().is_some_and(|r| now >= r.deadline) {
            self.complete_round(now, out);
        }
    }

    fn poll_result(&mut self) -> Option<R::Output> {
        self.take_result()
    }

    /// Completes every remaining round with what has been heard.
    fn finish_now(&mut self, now: Duration, out: &mut Vec<Outgoing>) -> Option<R::Output> {
        while self.running.is_some() {
            self.complete_round(now, out);
        }
        self.take_result()
    }
}
