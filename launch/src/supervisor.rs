//! Process supervision for `cqnet run`: spawns one child per actor (this same
//! executable, hidden `actor` subcommand), watches for its `ready` line,
//! keeps the tail of its stderr and a log file, delivers signals, restarts,
//! and at the end stops and reaps every child, whatever happened.

use std::collections::{HashMap, VecDeque};
use std::ffi::OsString;
use std::os::fd::OwnedFd;
use std::os::unix::process::ExitStatusExt;
use std::path::PathBuf;
use std::process::ExitStatus;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use fusion_graph::scenario::Signal;
use fusion_graph::ActorId;
use nix::sys::signal::{kill, Signal as NixSignal};
use nix::unistd::Pid;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::signal::unix::{signal as unix_signal, SignalKind};
use tokio::sync::mpsc::UnboundedReceiver;

use crate::spawner::{Spawned, Spawner};

/// Lines of a child's output kept for error messages (its stderr: its
/// stdout carries only the `ready` line, which is not kept).
const STDERR_TAIL_LINES: usize = 20;
/// After asking children to stop: wait this long, then SIGTERM, then SIGKILL.
const GRACE: Duration = Duration::from_secs(3);

/// What the world thread asks of the supervisor.
#[derive(Debug)]
pub enum Command {
    Spawn {
        actor: ActorId,
        rejoin: bool,
    },
    Signal {
        actor: ActorId,
        signal: Signal,
    },
    /// SIGCONT a stopped child.
    Continue {
        actor: ActorId,
    },
    /// Several hosts: send the byte counts of every host's actors and
    /// bridge ([`Event::Counts`]). One host's supervisor has none to send:
    /// its children's ledgers are on this machine.
    Collect,
    /// Every child should be exiting now: wait, then terminate the rest.
    Shutdown,
}

/// What the supervisor reports to the world thread.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    Ready(ActorId),
    Exited {
        actor: ActorId,
        status: String,
        stderr_tail: String,
    },
    /// Every child has exited and been reaped.
    AllReaped,
    Interrupted,
    /// Several hosts: a lost host's agent is back, and these, its actors,
    /// can be started again.
    HostBack(Vec<ActorId>),
    /// Several hosts: the answer to [`Command::Collect`]. Every host's
    /// actors' counts merged (`Accounting::to_csv`), and each host's
    /// bridge's counts by host name; a host that did not answer is missing.
    Counts {
        accounting_csv: String,
        bridges: Vec<(String, fusion_graph::hosts::BridgeCounts)>,
        /// What each host that answered sent home, by host name.
        homes: Vec<(String, HostFiles)>,
    },
}

/// What a host sends home at the end of a run: its actors' logs and
/// memory and CPU files, by their path in a run's results folder
/// (`logs/<actor>.log`, `accounting/<actor>.memory`, …), and the CPU its
/// agent and the actors it reaped used.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HostFiles {
    pub files: Vec<(String, Vec<u8>)>,
    pub cpu_seconds: Option<f64>,
}

impl HostFiles {
    /// Writes the files into the results folder `out`, where a run on one
    /// host leaves the same files (`logs/`, `accounting/`). A path outside
    /// those two folders is refused and said.
    pub fn write_home(&self, host: &str, out: &std::path::Path) {
        for (path, bytes) in &self.files {
            if !Self::is_allowed(path) {
                tracing::warn!(
                    host,
                    path,
                    "a file from a host outside logs/ and accounting/; dropped"
                );
                continue;
            }
            let to = out.join(path);
            let written = to
                .parent()
                .map_or(Ok(()), std::fs::create_dir_all)
                .and_then(|()| std::fs::write(&to, bytes));
            if let Err(e) = written {
                tracing::warn!(host, path, error = %e, "could not bring a host's file home");
            }
        }
    }

    /// Whether `path` is one a host may send: `logs/` or `accounting/`
    /// and a plain file name (what comes over the network is not trusted
    /// to stay inside the results folder).
    pub fn is_allowed(path: &str) -> bool {
        let Some((folder, name)) = path.split_once('/') else {
            return false;
        };
        matches!(folder, "logs" | "accounting")
            && !name.is_empty()
            && name.len() <= 64
            && name != "."
            && name != ".."
            && name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'))
    }
}

/// The program that runs an actor, and the arguments it takes before
/// `actor …`: this executable by default. A program that carries cqnet as
/// a library (the Python package) names the interpreter and how to reach
/// cqnet's entry point through it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActorProgram {
    pub program: PathBuf,
    pub leading_args: Vec<std::ffi::OsString>,
}

/// What [`ActorProgram::for_this_process`] gives in a process whose
/// executable is not cqnet (a Python interpreter running the package's
/// `cqnet` command).
static HOST_PROGRAM: std::sync::OnceLock<ActorProgram> = std::sync::OnceLock::new();

impl ActorProgram {
    /// How this process starts an actor: the running executable, which is
    /// `cqnet` itself, unless a host program said otherwise
    /// ([`ActorProgram::set_for_this_process`]).
    pub fn for_this_process() -> anyhow::Result<Self> {
        use anyhow::Context;
        if let Some(p) = HOST_PROGRAM.get() {
            return Ok(p.clone());
        }
        Ok(Self {
            program: std::env::current_exe().context("finding the cqnet executable")?,
            leading_args: Vec::new(),
        })
    }

    /// A program that carries cqnet as a library says, once, how its
    /// actors start; false if it had already said.
    pub fn set_for_this_process(self) -> bool {
        HOST_PROGRAM.set(self).is_ok()
    }
}

/// How to start a child.
#[derive(Debug, Clone)]
pub struct ChildSpec {
    pub program: ActorProgram,
    pub run_id: String,
    pub scenario_file: PathBuf,
    pub log_dir: PathBuf,
    pub centralized: bool,
    /// Which core each actor runs on, if the run places them.
    pub cores: Option<crate::cores::CorePlacement>,
}

struct Child {
    pid: Option<u32>,
    done: tokio::sync::watch::Receiver<bool>,
}

/// The next delivery of a signal we listen for; never, if we could not.
async fn next_signal(listener: &mut Option<tokio::signal::unix::Signal>) -> Option<()> {
    match listener {
        Some(l) => l.recv().await,
        None => std::future::pending().await,
    }
}

pub async fn supervise(
    spec: ChildSpec,
    mut commands: UnboundedReceiver<Command>,
    events: std::sync::mpsc::Sender<Event>,
) {
    let mut children: HashMap<ActorId, Child> = HashMap::new();
    // Dropped after every child is reaped: children die with the thread
    // that started them.
    let spawner = Spawner::start();
    // SIGTERM (what `timeout`, systemd and CI send) and SIGHUP (a closed
    // terminal) stop a run exactly as Ctrl-C does: children stopped and
    // reaped, shared memory removed, results written.
    let mut terminate = unix_signal(SignalKind::terminate()).ok();
    let mut hangup = unix_signal(SignalKind::hangup()).ok();
    loop {
        let command = tokio::select! {
            c = commands.recv() => c,
            _ = tokio::signal::ctrl_c() => {
                let _ = events.send(Event::Interrupted);
                continue;
            }
            Some(()) = next_signal(&mut terminate) => {
                let _ = events.send(Event::Interrupted);
                continue;
            }
            Some(()) = next_signal(&mut hangup) => {
                let _ = events.send(Event::Interrupted);
                continue;
            }
        };
        match command {
            Some(Command::Spawn { actor, rejoin }) => {
                let started = spawner
                    .as_ref()
                    .map_err(|e| std::io::Error::new(e.kind(), format!("no spawner thread: {e}")))
                    .and_then(|spawner| spawn(spawner, &spec, actor, rejoin, events.clone()));
                match started {
                    Ok(child) => {
                        children.insert(actor, child);
                    }
                    Err(e) => {
                        let _ = events.send(Event::Exited {
                            actor,
                            status: format!("could not start: {e}"),
                            stderr_tail: String::new(),
                        });
                    }
                }
            }
            Some(Command::Signal { actor, signal }) => {
                if let Some(pid) = children.get(&actor).and_then(|c| c.pid) {
                    let sig = match signal {
                        Signal::Kill => NixSignal::SIGKILL,
                        Signal::Term => NixSignal::SIGTERM,
                        Signal::Stop => NixSignal::SIGSTOP,
                    };
                    let _ = kill(Pid::from_raw(pid as i32), sig);
                }
            }
            Some(Command::Continue { actor }) => {
                if let Some(pid) = children.get(&actor).and_then(|c| c.pid) {
                    let _ = kill(Pid::from_raw(pid as i32), NixSignal::SIGCONT);
                }
            }
            Some(Command::Collect) => {}
            Some(Command::Shutdown) | None => break,
        }
    }
    reap_all(&mut children).await;
    let _ = events.send(Event::AllReaped);
}

/// Waits for every child; what has not exited after the grace period gets
/// SIGTERM (stopped ones SIGCONT first), then SIGKILL.
async fn reap_all(children: &mut HashMap<ActorId, Child>) {
    let all_done = |children: &HashMap<ActorId, Child>| children.values().all(|c| *c.done.borrow());
    for (signal, wait) in [
        (None, GRACE),
        (Some(NixSignal::SIGTERM), GRACE),
        (Some(NixSignal::SIGKILL), GRACE),
    ] {
        if let Some(sig) = signal {
            for c in children.values().filter(|c| !*c.done.borrow()) {
                if let Some(pid) = c.pid {
                    let _ = kill(Pid::from_raw(pid as i32), NixSignal::SIGCONT);
                    let _ = kill(Pid::from_raw(pid as i32), sig);
                }
            }
        }
        let deadline = tokio::time::Instant::now() + wait;
        while !all_done(children) && tokio::time::Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        if all_done(children) {
            return;
        }
    }
}

fn spawn(
    spawner: &Spawner,
    spec: &ChildSpec,
    actor: ActorId,
    rejoin: bool,
    events: std::sync::mpsc::Sender<Event>,
) -> std::io::Result<Child> {
    let mut args = spec.program.leading_args.clone();
    args.extend(
        [
            "actor",
            "--run-id",
            &spec.run_id,
            "--actor",
            &actor.to_string(),
            "--scenario",
        ]
        .map(OsString::from),
    );
    args.push(spec.scenario_file.clone().into());
    if spec.centralized {
        args.push("--centralized".into());
    }
    if rejoin {
        args.push("--rejoin".into());
    }
    if let Some(core) = spec.cores.as_ref().and_then(|c| c.core_of(actor)) {
        args.extend(["--core".into(), core.to_string().into()]);
    }
    // One pipe for the child's stdout and stderr: the launcher holds one
    // descriptor per child for its output instead of two, and opens its
    // log file only when it has something to say. At 2,600 children the
    // launcher's descriptors are what limits the network (ulimit -n).
    let Spawned { pid, output, pidfd } = spawner
        .spawn(spec.program.program.clone(), args)
        .map_err(|e| {
            std::io::Error::new(e.kind(), format!("{}: {e}", spec.program.program.display()))
        })?;
    // Killed and reaped if the supervisor goes before it has waited for it.
    let exit = ExitWatch::new(pid, pidfd)?;
    let pid = Some(pid);
    let output = tokio::net::unix::pipe::Receiver::from_owned_fd(output)?;
    let tail = Arc::new(Mutex::new(VecDeque::new()));
    let (done_tx, done_rx) = tokio::sync::watch::channel(false);

    let log_path = spec.log_dir.join(format!("{actor}.log"));
    let output_tail = tail.clone();
    let ready_events = events.clone();
    let output_done = tokio::spawn(async move {
        let mut log: Option<tokio::fs::File> = None;
        let mut lines = BufReader::new(output).lines();
        while let Ok(Some(line)) = lines.next_line().await {
            if line.trim() == "ready" {
                let _ = ready_events.send(Event::Ready(actor));
                continue;
            }
            if log.is_none() {
                log = tokio::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(&log_path)
                    .await
                    .ok();
            }
            if let Some(f) = log.as_mut() {
                let _ = f.write_all(format!("{line}\n").as_bytes()).await;
            }
            let mut t = output_tail.lock().expect("tail lock");
            if t.len() == STDERR_TAIL_LINES {
                t.pop_front();
            }
            t.push_back(line);
        }
    });
    let exit_tail = tail.clone();
    tokio::spawn(async move {
        let status = exit
            .wait()
            .await
            .map_or_else(|e| format!("wait failed: {e}"), |s| s.to_string());
        // Let the output reader take the last lines before reporting.
        let _ = tokio::time::timeout(Duration::from_millis(500), output_done).await;
        let stderr_tail = exit_tail
            .lock()
            .expect("tail lock")
            .iter()
            .cloned()
            .collect::<Vec<_>>()
            .join("\n");
        let _ = done_tx.send(true);
        let _ = events.send(Event::Exited {
            actor,
            status,
            stderr_tail,
        });
    });
    Ok(Child { pid, done: done_rx })
}

/// A child's exit, watched through its pidfd. A child not yet waited for
/// when this is dropped (the supervisor gone) is killed and reaped.
struct ExitWatch {
    pid: u32,
    pidfd: AsyncFd<OwnedFd>,
    reaped: bool,
}

impl ExitWatch {
    fn new(pid: u32, pidfd: OwnedFd) -> std::io::Result<Self> {
        // SAFETY: the AsyncFd owns the OwnedFd, which stays open and the same
        // descriptor until the AsyncFd is dropped.
        let pidfd =
            unsafe { AsyncFd::register_with_interest(pidfd, tokio::io::Interest::READABLE) }
                .map_err(|e| {
                    // Unwatchable: not left running.
                    let _ = kill(Pid::from_raw(pid as i32), NixSignal::SIGKILL);
                    let _ = wait_for_exit(pid);
                    std::io::Error::from(e)
                })?;
        Ok(Self {
            pid,
            pidfd,
            reaped: false,
        })
    }

    async fn wait(mut self) -> std::io::Result<ExitStatus> {
        // Readable once the child has exited: the wait below returns at once.
        let _exited = self.pidfd.readable().await?;
        let status = wait_for_exit(self.pid)?;
        self.reaped = true;
        Ok(status)
    }
}

impl Drop for ExitWatch {
    fn drop(&mut self) {
        if !self.reaped {
            let _ = kill(Pid::from_raw(self.pid as i32), NixSignal::SIGKILL);
            let _ = wait_for_exit(self.pid);
        }
    }
}

/// Reaps child `pid`, waiting for it to exit.
fn wait_for_exit(pid: u32) -> std::io::Result<ExitStatus> {
    let mut status = 0;
    loop {
        // SAFETY: waitpid writes the status of our own child `pid`.
        if unsafe { libc::waitpid(pid as i32, &mut status, 0) } == pid as i32 {
            return Ok(ExitStatus::from_raw(status));
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}
