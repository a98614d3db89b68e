//! The launcher's side of several hosts: the supervisor the world thread
//! talks to, speaking to the agents over Zenoh instead of to processes.
//! Same commands in, same events out, so the world does not ask where its
//! actors run; three more things happen here:
//! - an agent's liveliness token going away, or a new agent of the same
//!   host appearing, is its host lost: each of its actors is reported
//!   exited, so the world drops them from membership and records the
//!   fault, and a spawn for it fails at once;
//! - an agent that comes back is set up again and reported as
//!   [`Event::HostBack`], for the world to start its actors rejoining;
//! - [`Command::Collect`] gathers every host's byte counts.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use fusion_graph::hosts::{BridgeCounts, Placement};
use fusion_graph::Topology;
use tokio::sync::mpsc::UnboundedReceiver;
use transport::accounting::Accounting;
use zenoh::Wait;

use super::trust::Role;
use super::{
    command_key, decode, encode, event_key, open_session, put, FromAgent, Order, Security, ToAgent,
};
use crate::supervisor::{Command, Event};

/// How often a set-up is repeated until the agent answers.
const SETUP_RETRY: Duration = Duration::from_millis(500);
/// How long hosts get to send their counts, and to finish after a shutdown.
const COLLECT_TIMEOUT: Duration = Duration::from_secs(10);
const SHUTDOWN_TIMEOUT: Duration = Duration::from_secs(20);

/// What a run over several hosts needs to reach its agents.
pub struct HostsRun {
    pub placement: Placement,
    pub topology: Topology,
    pub run: String,
    /// The effective scenario, sent to every agent.
    pub scenario: String,
    pub centralized: bool,
    /// Where to keep every host's byte counts as they stand, once a
    /// second, for the live view's traffic; `None` without a view.
    pub traffic: Option<PathBuf>,
    /// The run's results folder, where the hosts' files come home.
    pub out: PathBuf,
}

/// How often the hosts send what the run has so far.
const PROGRESS_PERIOD: Duration = Duration::from_secs(5);

/// How often the hosts' byte counts are asked for while a view is open.
const TRAFFIC_PERIOD: Duration = Duration::from_secs(1);

/// What happened to the hosts, for the run's report.
#[derive(Debug, Default, Clone)]
pub struct HostEvents {
    /// (host, seconds since the start) of every loss and every return.
    pub lost: Vec<(String, f64)>,
    pub back: Vec<(String, f64)>,
}

enum Incoming {
    Command(Option<Command>),
    Alive {
        host: usize,
        /// The agent's session, which its token names.
        instance: String,
        up: bool,
    },
    Agent {
        host: usize,
        said: Option<FromAgent>,
    },
}

#[derive(Default)]
struct HostState {
    up: bool,
    /// The session of the agent last seen up.
    instance: Option<String>,
    set_up: bool,
    /// Lost at least once: its next set-up is a return.
    lost: bool,
    last_setup: Option<Instant>,
    /// Commands for it while it was not set up yet.
    pending: Vec<ToAgent>,
    counts: Option<(String, BridgeCounts, crate::supervisor::HostFiles)>,
    /// The counts of its last progress report: what a host lost for good
    /// leaves.
    progress: Option<(String, BridgeCounts)>,
    finished: bool,
}

/// Runs until every host finished after a [`Command::Shutdown`] (or the
/// timeout), then sends [`Event::AllReaped`]. Interrupts (Ctrl-C, SIGTERM,
/// SIGHUP) are reported as on one host.
pub fn supervise_hosts(
    setup: HostsRun,
    commands: UnboundedReceiver<Command>,
    events: mpsc::Sender<Event>,
) -> anyhow::Result<HostEvents> {
    let started = Instant::now();
    let hosts = setup.placement.hosts().to_vec();
    let endpoints: Vec<String> = hosts.iter().map(|h| h.endpoint.clone()).collect();
    let security = Security::for_role(&setup.placement, Role::Launcher)?;
    let launcher_host = setup.placement.host_of(fusion_graph::ActorId::Launcher);
    let shaping = super::relay_shaping(&setup.placement, launcher_host);
    let linked = open_session(
        None,
        &endpoints,
        Some(&hosts[launcher_host].endpoint),
        &security,
        shaping,
    )?;
    let session = &linked.session;
    let sender = session.zid().to_string();
    let (tx, rx) = mpsc::channel::<Incoming>();
    forward_commands(commands, tx.clone());
    forward_interrupts(events.clone());
    let mut keep = Vec::new();
    for (h, host) in hosts.iter().enumerate() {
        let tx = tx.clone();
        let sub = session
            .declare_subscriber(event_key(&host.name))
            .callback(move |sample| {
                let said = decode::<FromAgent>(&sample.payload().to_bytes());
                let _ = tx.send(Incoming::Agent { host: h, said });
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("subscribing to {}'s events: {e}", host.name))?;
        keep.push(sub);
    }
    let names: Vec<String> = hosts.iter().map(|h| h.name.clone()).collect();
    let alive_tx = tx.clone();
    let _liveliness = session
        .liveliness()
        .declare_subscriber("cqnet/agent/*/alive/*")
        .history(true)
        .callback(move |sample| {
            let key = sample.key_expr().as_str();
            let mut parts = key.split('/').skip(2);
            let name = parts.next().unwrap_or_default();
            let instance = parts.nth(1).unwrap_or_default().to_string();
            if let Some(host) = names.iter().position(|n| n == name) {
                let up = sample.kind() == zenoh::sample::SampleKind::Put;
                let _ = alive_tx.send(Incoming::Alive { host, instance, up });
            }
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("watching the agents' liveliness: {e}"))?;

    let mut state: Vec<HostState> = hosts.iter().map(|_| HostState::default()).collect();
    let mut report = HostEvents::default();
    let mut collecting: Option<Instant> = None;
    let mut shutting: Option<Instant> = None;
    let mut traffic_asked: Option<Instant> = None;
    let mut progress_asked = Instant::now();
    let mut traffic: Vec<Option<Accounting>> = hosts.iter().map(|_| None).collect();
    let send = |h: usize, c: &ToAgent| {
        let order = Order {
            run: setup.run.clone(),
            sender: sender.clone(),
            command: c.clone(),
        };
        if let Err(e) = put(session, &command_key(&hosts[h].name), encode(&order)) {
            tracing::warn!(host = %hosts[h].name, error = %e, "could not reach the agent");
        }
    };
    let setup_message = |after_loss: bool| ToAgent::Setup {
        run: setup.run.clone(),
        scenario: setup.scenario.clone(),
        centralized: setup.centralized,
        after_loss,
    };
    let actors_on = |h: usize| setup.placement.actors_on(h, &setup.topology);
    let mut lose_host = |s: &mut HostState, host: usize| {
        s.up = false;
        s.set_up = false;
        s.lost = true;
        s.pending.clear();
        report
            .lost
            .push((hosts[host].name.clone(), started.elapsed().as_secs_f64()));
        tracing::warn!(host = %hosts[host].name, "host lost");
        for actor in actors_on(host) {
            let _ = events.send(Event::Exited {
                actor,
                status: format!("lost with host {}", hosts[host].name),
                stderr_tail: String::new(),
            });
        }
    };
    loop {
        let incoming = rx.recv_timeout(Duration::from_millis(100));
        for (h, s) in state.iter_mut().enumerate() {
            if s.up && !s.set_up && s.last_setup.is_none_or(|t| t.elapsed() >= SETUP_RETRY) {
                send(h, &setup_message(s.lost));
                s.last_setup = Some(Instant::now());
            }
        }
        if setup.traffic.is_some()
            && shutting.is_none()
            && traffic_asked.is_none_or(|t| t.elapsed() >= TRAFFIC_PERIOD)
        {
            for (h, s) in state.iter().enumerate() {
                if s.set_up {
                    send(h, &ToAgent::Traffic);
                }
            }
            traffic_asked = Some(Instant::now());
        }
        if shutting.is_none() && collecting.is_none() && progress_asked.elapsed() >= PROGRESS_PERIOD
        {
            for (h, s) in state.iter().enumerate() {
                if s.set_up {
                    send(h, &ToAgent::Progress);
                }
            }
            progress_asked = Instant::now();
        }
        match incoming {
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Ok(Incoming::Alive {
                host,
                instance,
                up: true,
            }) => {
                let s = &mut state[host];
                let new = s.instance.as_ref() != Some(&instance);
                if new || !s.up {
                    if new && s.up && !s.finished {
                        // Started again before its old session's lease ran out.
                        lose_host(s, host);
                    }
                    s.instance = Some(instance);
                    s.up = true;
                    s.set_up = false;
                    s.last_setup = None;
                    s.finished = false;
                }
            }
            Ok(Incoming::Alive {
                host,
                instance,
                up: false,
            }) => {
                let s = &mut state[host];
                if s.instance.as_ref() != Some(&instance) {
                    // An agent already replaced.
                } else if s.up && s.finished {
                    // An agent leaving after its run finished (`--once`).
                    s.up = false;
                } else if s.up && shutting.is_some() {
                    // Leaving as the run ends, its `Finished` overtaken by
                    // the end of its token: not a loss.
                    s.up = false;
                    s.set_up = false;
                } else if s.up {
                    lose_host(s, host);
                }
            }
            Ok(Incoming::Agent { host, said: None }) => {
                tracing::warn!(host = %hosts[host].name, "a message from the agent did not decode; dropped");
            }
            Ok(Incoming::Agent {
                host,
                said: Some(said),
            }) => match said {
                FromAgent::SetUp { run } if run == setup.run => {
                    let s = &mut state[host];
                    if !s.set_up && s.up {
                        s.set_up = true;
                        for c in std::mem::take(&mut s.pending) {
                            send(host, &c);
                        }
                        if s.lost {
                            report
                                .back
                                .push((hosts[host].name.clone(), started.elapsed().as_secs_f64()));
                            let _ = events.send(Event::HostBack(actors_on(host)));
                        }
                    }
                }
                FromAgent::SetUp { .. } => {}
                FromAgent::Ready(a) => {
                    let _ = events.send(Event::Ready(a));
                }
                FromAgent::Exited {
                    actor,
                    status,
                    stderr_tail,
                } => {
                    let _ = events.send(Event::Exited {
                        actor,
                        status,
                        stderr_tail,
                    });
                }
                FromAgent::Failed { message } => {
                    // Told as the exit of its host's actors, so that a
                    // failed start ends the run with the agent's reason.
                    for actor in actors_on(host) {
                        let _ = events.send(Event::Exited {
                            actor,
                            status: format!("agent {} could not set the run up", hosts[host].name),
                            stderr_tail: message.clone(),
                        });
                    }
                }
                FromAgent::Counts {
                    accounting_csv,
                    bridge,
                    home,
                } => state[host].counts = Some((accounting_csv, bridge, home)),
                FromAgent::Progress {
                    accounting_csv,
                    bridge,
                    home,
                } => {
                    home.write_home(&hosts[host].name, &setup.out);
                    state[host].progress = Some((accounting_csv, bridge));
                }
                FromAgent::Traffic { accounting_csv } => {
                    traffic[host] = Accounting::from_csv(&accounting_csv, setup.topology.payloads);
                    if let Some(path) = &setup.traffic {
                        write_traffic(path, &traffic);
                    }
                }
                FromAgent::Finished => state[host].finished = true,
            },
            Ok(Incoming::Command(Some(command))) => match command {
                Command::Spawn { actor, rejoin } => {
                    let h = setup.placement.host_of(actor);
                    let c = ToAgent::Spawn { actor, rejoin };
                    if state[h].set_up {
                        send(h, &c);
                    } else if state[h].up || !state[h].lost {
                        // Not up yet at the start, or setting up.
                        state[h].pending.push(c);
                    } else {
                        let _ = events.send(Event::Exited {
                            actor,
                            status: format!("its host {} is lost", hosts[h].name),
                            stderr_tail: String::new(),
                        });
                    }
                }
                Command::Signal { actor, signal } => send(
                    setup.placement.host_of(actor),
                    &ToAgent::Signal { actor, signal },
                ),
                Command::Continue { actor } => {
                    send(setup.placement.host_of(actor), &ToAgent::Continue { actor })
                }
                Command::Collect => {
                    for (h, s) in state.iter_mut().enumerate() {
                        s.counts = None;
                        if s.set_up {
                            send(h, &ToAgent::Collect);
                        }
                    }
                    collecting = Some(Instant::now());
                }
                Command::Shutdown => {
                    for (h, s) in state.iter().enumerate() {
                        if s.set_up {
                            send(h, &ToAgent::Shutdown);
                        }
                    }
                    shutting = Some(Instant::now());
                }
            },
            Ok(Incoming::Command(None)) => shutting = shutting.or(Some(Instant::now())),
        }
        if let Some(since) = collecting {
            let all = state.iter().all(|s| !s.set_up || s.counts.is_some());
            if all || since.elapsed() >= COLLECT_TIMEOUT {
                let _ = events.send(merged_counts(&hosts, &state, setup.topology.payloads));
                collecting = None;
            }
        }
        if let Some(since) = shutting {
            let all = state.iter().all(|s| !s.set_up || s.finished);
            if all || since.elapsed() >= SHUTDOWN_TIMEOUT {
                if !all {
                    tracing::warn!("some agents did not finish in {SHUTDOWN_TIMEOUT:?}");
                }
                break;
            }
        }
    }
    let _ = events.send(Event::AllReaped);
    Ok(report)
}

/// Every host's latest byte counts, merged, where the live view reads
/// them.
fn write_traffic(path: &Path, traffic: &[Option<Accounting>]) {
    let mut all = Accounting::default();
    for a in traffic.iter().flatten() {
        all.merge(a);
    }
    if let Err(e) = crate::results::write_atomically(path, all.to_csv().as_bytes()) {
        tracing::warn!(error = %e, "could not write the hosts' traffic for the view");
    }
}

fn merged_counts(
    hosts: &[fusion_graph::hosts::HostConfig],
    state: &[HostState],
    payloads: wire::payloads::Payloads,
) -> Event {
    let mut accounting = Accounting::default();
    let mut bridges = Vec::new();
    let mut homes = Vec::new();
    for (host, s) in hosts.iter().zip(state) {
        match &s.counts {
            Some((csv, bridge, home)) => {
                match Accounting::from_csv(csv, payloads) {
                    Some(a) => accounting.merge(&a),
                    None => tracing::warn!(host = %host.name, "its byte counts did not parse"),
                }
                bridges.push((host.name.clone(), *bridge));
                homes.push((host.name.clone(), home.clone()));
            }
            None => match &s.progress {
                // Lost for good: what it last reported.
                Some((csv, bridge)) => {
                    tracing::warn!(host = %host.name, "the host's byte counts as of its last progress report");
                    if let Some(a) = Accounting::from_csv(csv, payloads) {
                        accounting.merge(&a);
                    }
                    bridges.push((host.name.clone(), *bridge));
                }
                None => tracing::warn!(host = %host.name, "no byte counts from this host"),
            },
        }
    }
    Event::Counts {
        accounting_csv: accounting.to_csv_with_world_misses(),
        bridges,
        homes,
    }
}

fn forward_commands(mut commands: UnboundedReceiver<Command>, tx: mpsc::Sender<Incoming>) {
    std::thread::spawn(move || loop {
        let c = commands.blocking_recv();
        let end = c.is_none();
        if tx.send(Incoming::Command(c)).is_err() || end {
            return;
        }
    });
}

/// Ctrl-C, SIGTERM and SIGHUP stop a run over several hosts as they stop
/// one on a single host.
fn forward_interrupts(events: mpsc::Sender<Event>) {
    std::thread::spawn(move || {
        let Ok(rt) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        else {
            return;
        };
        rt.block_on(async move {
            use tokio::signal::unix::{signal, SignalKind};
            let (Ok(mut term), Ok(mut hup)) = (
                signal(SignalKind::terminate()),
                signal(SignalKind::hangup()),
            ) else {
                return;
            };
            loop {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                    _ = hup.recv() => {}
                }
                if events.send(Event::Interrupted).is_err() {
                    return;
                }
            }
        });
    });
}

/// `cqnet run --local-agents`: one agent process per host on this
/// machine, each with its own folder under `out/hosts/`.
pub struct LocalAgents {
    children: Vec<std::process::Child>,
}

impl LocalAgents {
    pub fn start(
        placement: &Placement,
        scenario_file: &Path,
        out: &Path,
        run: &str,
    ) -> anyhow::Result<Self> {
        let exe = std::env::current_exe().context("finding the cqnet executable")?;
        let mut children = Vec::new();
        for host in placement.hosts() {
            let log =
                std::fs::File::create(out.join("logs").join(format!("agent-{}.log", host.name)))?;
            let mut cmd = std::process::Command::new(&exe);
            cmd.arg("agent")
                .arg(scenario_file)
                .arg("--host")
                .arg(&host.name)
                .arg("--dir")
                .arg(agent_dir(out, &host.name))
                .arg("--once")
                .arg("--run")
                .arg(run)
                .stdin(std::process::Stdio::null())
                .stdout(log.try_clone()?)
                .stderr(log);
            // Die with the launcher, whatever happens to it.
            unsafe {
                std::os::unix::process::CommandExt::pre_exec(&mut cmd, || {
                    nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGKILL)
                        .map_err(std::io::Error::from)
                });
            }
            children.push(
                cmd.spawn()
                    .with_context(|| format!("starting agent {}", host.name))?,
            );
        }
        Ok(Self { children })
    }

    /// Waits for every agent to exit, killing those still there after
    /// `grace`.
    pub fn reap(mut self, grace: Duration) {
        let deadline = Instant::now() + grace;
        for c in &mut self.children {
            while Instant::now() < deadline && matches!(c.try_wait(), Ok(None)) {
                std::thread::sleep(Duration::from_millis(20));
            }
            if matches!(c.try_wait(), Ok(None)) {
                let _ = c.kill();
            }
            let _ = c.wait();
        }
        self.children.clear();
    }
}

impl Drop for LocalAgents {
    fn drop(&mut self) {
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// Where a local agent of host `name` keeps its runs.
pub fn agent_dir(out: &Path, name: &str) -> PathBuf {
    out.join("hosts").join(name)
}
