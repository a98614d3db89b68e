//! Launch cqnet sensor networks as real processes from your own tests, and
//! assert on what they report: the bytes that crossed each link, the
//! messages dropped, each node's error and bound, and what each fault cost.
//!
//! ```
//! use cqnet_testkit::{default_scenario, exclusive, ActorId, Kill, MessageKind, Network, Signal};
//!
//! let _one_network_at_a_time = exclusive();
//! let mut scenario = default_scenario();
//! scenario.steps = 20;
//! scenario.sensors.per_cell = Some([2, 2]); // 9 nodes, 36 sensors: 46 processes
//! let run = Network::new(scenario)
//!     .lockstep()
//!     // Generous timeouts: many processes on a busy machine can be slow, and
//!     // a round that times out sends fewer bytes.
//!     .set("consensus.round_timeout_ms", 20000)
//!     .set("clock.step_timeout_ms", 60000)
//!     .fault(Kill {
//!         actor: "node-4".into(),
//!         at_step: 10,
//!         signal: Signal::Kill,
//!         restart_after: None,
//!     })
//!     .run()
//!     .expect("the network ran");
//! run.assert_success().assert_clean();
//! // 10 consensus rounds a step on the link node-0 → node-1, 205 bytes a message.
//! assert_eq!(run.bytes(ActorId::Node(0), ActorId::Node(1), MessageKind::Consensus), 20 * 10 * 205);
//! assert_eq!(run.fault_cost().missing_node_steps, 11);
//! assert!(run.rmse(10..=20) < 5.0);
//! ```
//!
//! # The `cqnet` executable
//!
//! Every node and sensor is its own process running the `cqnet` program.
//! [`Network`] finds it, in this order: [`Network::executable`]; the
//! `CQNET_BIN` environment variable; `cqnet` as Cargo built it, in the
//! target folder the test runs from or that of the current directory's
//! workspace; `cqnet` on `PATH`. To build it with your tests, add a
//! binary to your crate whose `main` is your program's [`App`] (re-exported
//! from `cqnet`):
//!
//! ```no_run
//! // src/bin/cqnet.rs
//! fn main() -> std::process::ExitCode {
//!     cqnet_testkit::App::new().main()
//! }
//! ```
//!
//! and in an integration test, `Network::new(s).executable(env!("CARGO_BIN_EXE_cqnet"))`
//! (with `.parts(app.vocabulary()?)` if the app adds parts the scenario names).
//!
//! # Cleanup
//!
//! Each network has its own run id, so tests can run side by side. Dropping a
//! [`RunningNetwork`] or a [`Run`] kills every process that carries its run
//! id and removes its shared memory, so a test that panics midway leaves
//! nothing behind. Networks take the machine's cores; [`exclusive`] runs
//! tests that launch them one at a time.

#![warn(missing_docs)]

mod cleanup;
mod network;
mod results;
mod separate_hosts;

use std::sync::{Mutex, MutexGuard};

pub use cqnet::App;
pub use fusion_graph::faults::{
    BurstLoss, Corrupt, Delay, Duplicate, Fault, FaultySensors, Kill, LinkSelector, Loss,
    Partition, Reorder, SensorMode, Signal,
};
pub use fusion_graph::scenario::Scenario;
pub use fusion_graph::vocabulary::Vocabulary;
pub use fusion_graph::ActorId;
pub use launch::summary::{AppliedFault, FaultCost, Summary};
pub use network::{Network, RunningNetwork, Target, DEFAULT_TIME_LIMIT};
pub use results::{Run, Tick};
pub use separate_hosts::{SeparateHosts, AGENT_PORT};
pub use transport::accounting::{Accounting, Counters};
pub use wire::MessageKind;

/// The built-in default scenario: 9 processing nodes on a 3 × 3 grid, 225
/// bearing sensors, 100 steps.
pub fn default_scenario() -> Scenario {
    Scenario::from_toml(
        fusion_graph::scenario::DEFAULT_SCENARIO,
        "<built-in default>",
        &[],
    )
    .expect("the built-in scenario is valid")
}

/// The sensor-selection scenario: PCRLB-driven sensor selection.
pub fn sensor_selection_scenario() -> Scenario {
    Scenario::from_toml(
        fusion_graph::scenario::SENSOR_SELECTION_SCENARIO,
        "<built-in sensor-selection>",
        &[],
    )
    .expect("the built-in scenario is valid")
}

/// The random-exchange scenario: 25 RSS nodes on a lattice, each with its
/// own sensor, cooperating by random exchange (`consensus.protocol` chooses
/// among the four random-exchange and KL trackers).
pub fn random_exchange_scenario() -> Scenario {
    Scenario::from_toml(
        fusion_graph::scenario::RANDOM_EXCHANGE_SCENARIO,
        "<built-in random-exchange>",
        &[],
    )
    .expect("the built-in scenario is valid")
}

/// Holds other network tests of this process off while held: a network of
/// 235 processes takes every core, and two at once slow each other into
/// their timeouts.
pub fn exclusive() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// What can go wrong in launching a network or reading its results.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// No `cqnet` program was given or found.
    #[error("no cqnet executable: set Network::executable or CQNET_BIN, or put `cqnet` on PATH")]
    ExecutableNotFound,
    /// The program could not be started.
    #[error("starting {executable}: {source}")]
    Spawn {
        /// The program's path.
        executable: String,
        /// Why it did not start.
        source: std::io::Error,
    },
    /// The scenario (with the added faults) could not be written for the run.
    #[error("writing the scenario for run {run_id}: {source}")]
    WriteScenario {
        /// The run it was for.
        run_id: String,
        /// Why it could not be written.
        source: std::io::Error,
    },
    /// A scenario file to add faults to did not load.
    #[error("the scenario: {0}")]
    Scenario(#[from] fusion_graph::ScenarioError),
    /// The run outlived its time limit and was killed.
    #[error("run {run_id} did not finish within {limit:?}; it was killed")]
    TimedOut {
        /// The run.
        run_id: String,
        /// The limit it outlived.
        limit: std::time::Duration,
    },
    /// The run id built from the tag is not one `cqnet` accepts.
    #[error("the run id {0:?}: {1}")]
    RunId(String, String),
    /// Setting up or changing separate hosts' namespaces failed.
    #[error("separate hosts: {0}")]
    Host(String),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_scenarios_load() {
        let t = fusion_graph::Topology::from_scenario(&default_scenario(), "default").unwrap();
        assert_eq!(t.nodes(), 9);
        assert!(sensor_selection_scenario().steps > 0);
    }
}
