//! Seed 001's Fig. 2: tracking error under four sensor managers, on seed
//! 001's scenario (N_max = 18, at most 4 per node).

use fusion_graph::scenario::SEED001_SCENARIO;

use super::{Arm, Check, Curve, Experiment, Figure, Outcome, Series};

const MANAGERS: [Arm; 4] = [
    Arm {
        label: "conditional PCRLB",
        overrides: &["sensors.manager=pcrlb"],
    },
    Arm {
        label: "non-conditional PCRLB",
        overrides: &["sensors.manager=pcrlb_nonconditional"],
    },
    Arm {
        label: "closest",
        overrides: &["sensors.manager=closest"],
    },
    Arm {
        label: "random",
        overrides: &["sensors.manager=random"],
    },
];

pub fn experiments() -> Vec<Experiment> {
    vec![Experiment {
        name: "sensor-selection",
        source: "Mohammadi and Asif (selection), Fig. 2",
        about: "position RMSE over time under the conditional-PCRLB, non-conditional-PCRLB, closest and random sensor managers, with the bytes each costs per step",
        scenario: SEED001_SCENARIO,
        base: &["reference.centralized=false"],
        arms: &MANAGERS,
        figure: Figure::OverTime {
            y_label: "position RMSE, m",
            curves: &[
                Curve {
                    arm: 0,
                    series: Series::Rmse,
                    label: "conditional PCRLB",
                },
                Curve {
                    arm: 1,
                    series: Series::Rmse,
                    label: "non-conditional PCRLB",
                },
                Curve {
                    arm: 2,
                    series: Series::Rmse,
                    label: "closest",
                },
                Curve {
                    arm: 3,
                    series: Series::Rmse,
                    label: "random",
                },
            ],
        },
        check: check_fig2,
    }]
}

/// "The conditional PCRLB-based approach gives the lowest RMSE": its mean
/// RMSE from step 10 is the lowest of the four. The statement gives every
/// manager's RMSE and its selection bytes per step, whatever the verdict.
fn check_fig2(o: &Outcome) -> Check {
    let rmse: Vec<Option<f64>> = MANAGERS
        .iter()
        .map(|m| o.arm(m.label).mean(Series::Rmse))
        .collect();
    let Some(rmse) = rmse.into_iter().collect::<Option<Vec<f64>>>() else {
        return Check {
            holds: false,
            statement: "an RMSE of fig. 2 is missing from the outcome".into(),
        };
    };
    let lowest = rmse.iter().copied().fold(f64::INFINITY, f64::min);
    let figures = MANAGERS
        .iter()
        .zip(&rmse)
        .map(|(m, r)| {
            let a = o.arm(m.label);
            format!(
                "{} {r:.3} m ({:.0} B/step selection, {:.0} B/step activations)",
                m.label, a.selection_bytes_per_step, a.activation_bytes_per_step
            )
        })
        .collect::<Vec<_>>()
        .join("; ");
    Check {
        holds: rmse[0] == lowest,
        statement: format!(
            "the conditional PCRLB manager's RMSE is {} the four; means from step 10: {figures}",
            if rmse[0] == lowest {
                "the lowest of"
            } else {
                "NOT the lowest of"
            }
        ),
    }
}
