//! A finished run's results, read back from its output folder, with the
//! questions a test asks of them.

use fusion_graph::vocabulary::Vocabulary;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::process::ExitStatus;
use std::sync::OnceLock;

use fusion_graph::ActorId;
use fusion_graph::RunId;
use launch::summary::{AppliedFault, FaultCost, Summary};
use transport::accounting::{Accounting, Counters};
use transport::iceoryx::run_resources;
use wire::MessageKind;

use crate::cleanup::{kill_and_clean, processes_with};

pub use launch::results::Tick;

/// Every row of a `ticks.csv` (none if it is missing); panics on a row that
/// does not parse, naming it.
pub fn read_ticks(path: &Path) -> Vec<Tick> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Vec::new();
    };
    text.lines()
        .skip(1)
        .map(|l| Tick::parse(l).unwrap_or_else(|| panic!("{}: bad row {l:?}", path.display())))
        .collect()
}

/// A finished run. Dropping it kills any process left with its run id and
/// removes its shared memory (there should be none: see
/// [`assert_clean`](Self::assert_clean)).
pub struct Run {
    run_id: RunId,
    out: PathBuf,
    executable: PathBuf,
    status: ExitStatus,
    stdout: String,
    stderr: String,
    ticks: Vec<Tick>,
    summary: OnceLock<Option<Summary>>,
    accounting: OnceLock<Option<Accounting>>,
    vocabulary: Vocabulary,
}

impl Run {
    // A run is what its network left: each part is needed, none optional.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        run_id: RunId,
        out: PathBuf,
        executable: PathBuf,
        status: ExitStatus,
        stdout: String,
        stderr: String,
        ticks: Vec<Tick>,
        vocabulary: Vocabulary,
    ) -> Self {
        Self {
            run_id,
            out,
            executable,
            status,
            stdout,
            stderr,
            ticks,
            summary: OnceLock::new(),
            accounting: OnceLock::new(),
            vocabulary,
        }
    }

    /// The run's id, on every process's command line and in its shared memory's names.
    pub fn run_id(&self) -> &str {
        self.run_id.as_str()
    }

    /// The run's output folder (`ticks.csv`, `links.csv`, `summary.json`, logs).
    pub fn out_dir(&self) -> &Path {
        &self.out
    }

    /// The `cqnet` program that ran.
    pub fn executable(&self) -> &Path {
        &self.executable
    }

    /// How the launcher exited.
    pub fn status(&self) -> ExitStatus {
        self.status
    }

    /// Whether the launcher exited successfully.
    pub fn succeeded(&self) -> bool {
        self.status.success()
    }

    /// The launcher's standard output (the summary table).
    pub fn stdout(&self) -> &str {
        &self.stdout
    }

    /// The launcher's standard error (progress, warnings, the error).
    pub fn stderr(&self) -> &str {
        &self.stderr
    }

    /// Panics with the program's stderr unless it exited successfully.
    pub fn assert_success(&self) -> &Self {
        assert!(
            self.succeeded(),
            "run {} failed ({}):\n{}",
            self.run_id(),
            self.status,
            self.stderr
        );
        self
    }

    /// Panics unless the program failed and its stderr names each of `words`.
    pub fn assert_failure_naming(&self, words: &[&str]) -> &Self {
        assert!(!self.succeeded(), "run {} succeeded", self.run_id());
        for w in words {
            assert!(
                self.stderr.contains(w),
                "stderr does not name {w:?}:\n{}",
                self.stderr
            );
        }
        self
    }

    /// `summary.json`; panics if the run wrote none (it failed before its
    /// first step, say).
    pub fn summary(&self) -> &Summary {
        self.summary
            .get_or_init(|| {
                let text = std::fs::read_to_string(self.out.join("summary.json")).ok()?;
                let summary = self.vocabulary.reading(|| serde_json::from_str(&text));
                Some(summary.expect("summary.json is a cqnet summary"))
            })
            .as_ref()
            .unwrap_or_else(|| {
                panic!(
                    "run {} wrote no summary.json:\n{}",
                    self.run_id(),
                    self.stderr
                )
            })
    }

    /// Every link's counters (`links.csv`); panics if the run wrote none.
    pub fn accounting(&self) -> &Accounting {
        self.accounting
            .get_or_init(|| {
                let text = std::fs::read_to_string(self.out.join("links.csv")).ok()?;
                let accounting = Accounting::from_csv(&text, self.vocabulary.payloads());
                Some(accounting.expect("links.csv is a cqnet link table"))
            })
            .as_ref()
            .unwrap_or_else(|| panic!("run {} wrote no links.csv:\n{}", self.run_id(), self.stderr))
    }

    /// Bytes of `kind` that `from` sent to `to`.
    pub fn bytes(&self, from: ActorId, to: ActorId, kind: MessageKind) -> u64 {
        self.accounting().get(from, to, kind).sent_bytes
    }

    /// Messages of `kind` that `from` sent to `to`.
    pub fn messages(&self, from: ActorId, to: ActorId, kind: MessageKind) -> u64 {
        self.accounting().get(from, to, kind).sent_messages
    }

    /// Every counter of `kind`, summed over links.
    pub fn counters(&self, kind: MessageKind) -> Counters {
        self.accounting()
            .by_kind()
            .get(&kind)
            .copied()
            .unwrap_or_default()
    }

    /// Messages of `kind` dropped by injected faults.
    pub fn dropped(&self, kind: MessageKind) -> u64 {
        self.counters(kind).dropped_messages
    }

    /// Messages of `kind` sent but neither received, dropped nor rejected.
    pub fn unaccounted(&self, kind: MessageKind) -> i64 {
        self.summary()
            .traffic
            .iter()
            .find(|t| t.kind == kind.name())
            .map_or(0, |t| t.unaccounted_messages)
    }

    /// The faults of the run: the schedule's and those it found (an actor
    /// that died on its own).
    pub fn faults(&self) -> &[AppliedFault] {
        &self.summary().faults
    }

    /// What the faults cost: messages dropped or late, rounds short of
    /// neighbours, node-steps without a report.
    pub fn fault_cost(&self) -> &FaultCost {
        &self.summary().fault_cost
    }

    /// Every row of `ticks.csv`.
    pub fn ticks(&self) -> &[Tick] {
        &self.ticks
    }

    /// Every row of `ticks.csv` as its text, sorted: two runs that
    /// computed the same thing give equal lists whatever order their rows
    /// were written in.
    pub fn sorted_tick_lines(&self) -> Vec<&str> {
        let mut lines: Vec<&str> = self.ticks.iter().map(|t| t.line.as_str()).collect();
        lines.sort();
        lines
    }

    /// One node's rows (`"node-4"`, or `"central"`).
    pub fn ticks_of<'a>(&'a self, node: &'a str) -> impl Iterator<Item = &'a Tick> + 'a {
        self.ticks.iter().filter(move |t| t.node == node)
    }

    /// Position RMSE of every node's fused estimate over `steps` (the
    /// centralized reference left out); NaN if no node reported then.
    pub fn rmse(&self, steps: RangeInclusive<u32>) -> f64 {
        rmse(
            self.ticks
                .iter()
                .filter(|t| t.is_node() && steps.contains(&t.step)),
        )
    }

    /// One node's position RMSE over `steps`; NaN if it did not report then.
    pub fn node_rmse(&self, node: &str, steps: RangeInclusive<u32>) -> f64 {
        rmse(self.ticks_of(node).filter(|t| steps.contains(&t.step)))
    }

    /// One node's mean CQ/dPCRLB over `steps`, if it reported one.
    pub fn mean_bound(&self, node: &str, steps: RangeInclusive<u32>) -> Option<f64> {
        let b: Vec<f64> = self
            .ticks_of(node)
            .filter(|t| steps.contains(&t.step))
            .filter_map(|t| t.bound)
            .collect();
        (!b.is_empty()).then(|| b.iter().sum::<f64>() / b.len() as f64)
    }

    /// Processes still running with this run's id.
    pub fn leftover_processes(&self) -> Vec<u32> {
        processes_with(self.run_id())
    }

    /// Files of this run's shared memory that still exist.
    pub fn leftover_shared_memory(&self) -> Vec<PathBuf> {
        run_resources(&self.run_id)
    }

    /// Panics if a process or shared memory of the run survived it.
    pub fn assert_clean(&self) -> &Self {
        assert_eq!(
            self.leftover_processes(),
            Vec::<u32>::new(),
            "processes of {} survived",
            self.run_id()
        );
        assert_eq!(
            self.leftover_shared_memory(),
            Vec::<PathBuf>::new(),
            "shared memory of {} survived",
            self.run_id()
        );
        self
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        kill_and_clean(&self.run_id);
    }
}

fn rmse<'a>(ticks: impl Iterator<Item = &'a Tick>) -> f64 {
    let (sum, n) = ticks.fold((0.0, 0usize), |(s, n), t| (s + t.error * t.error, n + 1));
    (sum / n as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tick_row_parses_with_its_empty_bounds() {
        let t = Tick::parse("3,node-4,1,2,3,4,2.5,0.7,,,10,4,3,1").unwrap();
        assert_eq!(t.step, 3);
        assert_eq!(t.bound, Some(0.7));
        assert_eq!(t.local_bound, None);
        assert_eq!(t.observations, 3);
        assert!(t.deadline_missed);
        assert_eq!((t.spread, t.active.len()), (None, 0));
        let t = Tick::parse("3,node-4,1,2,3,4,2.5,0.7,,,10,4,3,0,1.25,17;3").unwrap();
        assert_eq!((t.spread, t.active), (Some(1.25), vec![17, 3]));
        assert!(Tick::parse("3,node-4,1,2,3,4,2.5,0.7,,,10,4,3,0,1.25,17;x").is_none());
        assert!(Tick::parse("3,node-4,1,2").is_none());
    }

    #[test]
    fn rmse_of_nothing_is_nan() {
        assert!(rmse(std::iter::empty()).is_nan());
    }
}
