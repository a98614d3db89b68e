//! Messages held back on their links: a latency, a jitter on it, and a
//! rate limit (netem's `delay` and `rate`).

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::check::Check;
use super::kind::{FaultKind, Targets, Window};
use super::select::LinkSelector;
use super::select::{check_links, link_targets, links_text, takes_link};
use crate::actor::ActorId;
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

impl FaultKind for Delay {
    fn window(&self) -> Window {
        Window::lasting(self.at_step, self.duration)
    }

    fn targets(&self) -> Targets<'_> {
        link_targets(&self.links)
    }

    fn check(&self, check: &Check) -> Result<(), ScenarioError> {
        check_links(&self.links, check)?;
        check.non_negative("latency_ms", self.latency_ms)?;
        check.non_negative("jitter_ms", self.jitter_ms)?;
        check.non_negative("rate_bps", self.rate_bps)?;
        check.duration(self.duration)
    }

    fn describe(&self) -> String {
        let rate = if self.rate_bps > 0.0 {
            format!(", rate {} bit/s", self.rate_bps)
        } else {
            String::new()
        };
        format!(
            "delay {} ms ± {} ms{rate} on {}",
            self.latency_ms,
            self.jitter_ms,
            links_text(&self.links)
        )
    }

    fn acts_on_links(&self) -> bool {
        true
    }

    fn shape_link(&self, fault: usize, from: ActorId, to: ActorId, rule: &mut LinkRule) {
        if !takes_link(&self.links, fault, from, to) {
            return;
        }
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
