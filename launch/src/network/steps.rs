//! The run's steps: the world advanced, the reports of every node gathered
//! until the step is complete or its time is up, and the results written.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use anyhow::Context;
use fusion_graph::faults::FaultSchedule;
use fusion_graph::scenario::Scenario;
use fusion_graph::{ActorId, Topology};
use node::CentralizedReference;
use transport::{IceoryxTransport, Transport};
use wire::{Message, Payload};

use crate::feed::{step_event, Hub, NodeEstimate, ViewEvent};
use crate::results::{Recorder, TickRow};
use crate::sim::central_telemetry;
use crate::world::World;

use super::holes::Gaps;
use super::options::{RunOptions, RunProgress};
use super::processes::{crash_fault, Processes};

/// The steps, from the first to the scenario's last or an interruption:
/// each ticks the world, applies the faults, gathers the nodes' reports
/// (and the centralized reference's observations) until every live node
/// reported (lockstep) or the step's time is up. Returns the steps done
/// and the seconds they took.
pub(super) fn run_steps(
    scenario: &Scenario,
    topology: &Topology,
    options: &RunOptions,
    lockstep: bool,
    w: &mut Processes<'_>,
    recorder: &mut Recorder<'_>,
    progress: &mut dyn FnMut(RunProgress<'_>),
) -> anyhow::Result<(u32, f64, Gaps)> {
    let view = options.view.as_deref();
    let mut gaps = Gaps::new(topology.nodes());
    let mut world = World::new(scenario)?;
    let mut reports = StepReports {
        central: options
            .centralized
            .then(|| CentralizedReference::new(scenario, topology))
            .transpose()
            .context("centralized reference")?,
        truths: BTreeMap::new(),
        inbox: Vec::new(),
        rows: Vec::new(),
        active_sensors: std::collections::BTreeSet::new(),
    };
    let schedule = FaultSchedule::new(&scenario.faults);
    let period = Duration::from_secs_f64(scenario.clock.step_period_ms / 1e3);
    let step_timeout = Duration::from_secs_f64(scenario.clock.step_timeout_ms / 1e3);
    let run_start = Instant::now();
    let mut steps_done = 0;
    let mut crashes_shown = 0;

    for step in 1..=scenario.steps {
        w.step = step;
        w.poll_events();
        let returned = w.restart_returning()? | w.admit_restarted();
        let process_faults = w.apply_process_faults(&schedule, step, lockstep)? || returned;
        schedule.apply_link_faults(step, w.transport.me(), w.transport.shaper(), topology);
        let views = schedule.membership_views(step, topology, &w.alive);
        let truth = world.advance();
        reports.remember_truth(step, truth.into());
        recorder.begin_step(step);
        crate::world::begin_step(
            &mut w.transport,
            &w.truths,
            step,
            &truth,
            &views,
            &w.views,
            process_faults,
        )?;
        w.views = views;
        let step_start = Instant::now();
        let step_end = if lockstep {
            step_start + step_timeout
        } else {
            run_start + period * step
        };
        loop {
            let all_in = recorder.reports(step) >= w.alive.iter().filter(|a| **a).count();
            if (lockstep && all_in) || Instant::now() >= step_end || w.interrupted {
                break;
            }
            let left = step_end.saturating_duration_since(Instant::now());
            w.transport.wait(left.min(Duration::from_millis(50)))?;
            let rows = reports.take(&mut w.transport, step)?;
            gaps.heard_from(&rows, &w.sensors_alive, &schedule);
            publish_late_rows(view, &rows, step);
            reports
                .rows
                .extend(rows.iter().filter(|r| r.step == step).cloned());
            recorder.record(rows)?;
            w.poll_events();
        }
        if let Some(update) = reports.central.as_mut().and_then(|c| c.finish_step()) {
            let row = TickRow {
                step,
                node: "central".into(),
                truth: truth.into(),
                telemetry: central_telemetry(update.estimate, update.bound),
            };
            reports.rows.push(row.clone());
            recorder.record(vec![row])?;
        }
        steps_done = step;
        gaps.close_step(step, &w.alive, &reports.rows);
        if let Some(hub) = view {
            let dead: Vec<u16> = (0..topology.nodes() as u16)
                .filter(|n| !w.alive[*n as usize])
                .collect();
            hub.publish(&step_event(
                &schedule,
                topology,
                step,
                [truth[0], truth[1]],
                &reports.active_sensors,
                &dead,
            ));
            hub.publish(&ViewEvent::Estimates {
                step,
                rows: reports.rows.iter().map(NodeEstimate::of).collect(),
            });
            for (actor, at, status) in &w.crashed[crashes_shown..] {
                hub.publish(&ViewEvent::Fault(crash_fault(*actor, *at, status)));
            }
            crashes_shown = w.crashed.len();
        }
        progress(RunProgress::Step {
            step,
            rows: &reports.rows,
        });
        reports.rows.clear();
        reports.active_sensors.clear();
        if w.interrupted {
            break;
        }
    }
    let wall = run_start.elapsed().as_secs_f64();
    if !lockstep && !w.interrupted {
        let heard = |rows: &[TickRow], w: &Processes<'_>| {
            gaps.heard_from(rows, &w.sensors_alive, &schedule)
        };
        await_last_reports(steps_done, w, &mut reports, recorder, heard)?;
    }
    Ok((steps_done, wall, gaps))
}

/// How long the launcher waits for a lagging node's next report after the
/// last step, and at most in all.
const LAST_REPORTS_IDLE: Duration = Duration::from_secs(2);
const LAST_REPORTS_AT_MOST: Duration = Duration::from_secs(30);

/// In real time the clock ends the steps, not the nodes: a node behind it
/// is still working on the last steps. Its reports are waited for (late,
/// as they are), while they keep coming, before the nodes are told to
/// stop; stopping them at once lost every report still on its way, all of
/// them in a network that lagged by more than its run.
fn await_last_reports(
    last: u32,
    w: &mut Processes<'_>,
    reports: &mut StepReports,
    recorder: &mut Recorder<'_>,
    mut heard: impl FnMut(&[TickRow], &Processes<'_>),
) -> anyhow::Result<()> {
    let started = Instant::now();
    let mut idle_until = started + LAST_REPORTS_IDLE;
    loop {
        let live = w.alive.iter().filter(|a| **a).count();
        let now = Instant::now();
        if recorder.reports(last) >= live
            || now >= idle_until
            || now >= started + LAST_REPORTS_AT_MOST
            || w.interrupted
        {
            return Ok(());
        }
        w.transport.wait(Duration::from_millis(50))?;
        let rows = reports.take(&mut w.transport, last + 1)?;
        if !rows.is_empty() {
            idle_until = Instant::now() + LAST_REPORTS_IDLE;
        }
        heard(&rows, w);
        recorder.record(rows)?;
        w.poll_events();
    }
}

/// What the launcher hears in a step: the nodes' reports, and the
/// observations the centralized reference weighs.
struct StepReports {
    central: Option<CentralizedReference>,
    /// The true state of each step still within the late-report horizon.
    truths: BTreeMap<u32, [f64; 4]>,
    inbox: Vec<Message>,
    /// This step's reports, for the progress and the view.
    rows: Vec<TickRow>,
    /// The sensors heard this step, for the view.
    active_sensors: std::collections::BTreeSet<u16>,
}

impl StepReports {
    /// Keeps `step`'s truth; reports later than the horizon are left out,
    /// so their truths go.
    fn remember_truth(&mut self, step: u32, truth: [f64; 4]) {
        self.truths.insert(step, truth);
        while let Some(oldest) = self.truths.first_entry() {
            if *oldest.key() + crate::results::LATE_ROW_HORIZON >= step {
                break;
            }
            oldest.remove();
        }
    }

    /// Takes what has arrived: the nodes' reports as rows (of this step or
    /// a late one), the observations into the centralized reference.
    fn take(
        &mut self,
        transport: &mut IceoryxTransport,
        step: u32,
    ) -> anyhow::Result<Vec<TickRow>> {
        self.inbox.clear();
        let now = transport.now();
        transport.receive(now, &mut self.inbox)?;
        let mut rows = Vec::new();
        for m in self.inbox.drain(..) {
            match (m.payload, m.header.sender) {
                (Payload::Telemetry(tel), ActorId::Node(n)) => {
                    let Some(truth) = self.truths.get(&m.header.step) else {
                        continue;
                    };
                    rows.push(TickRow {
                        step: m.header.step,
                        node: format!("node-{n}"),
                        truth: *truth,
                        telemetry: tel,
                    });
                }
                (
                    payload @ (Payload::Observation { .. } | Payload::RawObservation { .. }),
                    sender,
                ) => {
                    if let (ActorId::Sensor(s), true) = (sender, m.header.step == step) {
                        self.active_sensors.insert(s);
                    }
                    if let Some(c) = self.central.as_mut() {
                        c.observe(&Message {
                            header: m.header,
                            payload,
                        });
                    }
                }
                _ => {}
            }
        }
        Ok(rows)
    }
}

/// Reports of earlier steps that arrived late go to the view at once.
fn publish_late_rows(view: Option<&Hub>, rows: &[TickRow], step: u32) {
    let Some(hub) = view else { return };
    let mut late: BTreeMap<u32, Vec<NodeEstimate>> = BTreeMap::new();
    for r in rows.iter().filter(|r| r.step < step) {
        late.entry(r.step).or_default().push(NodeEstimate::of(r));
    }
    for (step, rows) in late {
        hub.publish(&ViewEvent::Estimates { step, rows });
    }
}
