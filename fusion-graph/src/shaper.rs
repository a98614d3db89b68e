//! Link faults, applied on the receiving side of each directed link: netem
//! cannot touch shared memory, so delay, loss, partitions, duplication,
//! reordering, corruption and burst loss live here.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use wire::ActorId;

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
    /// Probability that a message arrives twice.
    pub duplicate: f64,
    /// Probability that a message is held back [`reorder_delay`](Self::reorder_delay).
    pub reorder: f64,
    pub reorder_delay: Duration,
    /// Probability that one bit of a message is flipped.
    pub corrupt: f64,
    /// Gilbert–Elliott burst loss, on top of `loss`.
    pub burst: Option<GilbertElliott>,
    /// Bits per second (0: unlimited): a message is serialized onto the
    /// link after the ones before it, then travels `latency`.
    pub rate: f64,
}

/// A two-state loss chain: `enter_bad` = P(good → bad) and `leave_bad` =
/// P(bad → good) per message; a message is lost with `loss_good` or
/// `loss_bad` in the state the chain is in once it has stepped. The mean
/// burst lasts `1/leave_bad` messages, and the chain spends
/// `enter_bad/(enter_bad + leave_bad)` of the time bad.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GilbertElliott {
    pub enter_bad: f64,
    pub leave_bad: f64,
    pub loss_good: f64,
    pub loss_bad: f64,
}

impl GilbertElliott {
    /// The long-run fraction of messages lost.
    pub fn mean_loss(&self) -> f64 {
        let total = self.enter_bad + self.leave_bad;
        if total == 0.0 {
            return self.loss_good;
        }
        let bad = self.enter_bad / total;
        bad * self.loss_bad + (1.0 - bad) * self.loss_good
    }
}

impl LinkRule {
    pub fn is_clear(&self) -> bool {
        *self == LinkRule::default()
    }

    /// Nothing but loss and partition: a message is either dropped or
    /// delivered at once, as it came.
    fn passes_unchanged(&self) -> bool {
        self.latency.is_zero()
            && self.jitter.is_zero()
            && self.rate == 0.0
            && self.duplicate == 0.0
            && self.reorder == 0.0
            && self.corrupt == 0.0
    }
}

/// What happens to an arriving message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admission {
    Deliver,
    /// Held, maybe tampered with or copied, until its delay has passed
    /// (possibly none); it comes out of [`LinkShaper::release_due`].
    Held,
    Dropped,
}

/// What a fault did to one copy of a message on its way.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord)]
pub struct Tampering {
    /// The second copy of a duplicated message.
    pub duplicate: bool,
    /// A bit was flipped; this was the kind byte before, so that the
    /// message can be counted under the kind it was sent as.
    pub corrupted_kind: Option<u8>,
}

/// A held message: release time, arrival order (ties), sender, bytes, and
/// what was done to it.
type Held = Reverse<(Duration, u64, ActorId, Vec<u8>, Tampering)>;

/// Per-receiver shaper: rules per sender, seeded randomness, each link's
/// burst-loss state, and the queue of held messages ordered by release time.
#[derive(Debug)]
pub struct LinkShaper {
    rules: HashMap<ActorId, LinkRule>,
    rng: ChaCha8Rng,
    held: BinaryHeap<Held>,
    sequence: u64,
    /// Links whose Gilbert–Elliott chain is in the bad state.
    in_burst: HashMap<ActorId, bool>,
    /// When each rate-limited link has finished serializing what it holds.
    busy_until: HashMap<ActorId, Duration>,
    /// Rules taken from each message's own step, for a receiver that is
    /// not told when steps begin (see [`LinkShaper::follow_steps`]).
    follow: Option<StepRules>,
}

/// The rules of a step, and the step they are in place for.
struct StepRules {
    step: Option<u32>,
    rules_at: Box<dyn FnMut(u32) -> Vec<(ActorId, LinkRule)> + Send>,
}

impl std::fmt::Debug for StepRules {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StepRules")
            .field("step", &self.step)
            .finish()
    }
}

impl LinkShaper {
    pub fn new(seed: u64) -> Self {
        Self {
            rules: HashMap::new(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            held: BinaryHeap::new(),
            sequence: 0,
            in_burst: HashMap::new(),
            busy_until: HashMap::new(),
            follow: None,
        }
    }

    /// From now on, each message arriving is judged by the rules of its
    /// own step, `rules_at(step)`, read from its header. A sensor or a
    /// channel is not told when a step begins: a message is all it learns
    /// of the step, so the message's step is the one whose faults apply.
    pub fn follow_steps(
        &mut self,
        rules_at: impl FnMut(u32) -> Vec<(ActorId, LinkRule)> + Send + 'static,
    ) {
        self.follow = Some(StepRules {
            step: None,
            rules_at: Box::new(rules_at),
        });
    }

    /// Puts in place the rules of the step of `bytes`, when they follow steps.
    fn rules_for_message(&mut self, bytes: &[u8]) {
        let Some(follow) = self.follow.as_mut() else {
            return;
        };
        let Some(step) = wire::peek_step(bytes) else {
            return;
        };
        if follow.step == Some(step) {
            return;
        }
        follow.step = Some(step);
        let rules = (follow.rules_at)(step);
        self.clear_rules();
        for (from, rule) in rules {
            self.set_rule(from, rule);
        }
    }

    /// Replaces the rule on the link from `from`; a clear rule removes it.
    /// A burst-loss chain keeps its state while its rule holds.
    pub fn set_rule(&mut self, from: ActorId, rule: LinkRule) {
        if rule.burst.is_none() {
            self.in_burst.remove(&from);
        }
        if rule.rate == 0.0 {
            self.busy_until.remove(&from);
        }
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

    fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.rng.random::<f64>() < p
    }

    /// Steps `from`'s burst chain, if it has one, and says whether this
    /// message is lost to it or to independent loss.
    fn lost(&mut self, from: ActorId, rule: &LinkRule) -> bool {
        if let Some(ge) = rule.burst {
            let bad = self.in_burst.entry(from).or_insert(false);
            let was_bad = *bad;
            let flip = if was_bad { ge.leave_bad } else { ge.enter_bad };
            let now_bad = was_bad ^ (flip > 0.0 && self.rng.random::<f64>() < flip);
            self.in_burst.insert(from, now_bad);
            if self.chance(if now_bad { ge.loss_bad } else { ge.loss_good }) {
                return true;
            }
        }
        self.chance(rule.loss)
    }

    /// Decides the fate of a message from `from` arriving at `now`. A held
    /// message is copied in, once per copy that will arrive.
    pub fn admit(&mut self, from: ActorId, bytes: &[u8], now: Duration) -> Admission {
        self.rules_for_message(bytes);
        let Some(rule) = self.rules.get(&from).copied() else {
            return Admission::Deliver;
        };
        if rule.blocked || self.lost(from, &rule) {
            return Admission::Dropped;
        }
        if rule.passes_unchanged() {
            return Admission::Deliver;
        }
        // netem's rate: the message leaves once the link has sent what came
        // before it, and takes its bits over the rate to do so.
        let sent = if rule.rate > 0.0 {
            let start = self.busy_until.get(&from).map_or(now, |b| (*b).max(now));
            let done = start + Duration::from_secs_f64(bytes.len() as f64 * 8.0 / rule.rate);
            self.busy_until.insert(from, done);
            done
        } else {
            now
        };
        let copies = if self.chance(rule.duplicate) { 2 } else { 1 };
        for copy in 0..copies {
            let mut tampering = Tampering {
                duplicate: copy == 1,
                corrupted_kind: None,
            };
            let mut b = bytes.to_vec();
            if !b.is_empty() && self.chance(rule.corrupt) {
                tampering.corrupted_kind = wire::peek_kind(&b);
                let bit = self.rng.random_range(0..b.len() * 8);
                b[bit / 8] ^= 1 << (bit % 8);
            }
            let mut delay = self.delay(&rule);
            if self.chance(rule.reorder) {
                delay += rule.reorder_delay;
            }
            self.sequence += 1;
            self.held
                .push(Reverse((sent + delay, self.sequence, from, b, tampering)));
        }
        Admission::Held
    }

    fn delay(&mut self, rule: &LinkRule) -> Duration {
        let jitter = if rule.jitter.is_zero() {
            0.0
        } else {
            self.rng.random_range(-1.0..=1.0) * rule.jitter.as_secs_f64()
        };
        Duration::from_secs_f64((rule.latency.as_secs_f64() + jitter).max(0.0))
    }

    /// Messages whose delay has passed by `now`, in release order.
    pub fn release_due(
        &mut self,
        now: Duration,
        mut deliver: impl FnMut(ActorId, Vec<u8>, Tampering),
    ) {
        while let Some(Reverse((due, ..))) = self.held.peek() {
            if *due > now {
                break;
            }
            let Reverse((_, _, from, bytes, tampering)) = self.held.pop().expect("peeked");
            deliver(from, bytes, tampering);
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

    /// A receiver that follows steps judges each message by its own step's
    /// rules: the link is cut at step 2 only, whatever came before.
    #[test]
    fn a_message_is_judged_by_the_rules_of_its_own_step() {
        use wire::{Message, Payload, WireFormat};
        let node = ActorId::Node(0);
        let mut s = LinkShaper::new(1);
        let (tx, rx) = std::sync::mpsc::channel();
        s.follow_steps(move |step| {
            let _ = tx.send(step);
            let blocked = LinkRule {
                blocked: true,
                ..LinkRule::default()
            };
            if step == 2 {
                vec![(node, blocked)]
            } else {
                Vec::new()
            }
        });
        let format = WireFormat {
            cell_bytes: 1,
            activation_bytes: 4,
            payloads: wire::payloads::Payloads::NONE,
        };
        let of_step = |step| {
            Message::new(node, step, 0, Payload::Control(wire::Control::BeginStep))
                .to_bytes(&format)
        };
        let t = Duration::ZERO;
        let fates: Vec<Admission> = [1, 2, 2, 3, 2]
            .into_iter()
            .map(|k| s.admit(node, &of_step(k), t))
            .collect();
        use Admission::{Deliver, Dropped};
        assert_eq!(fates, vec![Deliver, Dropped, Dropped, Deliver, Dropped]);
        // Rules are made again only when the step changes.
        assert_eq!(rx.try_iter().collect::<Vec<u32>>(), vec![1, 2, 3, 2]);
    }

    /// netem's `rate`: a 14-byte message on a 1000 bit/s link with 2 ms of
    /// latency arrives 2 + 112 ms later, and one sent right behind it waits
    /// for the link: 2 + 224 ms.
    #[test]
    fn a_rate_limit_serializes_messages_by_their_size() {
        let mut s = LinkShaper::new(3);
        let a = ActorId::Sensor(4);
        s.set_rule(
            a,
            LinkRule {
                latency: Duration::from_millis(2),
                rate: 1000.0,
                ..LinkRule::default()
            },
        );
        let t0 = Duration::from_secs(1);
        assert_eq!(s.admit(a, &[0u8; 14], t0), Admission::Held);
        assert_eq!(s.admit(a, &[1u8; 14], t0), Admission::Held);
        assert_eq!(s.next_due(), Some(t0 + Duration::from_millis(114)));
        let mut out = Vec::new();
        s.release_due(t0 + Duration::from_millis(114), |_, b, _| out.push(b[0]));
        assert_eq!(out, vec![0]);
        assert_eq!(s.next_due(), Some(t0 + Duration::from_millis(226)));
        // A message after the link went idle starts at once.
        s.release_due(t0 + Duration::from_secs(5), |_, _, _| {});
        let later = t0 + Duration::from_secs(5);
        s.admit(a, &[2u8; 15], later);
        assert_eq!(s.next_due(), Some(later + Duration::from_millis(2 + 120)));
    }

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
        s.release_due(Duration::from_millis(29), |f, b, _| out.push((f, b)));
        assert!(out.is_empty());
        s.release_due(Duration::from_millis(30), |f, b, _| out.push((f, b)));
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

    fn shaper_with(rule: LinkRule) -> (LinkShaper, ActorId) {
        let mut s = LinkShaper::new(7);
        let a = ActorId::Node(1);
        s.set_rule(a, rule);
        (s, a)
    }

    fn released(s: &mut LinkShaper, now: Duration) -> Vec<(Vec<u8>, Tampering)> {
        let mut out = Vec::new();
        s.release_due(now, |_, b, t| out.push((b, t)));
        out
    }

    #[test]
    fn duplication_delivers_a_marked_second_copy() {
        let (mut s, a) = shaper_with(LinkRule {
            duplicate: 1.0,
            ..Default::default()
        });
        assert_eq!(s.admit(a, b"ab", Duration::ZERO), Admission::Held);
        let out = released(&mut s, Duration::ZERO);
        assert_eq!(out.len(), 2);
        assert_eq!(
            (out[0].0.as_slice(), out[0].1.duplicate),
            (&b"ab"[..], false)
        );
        assert_eq!(
            (out[1].0.as_slice(), out[1].1.duplicate),
            (&b"ab"[..], true)
        );
    }

    #[test]
    fn corruption_flips_exactly_one_bit_and_remembers_the_kind() {
        let (mut s, a) = shaper_with(LinkRule {
            corrupt: 1.0,
            ..Default::default()
        });
        let original = [2u8, 5, 0, 0, 9, 9, 9];
        for _ in 0..200 {
            s.admit(a, &original, Duration::ZERO);
            let out = released(&mut s, Duration::ZERO);
            let (bytes, t) = &out[0];
            let flipped: u32 = bytes
                .iter()
                .zip(original)
                .map(|(x, y)| (x ^ y).count_ones())
                .sum();
            assert_eq!(flipped, 1);
            assert_eq!(t.corrupted_kind, Some(5));
        }
    }

    #[test]
    fn reordering_lets_later_messages_overtake() {
        let (mut s, a) = shaper_with(LinkRule {
            reorder: 0.5,
            reorder_delay: Duration::from_millis(10),
            ..Default::default()
        });
        for i in 0..100u8 {
            s.admit(a, &[i], Duration::from_micros(i as u64));
        }
        let order: Vec<u8> = released(&mut s, Duration::from_secs(1))
            .into_iter()
            .map(|(b, _)| b[0])
            .collect();
        assert_eq!(order.len(), 100);
        // A held-back message comes out after later ones: behind a larger number.
        let overtaken = order
            .iter()
            .enumerate()
            .filter(|(i, x)| order[..*i].iter().any(|y| y > x))
            .count();
        assert!(
            (35..=65).contains(&overtaken),
            "{overtaken} of 100 overtaken"
        );
        // Nothing held back is out before its delay.
        s.admit(a, &[0], Duration::ZERO);
        let early = released(&mut s, Duration::from_millis(9)).len();
        let late = released(&mut s, Duration::from_millis(10)).len();
        assert_eq!(early + late, 1);
    }

    #[test]
    fn gilbert_elliott_losses_come_in_bursts_of_the_chains_length() {
        let ge = GilbertElliott {
            enter_bad: 0.05,
            leave_bad: 0.25,
            loss_good: 0.0,
            loss_bad: 1.0,
        };
        let (mut s, a) = shaper_with(LinkRule {
            burst: Some(ge),
            ..Default::default()
        });
        let lost: Vec<bool> = (0..200_000)
            .map(|_| s.admit(a, b"x", Duration::ZERO) == Admission::Dropped)
            .collect();
        let fraction = lost.iter().filter(|l| **l).count() as f64 / lost.len() as f64;
        // Stationary: p / (p + r) of the time bad.
        assert!((fraction - ge.mean_loss()).abs() < 0.01, "{fraction}");
        assert!((ge.mean_loss() - 1.0 / 6.0).abs() < 1e-12);
        // A burst lasts 1/r messages on average.
        let bursts = lost.windows(2).filter(|w| !w[0] && w[1]).count();
        let mean_burst = lost.iter().filter(|l| **l).count() as f64 / bursts as f64;
        assert!((mean_burst - 4.0).abs() < 0.2, "{mean_burst}");
        // Independent loss at the same mean would give bursts of 1.2.
    }
}
