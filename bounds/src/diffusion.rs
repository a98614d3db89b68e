//! The random-exchange paper's PCRLB for the random-exchange diffusion filter (RndEx-PF,
//! §III), and the centralized PCRLB it is compared with.
//!
//! Under random exchange, node r's posterior at step n is the one its
//! exchange partner held at n − 1, updated with every measurement of r's
//! closed neighbourhood N\[r\]. Followed back in time, a posterior walks a
//! random path through the network, and conditioned on that path its Fisher
//! information obeys Tichavsky's recursion (eq. 4) with
//! `D22 = Q⁻¹ + Σ_{ℓ∈N[r_n]} E J_ℓ(x_n)` (eq. 7). The path-free bound of
//! node r is `J*_{n,r} = E_paths J_{n,r}` (eq. 15), a Monte Carlo average
//! over N_f path realizations (eq. 16).
//!
//! The expectations `E J_ℓ(x_n)` do not depend on the path: they are taken
//! once per step over N_T trajectories drawn from the prior and the
//! dynamics (eq. 13). The paper draws a fresh set of trajectories at every
//! step; one set carried forward is the same expectation, and what
//! Tichavsky's own Monte Carlo does.
//!
//! Each of the N_f realizations draws one random matching per step for the
//! whole network ([`random_matching`], the protocol cqnet's nodes run), so
//! one realization yields a path for every node at once.

use rand::seq::IndexedRandom;
use rand::Rng;

use crate::dynamics::Dynamics;
use crate::pcrlb::{
    dynamics_terms, information_update, observation_information, position_bound, prior_draws,
    SensorTerm,
};
use crate::{BoundError, Mat4, State};

/// How many trajectories and paths the Monte Carlo averages use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MonteCarloSize {
    /// N_T: trajectories for the expectations of eqs. 11–13.
    pub trajectories: usize,
    /// N_f: path realizations averaged in eq. 16.
    pub paths: usize,
}

/// The bounds of the random-exchange paper's Fig. 1, step by step from 0 to `steps`.
#[derive(Debug, Clone, PartialEq)]
pub struct DiffusionBounds {
    /// `J*_{n,r}` for each step n and node r.
    pub rndex: Vec<Vec<Mat4>>,
    /// `E_paths tr_pos(J_{n,r}⁻¹)`: the bound of each path averaged, rather
    /// than its information. By Jensen's inequality it is at least
    /// `tr_pos(J*⁻¹)`; the gap is what averaging Fisher matrices over paths
    /// (eq. 15) gives away.
    pub rndex_path_traces: Vec<Vec<f64>>,
    /// The centralized filter's information, every sensor at every step.
    pub centralized: Vec<Mat4>,
}

impl DiffusionBounds {
    /// The paper's Fig. 1 curve: `sqrt(mean_r tr_pos (J*_{n,r})⁻¹)`, metres.
    pub fn rndex_position_bound(&self, step: usize) -> Option<f64> {
        let nodes = &self.rndex[step];
        let mut total = 0.0;
        for j in nodes {
            total += position_bound(j)?.powi(2);
        }
        Some((total / nodes.len() as f64).sqrt())
    }

    /// `sqrt(mean_r E_paths tr_pos J_{n,r}⁻¹)`, metres: the paths' bounds
    /// averaged (see [`DiffusionBounds::rndex_path_traces`]).
    pub fn rndex_path_averaged_bound(&self, step: usize) -> Option<f64> {
        let traces = &self.rndex_path_traces[step];
        let mean = traces.iter().sum::<f64>() / traces.len() as f64;
        mean.is_finite().then(|| mean.sqrt())
    }

    /// `sqrt(tr_pos J_c⁻¹)`, metres.
    pub fn centralized_position_bound(&self, step: usize) -> Option<f64> {
        position_bound(&self.centralized[step])
    }
}

/// Attempts a node makes to find a partner in one step.
pub const EXCHANGE_ATTEMPTS: u32 = 3;

/// One step's matching of random exchange: in each of
/// [`EXCHANGE_ATTEMPTS`] attempts every node not yet paired flips a coin;
/// a requester asks one neighbour it has not asked, chosen uniformly; a
/// listener takes one of the requests it got, chosen uniformly, and
/// refuses the rest. `partner[r]` is the node whose posterior r continues
/// from (r itself when it stayed unpaired). cqnet's nodes draw this very
/// matching, alike, from the network's stream of the step
/// (`node::fusion::RandomExchange`), so the protocol's pairs and the RndEx
/// PCRLB's path model are one law.
pub fn random_matching<R: Rng + ?Sized>(neighbours: &[Vec<usize>], rng: &mut R) -> Vec<usize> {
    let n = neighbours.len();
    let mut partner: Vec<usize> = (0..n).collect();
    let mut paired = vec![false; n];
    let mut asked: Vec<Vec<usize>> = vec![Vec::new(); n];
    let mut requests: Vec<Vec<usize>> = vec![Vec::new(); n];
    let mut requester = vec![false; n];
    let mut untried = Vec::new();
    for _ in 0..EXCHANGE_ATTEMPTS {
        requests.iter_mut().for_each(Vec::clear);
        for r in 0..n {
            requester[r] = !paired[r] && rng.random::<bool>();
        }
        for r in (0..n).filter(|&r| requester[r]) {
            untried.clear();
            untried.extend(
                neighbours[r]
                    .iter()
                    .copied()
                    .filter(|l| *l != r && !asked[r].contains(l)),
            );
            if let Some(&l) = untried.choose(rng) {
                asked[r].push(l);
                requests[l].push(r);
            }
        }
        for l in 0..n {
            if paired[l] || requester[l] {
                continue;
            }
            if let Some(&r) = requests[l].choose(rng) {
                partner[l] = r;
                partner[r] = l;
                paired[l] = true;
                paired[r] = true;
            }
        }
    }
    partner
}

/// The random-exchange paper's two bounds. `sensors[r]` is the sensor co-located with node
/// r; `neighbours[r]` are r's neighbours in the network graph (r itself
/// excluded), so that its closed neighbourhood is `{r} ∪ neighbours[r]`.
#[allow(clippy::too_many_arguments)]
pub fn diffusion_bounds<R: Rng + ?Sized>(
    dynamics: &Dynamics,
    sensors: &[SensorTerm<'_>],
    neighbours: &[Vec<usize>],
    prior_mean: &State,
    prior_cov: &Mat4,
    steps: usize,
    size: MonteCarloSize,
    rng: &mut R,
) -> Result<DiffusionBounds, BoundError> {
    if size.trajectories == 0 || size.paths == 0 {
        return Err(BoundError::NoParticles);
    }
    if sensors.len() != neighbours.len() {
        return Err(BoundError::NeighbourhoodCount {
            sensors: sensors.len(),
            nodes: neighbours.len(),
        });
    }
    let prior =
        nalgebra::Cholesky::new(*prior_cov).ok_or(BoundError::NotPositiveDefinite("P_0"))?;
    let expectations = expectations(
        dynamics,
        sensors,
        neighbours,
        prior_mean,
        &prior,
        steps,
        size.trajectories,
        rng,
    )?;
    let j0 = prior.inverse();

    let mut centralized = vec![j0];
    for e in &expectations {
        let last = centralized.last().expect("starts with J_0");
        centralized.push(information_update(last, &e.terms, dynamics.q_inv(), &e.all)?.updated);
    }

    let nodes = sensors.len();
    let mut sums = vec![vec![Mat4::zeros(); nodes]; steps + 1];
    let mut traces = vec![vec![0.0; nodes]; steps + 1];
    let trace = |j: &Mat4| position_bound(j).map_or(f64::INFINITY, |b| b * b);
    let mut current = vec![j0; nodes];
    let mut next = vec![Mat4::zeros(); nodes];
    for _ in 0..size.paths {
        current.fill(j0);
        sums[0].iter_mut().for_each(|s| *s += j0);
        traces[0].iter_mut().for_each(|t| *t += trace(&j0));
        let per_step = expectations.iter().zip(sums.iter_mut().skip(1));
        for ((e, sum), tr) in per_step.zip(traces.iter_mut().skip(1)) {
            let partner = random_matching(neighbours, rng);
            for r in 0..nodes {
                let from = &current[partner[r]];
                next[r] =
                    information_update(from, &e.terms, dynamics.q_inv(), &e.closed[r])?.updated;
                sum[r] += next[r];
                tr[r] += trace(&next[r]);
            }
            std::mem::swap(&mut current, &mut next);
        }
    }
    let scale = 1.0 / size.paths as f64;
    let rndex = sums
        .into_iter()
        .map(|step| step.into_iter().map(|j| j * scale).collect())
        .collect();
    let rndex_path_traces = traces
        .into_iter()
        .map(|step| step.into_iter().map(|t| t * scale).collect())
        .collect();
    Ok(DiffusionBounds {
        rndex,
        rndex_path_traces,
        centralized,
    })
}

/// What every path shares at one step: the dynamics terms, the expected
/// information of each closed neighbourhood, and of the whole network.
struct StepExpectations {
    terms: crate::pcrlb::DynamicsTerms,
    closed: Vec<Mat4>,
    all: Mat4,
}

#[allow(clippy::too_many_arguments)]
fn expectations<R: Rng + ?Sized>(
    dynamics: &Dynamics,
    sensors: &[SensorTerm<'_>],
    neighbours: &[Vec<usize>],
    prior_mean: &State,
    prior: &nalgebra::Cholesky<f64, nalgebra::U4>,
    steps: usize,
    trajectories: usize,
    rng: &mut R,
) -> Result<Vec<StepExpectations>, BoundError> {
    let mut states = prior_draws(prior_mean, prior, trajectories, rng);
    let weights = vec![1.0 / trajectories as f64; trajectories];
    let mut out = Vec::with_capacity(steps);
    for _ in 0..steps {
        let terms = dynamics_terms(dynamics, &states, &weights)?;
        for x in states.iter_mut() {
            *x = dynamics.propagate(x, rng);
        }
        let per_sensor = sensors
            .iter()
            .map(|s| observation_information(std::slice::from_ref(s), &states, &weights))
            .collect::<Result<Vec<_>, _>>()?;
        let closed = neighbours
            .iter()
            .enumerate()
            .map(|(r, ns)| {
                per_sensor[r]
                    + ns.iter()
                        .filter(|&&l| l != r)
                        .map(|&l| per_sensor[l])
                        .sum::<Mat4>()
            })
            .collect();
        let all = per_sensor.iter().sum();
        out.push(StepExpectations { terms, closed, all });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::CoordinatedTurn;
    use crate::fisher::Measurement;
    use crate::observation::{ObservationModel, SensorLaw};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn dynamics() -> Dynamics {
        Dynamics::new(CoordinatedTurn::constant_velocity(1.0, 0.05)).unwrap()
    }

    fn prior() -> (State, Mat4) {
        (
            State::new(50.0, 50.0, 0.0, 0.0),
            Mat4::from_diagonal(&State::new(25.0, 25.0, 0.0025, 0.0025)),
        )
    }

    /// A 5 × 5 lattice, 20 m apart, each node its four nearest neighbours.
    fn lattice() -> (Vec<ObservationModel>, Vec<Vec<usize>>) {
        let law = SensorLaw::Rss {
            p0: -30.0,
            zeta: 3.0,
            d0: 1.0,
            sigma: 4.0,
            near_field: None,
        };
        let mut models = Vec::new();
        let mut neighbours = Vec::new();
        for i in 0..5usize {
            for j in 0..5usize {
                models.push(law.at([10.0 + 20.0 * j as f64, 10.0 + 20.0 * i as f64]));
                let mut ns = Vec::new();
                if i > 0 {
                    ns.push((i - 1) * 5 + j);
                }
                if i < 4 {
                    ns.push((i + 1) * 5 + j);
                }
                if j > 0 {
                    ns.push(i * 5 + j - 1);
                }
                if j < 4 {
                    ns.push(i * 5 + j + 1);
                }
                neighbours.push(ns);
            }
        }
        (models, neighbours)
    }

    fn raw(models: &[ObservationModel]) -> Vec<SensorTerm<'_>> {
        models
            .iter()
            .map(|m| SensorTerm {
                model: m,
                measurement: Measurement::Raw,
            })
            .collect()
    }

    const SMALL: MonteCarloSize = MonteCarloSize {
        trajectories: 300,
        paths: 200,
    };

    #[test]
    fn a_matching_pairs_neighbours_both_ways_or_leaves_a_node_alone() {
        let (_, neighbours) = lattice();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut paired = 0;
        for _ in 0..2000 {
            let partner = random_matching(&neighbours, &mut rng);
            for (r, &p) in partner.iter().enumerate() {
                assert_eq!(partner[p], r, "{partner:?}");
                assert!(p == r || neighbours[r].contains(&p));
                paired += usize::from(p != r);
            }
        }
        // On a 5 × 5 lattice three attempts pair most nodes.
        let share = paired as f64 / (2000.0 * 25.0);
        assert!(share > 0.5 && share < 1.0, "{share}");
    }

    /// When every node hears every sensor, every path sees the same
    /// measurements: the diffusion bound is the centralized one.
    #[test]
    fn a_complete_graph_gives_the_centralized_bound() {
        let (models, _) = lattice();
        let complete: Vec<Vec<usize>> = (0..25)
            .map(|r| (0..25).filter(|&l| l != r).collect())
            .collect();
        let (mean, cov) = prior();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let b = diffusion_bounds(
            &dynamics(),
            &raw(&models),
            &complete,
            &mean,
            &cov,
            30,
            SMALL,
            &mut rng,
        )
        .unwrap();
        for n in 0..=30 {
            for j in &b.rndex[n] {
                let err = (j - b.centralized[n]).abs().max() / b.centralized[n].abs().max();
                assert!(err < 1e-12, "step {n}: {err}");
            }
        }
    }

    /// The linear-Gaussian limit: with no edges each node keeps its own
    /// posterior, and a linear sensor's bound is the Kalman filter's
    /// information, whatever the trajectories.
    #[test]
    fn isolated_nodes_with_linear_sensors_give_the_kalman_information() {
        let law = SensorLaw::Linear {
            h: [1.0, 0.0, 0.0, 0.0],
            r: 4.0,
        };
        let models = [law.at([0.0, 0.0]), law.at([0.0, 0.0])];
        let law_y = SensorLaw::Linear {
            h: [0.0, 1.0, 0.0, 0.0],
            r: 9.0,
        };
        let models = [models[0].clone(), law_y.at([0.0, 0.0])];
        let isolated = vec![vec![], vec![]];
        let (mean, cov) = prior();
        let d = dynamics();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let b = diffusion_bounds(
            &d,
            &raw(&models),
            &isolated,
            &mean,
            &cov,
            40,
            SMALL,
            &mut rng,
        )
        .unwrap();
        let f = d.jacobian(&mean);
        for (node, (h, r)) in [
            (State::new(1.0, 0.0, 0.0, 0.0), 4.0),
            (State::new(0.0, 1.0, 0.0, 0.0), 9.0),
        ]
        .into_iter()
        .enumerate()
        {
            let mut j = cov.try_inverse().unwrap();
            for n in 1..=40 {
                let p = f * j.try_inverse().unwrap() * f.transpose() + d.q();
                j = p.try_inverse().unwrap() + h * h.transpose() / r;
                let err = (b.rndex[n][node] - j).abs().max() / j.abs().max();
                assert!(err < 1e-8, "node {node} step {n}: {err}");
            }
        }
        // And the centralized bound has both sensors.
        assert!(b.centralized_position_bound(40).unwrap() < b.rndex_position_bound(40).unwrap());
    }

    /// The random-exchange paper's Fig. 1 ordering: the centralized bound below the RndEx
    /// bound, which is below a node that never exchanges, for RSS sensors.
    #[test]
    fn diffusion_sits_between_the_centralized_and_the_lone_node() {
        let (models, neighbours) = lattice();
        let (mean, cov) = prior();
        let d = dynamics();
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let b = diffusion_bounds(
            &d,
            &raw(&models),
            &neighbours,
            &mean,
            &cov,
            50,
            SMALL,
            &mut rng,
        )
        .unwrap();
        let alone: Vec<Vec<usize>> = neighbours.iter().map(|_| Vec::new()).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let lone =
            diffusion_bounds(&d, &raw(&models), &alone, &mean, &cov, 50, SMALL, &mut rng).unwrap();
        for n in [10, 25, 50] {
            let (c, r, l) = (
                b.centralized_position_bound(n).unwrap(),
                b.rndex_position_bound(n).unwrap(),
                lone.rndex_position_bound(n).unwrap(),
            );
            assert!(
                c < r && r < l,
                "step {n}: centralized {c}, rndex {r}, alone {l}"
            );
        }
    }

    /// The path average converges: 200 and 1000 paths agree closely.
    #[test]
    fn the_bound_settles_as_paths_grow() {
        let (models, neighbours) = lattice();
        let (mean, cov) = prior();
        let d = dynamics();
        let run = |paths| {
            let mut rng = ChaCha8Rng::seed_from_u64(5);
            let size = MonteCarloSize {
                trajectories: 300,
                paths,
            };
            diffusion_bounds(
                &d,
                &raw(&models),
                &neighbours,
                &mean,
                &cov,
                30,
                size,
                &mut rng,
            )
            .unwrap()
            .rndex_position_bound(30)
            .unwrap()
        };
        let (few, many) = (run(200), run(1000));
        assert!((few / many - 1.0).abs() < 0.01, "{few} vs {many}");
    }

    /// Averaging the paths' bounds rather than their information (the
    /// Jensen gap): never below eq. 16's bound, node by node, and equal to
    /// it when every path is the same (a complete graph).
    #[test]
    fn the_paths_averaged_bound_is_at_least_the_averaged_informations() {
        let (models, neighbours) = lattice();
        let complete: Vec<Vec<usize>> = (0..25)
            .map(|r| (0..25).filter(|&l| l != r).collect())
            .collect();
        let (mean, cov) = prior();
        for (graph, equal) in [(&neighbours, false), (&complete, true)] {
            let mut rng = ChaCha8Rng::seed_from_u64(8);
            let b = diffusion_bounds(
                &dynamics(),
                &raw(&models),
                graph,
                &mean,
                &cov,
                20,
                SMALL,
                &mut rng,
            )
            .unwrap();
            let mut gap = 0.0_f64;
            for n in 0..=20 {
                for (j, t) in b.rndex[n].iter().zip(&b.rndex_path_traces[n]) {
                    let of_mean = position_bound(j).unwrap().powi(2);
                    assert!(*t >= of_mean * (1.0 - 1e-9), "step {n}: {t} < {of_mean}");
                    gap = gap.max(t / of_mean - 1.0);
                }
            }
            let averaged = b.rndex_path_averaged_bound(20).unwrap();
            let of_mean = b.rndex_position_bound(20).unwrap();
            if equal {
                assert!(gap < 1e-9, "{gap}");
            } else {
                assert!(gap > 1e-6 && averaged > of_mean, "{gap}");
            }
        }
    }

    #[test]
    fn empty_monte_carlo_is_an_error() {
        let (models, neighbours) = lattice();
        let (mean, cov) = prior();
        let size = MonteCarloSize {
            trajectories: 0,
            paths: 10,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        assert!(diffusion_bounds(
            &dynamics(),
            &raw(&models),
            &neighbours,
            &mean,
            &cov,
            5,
            size,
            &mut rng
        )
        .is_err());
    }
}
