//! One processing node's computation for one step of the default scenario
//! (the workload is in `common/workload.rs`, which the
//! `step_instructions` example counts under callgrind).

use std::hint::black_box;

use bounds::chacha::WideChaCha8;
use bounds::observation::{Autodiff, DifferentiableLaw, Real};
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use rand::SeedableRng;

#[path = "common/workload.rs"]
mod workload;
use workload::Workload;

fn bench(c: &mut Criterion) {
    let w = Workload::new();
    let model = &w.model;
    let evidence = Workload::evidence(&w.observations);
    c.bench_function(
        "node step: local filter + local bound, 1000 particles, 3 sensors",
        |b| {
            b.iter_batched(
                || w.local.clone(),
                |mut l| black_box(l.update(model, &evidence, false).unwrap()),
                BatchSize::LargeInput,
            )
        },
    );
    c.bench_function(
        "node step: fusion filter + CQ/dPCRLB, 1000 particles",
        |b| {
            b.iter_batched(
                || w.fusion.clone(),
                |mut f| black_box(f.step(model, &w.sums).unwrap()),
                BatchSize::LargeInput,
            )
        },
    );
    // The particle filter alone, no bound: what `bench/peers/stonesoup.sh`
    // compares with Stone Soup's.
    c.bench_function(
        "particle filter alone: predict, 3 bearings, resample, 1000 particles",
        |b| {
            let mut rng = WideChaCha8::seed_from_u64(4);
            b.iter_batched(
                || w.filter.clone(),
                |mut f| {
                    Workload::filter_step(model, &w.observations, &mut f, &mut rng);
                    black_box(f)
                },
                BatchSize::LargeInput,
            )
        },
    );
    // The node's ΔL for consensus, over the fusion filter's prediction (the
    // prediction itself is counted in the fusion filter's step above).
    c.bench_function(
        "node step: ΔL over the fusion filter's prediction, 1000 particles, 3 sensors",
        |b| {
            b.iter_batched(
                || {
                    let mut f = w.fusion.clone();
                    f.predict(model).unwrap();
                    f
                },
                |mut f| {
                    black_box(
                        f.observation_information(model, &Workload::evidence(&w.observations))
                            .unwrap(),
                    )
                },
                BatchSize::LargeInput,
            )
        },
    );
}

/// The built-in bearing's arithmetic as a program would write it, g and R
/// alone, its gradients by automatic differentiation.
#[derive(Debug)]
struct UserBearing;

impl DifferentiableLaw for UserBearing {
    fn mean<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
        (x[0] - sensor[0]).atan2(x[1] - sensor[1])
    }

    fn variance<D: Real>(&self, sensor: [f64; 2], x: [D; 4]) -> D {
        // The default scenario's σ_θ = 0.02, d_0 = 500.
        let (dx, dy) = (x[0] - sensor[0], x[1] - sensor[1]);
        (dx * dx + dy * dy) * (0.02 * 0.02 / (500.0 * 500.0)) + 0.02 * 0.02
    }

    fn is_angular(&self) -> bool {
        true
    }
}

/// The local filter's step with the sensors' law a program's: what a law
/// of one's own costs against the built-in one in a node's step.
fn users_law(c: &mut Criterion) {
    let w = Workload::with_law(bounds::Law::new("user_bearing", Autodiff(UserBearing)));
    let model = &w.model;
    let evidence = Workload::evidence(&w.observations);
    c.bench_function(
        "node step: local filter + local bound, 1000 particles, 3 sensors, a user's bearing, automatic gradients",
        |b| {
            b.iter_batched(
                || w.local.clone(),
                |mut l| black_box(l.update(model, &evidence, false).unwrap()),
                BatchSize::LargeInput,
            )
        },
    );
}

criterion_group!(benches, bench, users_law);
criterion_main!(benches);
