//! The CF/DPF node's part in a negotiated sensor selection (any
//! `NegotiatedManager`; cqnet's is the PCRLB selection, gathered to the
//! fusion graph's centre along a spanning tree and chosen there once): its
//! scores, from the fusion filter's prediction,
//! computed in the step or ahead of it, and the activation once the choice
//! reaches it. A manager that chooses alone is asked here too.

use std::time::Duration;

use crate::sensor_manager::{Manager, SelectionInputs};
use crate::Outgoing;

use super::{CfDpfNode, Phase};

#[derive(Debug)]
pub(super) struct Selecting {
    pub(super) step: u32,
    /// The scores, from [`Work::SelectionScores`] until the selection starts.
    pub(super) inputs: Option<SelectionInputs>,
    pub(super) scored: bool,
    pub(super) scoring_time: Duration,
    /// When the selection's rounds began.
    pub(super) rounds_started: Duration,
}

/// The next step's selection scores, computed in the idle time after a
/// step's report so that the step itself starts with its candidates ready.
/// Nothing between a report and the next `BeginStep` touches the fusion
/// filter but a neighbour's state for a rejoining node, which drops them;
/// a step begun other than the next drops them too (the filter coasts).
///
/// In real time the scoring waits for the step's deadline, when every
/// node's waits have closed: scored at once after the report, it took the
/// CPU from neighbours still in their last consensus rounds (round p50
/// 240 → 570 µs on two cores with the selection paper's network).
#[derive(Debug)]
pub(super) struct ScoredAhead {
    pub(super) step: u32,
    /// When the scoring may run.
    pub(super) due: Duration,
    /// `None` until [`Work::SelectionScores`] has run.
    pub(super) inputs: Option<SelectionInputs>,
    pub(super) scoring_time: Duration,
    /// Set once `due` has passed.
    pub(super) released: bool,
}

impl ScoredAhead {
    /// Released and not yet scored.
    pub(super) fn wants_scoring(&self) -> bool {
        self.released && self.inputs.is_none()
    }
}

impl CfDpfNode {
    /// When the next step's scoring may run, while it waits.
    pub(super) fn ahead_due(&self) -> Option<Duration> {
        let a = self.ahead.as_ref().filter(|a| !a.released)?;
        matches!(self.phase, Phase::Idle).then_some(a.due)
    }

    /// A manager that chooses alone, from the prediction if it asks for one.
    pub(super) fn choose_alone(&mut self, step: u32) -> Vec<usize> {
        let Manager::Alone(manager) = &mut self.manager else {
            return Vec::new();
        };
        let predicted = if manager.needs_prediction() {
            match self.fusion.predict(&self.model) {
                Ok(p) => Some(p),
                Err(e) => {
                    tracing::error!(node = self.core.index(), error = %e, "prediction failed");
                    None
                }
            }
        } else {
            None
        };
        manager.choose(&self.core.selection_context(step, predicted))
    }

    /// The selection's scores, from the fusion filter's prediction.
    pub(super) fn score_selection(&mut self) {
        let own = self.own_sensors().to_vec();
        let Manager::Negotiated(selection) = &mut self.manager else {
            return;
        };
        let slot = match (&mut self.phase, self.ahead.as_mut()) {
            (Phase::Selecting(s), _) if !s.scored => {
                s.scored = true;
                &mut s.inputs
            }
            (Phase::Idle, Some(ahead)) => &mut ahead.inputs,
            _ => return,
        };
        let inputs = selection.inputs(&mut self.fusion, &self.model, &own)
            .unwrap_or_else(|e| {
                tracing::error!(node = self.core.index(), error = %e, "selection scores failed; proposing nothing");
                SelectionInputs {
                    predicted: bounds::Mat4::identity(),
                    own: Vec::new(),
                }
            });
        *slot = Some(inputs);
    }

    /// Starts the selection with its scores, computed just now or, `ahead`,
    /// before the step began (their time is then not the step's).
    pub(super) fn start_selection(
        &mut self,
        scoring_time: Duration,
        ahead: bool,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let (Phase::Selecting(s), Manager::Negotiated(selection)) =
            (&mut self.phase, &mut self.manager)
        else {
            return;
        };
        let Some(inputs) = s.inputs.take() else {
            return;
        };
        s.scoring_time = if ahead { Duration::ZERO } else { scoring_time };
        s.rounds_started = now;
        self.scoring_time = scoring_time;
        selection.expect_step(s.step);
        selection.start(s.step, inputs, self.core.view(), now, out);
        self.poll_selection(now, out);
    }

    /// Activates the selection's sensors once it is done.
    pub(super) fn poll_selection(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let (Phase::Selecting(s), Manager::Negotiated(selection)) =
            (&self.phase, &mut self.manager)
        else {
            return;
        };
        if let Some(selected) = selection.poll_result() {
            // Scoring as the driver timed it, if it ran in the step, then
            // the gather and the choice by the clock.
            self.selection_time = s.scoring_time + now.saturating_sub(s.rounds_started);
            let step = s.step;
            self.without_choice = !selected.heard;
            self.activate(step, selected.own, now, out);
        }
    }
}
