//! `cqnet view OUT_DIR`: a finished run (of `run` or `sim`) read back from
//! its results and replayed to the view, a step per step period.
//!
//! What the results files do not keep is not shown: which sensors were
//! active, and link traffic over time (the replay shows each link's
//! average over the whole run).

use fusion_graph::vocabulary::Vocabulary;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use fusion_graph::faults::FaultSchedule;
use fusion_graph::scenario::Fault;
use fusion_graph::Topology;
use transport::accounting::Accounting;

use launch::feed::{link_bytes_per_step, setup_event, step_event, Hub, NodeEstimate, ViewEvent};
use launch::results::Tick;
use launch::summary::Summary;

/// A finished run, read back.
pub struct FinishedRun {
    pub summary: Summary,
    pub topology: Topology,
    /// Per step: the truth and every report.
    pub steps: BTreeMap<u32, ([f64; 2], Vec<NodeEstimate>)>,
    pub accounting: Option<Accounting>,
}

impl FinishedRun {
    /// The run in `dir`, written by a program with `vocabulary`'s parts.
    pub fn read(dir: &Path, vocabulary: Vocabulary) -> anyhow::Result<Self> {
        let summary_path = dir.join("summary.json");
        let text = std::fs::read_to_string(&summary_path).with_context(|| {
            format!(
                "reading {} (is {} the output folder of a finished `cqnet run` or `cqnet sim`?)",
                summary_path.display(),
                dir.display()
            )
        })?;
        let summary: Summary = vocabulary
            .reading(|| serde_json::from_str(&text))
            .with_context(|| format!("{} is not a cqnet summary", summary_path.display()))?;
        let topology =
            Topology::from_scenario(&summary.scenario, &summary_path.display().to_string())?;
        let ticks_path = dir.join("ticks.csv");
        let ticks = std::fs::read_to_string(&ticks_path)
            .with_context(|| format!("reading {}", ticks_path.display()))?;
        let steps = parse_ticks(&ticks).with_context(|| format!("in {}", ticks_path.display()))?;
        let accounting = std::fs::read_to_string(dir.join("links.csv"))
            .ok()
            .and_then(|t| Accounting::from_csv(&t, vocabulary.payloads()));
        Ok(Self {
            summary,
            topology,
            steps,
            accounting,
        })
    }
}

type Steps = BTreeMap<u32, ([f64; 2], Vec<NodeEstimate>)>;

/// `ticks.csv`, read by [`Tick::parse`], into each step's truth and reports.
fn parse_ticks(text: &str) -> anyhow::Result<Steps> {
    let mut steps = Steps::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let tick = Tick::parse(line)
            .ok_or_else(|| anyhow::anyhow!("line {}: not a row of ticks.csv: {line:?}", i + 1))?;
        let entry = steps
            .entry(tick.step)
            .or_insert_with(|| ([0.0; 2], Vec::new()));
        entry.0 = tick.truth;
        entry.1.push(NodeEstimate {
            node: tick.node,
            estimate: tick.estimate,
            error: tick.error,
            bound: tick.bound,
            disagreement: tick.disagreement,
        });
    }
    Ok(steps)
}

/// Nodes a scheduled kill holds down at `step`.
fn killed_nodes(faults: &[Fault], step: u32) -> Vec<u16> {
    faults
        .iter()
        .filter(|f| f.holds(step))
        .filter_map(|f| match f {
            Fault::Kill(kill) => match kill.actor.parse() {
                Ok(fusion_graph::ActorId::Node(n)) => Some(n),
                _ => None,
            },
            _ => None,
        })
        .collect()
}

/// Publishes the run to `hub`, `period` apart per step (zero: at once).
pub fn replay(run: &FinishedRun, hub: &Hub, period: Duration) {
    let scenario = &run.summary.scenario;
    let mut setup = setup_event(scenario, &run.topology, "replay");
    if let ViewEvent::Setup { faults, .. } = &mut setup {
        // The summary's list has the faults the run found too (crashes).
        faults.clone_from(&run.summary.faults);
    }
    hub.publish(&setup);
    let schedule = FaultSchedule::new(&scenario.faults);
    for (&step, (truth, rows)) in &run.steps {
        let dead = killed_nodes(&scenario.faults, step);
        hub.publish(&step_event(
            &schedule,
            &run.topology,
            step,
            *truth,
            &BTreeSet::new(),
            &dead,
        ));
        hub.publish(&ViewEvent::Estimates {
            step,
            rows: rows.clone(),
        });
        if !period.is_zero() {
            std::thread::sleep(period);
        }
    }
    if let Some(acc) = &run.accounting {
        let steps = run.summary.steps as f64;
        hub.publish(&ViewEvent::Traffic {
            step: run.summary.steps,
            bytes_per_step: link_bytes_per_step(&run.topology, acc, |_| steps),
        });
    }
    hub.publish(&ViewEvent::End {
        steps: run.summary.steps,
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_parse_into_steps_with_their_truth_and_reports() {
        let text = "step,node,true_x,true_y,est_x,est_y,error,bound,local_bound\n\
                    1,node-0,1,2,3,4,2.8,0.5,\n\
                    1,central,1,2,1,2,0,,\n\
                    2,node-0,5,6,5,6,0,1,\n";
        let steps = parse_ticks(text).unwrap();
        assert_eq!(steps.len(), 2);
        assert_eq!(steps[&1].0, [1.0, 2.0]);
        assert_eq!(steps[&1].1.len(), 2);
        assert_eq!(steps[&1].1[1].bound, None);
        assert_eq!(steps[&2].1[0].bound, Some(1.0));
    }

    #[test]
    fn a_malformed_row_is_an_error_naming_its_line() {
        let e = parse_ticks("header\n1,node-0,x,2,3,4,5,6\n").unwrap_err();
        assert!(format!("{e:#}").contains("line 2"), "{e:#}");
    }
}
