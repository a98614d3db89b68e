//! Each message on the links arrives twice with `probability` (netem's
//! `duplicate`).

use serde::{Deserialize, Serialize};

use super::on_links::{on_its_links, LinkFault};
use super::select::either;
use super::select::LinkSelector;
use crate::check::Check;
use crate::shaper::LinkRule;
use crate::ScenarioError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Duplicate {
    pub links: Vec<LinkSelector>,
    pub at_step: u32,
    pub duration: Option<u32>,
    pub probability: f64,
}

impl LinkFault for Duplicate {
    on_its_links!();

    fn check_values(&self, check: &Check) -> Result<(), ScenarioError> {
        check.probability("probability", self.probability)
    }

    fn effect(&self) -> String {
        format!("duplicate {}", self.probability)
    }

    fn shape(&self, rule: &mut LinkRule) {
        rule.duplicate = either(rule.duplicate, self.probability);
    }
}
