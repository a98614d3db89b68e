//! Random exchange (the random-exchange paper §III-A, RndEx-PF): each node swaps its
//! parametric posterior with one random neighbour, by request and
//! acknowledgement, and continues the step from the posterior it received.
//!
//! A step is [`EXCHANGE_ATTEMPTS`] attempts of `attempt` each. In every
//! attempt a node not yet paired flips a coin: a *requester* asks one live
//! neighbour it has not asked yet; a *listener* accepts the first request
//! that reaches it and refuses the rest; a requester refuses every request.
//! So no node is ever paired twice, and no two requests can cross in a
//! cycle of refusals. An accepted request is answered with the reply and
//! the listener's posterior; the requester sends its own on the reply.
//!
//! Nothing waits forever. A lost request or reply costs the attempt; a lost
//! posterior, or a partner that died, ends the step at `attempt` after the
//! last attempt with the node's own posterior. A node that stays unpaired
//! keeps its own. The same protocol, without losses, is the path model of
//! the RndEx PCRLB (`bounds::diffusion::random_matching`).

use std::time::Duration;

use bounds::diffusion::EXCHANGE_ATTEMPTS;
use bounds::Gaussian;
use fusion_graph::Channel;
use fusion_graph::{ActorId, Topology};
use rand::seq::IndexedRandom;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
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
    /// Asked `to` this attempt (`None`: refused, or no one left to ask).
    Requesting {
        to: Option<u16>,
    },
    Listening,
    /// Waiting for the partner's posterior.
    Paired {
        partner: u16,
    },
    Finished,
}

#[derive(Debug, Clone)]
struct Running {
    step: u32,
    own: Gaussian,
    view: Vec<bool>,
    started: Duration,
    /// 0-based.
    attempt: u32,
    asked: Vec<u16>,
    role: Role,
}

pub struct RandomExchange {
    node: u16,
    neighbours: Vec<u16>,
    attempt: Duration,
    rng: ChaCha8Rng,
    current_step: u32,
    running: Option<Running>,
    /// Messages of a step this node has not started yet.
    early: Vec<Message>,
    done: Option<Exchanged>,
}

impl RandomExchange {
    /// `attempt`: how long one attempt lasts (a request and its reply).
    pub fn new(node: u16, topology: &Topology, attempt: Duration, rng: ChaCha8Rng) -> Self {
        Self {
            node,
            neighbours: topology.neighbours[node as usize].clone(),
            attempt,
            rng,
            current_step: 0,
            running: None,
            early: Vec::new(),
            done: None,
        }
    }

    fn send(&self, to: u16, step: u32, attempt: u32, payload: Payload, out: &mut Vec<Outgoing>) {
        out.push(Outgoing {
            channel: Channel::Pair {
                from: self.node,
                to,
            },
            message: Message::new(ActorId::Node(self.node), step, attempt as u16 + 1, payload),
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

    /// A new attempt for a node not yet paired: a coin for its role.
    fn begin_attempt(&mut self, out: &mut Vec<Outgoing>) {
        let Some(r) = &self.running else { return };
        let (step, attempt) = (r.step, r.attempt);
        let requesting = self.rng.random::<bool>();
        let untried: Vec<u16> = self
            .neighbours
            .iter()
            .copied()
            .filter(|n| r.view[*n as usize] && !r.asked.contains(n))
            .collect();
        let role = if requesting {
            let to = untried.choose(&mut self.rng).copied();
            if let Some(to) = to {
                self.send(to, step, attempt, Payload::ExchangeRequest, out);
            }
            Role::Requesting { to }
        } else {
            Role::Listening
        };
        let r = self.running.as_mut().expect("checked above");
        if let Role::Requesting { to: Some(to) } = role {
            r.asked.push(to);
        }
        r.role = role;
    }

    fn finish(&mut self, posterior: Gaussian, partner: Option<u16>, now: Duration) {
        let Some(r) = self.running.as_mut() else {
            return;
        };
        r.role = Role::Finished;
        self.done = Some(Exchanged {
            posterior,
            partner,
            stats: RoundStats {
                rounds_completed: r.attempt as u16 + 1,
                neighbours_heard: u16::from(partner.is_some()),
                total: now.saturating_sub(r.started),
                later_rounds: Duration::ZERO,
            },
        });
    }

    /// Pairs with `partner`, having sent it this node's posterior.
    fn pair(&mut self, partner: u16) {
        if let Some(r) = self.running.as_mut() {
            r.role = Role::Paired { partner };
        }
    }
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
        self.running = Some(Running {
            step,
            own: value,
            view: view.to_vec(),
            started: now,
            attempt: 0,
            asked: Vec::new(),
            role: Role::Listening,
        });
        self.begin_attempt(out);
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
        if !self.neighbours.contains(&from) || step < self.current_step {
            return Handled::Late;
        }
        let Some(r) = self.running.as_ref().filter(|r| r.step == step) else {
            // A neighbour already in a step this node has not begun. Each
            // neighbour sends at most a request, a reply and a posterior per
            // attempt; more than that is not a protocol's, and is dropped.
            let cap = 3 * EXCHANGE_ATTEMPTS as usize * self.neighbours.len();
            if self.early.len() >= cap {
                return Handled::Late;
            }
            self.early.push(message.clone());
            return Handled::Taken;
        };
        let (role, attempt, own) = (r.role, r.attempt, r.own);
        let asked_before = r.asked.contains(&from);
        match (&message.payload, role) {
            (Payload::ExchangeRequest, Role::Listening) if r.view[from as usize] => {
                self.send(
                    from,
                    step,
                    attempt,
                    Payload::ExchangeReply { accepted: true },
                    out,
                );
                self.send(from, step, attempt, Self::posterior_payload(&own), out);
                self.pair(from);
            }
            (Payload::ExchangeRequest, _) => {
                self.send(
                    from,
                    step,
                    attempt,
                    Payload::ExchangeReply { accepted: false },
                    out,
                );
            }
            (
                Payload::ExchangeReply { accepted: true },
                Role::Requesting { .. } | Role::Listening,
            ) if asked_before => {
                self.send(from, step, attempt, Self::posterior_payload(&own), out);
                self.pair(from);
            }
            (Payload::ExchangeReply { accepted: false }, Role::Requesting { to: Some(to) })
                if to == from =>
            {
                if let Some(r) = self.running.as_mut() {
                    r.role = Role::Requesting { to: None };
                }
            }
            (Payload::ExchangePosterior(g), Role::Paired { partner }) if partner == from => {
                let g = Gaussian {
                    mean: g.mean.into(),
                    cov: unpack_mat4(&g.covariance),
                };
                self.finish(g, Some(from), now);
            }
            // The reply was lost or overtaken: the posterior says accepted.
            (Payload::ExchangePosterior(g), Role::Requesting { .. } | Role::Listening)
                if asked_before =>
            {
                self.send(from, step, attempt, Self::posterior_payload(&own), out);
                let g = Gaussian {
                    mean: g.mean.into(),
                    cov: unpack_mat4(&g.covariance),
                };
                self.finish(g, Some(from), now);
            }
            _ => return Handled::Late,
        }
        Handled::Taken
    }

    fn poll_timeout(&self) -> Option<Duration> {
        let r = self.running.as_ref()?;
        if r.role == Role::Finished {
            return None;
        }
        let attempts_over = r.attempt + 1 >= EXCHANGE_ATTEMPTS;
        // Paired after the last attempt: one attempt's grace for the posterior.
        let k = if attempts_over {
            EXCHANGE_ATTEMPTS + 1
        } else {
            r.attempt + 1
        };
        Some(r.started + self.attempt * k)
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        while self.poll_timeout().is_some_and(|t| t <= now) {
            let r = self.running.as_mut().expect("a timeout only while running");
            if r.attempt + 1 >= EXCHANGE_ATTEMPTS {
                let own = r.own;
                self.finish(own, None, now);
                return;
            }
            r.attempt += 1;
            if !matches!(r.role, Role::Paired { .. }) {
                self.begin_attempt(out);
            }
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
    use bounds::{Mat4, State};
    use fusion_graph::Scenario;
    use rand::SeedableRng;
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
            .map(|r| {
                RandomExchange::new(
                    r,
                    &t,
                    ATTEMPT,
                    ChaCha8Rng::seed_from_u64(seed * 100 + r as u64),
                )
            })
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
        let mut node = RandomExchange::new(0, &t, ATTEMPT, ChaCha8Rng::seed_from_u64(1));
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
