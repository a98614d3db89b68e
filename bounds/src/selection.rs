//! PCRLB-driven sensor selection (the selection paper §4; docs/equations.md, "PCRLB sensor
//! selection"): the cost of a set of active sensors and the greedy choice,
//! as pure functions.
//!
//! The cost of a set A is the position trace of the bound it would give,
//!
//! ```text
//! C(A) = tr_pos[(L(k+1|k) + Σ_{s∈A} J̄_s)⁻¹],
//! ```
//!
//! with `L(k+1|k) = Q⁻¹ − D21 (L_G(k) + D11)⁻¹ D12` the predicted global
//! information and `J̄_s` sensor s's expected information over the
//! predicted particles (the conditional manager) or at the predicted
//! estimate (the non-conditional one). [`greedy`] is what the distributed
//! selection runs, once, at the root of its spanning tree.

use std::cmp::Ordering;

use nalgebra::Cholesky;

use crate::Mat4;

/// `C(A ∪ {candidate})`: the position trace of `(predicted + chosen +
/// candidate)⁻¹`, where `chosen` is `Σ_{s∈A} J̄_s`. `None` if the sum is not
/// positive definite.
pub fn selection_cost(predicted: &Mat4, chosen: &Mat4, candidate: &Mat4) -> Option<f64> {
    let total = predicted + chosen + candidate;
    let cov = Cholesky::new((total + total.transpose()) * 0.5)?.inverse();
    let trace = cov[(0, 0)] + cov[(1, 1)];
    trace.is_finite().then_some(trace)
}

/// One sensor a node could activate, with its expected information.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub node: u16,
    pub sensor: u16,
    pub information: Mat4,
}

/// The order of (cost, node, sensor) proposals: lower cost first, then the
/// smaller node, then the smaller sensor (docs/equations.md's tie-break), so
/// that the choice does not depend on the order the candidates came in.
pub fn proposal_order(a: (f64, u16, u16), b: (f64, u16, u16)) -> Ordering {
    a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2)))
}

/// Greedy selection: one sensor per iteration, the candidate of least
/// [`selection_cost`] given those already chosen, until `n_max` are chosen
/// or no node has room under its cap `per_node_cap`. Returns the chosen
/// (node, sensor) pairs in the order chosen.
pub fn greedy(
    predicted: &Mat4,
    candidates: &[Candidate],
    per_node_cap: usize,
    n_max: usize,
) -> Vec<(u16, u16)> {
    let mut chosen: Vec<(u16, u16)> = Vec::new();
    let mut taken = vec![false; candidates.len()];
    let mut sum = Mat4::zeros();
    while chosen.len() < n_max {
        let count = |node: u16| chosen.iter().filter(|(n, _)| *n == node).count();
        let mut best: Option<(f64, u16, u16, usize)> = None;
        for (i, c) in candidates.iter().enumerate() {
            if taken[i] || count(c.node) >= per_node_cap {
                continue;
            }
            let Some(cost) = selection_cost(predicted, &sum, &c.information) else {
                continue;
            };
            let proposal = (cost, c.node, c.sensor);
            if best.is_none_or(|b| proposal_order(proposal, (b.0, b.1, b.2)) == Ordering::Less) {
                best = Some((cost, c.node, c.sensor, i));
            }
        }
        let Some((_, node, sensor, i)) = best else {
            break;
        };
        taken[i] = true;
        sum += candidates[i].information;
        chosen.push((node, sensor));
    }
    chosen
}

/// The offline schedule of the conventional (non-conditional) PCRLB
/// manager: the greedy choice at every step on Tichavsky's bound, its
/// expectations taken over `trajectories` drawn from the prior
/// `N(prior_mean, prior_cov)` and the dynamics, so it uses no data and
/// every node computes the same schedule before the run. At step k the
/// predicted information is `J(k|k−1)` and each candidate's `J̄_s` is its
/// expected information over the trajectories' x(k); the chosen sensors'
/// information then advances `J`. `candidates[i] = (node, sensor, term)`.
/// Returns, for steps 1..=`steps`, the (node, sensor) pairs chosen.
#[allow(clippy::too_many_arguments)]
pub fn offline_schedule<R: rand::Rng + ?Sized>(
    dynamics: &crate::Dynamics,
    candidates: &[(u16, u16, crate::SensorTerm<'_>)],
    prior_mean: &crate::State,
    prior_cov: &Mat4,
    steps: usize,
    trajectories: usize,
    per_node_cap: usize,
    n_max: usize,
    rng: &mut R,
) -> Result<Vec<Vec<(u16, u16)>>, crate::BoundError> {
    use crate::pcrlb::{dynamics_terms, information_update, observation_information, prior_draws};
    let chol = Cholesky::new(*prior_cov).ok_or(crate::BoundError::NotPositiveDefinite("P_0"))?;
    let mut states = prior_draws(prior_mean, &chol, trajectories, rng);
    let weights = vec![1.0 / trajectories as f64; trajectories];
    let mut information = chol.inverse();
    let mut schedule = Vec::with_capacity(steps);
    let mut scored: Vec<Candidate> = Vec::with_capacity(candidates.len());
    for _ in 0..steps {
        let terms = dynamics_terms(dynamics, &states, &weights)?;
        for x in states.iter_mut() {
            *x = dynamics.propagate(x, rng);
        }
        scored.clear();
        for (node, sensor, term) in candidates {
            scored.push(Candidate {
                node: *node,
                sensor: *sensor,
                information: observation_information(
                    std::slice::from_ref(term),
                    &states,
                    &weights,
                )?,
            });
        }
        let zero = Mat4::zeros();
        let predicted =
            information_update(&information, &terms, dynamics.q_inv(), &zero)?.predicted;
        let chosen = greedy(&predicted, &scored, per_node_cap, n_max);
        let gained: Mat4 = scored
            .iter()
            .filter(|c| chosen.contains(&(c.node, c.sensor)))
            .map(|c| c.information)
            .sum();
        information = predicted + gained;
        schedule.push(chosen);
    }
    Ok(schedule)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fisher::{expected_information, Measurement};
    use crate::observation::SensorLaw;
    use crate::quantizer::Quantizer;
    use crate::State;
    use std::f64::consts::PI;

    fn prior() -> Mat4 {
        Mat4::from_diagonal(&State::new(1.0 / 25.0, 1.0 / 25.0, 0.25, 0.25))
    }

    fn position_info(xx: f64, yy: f64) -> Mat4 {
        Mat4::from_diagonal(&State::new(xx, yy, 0.0, 0.0))
    }

    /// Linear position measurements: the information adds, and the cost is
    /// the closed form `1/(a + x) + 1/(b + y)`.
    #[test]
    fn cost_is_the_closed_form_for_linear_sensors() {
        let cost =
            selection_cost(&prior(), &position_info(0.5, 0.0), &position_info(0.0, 2.0)).unwrap();
        let expected = 1.0 / (0.04 + 0.5) + 1.0 / (0.04 + 2.0);
        assert!((cost - expected).abs() < 1e-12, "{cost} vs {expected}");
        assert!(selection_cost(&Mat4::zeros(), &Mat4::zeros(), &Mat4::zeros()).is_none());
    }

    #[test]
    fn greedy_respects_the_caps_and_never_picks_twice() {
        // 4 nodes × 5 sensors, information growing with the sensor id.
        let candidates: Vec<Candidate> = (0..4u16)
            .flat_map(|node| {
                (0..5u16).map(move |s| Candidate {
                    node,
                    sensor: node * 5 + s,
                    information: position_info(0.1 * (s + 1) as f64, 0.05 * (node + 1) as f64),
                })
            })
            .collect();
        for (cap, n_max) in [(2, 6), (3, 20), (1, 3), (5, 0)] {
            let chosen = greedy(&prior(), &candidates, cap, n_max);
            assert_eq!(chosen.len(), n_max.min(4 * cap), "cap {cap}, n_max {n_max}");
            for node in 0..4 {
                assert!(chosen.iter().filter(|(n, _)| *n == node).count() <= cap);
            }
            let mut sensors: Vec<u16> = chosen.iter().map(|c| c.1).collect();
            sensors.sort_unstable();
            sensors.dedup();
            assert_eq!(sensors.len(), chosen.len(), "a sensor chosen twice");
            assert!(
                chosen.iter().all(|(n, s)| s / 5 == *n),
                "a sensor of another node"
            );
        }
    }

    /// Each iteration takes the candidate that lowers the cost most: with
    /// diminishing returns on one axis, the second pick goes to the other.
    #[test]
    fn greedy_balances_the_axes() {
        let candidates = [
            Candidate {
                node: 0,
                sensor: 0,
                information: position_info(10.0, 0.0),
            },
            Candidate {
                node: 0,
                sensor: 1,
                information: position_info(9.0, 0.0),
            },
            Candidate {
                node: 1,
                sensor: 2,
                information: position_info(0.0, 2.0),
            },
        ];
        assert_eq!(greedy(&prior(), &candidates, 2, 2), vec![(0, 0), (1, 2)]);
    }

    #[test]
    fn ties_go_to_the_smaller_node_then_the_smaller_sensor() {
        let same = position_info(1.0, 1.0);
        let candidates = [
            Candidate {
                node: 2,
                sensor: 9,
                information: same,
            },
            Candidate {
                node: 1,
                sensor: 7,
                information: same,
            },
            Candidate {
                node: 1,
                sensor: 4,
                information: same,
            },
        ];
        assert_eq!(greedy(&prior(), &candidates, 1, 1), vec![(1, 4)]);
        let better = |a, b| proposal_order(a, b) == Ordering::Less;
        assert!(better((1.0, 1, 4), (1.0, 1, 7)) && better((1.0, 1, 7), (1.0, 2, 0)));
        assert!(better((0.5, 9, 9), (1.0, 0, 0)));
    }

    /// A bearing sensor 5 m from the target is far more informative than
    /// sensors hundreds of metres away (J ∝ 1/(d² R(d))): it is chosen first.
    #[test]
    fn the_sensor_beside_the_target_is_chosen_first() {
        let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
        let target = State::new(500.0, 500.0, 5.0, -3.0);
        let sites = [
            [800.0, 200.0],
            [150.0, 450.0],
            [503.0, 504.0],
            [900.0, 900.0],
            [300.0, 700.0],
        ];
        let models: Vec<_> = sites
            .iter()
            .map(|p| {
                SensorLaw::Bearing {
                    sigma_theta: 0.02,
                    d0: 500.0,
                    near_field: None,
                }
                .at(*p)
            })
            .collect();
        let candidates: Vec<Candidate> = models
            .iter()
            .enumerate()
            .map(|(i, m)| Candidate {
                node: i as u16 % 2,
                sensor: i as u16,
                information: expected_information(m, Measurement::Quantized(&q), &target),
            })
            .collect();
        let chosen = greedy(&prior(), &candidates, 3, 3);
        assert_eq!(chosen[0], (0, 2), "{chosen:?}");
    }

    /// The offline schedule on linear sensors: the expectations are exact,
    /// so each step's choice is the greedy one on the Kalman filter's
    /// predicted information, which the chosen sensors then update; the
    /// caps hold at every step.
    #[test]
    fn the_offline_schedule_is_greedy_on_the_kalman_recursion() {
        use crate::dynamics::{CoordinatedTurn, Dynamics};
        use crate::pcrlb::SensorTerm;
        use rand::SeedableRng;
        let dynamics = Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.5)).unwrap();
        let laws = [
            (0, [1.0, 0.0, 0.0, 0.0], 1.0),
            (0, [0.0, 1.0, 0.0, 0.0], 4.0),
            (1, [1.0, 0.0, 0.0, 0.0], 2.0),
            (1, [0.0, 1.0, 0.0, 0.0], 1.5),
            (2, [0.7, 0.7, 0.0, 0.0], 0.5),
        ];
        let models: Vec<_> = laws
            .iter()
            .map(|(_, h, r)| SensorLaw::Linear { h: *h, r: *r }.at([0.0, 0.0]))
            .collect();
        let candidates: Vec<(u16, u16, SensorTerm)> = laws
            .iter()
            .zip(&models)
            .enumerate()
            .map(|(i, ((node, _, _), model))| {
                (
                    *node as u16,
                    i as u16,
                    SensorTerm {
                        model,
                        measurement: Measurement::Raw,
                    },
                )
            })
            .collect();
        let prior_cov = Mat4::from_diagonal(&State::new(100.0, 100.0, 4.0, 4.0));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let schedule = offline_schedule(
            &dynamics,
            &candidates,
            &State::new(0.0, 0.0, 1.0, 1.0),
            &prior_cov,
            12,
            50,
            1,
            2,
            &mut rng,
        )
        .unwrap();
        let f = dynamics.jacobian(&State::zeros());
        let info = |i: usize| {
            let (_, h, r) = laws[i];
            let h = State::from(h);
            h * h.transpose() / r
        };
        let mut j = prior_cov.try_inverse().unwrap();
        for chosen in &schedule {
            let predicted = (f * j.try_inverse().unwrap() * f.transpose() + dynamics.q())
                .try_inverse()
                .unwrap();
            let all: Vec<Candidate> = laws
                .iter()
                .enumerate()
                .map(|(i, (node, _, _))| Candidate {
                    node: *node as u16,
                    sensor: i as u16,
                    information: info(i),
                })
                .collect();
            assert_eq!(chosen, &greedy(&predicted, &all, 1, 2));
            assert_eq!(chosen.len(), 2);
            assert_ne!(chosen[0].0, chosen[1].0, "one per node");
            j = predicted + chosen.iter().map(|(_, s)| info(*s as usize)).sum::<Mat4>();
        }
    }
}
