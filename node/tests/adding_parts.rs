//! How to add a sensor manager and a fusion protocol: a toy of each,
//! plugged into a node with `CfDpfNode::with_parts` and run for a step.
//! ARCHITECTURE.md points here; keep the two in step.

use std::time::Duration;

use bounds::State;
use fusion_graph::{stream_rng, ActorId, Scenario, Stream, Topology};
use node::fusion::{Fused, FusionProtocol, Handled, InformationVector, RoundStats};
use node::sensor_manager::{SelectionContext, SensorManager};
use node::{Actor, CfDpfNode, Node, Outgoing, ProcessingNode, SensingModel};
use wire::{Control, Message, Payload};

/// A sensor manager: always the node's first `k` sensors.
struct FirstK(usize);

impl SensorManager for FirstK {
    fn choose(&mut self, context: &SelectionContext<'_>) -> Vec<usize> {
        (0..self.0.min(context.own_sensors.len())).collect()
    }
}

/// A fusion protocol: no cooperation at all. The node's own vector stands
/// for the network's sums at once, and nothing is sent.
#[derive(Default)]
struct Alone {
    result: Option<Fused>,
}

impl FusionProtocol for Alone {
    type Value = InformationVector;
    type Output = Fused;

    fn expect_step(&mut self, _step: u32) {}

    fn start(
        &mut self,
        _: u32,
        value: InformationVector,
        _: &[bool],
        _: Duration,
        _: &mut Vec<Outgoing>,
    ) {
        self.result = Some(Fused {
            sums: value.to_sums(),
            stats: RoundStats::default(),
        });
    }

    fn handle(&mut self, _: &Message, _: Duration, _: &mut Vec<Outgoing>) -> Handled {
        Handled::NotMine
    }

    fn poll_timeout(&self) -> Option<Duration> {
        None
    }

    fn handle_timeout(&mut self, _: Duration, _: &mut Vec<Outgoing>) {}

    fn poll_result(&mut self) -> Option<Fused> {
        self.result.take()
    }

    fn finish_now(&mut self, _: Duration, _: &mut Vec<Outgoing>) -> Option<Fused> {
        self.result.take()
    }
}

#[test]
fn a_node_runs_a_step_with_a_toy_manager_and_a_toy_protocol() {
    let scenario = Scenario::default_scenario();
    let topology = Topology::from_scenario(&scenario, "default").unwrap();
    let mut node = ProcessingNode::new(
        CfDpfNode::with_parts(
            &scenario,
            &topology,
            8,
            Box::new(FirstK(2)),
            Box::new(Alone::default()),
        )
        .unwrap(),
    );
    let now = Duration::ZERO;
    let mut out = Vec::new();
    let begin = Message::new(
        ActorId::Launcher,
        1,
        0,
        Payload::Control(Control::BeginStep),
    );
    node.handle(&begin, now, &mut out);

    // The activation names the first two sensors; they answer.
    let Payload::Activate { mask } = &out[0].message.payload else {
        panic!("the first message is the activation")
    };
    assert!(mask.contains(0) && mask.contains(1) && !mask.contains(2));
    let model = SensingModel::from_scenario(&scenario, &topology).unwrap();
    let truth = State::from(scenario.target.initial_state());
    for &s in &topology.node_sensors[8][..2] {
        let mut noise = stream_rng(scenario.seed, ActorId::Sensor(s), 1, Stream::SensorNoise);
        let z = model.sensors[s as usize].sample(&truth, &mut noise);
        let cell = model.quantizer.as_ref().unwrap().encode(z);
        let obs = Message::new(ActorId::Sensor(s), 1, 0, Payload::Observation { cell });
        node.handle(&obs, now, &mut out);
    }

    // The driver runs the node's work; the toy protocol answers at once.
    while let Some(work) = node.poll_work() {
        node.run_work(work);
        node.work_done(work, Duration::from_micros(1), now, &mut out);
    }
    let telemetry = out.iter().find_map(|o| match &o.message.payload {
        Payload::Telemetry(t) => Some(t),
        _ => None,
    });
    let t = telemetry.expect("the step ends with telemetry");
    assert_eq!((t.observations, t.rounds_completed), (2, 0));
    assert!(t.bound.is_some());
    assert!(node.is_idle());
}
