//! The faults a scenario injects. Each kind is one type in its own file,
//! holding everything about it: its fields (parsed by serde), its checks,
//! what it does to a link, a sensor or a process, and how a run's summary
//! describes it. [`FaultSchedule`] evaluates the schedule at a step.
//!
//! Adding a kind is its file plus one line in [`fault_kinds!`]'s list.

mod burst_loss;
mod check;
mod corrupt;
mod delay;
mod duplicate;
mod kill;
mod loss;
mod partition;
mod reorder;
mod schedule;
mod select;
mod sensor;

use serde::{Deserialize, Serialize};

use crate::actor::ActorId;
use crate::shaper::LinkRule;
use crate::ScenarioError;

pub use burst_loss::BurstLoss;
pub use check::Check;
pub use corrupt::Corrupt;
pub use delay::Delay;
pub use duplicate::Duplicate;
pub use kill::{Kill, Signal};
pub use loss::Loss;
pub use partition::Partition;
pub use reorder::Reorder;
pub use schedule::{FaultSchedule, ProcessEvent};
pub use select::{is_wildcard, LinkSelector};
pub use sensor::{FaultySensors, SensorFault, SensorMode};

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
}

/// Declares [`Fault`], one variant per kind, spelled in a scenario by its
/// snake-case name under `kind`.
macro_rules! fault_kinds {
    ($($(#[$doc:meta])* $variant:ident),+ $(,)?) => {
        /// One entry of the fault schedule.
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(tag = "kind", rename_all = "snake_case")]
        pub enum Fault {
            $($(#[$doc])* $variant($variant),)+
        }

        impl Fault {
            /// The kind behind the entry.
            pub fn kind(&self) -> &dyn FaultKind {
                match self {
                    $(Fault::$variant(f) => f,)+
                }
            }
        }

        $(impl From<$variant> for Fault {
            fn from(f: $variant) -> Self {
                Fault::$variant(f)
            }
        })+
    };
}

fault_kinds! {
    Delay,
    Loss,
    Partition,
    Kill,
    Duplicate,
    Reorder,
    Corrupt,
    BurstLoss,
    /// Spelled `kind = "sensor"`.
    #[serde(rename = "sensor")]
    FaultySensors,
}

impl Fault {
    pub fn at_step(&self) -> u32 {
        self.kind().window().at_step
    }

    /// The step at which the fault ends (exclusive), if it ends.
    pub fn end_step(&self) -> Option<u32> {
        self.kind().window().end
    }

    pub fn holds(&self, step: u32) -> bool {
        self.kind().window().holds(step)
    }

    /// Checks entry `index` of a schedule of `steps` steps.
    pub fn check(&self, file: &str, index: usize, steps: u32) -> Result<(), ScenarioError> {
        let check = Check::new(file, index);
        let at = self.at_step();
        if at == 0 || at > steps {
            return Err(check.fail("at_step", format!("a step from 1 to {steps}"), at));
        }
        self.kind().check(&check)
    }
}

#[cfg(test)]
mod tests {
    use crate::scenario::{Scenario, DEFAULT_SCENARIO};
    use crate::topology::Topology;

    /// One entry of every kind, as a scenario file spells it.
    const EVERY_KIND: &str = r#"
[[faults]]
kind = "delay"
links = [{ from = "node-1", to = "*" }]
at_step = 2
duration = 3
latency_ms = 80.0
jitter_ms = 5.0
rate_bps = 64000.0

[[faults]]
kind = "loss"
links = [{ from = "*", to = "*", fraction = 0.5 }]
at_step = 2
probability = 0.3

[[faults]]
kind = "partition"
groups = [["node-0"], ["node-1", "node-2"]]
at_step = 3
duration = 2

[[faults]]
kind = "kill"
actor = "sensor-3"
at_step = 4
signal = "SIGSTOP"
restart_after = 2

[[faults]]
kind = "duplicate"
links = [{ from = "node-0", to = "node-1" }]
at_step = 1
probability = 0.5

[[faults]]
kind = "reorder"
links = [{ from = "node-0", to = "node-1" }]
at_step = 1
probability = 0.5
delay_ms = 10.0

[[faults]]
kind = "corrupt"
links = [{ from = "node-0", to = "node-1" }]
at_step = 1
probability = 0.1

[[faults]]
kind = "burst_loss"
links = [{ from = "*", to = "node-4" }]
at_step = 1
enter_bad = 0.1
leave_bad = 0.5

[[faults]]
kind = "sensor"
sensors = ["sensor-7"]
at_step = 5
mode = "bias"
bias = 0.2
"#;

    /// The scenario with `extra`, checked against its network too (which
    /// is where names are checked).
    fn parse(extra: &str) -> Result<Scenario, String> {
        let s = Scenario::from_toml(&format!("{DEFAULT_SCENARIO}\n{extra}"), "f.toml", &[])
            .map_err(|e| e.to_string())?;
        Topology::from_scenario(&s, "f.toml").map_err(|e| e.to_string())?;
        Ok(s)
    }

    #[test]
    fn every_kind_reads_and_writes_as_the_file_spells_it() {
        let s = parse(EVERY_KIND).unwrap();
        assert_eq!(s.faults.len(), 9);
        let again = Scenario::from_toml(&s.to_toml(), "again", &[]).unwrap();
        assert_eq!(again.faults, s.faults);
        let described: Vec<String> = s.faults.iter().map(|f| f.kind().describe()).collect();
        assert_eq!(
            described[0],
            "delay 80 ms ± 5 ms, rate 64000 bit/s on node-1->*"
        );
        assert_eq!(described[1], "loss 0.3 on *->* (0.5 of them)");
        assert_eq!(
            described[3],
            "kill sensor-3 with Stop, restart after 2 steps"
        );
        assert_eq!(described[8], "sensor bias 0.2 on sensor-7");
        // A kill's window is its time down.
        assert_eq!(
            (s.faults[3].at_step(), s.faults[3].end_step()),
            (4, Some(6))
        );
        assert!(s.faults[2].holds(4) && !s.faults[2].holds(5));
    }

    #[test]
    fn an_unknown_field_or_kind_is_refused_by_name() {
        let err = parse("[[faults]]\nkind = \"loss\"\nlinks = []\nat_step = 2\nprobability = 0.3\nlatency_ms = 5.0\n")
            .unwrap_err();
        assert!(err.contains("latency_ms"), "{err}");
        let err = parse("[[faults]]\nkind = \"flood\"\nat_step = 2\n").unwrap_err();
        assert!(err.contains("flood"), "{err}");
    }

    /// Each kind's own checks, each naming its key.
    #[test]
    fn each_kind_checks_its_values() {
        let cases = [
            ("kind = \"delay\"\nlinks = [{ from = \"*\", to = \"*\" }]\nat_step = 2\nlatency_ms = -1.0", "faults[0].latency_ms"),
            ("kind = \"delay\"\nlinks = []\nat_step = 2\nlatency_ms = 1.0", "faults[0].links"),
            ("kind = \"loss\"\nlinks = [{ from = \"*\", to = \"*\", fraction = 2.0 }]\nat_step = 2\nprobability = 0.1", "faults[0].links[0].fraction"),
            ("kind = \"loss\"\nlinks = [{ from = \"*\", to = \"*\" }]\nat_step = 2\nduration = 0\nprobability = 0.1", "faults[0].duration"),
            ("kind = \"partition\"\ngroups = [[\"node-0\"]]\nat_step = 2", "faults[0].groups"),
            ("kind = \"kill\"\nactor = \"node-1\"\nat_step = 2\nsignal = \"SIGKILL\"\nrestart_after = 0", "faults[0].restart_after"),
            ("kind = \"duplicate\"\nlinks = [{ from = \"*\", to = \"*\" }]\nat_step = 2\nprobability = -0.1", "faults[0].probability"),
            ("kind = \"reorder\"\nlinks = [{ from = \"*\", to = \"*\" }]\nat_step = 2\nprobability = 0.1\ndelay_ms = 0.0", "faults[0].delay_ms"),
            ("kind = \"corrupt\"\nlinks = [{ from = \"*\", to = \"*\" }]\nat_step = 2\nprobability = 3.0", "faults[0].probability"),
            ("kind = \"burst_loss\"\nlinks = [{ from = \"*\", to = \"*\" }]\nat_step = 2\nenter_bad = 0.1\nleave_bad = 1.5", "faults[0].leave_bad"),
            ("kind = \"sensor\"\nsensors = [\"sensor-1\"]\nat_step = 2\nmode = \"byzantine\"", "faults[0].phantom"),
            ("kind = \"sensor\"\nsensors = [\"node-1\"]\nat_step = 2\nmode = \"dropout\"", "faults[0].sensors"),
            ("kind = \"kill\"\nactor = \"node-1\"\nat_step = 0\nsignal = \"SIGKILL\"", "faults[0].at_step"),
        ];
        for (fault, key) in cases {
            let err = parse(&format!("[[faults]]\n{fault}\n")).unwrap_err();
            assert!(err.contains(&format!("`{key}`")), "{fault}\n→ {err}");
        }
    }
}
