//! A paper's claim as the runs judge it: the paired interval behind it,
//! its verdict, and `claims.csv`.

use crate::paired::{Paired, Verdict};

/// Whether the paper's result holds, and the figures that say so: the
/// verdict of all its claims together, and each claim with its interval.
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    pub verdict: Verdict,
    pub statement: String,
    pub claims: Vec<Claim>,
}

/// One claim of a paper as the runs judge it, with the paired interval
/// behind it when it is estimated (none when it is exact).
#[derive(Debug, Clone, PartialEq)]
pub struct Claim {
    pub claim: String,
    pub paired: Option<Paired>,
    /// The interval in the claim's own unit ("+0.90 ± 0.72 % over 10
    /// runs"); empty for an exact claim.
    pub interval: String,
    pub verdict: Verdict,
}

impl Claim {
    /// A claim judged by a paired difference (`judge`), with its interval
    /// as `interval` words it; with no pairs at all it does not hold.
    pub fn judged(
        claim: impl Into<String>,
        paired: Option<Paired>,
        judge: impl Fn(&Paired) -> Verdict,
        interval: impl Fn(&Paired) -> String,
    ) -> Self {
        Self {
            claim: claim.into(),
            paired,
            interval: paired.as_ref().map_or("no paired runs".into(), interval),
            verdict: paired.as_ref().map_or(Verdict::DoesNotHold, judge),
        }
    }

    /// A claim checked exactly (a count, a budget).
    pub fn exact(claim: impl Into<String>, holds: bool) -> Self {
        Self {
            claim: claim.into(),
            paired: None,
            interval: String::new(),
            verdict: Verdict::of(holds),
        }
    }

    /// "claim: verdict (interval)", as the statement says it.
    pub fn said(&self) -> String {
        if self.interval.is_empty() {
            format!("{}: {}", self.claim, self.verdict.words())
        } else {
            format!(
                "{}: {} ({})",
                self.claim,
                self.verdict.words(),
                self.interval
            )
        }
    }

    /// The line of `claims.csv`.
    fn csv_row(&self) -> String {
        let (mean, half, runs, needed) = match self.paired {
            Some(p) => (
                format!("{}", p.mean),
                format!("{}", p.half_width),
                p.runs.to_string(),
                match self.verdict {
                    Verdict::NotResolved {
                        needed: Some(n), ..
                    } => n.to_string(),
                    _ => String::new(),
                },
            ),
            None => Default::default(),
        };
        let verdict = self.verdict.label();
        format!(
            "\"{}\",{mean},{half},{runs},{needed},{verdict}\n",
            self.claim.replace('"', "'")
        )
    }
}

impl Check {
    /// A check made of claims: their verdicts together, and a statement
    /// that says each claim, then `figures`.
    pub fn of_claims(claims: Vec<Claim>, figures: impl std::fmt::Display) -> Self {
        let said: Vec<String> = claims.iter().map(Claim::said).collect();
        Self {
            verdict: Verdict::all(claims.iter().map(|c| c.verdict)),
            statement: format!("{}; {figures}", said.join("; ")),
            claims,
        }
    }
}

/// `claims.csv`: every claim's paired difference, its 95 % half-width,
/// the runs, the runs that would resolve it, and its verdict; a check
/// with no claims of its own is one exact row.
pub fn claims_csv(check: &Check) -> String {
    let mut out =
        String::from("claim,mean_difference,half_width_95,runs,runs_to_resolve,verdict\n");
    if check.claims.is_empty() {
        let exact = Claim {
            verdict: check.verdict,
            ..Claim::exact("the experiment's check, exact", false)
        };
        out += &exact.csv_row();
    }
    for c in &check.claims {
        out += &c.csv_row();
    }
    out
}
