//! Result files, written row by row as a run goes so that a crash loses
//! nothing already written: `ticks.csv`, `links.csv`, `summary.json`.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::Context;
use fusion_graph::scenario::{ClockMode, Scenario};
use serde::Serialize;
use transport::accounting::Accounting;
use wire::{MessageKind, Telemetry};

pub use crate::summary::{
    steps_to_recover, window_rmse, BoundTraffic, Estimates, StepMeans, Traffic,
};

/// Steps before this are left out of the averages (the filters' transient).
pub const AVERAGE_FROM_STEP: u32 = 10;

/// One row of `ticks.csv`: a node's (or the centralized reference's) step.
#[derive(Debug, Clone, PartialEq)]
pub struct TickRow {
    pub step: u32,
    /// `node-<i>` or `central`.
    pub node: String,
    pub truth: [f64; 4],
    pub telemetry: Telemetry,
}

impl TickRow {
    pub fn error(&self) -> f64 {
        (self.telemetry.estimate[0] - self.truth[0])
            .hypot(self.telemetry.estimate[1] - self.truth[1])
    }
}

const TICKS_HEADER: &str = "step,node,true_x,true_y,est_x,est_y,error,bound,local_bound,aux_bound,rounds,live_neighbours,observations,deadline_missed,spread,active,design,disagreement,short_rounds\n";

/// A row of `ticks.csv` as read back (the live view's replay and the
/// testkit read it; [`ResultsWriter`] writes it): a node's (or the
/// centralized reference's) report for a step.
#[derive(Debug, Clone, PartialEq)]
pub struct Tick {
    /// The step, from 1.
    pub step: u32,
    /// `node-<i>` or `central`.
    pub node: String,
    /// The target's true position, metres.
    pub truth: [f64; 2],
    /// The node's fused position estimate, metres.
    pub estimate: [f64; 2],
    /// Position error, metres.
    pub error: f64,
    /// CQ/dPCRLB position bound, metres.
    pub bound: Option<f64>,
    /// The bound of the node's own sensors alone, metres.
    pub local_bound: Option<f64>,
    /// The auxiliary-FIM baseline bound, when it ran, metres.
    pub aux_bound: Option<f64>,
    /// Consensus rounds the node completed.
    pub rounds_completed: u32,
    /// Neighbours heard in the last round.
    pub live_neighbours: u32,
    /// Observations the node's filters used.
    pub observations: u32,
    /// The node finished after its step's deadline.
    pub deadline_missed: bool,
    /// The spread of the node's prediction, `sqrt(tr_pos P(k|k−1))`, metres.
    pub spread: Option<f64>,
    /// The sensors the node activated for the step.
    pub active: Vec<u16>,
    /// A fusion centre's transmission probability for each of its sensors
    /// (empty for other nodes).
    pub design: Vec<f64>,
    /// How far the node still was from its neighbours after its last
    /// consensus round, as a share (the protocol's measure).
    pub disagreement: Option<f64>,
    /// Consensus rounds that ended at their deadline without a
    /// neighbour's value they awaited.
    pub short_rounds: u32,
    /// The row as written.
    pub line: String,
}

impl Tick {
    /// The row `line`, or `None` if it is not one: fewer than its first
    /// eight columns (step to bound), or a value that does not parse.
    /// Columns after those may be missing, and read as empty.
    pub fn parse(line: &str) -> Option<Self> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 8 {
            return None;
        }
        let num = |i: usize| f.get(i)?.parse::<f64>().ok();
        // A later column that is absent reads as 0; one that is there must parse.
        let int = |i: usize| f.get(i).map_or(Some(0), |v| v.parse::<u32>().ok());
        Some(Self {
            step: int(0)?,
            node: f.get(1)?.to_string(),
            truth: [num(2)?, num(3)?],
            estimate: [num(4)?, num(5)?],
            error: num(6)?,
            bound: num(7),
            local_bound: num(8),
            aux_bound: num(9),
            rounds_completed: int(10)?,
            live_neighbours: int(11)?,
            observations: int(12)?,
            deadline_missed: f.get(13) == Some(&"1"),
            spread: num(14),
            active: match f.get(15).filter(|v| !v.is_empty()) {
                Some(ids) => ids
                    .split(';')
                    .map(|s| s.parse().ok())
                    .collect::<Option<_>>()?,
                None => Vec::new(),
            },
            design: match f.get(16).filter(|v| !v.is_empty()) {
                Some(ps) => ps
                    .split(';')
                    .map(|p| p.parse().ok())
                    .collect::<Option<_>>()?,
                None => Vec::new(),
            },
            disagreement: num(17),
            short_rounds: int(18)?,
            line: line.to_string(),
        })
    }

    /// A processing node's row (not the centralized reference's).
    pub fn is_node(&self) -> bool {
        self.node != "central"
    }
}

pub struct ResultsWriter {
    dir: PathBuf,
    ticks: BufWriter<File>,
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x}"))
}

impl ResultsWriter {
    pub fn create(dir: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating the output folder {}", dir.display()))?;
        let path = dir.join("ticks.csv");
        let mut ticks = BufWriter::new(
            File::create(&path).with_context(|| format!("creating {}", path.display()))?,
        );
        ticks.write_all(TICKS_HEADER.as_bytes())?;
        Ok(Self {
            dir: dir.to_path_buf(),
            ticks,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Appends rows and flushes them to disk.
    pub fn write_ticks(&mut self, rows: &[TickRow]) -> anyhow::Result<()> {
        for r in rows {
            let t = &r.telemetry;
            writeln!(
                self.ticks,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                r.step,
                r.node,
                r.truth[0],
                r.truth[1],
                t.estimate[0],
                t.estimate[1],
                r.error(),
                opt(t.bound),
                opt(t.local_bound),
                opt(t.aux_bound),
                t.rounds_completed,
                t.live_neighbours,
                t.observations,
                t.deadline_missed as u8,
                opt(t.spread),
                t.active
                    .iter()
                    .map(u16::to_string)
                    .collect::<Vec<_>>()
                    .join(";"),
                t.design
                    .iter()
                    .map(|p| format!("{}", f64::from(*p) / 1e4))
                    .collect::<Vec<_>>()
                    .join(";"),
                opt(t.disagreement),
                t.short_rounds
            )?;
        }
        self.ticks.flush()?;
        Ok(())
    }

    pub fn write_links(&self, accounting: &Accounting) -> anyhow::Result<()> {
        write_atomically(&self.dir.join("links.csv"), accounting.to_csv().as_bytes())
    }

    pub fn write_summary<S: Serialize>(&self, summary: &S) -> anyhow::Result<()> {
        write_atomically(
            &self.dir.join("summary.json"),
            serde_json::to_string_pretty(summary)?.as_bytes(),
        )
    }
}

/// Writes through a temporary file and a rename, so a reader never sees half a file.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(())
}

/// Running sums for the summary's averages.
#[derive(Debug, Clone, Default)]
pub struct Averages {
    sq_error: f64,
    errors: u64,
    bound: (f64, u64),
    local_bound: (f64, u64),
    aux_bound: (f64, u64),
    central_sq_error: f64,
    central_errors: u64,
    central_bound: (f64, u64),
    pub deadline_misses: u64,
    pub rows: u64,
}

fn add(acc: &mut (f64, u64), v: Option<f64>) {
    if let Some(v) = v {
        acc.0 += v;
        acc.1 += 1;
    }
}

fn mean(acc: (f64, u64)) -> Option<f64> {
    (acc.1 > 0).then(|| acc.0 / acc.1 as f64)
}

impl Averages {
    pub fn add(&mut self, r: &TickRow) {
        self.rows += 1;
        self.deadline_misses += r.telemetry.deadline_missed as u64;
        if r.step < AVERAGE_FROM_STEP {
            return;
        }
        let e2 = r.error().powi(2);
        if r.node == "central" {
            self.central_sq_error += e2;
            self.central_errors += 1;
            add(&mut self.central_bound, r.telemetry.bound);
        } else {
            self.sq_error += e2;
            self.errors += 1;
            add(&mut self.bound, r.telemetry.bound);
            add(&mut self.local_bound, r.telemetry.local_bound);
            add(&mut self.aux_bound, r.telemetry.aux_bound);
        }
    }

    pub fn estimates(&self) -> Estimates {
        Estimates {
            from_step: AVERAGE_FROM_STEP,
            rmse: (self.errors > 0).then(|| (self.sq_error / self.errors as f64).sqrt()),
            mean_bound: mean(self.bound),
            mean_local_bound: mean(self.local_bound),
            mean_aux_bound: mean(self.aux_bound),
            centralized_rmse: (self.central_errors > 0)
                .then(|| (self.central_sq_error / self.central_errors as f64).sqrt()),
            mean_centralized_bound: mean(self.central_bound),
        }
    }
}

/// Per-step sums over nodes (and, merged, over runs): what a figure over
/// time plots. Each step's entry holds the nodes' squared errors and
/// bounds, and the centralized reference's apart.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepSeries {
    steps: Vec<StepSums>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct StepSums {
    sq_error: (f64, u64),
    bound: (f64, u64),
    aux_bound: (f64, u64),
    central_sq_error: (f64, u64),
    central_bound: (f64, u64),
    largest_disagreement: Option<f64>,
}

impl StepSeries {
    pub fn add(&mut self, r: &TickRow) {
        let i = r.step.saturating_sub(1) as usize;
        if self.steps.len() <= i {
            self.steps.resize(i + 1, StepSums::default());
        }
        let s = &mut self.steps[i];
        let e2 = Some(r.error().powi(2));
        if r.node == "central" {
            add(&mut s.central_sq_error, e2);
            add(&mut s.central_bound, r.telemetry.bound);
        } else {
            add(&mut s.sq_error, e2);
            add(&mut s.bound, r.telemetry.bound);
            add(&mut s.aux_bound, r.telemetry.aux_bound);
            s.largest_disagreement = larger(s.largest_disagreement, r.telemetry.disagreement);
        }
    }

    /// Adds another run's sums.
    pub fn merge(&mut self, other: &StepSeries) {
        if self.steps.len() < other.steps.len() {
            self.steps.resize(other.steps.len(), StepSums::default());
        }
        let sum = |a: &mut (f64, u64), b: (f64, u64)| {
            a.0 += b.0;
            a.1 += b.1;
        };
        for (a, b) in self.steps.iter_mut().zip(&other.steps) {
            sum(&mut a.sq_error, b.sq_error);
            sum(&mut a.bound, b.bound);
            sum(&mut a.aux_bound, b.aux_bound);
            sum(&mut a.central_sq_error, b.central_sq_error);
            sum(&mut a.central_bound, b.central_bound);
            a.largest_disagreement = larger(a.largest_disagreement, b.largest_disagreement);
        }
    }

    /// Step 1, 2, …: the means.
    pub fn means(&self) -> Vec<StepMeans> {
        self.steps
            .iter()
            .enumerate()
            .map(|(i, s)| StepMeans {
                step: i as u32 + 1,
                rmse: mean(s.sq_error).map(f64::sqrt),
                bound: mean(s.bound),
                aux_bound: mean(s.aux_bound),
                centralized_rmse: mean(s.central_sq_error).map(f64::sqrt),
                centralized_bound: mean(s.central_bound),
                largest_disagreement: s.largest_disagreement,
            })
            .collect()
    }
}

fn larger(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.max(b)),
        (a, b) => a.or(b),
    }
}

pub fn traffic(accounting: &Accounting, steps: u32) -> (Vec<Traffic>, BoundTraffic) {
    let kinds = accounting.by_kind();
    let rows = kinds
        .iter()
        .map(|(k, c)| Traffic {
            kind: k.name().into(),
            messages: c.sent_messages,
            bytes: c.sent_bytes,
            bytes_per_step: c.sent_bytes as f64 / steps.max(1) as f64,
            dropped_messages: c.dropped_messages,
            malformed_messages: c.malformed_messages,
            duplicated_messages: c.duplicated_messages,
            unaccounted_messages: c.unaccounted_messages(*k),
        })
        .collect();
    let consensus = kinds
        .get(&MessageKind::Consensus)
        .map_or(0, |c| c.sent_messages);
    let aux = kinds
        .get(&MessageKind::ConsensusAux)
        .map(|c| c.sent_messages);
    // A protocol of one's own counts what its payload says carries the
    // bound's information.
    let declared: u64 = kinds
        .iter()
        .map(|(k, c)| match k {
            MessageKind::Protocol(p) => c.sent_messages * p.bound_bytes() as u64,
            _ => 0,
        })
        .sum();
    let bound = BoundTraffic {
        cq_dpcrlb_bytes: consensus * 80 + declared,
        auxiliary_fim_bytes: aux.map(|a| consensus * 80 + a * 80),
    };
    (rows, bound)
}

/// The transmissions the `slot_values` messages sent carry: each is a
/// header, the slots' mask (4 bytes) and a value (8 bytes) per slot.
pub fn energy(accounting: &Accounting, steps: u32) -> crate::summary::Energy {
    let transmissions = accounting
        .by_kind()
        .get(&MessageKind::SlotValues)
        .map_or(0, |c| {
            (c.sent_bytes - c.sent_messages * (wire::HEADER_BYTES as u64 + 4)) / 8
        });
    crate::summary::Energy {
        transmissions,
        per_step: transmissions as f64 / f64::from(steps.max(1)),
    }
}

/// What a run knows about itself beyond its rows, for the summary.
pub struct RunFacts {
    pub command: String,
    pub run_id: String,
    pub steps_done: u32,
    pub wall_seconds: f64,
    pub steps_per_second: f64,
    pub processes: usize,
    /// `run`: seconds from the launcher's start to every actor's `ready`.
    pub startup_seconds: Option<f64>,
    pub children_memory_kb: Option<crate::summary::ChildrenMemory>,
    pub children_cpu: Option<crate::summary::ChildrenCpu>,
    /// Whether the consensus round latency means anything: in `sim` the
    /// rounds run on the virtual clock.
    pub real_time_rounds: bool,
    /// Faults nobody scheduled: actors that died on their own (`run`).
    pub unscheduled_faults: Vec<crate::summary::AppliedFault>,
}

/// How many steps late a node's report may arrive and still count. Older
/// reports are left out: the launcher keeps each step's truth and reporters
/// only this long, so that its memory does not grow with the run.
pub const LATE_ROW_HORIZON: u32 = 1000;

/// One recorder for `sim` and `run`: takes the rows as they come, writes
/// `ticks.csv` as it goes, and at the end `links.csv` and `summary.json`.
pub struct Recorder<'w> {
    writer: &'w mut ResultsWriter,
    scenario: fusion_graph::Scenario,
    degree: Vec<usize>,
    averages: Averages,
    stages: crate::summary::StageSums,
    cost: crate::summary::FaultCost,
    round_latency: crate::summary::LatencyHistogram,
    /// Which nodes reported each step still within [`LATE_ROW_HORIZON`]: a
    /// node's row counts once.
    reported: std::collections::BTreeMap<u32, std::collections::BTreeSet<u16>>,
    /// Rows of the steps that have left `reported`: those before `horizon`.
    reported_earlier: u64,
    horizon: u32,
    /// Per-step errors, for what each fault did to tracking.
    series: StepSeries,
}

impl<'w> Recorder<'w> {
    pub fn new(
        writer: &'w mut ResultsWriter,
        scenario: &fusion_graph::Scenario,
        topology: &fusion_graph::Topology,
    ) -> Self {
        Self {
            writer,
            scenario: scenario.clone(),
            degree: topology.neighbours.iter().map(Vec::len).collect(),
            averages: Averages::default(),
            stages: Default::default(),
            cost: Default::default(),
            round_latency: Default::default(),
            reported: Default::default(),
            reported_earlier: 0,
            horizon: 0,
            series: StepSeries::default(),
        }
    }

    /// How many nodes reported `step`.
    pub fn reports(&self, step: u32) -> usize {
        self.reported.get(&step).map_or(0, |s| s.len())
    }

    /// At `step`: forgets which nodes reported the steps before `step -`
    /// [`LATE_ROW_HORIZON`], keeping their count: what the launcher holds
    /// stays the same however long the run.
    pub fn begin_step(&mut self, step: u32) {
        self.horizon = self.horizon.max(step.saturating_sub(LATE_ROW_HORIZON));
        while let Some(entry) = self.reported.first_entry() {
            if *entry.key() >= self.horizon {
                break;
            }
            self.reported_earlier += entry.remove().len() as u64;
        }
    }

    /// Node rows (a repeated one is ignored) and the centralized
    /// reference's, written at once.
    pub fn record(&mut self, rows: Vec<TickRow>) -> anyhow::Result<()> {
        let mut kept = Vec::with_capacity(rows.len());
        for r in rows {
            if let Some(n) = r
                .node
                .strip_prefix("node-")
                .and_then(|n| n.parse::<u16>().ok())
            {
                if r.step < self.horizon {
                    tracing::warn!(
                        step = r.step,
                        node = n,
                        "a report older than the horizon is left out"
                    );
                    continue;
                }
                if !self.reported.entry(r.step).or_default().insert(n) {
                    continue;
                }
                let t = &r.telemetry;
                self.stages.add(t.stage_micros);
                self.cost.late_messages += t.late_messages as u64;
                self.cost.gated_observations += t.gated as u64;
                self.cost.lagged_observations += t.lagged as u64;
                self.cost.node_steps_without_choice += u64::from(t.without_choice);
                if t.rounds_completed > 1 {
                    // Rounds 2..N_c: every neighbour is exchanging by then.
                    self.round_latency
                        .add(t.stage_micros[2] as f64 / (t.rounds_completed - 1) as f64);
                }
                if t.missed_neighbours > 0 {
                    self.cost.rounds_with_fewer_neighbours += 1;
                }
                self.cost.short_rounds += u64::from(t.short_rounds);
                self.cost.node_steps_with_short_rounds += u64::from(t.short_rounds > 0);
            }
            self.averages.add(&r);
            self.series.add(&r);
            kept.push(r);
        }
        self.writer.write_ticks(&kept)
    }

    /// Writes `links.csv` and `summary.json`, and returns the summary.
    pub fn finish(
        mut self,
        accounting: &Accounting,
        facts: RunFacts,
    ) -> anyhow::Result<crate::summary::Summary> {
        self.writer.write_links(accounting)?;
        let nodes = self.degree.len() as u64;
        let reported =
            self.reported_earlier + self.reported.values().map(|s| s.len() as u64).sum::<u64>();
        self.cost.missing_node_steps = (facts.steps_done as u64 * nodes).saturating_sub(reported);
        self.cost.dropped_messages = accounting
            .by_kind()
            .values()
            .map(|c| c.dropped_messages)
            .sum();
        self.cost.duplicated_messages = accounting
            .by_kind()
            .values()
            .map(|c| c.duplicated_messages)
            .sum();
        self.cost.corrupted_messages = accounting
            .iter()
            .filter(|((_, _, kind), _)| *kind != MessageKind::Malformed)
            .map(|(_, c)| c.malformed_messages)
            .sum();
        let (traffic, bound_traffic) = traffic(accounting, facts.steps_done.max(1));
        let means = self.series.means();
        let mut timing_dependent = timing_dependent(&self.scenario, &facts.command);
        if self.cost.short_rounds > 0 {
            // With nothing else to blame, the neighbours were slow, and a
            // longer timeout waits for them; lost values it cannot bring.
            let hint = if timing_dependent.is_empty() {
                " (a larger consensus.round_timeout_ms waits for slow neighbours)"
            } else {
                ""
            };
            timing_dependent.push(format!(
                "{} consensus rounds in {} node-steps ended at their deadline without a neighbour's value{hint}",
                self.cost.short_rounds, self.cost.node_steps_with_short_rounds
            ));
        }
        let summary = crate::summary::Summary {
            command: facts.command,
            run_id: facts.run_id,
            scenario: self.scenario.clone(),
            steps: facts.steps_done,
            estimates: self.averages.estimates(),
            traffic,
            bound_traffic,
            energy: self
                .scenario
                .channel
                .is_some()
                .then(|| energy(accounting, facts.steps_done.max(1))),
            deadline_misses: self.averages.deadline_misses,
            world_misses: accounting.world_misses(),
            faults: self
                .scenario
                .faults
                .iter()
                .map(crate::summary::AppliedFault::from_fault)
                .chain(facts.unscheduled_faults)
                .map(|mut f| {
                    f.measure(&means);
                    f
                })
                .collect(),
            fault_cost: self.cost,
            timing_dependent,
            disagreement: crate::summary::Disagreement::of_steps(&means),
            wall_seconds: facts.wall_seconds,
            steps_per_second: facts.steps_per_second,
            stage_micros: self.stages.means(),
            round_latency_micros: if facts.real_time_rounds {
                self.round_latency.percentiles()
            } else {
                None
            },
            processes: facts.processes,
            startup_seconds: facts.startup_seconds,
            peak_memory_kb: crate::usage::peak_memory_kb(),
            cpu_seconds: crate::usage::own_cpu_seconds(),
            children_memory_kb: facts.children_memory_kb,
            children_cpu: facts.children_cpu,
        };
        self.writer.write_summary(&summary)?;
        Ok(summary)
    }
}

/// What in `scenario`, run by `command`, can end a wait by the clock, so
/// that its results depend on when messages arrive (see
/// `Summary::timing_dependent`). `sim`'s clock is virtual; a `run` in real
/// time ends its waits by the period.
pub fn timing_dependent(scenario: &Scenario, command: &str) -> Vec<String> {
    let mut why = Vec::new();
    if command == "run" && scenario.clock.mode == ClockMode::Realtime {
        why.push("the real-time clock: every step's waits end by its period".to_string());
    }
    for f in &scenario.faults {
        if f.kind().loses_messages() {
            why.push(format!(
                "the fault at step {} ({}) loses messages on purpose; a wait for one ends by the clock",
                f.at_step(),
                f.kind().describe()
            ));
        }
    }
    for h in &scenario.hosts {
        if h.link.as_ref().is_some_and(|l| l.cut_at_step.is_some()) {
            why.push(format!(
                "host {}'s link is cut; waits for its nodes end by the clock",
                h.name
            ));
        }
    }
    why
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A real-time run's waits end by the clock; `sim`'s and a lockstep
    /// run's do not, unless a fault loses messages.
    #[test]
    fn what_makes_a_run_depend_on_timing_is_named() {
        let s = Scenario::default_scenario();
        assert_eq!(s.clock.mode, ClockMode::Realtime);
        assert!(timing_dependent(&s, "sim").is_empty());
        assert!(timing_dependent(&s, "run --lockstep").is_empty());
        let real_time = timing_dependent(&s, "run");
        assert_eq!(real_time.len(), 1);
        assert!(real_time[0].contains("real-time clock"), "{real_time:?}");
    }

    fn row(step: u32, node: u16) -> TickRow {
        TickRow {
            step,
            node: format!("node-{node}"),
            truth: [0.0; 4],
            telemetry: Telemetry {
                bound: Some(1.0),
                rounds_completed: 3,
                live_neighbours: 1,
                observations: 3,
                stage_micros: [10, 10, 40, 50, 0, 0],
                ..Telemetry::of_estimate([1.0, 0.0, 0.0, 0.0])
            },
        }
    }

    /// Past the horizon the recorder forgets who reported, not how many:
    /// the summary's missing node-steps stay exact, a repeated row still
    /// counts once, and a row older than the horizon is left out.
    #[test]
    fn reports_past_the_horizon_are_forgotten_but_counted() {
        let dir = std::env::temp_dir().join(format!("cqnet-recorder-{}", std::process::id()));
        let mut writer = ResultsWriter::create(&dir).unwrap();
        let mut scenario = fusion_graph::Scenario::default_scenario();
        scenario.faults.clear();
        let topology = fusion_graph::Topology::from_scenario(&scenario, "d").unwrap();
        let steps = 3 * LATE_ROW_HORIZON;
        let mut recorder = Recorder::new(&mut writer, &scenario, &topology);
        for step in 1..=steps {
            recorder.begin_step(step);
            // Node 0 misses every tenth step; node 1 reports twice.
            let rows = (0..topology.nodes() as u16)
                .filter(|n| *n != 0 || step % 10 != 0)
                .map(|n| row(step, n))
                .chain([row(step, 1)])
                .collect();
            recorder.record(rows).unwrap();
        }
        assert!(recorder.reported.len() <= LATE_ROW_HORIZON as usize + 1);
        // Too late: step 1 is long past the horizon.
        recorder.record(vec![row(1, 0), row(10, 0)]).unwrap();
        let summary = recorder
            .finish(&Accounting::default(), facts(steps))
            .unwrap();
        assert_eq!(summary.fault_cost.missing_node_steps, steps as u64 / 10);
        let latency = summary.round_latency_micros.unwrap();
        assert_eq!((latency.p50, latency.p99), (20.0, 20.0));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A lockstep run with a round that ended short is named as depending
    /// on timing, its short rounds counted in the fault cost and written
    /// to `ticks.csv`; one without is not.
    #[test]
    fn short_rounds_make_a_lockstep_run_depend_on_timing() {
        let run = |short: &[(u32, u16, u16)], tag: &str| {
            let dir =
                std::env::temp_dir().join(format!("cqnet-short-{tag}-{}", std::process::id()));
            let mut writer = ResultsWriter::create(&dir).unwrap();
            let mut scenario = fusion_graph::Scenario::default_scenario();
            scenario.faults.clear();
            let topology = fusion_graph::Topology::from_scenario(&scenario, "d").unwrap();
            let mut recorder = Recorder::new(&mut writer, &scenario, &topology);
            for step in 1..=4 {
                recorder.begin_step(step);
                let rows = (0..topology.nodes() as u16)
                    .map(|n| {
                        let mut r = row(step, n);
                        if let Some((_, _, k)) =
                            short.iter().find(|(s, m, _)| *s == step && *m == n)
                        {
                            r.telemetry.short_rounds = *k;
                        }
                        r
                    })
                    .collect();
                recorder.record(rows).unwrap();
            }
            let mut facts = facts(4);
            facts.command = "run --lockstep".into();
            let summary = recorder.finish(&Accounting::default(), facts).unwrap();
            drop(writer);
            let ticks: Vec<Tick> = std::fs::read_to_string(dir.join("ticks.csv"))
                .unwrap()
                .lines()
                .skip(1)
                .map(|l| Tick::parse(l).unwrap())
                .collect();
            let _ = std::fs::remove_dir_all(&dir);
            (summary, ticks)
        };
        let (clean, _) = run(&[], "clean");
        assert!(
            clean.timing_dependent.is_empty(),
            "{:?}",
            clean.timing_dependent
        );
        assert_eq!(clean.fault_cost.short_rounds, 0);
        let (short, ticks) = run(&[(2, 3, 2), (3, 3, 1), (3, 5, 1)], "short");
        assert_eq!(short.fault_cost.short_rounds, 4);
        assert_eq!(short.fault_cost.node_steps_with_short_rounds, 3);
        assert_eq!(short.timing_dependent.len(), 1);
        assert!(
            short.timing_dependent[0].starts_with("4 consensus rounds in 3 node-steps"),
            "{:?}",
            short.timing_dependent
        );
        let node_3_step_2 = ticks
            .iter()
            .find(|t| t.step == 2 && t.node == "node-3")
            .unwrap();
        assert_eq!(node_3_step_2.short_rounds, 2);
    }

    fn facts(steps: u32) -> RunFacts {
        RunFacts {
            command: "test".into(),
            run_id: "test".into(),
            steps_done: steps,
            wall_seconds: 1.0,
            steps_per_second: 1.0,
            processes: 1,
            startup_seconds: None,
            children_memory_kb: None,
            children_cpu: None,
            real_time_rounds: true,
            unscheduled_faults: vec![],
        }
    }
}
