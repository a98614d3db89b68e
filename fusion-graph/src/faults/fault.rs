//! The schedule's entry: one of the fault kinds, spelled by `kind`.

use serde::{Deserialize, Serialize};

use super::burst_loss::BurstLoss;
use super::corrupt::Corrupt;
use super::delay::Delay;
use super::duplicate::Duplicate;
use super::kill::Kill;
use super::kind::FaultKind;
use super::loss::Loss;
use super::partition::Partition;
use super::reorder::Reorder;
use super::sensor::FaultySensors;
use crate::check::Check;
use crate::ScenarioError;

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
        let check = Check::fault(file, index);
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
