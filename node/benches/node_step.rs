//! One processing node's computation for one step of the default scenario:
//! the local filter with its local bound (1000 particles, 3 quantized
//! bearings), and the fusion filter with the global CQ/dPCRLB (1000
//! particles), each from a tracking state reached by running a few steps.

use std::hint::black_box;

use bounds::State;
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use fusion_graph::wire::Payload;
use fusion_graph::{Scenario, Topology};
use node::actor::{network_prior, sensing_model};
use node::estimator::{Contribution, FusionFilter, LocalFilter, Observation, ObservedValue};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sensor::{SensorActor, SensorInput};

fn bench(c: &mut Criterion) {
    let scenario = Scenario::default_scenario();
    let topology = Topology::from_scenario(&scenario, "default").unwrap();
    let model = sensing_model(&scenario, &topology);
    let prior = network_prior(&scenario);
    let truth = State::from(scenario.target.initial_state());
    // Three sensors of node 8 (the cell the target starts in).
    let observations: Vec<Observation> = topology.node_sensors[8][..3]
        .iter()
        .map(|&s| {
            let mut a = SensorActor::new(&scenario, &topology, s);
            a.handle(SensorInput::Tick { step: 1, truth });
            let Payload::Observation { cell } = a
                .handle(SensorInput::Activation {
                    step: 1,
                    active: true,
                })
                .unwrap()
                .payload
            else {
                unreachable!()
            };
            Observation {
                sensor: s,
                value: ObservedValue::Cell(cell),
            }
        })
        .collect();
    let mut local = LocalFilter::new(1000, &prior, ChaCha8Rng::seed_from_u64(1)).unwrap();
    let mut contribution = Contribution::zero();
    for _ in 0..5 {
        contribution = local
            .step(&model, &observations, false)
            .unwrap()
            .contribution;
    }
    let mut sums = contribution;
    sums.delta_l *= 9.0;
    sums.delta_lambda *= 9.0;
    sums.delta_eta *= 9.0;
    let fusion = FusionFilter::new(1000, &prior, false, ChaCha8Rng::seed_from_u64(2)).unwrap();

    c.bench_function(
        "node step: local filter + local bound, 1000 particles, 3 sensors",
        |b| {
            b.iter_batched(
                || local.clone(),
                |mut l| black_box(l.step(&model, &observations, false).unwrap()),
                BatchSize::LargeInput,
            )
        },
    );
    c.bench_function(
        "node step: fusion filter + CQ/dPCRLB, 1000 particles",
        |b| {
            b.iter_batched(
                || fusion.clone(),
                |mut f| black_box(f.step(&model, &sums).unwrap()),
                BatchSize::LargeInput,
            )
        },
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
