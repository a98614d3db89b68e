//! The exact network sums, as if consensus had converged: a checking mode.
//! The nodes of one process (`cqnet sim`) share an [`ExactSumOracle`]; each
//! deposits its vector and takes the exact sum over its live component once
//! every member has deposited. Separate processes share no oracle, so
//! `cqnet run` refuses this protocol.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::rc::Rc;
use std::time::Duration;

use fusion_graph::Topology;
use wire::Message;

use super::{Fused, FusionProtocol, Handled, InformationVector, RoundStats};
use crate::Outgoing;

/// The vectors deposited per step, by node.
#[derive(Debug, Default)]
pub struct ExactSumOracle {
    deposits: BTreeMap<u32, BTreeMap<u16, InformationVector>>,
}

impl ExactSumOracle {
    pub fn shared() -> Rc<RefCell<Self>> {
        Rc::new(RefCell::new(Self::default()))
    }

    /// The sum over the nodes of `view` at `step`, once all have deposited;
    /// summed in node order, so every member gets the same numbers.
    fn sum(&self, step: u32, view: &[bool]) -> Option<InformationVector> {
        let deposits = self.deposits.get(&step)?;
        let mut members = (0..view.len() as u16).filter(|i| view[*i as usize]);
        let first = *deposits.get(&members.next()?)?;
        members.try_fold(first, |mut acc, m| {
            acc.add_scaled(1.0, deposits.get(&m)?);
            Some(acc)
        })
    }

    fn forget_before(&mut self, step: u32) {
        self.deposits.retain(|s, _| *s >= step);
    }
}

struct Pending {
    step: u32,
    own: InformationVector,
    view: Vec<bool>,
    deadline: Duration,
}

pub struct ExactSums {
    node: u16,
    oracle: Rc<RefCell<ExactSumOracle>>,
    /// How long to wait for the others before fusing alone.
    timeout: Duration,
    live_neighbours: Vec<u16>,
    pending: Option<Pending>,
    /// What the node fuses with after waiting in vain.
    given_up: Option<Fused>,
}

impl ExactSums {
    pub fn new(
        node: u16,
        topology: &Topology,
        oracle: Rc<RefCell<ExactSumOracle>>,
        timeout: Duration,
    ) -> Self {
        Self {
            node,
            oracle,
            timeout,
            live_neighbours: topology.neighbours[node as usize].clone(),
            pending: None,
            given_up: None,
        }
    }

    fn stats(&self, view: &[bool]) -> RoundStats {
        RoundStats {
            rounds_completed: 0,
            neighbours_heard: self
                .live_neighbours
                .iter()
                .filter(|m| view[**m as usize])
                .count() as u16,
            neighbours_expected: self.live_neighbours.len() as u16,
            ..RoundStats::default()
        }
    }
}

impl FusionProtocol for ExactSums {
    type Value = InformationVector;
    type Output = Fused;

    fn expect_step(&mut self, step: u32) {
        self.oracle
            .borrow_mut()
            .forget_before(step.saturating_sub(1));
    }

    fn start(
        &mut self,
        step: u32,
        value: InformationVector,
        view: &[bool],
        now: Duration,
        _out: &mut Vec<Outgoing>,
    ) {
        let mut view = view.to_vec();
        view[self.node as usize] = true;
        self.oracle
            .borrow_mut()
            .deposits
            .entry(step)
            .or_default()
            .insert(self.node, value);
        self.pending = Some(Pending {
            step,
            own: value,
            view,
            deadline: now + self.timeout,
        });
    }

    /// The oracle carries everything: no message is this protocol's.
    fn handle(&mut self, _message: &Message, _now: Duration, _out: &mut Vec<Outgoing>) -> Handled {
        Handled::NotMine
    }

    fn poll_timeout(&self) -> Option<Duration> {
        self.pending.as_ref().map(|p| p.deadline)
    }

    /// At the deadline the node stops waiting for the others (one that
    /// never deposits must not hold it, nor leave a past deadline that would
    /// wake its driver again and again) and fuses alone.
    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        if self.pending.as_ref().is_some_and(|p| now >= p.deadline) {
            self.given_up = self.finish_now(now, out);
        }
    }

    fn poll_result(&mut self) -> Option<Fused> {
        if let Some(fused) = self.given_up.take() {
            return Some(fused);
        }
        let p = self.pending.as_ref()?;
        let sum = self.oracle.borrow().sum(p.step, &p.view)?;
        let stats = self.stats(&p.view);
        self.pending = None;
        Some(Fused {
            sums: sum.to_sums(),
            stats,
        })
    }

    /// Whatever the oracle has, or this node's own vector alone.
    fn finish_now(&mut self, _now: Duration, _out: &mut Vec<Outgoing>) -> Option<Fused> {
        if let Some(done) = self.poll_result() {
            return Some(done);
        }
        let p = self.pending.take()?;
        Some(Fused {
            sums: p.own.to_sums(),
            stats: self.stats(&p.view),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::Scenario;

    fn line() -> Topology {
        let s = Scenario::from_toml(crate::harness::LINE, "line", &[]).unwrap();
        Topology::from_scenario(&s, "line").unwrap()
    }

    fn vector(k: f64) -> InformationVector {
        InformationVector {
            delta_eta: [k; 4],
            delta_lambda: [k; 10],
            delta_l: [k; 10],
            delta_l_late: [0.0; 10],
            s_obs: None,
        }
    }

    #[test]
    fn every_member_gets_the_exact_sum_once_all_deposited() {
        let t = line();
        let oracle = ExactSumOracle::shared();
        let timeout = Duration::from_millis(50);
        let mut nodes: Vec<ExactSums> = (0..3)
            .map(|i| ExactSums::new(i, &t, oracle.clone(), timeout))
            .collect();
        let mut out = Vec::new();
        for (i, n) in nodes.iter_mut().enumerate() {
            assert!(n.poll_result().is_none());
            n.start(
                4,
                vector(i as f64 + 1.0),
                &[true; 3],
                Duration::ZERO,
                &mut out,
            );
        }
        assert!(out.is_empty(), "the oracle carries everything");
        for n in &mut nodes {
            assert_eq!(n.poll_result().unwrap().sums.delta_eta[0], 6.0);
        }
    }

    #[test]
    fn a_member_that_never_deposits_costs_one_timeout_then_the_node_fuses_alone() {
        let t = line();
        let oracle = ExactSumOracle::shared();
        let mut n = ExactSums::new(0, &t, oracle, Duration::from_millis(50));
        let mut out = Vec::new();
        n.start(1, vector(2.0), &[true; 3], Duration::ZERO, &mut out);
        n.handle_timeout(Duration::from_millis(49), &mut out);
        assert!(n.poll_result().is_none());
        n.handle_timeout(Duration::from_millis(50), &mut out);
        assert_eq!(n.poll_timeout(), None, "no past deadline left behind");
        assert_eq!(n.poll_result().unwrap().sums.delta_eta[0], 2.0);
    }
}
