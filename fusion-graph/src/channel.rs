//! What a message travels on: a run (its id names every shared-memory
//! resource) and a channel of it (one publisher, its subscribers).

use wire::ActorId;

/// A run id or a publisher that breaks the channels' rules.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ChannelError {
    #[error("run id `{id}` must be 1-32 characters of a-z, 0-9 and -")]
    BadRunId { id: String },
    #[error("{actor} is not the publisher of channel {channel}")]
    NotPublisher { channel: String, actor: String },
}

/// A publish/subscribe channel. Every channel has exactly one publisher, so a
/// receiver always knows which directed link a message came over, even when
/// the bytes are garbage.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub enum Channel {
    /// Launcher → every sensor and multiple-access channel: the stop. (The
    /// target's truth is not a message: see `world`.)
    Lifecycle,
    /// Node → one of its sensors, or its multiple-access channel: the step's
    /// activation. One channel each, so that a sensor its node does not
    /// activate receives nothing and is never woken.
    Activation { node: u16, to: ActorId },
    /// Sensor → its node (and the centralized reference).
    Observation(u16),
    /// Node → its fusion-graph neighbours.
    Consensus(u16),
    /// Node → one neighbour: a message for it alone (random exchange), so
    /// that it reaches, and is counted for, that neighbour only.
    Pair { from: u16, to: u16 },
    /// Launcher → one actor.
    Control(ActorId),
    /// Node → launcher.
    Telemetry(u16),
    /// Node i's multiple-access channel → node i: what each slot received.
    MacOutput(u16),
}

impl Channel {
    /// The one actor that publishes on this channel.
    pub fn publisher(self) -> ActorId {
        match self {
            Channel::Lifecycle | Channel::Control(_) => ActorId::Launcher,
            Channel::Activation { node: n, .. } | Channel::Consensus(n) | Channel::Telemetry(n) => {
                ActorId::Node(n)
            }
            Channel::Pair { from, .. } => ActorId::Node(from),
            Channel::Observation(s) => ActorId::Sensor(s),
            Channel::MacOutput(n) => ActorId::Mac(n),
        }
    }

    /// Only a channel's one publisher may publish on it.
    pub fn check_publisher(self, actor: ActorId) -> Result<(), ChannelError> {
        if self.publisher() == actor {
            Ok(())
        } else {
            Err(ChannelError::NotPublisher {
                channel: self.service_suffix(),
                actor: actor.to_string(),
            })
        }
    }

    /// The part of the service name after `cqnet/<run>/`.
    pub fn service_suffix(self) -> String {
        match self {
            Channel::Lifecycle => "lifecycle".into(),
            Channel::Activation { node, to } => format!("act/node-{node}/{to}"),
            Channel::Observation(s) => format!("obs/sensor-{s}"),
            Channel::Consensus(n) => format!("cons/node-{n}"),
            Channel::Pair { from, to } => format!("pair/node-{from}/node-{to}"),
            Channel::Control(a) => format!("ctl/{a}"),
            Channel::Telemetry(n) => format!("telemetry/node-{n}"),
            Channel::MacOutput(n) => format!("mac/node-{n}"),
        }
    }
}

/// A run's identity: lowercase letters, digits and `-`, at most 32 characters.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct RunId(String);

impl RunId {
    pub fn new(id: &str) -> Result<Self, ChannelError> {
        let ok = !id.is_empty()
            && id.len() <= 32
            && id
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-');
        if !ok {
            return Err(ChannelError::BadRunId { id: id.into() });
        }
        Ok(Self(id.into()))
    }

    /// A fresh id from the process id and the clock.
    pub fn generate() -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        Self(format!("r{}-{:x}", std::process::id(), nanos & 0xffff_ffff))
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The file-name prefix of every iceoryx2 resource of this run.
    pub fn prefix(&self) -> String {
        format!("cqnet_{}_", self.0.replace('-', "_"))
    }
}

impl std::fmt::Display for RunId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
