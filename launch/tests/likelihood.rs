//! The sensors' observations and the nodes' likelihood agree: the summed
//! log-likelihood of many quantized bearings peaks at the true state.

use bounds::State;
use fusion_graph::world::StillTarget;
use fusion_graph::{ActorId, Scenario, Topology};
use node::{Observation, ObservedValue, SensingModel};
use sensor::SensorActor;
use wire::{BitMask, Message, Payload};

#[test]
fn summed_log_likelihood_peaks_at_the_truth() {
    let s = Scenario::default_scenario();
    let t = Topology::from_scenario(&s, "d").unwrap();
    let model = SensingModel::from_scenario(&s, &t).unwrap();
    let truth = State::new(1230.0, 1170.0, -6.0, -7.0);
    let mut observations = Vec::new();
    for i in 0..t.sensors() as u16 {
        let mut a = SensorActor::new(&s, &t, i).unwrap();
        // Activate every sensor of the owner: this one's bit is among them.
        let owner = t.sensor_owner[i as usize];
        let mask = BitMask::from_indices(0..t.node_sensors[owner as usize].len());
        let m = a
            .answer(
                &Message::new(ActorId::Node(owner), 5, 0, Payload::Activate { mask }),
                &StillTarget(truth),
            )
            .unwrap()
            .unwrap();
        let Payload::Observation { cell } = m.payload else {
            panic!()
        };
        observations.push(Observation {
            sensor: i,
            value: ObservedValue::Cell(cell),
        });
    }
    let ll = |x: &State| {
        observations
            .iter()
            .map(|o| model.ln_likelihood(o, x))
            .sum::<f64>()
    };
    let mut best = (f64::NEG_INFINITY, State::zeros());
    for dx in -40..=40 {
        for dy in -40..=40 {
            let x = truth + State::new(dx as f64 * 0.5, dy as f64 * 0.5, 0.0, 0.0);
            let v = ll(&x);
            if v > best.0 {
                best = (v, x);
            }
        }
    }
    let miss = (best.1 - truth).norm();
    assert!(
        miss < 3.0,
        "likelihood peaks {miss:.1} m from the truth, at {:?}",
        best.1
    );
}
