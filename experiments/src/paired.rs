//! Paired comparisons of two arms over the same runs: the arms of an
//! experiment share their seeds, so run k of each tracks the same target
//! through the same noise, and the difference of their per-run figures
//! has far less spread than either figure.

/// The mean of per-run differences `a − b`, with its 95 % interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Paired {
    pub runs: usize,
    pub mean: f64,
    /// The differences' sample standard deviation.
    pub sd: f64,
    /// Half the width of the 95 % interval (Student's t on runs − 1
    /// degrees of freedom).
    pub half_width: f64,
}

/// What the runs say of a claim: it holds, it does not, or the interval
/// still holds zero at this many runs. A verdict is never read off a
/// difference of means the noise could reverse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    Holds,
    DoesNotHold,
    /// At `runs` runs the interval holds zero; about `needed` runs would
    /// resolve it if the mean difference and its spread stay as measured
    /// (`None`: the mean difference is zero).
    NotResolved {
        runs: usize,
        needed: Option<usize>,
    },
}

impl Verdict {
    /// A claim checked exactly (arithmetic, or a count), not estimated.
    pub fn of(holds: bool) -> Self {
        if holds {
            Verdict::Holds
        } else {
            Verdict::DoesNotHold
        }
    }

    /// Several claims that must all hold: one that does not decides; else
    /// one not resolved leaves the whole not resolved (at the most runs
    /// any of them needs).
    pub fn all(verdicts: impl IntoIterator<Item = Verdict>) -> Self {
        let mut out = Verdict::Holds;
        for v in verdicts {
            out = match (out, v) {
                (Verdict::DoesNotHold, _) | (_, Verdict::DoesNotHold) => Verdict::DoesNotHold,
                (
                    Verdict::NotResolved { runs, needed: a },
                    Verdict::NotResolved { runs: r, needed: b },
                ) => Verdict::NotResolved {
                    runs: runs.min(r),
                    needed: a.zip(b).map(|(a, b)| a.max(b)),
                },
                (n @ Verdict::NotResolved { .. }, Verdict::Holds)
                | (Verdict::Holds, n @ Verdict::NotResolved { .. }) => n,
                (Verdict::Holds, Verdict::Holds) => Verdict::Holds,
            };
        }
        out
    }

    /// "holds", "does not hold" or "not resolved": the verdict as a table
    /// or a program reads it (`claims.csv`, the Python package).
    pub fn label(&self) -> &'static str {
        match self {
            Verdict::Holds => "holds",
            Verdict::DoesNotHold => "does not hold",
            Verdict::NotResolved { .. } => "not resolved",
        }
    }

    pub fn holds(&self) -> bool {
        *self == Verdict::Holds
    }

    /// "holds", "does NOT hold", or "not resolved at 20 runs (about 310
    /// would resolve it)".
    pub fn words(&self) -> String {
        match self {
            Verdict::Holds => "holds".into(),
            Verdict::DoesNotHold => "does NOT hold".into(),
            Verdict::NotResolved { runs, needed } => format!(
                "not resolved at {runs} runs{}",
                needed.map_or(String::new(), |n| format!(" (about {n} would resolve it)"))
            ),
        }
    }
}

/// Where a paired difference puts `a` against `b`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Order {
    /// The whole interval is below zero: `a` is lower.
    Lower,
    /// The whole interval is above zero: `a` is higher.
    Higher,
    /// The interval holds zero: not resolved at this many runs.
    Unresolved,
}

impl Paired {
    /// The paired difference of the runs both arms have a figure for;
    /// `None` with fewer than two such runs.
    pub fn of(a: &[Option<f64>], b: &[Option<f64>]) -> Option<Self> {
        let d: Vec<f64> = a
            .iter()
            .zip(b)
            .filter_map(|(a, b)| Some((*a)? - (*b)?))
            .collect();
        let n = d.len();
        if n < 2 {
            return None;
        }
        let mean = d.iter().sum::<f64>() / n as f64;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        Some(Self {
            runs: n,
            mean,
            sd: var.sqrt(),
            half_width: t95(n - 1) * (var / n as f64).sqrt(),
        })
    }

    /// The verdict on the claim that `a` is `expected` of `b` (lower or
    /// higher): the interval on the expected side holds, on the other side
    /// does not, across zero not resolved.
    pub fn verdict(&self, expected: Order) -> Verdict {
        match self.order() {
            Order::Unresolved => Verdict::NotResolved {
                runs: self.runs,
                needed: self.runs_to_resolve(),
            },
            found => Verdict::of(found == expected),
        }
    }

    /// The fewest runs whose 95 % interval, with this mean difference and
    /// spread, would leave out zero: the smallest n with
    /// t₀.₉₇₅(n − 1)·sd/√n < |mean|. `None` when the mean is zero (or
    /// past ten million runs).
    pub fn runs_to_resolve(&self) -> Option<usize> {
        self.runs_for_margin(self.mean.abs())
    }

    /// The fewest runs whose interval's half-width is below `margin`.
    fn runs_for_margin(&self, margin: f64) -> Option<usize> {
        if margin <= 0.0 || !margin.is_finite() {
            return None;
        }
        // The normal's n, then up to where Student's t agrees.
        let guess = ((1.959_964 * self.sd / margin).powi(2)).ceil().max(2.0);
        if guess > 1e7 {
            return None;
        }
        (2.max(guess as usize / 2)..=10_000_000)
            .find(|&n| t95(n - 1) * self.sd / (n as f64).sqrt() < margin)
    }

    /// The verdict on the claim that the mean lies between `lo` and `hi`
    /// ("within 5 %"): it holds when the whole interval does, does not
    /// when none of it does, and is not resolved otherwise, with the runs
    /// that would put the interval on one side.
    pub fn verdict_within(&self, lo: f64, hi: f64) -> Verdict {
        let (a, b) = (self.mean - self.half_width, self.mean + self.half_width);
        if a > lo && b < hi {
            return Verdict::Holds;
        }
        if b <= lo || a >= hi {
            return Verdict::DoesNotHold;
        }
        let m = self.mean;
        let margin = if m > lo && m < hi {
            (m - lo).min(hi - m)
        } else {
            (lo - m).max(m - hi)
        };
        Verdict::NotResolved {
            runs: self.runs,
            needed: self.runs_for_margin(margin),
        }
    }

    /// One arm's per-run figures against zero (or a difference already
    /// taken run by run).
    pub fn of_values(values: &[Option<f64>]) -> Option<Self> {
        Self::of(values, &vec![Some(0.0); values.len()])
    }

    pub fn order(&self) -> Order {
        if self.mean + self.half_width < 0.0 {
            Order::Lower
        } else if self.mean - self.half_width > 0.0 {
            Order::Higher
        } else {
            Order::Unresolved
        }
    }

    /// `−0.058 ± 0.041`.
    pub fn text(&self, digits: usize) -> String {
        format!("{:+.digits$} ± {:.digits$}", self.mean, self.half_width)
    }
}

/// The 95 % interval of an RMSE over runs, from each run's mean squared
/// error: the interval of the mean of the squares (Student's t), its ends
/// as root mean squares (the lower end at least zero). `None` with fewer
/// than two runs.
pub fn rmse_interval(run_rmses: &[f64]) -> Option<(f64, f64)> {
    let n = run_rmses.len();
    if n < 2 {
        return None;
    }
    let squares: Vec<f64> = run_rmses.iter().map(|r| r * r).collect();
    let mean = squares.iter().sum::<f64>() / n as f64;
    let var = squares.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let half = t95(n - 1) * (var / n as f64).sqrt();
    Some(((mean - half).max(0.0).sqrt(), (mean + half).sqrt()))
}

/// The two-sided 95 % quantile of Student's t with `dof` degrees of
/// freedom: tabulated to 30, then the normal's with the first correction
/// term of its expansion (within 0.1 % from 30 on).
fn t95(dof: usize) -> f64 {
    const TABLE: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    match dof {
        0 => f64::INFINITY,
        1..=30 => TABLE[dof - 1],
        _ => {
            let z: f64 = 1.959_964;
            z + (z.powi(3) + z) / (4.0 * dof as f64)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_t_quantile_meets_the_normal_one() {
        assert_eq!(t95(1), 12.706);
        // Tabulated values at 40 and 120 degrees of freedom.
        assert!((t95(40) - 2.021).abs() < 0.002, "{}", t95(40));
        assert!((t95(120) - 1.980).abs() < 0.001, "{}", t95(120));
    }

    /// Differences 1, 2, 3, 4, 5: mean 3, sd √2.5, and the interval
    /// 3 ± 2.776·√2.5/√5 = 3 ± 1.963 (t with 4 degrees of freedom).
    #[test]
    fn the_interval_of_a_known_case() {
        let a: Vec<Option<f64>> = [11.0, 12.0, 13.0, 14.0, 15.0].map(Some).to_vec();
        let b = vec![Some(10.0); 5];
        let p = Paired::of(&a, &b).unwrap();
        assert_eq!(p.runs, 5);
        assert!((p.mean - 3.0).abs() < 1e-12);
        assert!((p.sd - 2.5f64.sqrt()).abs() < 1e-12);
        assert!((p.half_width - 1.963).abs() < 5e-4, "{}", p.half_width);
        assert_eq!(p.verdict(Order::Higher), Verdict::Holds);
        assert_eq!(p.verdict(Order::Lower), Verdict::DoesNotHold);
    }

    /// A mean difference of 0.1 with sd 1 needs about (1.96/0.1)² = 385
    /// runs; with Student's t, the first n whose interval leaves zero out.
    #[test]
    fn the_runs_that_would_resolve_a_difference() {
        let p = Paired {
            runs: 20,
            mean: 0.1,
            sd: 1.0,
            half_width: t95(19) / 20f64.sqrt(),
        };
        let n = p.runs_to_resolve().unwrap();
        assert!(t95(n - 1) / (n as f64).sqrt() < 0.1);
        assert!(t95(n - 2) / ((n - 1) as f64).sqrt() >= 0.1);
        assert!((385..=390).contains(&n), "{n}");
        assert_eq!(
            p.verdict(Order::Lower),
            Verdict::NotResolved {
                runs: 20,
                needed: Some(n)
            }
        );
        assert_eq!(Paired { mean: 0.0, ..p }.runs_to_resolve(), None);
        assert_eq!(
            Verdict::NotResolved {
                runs: 20,
                needed: Some(n)
            }
            .words(),
            format!("not resolved at 20 runs (about {n} would resolve it)")
        );
    }

    /// "Within 5 %": an interval inside holds, one outside does not, one
    /// across an edge is not resolved.
    #[test]
    fn a_claim_of_closeness_takes_the_whole_interval() {
        let p = |mean, half_width| Paired {
            runs: 10,
            mean,
            sd: half_width * 10f64.sqrt() / t95(9),
            half_width,
        };
        assert_eq!(p(0.01, 0.02).verdict_within(-0.05, 0.05), Verdict::Holds);
        assert_eq!(
            p(0.09, 0.02).verdict_within(-0.05, 0.05),
            Verdict::DoesNotHold
        );
        let open = p(0.04, 0.02).verdict_within(-0.05, 0.05);
        let Verdict::NotResolved {
            needed: Some(n), ..
        } = open
        else {
            panic!("{open:?}")
        };
        // Half-width 0.02 at 10 runs must shrink below the margin 0.01.
        assert!(n > 10 && t95(n - 1) * p(0.04, 0.02).sd / (n as f64).sqrt() < 0.01);
        assert_eq!(
            Paired::of_values(&[Some(1.0), Some(3.0)]).unwrap().mean,
            2.0
        );
    }

    /// Runs with RMSE 1 and 3: squares 1 and 9, mean 5, sd √32, standard
    /// error 4, so 5 ± 12.706·4 and the band is from 0 (clamped) to
    /// √(5 + 50.82).
    #[test]
    fn an_rmse_band_is_the_interval_of_the_mean_square() {
        let (lo, hi) = rmse_interval(&[1.0, 3.0]).unwrap();
        assert_eq!(lo, 0.0);
        assert!((hi - (5.0 + 12.706 * 4.0f64).sqrt()).abs() < 1e-9, "{hi}");
        let (lo, hi) = rmse_interval(&[2.0; 5]).unwrap();
        assert_eq!((lo, hi), (2.0, 2.0));
        assert!(rmse_interval(&[1.0]).is_none());
    }

    #[test]
    fn claims_together_take_the_weakest_verdict() {
        let open = |needed| Verdict::NotResolved {
            runs: 10,
            needed: Some(needed),
        };
        assert_eq!(
            Verdict::all([Verdict::Holds, Verdict::Holds]),
            Verdict::Holds
        );
        assert_eq!(Verdict::all([Verdict::Holds, open(40), open(90)]), open(90));
        assert_eq!(
            Verdict::all([open(40), Verdict::DoesNotHold]),
            Verdict::DoesNotHold
        );
    }

    #[test]
    fn a_shared_noise_cancels_in_the_pairs() {
        // Each run's figure is a large common part plus a small offset of
        // the arm: unpaired, the spread would hide the offset.
        let common = [3.0, 9.0, 1.0, 7.0, 5.0, 2.0, 8.0, 4.0];
        let a: Vec<Option<f64>> = common
            .iter()
            .enumerate()
            .map(|(i, c)| Some(c - 0.1 + 0.01 * (i % 2) as f64))
            .collect();
        let b: Vec<Option<f64>> = common.iter().map(|c| Some(*c)).collect();
        let p = Paired::of(&a, &b).unwrap();
        assert_eq!(p.runs, 8);
        assert!((p.mean + 0.095).abs() < 1e-12);
        assert_eq!(p.order(), Order::Lower);
        assert_eq!(Paired::of(&b, &a).unwrap().order(), Order::Higher);
        let noisy: Vec<Option<f64>> = common.iter().map(|c| Some(10.0 - c)).collect();
        assert_eq!(Paired::of(&noisy, &b).unwrap().order(), Order::Unresolved);
        // A run missing from either arm is left out of the pairs.
        let mut gap = a.clone();
        gap[0] = None;
        assert_eq!(Paired::of(&gap, &b).unwrap().runs, 7);
        assert!(Paired::of(&[Some(1.0)], &[Some(2.0)]).is_none());
    }
}
