//! Average consensus with one round of memory (docs/equations.md, "Short
//! memory"): `x(t+1) = (1 + α) W x(t) − α x(t−1)`, the first round plain,
//! with `α = 2 / (1 + √(1 − λ₂²)) − 1` from the fusion graph's λ₂
//! (Oreshkin, Coates and Rabbat, IEEE Trans. Signal Processing, 2010).
//! Where average consensus leaves λ₂ of the disagreement a round, this
//! leaves about √α: on the 10 × 10 grid 0.82 rather than 0.98, so a
//! hundredth of the disagreement takes about 23 rounds rather than 222.
//!
//! The messages are average consensus's, one value a round: the memory is
//! the node's own last value, kept, never sent. With every neighbour
//! heard the weights are symmetric and doubly stochastic, and the update
//! keeps the network's average (its two terms are averages of averages),
//! so the sums at the end are N_f times the average, as for average
//! consensus.
//!
//! The memory holds only while every live neighbour is heard, round after
//! round, with the same weights. A round that misses a live neighbour (a
//! message lost or late, a neighbour gone quiet) need not keep the
//! network's average, since that neighbour may have heard this node. Plain
//! consensus carries such a loss e on as it is; the extrapolation would
//! carry on e / (1 − α), for the average's own recursion is
//! `m(t+1) = m(t) + α (m(t) − m(t−1))`. So that round is plain, and so is
//! the next, after which the memory is valid again. A neighbour presumed
//! gone is not live, and the memory holds without it. A step starts
//! without memory, so a restarted node or a new view costs nothing more
//! than average consensus would.

use std::time::Duration;

use fusion_graph::{MetropolisWeights, Topology};
use wire::Payload;

use super::information::InformationPieces;
use super::rounds::{weighted, At};
use super::{Fused, InformationVector, RoundEngine, RoundRule, RoundsDone};

/// A node's value with its memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Remembered {
    pub now: InformationVector,
    /// The value of the round before, and the neighbours that round heard;
    /// `None` in the first round and after a round that missed a live
    /// neighbour.
    before: Option<(InformationVector, Vec<u16>)>,
}

impl Remembered {
    fn fresh(now: InformationVector) -> Self {
        Self { now, before: None }
    }
}

/// The round rule of short-memory consensus on the information vector.
pub struct ShortMemory {
    /// α, in [0, 1).
    alpha: f64,
    with_aux: bool,
}

impl ShortMemory {
    /// One round plain, then `x(t+1) = (1 + alpha) W x(t) − alpha x(t−1)`.
    pub fn new(alpha: f64, with_aux: bool) -> Self {
        Self {
            alpha: alpha.clamp(0.0, 0.999),
            with_aux,
        }
    }
}

impl RoundRule for ShortMemory {
    type Input = InformationVector;
    type Value = Remembered;
    type Output = Fused;
    type Pieces = InformationPieces;

    fn begin(&self, _: u32, input: InformationVector) -> Remembered {
        Remembered::fresh(input)
    }

    fn payloads(&self, _: At, value: &Remembered, out: &mut Vec<Payload>) {
        value.now.payloads(out);
    }

    fn absorb(&self, pieces: &mut InformationPieces, payload: &Payload) -> bool {
        pieces.absorb(payload)
    }

    fn assemble(&self, pieces: &InformationPieces) -> Option<Remembered> {
        pieces.assemble(self.with_aux).map(Remembered::fresh)
    }

    fn combine(
        &self,
        own: &Remembered,
        heard: &[(u16, Remembered)],
        weights: &MetropolisWeights,
    ) -> Remembered {
        let mut mixed = own.now.scaled(weights.own);
        for (w, v) in weighted(heard, weights) {
            mixed.add_scaled(w, &v.now);
        }
        let ids: Vec<u16> = heard.iter().map(|(m, _)| *m).collect();
        let whole = weights.unheard == 0;
        let now = match &own.before {
            Some((before, last)) if whole && *last == ids => {
                let mut next = mixed.scaled(1.0 + self.alpha);
                next.add_scaled(-self.alpha, before);
                next
            }
            // The weights changed, so the memory is of another matrix; or
            // a neighbour went unheard, so this round may not have kept the
            // network's average, and extrapolating would amplify the loss.
            _ => mixed,
        };
        Remembered {
            now,
            before: whole.then_some((own.now, ids)),
        }
    }

    /// The network sums: N_f times the average.
    fn finish(&self, done: RoundsDone<Remembered>) -> Fused {
        Fused {
            sums: done.value.now.scaled(done.component_size as f64).to_sums(),
            stats: done.stats,
        }
    }

    fn disagreement(&self, own: &Remembered, heard: &Remembered) -> Option<f64> {
        Some(own.now.disagreement(&heard.now))
    }
}

/// Short-memory consensus on the information vector.
pub type ShortMemoryConsensus = RoundEngine<ShortMemory>;

/// `rounds` rounds per step with memory weight `alpha`, each closing at
/// `round_timeout` with the neighbours heard; `with_aux` also mixes
/// `S_obs`.
pub fn short_memory_consensus(
    node: u16,
    topology: &Topology,
    rounds: u16,
    round_timeout: Duration,
    alpha: f64,
    with_aux: bool,
) -> ShortMemoryConsensus {
    RoundEngine::new(
        ShortMemory::new(alpha, with_aux),
        node,
        topology,
        rounds,
        round_timeout,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::testing::{drive, Fate};
    use crate::fusion::{average_consensus, FusionProtocol};
    use fusion_graph::Scenario;

    fn grid(side: u32) -> Topology {
        let width = (500 * side).to_string();
        let sets = [
            format!("nodes.grid=[{side},{side}]"),
            format!("region.width={width}"),
            format!("region.height={width}"),
        ];
        let s = Scenario::from_toml(fusion_graph::scenario::DEFAULT_SCENARIO, "g", &sets).unwrap();
        Topology::from_scenario(&s, "g").unwrap()
    }

    /// Each node's vector, different in every part.
    fn value(node: u16) -> InformationVector {
        let x = f64::from(node);
        InformationVector::new(
            [x, 2.0 * x - 5.0, 1.0, -x],
            std::array::from_fn(|i| x * 0.1 + i as f64),
            std::array::from_fn(|i| 1.0 + x * i as f64 * 0.01),
        )
    }

    fn network_sum(n: usize) -> InformationVector {
        let mut sum = value(0);
        for node in 1..n as u16 {
            sum.add_scaled(1.0, &value(node));
        }
        sum
    }

    /// The largest relative difference of any node's sums from the network's.
    fn error<P: FusionProtocol<Value = InformationVector, Output = Fused>>(
        protocols: Vec<P>,
        n: usize,
        mut fate: impl FnMut(u16, u16, &Payload) -> Fate,
    ) -> (f64, Vec<Fused>) {
        let results = drive(
            protocols,
            value,
            &vec![true; n],
            |from, to, p| fate(from, to, p),
            Duration::from_secs(60),
        );
        let want = network_sum(n).to_sums();
        let fused: Vec<Fused> = results.into_iter().map(|r| r.expect("finished")).collect();
        let worst = fused
            .iter()
            .map(|f| {
                let eta = (f.sums.delta_eta - want.delta_eta).norm() / want.delta_eta.norm();
                let l = (f.sums.delta_l - want.delta_l).norm() / want.delta_l.norm();
                eta.max(l)
            })
            .fold(0.0, f64::max);
        (worst, fused)
    }

    fn on_time(_: u16, _: u16, _: &Payload) -> Fate {
        Fate::Deliver(Duration::from_millis(1))
    }

    /// On the 10 × 10 grid, 25 rounds with memory get every node closer to
    /// the network's sums than 100 rounds of average consensus, with the
    /// same messages a round; the average is kept (200 rounds: exact).
    #[test]
    fn memory_gets_further_in_fewer_rounds_with_the_same_messages() {
        let t = grid(10);
        let n = t.nodes();
        let alpha = t.mixing(&t.all_alive()).memory_weight();
        let timeout = Duration::from_millis(50);
        let short = |rounds| -> Vec<ShortMemoryConsensus> {
            (0..n as u16)
                .map(|i| short_memory_consensus(i, &t, rounds, timeout, alpha, false))
                .collect()
        };
        let plain: Vec<_> = (0..n as u16)
            .map(|i| average_consensus(i, &t, 100, timeout, false))
            .collect();
        let mut messages = [0usize; 2];
        let (fast, _) = error(short(25), n, |_, _, _| {
            messages[0] += 1;
            Fate::Deliver(Duration::from_millis(1))
        });
        let (slow, _) = error(plain, n, |_, _, _| {
            messages[1] += 1;
            Fate::Deliver(Duration::from_millis(1))
        });
        assert!(
            fast < slow,
            "25 rounds with memory {fast}, 100 without {slow}"
        );
        assert_eq!(
            messages[0] * 100,
            messages[1] * 25,
            "a message a round a link"
        );
        let (exact, fused) = error(short(200), n, on_time);
        assert!(exact < 1e-9, "{exact}");
        let d = fused[0].stats.disagreement.unwrap();
        assert!(d < 1e-9, "agreed: {d}");
    }

    /// Messages lost at random (a fifth) in every round: memory falls back
    /// to plain rounds where the weights changed, and the nodes end no
    /// further from the network's sums than average consensus under the
    /// same losses, and never far.
    #[test]
    fn lost_messages_do_not_make_it_diverge() {
        let t = grid(6);
        let n = t.nodes();
        let alpha = t.mixing(&t.all_alive()).memory_weight();
        let timeout = Duration::from_millis(50);
        let lossy = || {
            let mut state = 0x9e37_79b9_7f4a_7c15u64;
            move |_: u16, _: u16, _: &Payload| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                if state.is_multiple_of(5) {
                    Fate::Drop
                } else {
                    Fate::Deliver(Duration::from_millis(1))
                }
            }
        };
        for rounds in [10, 30, 60] {
            let short: Vec<_> = (0..n as u16)
                .map(|i| short_memory_consensus(i, &t, rounds, timeout, alpha, false))
                .collect();
            let plain: Vec<_> = (0..n as u16)
                .map(|i| average_consensus(i, &t, rounds, timeout, false))
                .collect();
            let (with_memory, fused) = error(short, n, lossy());
            let (without, _) = error(plain, n, lossy());
            assert!(
                with_memory.is_finite() && with_memory < 1.0,
                "{rounds}: {with_memory}"
            );
            assert!(
                with_memory <= without * 1.5,
                "{rounds} rounds: {with_memory} with memory, {without} without"
            );
            // A node that heard nobody in its last round has no measure.
            let said: Vec<f64> = fused.iter().filter_map(|f| f.stats.disagreement).collect();
            assert!(said.len() > n / 2 && said.iter().all(|d| d.is_finite()));
        }
    }

    /// The memory is the node's own: the first round is plain; a node that
    /// heard other neighbours than the round before, or missed a live one,
    /// runs a plain round, and so does the round after a miss.
    #[test]
    fn memory_holds_only_while_the_weights_do() {
        let rule = ShortMemory::new(0.5, false);
        let own = Remembered::fresh(value(1));
        let heard = [(2u16, Remembered::fresh(value(3)))];
        let weights = MetropolisWeights {
            own: 0.5,
            neighbours: vec![(2, 0.5)],
            unheard: 0,
        };
        let plain = |own: &InformationVector| {
            let mut v = own.scaled(0.5);
            v.add_scaled(0.5, &value(3));
            v
        };
        let first = rule.combine(&own, &heard, &weights);
        assert_eq!(first.now, plain(&value(1)));
        let second = rule.combine(&first, &heard, &weights);
        let mut want = plain(&first.now).scaled(1.5);
        want.add_scaled(-0.5, &value(1));
        assert_eq!(second.now, want);
        let alone = MetropolisWeights {
            own: 1.0,
            neighbours: vec![],
            unheard: 0,
        };
        let changed = rule.combine(&second, &[], &alone);
        assert_eq!(changed.now, second.now, "a plain round with nobody heard");

        let missed = MetropolisWeights {
            unheard: 1,
            ..weights.clone()
        };
        let short = rule.combine(&second, &heard, &missed);
        assert_eq!(short.now, plain(&second.now), "a round that missed one");
        let after = rule.combine(&short, &heard, &weights);
        assert_eq!(after.now, plain(&short.now), "and the round after it");
        let again = rule.combine(&after, &heard, &weights);
        let mut want = plain(&after.now).scaled(1.5);
        want.add_scaled(-0.5, &short.now);
        assert_eq!(again.now, want, "then the memory holds again");
    }
}
