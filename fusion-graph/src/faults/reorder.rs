//! Each message held back `delay_ms` with `probability`, so that messages
//! sent after it overtake it (netem's `reorder`).

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::on_links::{on_its_links, LinkFault};
use super::select::either;
use super::select::LinkSelector;
use crate::check::Check;
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

impl LinkFault for Reorder {
    on_its_links!();

    fn check_values(&self, check: &Check) -> Result<(), ScenarioError> {
        check.probability("probability", self.probability)?;
        check.positive("delay_ms", self.delay_ms)
    }

    fn effect(&self) -> String {
        format!(
            "reorder {} (held back {} ms)",
            self.probability, self.delay_ms
        )
    }

    fn shape(&self, rule: &mut LinkRule) {
        rule.reorder = either(rule.reorder, self.probability);
        rule.reorder_delay = rule
            .reorder_delay
            .max(Duration::from_secs_f64(self.delay_ms / 1e3));
    }
}
