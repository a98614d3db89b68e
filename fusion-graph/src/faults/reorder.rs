//! Each message held back `delay_ms` with `probability`, so that messages
//! sent after it overtake it (netem's `reorder`).

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::check::Check;
use super::kind::{FaultKind, Targets, Window};
use super::select::LinkSelector;
use super::select::{check_links, either, link_targets, links_text, takes_link};
use crate::actor::ActorId;
use crate::shaper::LinkRule;
use crate::ScenarioError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Reorder {
    pub links: Vec<LinkSelector>,
    pub at_step: u32,
    pub duration: Option<u32>,
    pub probability: f64,
    pub delay_ms: f64,
}

impl FaultKind for Reorder {
    fn window(&self) -> Window {
        Window::lasting(self.at_step, self.duration)
    }

    fn targets(&self) -> Targets<'_> {
        link_targets(&self.links)
    }

    fn check(&self, check: &Check) -> Result<(), ScenarioError> {
        check_links(&self.links, check)?;
        check.probability("probability", self.probability)?;
        check.positive("delay_ms", self.delay_ms)?;
        check.duration(self.duration)
    }

    fn describe(&self) -> String {
        format!(
            "reorder {} (held back {} ms) on {}",
            self.probability,
            self.delay_ms,
            links_text(&self.links)
        )
    }

    fn acts_on_links(&self) -> bool {
        true
    }

    fn shape_link(&self, fault: usize, from: ActorId, to: ActorId, rule: &mut LinkRule) {
        if takes_link(&self.links, fault, from, to) {
            rule.reorder = either(rule.reorder, self.probability);
            rule.reorder_delay = rule
                .reorder_delay
                .max(Duration::from_secs_f64(self.delay_ms / 1e3));
        }
    }
}
