//! Several hosts (`--features zenoh`): a scenario's `[[hosts]]` spread its
//! network over hosts, each with its own iceoryx2 domain and its own
//! `cqnet agent`, with Zenoh between them.
//!
//! - **The agent** (`agent.rs`) runs on each host. When the launcher asks,
//!   it opens its host's bridge and spawns, signals and reaps its host's
//!   actors with the same supervisor `cqnet run` uses on one host.
//! - **The bridge** (`bridge.rs`), one per host, in the agent: everything
//!   published on its host that another host reads goes out over Zenoh in
//!   one batch per destination host, wake-ups after the bytes they announce;
//!   what comes in is published on the host and its receivers woken. The
//!   actors do not know: they publish and read their iceoryx2 channels as
//!   on one host, so link faults and byte counts stay theirs.
//! - **The launcher** (`remote.rs`) stays the world and the membership
//!   service. It talks to the agents instead of to a local supervisor, and
//!   watches their Zenoh liveliness: a lost agent is a lost host, whose
//!   actors are told to the world as dead; an agent that comes back gets
//!   its actors started again, rejoining.
//!
//! Why one bridge per host rather than a Zenoh session in every actor: an
//! actor would pay a Zenoh session's threads and memory (235 of them in
//! the default scenario), every actor would need to know which of its
//! messages cross, and the wake-up of a far actor would need a second
//! mechanism. Measured figures for the bridge are in the README.

pub mod agent;
pub mod bridge;
pub mod remote;

use anyhow::Context;
use fusion_graph::scenario::Signal;
use fusion_graph::ActorId;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use zenoh::Wait;

pub use fusion_graph::hosts::BridgeCounts;

/// What the launcher asks of an agent.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub enum ToAgent {
    /// Open the run's bridge: the run id, the effective scenario (TOML) and
    /// whether sensors also report to the centralized reference. Sent again
    /// until the agent answers.
    Setup {
        run: String,
        scenario: String,
        centralized: bool,
        /// The launcher lost this host (its link was cut longer than the
        /// lease) and counts its actors gone: an agent still serving the
        /// run stops them before it answers, for their successors to
        /// rejoin.
        after_loss: bool,
    },
    Spawn {
        actor: ActorId,
        rejoin: bool,
    },
    Signal {
        actor: ActorId,
        signal: Signal,
    },
    Continue {
        actor: ActorId,
    },
    /// Send the byte counts of this host's actors and of its bridge.
    Collect,
    /// Send the byte counts of this host's actors as they stand, for the
    /// live view's traffic (once a second while it is open).
    Traffic,
    /// Send what the run has so far (every few seconds): the counts and
    /// the logs that grew, so that a host lost for good leaves them.
    Progress,
    /// Every actor should be exiting: reap them, close the bridge.
    Shutdown,
}

/// What an agent tells the launcher.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub enum FromAgent {
    SetUp {
        run: String,
    },
    Ready(ActorId),
    Exited {
        actor: ActorId,
        status: String,
        stderr_tail: String,
    },
    /// The host's actors' ledgers, merged (`Accounting::to_csv`), the
    /// bridge's own counts, and what else of the run comes home: the
    /// actors' logs, memory and CPU.
    Counts {
        accounting_csv: String,
        bridge: BridgeCounts,
        home: crate::supervisor::HostFiles,
    },
    /// The host's actors' ledgers as they stand (`Accounting::to_csv`).
    Traffic {
        accounting_csv: String,
    },
    /// What the run has so far: as [`FromAgent::Counts`], with only the
    /// logs that grew since the last.
    Progress {
        accounting_csv: String,
        bridge: BridgeCounts,
        home: crate::supervisor::HostFiles,
    },
    /// Could not set the run up: why.
    Failed {
        message: String,
    },
    /// The run is over here: every actor reaped, the bridge closed.
    Finished,
}

fn command_key(host: &str) -> String {
    format!("cqnet/agent/{host}/command")
}

fn event_key(host: &str) -> String {
    format!("cqnet/agent/{host}/event")
}

/// The key an agent's liveliness token holds while it lives.
fn liveliness_key(host: &str) -> String {
    format!("cqnet/agent/{host}/alive")
}

/// The key a host's bridge reads what other hosts send it on.
fn bridge_key(run: &str, host: &str) -> String {
    format!("cqnet/run/{run}/bridge/{host}")
}

/// Opens a Zenoh peer session listening on `listen` (if any) and connecting
/// to `connect`. Multicast scouting is off: the scenario names every
/// endpoint, and a test on one machine must not find another test's peers.
fn open_session(listen: Option<&str>, connect: &[String]) -> anyhow::Result<zenoh::Session> {
    let mut config = zenoh::Config::default();
    let set = |config: &mut zenoh::Config, key: &str, value: String| {
        config
            .insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("zenoh config `{key}` = {value}: {e}"))
    };
    set(&mut config, "mode", "\"peer\"".into())?;
    set(&mut config, "scouting/multicast/enabled", "false".into())?;
    let listen: Vec<&str> = listen.into_iter().collect();
    set(
        &mut config,
        "listen/endpoints",
        serde_json::to_string(&listen)?,
    )?;
    set(
        &mut config,
        "connect/endpoints",
        serde_json::to_string(connect)?,
    )?;
    zenoh::open(config)
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("opening a Zenoh session (listening on {listen:?})"))
}

/// The agent protocol's encoding: bincode, bounded so that a forged length
/// cannot ask for gigabytes.
fn encode<T: Serialize>(value: &T) -> Vec<u8> {
    bincode::serde::encode_to_vec(value, config()).expect("encoding to a Vec cannot fail")
}

/// `None` for bytes that are not a `T`: the caller counts and drops them.
fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Option<T> {
    bincode::serde::decode_from_slice(bytes, config())
        .ok()
        .map(|(v, _)| v)
}

fn config() -> bincode::config::Configuration<
    bincode::config::LittleEndian,
    bincode::config::Varint,
    bincode::config::Limit<{ 64 << 20 }>,
> {
    bincode::config::standard().with_limit::<{ 64 << 20 }>()
}

/// Puts `bytes` on `key`, blocking rather than dropping when the link is
/// congested: a lost control message or batch would be a silent loss.
fn put(session: &zenoh::Session, key: &str, bytes: Vec<u8>) -> anyhow::Result<()> {
    session
        .put(key, bytes)
        .congestion_control(zenoh::qos::CongestionControl::Block)
        .wait()
        .map_err(|e| anyhow::anyhow!("zenoh put on {key}: {e}"))
}
