//! How many consensus rounds a scenario's fusion graph needs: chosen for
//! `consensus.rounds = "auto"`, and advised on when the rounds given leave
//! more of the nodes' disagreement than `consensus.accuracy`.
//!
//! Both read the graph as the scenario lays it out, every node alive. A
//! fault that kills nodes or partitions the graph changes it: each part
//! then mixes by itself, towards its own average, at its own λ₂ (often
//! faster, being smaller; a node whose death leaves a long path, slower).
//! The figures are the intact network's.

use super::{ConsensusProtocol, Scenario};
use crate::{Mixing, ScenarioError, Topology};

/// `consensus.accuracy` when a scenario gives none: half the initial
/// disagreement left. Tracking asks less of consensus than agreement to
/// the last digit: on the 10 × 10 grid, 40 rounds of average consensus
/// (λ₂⁴⁰ = 0.44) already track within the bound (docs/experiments.md,
/// consensus at scale).
pub(super) fn default_accuracy() -> f64 {
    0.5
}

/// The most rounds `"auto"` may choose: a step of more would not finish
/// in any period a tracker runs at.
pub const MAX_AUTO_ROUNDS: u32 = 1000;

/// How `"auto"` chose the rounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoundsChoice {
    /// λ₂ of the fusion graph's Metropolis weights.
    pub slem: f64,
    pub rounds: u32,
    /// The share of the disagreement they leave at most.
    pub left: f64,
}

/// The scenario's rounds leave more disagreement than its accuracy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoundsAdvice {
    pub slem: f64,
    pub rounds: u32,
    /// The share of the disagreement its rounds leave.
    pub left: f64,
    pub accuracy: f64,
    /// The rounds that would leave at most `accuracy`, if any would.
    pub needed: Option<u32>,
}

impl std::fmt::Display for RoundsAdvice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "consensus.rounds = {} leaves {:.0} % of the nodes' disagreement on this fusion graph \
             (λ₂ = {:.4}), more than consensus.accuracy = {}",
            self.rounds,
            100.0 * self.left,
            self.slem,
            self.accuracy
        )?;
        match self.needed {
            Some(n) => write!(
                f,
                "; {n} rounds would leave at most that (consensus.rounds = \"auto\" chooses them)"
            ),
            None => write!(f, "; no number of rounds would: the graph is not connected"),
        }
    }
}

/// Takes `consensus.rounds = "auto"` out of a scenario's table, leaving a
/// placeholder for the rounds chosen once the graph is known; whether it
/// was there.
pub(super) fn take_auto_rounds(value: &mut toml::Table) -> bool {
    let Some(rounds) = value
        .get_mut("consensus")
        .and_then(|c| c.as_table_mut())
        .and_then(|c| c.get_mut("rounds"))
    else {
        return false;
    };
    if rounds.as_str() != Some("auto") {
        return false;
    }
    *rounds = toml::Value::Integer(1);
    true
}

impl ConsensusProtocol {
    /// The share of the disagreement `rounds` rounds of the protocol leave
    /// at most on a graph that mixes so, for the protocols whose rate is
    /// known: λ₂ a round for average consensus and KL fusion's rounds;
    /// short memory as [`Mixing::left_after_short_memory`] says.
    pub fn left_after(self, mixing: Mixing, rounds: u32) -> Option<f64> {
        self.shares_left(mixing)
            .map(|mut left| left.nth(rounds as usize).unwrap_or(0.0))
    }

    /// The shares left after 0, 1, 2, … rounds.
    fn shares_left(self, mixing: Mixing) -> Option<Box<dyn Iterator<Item = f64>>> {
        if self == Self::SHORT_MEMORY {
            return Some(Box::new(mixing.short_memory_left()));
        }
        let plain =
            self == Self::AVERAGE || self == Self::KL_CONSENSUS || self == Self::KL_ITERATIVE;
        let slem = mixing.slem;
        plain.then(|| {
            Box::new(std::iter::successors(Some(1.0), move |l| Some(l * slem)))
                as Box<dyn Iterator<Item = f64>>
        })
    }

    /// The fewest rounds, up to `most`, that leave at most `share`; `None`
    /// if the protocol's rate is not known or no such number of rounds
    /// does.
    pub fn rounds_for(self, mixing: Mixing, share: f64, most: u32) -> Option<u32> {
        if mixing.slem >= 1.0 {
            return None;
        }
        let found = self
            .shares_left(mixing)?
            .take(most as usize + 1)
            .position(|left| left <= share)?;
        Some((found as u32).max(1))
    }
}

impl Scenario {
    /// `consensus.rounds = "auto"`: the fewest rounds of the scenario's
    /// protocol that leave at most `consensus.accuracy` of the
    /// disagreement on its fusion graph, every node alive.
    pub fn choose_rounds(&mut self, file: &str) -> Result<(), ScenarioError> {
        let bad = |expected: &str, got: String| ScenarioError::Invalid {
            file: file.into(),
            key: "consensus.rounds".into(),
            expected: expected.into(),
            got,
        };
        let protocol = self.consensus.protocol;
        let topology = Topology::from_scenario(self, file)?;
        let mixing = topology.mixing(&topology.all_alive());
        if protocol.left_after(mixing, 1).is_none() {
            return Err(bad(
                "a number of rounds: \"auto\" knows how far average, short_memory, \
                 kl_consensus and kl_iterative get",
                format!("\"auto\" with consensus.protocol = \"{}\"", protocol.name()),
            ));
        }
        let accuracy = self.consensus.accuracy;
        let rounds = protocol
            .rounds_for(mixing, accuracy, MAX_AUTO_ROUNDS)
            .ok_or_else(|| {
                bad(
                    &format!(
                        "a fusion graph that mixes within {MAX_AUTO_ROUNDS} rounds to \
                         consensus.accuracy"
                    ),
                    format!("\"auto\" with λ₂ = {:.6}", mixing.slem),
                )
            })?;
        self.consensus.rounds = rounds;
        self.consensus.chosen = Some(RoundsChoice {
            slem: mixing.slem,
            rounds,
            left: protocol.left_after(mixing, rounds).unwrap_or(0.0),
        });
        Ok(())
    }

    /// Advice, when the scenario's rounds of a protocol whose rate is known
    /// leave more than `consensus.accuracy` of the disagreement on
    /// `topology`, every node alive.
    pub fn rounds_advice(&self, topology: &Topology) -> Option<RoundsAdvice> {
        let mixing = topology.mixing(&topology.all_alive());
        let protocol = self.consensus.protocol;
        let rounds = self.consensus.rounds;
        let left = protocol.left_after(mixing, rounds)?;
        let accuracy = self.consensus.accuracy;
        (left > accuracy).then(|| RoundsAdvice {
            slem: mixing.slem,
            rounds,
            left,
            accuracy,
            needed: protocol.rounds_for(mixing, accuracy, 100_000),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::DEFAULT_SCENARIO;

    fn scenario(sets: &[&str]) -> Result<Scenario, ScenarioError> {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        Scenario::from_toml(DEFAULT_SCENARIO, "d", &sets)
    }

    const TEN: [&str; 3] = [
        "nodes.grid=[10,10]",
        "region.width=5000",
        "region.height=5000",
    ];

    #[test]
    fn auto_chooses_the_fewest_rounds_that_reach_the_accuracy() {
        let s = scenario(
            &[
                &TEN[..],
                &["consensus.rounds=\"auto\"", "consensus.accuracy=0.01"],
            ]
            .concat(),
        )
        .unwrap();
        let chosen = s.consensus.chosen.unwrap();
        assert_eq!(s.consensus.rounds, chosen.rounds);
        assert!(chosen.slem.powi(chosen.rounds as i32) <= 0.01);
        assert!(chosen.slem.powi(chosen.rounds as i32 - 1) > 0.01);
        assert!(chosen.left <= 0.01);
        // ln 0.01 / ln 0.9795 ≈ 222 rounds.
        assert!((220..=226).contains(&chosen.rounds), "{}", chosen.rounds);
        // The children read the number.
        let again = Scenario::from_toml(&s.to_toml(), "child", &[]).unwrap();
        assert_eq!(again.consensus.rounds, chosen.rounds);
        assert!(again.consensus.chosen.is_none());
        // Short memory needs far fewer.
        let short = scenario(
            &[
                &TEN[..],
                &[
                    "consensus.rounds=\"auto\"",
                    "consensus.accuracy=0.01",
                    "consensus.protocol=\"short_memory\"",
                ],
            ]
            .concat(),
        )
        .unwrap();
        // √α = 0.815 a round in the long run (23 rounds to 1 %); the
        // slowest modes' transient costs some more.
        assert!(
            (23..40).contains(&short.consensus.rounds),
            "{}",
            short.consensus.rounds
        );
    }

    #[test]
    fn too_few_rounds_are_advised_on_and_enough_are_not() {
        let ten = scenario(&TEN).unwrap();
        let t = Topology::from_scenario(&ten, "d").unwrap();
        let advice = ten
            .rounds_advice(&t)
            .expect("10 rounds on 10 × 10 are too few");
        assert_eq!(advice.rounds, 10);
        assert!((advice.left - 0.9795f64.powi(10)).abs() < 0.01);
        let needed = advice.needed.unwrap();
        assert!(0.9795f64.powi(needed as i32) <= 0.5 + 1e-3 && needed > 10);
        let text = advice.to_string();
        assert!(
            text.contains("λ₂ = 0.979") && text.contains(&needed.to_string()),
            "{text}"
        );
        let three = scenario(&[]).unwrap();
        let t3 = Topology::from_scenario(&three, "d").unwrap();
        assert_eq!(
            three.rounds_advice(&t3),
            None,
            "10 rounds on 3 × 3 leave 7 %"
        );
    }

    #[test]
    fn auto_is_refused_where_it_cannot_choose() {
        let exact =
            scenario(&["consensus.rounds=\"auto\"", "consensus.protocol=\"exact\""]).unwrap_err();
        assert!(exact.to_string().contains("consensus.rounds"), "{exact}");
        for bad in [
            "consensus.accuracy=0",
            "consensus.accuracy=1",
            "consensus.rounds=\"many\"",
        ] {
            assert!(scenario(&[bad]).is_err(), "{bad}");
        }
    }
}
