//! PCRLB-driven distributed sensor selection (the selection paper §4; docs/equations.md, "PCRLB
//! sensor selection"): a greedy choice, one sensor per iteration, agreed over
//! the fusion graph.
//!
//! In each iteration every node scores its own not-yet-chosen sensors by
//! `C(A ∪ {m})` ([`bounds::selection::selection_cost`]) on its own
//! predicted information, proposes its best, and min-consensus over the
//! fusion graph (as many rounds as its diameter) picks the network's best.
//! The winning proposal carries the winner's `J̄`, so every node adds it to
//! its `Σ_{s∈A} J̄_s`; the winner's owner marks it chosen. It stops at
//! `N_max` sensors, or when no live node has room under its cap. Every
//! message is a real one: the proposals and their rounds are the
//! min-consensus messages, and the winner's `J̄` travels inside them.
//!
//! Unlike the other managers this one is a protocol, a sans-IO state
//! machine driven like a [`FusionProtocol`](crate::fusion::FusionProtocol):
//! the node starts it at `BeginStep`, feeds it messages and timeouts, and
//! activates its sensors when it yields.
//!
//! A neighbour that misses two rounds in a row is presumed gone for the
//! rest of the step's selection, so that a node killed mid-selection costs
//! two round timeouts, not one per remaining round (up to N_max × diameter).
//! The launcher's membership view at the next step says who is alive.

use std::cmp::Ordering;
use std::time::Duration;

use bounds::pcrlb::{dynamics_terms, information_update};
use bounds::selection::selection_cost;
use bounds::{BoundError, Mat4, State};
use fusion_graph::wire::{Message, Proposal};
use fusion_graph::{Scenario, Topology};

use crate::estimator::SensingModel;
use crate::fusion::{min_consensus, proposal_order, FusionProtocol, Handled, MinConsensus};
use crate::Outgoing;

/// Which bound scores a candidate set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scoring {
    /// The conditional PCRLB: `J̄` over the fusion filter's predicted
    /// particles, `L(k+1|k)` from the global CQ/dPCRLB.
    Conditional,
    /// Tichavsky's recursion run at the estimate: `J̄` at the predicted
    /// estimate, `J(k+1|k)` carried by this manager along the estimates.
    /// It conditions on the data through x̂, so it is not the conventional
    /// (offline) PCRLB; that is [`super::OfflinePcrlb`].
    AtEstimate,
}

/// What a node brings to a step's selection.
#[derive(Debug, Clone, PartialEq)]
pub struct SelectionInputs {
    /// The predicted information the cost is taken on.
    pub predicted: Mat4,
    /// `J̄` of each of the node's own sensors, in the order of its list.
    pub own: Vec<Mat4>,
}

/// A step's selection, as this node saw it.
#[derive(Debug, Clone, PartialEq)]
pub struct Selected {
    /// Positions in the node's own sensor list to activate, increasing.
    pub own: Vec<usize>,
    /// Sensors chosen network-wide.
    pub total: u16,
    /// Iterations run (each one min-consensus).
    pub iterations: u16,
    /// From the start of the selection to its end.
    pub elapsed: Duration,
}

#[derive(Debug, Clone)]
struct Iterating {
    step: u32,
    iteration: u16,
    inputs: SelectionInputs,
    chosen: Vec<bool>,
    /// `Σ_{s∈A} J̄_s` as the winners' proposals carried it.
    sum: Mat4,
    total: u16,
    view: Vec<bool>,
    started: Duration,
}

pub struct PcrlbSelection {
    node: u16,
    own_sensors: Vec<u16>,
    scoring: Scoring,
    per_node: usize,
    max_total: usize,
    /// Rounds per iteration: the fusion graph's diameter.
    rounds: u16,
    engine: MinConsensus,
    running: Option<Iterating>,
    result: Option<Selected>,
    /// `J(k)` of Tichavsky's recursion along the estimates.
    tichavsky: Mat4,
}

impl PcrlbSelection {
    pub fn new(
        node: u16,
        topology: &Topology,
        scoring: Scoring,
        per_node: usize,
        max_total: usize,
        round_timeout: Duration,
        prior_information: Mat4,
    ) -> Self {
        let rounds = topology.diameter().max(1) as u16;
        let last_round = rounds.saturating_mul(max_total.min(u16::MAX as usize) as u16);
        Self {
            node,
            own_sensors: topology.node_sensors[node as usize].clone(),
            scoring,
            per_node,
            max_total,
            rounds,
            engine: min_consensus(node, topology, rounds, round_timeout)
                .with_last_round(last_round)
                .presume_gone_after(2),
            running: None,
            result: None,
            tichavsky: prior_information,
        }
    }

    /// The manager the scenario names, if it is a PCRLB one. Without
    /// `max_active_total`, every live node may fill its cap.
    pub fn for_scenario(
        scenario: &Scenario,
        topology: &Topology,
        node: u16,
        scoring: Scoring,
        prior_information: Mat4,
    ) -> Self {
        let per_node = scenario.sensors.active_per_node as usize;
        let max_total = scenario
            .sensors
            .max_active_total
            .map_or(per_node * topology.nodes(), |m| m as usize);
        Self::new(
            node,
            topology,
            scoring,
            per_node,
            max_total,
            Duration::from_secs_f64(scenario.consensus.round_timeout_ms / 1e3),
            prior_information,
        )
    }

    pub fn scoring(&self) -> Scoring {
        self.scoring
    }

    /// The inputs at the fusion filter's estimate at k:
    /// `J(k+1|k)` from this manager's `J(k)` with the dynamics linearised
    /// there, and each own sensor's `J_Y` at the predicted estimate.
    pub fn nonconditional_inputs(
        &self,
        model: &SensingModel,
        estimate: &State,
    ) -> Result<SelectionInputs, BoundError> {
        let terms = dynamics_terms(&model.dynamics, &[*estimate], &[1.0])?;
        let zero = Mat4::zeros();
        let predicted =
            information_update(&self.tichavsky, &terms, model.dynamics.q_inv(), &zero)?.predicted;
        let at = [model.dynamics.transition(estimate)];
        let own = self
            .own_sensors
            .iter()
            .map(|s| model.expected_information(*s, &at, &[1.0]))
            .collect::<Result<_, _>>()?;
        Ok(SelectionInputs { predicted, own })
    }

    /// Messages of earlier steps are late from now on.
    pub fn expect_step(&mut self, step: u32) {
        self.engine.expect_step(step);
    }

    /// Starts `step`'s selection over the live nodes in `view`.
    pub fn start(
        &mut self,
        step: u32,
        inputs: SelectionInputs,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        self.result = None;
        let mut view = view.to_vec();
        view[self.node as usize] = true;
        self.running = Some(Iterating {
            step,
            iteration: 0,
            chosen: vec![false; inputs.own.len()],
            inputs,
            sum: Mat4::zeros(),
            total: 0,
            view,
            started: now,
        });
        self.propose(now, out);
    }

    pub fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) -> Handled {
        let handled = self.engine.handle(message, now, out);
        self.advance(now, out);
        handled
    }

    pub fn poll_timeout(&self) -> Option<Duration> {
        self.running.as_ref().and(self.engine.poll_timeout())
    }

    pub fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        self.engine.handle_timeout(now, out);
        self.advance(now, out);
    }

    /// The step's selection, once it is done.
    pub fn poll_result(&mut self) -> Option<Selected> {
        self.result.take()
    }

    /// Ends the running selection at once with the sensors chosen so far.
    pub fn finish_now(&mut self, now: Duration, out: &mut Vec<Outgoing>) -> Option<Selected> {
        if self.running.is_some() {
            let _ = self.engine.finish_now(now, out);
            self.finish(now);
        }
        self.result.take()
    }

    /// This node's best proposal for the running iteration, sent off.
    fn propose(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(it) = &self.running else {
            return;
        };
        let proposal = best_candidate(self.node, &self.own_sensors, it, self.per_node);
        let offset = it.iteration.saturating_mul(self.rounds);
        let (step, view) = (it.step, it.view.clone());
        self.engine
            .start_at(step, offset, proposal, &view, now, out);
        self.advance(now, out);
    }

    /// Takes a finished iteration's winner and starts the next iteration,
    /// or ends the selection.
    fn advance(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(done) = self.engine.take_done() else {
            return;
        };
        if self.take_winner(&done.value) {
            // May finish at once, and recurse, on a node with no live neighbour.
            self.propose(now, out);
        } else {
            self.finish(now);
        }
    }

    /// Adds the agreed winner to `Σ_A J̄` (and, at its owner, to the chosen);
    /// whether another iteration follows.
    fn take_winner(&mut self, winner: &Proposal) -> bool {
        let Some(it) = self.running.as_mut() else {
            return false;
        };
        it.iteration += 1;
        if winner.is_nothing() {
            return false;
        }
        let [xx, xy, yy] = winner.information;
        it.sum[(0, 0)] += xx;
        it.sum[(0, 1)] += xy;
        it.sum[(1, 0)] += xy;
        it.sum[(1, 1)] += yy;
        it.total += 1;
        if winner.node == self.node {
            if let Some(i) = self.own_sensors.iter().position(|s| *s == winner.sensor) {
                it.chosen[i] = true;
            }
        }
        (it.total as usize) < self.max_total
    }

    fn finish(&mut self, now: Duration) {
        let Some(it) = self.running.take() else {
            return;
        };
        if self.scoring == Scoring::AtEstimate {
            self.tichavsky = it.inputs.predicted + it.sum;
        }
        self.result = Some(Selected {
            own: (0..it.chosen.len()).filter(|i| it.chosen[*i]).collect(),
            total: it.total,
            iterations: it.iteration,
            elapsed: now.saturating_sub(it.started),
        });
    }
}

/// The node's least-cost sensor not yet chosen, or a proposal of nothing
/// when the node is at its cap or has no sensor left.
fn best_candidate(node: u16, own_sensors: &[u16], it: &Iterating, per_node: usize) -> Proposal {
    let nothing = Proposal {
        cost: Proposal::NOTHING,
        node,
        sensor: u16::MAX,
        information: [0.0; 3],
    };
    if it.chosen.iter().filter(|c| **c).count() >= per_node {
        return nothing;
    }
    let mut best = nothing;
    for (i, info) in it.inputs.own.iter().enumerate() {
        if it.chosen[i] {
            continue;
        }
        let Some(cost) = selection_cost(&it.inputs.predicted, &it.sum, info) else {
            continue;
        };
        let candidate = Proposal {
            // A real cost, however large, stays below "nothing".
            cost: cost.min(Proposal::NOTHING * 0.5),
            node,
            sensor: own_sensors[i],
            information: [info[(0, 0)], info[(0, 1)], info[(1, 1)]],
        };
        if proposal_order(&candidate, &best) == Ordering::Less {
            best = candidate;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounds::selection::{greedy, Candidate};
    use fusion_graph::wire::Payload;
    use fusion_graph::ActorId;

    const TIMEOUT: Duration = Duration::from_millis(50);

    fn line() -> Topology {
        let s = Scenario::from_toml(crate::harness::LINE, "line", &[]).unwrap();
        Topology::from_scenario(&s, "line").unwrap()
    }

    fn position_info(xx: f64, xy: f64, yy: f64) -> Mat4 {
        let mut m = Mat4::zeros();
        m[(0, 0)] = xx;
        m[(0, 1)] = xy;
        m[(1, 0)] = xy;
        m[(1, 1)] = yy;
        m
    }

    /// Sensor `s`'s information: each informative along one axis, more so
    /// for some, so that diminishing returns matter.
    fn sensor_info(s: u16) -> Mat4 {
        let strength = 0.05 + 0.03 * ((s * 7) % 5) as f64;
        if s.is_multiple_of(2) {
            position_info(strength, 0.01, 0.1 * strength)
        } else {
            position_info(0.1 * strength, -0.01, strength)
        }
    }

    fn predicted() -> Mat4 {
        Mat4::from_diagonal(&State::new(0.02, 0.02, 0.5, 0.5))
    }

    /// Runs one step's selection on the line with virtual time: messages
    /// are carried at once unless `drop` says so, and timeouts fire when
    /// nothing is in flight. Returns each node's result (`None` for a node
    /// not started) and the virtual time it took.
    fn select(
        cap: usize,
        n_max: usize,
        started: [bool; 3],
        mut drop: impl FnMut(&Message) -> bool,
    ) -> (Vec<Option<Selected>>, Duration) {
        let t = line();
        let mut nodes: Vec<PcrlbSelection> = (0..3)
            .map(|i| {
                PcrlbSelection::new(
                    i,
                    &t,
                    Scoring::Conditional,
                    cap,
                    n_max,
                    TIMEOUT,
                    Mat4::identity(),
                )
            })
            .collect();
        let mut results: Vec<Option<Selected>> = vec![None; 3];
        let mut now = Duration::ZERO;
        let mut queue: Vec<Outgoing> = Vec::new();
        let view = [true; 3];
        for i in 0..3u16 {
            if started[i as usize] {
                let inputs = SelectionInputs {
                    predicted: predicted(),
                    own: t.node_sensors[i as usize]
                        .iter()
                        .map(|s| sensor_info(*s))
                        .collect(),
                };
                nodes[i as usize].expect_step(1);
                nodes[i as usize].start(1, inputs, &view, now, &mut queue);
            }
        }
        loop {
            for (i, n) in nodes.iter_mut().enumerate() {
                if let Some(r) = n.poll_result() {
                    results[i] = Some(r);
                }
            }
            if let Some(o) = queue.pop() {
                if drop(&o.message) {
                    continue;
                }
                for to in o.receivers {
                    let ActorId::Node(n) = to else { continue };
                    if started[n as usize] {
                        let mut out = Vec::new();
                        nodes[n as usize].handle(&o.message, now, &mut out);
                        queue.extend(out);
                    }
                }
                continue;
            }
            let Some(next) = nodes.iter().filter_map(|n| n.poll_timeout()).min() else {
                return (results, now);
            };
            now = now.max(next);
            for n in nodes.iter_mut() {
                n.handle_timeout(now, &mut queue);
            }
        }
    }

    fn chosen_by(results: &[Option<Selected>]) -> Vec<(u16, u16)> {
        let t = line();
        let mut v = Vec::new();
        for (i, r) in results.iter().enumerate() {
            if let Some(r) = r {
                v.extend(r.own.iter().map(|p| (i as u16, t.node_sensors[i][*p])));
            }
        }
        v.sort();
        v
    }

    #[test]
    fn the_distributed_choice_is_the_greedy_one() {
        let t = line();
        let candidates: Vec<Candidate> = (0..3u16)
            .flat_map(|n| {
                t.node_sensors[n as usize].iter().map(move |s| Candidate {
                    node: n,
                    sensor: *s,
                    information: sensor_info(*s),
                })
            })
            .collect();
        for (cap, n_max) in [(1, 3), (2, 4), (3, 9), (2, 2)] {
            let (results, took) = select(cap, n_max, [true; 3], |_| false);
            let mut expected = greedy(&predicted(), &candidates, cap, n_max);
            expected.sort();
            assert_eq!(chosen_by(&results), expected, "cap {cap}, N_max {n_max}");
            assert!(results.iter().all(|r| r
                .as_ref()
                .is_some_and(|r| r.total as usize == expected.len())));
            assert_eq!(took, Duration::ZERO, "no one waited");
        }
    }

    #[test]
    fn every_message_is_a_counted_min_consensus_round() {
        let mut sent = 0;
        let (results, _) = select(2, 4, [true; 3], |m| {
            assert!(matches!(m.payload, Payload::MinConsensus(_)));
            sent += 1;
            false
        });
        // 4 iterations × diameter 2 rounds × 4 senders' messages (node 1
        // sends one message to its two neighbours: one per round).
        assert_eq!(results[0].as_ref().unwrap().iterations, 4);
        assert_eq!(sent, 4 * 2 * 3);
    }

    #[test]
    fn a_node_lost_mid_selection_costs_two_timeouts_not_the_step() {
        // Node 2 falls silent after its first iteration (wire rounds 1, 2).
        let (results, took) = select(2, 6, [true; 3], |m| {
            m.header.sender == ActorId::Node(2) && m.header.round > 2
        });
        // Node 1 waits out two rounds, then goes on without it; node 0,
        // whose rounds wait on node 1's, may wait out one more. Without the
        // rule every one of the 10 rounds left would cost a timeout.
        assert!(took <= 3 * TIMEOUT, "took {took:?}");
        let (a, b) = (results[0].as_ref().unwrap(), results[1].as_ref().unwrap());
        assert_eq!((a.total, b.total), (b.total, a.total));
        assert!(a.total >= 4, "{a:?}");
    }

    #[test]
    fn with_no_room_left_the_selection_stops_early() {
        // Caps of 1 on three nodes: at most 3 sensors whatever N_max says.
        let (results, _) = select(1, 8, [true; 3], |_| false);
        assert_eq!(chosen_by(&results).len(), 3);
        let r = results[1].as_ref().unwrap();
        assert_eq!((r.total, r.iterations), (3, 4), "the fourth found nothing");
    }

    #[test]
    fn a_node_dead_before_the_selection_costs_two_timeouts() {
        let (results, took) = select(2, 4, [true, true, false], |_| false);
        assert!(results[2].is_none());
        assert_eq!(took, 2 * TIMEOUT);
        assert_eq!(chosen_by(&results).len(), 4);
    }
}
