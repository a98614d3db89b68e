//! An actor's process signalled at a step, and restarted (or continued,
//! after SIGSTOP) `restart_after` steps later.

use serde::{Deserialize, Serialize};

use super::effects::{ProcessEvent, Signal};
use super::kind::{FaultKind, Targets, Window};
use crate::check::Check;
use crate::ScenarioError;
use wire::ActorId;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Kill {
    pub actor: String,
    pub at_step: u32,
    pub signal: Signal,
    pub restart_after: Option<u32>,
}

impl FaultKind for Kill {
    fn window(&self) -> Window {
        Window::lasting(self.at_step, self.restart_after)
    }

    fn targets(&self) -> Targets<'_> {
        Targets {
            key: "actor",
            names: vec![self.actor.as_str()],
            sensors_only: false,
        }
    }

    fn check(&self, check: &Check) -> Result<(), ScenarioError> {
        if self.restart_after == Some(0) {
            return Err(check.fail("restart_after", "at least 1 step", 0));
        }
        Ok(())
    }

    fn describe(&self) -> String {
        let restart = self
            .restart_after
            .map_or(String::new(), |r| format!(", restart after {r} steps"));
        format!("kill {} with {:?}{restart}", self.actor, self.signal)
    }

    fn process_events(&self, step: u32, events: &mut Vec<ProcessEvent>) {
        // The topology's check has refused a name that is not an actor.
        let Ok(actor) = self.actor.parse::<ActorId>() else {
            return;
        };
        let signal = self.signal;
        if self.at_step == step {
            events.push(ProcessEvent::Kill { actor, signal });
        }
        if self.window().end == Some(step) {
            events.push(ProcessEvent::Restart { actor, signal });
        }
    }

    /// What was sent to a killed or stopped actor, and what its neighbours
    /// wait for from it until they learn it is gone, never arrives.
    fn loses_messages(&self) -> bool {
        true
    }
}
