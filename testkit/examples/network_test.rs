//! An integration test of your own, to copy into your crate's `tests/`.
//!
//! It launches a small network as real processes (a launcher, 9 processing
//! nodes, 4 sensors each: 46 processes), cuts it in two for ten steps, and checks
//! what crossed the cut, what the partition cost and that tracking recovers.
//! Cargo runs it with `cargo test` (it is declared with `test = true`), and
//! `cargo run --example network_test` runs it as a program.

use cqnet_testkit::{default_scenario, exclusive, ActorId, MessageKind, Network, Partition};

#[test]
fn a_partition_stops_consensus_across_it_and_tracking_recovers() {
    partition_run_checks();
}

fn main() {
    partition_run_checks();
    println!("the partitioned network behaved as expected");
}

fn partition_run_checks() {
    let _one_network_at_a_time = exclusive();
    let mut scenario = default_scenario();
    scenario.steps = 30;
    // What is checked does not depend on the network's size, and a smaller
    // one starts in a fraction of the time: 2 x 2 sensors per node, not 5 x 5.
    scenario.sensors.per_cell = Some([2, 2]);
    let run = Network::new(scenario)
        .tag("example-partition")
        .lockstep()
        .no_central()
        // A short round timeout: a node stops waiting for the far side soon.
        .set("consensus.round_timeout_ms", 100)
        .set("clock.step_timeout_ms", 2000)
        .fault(Partition {
            groups: vec![
                vec![
                    "node-0".into(),
                    "node-1".into(),
                    "node-3".into(),
                    "node-4".into(),
                ],
                vec![
                    "node-2".into(),
                    "node-5".into(),
                    "node-6".into(),
                    "node-7".into(),
                    "node-8".into(),
                ],
            ],
            at_step: 10,
            duration: Some(10),
        })
        .run()
        .expect("the network ran");
    run.assert_success().assert_clean();

    // node-1 and node-2 are fusion-graph neighbours on opposite sides, ten
    // consensus rounds a step for 30 steps: every message node-1 published
    // reached node-2, which took it in outside the partition and dropped it
    // inside. (A message of the step before the cut can reach node-2 after
    // it entered the cut, so the split is not exactly 200 and 100.)
    let counters = run
        .accounting()
        .get(ActorId::Node(1), ActorId::Node(2), MessageKind::Consensus);
    assert_eq!(
        counters.received_messages + counters.dropped_messages,
        30 * 10,
        "{counters:?}"
    );
    assert!(
        (95..=105).contains(&counters.dropped_messages),
        "{counters:?}"
    );
    assert_eq!(counters.received_bytes, counters.received_messages * 205);
    // node-1 left node-2 out of its consensus during the cut, but its
    // messages still reached node-2's queue, and they are counted as sent.
    assert_eq!(counters.sent_messages, 30 * 10, "{counters:?}");

    // The run counts the partition's cost, and the estimate recovers after it.
    assert_eq!(run.faults().len(), 1);
    assert!(run.fault_cost().dropped_messages >= counters.dropped_messages);
    assert!(
        run.rmse(25..=30) < 10.0,
        "RMSE after the partition: {}",
        run.rmse(25..=30)
    );
}
