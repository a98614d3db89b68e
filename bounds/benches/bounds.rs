//! `J_Y` for one particle, and one local bound update for 1000 particles and
//! 3 sensors, with the default scenario's 8-bit bearing quantizer (the
//! built-in bearing, and the same law written as a program's, its
//! gradients automatic); the
//! compressive channel's two designs of one step; the random generators.

use std::f64::consts::PI;
use std::hint::black_box;

use bounds::observation::{Autodiff, DifferentiableLaw, Real};
use bounds::pcrlb::{dynamics_terms, observation_information};
use bounds::{
    expected_information, ConditionalBound, CoordinatedTurn, Dynamics, Law, Mat4, Measurement,
    ProcessNoise, Quantizer, SensorLaw, SensorTerm, State,
};
use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, RngCore, SeedableRng};

fn default_dynamics() -> Dynamics {
    Dynamics::new(CoordinatedTurn {
        period: 1.0,
        maneuver_accel: 0.1,
        min_speed: 0.1,
        sigma_v: 0.05,
        process_noise: ProcessNoise::Continuous,
    })
    .unwrap()
}

fn bench(c: &mut Criterion) {
    let q = Quantizer::uniform_wrapped(8, -PI, PI).unwrap();
    let model = SensorLaw::Bearing {
        sigma_theta: 0.02,
        d0: 500.0,
        near_field: None,
    }
    .at([250.0, 350.0]);
    let x = State::new(700.0, 900.0, -6.0, -7.0);
    c.bench_function("J_Y one particle, 8-bit bearing", |b| {
        b.iter(|| {
            expected_information(black_box(&model), Measurement::Quantized(&q), black_box(&x))
        })
    });

    // The quantizer's part of J_Y alone, over bearings and noise levels a
    // 1000-particle cloud spreads over.
    let mut rng = rand::rngs::StdRng::seed_from_u64(2);
    let cloud: Vec<(f64, f64)> = (0..1000)
        .map(|_| {
            let sigma = 0.02 * rng.random_range(1.0..2.5_f64);
            (rng.random_range(-PI..PI), sigma * sigma)
        })
        .collect();
    c.bench_function("Fisher scalars of 1000 particles, 8-bit bearing", |b| {
        b.iter(|| {
            cloud
                .iter()
                .map(|&(g, r)| q.fisher_scalars(black_box(g), r).gg)
                .sum::<f64>()
        })
    });

    let bearing: Law = SensorLaw::Bearing {
        sigma_theta: 0.02,
        d0: 500.0,
        near_field: None,
    }
    .into();
    let user = Law::new(
        "user_bearing",
        Autodiff(UserBearing::<false> {
            sigma_theta: 0.02,
            d0: 500.0,
        }),
    );
    let helped = Law::new(
        "user_bearing_atan2",
        Autodiff(UserBearing::<true> {
            sigma_theta: 0.02,
            d0: 500.0,
        }),
    );
    for (name, law) in [
        ("built-in bearing", bearing),
        ("a user's bearing, automatic gradients", user),
        (
            "a user's bearing, automatic gradients, one-call atan2",
            helped,
        ),
    ] {
        local_bound_update(c, &q, x, &law, name);
    }
}

/// The built-in bearing's arithmetic as a program would write it, g and R
/// alone, its gradients by automatic differentiation: what a law of one's
/// own costs against the built-in one.
/// `ONE_CALL`: its arctangent through `bounds::observation::atan2` rather
/// than the number's own.
#[derive(Debug)]
struct UserBearing<const ONE_CALL: bool> {
    sigma_theta: f64,
    d0: f64,
}

impl<const ONE_CALL: bool> DifferentiableLaw for UserBearing<ONE_CALL> {
    fn mean<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
        let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
        if ONE_CALL {
            bounds::observation::atan2(dx, dy)
        } else {
            dx.atan2(dy)
        }
    }

    fn variance<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
        let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
        let s2 = self.sigma_theta * self.sigma_theta;
        (dx * dx + dy * dy) * (s2 / (self.d0 * self.d0)) + s2
    }

    fn is_angular(&self) -> bool {
        true
    }
}

/// One local bound update over 1000 particles and 3 sensors of `law`.
fn local_bound_update(c: &mut Criterion, q: &Quantizer, x: State, law: &Law, name: &str) {
    let dynamics = default_dynamics();
    let models = [[250.0, 350.0], [50.0, 150.0], [450.0, 450.0]].map(|s| law.at(s));
    let sensors: Vec<SensorTerm> = models
        .iter()
        .map(|m| SensorTerm {
            model: m,
            measurement: Measurement::Quantized(q),
        })
        .collect();
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    let posterior: Vec<State> = (0..1000)
        .map(|_| {
            x + State::new(
                rng.random_range(-20.0..20.0),
                rng.random_range(-20.0..20.0),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
            )
        })
        .collect();
    let predicted: Vec<State> = posterior
        .iter()
        .map(|p| dynamics.propagate(p, &mut rng))
        .collect();
    let weights = vec![1e-3; 1000];
    let prior = Mat4::from_diagonal(&State::new(2500.0, 2500.0, 4.0, 4.0));
    let title = if name.starts_with("built-in") {
        // The name the benchmark has always had, so that its history holds.
        "local bound update, 1000 particles, 3 sensors".to_string()
    } else {
        format!("local bound update, 1000 particles, 3 sensors, {name}")
    };
    c.bench_function(&title, |b| {
        b.iter(|| {
            let mut bound = ConditionalBound::from_prior(&prior).unwrap();
            let terms = dynamics_terms(&dynamics, black_box(&posterior), &weights).unwrap();
            let obs = observation_information(&sensors, black_box(&predicted), &weights).unwrap();
            bound.advance(&terms, dynamics.q_inv(), &obs).unwrap()
        })
    });
}

/// 4 KB of ChaCha8 words: rand_chacha's generator against the same stream
/// sixteen blocks at a time (`bounds::chacha`, AVX-512 where the CPU has it).
fn generators(c: &mut Criterion) {
    let mut words = [0u64; 512];
    let mut theirs = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    c.bench_function("ChaCha8, 4 KB as u64s: rand_chacha", |b| {
        b.iter(|| {
            for w in words.iter_mut() {
                *w = theirs.next_u64();
            }
            black_box(&words);
        })
    });
    let mut ours = bounds::chacha::WideChaCha8::seed_from_u64(1);
    c.bench_function("ChaCha8, 4 KB as u64s: sixteen blocks at a time", |b| {
        b.iter(|| {
            for w in words.iter_mut() {
                *w = ours.next_u64();
            }
            black_box(&words);
        })
    });
}

/// One step's design for the compressive scenario's 25 amplitude sensors
/// (20 m field, n = 2, r = 1, ε = 0.1) over M = 6 slots at E = 6, the
/// target at (7, 9): eq. 4.19's design and the one that counts a sensor
/// once (its sample matrices included). The channel's step is 500 ms.
fn designs(c: &mut Criterion) {
    use bounds::compressive::{
        counted_once_probabilities, optimal_probabilities, DesignProblem, PositionBlock, SAMPLES,
    };
    let target = [7.0, 9.0];
    // ∇a for a = sqrt(P0 / (1 + d²)), P0 = 1000, at the target.
    let blocks: Vec<PositionBlock> = (0..25)
        .map(|j| {
            let s = [2.0 + 4.0 * f64::from(j % 5), 2.0 + 4.0 * f64::from(j / 5)];
            let (dx, dy) = (target[0] - s[0], target[1] - s[1]);
            let d2 = dx * dx + dy * dy;
            let k = -(1000.0f64).sqrt() * (1.0 + d2).powf(-1.5);
            let g = [k * dx, k * dy];
            [g[0] * g[0], g[0] * g[1], g[1] * g[1]]
        })
        .collect();
    let problem = DesignProblem {
        predicted: Mat4::from_diagonal(&State::new(0.5, 0.5, 1.0, 1.0)),
        blocks: &blocks,
        slots: 6,
        energy: 6.0,
        r: 1.0,
        epsilon: 0.1,
    };
    c.bench_function("compressive design, eq. 4.19, 25 sensors, M = 6", |b| {
        b.iter(|| optimal_probabilities(black_box(&problem)))
    });
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    c.bench_function("compressive design, counted once, 25 sensors, M = 6", |b| {
        b.iter(|| counted_once_probabilities(black_box(&problem), SAMPLES, &mut rng))
    });
}

criterion_group!(benches, bench, designs, generators);
criterion_main!(benches);
