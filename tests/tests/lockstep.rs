//! The determinism invariant, held everywhere: every built-in scenario,
//! with every built-in fusion protocol and sensor manager it allows, runs
//! as real processes in lockstep to `sim`'s results bit for bit. Every
//! random draw comes from a named stream, and no choice depends on which
//! message reaches a process first (random exchange draws its pairs from
//! the network's stream of the step, not from the order requests arrive
//! in). A scenario where a message is lost on purpose says in its summary
//! that it cannot hold.

use std::path::PathBuf;
use std::time::Duration;

use cqnet_testkit::{exclusive, LinkSelector, Loss, Network};

const CQNET: &str = env!("CARGO_BIN_EXE_cqnet-under-test");
const STEPS: u32 = 3;

fn scenario_file(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fusion-graph/scenarios")
        .join(format!("{name}.toml"))
}

const MANAGERS: [&str; 5] = [
    "random",
    "closest",
    "pcrlb",
    "pcrlb_at_estimate",
    "pcrlb_offline",
];
const TRACKERS: [&str; 4] = [
    "random_exchange",
    "kl_consensus",
    "kl_diffusion",
    "kl_iterative",
];

/// Every built-in scenario with the protocols and managers it allows: the
/// CF/DPF with each manager, and each tracker (which activates at random),
/// where the scenario's sensors have them; the locator and the fusion
/// centre with their own.
fn matrix() -> Vec<(&'static str, &'static str, &'static str)> {
    let mut m = Vec::new();
    for scenario in ["default", "sensor-selection", "random-exchange"] {
        for manager in MANAGERS {
            m.push((scenario, "average", manager));
        }
    }
    for scenario in ["default", "random-exchange"] {
        for tracker in TRACKERS {
            m.push((scenario, tracker, "random"));
        }
    }
    // Scored by the auxiliary FIM, which only this manager needs carried.
    m.push(("sensor-selection", "average", "pcrlb_aux"));
    m.push(("default", "short_memory", "random"));
    m.push(("location", "ml_location", "random"));
    m.push(("compressive", "average", "random"));
    m
}

fn network(i: usize, scenario: &str, protocol: &str, manager: &str) -> Network {
    let network = Network::from_file(scenario_file(scenario));
    let network = if manager == "pcrlb_aux" {
        network.set("consensus.auxiliary_fim", true)
    } else {
        network
    };
    network
        .executable(CQNET)
        .tag(&format!("matrix{i}"))
        .lockstep()
        .no_central()
        .set("steps", STEPS)
        .set("consensus.protocol", format!("\"{protocol}\""))
        .set("sensors.manager", format!("\"{manager}\""))
        // No wait may end by the clock on a busy machine: one that does
        // changes what a node has heard.
        .set("consensus.round_timeout_ms", 20000)
        .set("clock.step_timeout_ms", 60000)
        .time_limit(Duration::from_secs(300))
}

#[test]
fn every_built_in_scenario_protocol_and_manager_runs_in_lockstep_as_sim_does() {
    let _guard = exclusive();
    let combinations = matrix();
    assert_eq!(combinations.len(), 27);
    for (i, (scenario, protocol, manager)) in combinations.into_iter().enumerate() {
        let what = format!("{scenario} with {protocol} and {manager}");
        let n = network(i, scenario, protocol, manager);
        let s = n
            .clone()
            .sim()
            .unwrap_or_else(|e| panic!("{what}: sim: {e}"));
        s.assert_success();
        assert!(
            s.summary().timing_dependent.is_empty(),
            "{what}: {:?}",
            s.summary().timing_dependent
        );
        let r = n.run().unwrap_or_else(|e| panic!("{what}: run: {e}"));
        r.assert_success();
        let (a, b) = (r.sorted_tick_lines(), s.sorted_tick_lines());
        assert!(!a.is_empty(), "{what}: no rows");
        assert_eq!(a, b, "{what}: run --lockstep and sim differ");
        r.assert_clean();
    }
}

/// A message lost on purpose ends a wait by the clock: the run says in its
/// summary that its results may depend on timing, and counts the rounds
/// that ended without a lost value.
#[test]
fn a_scenario_that_loses_messages_says_lockstep_need_not_equal_sim() {
    let n = Network::from_file(scenario_file("default"))
        .executable(CQNET)
        .tag("says-timing")
        .no_central()
        .set("steps", 2)
        .fault(Loss {
            links: vec![LinkSelector::new("node-0", "node-1")],
            at_step: 1,
            duration: None,
            probability: 0.5,
        });
    let s = n.sim().unwrap();
    s.assert_success();
    let why = &s.summary().timing_dependent;
    assert_eq!(why.len(), 2, "{why:?}");
    assert!(why[0].contains("loss"), "{why:?}");
    assert!(
        why[1].contains("consensus rounds") && !why[1].contains("round_timeout_ms"),
        "the lost values' rounds, with no advice to wait longer: {why:?}"
    );
    assert!(s.summary().fault_cost.short_rounds > 0);
}
