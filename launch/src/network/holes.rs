//! What a run's reports leave out, told as it happens and at the end: live
//! nodes with no report in time ([`Holes`]), and sensors activated again
//! and again that never answered ([`Unanswered`]); [`Gaps`] feeds both the
//! same reports.

use std::collections::BTreeMap;

use fusion_graph::faults::{FaultSchedule, SensorFault};
use fusion_graph::ActorId;

use crate::results::TickRow;
use crate::summary::AppliedFault;

use super::processes::name_some;

/// Everything the reports leave out.
pub(super) struct Gaps {
    holes: Holes,
    sensors: Unanswered,
}

impl Gaps {
    pub(super) fn new(nodes: usize) -> Self {
        Self {
            holes: Holes::new(nodes),
            sensors: Unanswered::default(),
        }
    }

    /// Reports that arrived, of any step.
    pub(super) fn heard_from(
        &mut self,
        rows: &[TickRow],
        sensors_alive: &[bool],
        schedule: &FaultSchedule,
    ) {
        self.holes.heard_from(rows);
        self.sensors.heard_from(rows, sensors_alive, schedule);
    }

    /// `step` is over: `rows` are its reports in time.
    pub(super) fn close_step(&mut self, step: u32, alive: &[bool], rows: &[TickRow]) {
        self.holes.close_step(step, alive, rows);
    }

    /// The gaps as faults of the run, for the summary.
    pub(super) fn as_faults(&self, last_step: u32) -> Vec<AppliedFault> {
        self.holes
            .as_fault()
            .into_iter()
            .chain(self.sensors.as_fault(last_step))
            .collect()
    }

    /// Why the run failed, if a live node never reported or a live sensor
    /// never answered.
    pub(super) fn failure(&self) -> Option<String> {
        self.holes
            .never_heard()
            .or_else(|| self.sensors.never_answered())
    }
}

/// The live nodes whose report of a step did not come in time: told as it
/// happens, and a node never heard from while it was live fails the run.
struct Holes {
    /// Steps each node was live.
    live_steps: Vec<u32>,
    /// Whether each node's report ever arrived, in time or late.
    heard: Vec<bool>,
    /// Live node-steps with no report in time, so far.
    missing: u64,
    /// Steps with a hole so far, which pace the warnings.
    steps_with_holes: u32,
    /// Which nodes reported the step being closed in time (kept to be
    /// refilled each step).
    in_time: Vec<bool>,
    /// The first and last steps with a hole.
    span: Option<(u32, u32)>,
    /// Live steps each node had no report in time for.
    missed: Vec<u32>,
}

/// The node a report row is from (`None` for the centralized reference's).
fn reporting_node(row: &TickRow) -> Option<usize> {
    match row.node.parse::<ActorId>() {
        Ok(ActorId::Node(n)) => Some(n as usize),
        _ => None,
    }
}

impl Holes {
    fn new(nodes: usize) -> Self {
        Self {
            live_steps: vec![0; nodes],
            heard: vec![false; nodes],
            missing: 0,
            steps_with_holes: 0,
            in_time: vec![false; nodes],
            span: None,
            missed: vec![0; nodes],
        }
    }

    fn heard_from(&mut self, rows: &[TickRow]) {
        for n in rows.iter().filter_map(reporting_node) {
            self.heard[n] = true;
        }
    }

    /// Counts the live nodes with no report among `rows`, `step`'s reports
    /// in time, and warns: at the first three steps with a hole, then at
    /// every twentieth, so that a long run with a lasting hole says so
    /// without flooding the terminal.
    fn close_step(&mut self, step: u32, alive: &[bool], rows: &[TickRow]) {
        self.in_time.fill(false);
        for n in rows.iter().filter_map(reporting_node) {
            self.in_time[n] = true;
        }
        let mut missing = Vec::new();
        for (n, live) in alive.iter().enumerate() {
            if !*live {
                continue;
            }
            self.live_steps[n] += 1;
            if !self.in_time[n] {
                missing.push(ActorId::Node(n as u16));
            }
        }
        if missing.is_empty() {
            return;
        }
        for a in &missing {
            if let ActorId::Node(n) = a {
                self.missed[*n as usize] += 1;
            }
        }
        self.span = Some(self.span.map_or((step, step), |(first, _)| (first, step)));
        self.missing += missing.len() as u64;
        self.steps_with_holes += 1;
        if self.steps_with_holes <= 3 || self.steps_with_holes.is_multiple_of(20) {
            tracing::warn!(
                "step {step}: no report in time from {} ({} live node-steps without one so far)",
                name_some(&missing, 5),
                self.missing
            );
        }
    }

    /// The holes as a fault of the run, for the summary: when, how many,
    /// and the nodes that missed the most.
    fn as_fault(&self) -> Option<AppliedFault> {
        let (first, last) = self.span?;
        let mut worst: Vec<(u32, ActorId)> = self
            .missed
            .iter()
            .enumerate()
            .filter(|(_, m)| **m > 0)
            .map(|(n, m)| (*m, ActorId::Node(n as u16)))
            .collect();
        worst.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        let nodes: Vec<ActorId> = worst.iter().map(|(_, a)| *a).collect();
        Some(AppliedFault::new(
            first,
            Some(last + 1),
            format!(
                "no report in time from live nodes: {} node-steps, from {}",
                self.missing,
                name_some(&nodes, 5)
            ),
        ))
    }

    /// The nodes that were live and never reported, as an error's words.
    fn never_heard(&self) -> Option<String> {
        let silent: Vec<ActorId> = (0..self.heard.len())
            .filter(|n| self.live_steps[*n] > 0 && !self.heard[*n])
            .map(|n| ActorId::Node(n as u16))
            .collect();
        let longest = silent
            .iter()
            .filter_map(|a| match a {
                ActorId::Node(n) => Some(self.live_steps[*n as usize]),
                _ => None,
            })
            .max()?;
        Some(format!(
            "{} never reported, though live for up to {longest} steps: the run has no estimate from {}",
            name_some(&silent, 10),
            if silent.len() == 1 { "it" } else { "them" }
        ))
    }
}

/// Sensors whose node says they were activated several times and never
/// answered: told once each as it happens (under heavy loss, a sensor may
/// answer later); one still unanswered in its node's last report is a
/// fault in the summary and fails the run. A sensor that is dead, or that a
/// `dropout` fault silences, is not counted: its silence is the fault's.
#[derive(Default)]
struct Unanswered {
    /// Each sensor told of, with its node and the step it was first told.
    told: BTreeMap<u16, (u16, u32)>,
    /// Each node's latest report: its step, and its first unanswered
    /// sensor that counts.
    latest: BTreeMap<u16, (u32, Option<u16>)>,
}

impl Unanswered {
    fn heard_from(&mut self, rows: &[TickRow], sensors_alive: &[bool], schedule: &FaultSchedule) {
        for r in rows {
            let Some(node) = reporting_node(r) else {
                continue;
            };
            let step = r.step;
            let counted = r.telemetry.first_unanswered.filter(|s| {
                sensors_alive.get(*s as usize).copied().unwrap_or(false)
                    && !matches!(schedule.sensor_fault(step, *s), Some(SensorFault::Dropout))
            });
            let node = node as u16;
            if self.latest.get(&node).is_some_and(|(at, _)| *at > step) {
                continue;
            }
            self.latest.insert(node, (step, counted));
            let Some(sensor) = counted else { continue };
            if self.told.contains_key(&sensor) {
                continue;
            }
            self.told.insert(sensor, (node, step));
            tracing::warn!(
                "step {step}: sensor-{sensor} has answered none of its activations ({} of node-{node}'s sensors so far)",
                r.telemetry.unanswered_sensors
            );
        }
    }

    /// The sensors still unanswered in their node's last report.
    fn still_silent(&self) -> Vec<(u16, u16)> {
        self.latest
            .iter()
            .filter_map(|(node, (_, s))| s.map(|s| (s, *node)))
            .collect()
    }

    /// The sensors still unanswered at the end, as a fault of the run for
    /// the summary (those that answered later were only told of).
    fn as_fault(&self, last_step: u32) -> Option<AppliedFault> {
        let silent = self.still_silent();
        let first = silent
            .iter()
            .filter_map(|(s, _)| self.told.get(s))
            .map(|(_, step)| *step)
            .min()?;
        let sensors: Vec<ActorId> = silent.iter().map(|(s, _)| ActorId::Sensor(*s)).collect();
        Some(AppliedFault::new(
            first,
            Some(last_step + 1),
            format!(
                "sensors that answered no activation: {}",
                name_some(&sensors, 5)
            ),
        ))
    }

    /// The sensors that never answered, as an error's words.
    fn never_answered(&self) -> Option<String> {
        let silent = self.still_silent();
        if silent.is_empty() {
            return None;
        }
        let names: Vec<String> = silent
            .iter()
            .take(5)
            .map(|(s, n)| format!("sensor-{s} (of node-{n})"))
            .collect();
        let more = silent.len().saturating_sub(5);
        Some(format!(
            "{}{} never answered an activation, though live and activated again and again",
            names.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        ))
    }
}
