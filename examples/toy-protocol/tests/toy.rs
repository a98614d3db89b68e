//! The toy protocols and manager, parts of this crate's program only, run
//! in one process (`sim`) and as real processes (`run --lockstep`): each
//! round's value crosses the links its protocol sends on, under the
//! protocol's own kind, counted like any other message, and the manager's
//! choice shows in which sensors send.

use cqnet_testkit::{default_scenario, ActorId, MessageKind, Network, Run, Scenario, Vocabulary};
use fusion_graph::Topology;
use node::fusion::At;
use toy_protocol::{gossip_target, NeighbourhoodValue, PosteriorShare, PushSumValue};

const STEPS: u32 = 6;
const ROUNDS: u32 = 2;
/// The header and the 24 numbers.
const MESSAGE_BYTES: u64 = 13 + 24 * 8;

fn vocabulary() -> Vocabulary {
    toy_protocol::app()
        .vocabulary()
        .expect("the toy parts list")
}

fn toy_network(protocol: &str) -> Network {
    let mut scenario = default_scenario();
    scenario.steps = STEPS;
    Network::new(scenario)
        .executable(env!("CARGO_BIN_EXE_toy-protocol"))
        .parts(vocabulary())
        .set("consensus.protocol", format!("\"{protocol}\""))
        .set("consensus.rounds", ROUNDS)
        // Generous, so that a loaded machine's scheduling never closes a
        // round before its neighbours' values are in (which would make
        // `run --lockstep` differ from `sim`); a round that has them all
        // closes at once.
        .set("consensus.round_timeout_ms", 500)
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
    let _one_network_at_a_time = cqnet_testkit::exclusive();
    let kind = vocabulary()
        .payloads()
        .of::<NeighbourhoodValue>()
        .unwrap()
        .kind();
    let sim = toy_network("neighbourhood_mean").sim().expect("sim starts");
    assert_toy_parts_ran(&sim, kind);
    let run = toy_network("neighbourhood_mean")
        .lockstep()
        .run()
        .expect("run starts");
    assert_toy_parts_ran(&run, kind);
    run.assert_clean();
    // Lockstep is sim, bit for bit, whatever the protocol.
    assert_eq!(run.sorted_tick_lines(), sim.sorted_tick_lines());
}

/// Every directed link carried `kind` exactly in the rounds its sender's
/// gossip drew its receiver, `message_bytes` each; the messages in all.
fn assert_gossip_links(
    run: &Run,
    kind: MessageKind,
    scenario: &Scenario,
    topology: &Topology,
    message_bytes: u64,
) -> u64 {
    let mut total = 0;
    for (a, neighbours) in topology.neighbours.iter().enumerate() {
        for &b in neighbours {
            let expected = (1..=STEPS)
                .flat_map(|step| (1..=ROUNDS as u16).map(move |round| At { step, round }))
                .filter(|&at| gossip_target(topology, scenario.seed, a as u16, at) == b)
                .count() as u64;
            let (from, to) = (ActorId::Node(a as u16), ActorId::Node(b));
            assert_eq!(run.messages(from, to, kind), expected, "{from} → {to}");
            assert_eq!(run.bytes(from, to, kind), expected * message_bytes);
            total += expected;
        }
    }
    total
}

/// What push-sum must show under both drivers: each round's half crosses
/// exactly the link to the neighbour drawn, and nothing else.
fn assert_push_sum_ran(run: &Run, kind: MessageKind) {
    run.assert_success();
    let scenario = default_scenario();
    let topology = Topology::from_scenario(&scenario, "default").unwrap();
    let total = assert_gossip_links(run, kind, &scenario, &topology, 13 + 25 * 8);
    // One message a node a round: nothing broadcast, nothing lost.
    assert_eq!(total, u64::from(STEPS * ROUNDS) * topology.nodes() as u64);
    assert_eq!(run.counters(kind).sent_messages, total);
    assert_eq!(run.unaccounted(kind), 0);
    assert_eq!(run.counters(MessageKind::Consensus).sent_messages, 0);
    assert_eq!(
        run.summary().bound_traffic.cq_dpcrlb_bytes,
        total * 80,
        "its ΔL is the bound's traffic"
    );
    // Hearing only the neighbours that gossip to it is no fault.
    assert_eq!(run.summary().fault_cost.rounds_with_fewer_neighbours, 0);
    for tick in run.ticks().iter().filter(|t| t.is_node()) {
        assert_eq!(tick.rounds_completed, ROUNDS, "{}", tick.line);
        assert!(tick.error.is_finite(), "{}", tick.line);
    }
}

#[test]
fn push_sum_gossips_point_to_point_in_sim_and_as_processes_alike() {
    let _one_network_at_a_time = cqnet_testkit::exclusive();
    let kind = vocabulary().payloads().of::<PushSumValue>().unwrap().kind();
    let sim = toy_network("push_sum").sim().expect("sim starts");
    assert_push_sum_ran(&sim, kind);
    let run = toy_network("push_sum")
        .lockstep()
        .run()
        .expect("run starts");
    assert_push_sum_ran(&run, kind);
    run.assert_clean();
    assert_eq!(run.sorted_tick_lines(), sim.sorted_tick_lines());
}

/// Two programs' parts in one test process: the toy's and cqnet's own,
/// which does not know the toy's names.
#[test]
fn another_program_does_not_know_the_toys_parts() {
    let text = fusion_graph::scenario::DEFAULT_SCENARIO;
    let set = ["consensus.protocol=\"push_sum\"".to_string()];
    let own = cqnet_testkit::App::new().vocabulary().unwrap();
    let refused = fusion_graph::Scenario::from_toml_in(own, text, "d", &set).unwrap_err();
    assert!(
        refused.to_string().contains("consensus.protocol"),
        "{refused}"
    );
    let toy = fusion_graph::Scenario::from_toml_in(vocabulary(), text, "d", &set).unwrap();
    assert_eq!(toy.consensus.protocol.name(), "push_sum");
    assert!(own.payloads().of::<PushSumValue>().is_none());
}

#[test]
fn a_bad_parameter_is_refused_by_its_full_key() {
    let run = toy_network("neighbourhood_mean")
        .set("consensus.params", "{ rounds = 3 }")
        .sim()
        .expect("sim starts");
    run.assert_failure_naming(&["consensus.params.rounds"]);
    let run = toy_network("push_sum")
        .set("consensus.auxiliary_fim", "true")
        .sim()
        .expect("sim starts");
    run.assert_failure_naming(&["consensus.auxiliary_fim"]);
    let run = toy_network("neighbourhood_mean")
        .set("sensors.manager_params", "{ k = 2, kk = 3 }")
        .sim()
        .expect("sim starts");
    run.assert_failure_naming(&["sensors.manager_params.kk"]);
}

/// The tracker of our own on the random-exchange network: each round's
/// half of a posterior crosses exactly the link to the neighbour drawn,
/// and the nodes track.
fn assert_gossip_tracker_ran(run: &Run, kind: MessageKind) {
    run.assert_success();
    let scenario = cqnet_testkit::random_exchange_scenario();
    let topology = Topology::from_scenario(&scenario, "random-exchange").unwrap();
    let total = assert_gossip_links(run, kind, &scenario, &topology, 13 + 15 * 8);
    assert_eq!(total, u64::from(STEPS * ROUNDS) * topology.nodes() as u64);
    assert_eq!(run.unaccounted(kind), 0);
    assert_eq!(run.counters(MessageKind::KlConsensus).sent_messages, 0);
    assert_eq!(run.summary().fault_cost.rounds_with_fewer_neighbours, 0);
    for tick in run.ticks().iter().filter(|t| t.is_node()) {
        assert_eq!(tick.rounds_completed, ROUNDS, "{}", tick.line);
        assert!(tick.error.is_finite(), "{}", tick.line);
    }
}

fn tracker_network() -> Network {
    let mut scenario = cqnet_testkit::random_exchange_scenario();
    scenario.steps = STEPS;
    Network::new(scenario)
        .executable(env!("CARGO_BIN_EXE_toy-protocol"))
        .parts(vocabulary())
        .set("consensus.protocol", "\"gossip_tracker\"")
        .set("consensus.rounds", ROUNDS)
        .set("consensus.round_timeout_ms", 500)
        .no_central()
}

#[test]
fn a_tracker_of_our_own_runs_in_sim_and_as_processes_alike() {
    let _one_network_at_a_time = cqnet_testkit::exclusive();
    let kind = vocabulary()
        .payloads()
        .of::<PosteriorShare>()
        .unwrap()
        .kind();
    let sim = tracker_network().sim().expect("sim starts");
    assert_gossip_tracker_ran(&sim, kind);
    let run = tracker_network().lockstep().run().expect("run starts");
    assert_gossip_tracker_ran(&run, kind);
    run.assert_clean();
    assert_eq!(run.sorted_tick_lines(), sim.sorted_tick_lines());
}
