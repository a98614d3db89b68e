//! The round engine the round-based protocols share: round k's value goes
//! to every live neighbour (or, if the rule says, to one neighbour over
//! the pair's channel); the round completes when every live neighbour the
//! rule expects has its round-k value in, or at the round's timeout with
//! those heard; then [`RoundRule::combine`] gives round k+1's value. Values for rounds still to
//! come are kept (a neighbour may be ahead); values for rounds past are late.
//!
//! A protocol that runs the engine several times within one step (a
//! locator: one consensus per phase of its search) starts each run at a
//! round offset, so that every run's rounds have their own numbers on the
//! wire and a neighbour one run ahead is kept, not mistaken for late.

use std::time::Duration;

use fusion_graph::Channel;
use fusion_graph::{ActorId, MetropolisWeights, Topology};
use wire::{Message, Payload};

use super::{FusionProtocol, Handled, RoundStats};
use crate::Outgoing;

/// A round of a step, as a rule is told it: `round` is its number on the
/// wire (1 for a step's first).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct At {
    pub step: u32,
    pub round: u16,
}

/// Whom a round's value goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum To {
    /// Every neighbour, on the node's consensus channel.
    Everyone,
    /// One neighbour, on the pair's own channel (the protocol's factory
    /// says it needs pairs, `Needs::POINT_TO_POINT`).
    Neighbour(u16),
    /// Nobody this round.
    Nobody,
}

/// What a round-based protocol's value is and how a round combines it.
pub trait RoundRule {
    /// What a node brings to a step.
    type Input;
    /// What the rounds mix: the input, or more (a push-sum's weight).
    type Value: Clone;
    /// What the protocol yields once its rounds are done.
    type Output;
    /// A neighbour's value as its payloads arrive (it may take more than one).
    type Pieces: Default + Clone;

    /// The first round's value from what the node brings.
    fn begin(&self, step: u32, input: Self::Input) -> Self::Value;

    /// The payloads round `at`'s value travels in.
    fn payloads(&self, at: At, value: &Self::Value, out: &mut Vec<Payload>);

    /// Whom round `at`'s value goes to: every neighbour, unless the rule
    /// says otherwise.
    fn to(&self, at: At) -> To {
        let _ = at;
        To::Everyone
    }

    /// Whether neighbour `from` sends to this node in round `at`: the
    /// round waits only for those, and hearing fewer of them is what a
    /// fault cost. Every neighbour, unless the rule says otherwise.
    fn expects(&self, at: At, from: u16) -> bool {
        let _ = (at, from);
        true
    }

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

    /// How far a neighbour's value `heard` is from the node's `own`, as a
    /// share of their size: what the step's report says of the last
    /// round, the largest over the neighbours heard. `None` (the default)
    /// if the rule has no measure.
    fn disagreement(&self, own: &Self::Value, heard: &Self::Value) -> Option<f64> {
        let _ = (own, heard);
        None
    }
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
    neighbours_expected: u16,
    /// Rounds so far completed without a neighbour they awaited.
    short_rounds: u16,
    /// Round k is `offset + k` on the wire.
    offset: u16,
    /// Set once only neighbours on probation are missing: the round waits
    /// for them until then at most.
    grace_until: Option<Duration>,
}

/// Where a neighbour stands in the running step, under
/// [`stop_awaiting_the_late`](RoundEngine::stop_awaiting_the_late).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Standing {
    OnTime,
    /// Missed a round: awaited only a short grace after the others.
    Probation,
    /// Missed a round on probation: not awaited for the rest of the step.
    NotAwaited,
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
    /// Stop waiting, for the rest of the step, for a neighbour that missed
    /// a round ([`stop_awaiting_the_late`](Self::stop_awaiting_the_late)).
    stop_awaiting: bool,
    /// Consecutive rounds each node has missed in the step `misses_step`.
    misses: Vec<u16>,
    /// Each neighbour's standing in the step `misses_step`.
    standing: Vec<Standing>,
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
            stop_awaiting: false,
            misses: vec![0; topology.nodes()],
            standing: vec![Standing::OnTime; topology.nodes()],
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

    /// A neighbour that misses a round's deadline is on probation: the
    /// next rounds wait for it only a grace (a fifth of the round timeout)
    /// after the other neighbours are in. If it is in by then it has caught
    /// up; if it misses again it is not waited for in the step's remaining
    /// rounds (its value is still used when it happens to be there), and it
    /// is waited for again from the next step.
    ///
    /// Why: waiting for a slow neighbour in every round (the default) costs
    /// a timeout a round, which makes the waiting node late for its own
    /// neighbours in turn, until the whole network misses the step. Giving
    /// up on a neighbour at its first miss is no better: a neighbour that
    /// merely started one timeout late (it waited for a sensor) answers
    /// just after the deadline and is back in step from then on, and
    /// dropping it would cut it out of the step's consensus.
    pub fn stop_awaiting_the_late(mut self) -> Self {
        self.stop_awaiting = true;
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
            self.standing.fill(Standing::OnTime);
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
            neighbours_expected: 0,
            short_rounds: 0,
            offset,
            grace_until: None,
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

    /// The running round, as the rule is told it.
    fn at(r: &Running<R::Value>) -> At {
        At {
            step: r.step,
            round: r.offset + r.round,
        }
    }

    /// This node's neighbours in `view` that the rule expects this round.
    fn expected<'a>(&'a self, r: &'a Running<R::Value>) -> impl Iterator<Item = u16> + 'a {
        let at = Self::at(r);
        self.live_neighbours(&r.view)
            .filter(move |m| self.rule.expects(at, *m))
    }

    fn send_round(&self, r: &Running<R::Value>, out: &mut Vec<Outgoing>) {
        let neighbours = &self.topology.neighbours[self.node as usize];
        let (channel, receivers, wake) = match self.rule.to(Self::at(r)) {
            To::Nobody => return,
            // Published on our channel, the message reaches every
            // neighbour's queue, the ones outside our view (dead, or across
            // a partition) too, so it is counted as sent to all of them;
            // only the live are woken.
            To::Everyone => (
                Channel::Consensus(self.node),
                neighbours.iter().map(|m| ActorId::Node(*m)).collect(),
                self.live_neighbours(&r.view).map(ActorId::Node).collect(),
            ),
            To::Neighbour(m) => {
                debug_assert!(neighbours.contains(&m), "a pair is two neighbours");
                let live = r.view.get(m as usize).copied().unwrap_or(false);
                (
                    Channel::Pair {
                        from: self.node,
                        to: m,
                    },
                    vec![ActorId::Node(m)],
                    if live { vec![ActorId::Node(m)] } else { vec![] },
                )
            }
        };
        let mut payloads = Vec::with_capacity(2);
        self.rule.payloads(Self::at(r), &r.value, &mut payloads);
        // Only the last payload wakes: a neighbour woken by the first
        // would find the value still in pieces.
        let last = payloads.len().saturating_sub(1);
        for (i, payload) in payloads.into_iter().enumerate() {
            let wake = if i == last { wake.clone() } else { Vec::new() };
            out.push(Outgoing {
                channel,
                message: Message::new(
                    ActorId::Node(self.node),
                    r.step,
                    r.offset + r.round,
                    payload,
                ),
                receivers: receivers.clone(),
                wake: Some(wake),
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

    /// Completes the running round if every live neighbour still awaited
    /// has been heard; starts the grace if only neighbours on probation
    /// are missing.
    fn try_complete_round(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(r) = &self.running else {
            return;
        };
        let mut only_probation = true;
        let mut all_in = true;
        for m in self.expected(r) {
            let standing = self.standing[m as usize];
            if standing == Standing::NotAwaited || self.heard_value(r, m).is_some() {
                continue;
            }
            all_in = false;
            only_probation &= standing == Standing::Probation;
        }
        if all_in {
            return self.complete_round(now, out);
        }
        let grace = self.round_timeout / 5;
        if let Some(r) = self.running.as_mut().filter(|_| only_probation) {
            r.grace_until.get_or_insert(now + grace);
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
        let at = Self::at(&r);
        let live: Vec<u16> = self.live_neighbours(&r.view).collect();
        let mut unheard = 0;
        for m in live {
            let expected = self.rule.expects(at, m);
            match self.heard_value(&r, m) {
                Some(v) => {
                    values.push((m, v));
                    self.misses[m as usize] = 0;
                    let s = &mut self.standing[m as usize];
                    if *s == Standing::Probation {
                        *s = Standing::OnTime;
                    }
                }
                // Not sending to us this round: neither heard nor missed.
                None if !expected => present[m as usize] = false,
                None => {
                    present[m as usize] = false;
                    unheard += 1;
                    self.misses[m as usize] += 1;
                    let s = &mut self.standing[m as usize];
                    *s = match *s {
                        _ if !self.stop_awaiting => Standing::OnTime,
                        Standing::OnTime => Standing::Probation,
                        Standing::Probation | Standing::NotAwaited => Standing::NotAwaited,
                    };
                }
            }
        }
        for m in 0..r.view.len() as u16 {
            if m != self.node && self.presumed_gone(m) {
                r.view[m as usize] = false;
            }
        }
        if unheard > 0 {
            r.short_rounds = r.short_rounds.saturating_add(1);
        }
        let mut weights = self.topology.metropolis_weights(self.node, &present);
        weights.unheard = unheard;
        let last = r.round >= self.rounds;
        let disagreement = if last {
            self.disagreement(&r.value, &values)
        } else {
            None
        };
        r.value = self.rule.combine(&r.value, &values, &weights);
        let wire_round = r.offset + r.round;
        self.heard
            .retain(|h| !(h.step == r.step && h.round == wire_round));
        r.neighbours_heard = values.len() as u16;
        r.neighbours_expected = self.topology.neighbours[self.node as usize]
            .iter()
            .filter(|m| self.rule.expects(at, **m))
            .count() as u16;
        if r.round == 1 {
            r.first_round_done = Some(now);
        }
        if r.round < self.rounds {
            r.round += 1;
            r.deadline = now + self.round_timeout;
            r.grace_until = None;
            self.send_round(&r, out);
            self.running = Some(r);
            self.try_complete_round(now, out);
        } else {
            self.done = Some(RoundsDone {
                component_size: self.topology.component_size(self.node, &r.view).max(1),
                stats: RoundStats {
                    rounds_completed: self.rounds,
                    neighbours_heard: r.neighbours_heard,
                    neighbours_expected: r.neighbours_expected,
                    short_rounds: r.short_rounds,
                    total: now.saturating_sub(r.started),
                    later_rounds: r
                        .first_round_done
                        .map_or(Duration::ZERO, |t| now.saturating_sub(t)),
                    disagreement,
                },
                value: r.value,
            });
        }
    }

    /// The largest of the rule's disagreements between the node's value
    /// and each heard neighbour's, in the same round.
    fn disagreement(&self, own: &R::Value, heard: &[(u16, R::Value)]) -> Option<f64> {
        heard
            .iter()
            .filter_map(|(_, v)| self.rule.disagreement(own, v))
            .reduce(f64::max)
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
    type Value = R::Input;
    type Output = R::Output;

    fn expect_step(&mut self, step: u32) {
        self.current_step = self.current_step.max(step);
        self.heard.retain(|h| h.step >= step);
    }

    fn start(
        &mut self,
        step: u32,
        input: R::Input,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let value = self.rule.begin(step, input);
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
        self.running
            .as_ref()
            .map(|r| r.grace_until.map_or(r.deadline, |g| g.min(r.deadline)))
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        if self.poll_timeout().is_some_and(|due| now >= due) {
            self.complete_round(now, out);
        }
    }

    fn poll_result(&mut self) -> Option<R::Output> {
        self.take_result()
    }

    /// Completes every remaining round with what has been heard. The
    /// result counts only the rounds that had run, not the ones cut short.
    fn finish_now(&mut self, now: Duration, out: &mut Vec<Outgoing>) -> Option<R::Output> {
        let cut_at = self.running.as_ref().map(|r| (r.round - 1, r.short_rounds));
        while self.running.is_some() {
            self.complete_round(now, out);
        }
        if let (Some(done), Some((ran, short))) = (self.done.as_mut(), cut_at) {
            done.stats.rounds_completed = ran;
            done.stats.short_rounds = short;
        }
        self.take_result()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::average::average_consensus;
    use crate::fusion::testing::{drive, Fate};
    use crate::fusion::InformationVector;
    use fusion_graph::scenario::{Scenario, DEFAULT_SCENARIO};

    const TIMEOUT: Duration = Duration::from_millis(50);
    const SLOW: u16 = 5;

    /// A 4×4 grid whose links join the four nearest nodes; node 5 is inside.
    fn grid() -> Topology {
        let overrides = [
            "nodes.grid=[4,4]",
            "region.width=2000",
            "region.height=2000",
        ]
        .map(String::from);
        let s = Scenario::from_toml(DEFAULT_SCENARIO, "grid", &overrides).unwrap();
        Topology::from_scenario(&s, "grid").unwrap()
    }

    /// Node i's value in the slow-node runs: its own, so that consensus
    /// has something to agree on.
    fn node_value(i: u16) -> InformationVector {
        InformationVector {
            delta_eta: [i as f64; 4],
            delta_lambda: [1.0; 10],
            delta_l: [1.0; 10],
            delta_l_late: [0.0; 10],
            s_obs: None,
        }
    }

    /// Each node's time from the start of 12 rounds of average consensus to
    /// its result, when everything node 5 sends takes 80 ms, longer than a
    /// round's 50 ms timeout.
    fn times_with_a_slow_node(stop_awaiting: bool) -> (Topology, Vec<Duration>) {
        let t = grid();
        let nodes: Vec<_> = (0..16)
            .map(|i| {
                let e = average_consensus(i, &t, 12, TIMEOUT, false);
                if stop_awaiting {
                    e.stop_awaiting_the_late()
                } else {
                    e
                }
            })
            .collect();
        let latency = |from: u16, _: u16, _: &Payload| {
            Fate::Deliver(Duration::from_millis(if from == SLOW { 80 } else { 1 }))
        };
        let got = drive(
            nodes,
            node_value,
            &[true; 16],
            latency,
            Duration::from_secs(60),
        );
        let times = got
            .iter()
            .map(|f| f.as_ref().unwrap().stats.total)
            .collect();
        (t, times)
    }

    #[test]
    fn a_slow_node_costs_its_neighbours_one_timeout_a_step_and_the_others_no_more() {
        let (t, times) = times_with_a_slow_node(true);
        let near = &t.neighbours[SLOW as usize];
        for (n, took) in times.iter().enumerate() {
            // One timeout, one grace of a neighbour on probation (10 ms),
            // and twelve rounds of 1 ms links (measured: 69-70 ms at
            // every node); a neighbour of the slow node may also wait a
            // round for a neighbour that itself waited out the timeout.
            assert!(
                *took < TIMEOUT * 2 + Duration::from_millis(40),
                "node-{n} took {took:?}"
            );
            if n as u16 != SLOW && !near.contains(&(n as u16)) {
                assert!(
                    *took < TIMEOUT + Duration::from_millis(40),
                    "node-{n} took {took:?}"
                );
            }
        }
        // Waiting for the slow node in every round instead stalls everyone
        // for many timeouts: the case the rule is for.
        let (_, waited) = times_with_a_slow_node(false);
        let far = waited
            .iter()
            .enumerate()
            .filter(|(n, _)| !near.contains(&(*n as u16)));
        for (n, took) in far.filter(|(n, _)| *n != SLOW as usize) {
            assert!(
                *took > TIMEOUT * 4,
                "node-{n} took only {took:?} waiting every round"
            );
        }
    }

    /// A value in two payloads wakes its receivers once, with the last:
    /// woken by the first, a neighbour would find the value in pieces.
    #[test]
    fn only_a_values_last_payload_wakes() {
        let t = grid();
        // With the auxiliary-FIM baseline a value is two payloads.
        let value = InformationVector {
            delta_eta: [1.0; 4],
            delta_lambda: [1.0; 10],
            delta_l: [1.0; 10],
            delta_l_late: [0.0; 10],
            s_obs: Some([1.0; 10]),
        };
        let mut e = average_consensus(SLOW, &t, 3, TIMEOUT, true);
        let mut sent = Vec::new();
        e.expect_step(1);
        e.start(1, value, &[true; 16], Duration::ZERO, &mut sent);
        assert_eq!(sent.len(), 2, "a value and its auxiliary part");
        assert_eq!(
            sent[0].wake.as_deref(),
            Some(&[][..]),
            "the first wakes no one"
        );
        let woken = sent[1].wake.as_ref().unwrap();
        for m in &t.neighbours[SLOW as usize] {
            assert!(woken.contains(&ActorId::Node(*m)), "node-{m} not woken");
        }
    }

    #[test]
    fn rounds_cut_short_are_not_counted_as_completed() {
        let t = grid();
        let mut e = average_consensus(0, &t, 12, TIMEOUT, false);
        let mut out = Vec::new();
        let v = InformationVector {
            delta_eta: [0.0; 4],
            delta_lambda: [1.0; 10],
            delta_l: [1.0; 10],
            delta_l_late: [0.0; 10],
            s_obs: None,
        };
        e.expect_step(1);
        e.start(1, v, &[true; 16], Duration::ZERO, &mut out);
        e.handle_timeout(TIMEOUT, &mut out);
        e.handle_timeout(TIMEOUT * 2, &mut out);
        let done = e.finish_now(TIMEOUT * 2, &mut out).unwrap();
        assert_eq!(done.stats.rounds_completed, 2);
        // Both ended at their deadline, with no neighbour heard.
        assert_eq!(done.stats.short_rounds, 2);
    }

    /// A round ends short only when a neighbour's value misses its
    /// deadline: with every value in time, no node has one; with node 5's
    /// values late, its neighbours do.
    #[test]
    fn short_rounds_are_those_a_late_value_missed() {
        let t = grid();
        let run = |slow_ms: u64| {
            let nodes: Vec<_> = (0..16)
                .map(|i| average_consensus(i, &t, 12, TIMEOUT, false).stop_awaiting_the_late())
                .collect();
            let latency = move |from: u16, _: u16, _: &Payload| {
                Fate::Deliver(Duration::from_millis(if from == SLOW {
                    slow_ms
                } else {
                    1
                }))
            };
            drive(
                nodes,
                node_value,
                &[true; 16],
                latency,
                Duration::from_secs(60),
            )
            .into_iter()
            .map(|f| f.unwrap().stats.short_rounds)
            .collect::<Vec<_>>()
        };
        assert_eq!(run(1), vec![0; 16], "every value in time");
        let late = run(80);
        for m in &t.neighbours[SLOW as usize] {
            assert!(late[*m as usize] > 0, "node-{m} heard every late value");
        }
    }
}
