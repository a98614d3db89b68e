//! The dissertation's chapter 4: sensor management by compressive sensing
//! over a multiple-access channel. Fig. 4.1, the tracking error with every
//! sensor sending on a channel of its own, with `E` random sensors, and
//! with the designed transmissions over M = 1, 3 and 6 slots; Fig. 4.2,
//! the designed probabilities over the field at two steps. Each for the
//! chapter's design (eq. 4.19) and for the design that counts a repeated
//! sensor once, against two baselines: random sensors on channels of their
//! own, and every sensor alike sharing the M slots.

use fusion_graph::scenario::COMPRESSIVE_SCENARIO;

use super::diagnostics::DesignRecord;
use super::paired::{Order, Paired, Verdict};
use super::{Arm, ArmOutcome, Check, Claim, Curve, Experiment, Figure, Outcome, Series};

pub(crate) const ARMS: [Arm; 9] = [
    Arm {
        label: "all send",
        overrides: &["channel.design=all"],
    },
    Arm {
        label: "random",
        overrides: &["channel.design=random"],
    },
    Arm {
        label: "uniform, M = 6",
        overrides: &["channel.design=uniform", "channel.slots=6"],
    },
    Arm {
        label: "M = 1",
        overrides: &["channel.slots=1"],
    },
    Arm {
        label: "M = 3",
        overrides: &["channel.slots=3"],
    },
    Arm {
        label: "M = 6",
        overrides: &["channel.slots=6"],
    },
    Arm {
        label: "counted once, M = 1",
        overrides: &["channel.design=counted_once", "channel.slots=1"],
    },
    Arm {
        label: "counted once, M = 3",
        overrides: &["channel.design=counted_once", "channel.slots=3"],
    },
    Arm {
        label: "counted once, M = 6",
        overrides: &["channel.design=counted_once", "channel.slots=6"],
    },
];

pub(crate) const CURVES: [Curve; 9] = [
    Curve {
        arm: 0,
        series: Series::Rmse,
        label: "all send (25 parallel channels)",
    },
    Curve {
        arm: 1,
        series: Series::Rmse,
        label: "random (E = 6 sensors, a channel each)",
    },
    Curve {
        arm: 2,
        series: Series::Rmse,
        label: "uniform p (random sensors in M = 6 slots)",
    },
    Curve {
        arm: 3,
        series: Series::Rmse,
        label: "eq. 4.19 design, M = 1",
    },
    Curve {
        arm: 4,
        series: Series::Rmse,
        label: "eq. 4.19 design, M = 3",
    },
    Curve {
        arm: 5,
        series: Series::Rmse,
        label: "eq. 4.19 design, M = 6",
    },
    Curve {
        arm: 6,
        series: Series::Rmse,
        label: "counted once, M = 1",
    },
    Curve {
        arm: 7,
        series: Series::Rmse,
        label: "counted once, M = 3",
    },
    Curve {
        arm: 8,
        series: Series::Rmse,
        label: "counted once, M = 6",
    },
];

/// The two designs: the chapter's (eq. 4.19) and the one that counts a
/// repeated sensor once; each with its arms at M = 1, 3 and 6.
pub(crate) const DESIGNS: [(&str, [&str; 3]); 2] = [
    ("eq. 4.19", ["M = 1", "M = 3", "M = 6"]),
    (
        "counted once",
        [
            "counted once, M = 1",
            "counted once, M = 3",
            "counted once, M = 6",
        ],
    ),
];

/// The steps of Fig. 4.2.
const DESIGN_STEPS: [u32; 2] = [4, 10];

/// A sensor counts as carrying probability from this on (Fig. 4.2: "the
/// rest are assigned almost zero").
const NEGLIGIBLE: f64 = 0.05;

pub fn experiments() -> Vec<Experiment> {
    vec![Experiment {
        name: "cs-sensor-management",
        source: "Zheng (dissertation), ch. 4, Figs. 4.1 and 4.2",
        about: "position RMSE over 15 steps of one fusion centre hearing 25 amplitude sensors through a multiple-access channel: all sensors on parallel channels, 6 random sensors on a channel each, every sensor alike sharing M = 6 slots, and transmission probabilities that maximize det J under the energy budget E = 6 over M = 1, 3, 6 slots, by the chapter's eq. 4.19 and by the drawn matrix's expected information (a repeated sensor counted once); each design's probabilities over the field at steps 4 and 10",
        scenario: COMPRESSIVE_SCENARIO,
        base: &[],
        arms: &ARMS,
        figure: Figure::OverTimeAndDesign {
            y_label: "position RMSE, m",
            curves: &CURVES,
            designs: &[(5, "design"), (8, "design-counted-once")],
            steps: &DESIGN_STEPS,
        },
        check: check_chapter_4,
    }]
}

/// Each run's RMSE over all its steps (the chapter's MSE is over its 15
/// steps, from the first), in seed order.
pub(crate) fn whole_run_rmse(arm: &ArmOutcome) -> Vec<Option<f64>> {
    arm.per_run_series
        .iter()
        .map(|steps| {
            let squares: Vec<f64> = steps.iter().filter_map(|m| m.rmse.map(|r| r * r)).collect();
            (!squares.is_empty())
                .then(|| (squares.iter().sum::<f64>() / squares.len() as f64).sqrt())
        })
        .collect()
}

/// Fig. 4.1's claims for one design, each a paired comparison of
/// whole-run RMSEs: "M = 6 is ahead of random" (and of random sensors in
/// the same slots), "close to all-send", "M = 1 < 3 < 6".
pub(crate) fn figure_4_1_claims(o: &Outcome, design: &str, arms: [&str; 3]) -> Vec<Claim> {
    let rmse = |label: &str| whole_run_rmse(o.arm(label));
    let (all, random, uniform) = (rmse("all send"), rmse("random"), rmse("uniform, M = 6"));
    let (m1, m3, m6) = (rmse(arms[0]), rmse(arms[1]), rmse(arms[2]));
    let lower = |claim: String, a: &[Option<f64>], b: &[Option<f64>]| {
        Claim::judged(
            claim,
            Paired::of(a, b),
            |p| p.verdict(Order::Lower),
            |p| format!("{} m over {} runs", p.text(3), p.runs),
        )
    };
    // Closer to all-send than to random: (M6 − all) − (random − M6) < 0,
    // run by run.
    let closer: Vec<Option<f64>> = m6
        .iter()
        .zip(&all)
        .zip(&random)
        .map(|((m6, all), random)| Some(2.0 * (*m6)? - (*all)? - (*random)?))
        .collect();
    let zeros = vec![Some(0.0); closer.len()];
    vec![
        lower(
            format!("{design}: M = 6 tracks better than random selection of E = 6 sensors"),
            &m6,
            &random,
        ),
        lower(
            format!("{design}: M = 6 tracks better than every sensor alike in the same 6 slots"),
            &m6,
            &uniform,
        ),
        lower(
            format!("{design}: M = 6 is closer to all-send than to random selection"),
            &closer,
            &zeros,
        ),
        lower(
            format!("{design}: M = 3 tracks better than M = 1"),
            &m3,
            &m1,
        ),
        lower(
            format!("{design}: M = 6 tracks better than M = 3"),
            &m6,
            &m3,
        ),
    ]
}

/// The bound a design promised against the one its drawn Φ gives, each
/// averaged over runs, step by step, in its M = 6 arm `arm`: the largest
/// share by which they differ, and whether it is within a tenth at every
/// step.
pub(crate) fn promise_claim(o: &Outcome, design: &str, arm: &str) -> Claim {
    let a = o.arm(arm);
    let worst = a
        .series(Series::Bound)
        .into_iter()
        .zip(a.series(Series::AuxBound))
        .filter_map(|(drawn, promised)| Some((promised? - drawn?).abs() / drawn?))
        .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
    Claim::exact(
        format!(
            "{design} at M = 6: the promised bound is within 10 % of the drawn Φ's at every step, averaged over runs (largest difference {})",
            worst.map_or("-".into(), |w| format!("{:.1} %", 100.0 * w))
        ),
        worst.is_some_and(|w| w < 0.1),
    )
}

/// Fig. 4.1 and 4.2's claims for each design, and what each design's
/// promise is worth.
fn check_chapter_4(o: &Outcome) -> Check {
    let mut claims = Vec::new();
    for (design, arms) in DESIGNS {
        claims.extend(figure_4_1_claims(o, design, arms));
        claims.extend(design_claims(design, &o.arm(arms[2]).diagnostics.designs));
        claims.push(promise_claim(o, design, arms[2]));
    }
    let means = ARMS
        .iter()
        .map(|a| {
            let arm = o.arm(a.label);
            let run = whole_run_rmse(arm);
            let values: Vec<f64> = run.iter().flatten().copied().collect();
            let mean = (!values.is_empty())
                .then(|| (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt());
            format!(
                "{} {} ({:.2} transmissions/step)",
                a.label,
                mean.map_or("-".into(), |m| format!("{m:.3} m")),
                arm.transmissions_per_step,
            )
        })
        .collect::<Vec<_>>()
        .join(", ");
    // Why a design disappoints or not: the bound each drawn Φ gives
    // against the one the design promised, over the steps.
    let promises = ARMS[2..]
        .iter()
        .map(|a| {
            let arm = o.arm(a.label);
            let over_steps = |s: Series| {
                let v: Vec<f64> = arm.series(s).into_iter().flatten().collect();
                (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
            };
            let metres = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.3} m"));
            format!(
                "{} {} given the drawn Φ against {} promised",
                a.label,
                metres(over_steps(Series::Bound)),
                metres(over_steps(Series::AuxBound))
            )
        })
        .collect::<Vec<_>>()
        .join(", ");
    Check::of_claims(
        claims,
        format!("RMSE over the 15 steps: {means}; PCRLB over the steps: {promises}"),
    )
}

/// Fig. 4.2's reading at step 4 of the M = 6 arm: the probability sits on
/// at most two sensors in most runs, and on exactly two in most runs, as
/// the chapter's 0.6840 and 0.3160. Each a share of runs with its 95 %
/// interval, against one half.
fn design_claims(design: &str, designs: &[DesignRecord]) -> Vec<Claim> {
    let at_4: Vec<&DesignRecord> = designs.iter().filter(|d| d.step == 4).collect();
    let carrying = |d: &DesignRecord| d.probabilities.iter().filter(|p| **p >= NEGLIGIBLE).count();
    let share = |pick: &dyn Fn(usize) -> bool| -> Vec<Option<f64>> {
        at_4.iter()
            .map(|d| Some(if pick(carrying(d)) { 1.0 } else { 0.0 }))
            .collect()
    };
    // The share of runs, against one half run by run.
    let most = |claim: String, values: Vec<Option<f64>>| {
        let half = vec![Some(0.5); values.len()];
        Claim::judged(
            claim,
            Paired::of(&values, &half),
            |p| p.verdict(Order::Higher),
            |p| {
                format!(
                    "{:.0} % ± {:.0} % of {} runs",
                    100.0 * (p.mean + 0.5),
                    100.0 * p.half_width,
                    p.runs
                )
            },
        )
    };
    let mut claims = vec![
        most(
            format!("{design}: at step 4, at most two sensors carry the M = 6 design's probability in most runs"),
            share(&|n| n <= 2),
        ),
        most(
            format!("{design}: at step 4, exactly two sensors share it in most runs (the chapter's 0.684 and 0.316)"),
            share(&|n| n == 2),
        ),
    ];
    if at_4.is_empty() {
        claims
            .iter_mut()
            .for_each(|c| c.verdict = Verdict::DoesNotHold);
    }
    claims
}
