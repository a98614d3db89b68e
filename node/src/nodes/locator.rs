//! A static target's locator node (`consensus.protocol = "ml_location"`)
//! as an I/O-free state machine, driven as every processing node is.
//!
//! A step: the launcher's `BeginStep` → the node activates its sensors,
//! sending them the quantizer's thresholds → its sensors' reports, until
//! all arrived or the listening deadline → [`Work::GridLikelihood`]: its
//! log-likelihood over the region's grid, with every report so far →
//! consensus phases of `consensus.rounds` rounds each, every one a network
//! sum ([`VectorSum`]):
//!
//! 1. the log-likelihoods over the region's grid: its best point;
//! 2. for each refinement, the log-likelihoods over a grid ten times finer
//!    (at the default 21 points) around the estimate so far: a better one;
//! 3. the sensors' Fisher information at the last estimate: the CRLB;
//!
//! → telemetry with the estimate and `sqrt(tr J⁻¹)`.
//!
//! Each finer grid is laid out around the node's own estimate so far, so a
//! phase sums like with like only when the one before has agreed on it, as
//! enough rounds make it; a node whose consensus is cut short (a lost
//! neighbour, a partition) adds a neighbour's grid to its own slightly
//! shifted one, and its estimate is off by the difference.

use std::time::Duration;

use bounds::{Quantizer, State};
use fusion_graph::scenario::Scenario;
use fusion_graph::{ActorId, Topology};
use wire::{Message, Payload, Stage};

use crate::collector::{Collector, Offer};
use crate::estimator::ObservedValue;
use crate::fusion::{vector_sum, FusionProtocol, Handled, RoundStats, Summed, VectorSum};
use crate::location::{position_bound, sensor_quantizer, Grid, LocalEvidence, LocationConfig};
use crate::sensor_manager::{SensorManager, UniformRandom};
use crate::{NodeError, Outgoing, Work};

use super::core::mask;
use super::{NodeCore, NodeKind, Report};

/// One step, from `BeginStep` to its telemetry.
struct Stepping {
    step: u32,
    /// The node's sensors, while it still listens to them.
    collector: Option<Collector>,
    observations: u16,
    /// [`Work::GridLikelihood`] has run: `coarse` holds the node's log-likelihood.
    weighed: bool,
    coarse: Vec<f64>,
    /// The consensus phase running: grid phases `0..=refinements`, then
    /// the information's.
    phase: Option<usize>,
    /// The grid of the phase running (while it is a grid's).
    grid: Grid,
    /// The estimate so far, from the last grid phase done.
    estimate: Option<[f64; 2]>,
    stats: RoundStats,
    weigh_time: Duration,
}

pub struct LocatorNode {
    core: NodeCore,
    coarse: Grid,
    /// The thresholds sent with each activation; `None`: raw reports.
    quantizer: Option<Quantizer>,
    evidence: LocalEvidence,
    manager: UniformRandom,
    /// One engine per phase, each on its own rounds of the step: the
    /// grids' and, last, the information's.
    phases: Vec<VectorSum>,
    rounds: u16,
    region_centre: [f64; 2],
    /// A bound wider than the region says the sensors cannot place the
    /// target in it at all: a node far from the target, whose own sensors
    /// all read noise, has a nearly singular J and a bound of 10⁷⁰ m,
    /// reported as none.
    region_diagonal: f64,
    listen: Duration,
    stepping: Option<Box<Stepping>>,
}

impl LocatorNode {
    /// Node `index` of a locator network, with the protocol's parameters
    /// (read and checked by its factory, [`crate::parts::location_config`]).
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
        config: LocationConfig,
    ) -> Result<Self, NodeError> {
        let coarse = Grid::over_region(scenario, config.grid);
        let quantizer = sensor_quantizer(scenario, config.thresholds);
        // Every phase's rounds have their own numbers on the wire.
        let rounds = scenario.consensus.rounds.min(u32::from(u16::MAX) / 8) as u16;
        let timeout = Duration::from_secs_f64(scenario.consensus.round_timeout_ms / 1e3);
        let grids = config.refinements + 1;
        let phase = |p: usize| {
            let len = if p < grids { coarse.len() } else { 3 };
            vector_sum(index, topology, len, rounds, timeout)
                .with_last_round((p as u16 + 1) * rounds)
                .presume_gone_after(2)
                // A value in 14 pieces is whole only if all 14 arrive: on
                // a lossy link most rounds would wait out their timeout.
                .stop_awaiting_the_late()
        };
        Ok(Self {
            core: NodeCore::new(scenario, topology, index, quantizer.as_ref()),
            evidence: LocalEvidence::new(scenario, topology, index, quantizer.clone()),
            phases: (0..=grids).map(phase).collect(),
            coarse,
            quantizer,
            manager: UniformRandom::for_scenario(scenario),
            rounds,
            region_centre: [scenario.region.width / 2.0, scenario.region.height / 2.0],
            region_diagonal: scenario.region.width.hypot(scenario.region.height),
            listen: timeout,
            stepping: None,
        })
    }

    /// The node's sensors are done: their reports join the evidence.
    fn close_own(&mut self) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        let Some(collector) = s.collector.take() else {
            return;
        };
        let collected = collector.close();
        s.observations = collected.observations.len() as u16;
        self.evidence.add(&collected.observations);
    }

    /// Moves the step on through the phases whose results are in.
    fn poll_phases(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        while let Some(phase) = self.stepping.as_ref().and_then(|s| s.phase) {
            let Some(summed) = self.phases[phase].poll_result() else {
                return;
            };
            self.next_phase(phase, summed, now, out);
        }
    }

    /// Takes phase `phase`'s network sums and starts the next phase, or
    /// reports the step after the last.
    fn next_phase(&mut self, phase: usize, summed: Summed, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        s.stats.rounds_completed += summed.stats.rounds_completed;
        s.stats.neighbours_heard = summed.stats.neighbours_heard;
        s.stats.neighbours_expected = summed.stats.neighbours_expected;
        s.stats.short_rounds = s
            .stats
            .short_rounds
            .saturating_add(summed.stats.short_rounds);
        s.stats.total += summed.stats.total;
        s.stats.later_rounds += summed.stats.later_rounds;
        let information_phase = self.phases.len() - 1;
        if phase == information_phase {
            s.phase = None;
            let information = [summed.sums[0], summed.sums[1], summed.sums[2]];
            return self.report(Some(information), out);
        }
        let best = best_point(&s.grid, &summed.sums, self.region_centre);
        s.estimate = Some(best);
        let next = phase + 1;
        let value = if next == information_phase {
            self.evidence.information(best).to_vec()
        } else {
            s.grid = s.grid.around(best);
            let mut value = Vec::with_capacity(s.grid.len());
            self.evidence.log_likelihood(&s.grid, &mut value);
            value
        };
        s.phase = Some(next);
        let offset = next as u16 * self.rounds;
        self.phases[next].start_at(s.step, offset, value, self.core.view(), now, out);
    }

    /// The step's telemetry; `information` is the network's, when the last
    /// phase finished.
    fn report(&mut self, information: Option<[f64; 3]>, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.take() else {
            return;
        };
        let estimate = s.estimate.unwrap_or(self.region_centre);
        let report = Report::of(&State::new(estimate[0], estimate[1], 0.0, 0.0))
            .bound(information.and_then(position_bound))
            .local_bound(
                position_bound(self.evidence.information(estimate))
                    .filter(|b| *b <= self.region_diagonal),
            )
            .rounds(&s.stats)
            .observations(s.observations)
            .stage(Stage::Local, s.weigh_time);
        out.push(self.core.report(s.step, report));
    }
}

impl NodeKind for LocatorNode {
    fn core(&mut self) -> &mut NodeCore {
        &mut self.core
    }

    /// Ends an overrun step at once with what it has: no more waiting for
    /// sensors or neighbours; its stages are not timed.
    fn finish_overrun(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        self.close_own();
        while let Some(s) = self.stepping.as_ref() {
            if let Some(work) = self.poll_work() {
                self.run_work(work);
                self.work_done(work, Duration::ZERO, now, out);
                continue;
            }
            match s.phase {
                Some(phase) => match self.phases[phase].finish_now(now, out) {
                    Some(summed) => self.next_phase(phase, summed, now, out),
                    None => self.report(None, out),
                },
                None => self.report(None, out),
            }
        }
    }

    fn begin_step(&mut self, step: u32, _: u32, now: Duration, out: &mut Vec<Outgoing>) {
        for engine in &mut self.phases {
            engine.expect_step(step);
        }
        let picks = self
            .manager
            .choose(&self.core.selection_context(step, None));
        let mask = mask(&picks);
        let payload = match &self.quantizer {
            Some(q) => Payload::ActivateThresholds {
                mask,
                thresholds: (1..q.cells() as u32).map(|c| q.cell_edges(c).0).collect(),
            },
            None => Payload::Activate { mask },
        };
        let collector = self
            .core
            .activate(step, &picks, payload, now + self.listen, out);
        let empty = collector.is_complete();
        self.stepping = Some(Box::new(Stepping {
            step,
            collector: Some(collector),
            observations: 0,
            weighed: false,
            coarse: Vec::new(),
            phase: None,
            grid: self.coarse,
            estimate: None,
            stats: RoundStats::default(),
            weigh_time: Duration::ZERO,
        }));
        if empty {
            self.close_own();
        }
    }

    fn observe(&mut self, step: u32, sensor: u16, value: ObservedValue, _: &mut Vec<Outgoing>) {
        let collector = self.stepping.as_mut().and_then(|s| s.collector.as_mut());
        let offer = self.core.offer(collector, step, sensor, value);
        let complete = self
            .stepping
            .as_ref()
            .and_then(|s| s.collector.as_ref())
            .is_some_and(Collector::is_complete);
        if offer == Offer::Taken && complete {
            self.close_own();
        }
    }

    fn take(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        match (&message.payload, message.header.sender) {
            (Payload::LocationConsensus { .. }, ActorId::Node(_)) => {
                // Round k of phase p is round p·N_c + k on the wire.
                let phase = (message.header.round.max(1) - 1) / self.rounds.max(1);
                let handled = match self.phases.get_mut(phase as usize) {
                    Some(engine) => engine.handle(message, now, out),
                    None => Handled::Late,
                };
                match handled {
                    Handled::Taken => self.poll_phases(now, out),
                    Handled::Late | Handled::NotMine => self.core.count_late(),
                }
            }
            _ => {
                self.core.taken(Handled::NotMine, message);
            }
        }
    }

    fn poll_timeout(&self) -> Option<Duration> {
        let s = self.stepping.as_ref()?;
        let listening = s.collector.as_ref().map(Collector::deadline);
        let consensus = s.phase.and_then(|p| self.phases[p].poll_timeout());
        [listening, consensus].into_iter().flatten().min()
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        if s.collector.as_ref().is_some_and(|c| now >= c.deadline()) {
            self.close_own();
        }
        if let Some(p) = self.stepping.as_ref().and_then(|s| s.phase) {
            self.phases[p].handle_timeout(now, out);
        }
        self.poll_phases(now, out);
    }

    fn poll_work(&self) -> Option<Work> {
        let s = self.stepping.as_ref()?;
        (s.collector.is_none() && !s.weighed).then_some(Work::GridLikelihood)
    }

    /// [`Work::GridLikelihood`]: the node's log-likelihood over the coarse grid.
    fn run_work(&mut self, work: Work) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        if work == Work::GridLikelihood && !s.weighed {
            self.evidence.log_likelihood(&self.coarse, &mut s.coarse);
            s.weighed = true;
        }
    }

    fn work_done(&mut self, work: Work, elapsed: Duration, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        if work != Work::GridLikelihood || s.phase.is_some() {
            return;
        }
        s.weigh_time = elapsed;
        s.phase = Some(0);
        let value = std::mem::take(&mut s.coarse);
        self.phases[0].start_at(s.step, 0, value, self.core.view(), now, out);
        self.poll_phases(now, out);
    }
}

/// The grid's best point by the summed log-likelihood; `fallback` when
/// the sums are flat (no report anywhere yet).
fn best_point(grid: &Grid, sums: &[f64], fallback: [f64; 2]) -> [f64; 2] {
    let (lo, hi) = sums
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(*v), hi.max(*v))
        });
    if sums.len() != grid.len() || lo >= hi {
        return fallback;
    }
    grid.best(sums)
}
