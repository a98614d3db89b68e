//! A step's report to the launcher, built by name: each node kind says what
//! it has (its estimate, its bounds, its rounds, the time of each of its
//! stages) and leaves the rest at nothing; the node core adds what it keeps.

use std::time::Duration;

use bounds::State;
use wire::{Stage, Telemetry};

use crate::fusion::RoundStats;

/// A step's telemetry, field by field.
#[derive(Debug, Clone)]
pub struct Report {
    telemetry: Telemetry,
    /// With censoring a sensor's silence is its answer: none is reported
    /// as not answering.
    silence_answers: bool,
}

impl Report {
    /// A report of `estimate` and nothing else yet. A component that is
    /// not finite is sent as 0: the wire carries no NaN the launcher would
    /// have to guard against.
    pub fn of(estimate: &State) -> Self {
        let estimate = std::array::from_fn(|i| {
            if estimate[i].is_finite() {
                estimate[i]
            } else {
                0.0
            }
        });
        Self {
            telemetry: Telemetry::of_estimate(estimate),
            silence_answers: false,
        }
    }

    /// The global bound, metres; one that is not finite is none.
    pub fn bound(mut self, bound: Option<f64>) -> Self {
        self.telemetry.bound = bound.filter(|b| b.is_finite());
        self
    }

    /// The bound of the node's own evidence, metres.
    pub fn local_bound(mut self, bound: Option<f64>) -> Self {
        self.telemetry.local_bound = bound.filter(|b| b.is_finite());
        self
    }

    /// A second global bound (the auxiliary FIM's, or what a design promised).
    pub fn aux_bound(mut self, bound: Option<f64>) -> Self {
        self.telemetry.aux_bound = bound.filter(|b| b.is_finite());
        self
    }

    /// The step's consensus: its rounds and neighbours heard, how far the
    /// node still was from them, and the time of its later rounds and of
    /// the whole.
    pub fn rounds(mut self, stats: &RoundStats) -> Self {
        self.telemetry.rounds_completed = stats.rounds_completed;
        self.telemetry.live_neighbours = stats.neighbours_heard;
        self.telemetry.missed_neighbours = stats
            .neighbours_expected
            .saturating_sub(stats.neighbours_heard);
        self.telemetry.short_rounds = stats.short_rounds;
        self.telemetry.disagreement = stats.disagreement.filter(|d| d.is_finite());
        self.stage(Stage::LaterRounds, stats.later_rounds)
            .stage(Stage::Consensus, stats.total)
    }

    /// Observations weighed this step.
    pub fn observations(mut self, n: u16) -> Self {
        self.telemetry.observations = n;
        self
    }

    /// Observations the innovation gate left out.
    pub fn gated(mut self, n: u16) -> Self {
        self.telemetry.gated = n;
        self
    }

    /// The step before's observations weighed late this step.
    pub fn lagged(mut self, n: u16) -> Self {
        self.telemetry.lagged = n;
        self
    }

    /// The time `stage` took, in whole microseconds (saturating).
    pub fn stage(mut self, stage: Stage, time: Duration) -> Self {
        self.telemetry.stage_micros[stage as usize] = time.as_micros().min(u32::MAX as u128) as u32;
        self
    }

    /// The spread of the prediction the sensor manager scored on, metres.
    pub fn spread(mut self, spread: Option<f64>) -> Self {
        self.telemetry.spread = spread.filter(|s| s.is_finite());
        self
    }

    /// The sensors activated this step.
    pub fn active(mut self, sensors: Vec<u16>) -> Self {
        self.telemetry.active = sensors;
        self
    }

    /// Each sensor's transmission probability, in ten-thousandths.
    pub fn design(mut self, design: Vec<u16>) -> Self {
        self.telemetry.design = design;
        self
    }

    /// A negotiated selection's choice never reached the node this step.
    pub fn without_choice(mut self, without: bool) -> Self {
        self.telemetry.without_choice = without;
        self
    }

    /// Silence is an answer (censoring): no sensor is reported as not answering.
    pub fn silence_answers(mut self, yes: bool) -> Self {
        self.silence_answers = yes;
        self
    }

    /// The telemetry, with what the node core keeps.
    pub(super) fn finish(
        mut self,
        late_messages: u32,
        deadline_missed: bool,
        unanswered: (u16, Option<u16>),
    ) -> Telemetry {
        let t = &mut self.telemetry;
        t.late_messages = late_messages;
        t.deadline_missed = deadline_missed;
        if !self.silence_answers {
            (t.unanswered_sensors, t.first_unanswered) = unanswered;
        }
        self.telemetry
    }
}
