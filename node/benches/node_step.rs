//! One processing node's computation for one step of the default scenario
//! (the workload is in `common/workload.rs`, which the
//! `step_instructions` example counts under callgrind).

use std::hint::black_box;

use bounds::chacha::WideChaCha8;
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

criterion_group!(benches, bench);
criterion_main!(benches);
