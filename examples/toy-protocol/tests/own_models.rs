//! The range-only sensor and the Ornstein–Uhlenbeck motion model, parts of
//! this crate's program only: their bound against one computed without
//! cqnet's arithmetic, and a network that uses them, in one process
//! (`sim`) and as real processes (`run --lockstep`).

use bounds::dynamics::{DifferentiableMotion, Dynamics, MotionModel};
use bounds::observation::check_gradients;
use bounds::pcrlb::{dynamics_terms, observation_information, SensorTerm};
use bounds::{ConditionalBound, Law, Mat4, Measurement, Quantizer, State};
use cqnet_testkit::{default_scenario, Network, Scenario, Vocabulary};
use fusion_graph::params::Params;
use rand::{Rng, SeedableRng};
use toy_protocol::OrnsteinUhlenbeck;

const SIGMA: f64 = 5.0;
const D0: f64 = 1000.0;
const HEIGHT: f64 = 1.0;
const BITS: u8 = 8;
const LO: f64 = 0.0;
const HI: f64 = 2200.0;

fn vocabulary() -> Vocabulary {
    toy_protocol::app()
        .vocabulary()
        .expect("the toy parts list")
}

/// The law as the program builds it from a scenario's table.
fn range_law() -> Law {
    let table: toml::Table = toml::from_str(&format!("sigma = {SIGMA}\nd0 = {D0}")).unwrap();
    let part = vocabulary()
        .law("range")
        .expect("the program lists `range`");
    part.build
        .build(&Params::new("observation", &table))
        .unwrap()
}

fn ou() -> OrnsteinUhlenbeck {
    OrnsteinUhlenbeck {
        period: 1.0,
        tau: 30.0,
        sigma: 0.05,
    }
}

/// The range law written out in plain arithmetic, apart from the crate's.
fn g_and_r(sensor: [f64; 2], x: &State) -> (f64, f64) {
    let d2 = (x[0] - sensor[0]).powi(2) + (x[1] - sensor[1]).powi(2);
    (
        (d2 + HEIGHT * HEIGHT).sqrt(),
        SIGMA * SIGMA * (1.0 + d2 / (D0 * D0)),
    )
}

/// The OU transition written out.
fn f(x: &State) -> State {
    let a = (-1.0f64 / 30.0).exp();
    let c = 30.0 * (1.0 - a);
    State::new(x[0] + c * x[2], x[1] + c * x[3], a * x[2], a * x[3])
}

/// `Φ(b) − Φ(a)` of the standard normal.
fn mass(a: f64, b: f64) -> f64 {
    let phi = |t: f64| 0.5 * libm::erfc(-t / std::f64::consts::SQRT_2);
    if a > 0.0 {
        // Upper tail: the difference of two small complements keeps its digits.
        phi(-a) - phi(-b)
    } else {
        phi(b) - phi(a)
    }
}

/// The quantized observation's Fisher information at x, from first
/// principles: `Σ_cells ∇P ∇Pᵀ / P`, with the cells' probabilities from
/// the written-out law and their gradients by central differences.
fn quantized_information(sensor: [f64; 2], x: &State) -> Mat4 {
    let cells = 1usize << BITS;
    let width = (HI - LO) / cells as f64;
    let edge = |i: usize| match i {
        0 => f64::NEG_INFINITY,
        i if i == cells => f64::INFINITY,
        i => LO + i as f64 * width,
    };
    let probability = |y: &State, i: usize| {
        let (g, r) = g_and_r(sensor, y);
        let s = r.sqrt();
        mass((edge(i) - g) / s, (edge(i + 1) - g) / s)
    };
    let mut j = Mat4::zeros();
    for i in 0..cells {
        let p = probability(x, i);
        if p < 1e-200 {
            continue;
        }
        let mut grad = State::zeros();
        for k in 0..2 {
            let h = 1e-3;
            let (mut up, mut down) = (*x, *x);
            up[k] += h;
            down[k] -= h;
            grad[k] = (probability(&up, i) - probability(&down, i)) / (2.0 * h);
        }
        j += grad * grad.transpose() / p;
    }
    j
}

fn central_jacobian(x: &State) -> Mat4 {
    let mut jac = Mat4::zeros();
    for k in 0..4 {
        let h = 1e-5 * x[k].abs().max(1.0);
        let (mut up, mut down) = (*x, *x);
        up[k] += h;
        down[k] -= h;
        jac.set_column(k, &((f(&up) - f(&down)) / (2.0 * h)));
    }
    jac
}

fn relative_error(a: &Mat4, b: &Mat4) -> f64 {
    (a - b).abs().max() / b.abs().max()
}

/// The law's automatic gradients and the model's automatic Jacobian
/// agree with central differences, near the sensor and far from it.
#[test]
fn the_automatic_gradients_agree_with_central_differences() {
    let law = range_law();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let sensor = [700.0, 300.0];
    let states: Vec<State> = (0..500)
        .map(|i| {
            let scale = if i < 100 { 3.0 } else { 1500.0 };
            State::new(
                sensor[0] + scale * rng.random_range(-1.0..1.0),
                sensor[1] + scale * rng.random_range(-1.0..1.0),
                rng.random_range(-9.0..9.0),
                rng.random_range(-9.0..9.0),
            )
        })
        .collect();
    check_gradients(&law, sensor, &states).unwrap();
    let model = bounds::dynamics::AutodiffMotion(ou());
    for x in &states {
        let (next, jac) = model.transition_and_jacobian(x);
        assert!((next - f(x)).abs().max() < 1e-9);
        assert!(
            relative_error(&jac, &central_jacobian(x)) < 1e-7,
            "{jac} at {x:?}"
        );
    }
}

/// One step of the conditional bound under the range law and the OU model,
/// by cqnet (its quantized Fisher information through the automatic
/// gradients, its B terms through the automatic Jacobian) and from first
/// principles (`J⁺ = D22 − D21 (J + D11)⁻¹ D12`, every expectation a sum
/// over the same particles, every derivative a central difference).
#[test]
fn the_bound_under_the_range_law_is_the_one_computed_from_first_principles() {
    let law = range_law();
    let q = Quantizer::uniform(BITS, LO, HI).unwrap();
    let dynamics = Dynamics::of(bounds::Motion::new(
        "ornstein_uhlenbeck",
        bounds::dynamics::AutodiffMotion(ou()),
    ))
    .unwrap();
    let sensors = [[250.0, 350.0], [900.0, 150.0], [1200.0, 1100.0]];
    let models: Vec<_> = sensors.iter().map(|s| law.at(*s)).collect();
    let terms: Vec<SensorTerm> = models
        .iter()
        .map(|m| SensorTerm {
            model: m,
            measurement: Measurement::Quantized(&q),
        })
        .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let centre = State::new(800.0, 700.0, -6.0, -4.0);
    let n = 300;
    let posterior: Vec<State> = (0..n)
        .map(|_| {
            centre
                + State::new(
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
        })
        .collect();
    let predicted: Vec<State> = posterior
        .iter()
        .map(|p| dynamics.propagate(p, &mut rng))
        .collect();
    let weights = vec![1.0 / n as f64; n];
    let prior = Mat4::from_diagonal(&State::new(2500.0, 2500.0, 4.0, 4.0));

    let mut bound = ConditionalBound::from_prior(&prior).unwrap();
    let b = dynamics_terms(&dynamics, &posterior, &weights).unwrap();
    let obs = observation_information(&terms, &predicted, &weights).unwrap();
    bound.advance(&b, dynamics.q_inv(), &obs).unwrap();

    let q_inv = DifferentiableMotion::process_noise(&ou())
        .try_inverse()
        .unwrap();
    let (mut d11, mut mean_f, mut j_y) = (Mat4::zeros(), Mat4::zeros(), Mat4::zeros());
    for (x, w) in posterior.iter().zip(&weights) {
        let jac = central_jacobian(x);
        d11 += jac.transpose() * q_inv * jac * *w;
        mean_f += jac * *w;
    }
    for (x, w) in predicted.iter().zip(&weights) {
        for s in &sensors {
            j_y += quantized_information(*s, x) * *w;
        }
    }
    let d12 = -(mean_f.transpose() * q_inv);
    let d22 = q_inv + j_y;
    let j = prior.try_inverse().unwrap();
    let expected = d22 - d12.transpose() * (j + d11).try_inverse().unwrap() * d12;
    assert!(
        relative_error(&obs, &j_y) < 1e-5,
        "J_Y: cqnet {obs}, first principles {j_y}"
    );
    assert!(
        relative_error(bound.information(), &expected) < 1e-5,
        "J(k+1): cqnet {}, first principles {expected}",
        bound.information()
    );
}

fn own_models_network(steps: u32) -> Network {
    let mut scenario = default_scenario();
    scenario.steps = steps;
    Network::new(scenario)
        .executable(env!("CARGO_BIN_EXE_toy-protocol"))
        .parts(vocabulary())
        .set(
            "observation",
            format!("{{ kind = \"range\", sigma = {SIGMA}, d0 = {D0} }}"),
        )
        .set("quantizer.lo", LO)
        .set("quantizer.hi", HI)
        .set(
            "dynamics",
            "{ kind = \"ornstein_uhlenbeck\", period = 1.0, tau = 30.0, sigma = 0.05 }",
        )
        // Generous, so that a loaded machine's scheduling never closes a
        // round before its neighbours' values are in.
        .set("consensus.round_timeout_ms", 500)
        .no_central()
}

/// The network with the range sensors and the OU target, in lockstep, is
/// `sim`, bit for bit.
#[test]
fn a_network_of_range_sensors_runs_in_sim_and_as_processes_alike() {
    let _one_network_at_a_time = cqnet_testkit::exclusive();
    let sim = own_models_network(8).sim().expect("sim starts");
    sim.assert_success();
    let run = own_models_network(8).lockstep().run().expect("run starts");
    run.assert_success();
    run.assert_clean();
    assert!(!sim.ticks().is_empty());
    assert_eq!(run.sorted_tick_lines(), sim.sorted_tick_lines());
}

/// The CF/DPF tracks the OU target with range sensors: over 12 seeds, the
/// fused estimate's RMSE at the centre node over steps 10–40, divided by
/// its mean CQ/dPCRLB, has a 95 % interval within 0.7–1.5: neither below
/// the bound (a bound broken) nor far above it (a filter lost).
#[test]
fn the_filter_tracks_within_the_bounds_interval() {
    const RUNS: u32 = 12;
    let ratios: Vec<f64> = (0..RUNS)
        .map(|seed| {
            let run = own_models_network(40)
                .set("seed", seed + 1)
                .sim()
                .expect("sim starts");
            run.assert_success();
            let rmse = run.node_rmse("node-4", 10..=40);
            let bound = run.mean_bound("node-4", 10..=40).expect("a bound");
            rmse / bound
        })
        .collect();
    let n = f64::from(RUNS);
    let mean = ratios.iter().sum::<f64>() / n;
    let sd = (ratios.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    // Student's t, 11 degrees of freedom, 97.5 %.
    let half = 2.201 * sd / n.sqrt();
    eprintln!("RMSE / bound: {ratios:?}, mean {mean:.3} ± {half:.3}");
    assert!(
        mean - half >= 0.7 && mean + half <= 1.5,
        "RMSE / bound {mean:.3} ± {half:.3} (runs {ratios:?})"
    );
}

/// A bad parameter of the law or the model is refused by its full key,
/// and a kind the program does not have lists those it does.
#[test]
fn a_bad_parameter_of_a_law_or_a_model_is_refused_by_its_full_key() {
    let read = |sets: &[String]| {
        Scenario::from_toml_in(
            vocabulary(),
            fusion_graph::scenario::DEFAULT_SCENARIO,
            "d",
            sets,
        )
        .map(|_| ())
        .map_err(|e| e.to_string())
    };
    let range = |extra: &str| {
        vec![
            format!("observation={{ kind = \"range\", d0 = 1000.0{extra} }}"),
            "quantizer.lo=0".into(),
            "quantizer.hi=2200".into(),
        ]
    };
    read(&range(", sigma = 5.0")).unwrap();
    for (extra, key) in [
        ("", "observation.sigma"),
        (", sigma = -1.0", "observation.sigma"),
        (", sigma = 5.0, colour = 2", "observation.colour"),
        (", sigma = 5.0, height = \"tall\"", "observation.height"),
    ] {
        let e = read(&range(extra)).unwrap_err();
        assert!(e.contains(&format!("`{key}`")), "{extra}: {e}");
    }
    let e = read(&["observation.kind=\"sonar\"".into()]).unwrap_err();
    assert!(
        e.contains("`observation.kind`") && e.contains("`range`"),
        "{e}"
    );
    let ou = |extra: &str| {
        vec![format!(
            "dynamics={{ kind = \"ornstein_uhlenbeck\"{extra} }}"
        )]
    };
    read(&ou(", period = 1.0, sigma = 0.05")).unwrap();
    for (extra, key) in [
        (", sigma = 0.05", "dynamics.period"),
        (", period = 1.0", "dynamics.sigma"),
        (", period = 1.0, sigma = 0.05, tau = 0", "dynamics.tau"),
        (
            ", period = 1.0, sigma = 0.05, maneuver_accel = 0.1",
            "dynamics.maneuver_accel",
        ),
    ] {
        let e = read(&ou(extra)).unwrap_err();
        assert!(e.contains(&format!("`{key}`")), "{extra}: {e}");
    }
    let e = read(&["dynamics.kind=\"brownian\"".into()]).unwrap_err();
    assert!(
        e.contains("`dynamics.kind`") && e.contains("`ornstein_uhlenbeck`"),
        "{e}"
    );
    // Another program does not know them.
    let other = Scenario::from_toml(
        fusion_graph::scenario::DEFAULT_SCENARIO,
        "d",
        &range(", sigma = 5.0"),
    )
    .unwrap_err()
    .to_string();
    assert!(other.contains("`observation.kind`"), "{other}");
}
