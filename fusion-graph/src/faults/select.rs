//! Which actors and links a fault takes: names, wildcards, and a fixed
//! share of what they match.

use serde::{Deserialize, Serialize};

use crate::ScenarioError;
use wire::ActorId;

use super::kind::Targets;
use crate::check::Check;

/// A directed link selector; `"*"` on either side matches every actor,
/// `"node-*"` every node and `"sensor-*"` every sensor.
/// `fraction` (default 1) takes that share of the links matched, chosen by
/// a hash of the fault and the link, so every process picks the same ones.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkSelector {
    pub from: String,
    pub to: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fraction: Option<f64>,
}

impl LinkSelector {
    pub fn new(from: impl Into<String>, to: impl Into<String>) -> Self {
        Self {
            from: from.into(),
            to: to.into(),
            fraction: None,
        }
    }
}

/// `"*"`, `"node-*"` or `"sensor-*"`.
pub fn is_wildcard(name: &str) -> bool {
    matches!(name, "*" | "node-*" | "sensor-*")
}

/// Whether the name or wildcard `sel` matches `actor`.
pub(super) fn matches(sel: &str, actor: ActorId) -> bool {
    match sel {
        "*" => true,
        "node-*" => matches!(actor, ActorId::Node(_)),
        "sensor-*" => matches!(actor, ActorId::Sensor(_)),
        _ => sel.parse::<ActorId>().is_ok_and(|a| a == actor),
    }
}

/// A number in [0, 1) fixed by its inputs: every process that evaluates
/// the schedule picks the same share of links or sensors (SplitMix64).
fn unit_hash(words: &[u64]) -> f64 {
    let mut h = 0x9E37_79B9_7F4A_7C15u64;
    for w in words {
        h ^= *w;
        h = h.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = h;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        h = z ^ (z >> 31);
    }
    (h >> 11) as f64 / (1u64 << 53) as f64
}

pub(super) fn actor_word(a: ActorId) -> u64 {
    let (kind, index) = a.to_wire();
    (kind as u64) << 16 | index as u64
}

/// Whether a fraction `fraction` of what a selector matches takes in this
/// one; `salt` tells the faults (and selectors) apart.
pub(super) fn in_share(fraction: Option<f64>, salt: &[u64]) -> bool {
    fraction.is_none_or(|f| f >= 1.0 || unit_hash(salt) < f)
}

/// Whether fault number `fault`'s selectors take the link `from → to`.
pub(super) fn takes_link(links: &[LinkSelector], fault: usize, from: ActorId, to: ActorId) -> bool {
    links.iter().enumerate().any(|(j, l)| {
        matches(&l.from, from)
            && matches(&l.to, to)
            && in_share(
                l.fraction,
                &[fault as u64, j as u64, actor_word(from), actor_word(to)],
            )
    })
}

/// At least one selector, each fraction a probability.
pub(super) fn check_links(links: &[LinkSelector], check: &Check) -> Result<(), ScenarioError> {
    check.non_empty("links", links.len())?;
    for (j, l) in links.iter().enumerate() {
        if let Some(p) = l.fraction {
            check.probability(&format!("links[{j}].fraction"), p)?;
        }
    }
    Ok(())
}

/// The actors named on either side of the selectors, wildcards left out.
pub(super) fn link_names(links: &[LinkSelector]) -> Vec<&str> {
    links
        .iter()
        .flat_map(|l| [l.from.as_str(), l.to.as_str()])
        .filter(|n| !is_wildcard(n))
        .collect()
}

/// How the summary writes the selectors.
pub(super) fn links_text(links: &[LinkSelector]) -> String {
    links
        .iter()
        .map(|l| match l.fraction {
            Some(f) => format!("{}->{} ({f} of them)", l.from, l.to),
            None => format!("{}->{}", l.from, l.to),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The actors a link fault names, under `links`.
pub(super) fn link_targets(links: &[LinkSelector]) -> Targets<'_> {
    Targets {
        key: "links",
        names: link_names(links),
        sensors_only: false,
    }
}

/// Combines independent probabilities of the same event, so two faults on
/// one link act as both would.
pub(super) fn either(a: f64, b: f64) -> f64 {
    1.0 - (1.0 - a) * (1.0 - b)
}
