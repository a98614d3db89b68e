//! What every fault kind is asked: when it holds, whom it names, its
//! checks, its summary line, and what it does.

use crate::shaper::LinkRule;
use crate::ScenarioError;
use wire::ActorId;

use super::effects::{ProcessEvent, SensorFault};
use crate::check::Check;

/// The steps a fault holds: from `at_step` (counted from 1) up to `end`,
/// exclusive; `None` holds to the end of the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    pub at_step: u32,
    pub end: Option<u32>,
}

impl Window {
    /// A window of `duration` steps from `at_step` (forever without one).
    pub fn lasting(at_step: u32, duration: Option<u32>) -> Self {
        Self {
            at_step,
            end: duration.map(|d| at_step + d),
        }
    }

    pub fn holds(&self, step: u32) -> bool {
        step >= self.at_step && self.end.is_none_or(|e| step < e)
    }
}

/// What a fault names in the network, for the topology's check that every
/// name is one of its actors.
pub struct Targets<'a> {
    /// The key under `faults[i]` that holds the names.
    pub key: &'static str,
    /// The names, wildcards left out.
    pub names: Vec<&'a str>,
    /// Whether only sensors may be named.
    pub sensors_only: bool,
}

/// One kind of fault. Only `window`, `targets`, `check` and `describe` are
/// asked of every kind; a kind acts through whichever of the others it
/// overrides (a link, a sensor, a process).
pub trait FaultKind {
    fn window(&self) -> Window;

    fn targets(&self) -> Targets<'_>;

    /// Checks the kind's own values; `at_step` is checked for every kind.
    fn check(&self, check: &Check) -> Result<(), ScenarioError>;

    /// One line for the run's summary.
    fn describe(&self) -> String;

    /// Whether the kind acts on links, so that receivers must set rules.
    fn acts_on_links(&self) -> bool {
        false
    }

    /// Adds the fault's effect, while it holds, to the rule on the link
    /// `from → to`; `fault` is its index in the schedule, which salts the
    /// choice of a fraction of links.
    fn shape_link(&self, _fault: usize, _from: ActorId, _to: ActorId, _rule: &mut LinkRule) {}

    /// What `sensor` does instead of measuring honestly while the fault
    /// holds, if it is one of those it takes.
    fn sensor_fault(&self, _fault: usize, _sensor: ActorId) -> Option<SensorFault> {
        None
    }

    /// The kills and restarts the fault makes at `step`.
    fn process_events(&self, _step: u32, _events: &mut Vec<ProcessEvent>) {}

    /// Whether the fault makes messages that were sent never arrive (lost,
    /// corrupted, or to or from an actor killed or stopped), so that a wait
    /// for one ends by the clock. What a node has heard of its other
    /// neighbours by then depends on timing: `run --lockstep` need not
    /// reproduce `sim` under such a fault.
    fn loses_messages(&self) -> bool {
        false
    }
}
