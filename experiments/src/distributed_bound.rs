//! The CQ/dPCRLB paper's figures (CQ/dPCRLB), on the default scenario.

use fusion_graph::scenario::DEFAULT_SCENARIO;

use super::{
    Arm, Bar, Check, Claim, Curve, Experiment, Figure, Metric, Order, Outcome, Paired, Series,
    Verdict,
};

/// The default quantizer, and no quantizer: the arms most figures compare.
const EIGHT_BITS: Arm = Arm {
    label: "8 bits",
    overrides: &["quantizer.bits=8"],
};
const RAW: Arm = Arm {
    label: "raw",
    overrides: &["quantizer.raw=true"],
};

pub fn experiments() -> Vec<Experiment> {
    vec![
        Experiment {
            name: "bound-aux-fim",
            source: "Mohammadi, Asif et al. (CQ/dPCRLB), Fig. 1(b)",
            about: "raw dPCRLB against the 8-bit CQ/dPCRLB, each with L_G and with the auxiliary FIM",
            scenario: DEFAULT_SCENARIO,
            base: &["consensus.auxiliary_fim=true", "reference.centralized=false"],
            arms: &[
                EIGHT_BITS,
                RAW,
            ],
            figure: Figure::OverTime {
                y_label: "position bound, m",
                curves: &[
                    Curve {
                        arm: 0,
                        series: Series::Bound,
                        label: "CQ/dPCRLB, 8 bits (L_G)",
                    },
                    Curve {
                        arm: 0,
                        series: Series::AuxBound,
                        label: "CQ/dPCRLB, 8 bits (auxiliary FIM)",
                    },
                    Curve {
                        arm: 1,
                        series: Series::Bound,
                        label: "dPCRLB, raw (L_G)",
                    },
                    Curve {
                        arm: 1,
                        series: Series::AuxBound,
                        label: "dPCRLB, raw (auxiliary FIM)",
                    },
                ],
            },
            check: check_fig1b,
        },
        Experiment {
            name: "bound-against-bits",
            source: "Mohammadi, Asif et al. (CQ/dPCRLB), Fig. 1(c)",
            about: "the CQ/dPCRLB for 4 to 8 bits and raw: it approaches raw as bits grow",
            scenario: DEFAULT_SCENARIO,
            base: &["reference.centralized=false"],
            arms: &[
                Arm {
                    label: "4 bits",
                    overrides: &["quantizer.bits=4"],
                },
                Arm {
                    label: "5 bits",
                    overrides: &["quantizer.bits=5"],
                },
                Arm {
                    label: "6 bits",
                    overrides: &["quantizer.bits=6"],
                },
                Arm {
                    label: "7 bits",
                    overrides: &["quantizer.bits=7"],
                },
                EIGHT_BITS,
                RAW,
            ],
            figure: Figure::OverTime {
                y_label: "CQ/dPCRLB position bound, m",
                curves: &[
                    Curve {
                        arm: 0,
                        series: Series::Bound,
                        label: "4 bits",
                    },
                    Curve {
                        arm: 1,
                        series: Series::Bound,
                        label: "5 bits",
                    },
                    Curve {
                        arm: 2,
                        series: Series::Bound,
                        label: "6 bits",
                    },
                    Curve {
                        arm: 3,
                        series: Series::Bound,
                        label: "7 bits",
                    },
                    Curve {
                        arm: 4,
                        series: Series::Bound,
                        label: "8 bits",
                    },
                    Curve {
                        arm: 5,
                        series: Series::Bound,
                        label: "raw",
                    },
                ],
            },
            check: check_fig1c,
        },
        Experiment {
            name: "distributed-against-centralized",
            source: "Mohammadi, Asif et al. (CQ/dPCRLB), Result 2",
            about: "the distributed against the centralized conditional bound, with the non-conditional (Tichavsky) PCRLB and the RMSEs",
            scenario: DEFAULT_SCENARIO,
            base: &["reference.centralized=true"],
            arms: &[EIGHT_BITS],
            figure: Figure::OverTime {
                y_label: "position bound and RMSE, m",
                curves: &[
                    Curve {
                        arm: 0,
                        series: Series::Bound,
                        label: "CQ/dPCRLB (distributed)",
                    },
                    Curve {
                        arm: 0,
                        series: Series::CentralizedBound,
                        label: "centralized conditional PCRLB",
                    },
                    Curve {
                        arm: 0,
                        series: Series::Nonconditional,
                        label: "non-conditional PCRLB (Tichavsky)",
                    },
                    Curve {
                        arm: 0,
                        series: Series::Rmse,
                        label: "RMSE, nodes' fused estimates",
                    },
                    Curve {
                        arm: 0,
                        series: Series::CentralizedRmse,
                        label: "RMSE, centralized filter",
                    },
                ],
            },
            check: check_central,
        },
        Experiment {
            name: "bound-traffic",
            source: "Mohammadi, Asif et al. (CQ/dPCRLB), Result 2, against Mohammadi and Asif (selection), Theorem 1",
            about: "bytes of bound information per step: CQ/dPCRLB (ΔL) against the auxiliary-FIM baseline (ΔL and S_obs), from the accounting",
            scenario: DEFAULT_SCENARIO,
            base: &["consensus.auxiliary_fim=true", "reference.centralized=false"],
            arms: &[EIGHT_BITS],
            figure: Figure::Bars {
                y_label: "bound bytes per step, whole network",
                bars: &[
                    Bar {
                        arm: 0,
                        metric: Metric::BoundBytesPerStep,
                        label: "CQ/dPCRLB",
                    },
                    Bar {
                        arm: 0,
                        metric: Metric::AuxBoundBytesPerStep,
                        label: "auxiliary FIM",
                    },
                ],
            },
            check: check_traffic,
        },
    ]
}

fn relative(a: f64, b: f64) -> f64 {
    a / b - 1.0
}

/// Run by run, `a / b − 1`: the runs share their seeds across arms.
fn relative_per_run(a: &[Option<f64>], b: &[Option<f64>]) -> Vec<Option<f64>> {
    a.iter()
        .zip(b)
        .map(|(a, b)| Some(relative((*a)?, (*b)?)))
        .collect()
}

/// A claim on per-run relative gaps, judged by `judge`; "+1.2 ± 0.4 %".
fn gap_claim(what: &str, gaps: &[Option<f64>], judge: impl Fn(&Paired) -> Verdict) -> Claim {
    Claim::judged(what, Paired::of_values(gaps), judge, |p| {
        format!(
            "{:+.2} ± {:.2} % over {} runs",
            100.0 * p.mean,
            100.0 * p.half_width,
            p.runs
        )
    })
}

/// "Within each set of plots the bounds virtually overlap"; the quantized
/// pair lies slightly above the raw one. Each run's mean bounds from step
/// 10, compared run by run: the relative gap's interval within ±5 %
/// (overlap), and the 8-bit bound's excess over raw within 0–10 %
/// (slightly above).
fn check_fig1b(o: &Outcome) -> Check {
    let (q, r) = (o.arm(EIGHT_BITS.label), o.arm(RAW.label));
    let figures = (
        q.mean(Series::Bound),
        q.mean(Series::AuxBound),
        r.mean(Series::Bound),
        r.mean(Series::AuxBound),
    );
    let (Some(q_lg), Some(q_aux), Some(r_lg), Some(r_aux)) = figures else {
        return missing("a bound of fig. 1(b)");
    };
    let within = |lo, hi| move |p: &Paired| p.verdict_within(lo, hi);
    Check::of_claims(
        vec![
            gap_claim(
                "L_G and the auxiliary FIM overlap at 8 bits (within 5 %)",
                &relative_per_run(&q.per_run_aux_bound, &q.per_run_bound),
                within(-0.05, 0.05),
            ),
            gap_claim(
                "they overlap raw (within 5 %)",
                &relative_per_run(&r.per_run_aux_bound, &r.per_run_bound),
                within(-0.05, 0.05),
            ),
            gap_claim(
                "the 8-bit bound lies slightly above raw (0 to 10 %)",
                &relative_per_run(&q.per_run_bound, &r.per_run_bound),
                within(0.0, 0.10),
            ),
        ],
        format!(
            "means from step 10: 8 bits {q_lg:.3} / {q_aux:.3} m, raw {r_lg:.3} / {r_aux:.3} m"
        ),
    )
}

/// "The CQ/dPCRLB approaches the dPCRLB as the number of quantization
/// levels are increased": run by run, the bound's excess over raw shrinks
/// with every bit added, and at 8 bits is not below raw by more than 1 %.
fn check_fig1c(o: &Outcome) -> Check {
    let labels = ["4 bits", "5 bits", "6 bits", "7 bits", "8 bits", "raw"];
    let Some(means) = labels
        .iter()
        .map(|l| o.arm(l).mean(Series::Bound))
        .collect::<Option<Vec<f64>>>()
    else {
        return missing("a bound of fig. 1(c)");
    };
    let raw = &o.arm("raw").per_run_bound;
    let gaps: Vec<Vec<Option<f64>>> = labels[..5]
        .iter()
        .map(|l| relative_per_run(&o.arm(l).per_run_bound, raw))
        .collect();
    let mut claims: Vec<Claim> = (0..4)
        .map(|i| {
            let shrink: Vec<Option<f64>> = gaps[i + 1]
                .iter()
                .zip(&gaps[i])
                .map(|(a, b)| Some((*a)? - (*b)?))
                .collect();
            gap_claim(
                &format!(
                    "the excess over raw shrinks from {} to {}",
                    labels[i],
                    labels[i + 1]
                ),
                &shrink,
                |p: &Paired| p.verdict(Order::Lower),
            )
        })
        .collect();
    claims.push(gap_claim(
        "at 8 bits the bound is not below raw by more than 1 %",
        &gaps[4],
        |p: &Paired| p.verdict_within(-0.01, f64::INFINITY),
    ));
    let excess = labels[..5]
        .iter()
        .zip(&means)
        .map(|(l, b)| format!("{l} {:+.1} %", 100.0 * relative(*b, means[5])))
        .collect::<Vec<_>>()
        .join(", ");
    Check::of_claims(
        claims,
        format!("means' excess over raw ({:.3} m): {excess}", means[5]),
    )
}

/// The distributed bound comes close to the centralized one (the CQ/dPCRLB
/// paper's claim for Result 2): run by run, within 5 %.
fn check_central(o: &Outcome) -> Check {
    let a = o.arm(EIGHT_BITS.label);
    let (Some(dist), Some(central), Some(noncond), Some(rmse), Some(c_rmse)) = (
        a.mean(Series::Bound),
        a.mean(Series::CentralizedBound),
        a.mean(Series::Nonconditional),
        a.mean(Series::Rmse),
        a.mean(Series::CentralizedRmse),
    ) else {
        return missing("a series of the centralized comparison");
    };
    Check::of_claims(
        vec![gap_claim(
            "the CQ/dPCRLB is within 5 % of the centralized conditional bound",
            &relative_per_run(&a.per_run_bound, &a.per_run_centralized_bound),
            |p: &Paired| p.verdict_within(-0.05, 0.05),
        )],
        format!(
            "means from step 10: CQ/dPCRLB {dist:.3} m, centralized {central:.3} m, \
             non-conditional {noncond:.3} m, RMSE {rmse:.3} m (nodes) and {c_rmse:.3} m (centralized)"
        ),
    )
}

/// The CQ/dPCRLB paper's point against the auxiliary FIM: the same bound for half the
/// bound traffic (ΔL alone against ΔL and S_obs).
fn check_traffic(o: &Outcome) -> Check {
    let a = o.arm(EIGHT_BITS.label);
    let Some(aux) = a.aux_bound_bytes_per_step else {
        return missing("the auxiliary FIM's traffic");
    };
    let cq = a.bound_bytes_per_step;
    let halves = cq > 0.0 && aux == 2.0 * cq;
    Check {
        verdict: Verdict::of(halves),
        claims: vec![Claim::exact(
            "the CQ/dPCRLB's bound traffic is half the auxiliary-FIM baseline's (a count of bytes)",
            halves,
        )],
        statement: format!(
            "CQ/dPCRLB sends {cq:.0} B of bound information per step, the auxiliary-FIM baseline {aux:.0} B ({:.2}×)",
            aux / cq
        ),
    }
}

fn missing(what: &str) -> Check {
    Check {
        verdict: Verdict::of(false),
        claims: Vec::new(),
        statement: format!("{what} is missing from the outcome"),
    }
}
