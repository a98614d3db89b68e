//! Random exchange (the random-exchange paper §III-A, RndEx-PF): each node swaps its
//! parametric posterior with one random neighbour, by request and
//! acknowledgement, and continues the step from the posterior it received.
//!
//! Who pairs with whom is a random matching of the live fusion graph that
//! every node draws alike, from the network's stream of the step
//! ([`Stream::Exchange`]), by the law of the RndEx PCRLB's path model
//! ([`random_matching`]: attempts in which every unpaired node flips a
//! coin, a requester asks a neighbour it has not asked, a listener takes
//! one of its requests). So the pairing is the model's to the draw, and it
//! does not depend on which message reaches a node first: `run --lockstep`
//! pairs as `sim` does. The pair then exchanges by request and
//! acknowledgement: the lower-numbered node asks, its partner accepts with
//! its posterior, and the asker answers with its own. A request from a
//! neighbour that is not the node's partner (their membership views
//! differ) is refused, and both keep their own.
//!
//! Nothing waits forever. A lost request, reply or posterior, or a partner
//! that died, ends the step at two attempts' time with the node's own
//! posterior. A node the matching leaves unpaired keeps its own at once.

use std::time::Duration;

use bounds::diffusion::random_matching;
use bounds::Gaussian;
use fusion_graph::Channel;
use fusion_graph::{stream_rng, ActorId, Stream, Topology};
use wire::{pack_mat4, unpack_mat4, GaussianMoments, Message, Payload};

use super::{FusionProtocol, Handled, RoundStats};
use crate::Outgoing;

/// What a step of random exchange yields.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exchanged {
    /// The partner's posterior, or the node's own when it stayed unpaired.
    pub posterior: Gaussian,
    pub partner: Option<u16>,
    pub stats: RoundStats,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    /// Asked its partner; waiting for the acknowledgement.
    Requesting {
        partner: u16,
    },
    /// Waiting for its partner's request.
    Listening {
        partner: u16,
    },
    /// Sent its posterior; waiting for the partner's.
    Paired {
        partner: u16,
    },
    Finished,
}

#[derive(Debug, Clone)]
struct Running {
    step: u32,
    own: Gaussian,
    started: Duration,
    role: Role,
}

pub struct RandomExchange {
    node: u16,
    topology: Topology,
    /// How long a request and its reply take; the step's exchange ends by
    /// two of them.
    attempt: Duration,
    /// The scenario's seed: the step's matching is drawn from the
    /// network's stream of it.
    seed: u64,
    current_step: u32,
    running: Option<Running>,
    /// Messages of a step this node has not started yet.
    early: Vec<Message>,
    done: Option<Exchanged>,
}

impl RandomExchange {
    /// `attempt`: how long one attempt lasts (a request and its reply);
    /// `seed`: the scenario's, which every node of the run shares.
    pub fn new(node: u16, topology: &Topology, attempt: Duration, seed: u64) -> Self {
        Self {
            node,
            topology: topology.clone(),
            attempt,
            seed,
            current_step: 0,
            running: None,
            early: Vec::new(),
            done: None,
        }
    }

    /// This node's partner at `step` in the matching of the live fusion
    /// graph (`view`), which every node with the same view draws alike;
    /// `None` if it stays unpaired.
    pub fn partner(&self, step: u32, view: &[bool]) -> Option<u16> {
        let partners = step_matching(&self.topology, view, self.seed, step);
        let p = partners[self.node as usize];
        (p != self.node as usize).then_some(p as u16)
    }

    fn neighbours(&self) -> &[u16] {
        &self.topology.neighbours[self.node as usize]
    }

    fn send(&self, to: u16, step: u32, payload: Payload, out: &mut Vec<Outgoing>) {
        out.push(Outgoing {
            channel: Channel::Pair {
                from: self.node,
                to,
            },
            message: Message::new(ActorId::Node(self.node), step, 1, payload),
            receivers: vec![ActorId::Node(to)],
            wake: None,
        });
    }

    fn posterior_payload(g: &Gaussian) -> Payload {
        Payload::ExchangePosterior(GaussianMoments {
            mean: g.mean.into(),
            covariance: pack_mat4(&g.cov),
        })
    }

    fn finish(&mut self, posterior: Gaussian, partner: Option<u16>, now: Duration) {
        let Some(r) = self.running.as_mut() else {
            return;
        };
        // Still `Finished` here only if the step's matching left it alone.
        let matched = !matches!(r.role, Role::Finished);
        r.role = Role::Finished;
        self.done = Some(Exchanged {
            posterior,
            partner,
            stats: RoundStats {
                rounds_completed: 1,
                neighbours_heard: u16::from(partner.is_some()),
                neighbours_expected: u16::from(matched),
                total: now.saturating_sub(r.started),
                ..RoundStats::default()
            },
        });
    }

    fn set_role(&mut self, role: Role) {
        if let Some(r) = self.running.as_mut() {
            r.role = role;
        }
    }
}

/// The matching of `step` over the fusion graph's live nodes (`view`):
/// [`random_matching`] on the network's stream of the step. `partner[r]`
/// is r itself when r stays unpaired.
pub fn step_matching(topology: &Topology, view: &[bool], seed: u64, step: u32) -> Vec<usize> {
    let live = |n: usize| view.get(n).copied().unwrap_or(false);
    let neighbours: Vec<Vec<usize>> = topology
        .neighbours
        .iter()
        .enumerate()
        .map(|(r, ns)| {
            if !live(r) {
                return Vec::new();
            }
            ns.iter()
                .map(|&m| m as usize)
                .filter(|&m| live(m))
                .collect()
        })
        .collect();
    let mut rng = stream_rng(seed, ActorId::Launcher, step, Stream::Exchange);
    random_matching(&neighbours, &mut rng)
}

impl FusionProtocol for RandomExchange {
    type Value = Gaussian;
    type Output = Exchanged;

    fn expect_step(&mut self, step: u32) {
        self.current_step = self.current_step.max(step);
        self.early.retain(|m| m.header.step >= step);
    }

    fn start(
        &mut self,
        step: u32,
        value: Gaussian,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        self.current_step = self.current_step.max(step);
        self.done = None;
        let mut view = view.to_vec();
        if let Some(me) = view.get_mut(self.node as usize) {
            *me = true;
        }
        let partner = self.partner(step, &view);
        self.running = Some(Running {
            step,
            own: value,
            started: now,
            role: Role::Finished,
        });
        match partner {
            None => self.finish(value, None, now),
            Some(p) if self.node < p => {
                self.send(p, step, Payload::ExchangeRequest, out);
                self.set_role(Role::Requesting { partner: p });
            }
            Some(p) => self.set_role(Role::Listening { partner: p }),
        }
        let early: Vec<Message> = std::mem::take(&mut self.early);
        for m in early {
            if m.header.step == step {
                self.handle(&m, now, out);
            }
        }
    }

    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) -> Handled {
        let ActorId::Node(from) = message.header.sender else {
            return Handled::NotMine;
        };
        if !matches!(
            message.payload,
            Payload::ExchangeRequest
                | Payload::ExchangeReply { .. }
                | Payload::ExchangePosterior(_)
        ) {
            return Handled::NotMine;
        }
        let step = message.header.step;
        if !self.neighbours().contains(&from) || step < self.current_step {
            return Handled::Late;
        }
        let Some(r) = self.running.as_ref().filter(|r| r.step == step) else {
            // A neighbour already in a step this node has not begun. Each
            // neighbour sends at most a request, a reply and a posterior a
            // step; more than that is not a protocol's, and is dropped.
            let cap = 3 * self.neighbours().len();
            if self.early.len() >= cap {
                return Handled::Late;
            }
            self.early.push(message.clone());
            return Handled::Taken;
        };
        let (role, own) = (r.role, r.own);
        let received = |g: &GaussianMoments| Gaussian {
            mean: g.mean.into(),
            cov: unpack_mat4(&g.covariance),
        };
        match (&message.payload, role) {
            (Payload::ExchangeRequest, Role::Listening { partner }) if partner == from => {
                self.send(from, step, Payload::ExchangeReply { accepted: true }, out);
                self.send(from, step, Self::posterior_payload(&own), out);
                self.set_role(Role::Paired { partner });
            }
            // Not this node's partner this step (their views differ), or a
            // second request.
            (Payload::ExchangeRequest, _) => {
                self.send(from, step, Payload::ExchangeReply { accepted: false }, out);
            }
            (Payload::ExchangeReply { accepted: true }, Role::Requesting { partner })
                if partner == from =>
            {
                self.send(from, step, Self::posterior_payload(&own), out);
                self.set_role(Role::Paired { partner });
            }
            (Payload::ExchangeReply { accepted: false }, Role::Requesting { partner })
                if partner == from =>
            {
                self.finish(own, None, now);
            }
            (Payload::ExchangePosterior(g), Role::Paired { partner }) if partner == from => {
                self.finish(received(g), Some(from), now);
            }
            // The acknowledgement was lost or overtaken: the posterior says
            // accepted.
            (Payload::ExchangePosterior(g), Role::Requesting { partner }) if partner == from => {
                self.send(from, step, Self::posterior_payload(&own), out);
                self.finish(received(g), Some(from), now);
            }
            _ => return Handled::Late,
        }
        Handled::Taken
    }

    fn poll_timeout(&self) -> Option<Duration> {
        let r = self.running.as_ref()?;
        (r.role != Role::Finished).then_some(r.started + self.attempt * 2)
    }

    fn handle_timeout(&mut self, now: Duration, _out: &mut Vec<Outgoing>) {
        if self.poll_timeout().is_some_and(|t| t <= now) {
            let own = self
                .running
                .as_ref()
                .expect("a timeout only while running")
                .own;
            self.finish(own, None, now);
        }
    }

    fn poll_result(&mut self) -> Option<Exchanged> {
        self.done.take()
    }

    fn finish_now(&mut self, now: Duration, _out: &mut Vec<Outgoing>) -> Option<Exchanged> {
        let own = self
            .running
            .as_ref()
            .filter(|r| r.role != Role::Finished)?
            .own;
        self.finish(own, None, now);
        self.done.take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::testing::{drive, Fate};
    use bounds::diffusion::EXCHANGE_ATTEMPTS;
    use bounds::{Mat4, State};
    use fusion_graph::Scenario;
    use rand::Rng;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use wire::MessageKind;

    const ATTEMPT: Duration = Duration::from_millis(20);

    fn lattice() -> Topology {
        let s = Scenario::from_toml(
            fusion_graph::scenario::RANDOM_EXCHANGE_SCENARIO,
            "random-exchange",
            &[],
        )
        .unwrap();
        Topology::from_scenario(&s, "random-exchange").unwrap()
    }

    fn own(r: u16) -> Gaussian {
        Gaussian {
            mean: State::new(r as f64, 100.0 + r as f64, 0.0, 0.0),
            cov: Mat4::identity() * (1.0 + r as f64),
        }
    }

    fn exchange(
        seed: u64,
        view: &[bool],
        fate: impl FnMut(u16, u16, &Payload) -> Fate,
    ) -> Vec<Option<Exchanged>> {
        let t = lattice();
        let nodes = (0..25u16)
            .map(|r| RandomExchange::new(r, &t, ATTEMPT, seed))
            .collect();
        drive(nodes, own, view, fate, ATTEMPT * (EXCHANGE_ATTEMPTS + 2))
    }

    fn latency(_: u16, _: u16, _: &Payload) -> Fate {
        Fate::Deliver(Duration::from_micros(500))
    }

    #[test]
    fn partners_swap_posteriors_both_ways_and_only_with_neighbours() {
        let t = lattice();
        let mut paired = 0;
        for seed in 0..200 {
            let got = exchange(seed, &[true; 25], latency);
            for (r, e) in got.iter().enumerate() {
                let e = e.expect("every node finishes");
                match e.partner {
                    Some(p) => {
                        assert!(t.neighbours[r].contains(&p));
                        assert_eq!(e.posterior, own(p), "node {r} holds its partner's");
                        assert_eq!(got[p as usize].unwrap().partner, Some(r as u16));
                        paired += 1;
                    }
                    None => assert_eq!(e.posterior, own(r as u16)),
                }
            }
        }
        // The bound's path model is this protocol without losses: the two
        // pair the same share of nodes.
        let share = paired as f64 / (200.0 * 25.0);
        let neighbours: Vec<Vec<usize>> = t
            .neighbours
            .iter()
            .map(|ns| ns.iter().map(|&n| n as usize).collect())
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let modelled = (0..2000)
            .map(|_| {
                let p = bounds::diffusion::random_matching(&neighbours, &mut rng);
                p.iter().enumerate().filter(|(r, p)| *r != **p).count()
            })
            .sum::<usize>() as f64
            / (2000.0 * 25.0);
        assert!(
            (share - modelled).abs() < 0.03,
            "protocol {share}, bound's model {modelled}"
        );
    }

    /// The protocol's pairs follow the RndEx PCRLB's path model: how often
    /// each edge of the lattice pairs, over 4,000 steps of the protocol
    /// (its messages delivered in an order the seed shuffles), is within
    /// its sampling error of how often the model's matching pairs it, drawn
    /// 4,000 times from a generator of its own.
    #[test]
    fn the_protocols_pairs_follow_the_path_models_law() {
        let t = lattice();
        let neighbours: Vec<Vec<usize>> = t
            .neighbours
            .iter()
            .map(|ns| ns.iter().map(|&n| n as usize).collect())
            .collect();
        let edges: Vec<(usize, usize)> = neighbours
            .iter()
            .enumerate()
            .flat_map(|(r, ns)| ns.iter().filter(move |&&m| m > r).map(move |&m| (r, m)))
            .collect();
        let trials = 4000;
        let mut protocol = vec![0u32; edges.len()];
        let mut model = vec![0u32; edges.len()];
        let mut rng = ChaCha8Rng::seed_from_u64(77);
        let count = |counts: &mut Vec<u32>, partner: &dyn Fn(usize) -> usize| {
            for (e, (r, m)) in edges.iter().enumerate() {
                if partner(*r) == *m {
                    counts[e] += 1;
                }
            }
        };
        for seed in 0..trials {
            // Each message's latency drawn from the seed: the arrival order
            // must not matter.
            let mut jitter = ChaCha8Rng::seed_from_u64(seed + 1_000_000);
            let got = exchange(seed, &[true; 25], |_, _, _| {
                Fate::Deliver(Duration::from_micros(jitter.random_range(1..900)))
            });
            count(&mut protocol, &|r| {
                got[r].unwrap().partner.map_or(r, usize::from)
            });
            let p = bounds::diffusion::random_matching(&neighbours, &mut rng);
            count(&mut model, &|r| p[r]);
        }
        for (e, (a, b)) in protocol.iter().zip(&model).enumerate() {
            // Two binomial shares of `trials` draws each: their difference's
            // standard error, from the pooled share.
            let pooled = f64::from(a + b) / (2.0 * trials as f64);
            let se = (2.0 * pooled * (1.0 - pooled) / trials as f64).sqrt();
            let diff = (f64::from(*a) - f64::from(*b)) / trials as f64;
            assert!(
                diff.abs() <= 4.5 * se.max(1e-9),
                "edge {:?}: protocol {a}, model {b} in {trials}",
                edges[e]
            );
        }
    }

    /// Who pairs with whom does not depend on the order messages arrive in:
    /// the same seed under different latencies gives the same pairs.
    #[test]
    fn the_pairs_do_not_depend_on_arrival_order() {
        for seed in 0..50 {
            let partners = |spread: u64| -> Vec<Option<u16>> {
                let mut jitter = ChaCha8Rng::seed_from_u64(spread);
                exchange(seed, &[true; 25], |_, _, _| {
                    Fate::Deliver(Duration::from_micros(jitter.random_range(1..5000)))
                })
                .iter()
                .map(|e| e.unwrap().partner)
                .collect()
            };
            let first = partners(1);
            for spread in 2..6 {
                assert_eq!(partners(spread), first, "seed {seed}");
            }
        }
    }

    /// Every message is a request, a reply, or one of the two posteriors of
    /// a pair: the bytes a step costs follow from the pairs and refusals.
    #[test]
    fn messages_are_a_request_and_reply_per_ask_and_two_posteriors_per_pair() {
        let mut counts = std::collections::HashMap::<MessageKind, usize>::new();
        let got = exchange(3, &[true; 25], |_, _, p| {
            *counts.entry(p.kind()).or_default() += 1;
            Fate::Deliver(Duration::from_micros(500))
        });
        let pairs = got.iter().filter(|e| e.unwrap().partner.is_some()).count() / 2;
        assert_eq!(counts[&MessageKind::ExchangePosterior], 2 * pairs);
        assert_eq!(
            counts[&MessageKind::ExchangeRequest],
            counts[&MessageKind::ExchangeReply]
        );
        assert!(counts[&MessageKind::ExchangeRequest] >= pairs);
    }

    /// Lost requests, replies and posteriors, and a dead neighbour: every
    /// live node still finishes within the step's attempts and its grace,
    /// with its own posterior or a live neighbour's.
    #[test]
    fn losses_and_a_dead_neighbour_never_hang_a_node() {
        let mut view = [true; 25];
        view[12] = false;
        for seed in 0..50 {
            let mut n = 0u32;
            let got = exchange(seed, &view, |_, _, _| {
                n += 1;
                if n.is_multiple_of(3) {
                    Fate::Drop
                } else {
                    Fate::Deliver(Duration::from_micros(500))
                }
            });
            for (r, e) in got.iter().enumerate() {
                if r == 12 {
                    assert!(e.is_none());
                    continue;
                }
                let e = e.expect("finishes despite losses");
                assert_ne!(e.partner, Some(12));
                let from = e.partner.unwrap_or(r as u16);
                assert_eq!(e.posterior, own(from));
                assert!(e.stats.total <= ATTEMPT * (EXCHANGE_ATTEMPTS + 1));
            }
        }
    }

    /// A request from a neighbour a step ahead waits for this node's step.
    #[test]
    fn a_request_for_a_step_not_begun_is_kept_until_it_begins() {
        let t = lattice();
        let mut node = RandomExchange::new(0, &t, ATTEMPT, 1);
        let request = Message::new(ActorId::Node(1), 2, 1, Payload::ExchangeRequest);
        let mut out = Vec::new();
        node.expect_step(1);
        assert_eq!(
            node.handle(&request, Duration::ZERO, &mut out),
            Handled::Taken
        );
        assert!(out.is_empty());
        node.expect_step(2);
        node.start(2, own(0), &[true; 25], Duration::ZERO, &mut out);
        // Answered at the start, accepted or refused by its coin.
        assert!(out.iter().any(|o| o.receivers == [ActorId::Node(1)]
            && o.channel == Channel::Pair { from: 0, to: 1 }
            && matches!(o.message.payload, Payload::ExchangeReply { .. })));
    }
}
