//! Messages held back on their links: a latency, a jitter on it, and a
//! rate limit (netem's `delay` and `rate`).

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::on_links::{on_its_links, LinkFault};
use super::select::LinkSelector;
use crate::check::Check;
use crate::shaper::LinkRule;
use crate::ScenarioError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Delay {
    pub links: Vec<LinkSelector>,
    pub at_step: u32,
    pub duration: Option<u32>,
    pub latency_ms: f64,
    #[serde(default)]
    pub jitter_ms: f64,
    /// netem's `rate`: the link carries this many bits per second, so a
    /// message takes its size over the rate to cross, queued behind the
    /// messages before it. 0: unlimited.
    #[serde(default)]
    pub rate_bps: f64,
}

impl LinkFault for Delay {
    on_its_links!();

    fn check_values(&self, check: &Check) -> Result<(), ScenarioError> {
        check.non_negative("latency_ms", self.latency_ms)?;
        check.non_negative("jitter_ms", self.jitter_ms)?;
        check.non_negative("rate_bps", self.rate_bps)
    }

    fn effect(&self) -> String {
        let rate = if self.rate_bps > 0.0 {
            format!(", rate {} bit/s", self.rate_bps)
        } else {
            String::new()
        };
        format!("delay {} ms ± {} ms{rate}", self.latency_ms, self.jitter_ms)
    }

    fn shape(&self, rule: &mut LinkRule) {
        let ms = |v: f64| Duration::from_secs_f64(v / 1e3);
        rule.latency = rule.latency.max(ms(self.latency_ms));
        rule.jitter = rule.jitter.max(ms(self.jitter_ms));
        // Two limits on one link: the slower holds.
        if self.rate_bps > 0.0 {
            rule.rate = if rule.rate > 0.0 {
                rule.rate.min(self.rate_bps)
            } else {
                self.rate_bps
            };
        }
    }
}
