//! Each message on the links lost with `probability` (netem's `loss`).

use serde::{Deserialize, Serialize};

use super::on_links::{on_its_links, LinkFault};
use super::select::either;
use super::select::LinkSelector;
use crate::check::Check;
use crate::shaper::LinkRule;
use crate::ScenarioError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Loss {
    pub links: Vec<LinkSelector>,
    pub at_step: u32,
    pub duration: Option<u32>,
    pub probability: f64,
}

impl LinkFault for Loss {
    on_its_links!();

    fn check_values(&self, check: &Check) -> Result<(), ScenarioError> {
        check.probability("probability", self.probability)
    }

    fn effect(&self) -> String {
        format!("loss {}", self.probability)
    }

    fn shape(&self, rule: &mut LinkRule) {
        rule.loss = either(rule.loss, self.probability);
    }

    fn loses_messages(&self) -> bool {
        true
    }
}
