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
pub mod relay;
pub mod remote;
pub mod trust;

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

/// A command as it travels on an agent's key: the run it is for and who
/// sent it. The sender is the sending session's Zenoh id as it says; what
/// vouches for it is the access control (only the launcher's certificate
/// may put on an agent's command key), and the id goes into the agent's
/// log of what it refused.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Order {
    pub run: String,
    pub sender: String,
    pub command: ToAgent,
}

impl ToAgent {
    /// The command's name, for logs.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Setup { .. } => "Setup",
            Self::Spawn { .. } => "Spawn",
            Self::Signal { .. } => "Signal",
            Self::Continue { .. } => "Continue",
            Self::Collect => "Collect",
            Self::Traffic => "Traffic",
            Self::Progress => "Progress",
            Self::Shutdown => "Shutdown",
        }
    }

    /// The actor the command is about, if it is about one.
    pub fn actor(&self) -> Option<ActorId> {
        match self {
            Self::Spawn { actor, .. } | Self::Signal { actor, .. } | Self::Continue { actor } => {
                Some(*actor)
            }
            _ => None,
        }
    }
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

pub fn command_key(host: &str) -> String {
    format!("cqnet/agent/{host}/command")
}

fn event_key(host: &str) -> String {
    format!("cqnet/agent/{host}/event")
}

/// The key an agent's liveliness token holds while it lives: its host,
/// and the session's own id, so that an agent started again is told from
/// the one it replaces before the old one's lease runs out (a killed
/// agent's QUIC peers hear nothing until then).
fn liveliness_key(host: &str, instance: &str) -> String {
    format!("cqnet/agent/{host}/alive/{instance}")
}

/// The key a host's bridge reads what other hosts send it on.
fn bridge_key(run: &str, host: &str) -> String {
    format!("cqnet/run/{run}/bridge/{host}")
}

/// How long a host's Zenoh peers wait without a word from it before they
/// count it gone (four keep-alives a lease).
pub const HOST_LEASE: std::time::Duration = std::time::Duration::from_secs(3);

/// How a session proves who it is and whom it lets in.
#[derive(Debug, Clone)]
pub enum Security {
    /// QUIC, whose TLS 1.3 authenticates both ends with the run's keys,
    /// and access control by certificate name (`trust.rs`).
    Tls {
        keys: trust::Keys,
        identity: String,
        access_control: serde_json::Value,
    },
    /// Plain TCP: anyone who reaches the port is in. Only where the
    /// scenario asks for it.
    PlainTcp,
}

impl Security {
    /// What the scenario's `[trust]` asks of `role`'s session; plain TCP
    /// warned of on stderr.
    pub fn for_role(
        placement: &fusion_graph::hosts::Placement,
        role: trust::Role<'_>,
    ) -> anyhow::Result<Self> {
        let who = match role {
            trust::Role::Launcher => "launcher".to_string(),
            trust::Role::Agent(h) => format!("agent {h}"),
        };
        if placement.plain_tcp() {
            eprintln!(
                "warning: {who}: plain TCP between hosts (`[trust] plain_tcp = true`): whoever reaches these ports can join the run, read it and command its agents"
            );
            return Ok(Self::PlainTcp);
        }
        let dir = placement.trust().keys.as_deref().context(
            "`quic/` endpoints need `[trust] keys = \"<folder>\"`, made by `cqnet hosts keys <folder> <host>…`",
        )?;
        let keys = trust::Keys::open(std::path::Path::new(dir))?;
        let identity = match role {
            trust::Role::Launcher => trust::LAUNCHER.to_string(),
            trust::Role::Agent(h) => h.to_string(),
        };
        keys.identity(&identity)?;
        let names: Vec<String> = placement.hosts().iter().map(|h| h.name.clone()).collect();
        Ok(Self::Tls {
            keys,
            identity,
            access_control: trust::access_control(role, &names),
        })
    }
}

/// What host `h`'s own relays do to its link: its `link`'s delay, jitter
/// and rate, unless a harness shapes the link in the kernel
/// ([`HOST_LINKS_APPLIED`](crate::network::HOST_LINKS_APPLIED)). A loss
/// the relay cannot stand for (on a `tcp/` stream) is warned of.
pub fn relay_shaping(
    placement: &fusion_graph::hosts::Placement,
    h: usize,
) -> Option<relay::Shaping> {
    if std::env::var_os(crate::network::HOST_LINKS_APPLIED).is_some() {
        return None;
    }
    let host = &placement.hosts()[h];
    let link = host.link.as_ref()?;
    if link.loss > 0.0 && placement.plain_tcp() {
        eprintln!(
            "warning: host {}: link.loss = {} is not applied: a relay carries a TCP stream and cannot drop packets (the kernel's netem can)",
            host.name, link.loss
        );
    }
    relay::Shaping::from_link(link)
}

/// A Zenoh session and the relays that shape its links (kept as long as it).
pub struct HostSession {
    pub session: zenoh::Session,
    _relays: Vec<relay::Relay>,
}

/// Opens a Zenoh peer session listening on `listen` (if any) and connecting
/// to `connect`. Multicast scouting is off: the scenario names every
/// endpoint, and a test on one machine must not find another test's peers.
/// With `shaping`, every link but the one to `local` (this host's own
/// endpoint, for the launcher) passes a relay of this process.
pub fn open_session(
    listen: Option<&str>,
    connect: &[String],
    local: Option<&str>,
    security: &Security,
    shaping: Option<relay::Shaping>,
) -> anyhow::Result<HostSession> {
    let mut relays = Vec::new();
    let (listen, connect) = match shaping {
        None => (listen.map(str::to_string), connect.to_vec()),
        Some(shaping) => {
            let listen = listen
                .map(|e| {
                    let (protocol, outside) = endpoint_address(e)?;
                    // Zenoh listens inside; the relay on the endpoint.
                    let carrying = relay::Carrying::for_protocol(&protocol);
                    let inside = free_loopback_port(carrying)?;
                    relays.push(relay::Relay::start(carrying, outside, inside, shaping)?);
                    anyhow::Ok(format!("{protocol}/{inside}"))
                })
                .transpose()?;
            let mut through = Vec::new();
            for e in connect {
                if Some(e.as_str()) == local {
                    through.push(e.clone());
                    continue;
                }
                let (protocol, far) = endpoint_address(e)?;
                let carrying = relay::Carrying::for_protocol(&protocol);
                let r = relay::Relay::start(carrying, "127.0.0.1:0".parse()?, far, shaping)?;
                through.push(format!("{protocol}/{}", r.local()));
                relays.push(r);
            }
            (listen, through)
        }
    };
    let session = open_zenoh(listen.as_deref(), &connect, security, !relays.is_empty())?;
    Ok(HostSession {
        session,
        _relays: relays,
    })
}

/// `quic/10.0.0.2:17447` → (`quic`, its socket address).
fn endpoint_address(endpoint: &str) -> anyhow::Result<(String, std::net::SocketAddr)> {
    use std::net::ToSocketAddrs;
    let (protocol, rest) = endpoint
        .split_once('/')
        .with_context(|| format!("{endpoint:?} is not a Zenoh endpoint"))?;
    let address = rest.split('#').next().unwrap_or(rest);
    let addr = address
        .to_socket_addrs()
        .with_context(|| format!("resolving {address:?}"))?
        .next()
        .with_context(|| format!("{address:?} resolves to no address"))?;
    Ok((protocol.to_string(), addr))
}

/// A port on 127.0.0.1 that was free a moment ago.
fn free_loopback_port(carrying: relay::Carrying) -> std::io::Result<std::net::SocketAddr> {
    match carrying {
        relay::Carrying::Stream => std::net::TcpListener::bind("127.0.0.1:0")?.local_addr(),
        relay::Carrying::Datagrams => std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr(),
    }
}

/// The session itself. Behind relays, gossip is off: a peer must not learn
/// the address a relay hides and connect around it.
fn open_zenoh(
    listen: Option<&str>,
    connect: &[String],
    security: &Security,
    behind_relays: bool,
) -> anyhow::Result<zenoh::Session> {
    let mut config = zenoh::Config::default();
    let set = |config: &mut zenoh::Config, key: &str, value: String| {
        config
            .insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("zenoh config `{key}` = {value}: {e}"))
    };
    set(&mut config, "mode", "\"peer\"".into())?;
    set(&mut config, "scouting/multicast/enabled", "false".into())?;
    if behind_relays {
        set(&mut config, "scouting/gossip/enabled", "false".into())?;
    }
    // A peer silent this long is gone. Zenoh's default is 10 s; over QUIC,
    // where a killed process sends no reset, that is how long a host's
    // loss (and the start of its replacement's link) would wait.
    set(
        &mut config,
        "transport/link/tx/lease",
        HOST_LEASE.as_millis().to_string(),
    )?;
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
    if let Security::Tls {
        keys,
        identity,
        access_control,
    } = security
    {
        let (cert, key) = keys.identity(identity)?;
        let path = |p: &std::path::Path| serde_json::to_string(&p.display().to_string());
        let tls = "transport/link/tls";
        set(
            &mut config,
            &format!("{tls}/root_ca_certificate"),
            path(&keys.authority())?,
        )?;
        for end in ["listen", "connect"] {
            set(
                &mut config,
                &format!("{tls}/{end}_certificate"),
                path(&cert)?,
            )?;
            set(
                &mut config,
                &format!("{tls}/{end}_private_key"),
                path(&key)?,
            )?;
        }
        set(&mut config, &format!("{tls}/enable_mtls"), "true".into())?;
        set(
            &mut config,
            &format!("{tls}/verify_name_on_connect"),
            "false".into(),
        )?;
        set(&mut config, "access_control", access_control.to_string())?;
    }
    zenoh::open(config)
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("opening a Zenoh session (listening on {listen:?})"))
}

/// The agent protocol's encoding: bincode, bounded so that a forged length
/// cannot ask for gigabytes. Public so that a test can speak it as a peer
/// that should not be heard.
pub fn encode<T: Serialize>(value: &T) -> Vec<u8> {
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
