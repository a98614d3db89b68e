//! One processing node's computation for one step of the default scenario:
//! the local filter with its local bound (1000 particles, 3 quantized
//! bearings), the fusion filter with the global CQ/dPCRLB (1000
//! particles), and the node's ΔL over the fusion filter's prediction, each
//! from a tracking state reached by running a few steps.

use std::hint::black_box;

use bounds::State;
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use fusion_graph::{stream_rng, ActorId, Scenario, Stream, Topology};
use node::estimator::{
    Contribution, Evidence, FusionFilter, LocalFilter, Observation, ObservedValue, SensingModel,
};
use node::filter::ParticleFilter;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn bench(c: &mut Criterion) {
    let scenario = Scenario::default_scenario();
    let topology = Topology::from_scenario(&scenario, "default").unwrap();
    let model = SensingModel::from_scenario(&scenario, &topology).unwrap();
    let prior = scenario.network_prior(&scenario.models().unwrap());
    let truth = State::from(scenario.target.initial_state());
    let quantizer = model.quantizer.as_ref().unwrap();
    // Three sensors of node 8 (the cell the target starts in), measured as
    // the sensors themselves would at step 1.
    let observations: Vec<Observation> = topology.node_sensors[8][..3]
        .iter()
        .map(|&s| {
            let mut noise = stream_rng(scenario.seed, ActorId::Sensor(s), 1, Stream::SensorNoise);
            let z = model.sensors[s as usize].sample(&truth, &mut noise);
            Observation {
                sensor: s,
                value: ObservedValue::Cell(quantizer.encode(z)),
            }
        })
        .collect();
    let mut local = LocalFilter::new(1000, &prior, ChaCha8Rng::seed_from_u64(1)).unwrap();
    let mut contribution = Contribution::zero();
    for _ in 0..5 {
        contribution = local
            .update(
                &model,
                &Evidence {
                    received: &observations,
                    ..Evidence::default()
                },
                false,
            )
            .unwrap()
            .contribution;
    }
    let mut sums = contribution;
    sums.delta_l *= 9.0;
    sums.delta_lambda *= 9.0;
    sums.delta_eta *= 9.0;
    // The fusion filter too from a tracking state: five steps on these sums.
    // (Until 2026-12-01 it was benched at its first step from the 50 m
    // prior, where the sums of nine nodes make it temper through many
    // stages; a running node meets that once.)
    let mut fusion = FusionFilter::new(1000, &prior, false, ChaCha8Rng::seed_from_u64(2)).unwrap();
    for _ in 0..5 {
        fusion.step(&model, &sums).unwrap();
    }

    c.bench_function(
        "node step: local filter + local bound, 1000 particles, 3 sensors",
        |b| {
            b.iter_batched(
                || local.clone(),
                |mut l| {
                    black_box(
                        l.update(
                            &model,
                            &Evidence {
                                received: &observations,
                                ..Evidence::default()
                            },
                            false,
                        )
                        .unwrap(),
                    )
                },
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
    // The particle filter alone, no bound: what `bench/peers/stonesoup.sh`
    // compares with Stone Soup's. Predict, weigh with the three quantized
    // bearings (tempered as the node does), resample.
    // From a tracking state, as the other benches: five steps from the prior.
    let mut filter_rng = ChaCha8Rng::seed_from_u64(3);
    let mut filter = ParticleFilter::from_gaussian(1000, &prior, &mut filter_rng)
        .expect("a positive definite prior");
    for _ in 0..5 {
        filter.predict(&model.dynamics, &mut filter_rng);
        filter.update(&mut filter_rng, |x| {
            observations.iter().map(|o| model.ln_likelihood(o, x)).sum()
        });
        filter.resample(&mut filter_rng);
    }
    c.bench_function(
        "particle filter alone: predict, 3 bearings, resample, 1000 particles",
        |b| {
            let mut rng = ChaCha8Rng::seed_from_u64(4);
            b.iter_batched(
                || filter.clone(),
                |mut f| {
                    f.predict(&model.dynamics, &mut rng);
                    f.update(&mut rng, |x| {
                        observations.iter().map(|o| model.ln_likelihood(o, x)).sum()
                    });
                    f.resample(&mut rng);
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
                    let mut f = fusion.clone();
                    f.predict(&model).unwrap();
                    f
                },
                |mut f| black_box(f.observation_information(&model, &observations).unwrap()),
                BatchSize::LargeInput,
            )
        },
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
