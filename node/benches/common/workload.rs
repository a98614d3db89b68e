//! The workload of one processing node's step in the default scenario,
//! shared by the `node_step` bench (timed) and the `step_instructions`
//! example (counted under callgrind): the local filter with its local
//! bound (1000 particles, 3 quantized bearings), the fusion filter with
//! the global CQ/dPCRLB (1000 particles), the particle filter alone, and
//! the node's ΔL, each from a state reached by running a few steps.

use bounds::chacha::WideChaCha8;
use bounds::State;
use fusion_graph::{stream_rng, ActorId, Scenario, Stream, Topology};
use node::estimator::{
    Contribution, Evidence, FusionFilter, LocalFilter, NetworkSums, Observation, ObservedValue,
    SensingModel,
};
use node::filter::ParticleFilter;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub struct Workload {
    pub model: SensingModel,
    /// Node 8's three observations (the cell the target starts in).
    pub observations: Vec<Observation>,
    pub local: LocalFilter,
    pub fusion: FusionFilter,
    pub sums: NetworkSums,
    /// The particle filter alone, as `bench/peers/stonesoup.sh` compares it.
    pub filter: ParticleFilter,
}

impl Workload {
    pub fn new() -> Self {
        Self::measuring_by(None)
    }

    /// The same workload with every sensor measuring by `law` instead of
    /// the scenario's (a program's law against the built-in one). The
    /// bench uses it; the instruction-counting example does not.
    #[allow(dead_code)]
    pub fn with_law(law: bounds::Law) -> Self {
        Self::measuring_by(Some(law))
    }

    fn measuring_by(law: Option<bounds::Law>) -> Self {
        let scenario = Scenario::default_scenario();
        let topology = Topology::from_scenario(&scenario, "default").unwrap();
        let mut model = SensingModel::from_scenario(&scenario, &topology).unwrap();
        if let Some(law) = law {
            model.sensors = model.sensors.iter().map(|s| law.at(s.sensor)).collect();
        }
        let prior = scenario.network_prior(&scenario.models().unwrap());
        let truth = State::from(scenario.target.initial_state());
        let quantizer = model.quantizer.as_ref().unwrap();
        // Three sensors of node 8, measured as the sensors themselves
        // would at step 1.
        let observations: Vec<Observation> = topology.node_sensors[8][..3]
            .iter()
            .map(|&s| {
                let mut noise =
                    stream_rng(scenario.seed, ActorId::Sensor(s), 1, Stream::SensorNoise);
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
                .update(&model, &Self::evidence(&observations), false)
                .unwrap()
                .contribution;
        }
        let mut sums = contribution;
        sums.delta_l *= 9.0;
        sums.delta_lambda *= 9.0;
        sums.delta_eta *= 9.0;
        // The fusion filter too from a tracking state: five steps on these
        // sums. (Until 2026-12-01 it was benched at its first step from the
        // 50 m prior, where the sums of nine nodes make it temper through
        // many stages; a running node meets that once.)
        let mut fusion =
            FusionFilter::new(1000, &prior, false, ChaCha8Rng::seed_from_u64(2)).unwrap();
        for _ in 0..5 {
            fusion.step(&model, &sums).unwrap();
        }
        // The particle filter alone, five steps from the prior.
        let mut filter_rng = WideChaCha8::seed_from_u64(3);
        let mut filter = ParticleFilter::from_gaussian(1000, &prior, &mut filter_rng)
            .expect("a positive definite prior");
        for _ in 0..5 {
            Self::filter_step(&model, &observations, &mut filter, &mut filter_rng);
        }
        Self {
            model,
            observations,
            local,
            fusion,
            sums,
            filter,
        }
    }

    pub fn evidence(observations: &[Observation]) -> Evidence<'_> {
        Evidence {
            received: observations,
            ..Evidence::default()
        }
    }

    /// Predict, weigh with the three quantized bearings (tempered as the
    /// node does), resample.
    pub fn filter_step(
        model: &SensingModel,
        observations: &[Observation],
        filter: &mut ParticleFilter,
        rng: &mut WideChaCha8,
    ) {
        filter.predict(&model.dynamics, rng);
        filter.update_batched(rng, |particles, out| {
            model.ln_likelihoods(observations, particles, out)
        });
        filter.resample(rng);
    }
}
