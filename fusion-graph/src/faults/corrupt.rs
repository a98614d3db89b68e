//! One random bit of each message flipped with `probability` (netem's
//! `corrupt`); the header's checksum catches it.

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
pub struct Corrupt {
    pub links: Vec<LinkSelector>,
    pub at_step: u32,
    pub duration: Option<u32>,
    pub probability: f64,
}

impl FaultKind for Corrupt {
    fn window(&self) -> Window {
        Window::lasting(self.at_step, self.duration)
    }

    fn targets(&self) -> Targets<'_> {
        link_targets(&self.links)
    }

    fn check(&self, check: &Check) -> Result<(), ScenarioError> {
        check_links(&self.links, check)?;
        check.probability("probability", self.probability)?;
        check.duration(self.duration)
    }

    fn describe(&self) -> String {
        format!(
            "corrupt {} on {}",
            self.probability,
            links_text(&self.links)
        )
    }

    fn acts_on_links(&self) -> bool {
        true
    }

    fn shape_link(&self, fault: usize, from: ActorId, to: ActorId, rule: &mut LinkRule) {
        if takes_link(&self.links, fault, from, to) {
            rule.corrupt = either(rule.corrupt, self.probability);
        }
    }
}
