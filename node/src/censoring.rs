//! The node's side of NIS censoring: the estimate it feeds back to its
//! sensors with their activation, its copy of each own sensor's censor, and
//! the silences of a step as measurements for its filter.

use bounds::censoring::{CensoringRule, Feedback, Innovation, NisCensor};
use fusion_graph::scenario::{CensoringPolicy, FeedbackKind, Scenario};
use fusion_graph::{ScenarioError, Topology};
use wire::{BitMask, Payload};

use crate::estimator::{Censored, SensingModel};
use crate::filter::Gaussian;
use crate::fusion::information::pack_matrix;

/// The node's side of NIS censoring: what it feeds back, its copy of each
/// own sensor's censoring state, and the innovations its active sensors
/// censor by this step, so that it can weigh their silence.
#[derive(Debug)]
pub(crate) struct NodeCensoring {
    feedback: FeedbackKind,
    /// By position in the node's own sensor list.
    censors: Vec<NisCensor>,
    /// The latest fused posterior, fed back with the next activation.
    pub(crate) fed_back: Gaussian,
    /// This step's active sensors and their innovation statistics.
    pending: (u32, Vec<(u16, Innovation)>),
    /// CFoMD: censor, but weigh nothing for silence.
    ignore_silence: bool,
}

impl NodeCensoring {
    pub(crate) fn for_scenario(
        scenario: &Scenario,
        models: &fusion_graph::Models,
        topology: &Topology,
        index: u16,
    ) -> Result<Option<Self>, ScenarioError> {
        let c = &scenario.censoring;
        if c.policy != CensoringPolicy::Nis {
            return Ok(None);
        }
        let rule =
            CensoringRule::for_budget(c.budget, scenario.sensors.active_per_node as usize, 1)
                .map_err(|e| ScenarioError::Invalid {
                    file: scenario.name.clone(),
                    key: "censoring.budget".into(),
                    expected: e.expected.into(),
                    got: e.value.to_string(),
                })?;
        let own = topology.node_sensors[index as usize].len();
        Ok(Some(Self {
            feedback: c.feedback,
            censors: vec![NisCensor::new(rule, models.prior_cov); own],
            fed_back: scenario.network_prior(models),
            pending: (0, Vec::new()),
            ignore_silence: c.ignore_silence,
        }))
    }

    /// The activation with the feedback, and the innovations the activated
    /// sensors will censor by (the same computation as theirs).
    pub(crate) fn activate(
        &mut self,
        step: u32,
        picks: &[usize],
        own: &[u16],
        model: &SensingModel,
        mask: BitMask,
    ) -> Payload {
        let covariance =
            (self.feedback == FeedbackKind::EstimateAndCovariance).then_some(self.fed_back.cov);
        let feedback = Feedback {
            estimate: self.fed_back.mean,
            covariance,
        };
        let innovations = picks
            .iter()
            .map(|&i| {
                let sensor = own[i];
                let innovation = self.censors[i].innovation(
                    step,
                    &feedback,
                    &model.sensors[sensor as usize],
                    &model.dynamics,
                );
                (sensor, innovation)
            })
            .collect();
        self.pending = (step, innovations);
        Payload::ActivateWithFeedback {
            mask,
            estimate: feedback.estimate.into(),
            covariance: covariance.as_ref().map(pack_matrix),
        }
    }

    /// The step's silent sensors as measurements (none for CFoMD, which
    /// ignores silence).
    pub(crate) fn silences(&self, step: u32, silent: &[u16]) -> Vec<Censored> {
        if self.ignore_silence {
            return Vec::new();
        }
        let mut all = self.active(step);
        all.retain(|c| silent.contains(&c.sensor));
        all
    }

    /// Every sensor activated for `step`, with the window it censors by:
    /// what the bound weighs, sent or silent. The bound is of the data, so
    /// it counts the silences even where the filter ignores them (CFoMD).
    pub(crate) fn active(&self, step: u32) -> Vec<Censored> {
        let (pending_step, innovations) = &self.pending;
        let Some(rule) = self.censors.first().map(|c| c.rule) else {
            return Vec::new();
        };
        if *pending_step != step {
            return Vec::new();
        }
        innovations
            .iter()
            .map(|(sensor, innovation)| Censored {
                sensor: *sensor,
                innovation: *innovation,
                rule,
            })
            .collect()
    }
}
