//! The exact network sums, as if consensus had converged: a checking mode.
//! The nodes of one process (`cqnet sim`) share an [`ExactSumOracle`]; each
//! deposits its vector and takes the exact sum over its live component once
//! every member has deposited. Separate processes share no oracle, so
//! `cqnet run` refuses this protocol.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::rc::Rc;
use std::time::Duration;

use fusion_graph::wire::Message;
use fusion_graph::Topology;

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

    /// Only a wake-up to look at the oracle again; giving up is `finish_now`.
    fn handle_timeout(&mut self, _now: Duration, _out: &mut Vec<Outgoing>) {}

    fn poll_result(&mut self) -> Option<Fused> {
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
