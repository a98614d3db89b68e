//! The network cut into groups: no message crosses between two groups
//! while the partition holds. Actors in no group keep every link.

use serde::{Deserialize, Serialize};

use super::kind::{FaultKind, Targets, Window};
use super::select::matches;
use crate::check::Check;
use crate::shaper::LinkRule;
use crate::ScenarioError;
use wire::ActorId;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Partition {
    pub groups: Vec<Vec<String>>,
    pub at_step: u32,
    pub duration: Option<u32>,
}

impl Partition {
    fn group_of(&self, actor: ActorId) -> Option<usize> {
        self.groups
            .iter()
            .position(|g| g.iter().any(|n| matches(n, actor)))
    }
}

impl FaultKind for Partition {
    fn window(&self) -> Window {
        Window::lasting(self.at_step, self.duration)
    }

    fn targets(&self) -> Targets<'_> {
        Targets {
            key: "groups",
            names: self.groups.iter().flatten().map(String::as_str).collect(),
            sensors_only: false,
        }
    }

    fn check(&self, check: &Check) -> Result<(), ScenarioError> {
        if self.groups.len() < 2 {
            return Err(check.fail("groups", "at least two groups", self.groups.len()));
        }
        check.duration(self.duration)
    }

    fn describe(&self) -> String {
        format!("partition {:?}", self.groups)
    }

    fn acts_on_links(&self) -> bool {
        true
    }

    fn shape_link(&self, _fault: usize, from: ActorId, to: ActorId, rule: &mut LinkRule) {
        if let (Some(a), Some(b)) = (self.group_of(from), self.group_of(to)) {
            rule.blocked |= a != b;
        }
    }
}
