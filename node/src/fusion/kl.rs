//! Kullback–Leibler fusion (the random-exchange paper §IV): K_max rounds of
//! `β_r ← Π_ℓ β_ℓ^{a_rℓ}` over the closed neighbourhood, Metropolis weights
//! `a_rℓ`. For Gaussian β this is average consensus on the natural
//! parameters, `Λ ← Σ a_rℓ Λ_ℓ` and `η ← Σ a_rℓ η_ℓ` (the paper's eq. after
//! Line 3, from its ref. [5]); as rounds grow every node reaches the
//! normalized geometric mean of all the nodes' Gaussians, the density that
//! minimizes the average KL divergence to them. With K_max = 1 it is the
//! non-iterative diffusion step of ref. [5].
//!
//! Unlike the CF/DPF's consensus the result is an average, not a network
//! sum: no N_f.

use std::time::Duration;

use bounds::{Gaussian, Mat4, State};
use fusion_graph::{MetropolisWeights, Topology};
use wire::{pack_mat4, unpack_mat4, GaussianInformation, Payload};

use super::information::relative_distance;
use super::rounds::{weighted, At};
use super::{RoundEngine, RoundRule, RoundStats, RoundsDone};

/// A Gaussian in information form: `Λ = P⁻¹`, `η = P⁻¹ m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NaturalGaussian {
    pub eta: State,
    pub lambda: Mat4,
}

impl NaturalGaussian {
    /// `None` when the covariance is not positive definite.
    pub fn from_moments(g: &Gaussian) -> Option<Self> {
        let lambda = nalgebra::Cholesky::new(g.cov)?.inverse();
        Some(Self {
            eta: lambda * g.mean,
            lambda,
        })
    }

    /// `None` when Λ is not positive definite.
    pub fn to_moments(&self) -> Option<Gaussian> {
        let chol = nalgebra::Cholesky::new(symmetric(self.lambda))?;
        Some(Gaussian {
            mean: chol.solve(&self.eta),
            cov: chol.inverse(),
        })
    }

    fn to_wire(self) -> GaussianInformation {
        GaussianInformation {
            eta: self.eta.into(),
            lambda: pack_mat4(&self.lambda),
        }
    }

    fn from_wire(g: &GaussianInformation) -> Self {
        Self {
            eta: State::from(g.eta),
            lambda: unpack_mat4(&g.lambda),
        }
    }
}

fn symmetric(m: Mat4) -> Mat4 {
    (m + m.transpose()) * 0.5
}

/// What a step of KL fusion yields: the node's fused Gaussian.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KlFused {
    pub fused: NaturalGaussian,
    pub stats: RoundStats,
}

/// The round rule: Metropolis-weighted sums of the natural parameters.
pub struct KlRule;

impl RoundRule for KlRule {
    type Input = NaturalGaussian;
    type Value = NaturalGaussian;
    type Output = KlFused;
    type Pieces = Option<NaturalGaussian>;

    fn begin(&self, _: u32, input: NaturalGaussian) -> NaturalGaussian {
        input
    }

    fn payloads(&self, _: At, value: &NaturalGaussian, out: &mut Vec<Payload>) {
        out.push(Payload::KlConsensus(value.to_wire()));
    }

    fn absorb(&self, pieces: &mut Option<NaturalGaussian>, payload: &Payload) -> bool {
        match payload {
            Payload::KlConsensus(g) => {
                *pieces = Some(NaturalGaussian::from_wire(g));
                true
            }
            _ => false,
        }
    }

    fn assemble(&self, pieces: &Option<NaturalGaussian>) -> Option<NaturalGaussian> {
        *pieces
    }

    fn combine(
        &self,
        own: &NaturalGaussian,
        heard: &[(u16, NaturalGaussian)],
        weights: &MetropolisWeights,
    ) -> NaturalGaussian {
        let mut next = NaturalGaussian {
            eta: own.eta * weights.own,
            lambda: own.lambda * weights.own,
        };
        for (w, v) in weighted(heard, weights) {
            next.eta += v.eta * w;
            next.lambda += v.lambda * w;
        }
        next
    }

    fn finish(&self, done: RoundsDone<NaturalGaussian>) -> KlFused {
        KlFused {
            fused: done.value,
            stats: done.stats,
        }
    }

    /// Λ's relative distance (as the information vector's, the
    /// information and not its mean).
    fn disagreement(&self, own: &NaturalGaussian, heard: &NaturalGaussian) -> Option<f64> {
        Some(relative_distance(
            own.lambda.as_slice(),
            heard.lambda.as_slice(),
        ))
    }
}

/// K_max rounds of KL fusion per step.
pub type KlFusion = RoundEngine<KlRule>;

/// `rounds` = K_max: 1 for the non-iterative form, 10 for the iterative.
pub fn kl_fusion(node: u16, topology: &Topology, rounds: u16, round_timeout: Duration) -> KlFusion {
    RoundEngine::new(KlRule, node, topology, rounds, round_timeout)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::testing::{drive, Fate};
    use fusion_graph::Scenario;

    fn lattice() -> Topology {
        let s = Scenario::from_toml(
            fusion_graph::scenario::RANDOM_EXCHANGE_SCENARIO,
            "random-exchange",
            &[],
        )
        .unwrap();
        Topology::from_scenario(&s, "random-exchange").unwrap()
    }

    /// Node r's Gaussian: a different mean and spread at every node.
    fn local(r: u16) -> NaturalGaussian {
        let k = r as f64;
        let mean = State::new(40.0 + k, 60.0 - 0.5 * k, 0.1 * (k % 3.0), -0.05 * k);
        let cov = Mat4::from_diagonal(&State::new(4.0 + k, 9.0 + 0.3 * k, 0.01, 0.02 + 0.001 * k));
        NaturalGaussian::from_moments(&Gaussian { mean, cov }).unwrap()
    }

    fn geometric_mean(nodes: u16) -> NaturalGaussian {
        let n = nodes as f64;
        let mut g = NaturalGaussian {
            eta: State::zeros(),
            lambda: Mat4::zeros(),
        };
        for r in 0..nodes {
            g.eta += local(r).eta / n;
            g.lambda += local(r).lambda / n;
        }
        g
    }

    fn fuse(
        rounds: u16,
        fate: impl FnMut(u16, u16, &Payload) -> Fate,
        view: &[bool],
    ) -> Vec<Option<KlFused>> {
        let t = lattice();
        let nodes: Vec<KlFusion> = (0..t.nodes() as u16)
            .map(|r| kl_fusion(r, &t, rounds, Duration::from_millis(50)))
            .collect();
        drive(nodes, local, view, fate, Duration::from_secs(10))
    }

    fn relative(a: &NaturalGaussian, b: &NaturalGaussian) -> f64 {
        ((a.eta - b.eta).norm() / b.eta.norm()).max((a.lambda - b.lambda).norm() / b.lambda.norm())
    }

    #[test]
    fn many_rounds_reach_the_normalized_geometric_mean() {
        let all = [true; 25];
        let target = geometric_mean(25);
        let far = fuse(
            200,
            |_, _, _| Fate::Deliver(Duration::from_micros(100)),
            &all,
        );
        for (r, f) in far.iter().enumerate() {
            let f = f.expect("every node finishes");
            assert!(relative(&f.fused, &target) < 1e-6, "node {r}");
            assert_eq!(f.stats.rounds_completed, 200);
        }
        // Ten rounds on this 8-hop lattice leave the nodes apart, but closer
        // than they started.
        let ten = fuse(
            10,
            |_, _, _| Fate::Deliver(Duration::from_micros(100)),
            &all,
        );
        let before: f64 = (0..25).map(|r| relative(&local(r), &target)).sum();
        let after: f64 = ten
            .iter()
            .map(|f| relative(&f.unwrap().fused, &target))
            .sum();
        assert!(after < 0.5 * before, "{after} vs {before}");
    }

    /// K_max = 1: each node's result is exactly its Metropolis-weighted
    /// combination of its closed neighbourhood (ref. [5]'s diffusion step).
    #[test]
    fn one_round_is_the_weighted_neighbourhood_combination() {
        let t = lattice();
        let all = [true; 25];
        let got = fuse(1, |_, _, _| Fate::Deliver(Duration::from_micros(100)), &all);
        for r in 0..25u16 {
            let w = t.metropolis_weights(r, &all);
            let mut expected = NaturalGaussian {
                eta: local(r).eta * w.own,
                lambda: local(r).lambda * w.own,
            };
            for (m, a) in &w.neighbours {
                expected.eta += local(*m).eta * *a;
                expected.lambda += local(*m).lambda * *a;
            }
            assert!(
                relative(&got[r as usize].unwrap().fused, &expected) < 1e-12,
                "node {r}"
            );
        }
    }

    /// A neighbour that died, or whose messages are lost, costs rounds their
    /// timeout but never hangs a node; the fused Λ stays positive definite.
    #[test]
    fn a_dead_neighbour_and_lost_messages_never_hang_a_node() {
        let mut view = [true; 25];
        view[12] = false; // the centre node is gone
        let got = fuse(
            10,
            |from, to, _| {
                if (from + to) % 7 == 0 {
                    Fate::Drop
                } else {
                    Fate::Deliver(Duration::from_micros(300))
                }
            },
            &view,
        );
        for (r, f) in got.iter().enumerate() {
            if r == 12 {
                assert!(f.is_none());
                continue;
            }
            let f = f.expect("finishes despite losses");
            assert!(f.fused.to_moments().is_some(), "node {r}");
        }
    }

    /// Every round, every node sends one `kl_consensus` to each neighbour
    /// and nothing else: K_max × (directed edges) messages of 13 + 112 B.
    #[test]
    fn a_step_costs_k_max_messages_per_directed_edge() {
        use wire::{encoded_len, WireFormat};
        let t = lattice();
        let directed: usize = t.neighbours.iter().map(Vec::len).sum();
        assert_eq!(directed, 80);
        let format = WireFormat {
            cell_bytes: 1,
            activation_bytes: 1,
            payloads: wire::payloads::Payloads::NONE,
        };
        for rounds in [1u16, 10] {
            let mut bytes = 0;
            let mut messages = 0;
            fuse(
                rounds,
                |_, _, p| {
                    messages += 1;
                    bytes += encoded_len(p.kind(), &format).unwrap();
                    Fate::Deliver(Duration::from_micros(100))
                },
                &[true; 25],
            );
            assert_eq!(messages, rounds as usize * directed);
            assert_eq!(bytes, rounds as usize * directed * (13 + 112));
        }
    }

    #[test]
    fn moments_and_natural_parameters_round_trip() {
        let g = Gaussian {
            mean: State::new(1.0, 2.0, 3.0, 4.0),
            cov: Mat4::from_diagonal(&State::new(2.0, 3.0, 0.5, 0.25)),
        };
        let back = NaturalGaussian::from_moments(&g)
            .unwrap()
            .to_moments()
            .unwrap();
        assert!((back.mean - g.mean).norm() < 1e-12);
        assert!((back.cov - g.cov).norm() < 1e-12);
    }
}
