//! The fault matrix, in Jepsen's manner: every fault kind cqnet can inject,
//! each at two scopes (one link, node or sensor; and a share of them), on the
//! default scenario, against a run with no fault. A fault holds for steps
//! [`WINDOW`]; each cell says whether the run completed, whether every
//! message is accounted for, how tracking fared during the fault and after
//! it, and how many steps it took to recover. And the Byzantine sensor on its
//! own: how far it drags the estimate, and what the innovation gate gives back.

use super::paired::{Order, Paired};
use super::{Arm, Check, Claim, Curve, Experiment, Figure, Outcome, Series, Verdict};
use launch::results::{steps_to_recover, window_rmse};
use launch::summary::{RECOVERY_FACTOR, RECOVERY_HOLD};

/// Steps `WINDOW.0..WINDOW.1` carry the fault.
pub const WINDOW: (u32, u32) = (20, 35);
/// Long enough to see the recovery.
pub const STEPS: u32 = 60;

/// The innovation gate at the chi-square(1) 0.999 quantile: an observation
/// whose ν²/S exceeds it is left out.
pub const GATE: &str = "filter.gate=10.83";

/// What every arm of the fault matrix shares: no centralized reference,
/// 60 steps, the innovation gate.
pub const MATRIX_BASE: [&str; 3] = ["reference.centralized=false", "steps=60", GATE];

/// `faults=[{…}]` with the window filled in.
macro_rules! fault {
    ($body:literal) => {
        concat!("faults=[{", $body, ", at_step = 20, duration = 15}]")
    };
}

/// `faults=[{…}, {…}, {…}]`: three faults, each stating its own window.
macro_rules! three_faults {
    ($a:literal, $b:literal, $c:literal) => {
        concat!("faults=[{", $a, "}, {", $b, "}, {", $c, "}]")
    };
}

/// The reference arm, then each kind at its two scopes.
pub const MATRIX: [Arm; 27] = [
    Arm {
        label: "no fault",
        overrides: &[],
    },
    Arm {
        label: "delay, one link",
        overrides: &[fault!(
            r#"kind = "delay", links = [{ from = "node-1", to = "node-4" }], latency_ms = 150.0"#
        )],
    },
    Arm {
        label: "delay, 30% of links",
        overrides: &[fault!(
            r#"kind = "delay", links = [{ from = "*", to = "*", fraction = 0.3 }], latency_ms = 150.0"#
        )],
    },
    Arm {
        label: "loss, one link",
        overrides: &[fault!(
            r#"kind = "loss", links = [{ from = "node-1", to = "node-4" }], probability = 0.5"#
        )],
    },
    Arm {
        label: "loss, 30% of links",
        overrides: &[fault!(
            r#"kind = "loss", links = [{ from = "*", to = "*", fraction = 0.3 }], probability = 0.5"#
        )],
    },
    Arm {
        label: "burst loss, one link",
        overrides: &[fault!(
            r#"kind = "burst_loss", links = [{ from = "node-1", to = "node-4" }], enter_bad = 0.1, leave_bad = 0.3"#
        )],
    },
    Arm {
        label: "burst loss, 30% of links",
        overrides: &[fault!(
            r#"kind = "burst_loss", links = [{ from = "*", to = "*", fraction = 0.3 }], enter_bad = 0.1, leave_bad = 0.3"#
        )],
    },
    Arm {
        label: "duplicate, one link",
        overrides: &[fault!(
            r#"kind = "duplicate", links = [{ from = "node-1", to = "node-4" }], probability = 0.5"#
        )],
    },
    Arm {
        label: "duplicate, 30% of links",
        overrides: &[fault!(
            r#"kind = "duplicate", links = [{ from = "*", to = "*", fraction = 0.3 }], probability = 0.5"#
        )],
    },
    Arm {
        label: "reorder, one link",
        overrides: &[fault!(
            r#"kind = "reorder", links = [{ from = "node-1", to = "node-4" }], probability = 0.5, delay_ms = 30.0"#
        )],
    },
    Arm {
        label: "reorder, 30% of links",
        overrides: &[fault!(
            r#"kind = "reorder", links = [{ from = "*", to = "*", fraction = 0.3 }], probability = 0.5, delay_ms = 30.0"#
        )],
    },
    Arm {
        label: "corrupt, one link",
        overrides: &[fault!(
            r#"kind = "corrupt", links = [{ from = "node-1", to = "node-4" }], probability = 0.3"#
        )],
    },
    Arm {
        label: "corrupt, 30% of links",
        overrides: &[fault!(
            r#"kind = "corrupt", links = [{ from = "*", to = "*", fraction = 0.3 }], probability = 0.3"#
        )],
    },
    Arm {
        label: "partition, one node cut off",
        overrides: &[fault!(
            r#"kind = "partition", groups = [["node-4"], ["node-0", "node-1", "node-2", "node-3", "node-5", "node-6", "node-7", "node-8"]]"#
        )],
    },
    Arm {
        label: "partition, network halved",
        overrides: &[fault!(
            r#"kind = "partition", groups = [["node-0", "node-1", "node-3", "node-4"], ["node-2", "node-5", "node-6", "node-7", "node-8"]]"#
        )],
    },
    Arm {
        label: "SIGKILL, one node",
        overrides: &[
            r#"faults=[{kind = "kill", actor = "node-4", signal = "SIGKILL", at_step = 20, restart_after = 15}]"#,
        ],
    },
    Arm {
        label: "SIGKILL, 3 of 9 nodes",
        overrides: &[three_faults!(
            r#"kind = "kill", actor = "node-0", signal = "SIGKILL", at_step = 20, restart_after = 15"#,
            r#"kind = "kill", actor = "node-4", signal = "SIGKILL", at_step = 20, restart_after = 15"#,
            r#"kind = "kill", actor = "node-8", signal = "SIGKILL", at_step = 20, restart_after = 15"#
        )],
    },
    Arm {
        label: "SIGSTOP, one node",
        overrides: &[
            r#"faults=[{kind = "kill", actor = "node-4", signal = "SIGSTOP", at_step = 20, restart_after = 15}]"#,
        ],
    },
    Arm {
        label: "SIGSTOP, 3 of 9 nodes",
        overrides: &[three_faults!(
            r#"kind = "kill", actor = "node-0", signal = "SIGSTOP", at_step = 20, restart_after = 15"#,
            r#"kind = "kill", actor = "node-4", signal = "SIGSTOP", at_step = 20, restart_after = 15"#,
            r#"kind = "kill", actor = "node-8", signal = "SIGSTOP", at_step = 20, restart_after = 15"#
        )],
    },
    Arm {
        label: "stuck sensor, one",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["sensor-112"], mode = "stuck""#
        )],
    },
    Arm {
        label: "stuck sensors, 30%",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["*"], fraction = 0.3, mode = "stuck""#
        )],
    },
    Arm {
        label: "biased sensor, one",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["sensor-112"], mode = "bias", bias = 0.1"#
        )],
    },
    Arm {
        label: "biased sensors, 30%",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["*"], fraction = 0.3, mode = "bias", bias = 0.1"#
        )],
    },
    Arm {
        label: "sensor dropout, one",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["sensor-112"], mode = "dropout""#
        )],
    },
    Arm {
        label: "sensor dropout, 30%",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["*"], fraction = 0.3, mode = "dropout""#
        )],
    },
    Arm {
        label: "Byzantine sensor, one",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["sensor-112"], mode = "byzantine", phantom = [300.0, 0.0]"#
        )],
    },
    Arm {
        label: "Byzantine sensors, 30%",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["*"], fraction = 0.3, mode = "byzantine", phantom = [300.0, 0.0]"#
        )],
    },
];

/// The Byzantine sensors and the innovation gate.
const BYZANTINE: [Arm; 4] = [
    Arm {
        label: "honest",
        overrides: &[],
    },
    Arm {
        label: "honest, gated",
        overrides: &[GATE],
    },
    Arm {
        label: "30% Byzantine",
        overrides: &[fault!(
            r#"kind = "sensor", sensors = ["*"], fraction = 0.3, mode = "byzantine", phantom = [300.0, 0.0]"#
        )],
    },
    Arm {
        label: "30% Byzantine, gated",
        overrides: &[
            GATE,
            fault!(
                r#"kind = "sensor", sensors = ["*"], fraction = 0.3, mode = "byzantine", phantom = [300.0, 0.0]"#
            ),
        ],
    },
];

pub fn experiments() -> Vec<Experiment> {
    vec![
        Experiment {
            name: "fault-matrix",
            source: "cqnet's fault injection",
            about: "every fault kind at two scopes, steps 20-34, against no fault: completion, accounting, RMSE during and after, steps to recover",
            scenario: fusion_graph::scenario::DEFAULT_SCENARIO,
            // With the innovation gate, reference arm included: without it
            // the CF/DPF does not recover from 30% stuck or Byzantine
            // sensors within the run (the `byzantine` experiment shows how).
            base: &MATRIX_BASE,
            arms: &MATRIX,
            figure: Figure::Panels {
                y_label: "position RMSE and bound, m",
                reference: 0,
                window: WINDOW,
            },
            check: check_matrix,
        },
        Experiment {
            name: "byzantine",
            source: "cqnet's fault injection and innovation gate",
            about: "30% of the sensors report a phantom 300 m east of the target for steps 20-34, with and without the innovation gate (nu^2/S <= 10.83)",
            scenario: fusion_graph::scenario::DEFAULT_SCENARIO,
            base: &["reference.centralized=false", "steps=60"],
            arms: &BYZANTINE,
            figure: Figure::OverTime {
                y_label: "position RMSE, m",
                curves: &[
                    Curve { arm: 0, series: Series::Rmse, label: "honest" },
                    Curve { arm: 1, series: Series::Rmse, label: "honest, gated" },
                    Curve { arm: 2, series: Series::Rmse, label: "30% Byzantine" },
                    Curve { arm: 3, series: Series::Rmse, label: "30% Byzantine, gated" },
                ],
            },
            check: check_byzantine,
        },
    ]
}

/// One cell of the matrix, measured against the reference arm.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    pub label: String,
    pub rmse_during: Option<f64>,
    pub rmse_after: Option<f64>,
    /// The reference arm's RMSE over the same steps after the window.
    pub reference_after: Option<f64>,
    /// Steps from the window's end until the RMSE is within
    /// [`RECOVERY_FACTOR`] of the reference's after-window RMSE for
    /// [`RECOVERY_HOLD`] steps running.
    pub recovered_after: Option<u32>,
    /// Messages neither received, dropped nor malformed, summed over kinds
    /// and runs (as magnitudes, so that no surplus hides a loss).
    pub unaccounted_messages: u64,
}

impl Cell {
    /// Back within the factor of the no-fault RMSE before the run ends,
    /// with every message accounted for.
    pub fn passes(&self) -> bool {
        self.recovered_after.is_some() && self.unaccounted_messages == 0
    }
}

/// Every arm but the first, measured against the first.
pub fn cells(outcome: &Outcome) -> Vec<Cell> {
    let reference = &outcome.arms[0];
    let end = WINDOW.1;
    let reference_after = window_rmse(&reference.steps, end, u32::MAX);
    outcome.arms[1..]
        .iter()
        .map(|a| Cell {
            label: a.label.clone(),
            rmse_during: window_rmse(&a.steps, WINDOW.0, end),
            rmse_after: window_rmse(&a.steps, end, u32::MAX),
            reference_after,
            recovered_after: reference_after.and_then(|r| {
                steps_to_recover(&a.steps, end, RECOVERY_HOLD, |_, rmse| {
                    rmse <= RECOVERY_FACTOR * r
                })
            }),
            unaccounted_messages: a.unaccounted_messages,
        })
        .collect()
}

/// The cells as a table: `<name>-cells.csv`.
pub fn cells_csv(outcome: &Outcome) -> String {
    let mut out = String::from(
        "cell,rmse_during,rmse_after,reference_rmse_after,recovered_after_steps,unaccounted_messages,passes\n",
    );
    let v = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x:.3}"));
    for c in cells(outcome) {
        out.push_str(&format!(
            "{},{},{},{},{},{},{}\n",
            c.label.replace(',', ";"),
            v(c.rmse_during),
            v(c.rmse_after),
            v(c.reference_after),
            c.recovered_after.map_or(String::new(), |k| k.to_string()),
            c.unaccounted_messages,
            c.passes()
        ));
    }
    out
}

fn check_matrix(outcome: &Outcome) -> Check {
    let cells = cells(outcome);
    let failing: Vec<&str> = cells
        .iter()
        .filter(|c| !c.passes())
        .map(|c| c.label.as_str())
        .collect();
    let slowest = cells
        .iter()
        .filter_map(|c| c.recovered_after.map(|k| (k, c.label.as_str())))
        .max();
    let claims = cells
        .iter()
        .map(|c| {
            Claim::exact(
                format!(
                    "under {}, the RMSE recovers to within {RECOVERY_FACTOR}x the no-fault RMSE and every message is accounted for",
                    c.label
                ),
                c.passes(),
            )
        })
        .collect();
    Check {
        verdict: Verdict::of(failing.is_empty()),
        claims,
        statement: format!(
            "{} of {} cells recover to within {RECOVERY_FACTOR}x the no-fault RMSE after the fault with every message accounted for{}{}",
            cells.len() - failing.len(),
            cells.len(),
            slowest.map_or(String::new(), |(k, l)| format!("; slowest: {l}, {k} steps")),
            if failing.is_empty() {
                String::new()
            } else {
                format!("; failing: {}", failing.join(", "))
            }
        ),
    }
}

fn check_byzantine(outcome: &Outcome) -> Check {
    let during = |label: &str| window_rmse(&outcome.arm(label).steps, WINDOW.0, WINDOW.1);
    let after = |label: &str| window_rmse(&outcome.arm(label).steps, WINDOW.1, u32::MAX);
    let (Some(honest), Some(gated_honest), Some(dragged), Some(defended)) = (
        during("honest"),
        during("honest, gated"),
        during("30% Byzantine"),
        during("30% Byzantine, gated"),
    ) else {
        return Check {
            verdict: Verdict::of(false),
            claims: Vec::new(),
            statement: "an arm reported no estimate during the fault".into(),
        };
    };
    let (Some(honest_after), Some(dragged_after), Some(defended_after)) = (
        after("honest"),
        after("30% Byzantine"),
        after("30% Byzantine, gated"),
    ) else {
        return Check {
            verdict: Verdict::of(false),
            claims: Vec::new(),
            statement: "an arm reported no estimate after the fault".into(),
        };
    };
    // Run by run: the gated and ungated RMSE during the attack, and the
    // gated RMSE after it against RECOVERY_FACTOR times the honest one.
    let per_run = |label: &str, from: u32, to: u32, scale: f64| -> Vec<Option<f64>> {
        outcome
            .arm(label)
            .per_run_series
            .iter()
            .map(|run| window_rmse(run, from, to).map(|r| r * scale))
            .collect()
    };
    let claims = vec![
        Claim::judged(
            "the innovation gate keeps the RMSE during the attack below the ungated one",
            Paired::of(
                &per_run("30% Byzantine, gated", WINDOW.0, WINDOW.1, 1.0),
                &per_run("30% Byzantine", WINDOW.0, WINDOW.1, 1.0),
            ),
            |p| p.verdict(Order::Lower),
            |p| format!("{} m over {} runs", p.text(2), p.runs),
        ),
        Claim::judged(
            format!("after the attack the gated RMSE is within {RECOVERY_FACTOR}x the honest one"),
            Paired::of(
                &per_run("30% Byzantine, gated", WINDOW.1, u32::MAX, 1.0),
                &per_run("honest", WINDOW.1, u32::MAX, RECOVERY_FACTOR),
            ),
            |p| p.verdict(Order::Lower),
            |p| {
                format!(
                    "gated minus {RECOVERY_FACTOR}x honest {} m over {} runs",
                    p.text(2),
                    p.runs
                )
            },
        ),
    ];
    Check {
        verdict: Verdict::all(claims.iter().map(|c| c.verdict)),
        claims,
        statement: format!(
            "RMSE during the fault: honest {honest:.1} m (gated {gated_honest:.1} m); 30% Byzantine sensors drag it to {dragged:.1} m, the gate holds it at {defended:.1} m; after it: honest {honest_after:.1} m, ungated {dragged_after:.1} m, gated {defended_after:.1} m"
        ),
    }
}
