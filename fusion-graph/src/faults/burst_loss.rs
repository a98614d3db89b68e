//! Gilbert–Elliott burst loss: per link a two-state chain, stepped once per
//! message, that enters the bad state with `enter_bad` and leaves it with
//! `leave_bad`; a message is lost with `loss_good` or `loss_bad`.

use serde::{Deserialize, Serialize};

use super::on_links::{on_its_links, LinkFault};
use super::select::LinkSelector;
use crate::check::Check;
use crate::shaper::{GilbertElliott, LinkRule};
use crate::ScenarioError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BurstLoss {
    pub links: Vec<LinkSelector>,
    pub at_step: u32,
    pub duration: Option<u32>,
    pub enter_bad: f64,
    pub leave_bad: f64,
    #[serde(default)]
    pub loss_good: f64,
    #[serde(default = "certain")]
    pub loss_bad: f64,
}

fn certain() -> f64 {
    1.0
}

impl LinkFault for BurstLoss {
    on_its_links!();

    fn check_values(&self, check: &Check) -> Result<(), ScenarioError> {
        check.probability("enter_bad", self.enter_bad)?;
        check.probability("leave_bad", self.leave_bad)?;
        check.probability("loss_good", self.loss_good)?;
        check.probability("loss_bad", self.loss_bad)
    }

    fn effect(&self) -> String {
        format!(
            "burst loss (Gilbert-Elliott p={} r={}, loss {}/{})",
            self.enter_bad, self.leave_bad, self.loss_good, self.loss_bad
        )
    }

    fn shape(&self, rule: &mut LinkRule) {
        // One chain per link: the later fault's, if two overlap.
        rule.burst = Some(GilbertElliott {
            enter_bad: self.enter_bad,
            leave_bad: self.leave_bad,
            loss_good: self.loss_good,
            loss_bad: self.loss_bad,
        });
    }

    fn loses_messages(&self) -> bool {
        true
    }
}
