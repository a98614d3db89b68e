//! Building a network and launching it: `cqnet run` as a child process with
//! its own run id and output folder, watched, bounded in time and cleaned up.

use fusion_graph::vocabulary::Vocabulary;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use fusion_graph::scenario::{Fault, Scenario};
use fusion_graph::ActorId;
use fusion_graph::RunId;

use crate::cleanup::{kill_and_clean, processes_matching};
use crate::results::{read_ticks, Run};
use crate::separate_hosts::SeparateHosts;
use crate::Error;

/// The longest a network may run before it is killed and its test fails,
/// unless [`Network::time_limit`] says otherwise: a hung run then fails its
/// test instead of holding CI until CI's own limit.
pub const DEFAULT_TIME_LIMIT: Duration = Duration::from_secs(300);

/// Where a scenario comes from.
#[derive(Debug, Clone)]
enum Source {
    Value(Box<Scenario>),
    /// Passed to `cqnet` as it is, so the program's own reading (and its
    /// errors) are what a test sees.
    File(PathBuf),
}

/// A network to launch: a scenario, faults, and how to run it.
#[derive(Debug, Clone)]
pub struct Network {
    source: Source,
    faults: Vec<Fault>,
    overrides: Vec<String>,
    executable: Option<PathBuf>,
    lockstep: bool,
    centralized: bool,
    extra_args: Vec<String>,
    env: Vec<(String, String)>,
    tag: String,
    time_limit: Duration,
    /// Each host in a namespace of its own ([`Network::on_separate_hosts`]).
    separate: Option<Arc<SeparateHosts>>,
    /// The parts of the program under test, which the scenario may name.
    vocabulary: Vocabulary,
}

impl Network {
    /// A network of `scenario`, run in real time with the centralized reference.
    pub fn new(scenario: Scenario) -> Self {
        Self::with_source(Source::Value(Box::new(scenario)))
    }

    /// A network of the scenario file at `path`, which `cqnet` itself reads
    /// (a bad file is the run's error, not this call's).
    pub fn from_file(path: impl Into<PathBuf>) -> Self {
        Self::with_source(Source::File(path.into()))
    }

    fn with_source(source: Source) -> Self {
        Self {
            source,
            faults: Vec::new(),
            overrides: Vec::new(),
            executable: None,
            lockstep: false,
            centralized: true,
            extra_args: Vec::new(),
            env: Vec::new(),
            tag: "run".into(),
            time_limit: DEFAULT_TIME_LIMIT,
            separate: None,
            vocabulary: Vocabulary::BUILT_IN,
        }
    }

    /// The parts of the program under test (its [`cqnet::App`]'s
    /// vocabulary), when its scenario names parts of its own: the test
    /// reads the scenario and the run's files in them.
    pub fn parts(mut self, vocabulary: Vocabulary) -> Self {
        self.vocabulary = vocabulary;
        self
    }

    /// Runs each host of the scenario (`[[hosts]]`, `--features zenoh`) in
    /// its own network and mount namespace of `hosts`: the launcher and
    /// the first host's agent in the first, each other host's agent in its
    /// own. The scenario's endpoints must be the namespaces' addresses
    /// ([`SeparateHosts::place`]).
    pub fn on_separate_hosts(mut self, hosts: &Arc<SeparateHosts>) -> Self {
        self.separate = Some(hosts.clone());
        self
    }

    /// The `cqnet` program to run (see the crate's documentation for the
    /// default).
    pub fn executable(mut self, path: impl Into<PathBuf>) -> Self {
        self.executable = Some(path.into());
        self
    }

    /// Start each step as soon as every live node reported: deterministic,
    /// and bit for bit what `cqnet sim` computes.
    pub fn lockstep(mut self) -> Self {
        self.lockstep = true;
        self
    }

    /// Leave out the launcher's centralized reference (and the observations
    /// every sensor would send it).
    pub fn no_central(mut self) -> Self {
        self.centralized = false;
        self
    }

    /// Adds a fault to the scenario's schedule.
    pub fn fault(mut self, fault: impl Into<Fault>) -> Self {
        self.faults.push(fault.into());
        self
    }

    /// Overrides a scenario value as `cqnet --set key=value` does (`value`
    /// in TOML: `"4"`, `"[3, 3]"`, `"\"pcrlb\""`). A bad key or value is the
    /// run's error, named by `cqnet`.
    pub fn set(mut self, key: &str, value: impl std::fmt::Display) -> Self {
        self.overrides.push(format!("{key}={value}"));
        self
    }

    /// More arguments for `cqnet run` (`--view`, say).
    pub fn arg(mut self, arg: impl Into<String>) -> Self {
        self.extra_args.push(arg.into());
        self
    }

    /// An environment variable for the launcher and, through it, every actor.
    pub fn env(mut self, key: impl Into<String>, value: impl Into<String>) -> Self {
        self.env.push((key.into(), value.into()));
        self
    }

    /// A word for the run id and output folder, to tell runs apart (a-z, 0-9, -).
    pub fn tag(mut self, tag: &str) -> Self {
        self.tag = tag
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() {
                    c.to_ascii_lowercase()
                } else {
                    '-'
                }
            })
            .collect();
        self
    }

    /// How long the run may take before it is killed.
    pub fn time_limit(mut self, limit: Duration) -> Self {
        self.time_limit = limit;
        self
    }

    /// Launches the network, waits for it to finish and reads its results.
    pub fn run(self) -> Result<Run, Error> {
        self.start()?.wait()
    }

    /// Launches the network and returns at once, to watch it, signal it or
    /// open its view while it runs.
    pub fn start(self) -> Result<RunningNetwork, Error> {
        let (executable, run_id, out, mut command) = self.command("run", &self.tag)?;
        command.arg("--run-id").arg(run_id.as_str());
        if self.lockstep {
            command.arg("--lockstep");
        }
        command.args(&self.extra_args);
        let Some(hosts) = &self.separate else {
            return self.spawn(command, executable, run_id, out);
        };
        let scenario = self.effective_scenario()?;
        hosts.apply_links(&scenario)?;
        let (mut command, agents) = on_separate_hosts(hosts, command, &out)?;
        command.env(launch::network::HOST_LINKS_APPLIED, "1");
        let cuts = schedule_cuts(hosts, &scenario, &out, self.time_limit);
        let mut running = self.spawn(command, executable, run_id, out)?;
        running.agents = agents;
        running.hosts = Some(hosts.clone());
        running.cuts = cuts;
        Ok(running)
    }

    /// Runs the same scenario in one process with `cqnet sim` (in-memory
    /// transport, virtual clock), for a reference to compare a network with.
    pub fn sim(self) -> Result<Run, Error> {
        let (executable, run_id, out, command) =
            self.command("sim", &format!("{}-sim", self.tag))?;
        self.spawn(command, executable, run_id, out)?.wait()
    }

    /// `cqnet <subcommand>` with a fresh run id, its own (emptied) output
    /// folder and the scenario's arguments.
    fn command(
        &self,
        subcommand: &str,
        tag: &str,
    ) -> Result<(PathBuf, RunId, PathBuf, Command), Error> {
        let executable = self.resolve_executable()?;
        let run_id = new_run_id(tag)?;
        let out = std::env::temp_dir()
            .join("cqnet-testkit")
            .join(run_id.as_str());
        let _ = std::fs::remove_dir_all(&out);
        let mut command = Command::new(&executable);
        command.arg(subcommand);
        self.scenario_args(&mut command, &out, run_id.as_str())?;
        command.arg("--out").arg(&out);
        Ok((executable, run_id, out, command))
    }

    /// The scenario as the run reads it: the file or value, the added
    /// faults and the overrides.
    fn effective_scenario(&self) -> Result<Scenario, Error> {
        let mut scenario = match &self.source {
            Source::Value(s) => (**s).clone(),
            Source::File(path) => Scenario::load_in(self.vocabulary, path, &[])?,
        };
        scenario.faults.extend(self.faults.iter().cloned());
        Ok(Scenario::from_toml_in(
            self.vocabulary,
            &scenario.to_toml(),
            "<the run's scenario>",
            &self.overrides,
        )?)
    }

    /// The scenario (file or value, with the added faults), overrides and
    /// reference flags.
    fn scenario_args(&self, command: &mut Command, out: &Path, run_id: &str) -> Result<(), Error> {
        let written = match (&self.source, self.faults.is_empty()) {
            (Source::File(path), true) => path.clone(),
            (source, _) => {
                let mut scenario = match source {
                    Source::Value(s) => (**s).clone(),
                    Source::File(path) => Scenario::load_in(self.vocabulary, path, &[])?,
                };
                scenario.faults.extend(self.faults.iter().cloned());
                let write_err = |source| Error::WriteScenario {
                    run_id: run_id.to_string(),
                    source,
                };
                std::fs::create_dir_all(out).map_err(write_err)?;
                #[cfg(feature = "zenoh")]
                if self.separate.is_some() {
                    // As `--local-agents` makes them for its own agents.
                    launch::hosts::trust::add_run_keys(&mut scenario, &out.join("keys"))
                        .map_err(|e| Error::Host(format!("{e:#}")))?;
                }
                let path = out.with_extension("toml");
                std::fs::write(&path, scenario.to_toml()).map_err(write_err)?;
                path
            }
        };
        command.arg(written);
        for o in &self.overrides {
            command.arg("--set").arg(o);
        }
        if !self.centralized {
            command.arg("--no-central");
        }
        for (k, v) in &self.env {
            command.env(k, v);
        }
        Ok(())
    }

    fn spawn(
        &self,
        mut command: Command,
        executable: PathBuf,
        run_id: RunId,
        out: PathBuf,
    ) -> Result<RunningNetwork, Error> {
        let mut child = command
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|source| Error::Spawn {
                executable: executable.display().to_string(),
                source,
            })?;
        let stdout = Captured::drain(child.stdout.take().map(|p| Box::new(p) as _));
        let stderr = Captured::drain(child.stderr.take().map(|p| Box::new(p) as _));
        Ok(RunningNetwork {
            child: Some(child),
            run_id,
            out,
            executable,
            stdout,
            stderr,
            started: Instant::now(),
            time_limit: self.time_limit,
            handed_over: false,
            agents: Vec::new(),
            hosts: None,
            cuts: None,
            vocabulary: self.vocabulary,
        })
    }

    fn resolve_executable(&self) -> Result<PathBuf, Error> {
        if let Some(path) = &self.executable {
            return Ok(path.clone());
        }
        if let Some(path) = std::env::var_os("CQNET_BIN") {
            return Ok(PathBuf::from(path));
        }
        if let Some(path) = built_cqnet() {
            return Ok(path);
        }
        std::env::var_os("PATH")
            .and_then(|paths| {
                std::env::split_paths(&paths)
                    .map(|dir| dir.join("cqnet"))
                    .find(|p| p.is_file())
            })
            .ok_or(Error::ExecutableNotFound)
    }
}

/// `cqnet` as Cargo built it: beside the test executable (a test runs from
/// `target/<profile>/deps` or `examples`, `cqnet` is in `target/<profile>`),
/// or in the `target` folder of the current directory's workspace (where
/// doc-tests run from), the newest build first.
fn built_cqnet() -> Option<PathBuf> {
    let beside = std::env::current_exe().ok().and_then(|exe| {
        exe.ancestors()
            .skip(1)
            .take(3)
            .map(|dir| dir.join("cqnet"))
            .find(|p| p.is_file())
    });
    if beside.is_some() {
        return beside;
    }
    let cwd = std::env::current_dir().ok()?;
    let target = cwd
        .ancestors()
        .map(|d| d.join("target"))
        .find(|t| t.is_dir())?;
    ["release", "debug"]
        .iter()
        .map(|profile| target.join(profile).join("cqnet"))
        .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
        .max()
        .map(|(_, p)| p)
}

/// The launcher's command moved into the first host's namespace, with that
/// host's agent started beside it (in the same mount namespace, so that
/// they share its `/dev/shm`), and the other hosts' agents started in
/// theirs, each serving one run and logging to `out/logs/agent-<host>.log`.
fn on_separate_hosts(
    hosts: &SeparateHosts,
    launcher: Command,
    out: &Path,
) -> Result<(Command, Vec<Child>), Error> {
    let logs = out.join("logs");
    let spawn_err = |source| Error::Spawn {
        executable: "ip netns exec".into(),
        source,
    };
    std::fs::create_dir_all(&logs).map_err(spawn_err)?;
    let exe = launcher.get_program().to_owned();
    let args: Vec<std::ffi::OsString> = launcher.get_args().map(|a| a.to_owned()).collect();
    // `run <scenario file> …`: the agents read their endpoints from it.
    let scenario = args.get(1).cloned().unwrap_or_default();
    let names: Vec<String> = hosts.hosts().map(str::to_string).collect();
    let agent_args = |name: &str| -> Vec<std::ffi::OsString> {
        vec![
            "agent".into(),
            scenario.clone(),
            "--host".into(),
            name.into(),
            "--dir".into(),
            out.join("hosts").join(name).into_os_string(),
            "--once".into(),
        ]
    };
    let log = |name: &str| -> Result<(Stdio, Stdio), Error> {
        let f = std::fs::File::create(logs.join(format!("agent-{name}.log"))).map_err(spawn_err)?;
        Ok((f.try_clone().map_err(spawn_err)?.into(), f.into()))
    };
    let mut agents = Vec::new();
    for name in names.iter().skip(1) {
        let (stdout, stderr) = log(name)?;
        let agent = hosts
            .command(name, &exe)
            .args(agent_args(name))
            // The kernel shapes these hosts' links (`apply_links`): no relay.
            .env(launch::network::HOST_LINKS_APPLIED, "1")
            .stdin(Stdio::null())
            .stdout(stdout)
            .stderr(stderr)
            .spawn()
            .map_err(spawn_err)?;
        agents.push(agent);
    }
    let first = &names[0];
    let agent_log = logs.join(format!("agent-{first}.log"));
    let mut command = hosts.command_with_companion(first, &exe, &agent_args(first), &agent_log);
    command.args(&args);
    for (k, v) in launcher.get_envs() {
        match v {
            Some(v) => command.env(k, v),
            None => command.env_remove(k),
        };
    }
    Ok((command, agents))
}

/// The cuts a scenario's host links ask for, done on a thread of their
/// own as the run reaches their steps (read from `ticks.csv`): the link
/// goes down at `cut_at_step` and up again `cut_steps` steps later, or
/// when the run ends.
struct CutSchedule {
    stop: Arc<std::sync::atomic::AtomicBool>,
    thread: JoinHandle<()>,
}

impl CutSchedule {
    fn stop(self) {
        self.stop.store(true, Ordering::Relaxed);
        let _ = self.thread.join();
    }
}

fn schedule_cuts(
    hosts: &Arc<SeparateHosts>,
    scenario: &Scenario,
    out: &Path,
    limit: Duration,
) -> Option<CutSchedule> {
    // (step, host, down): in step order.
    let mut events: Vec<(u32, String, bool)> = Vec::new();
    for h in &scenario.hosts {
        if let Some(at) = h.link.as_ref().and_then(|l| l.cut_at_step) {
            let steps = h.link.as_ref().map_or(0, |l| l.cut_steps);
            events.push((at, h.name.clone(), true));
            events.push((at + steps, h.name.clone(), false));
        }
    }
    if events.is_empty() {
        return None;
    }
    events.sort();
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (hosts, ticks, stopping) = (hosts.clone(), out.join("ticks.csv"), stop.clone());
    let thread = std::thread::spawn(move || {
        let deadline = Instant::now() + limit;
        let mut down: Vec<String> = Vec::new();
        for (step, host, cut) in events {
            while !stopping.load(Ordering::Relaxed)
                && Instant::now() < deadline
                && latest_step(&ticks) < step.saturating_sub(1)
            {
                std::thread::sleep(Duration::from_millis(2));
            }
            if stopping.load(Ordering::Relaxed) || Instant::now() >= deadline {
                break;
            }
            let done = if cut {
                down.push(host.clone());
                hosts.cut(&host)
            } else {
                down.retain(|h| *h != host);
                hosts.restore(&host)
            };
            if let Err(e) = done {
                eprintln!("cqnet-testkit: {e}");
            }
        }
        // A cut the run did not live to end is ended for the agents to leave.
        for host in down {
            let _ = hosts.restore(&host);
        }
    });
    Some(CutSchedule { stop, thread })
}

/// The latest step in `ticks.csv` so far (0 before any).
fn latest_step(ticks: &Path) -> u32 {
    std::fs::read_to_string(ticks)
        .ok()
        .and_then(|t| {
            t.lines()
                .skip(1)
                .filter_map(|l| l.split(',').next()?.parse::<u32>().ok())
                .max()
        })
        .unwrap_or(0)
}

/// A run id unique to this process and call: `t<pid>-<tag>-<n>`.
fn new_run_id(tag: &str) -> Result<RunId, Error> {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let id = format!(
        "t{}-{tag}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    );
    RunId::new(&id).map_err(|e| Error::RunId(id, e.to_string()))
}

/// Whom to signal in a running network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// The launcher (`cqnet run` itself).
    Launcher,
    /// One node or sensor process.
    Actor(ActorId),
    /// The agent of the host of this name, as `cqnet run --local-agents`
    /// starts it (several hosts, `--features zenoh`).
    Agent(&'static str),
}

/// A pipe read to its end on a thread, readable while it fills.
struct Captured {
    bytes: Arc<Mutex<Vec<u8>>>,
    reader: Option<JoinHandle<()>>,
}

impl Captured {
    fn drain(pipe: Option<Box<dyn Read + Send>>) -> Self {
        let bytes = Arc::new(Mutex::new(Vec::new()));
        let sink = bytes.clone();
        let reader = std::thread::spawn(move || {
            let Some(mut pipe) = pipe else { return };
            let mut buf = [0u8; 4096];
            while let Ok(n) = pipe.read(&mut buf) {
                if n == 0 {
                    break;
                }
                sink.lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .extend_from_slice(&buf[..n]);
            }
        });
        Self {
            bytes,
            reader: Some(reader),
        }
    }

    fn text(&self) -> String {
        String::from_utf8_lossy(&self.bytes.lock().unwrap_or_else(|p| p.into_inner())).into_owned()
    }

    fn finish(mut self) -> String {
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
        self.text()
    }
}

/// A network that is running. Dropping it kills every process of the run
/// and removes the run's shared memory.
pub struct RunningNetwork {
    child: Option<Child>,
    run_id: RunId,
    out: PathBuf,
    executable: PathBuf,
    stdout: Captured,
    stderr: Captured,
    started: Instant,
    time_limit: Duration,
    /// `wait` made a `Run`, which cleans up when it is dropped.
    handed_over: bool,
    /// The agents of hosts in namespaces of their own, but the launcher's.
    agents: Vec<Child>,
    /// The namespaces, kept until the run is over.
    hosts: Option<Arc<SeparateHosts>>,
    /// The thread that cuts and restores host links at their steps.
    cuts: Option<CutSchedule>,
    /// The program's parts, which its files may name.
    vocabulary: Vocabulary,
}

impl RunningNetwork {
    /// The run's id, on every process's command line and in its shared memory's names.
    pub fn run_id(&self) -> &str {
        self.run_id.as_str()
    }

    /// The run's output folder (`ticks.csv`, `links.csv`, `summary.json`, logs).
    pub fn out_dir(&self) -> &Path {
        &self.out
    }

    /// The launcher's stderr so far.
    pub fn stderr_so_far(&self) -> String {
        self.stderr.text()
    }

    /// Waits until the launcher's stderr has a line containing `needle`,
    /// and returns that line (None after `timeout`, or if the launcher ended).
    pub fn wait_for_stderr_line(&mut self, needle: &str, timeout: Duration) -> Option<String> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Some(line) = self.stderr.text().lines().find(|l| l.contains(needle)) {
                return Some(line.to_string());
            }
            if self.has_exited() {
                return None;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        None
    }

    /// Waits until `ticks.csv` has a row of `step` or later (polled every
    /// 2 ms, so what follows lands early in the next step); false after
    /// `timeout` or if the launcher ended first.
    pub fn wait_for_step(&mut self, step: u32, timeout: Duration) -> bool {
        let ticks = self.out.join("ticks.csv");
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            let reached = std::fs::read_to_string(&ticks).is_ok_and(|t| {
                t.lines()
                    .skip(1)
                    .filter_map(|l| l.split(',').next()?.parse::<u32>().ok())
                    .any(|s| s >= step)
            });
            if reached {
                return true;
            }
            if self.has_exited() {
                return false;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        false
    }

    /// Sends `signal` (`"KILL"`, `"TERM"`, `"STOP"`…, as `kill -<signal>`)
    /// to the launcher or to one actor's process; returns how many
    /// processes it reached.
    pub fn signal(&self, target: Target, signal: &str) -> usize {
        self.pids(target)
            .iter()
            .filter(|pid| {
                Command::new("kill")
                    .arg(format!("-{signal}"))
                    .arg(pid.to_string())
                    .status()
                    .is_ok_and(|s| s.success())
            })
            .count()
    }

    /// The process ids of the launcher or of one actor: one while it
    /// runs, none while it is down (a restarted actor has a new one).
    pub fn pids(&self, target: Target) -> Vec<u32> {
        match (target, &self.child) {
            (Target::Launcher, Some(c)) => vec![c.id()],
            (Target::Launcher, None) => vec![],
            (Target::Actor(a), _) => {
                // On several hosts an actor's run id is its host's domain,
                // `<run>-<host>`.
                let on_one_host = format!("--run-id {} --actor {a} ", self.run_id.as_str());
                let on_a_host = format!("--run-id {}-", self.run_id.as_str());
                let by_name = format!(" --actor {a} ");
                let mut pids = processes_matching(&on_one_host);
                pids.extend(
                    processes_matching(&on_a_host)
                        .into_iter()
                        .filter(|p| processes_matching(&by_name).contains(p)),
                );
                pids
            }
            (Target::Agent(name), _) => processes_matching(&format!(
                "--host {name} --dir {}",
                self.out.join("hosts").join(name).display()
            )),
        }
    }

    /// Starts the agent of host `name` again, as `--local-agents` first
    /// started it (after a test killed it, say). The caller waits for the
    /// child: it exits once the run is over.
    pub fn start_agent(&self, name: &str) -> std::io::Result<Child> {
        let log = std::fs::File::create(
            self.out
                .join("logs")
                .join(format!("agent-{name}-again.log")),
        )?;
        Command::new(&self.executable)
            .arg("agent")
            .arg(self.out.join("scenario.toml"))
            .arg("--host")
            .arg(name)
            .arg("--dir")
            .arg(self.out.join("hosts").join(name))
            .arg("--once")
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .spawn()
    }

    fn has_exited(&mut self) -> bool {
        self.child
            .as_mut()
            .is_none_or(|c| c.try_wait().ok().flatten().is_some())
    }

    /// Waits for the launcher to finish (killing it past the time limit)
    /// and reads the results.
    pub fn wait(mut self) -> Result<Run, Error> {
        let mut child = self.child.take().expect("not waited for yet");
        let status = loop {
            if let Ok(Some(status)) = child.try_wait() {
                break status;
            }
            if self.started.elapsed() > self.time_limit {
                let _ = child.kill();
                let _ = child.wait();
                return Err(Error::TimedOut {
                    run_id: self.run_id.as_str().to_string(),
                    limit: self.time_limit,
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        self.reap_agents();
        let stdout = std::mem::replace(&mut self.stdout, Captured::drain(None)).finish();
        let stderr = std::mem::replace(&mut self.stderr, Captured::drain(None)).finish();
        let ticks = read_ticks(&self.out.join("ticks.csv"));
        // From here the run's cleanup is the `Run`'s, when it is dropped: a
        // test may first look at what the launcher left (after a SIGKILL).
        self.handed_over = true;
        Ok(Run::new(
            self.run_id.clone(),
            self.out.clone(),
            self.executable.clone(),
            status,
            stdout,
            stderr,
            ticks,
            self.vocabulary,
        ))
    }
}

impl RunningNetwork {
    /// Waits for the agents a separate-hosts run started (each serves one
    /// run and exits after it), killing those still there after 10 s.
    fn reap_agents(&mut self) {
        if let Some(cuts) = self.cuts.take() {
            cuts.stop();
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        for agent in &mut self.agents {
            while Instant::now() < deadline && matches!(agent.try_wait(), Ok(None)) {
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = agent.kill();
            let _ = agent.wait();
        }
        self.agents.clear();
    }
}

impl Drop for RunningNetwork {
    fn drop(&mut self) {
        if let Some(cuts) = self.cuts.take() {
            cuts.stop();
        }
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        for agent in &mut self.agents {
            let _ = agent.kill();
            let _ = agent.wait();
        }
        if !self.handed_over {
            kill_and_clean(&self.run_id);
        }
    }
}
