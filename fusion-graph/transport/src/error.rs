//! What the transports' operations can fail with.

use fusion_graph::channel::ChannelError;

/// What a transport's backend (iceoryx2, or another) reported.
pub type BackendError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Setting up a transport: the run, its services and this actor's ports.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error(transparent)]
    Channel(#[from] ChannelError),
    #[error("setting up {what}")]
    Backend {
        what: String,
        #[source]
        source: BackendError,
    },
}

/// Publishing one message.
#[derive(Debug, thiserror::Error)]
pub enum SendError {
    #[error("{actor} does not publish on channel {channel}")]
    NotPublisher { channel: String, actor: String },
    #[error("channel {channel} is read by {readers}, and each of them gets every message on it: a message for {receivers} alone cannot be sent on it (a message to one neighbour goes on the pair's own channel)")]
    Receivers {
        channel: String,
        receivers: String,
        readers: String,
    },
    #[error("publishing on {channel}")]
    Backend {
        channel: String,
        #[source]
        source: BackendError,
    },
}

/// Draining this actor's subscriptions.
#[derive(Debug, thiserror::Error)]
#[error("receiving on {channel}")]
pub struct ReceiveError {
    pub channel: String,
    #[source]
    pub source: BackendError,
}

/// Sleeping until woken.
#[derive(Debug, thiserror::Error)]
#[error("waiting for a wake-up")]
pub struct WaitError {
    #[source]
    pub source: BackendError,
}

/// Any transport operation's error, for callers that do several.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error(transparent)]
    Setup(#[from] SetupError),
    #[error(transparent)]
    Send(#[from] SendError),
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    #[error(transparent)]
    Wait(#[from] WaitError),
}
