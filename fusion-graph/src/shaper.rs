//! Link faults, applied on the receiving side of each directed link: netem
//! cannot touch shared memory, so delay, loss and partitions live here.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::actor::ActorId;

/// The faults currently applied to one incoming link.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LinkRule {
    pub latency: Duration,
    /// Uniform in `[−jitter, +jitter]`, added to the latency (never below 0).
    pub jitter: Duration,
    /// Probability that a message is dropped.
    pub loss: f64,
    /// Partitioned: every message is dropped.
    pub blocked: bool,
}

impl LinkRule {
    pub fn is_clear(&self) -> bool {
        *self == LinkRule::default()
    }
}

/// What happens to an arriving message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admission {
    Deliver,
    /// Held until its delay has passed; it comes out of [`LinkShaper::release_due`].
    Held,
    Dropped,
}

/// A delayed message: release time, arrival order (ties), sender, bytes.
type Held = Reverse<(Duration, u64, ActorId, Vec<u8>)>;

/// Per-receiver shaper: rules per sender, seeded randomness, and the queue of
/// delayed messages ordered by release time.
#[derive(Debug)]
pub struct LinkShaper {
    rules: HashMap<ActorId, LinkRule>,
    rng: ChaCha8Rng,
    held: BinaryHeap<Held>,
    sequence: u64,
}

impl LinkShaper {
    pub fn new(seed: u64) -> Self {
        Self {
            rules: HashMap::new(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            held: BinaryHeap::new(),
            sequence: 0,
        }
    }

    /// Replaces the rule on the link from `from`; a clear rule removes it.
    pub fn set_rule(&mut self, from: ActorId, rule: LinkRule) {
        if rule.is_clear() {
            self.rules.remove(&from);
        } else {
            self.rules.insert(from, rule);
        }
    }

    pub fn clear_rules(&mut self) {
        self.rules.clear();
    }

    pub fn rule(&self, from: ActorId) -> LinkRule {
        self.rules.get(&from).copied().unwrap_or_default()
    }

    /// Decides the fate of a message from `from` arriving at `now`. A held
    /// message is kept here (the bytes are moved in).
    pub fn admit(&mut self, from: ActorId, bytes: &[u8], now: Duration) -> Admission {
        let Some(rule) = self.rules.get(&from).copied() else {
            return Admission::Deliver;
        };
        if rule.blocked || (rule.loss > 0.0 && self.rng.random::<f64>() < rule.loss) {
            return Admission::Dropped;
        }
        if rule.latency.is_zero() && rule.jitter.is_zero() {
            return Admission::Deliver;
        }
        let jitter = if rule.jitter.is_zero() {
            0.0
        } else {
            self.rng.random_range(-1.0..=1.0) * rule.jitter.as_secs_f64()
        };
        let delay = Duration::from_secs_f64((rule.latency.as_secs_f64() + jitter).max(0.0));
        self.sequence += 1;
        self.held
            .push(Reverse((now + delay, self.sequence, from, bytes.to_vec())));
        Admission::Held
    }

    /// Messages whose delay has passed by `now`, in release order.
    pub fn release_due(&mut self, now: Duration, mut deliver: impl FnMut(ActorId, Vec<u8>)) {
        while let Some(Reverse((due, ..))) = self.held.peek() {
            if *due > now {
                break;
            }
            let Reverse((_, _, from, bytes)) = self.held.pop().expect("peeked");
            deliver(from, bytes);
        }
    }

    /// When the next held message is due, if any.
    pub fn next_due(&self) -> Option<Duration> {
        self.held.peek().map(|Reverse((due, ..))| *due)
    }

    pub fn held_count(&self) -> usize {
        self.held.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delay_holds_until_due_and_loss_drops_the_expected_fraction() {
        let mut s = LinkShaper::new(1);
        let a = ActorId::Node(1);
        s.set_rule(
            a,
            LinkRule {
                latency: Duration::from_millis(30),
                ..Default::default()
            },
        );
        assert_eq!(s.admit(a, b"x", Duration::ZERO), Admission::Held);
        let mut out = Vec::new();
        s.release_due(Duration::from_millis(29), |f, b| out.push((f, b)));
        assert!(out.is_empty());
        s.release_due(Duration::from_millis(30), |f, b| out.push((f, b)));
        assert_eq!(out, vec![(a, b"x".to_vec())]);

        s.set_rule(
            a,
            LinkRule {
                loss: 0.3,
                ..Default::default()
            },
        );
        let dropped = (0..20_000)
            .filter(|_| s.admit(a, b"y", Duration::ZERO) == Admission::Dropped)
            .count();
        let frac = dropped as f64 / 20_000.0;
        assert!((frac - 0.3).abs() < 0.015, "{frac}");
        // Other links are untouched; a partition drops everything.
        assert_eq!(
            s.admit(ActorId::Node(2), b"z", Duration::ZERO),
            Admission::Deliver
        );
        s.set_rule(
            a,
            LinkRule {
                blocked: true,
                ..Default::default()
            },
        );
        assert_eq!(s.admit(a, b"z", Duration::ZERO), Admission::Dropped);
        s.set_rule(a, LinkRule::default());
        assert_eq!(s.admit(a, b"z", Duration::ZERO), Admission::Deliver);
    }
}
