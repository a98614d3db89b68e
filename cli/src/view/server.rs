//! The view's web server: the page, and the hub's events as server-sent
//! events, on its own thread and runtime so that a slow page never holds the
//! launcher's world thread.

use std::convert::Infallible;
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse};
use axum::routing::get;
use axum::Router;
use futures_util::stream::{self, Stream, StreamExt};
use tokio::sync::broadcast::error::RecvError;

use launch::feed::{Hub, Poll};

/// The page: plain HTML and JS, no build step, nothing fetched from elsewhere.
const PAGE: &str = include_str!("page.html");

/// A running view server. Dropping it stops the server.
pub struct ViewServer {
    url: String,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<JoinHandle<()>>,
}

impl ViewServer {
    /// Binds 127.0.0.1:`port` (0: any free port) now, so a port in use is an
    /// error before anything starts, and serves `hub` until dropped.
    pub fn start(hub: Arc<Hub>, port: u16, mut poll: Option<Poll>) -> anyhow::Result<Self> {
        let listener = std::net::TcpListener::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, port)))
            .with_context(|| format!("binding the view's port 127.0.0.1:{port}"))?;
        listener.set_nonblocking(true)?;
        let url = format!("http://{}/", listener.local_addr()?);
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("view".into())
            .spawn(move || {
                let runtime = match tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                {
                    Ok(r) => r,
                    Err(e) => return tracing::warn!(error = %e, "the view could not start"),
                };
                runtime.block_on(async move {
                    let listener = match tokio::net::TcpListener::from_std(listener) {
                        Ok(l) => l,
                        Err(e) => return tracing::warn!(error = %e, "the view could not listen"),
                    };
                    let app = Router::new()
                        .route("/", get(|| async { Html(PAGE) }))
                        .route("/events", get(move || events(hub.clone())));
                    let poller = async move {
                        let Some(poll) = poll.as_mut() else {
                            return std::future::pending().await;
                        };
                        let mut every = tokio::time::interval(Duration::from_secs(1));
                        loop {
                            every.tick().await;
                            poll();
                        }
                    };
                    tokio::select! {
                        served = axum::serve(listener, app) => {
                            if let Err(e) = served {
                                tracing::warn!(error = %e, "the view stopped");
                            }
                        }
                        _ = poller => {}
                        _ = stopped => {}
                    }
                });
                // Dropping the runtime here ends the open event streams.
            })
            .context("starting the view's thread")?;
        Ok(Self {
            url,
            stop: Some(stop),
            thread: Some(thread),
        })
    }

    pub fn url(&self) -> &str {
        &self.url
    }
}

impl Drop for ViewServer {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The hub's history, then its live events; a page that fell too far behind
/// has its stream ended, and its `EventSource` reconnects for the history.
async fn events(hub: Arc<Hub>) -> impl IntoResponse {
    let (history, live) = hub.subscribe();
    let history = stream::iter(history);
    let live = stream::unfold(live, |mut live| async move {
        match live.recv().await {
            Ok(json) => Some((json, live)),
            Err(RecvError::Lagged(_) | RecvError::Closed) => None,
        }
    });
    let stream: std::pin::Pin<Box<dyn Stream<Item = Result<Event, Infallible>> + Send>> = Box::pin(
        history
            .chain(live)
            .map(|json| Ok(Event::default().data(&*json))),
    );
    Sse::new(stream).keep_alive(KeepAlive::default())
}
