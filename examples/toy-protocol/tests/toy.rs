//! The toy protocol and manager, registered only in this crate's program,
//! run in one process (`sim`) and as real processes (`run --lockstep`):
//! each round's value crosses every fusion-graph link under the protocol's
//! own kind, counted like any other message, and the manager's choice shows
//! in which sensors send.

use cqnet_testkit::{default_scenario, ActorId, MessageKind, Network, Run};
use fusion_graph::Topology;

const STEPS: u32 = 6;
const ROUNDS: u32 = 2;
/// The header and the 24 numbers.
const MESSAGE_BYTES: u64 = 13 + 24 * 8;

fn toy_network() -> Network {
    toy_protocol::register().expect("the toy parts register");
    let mut scenario = default_scenario();
    scenario.steps = STEPS;
    Network::new(scenario)
        .executable(env!("CARGO_BIN_EXE_toy-protocol"))
        .set("consensus.protocol", "\"neighbourhood_mean\"")
        .set("consensus.params", format!("{{ rounds = {ROUNDS} }}"))
        .set("sensors.manager", "\"first_k\"")
        .set("sensors.manager_params", "{ k = 2 }")
        .no_central()
}

/// What both drivers must show.
fn assert_toy_parts_ran(run: &Run, kind: MessageKind) {
    run.assert_success();
    let scenario = default_scenario();
    let topology = Topology::from_scenario(&scenario, "default").unwrap();
    // Every directed fusion-graph link carries one message a round.
    for (a, neighbours) in topology.neighbours.iter().enumerate() {
        for &b in neighbours {
            let (from, to) = (ActorId::Node(a as u16), ActorId::Node(b));
            assert_eq!(
                run.messages(from, to, kind),
                u64::from(STEPS * ROUNDS),
                "{from} → {to}"
            );
            assert_eq!(
                run.bytes(from, to, kind),
                u64::from(STEPS * ROUNDS) * MESSAGE_BYTES
            );
        }
    }
    assert_eq!(run.unaccounted(kind), 0);
    // Its ΔL (80 of each message's bytes) is the bound's traffic, as the
    // built-in consensus's is.
    assert_eq!(
        run.summary().bound_traffic.cq_dpcrlb_bytes,
        run.counters(kind).sent_messages * 80
    );
    assert!(run.summary().bound_traffic.cq_dpcrlb_bytes > 0);
    // No average consensus ran: the toy replaced it.
    assert_eq!(run.counters(MessageKind::Consensus).sent_messages, 0);
    // Each node's first two sensors observe every step, the others never.
    for (node, sensors) in topology.node_sensors.iter().enumerate() {
        for (position, &sensor) in sensors.iter().enumerate() {
            let sent = run.messages(
                ActorId::Sensor(sensor),
                ActorId::Node(node as u16),
                MessageKind::Observation,
            );
            let expected = if position < 2 { STEPS } else { 0 };
            assert_eq!(sent, u64::from(expected), "sensor-{sensor} of node-{node}");
        }
    }
    for tick in run.ticks().iter().filter(|t| t.is_node()) {
        assert_eq!(tick.rounds_completed, ROUNDS, "{}", tick.line);
        assert!(tick.error.is_finite());
    }
}

#[test]
fn the_toy_protocol_and_manager_run_in_sim_and_as_processes_alike() {
    let kind = toy_protocol::register().unwrap();
    let sim = toy_network().sim().expect("sim starts");
    assert_toy_parts_ran(&sim, kind);
    let run = toy_network().lockstep().run().expect("run starts");
    assert_toy_parts_ran(&run, kind);
    run.assert_clean();
    // Lockstep is sim, bit for bit, whatever the protocol.
    assert_eq!(run.sorted_tick_lines(), sim.sorted_tick_lines());
}

#[test]
fn a_bad_parameter_is_refused_by_its_full_key() {
    let run = toy_network()
        .set("consensus.params", "{ rounds = 0 }")
        .sim()
        .expect("sim starts");
    run.assert_failure_naming(&["consensus.params.rounds"]);
    let run = toy_network()
        .set("sensors.manager_params", "{ k = 2, kk = 3 }")
        .sim()
        .expect("sim starts");
    run.assert_failure_naming(&["sensors.manager_params.kk"]);
}
