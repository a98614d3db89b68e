//! `cqnet agent`: one host's share of a multi-host run. It listens on its
//! host's Zenoh endpoint, holds a liveliness token while it lives, and for
//! each run the launcher sets up: opens its host's bridge, spawns, signals
//! and reaps its host's actors (the one-host supervisor, unchanged), and
//! reports their readiness, exits and byte counts.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use fusion_graph::hosts::Placement;
use fusion_graph::vocabulary::Vocabulary;
use fusion_graph::RunId;
use fusion_graph::{ActorId, Scenario, Topology};
use transport::accounting::read_ledger;
use transport::accounting::Accounting;
use transport::iceoryx::remove_run_resources;
use zenoh::Wait;

use super::bridge::{Bridge, HostWorld, Setting};
use super::trust::Role;
use super::{
    command_key, decode, encode, event_key, liveliness_key, open_session, put, FromAgent, Order,
    Security, ToAgent,
};
use crate::actor_process::{cpu_path, ledger_path, memory_path};
use crate::supervisor::{supervise, ChildSpec, Command, Event, HostFiles};

#[derive(Debug, clap::Args)]
pub struct AgentArgs {
    /// The scenario file: its `[[hosts]]` give this host's endpoint and the
    /// others'. The run itself uses the scenario the launcher sends.
    pub scenario: PathBuf,
    /// This host's name in the scenario.
    #[arg(long)]
    pub host: String,
    /// Where the host's actors write their logs and byte counts.
    #[arg(long, default_value = "out/agent")]
    pub dir: PathBuf,
    /// Serve one run and exit (as `cqnet run --local-agents` starts them).
    #[arg(long)]
    pub once: bool,
    /// Serve only the run with this id: a setup for any other is refused.
    #[arg(long)]
    pub run: Option<String>,
}

/// How often the agent looks at both its command subscription and its
/// supervisor's events.
const POLL: Duration = Duration::from_millis(5);
/// How long the actors of a host the launcher lost get to exit after
/// SIGKILL before the agent answers regardless.
const CLEARING_TIMEOUT: Duration = Duration::from_secs(5);

/// `vocabulary`: the program's parts, which the launcher's scenario may
/// name (the agent is the same program as the launcher).
pub fn run_agent(args: &AgentArgs, vocabulary: Vocabulary) -> anyhow::Result<()> {
    let scenario = Scenario::load_in(vocabulary, &args.scenario, &[])?;
    let topology = Topology::from_scenario(&scenario, &args.scenario.display().to_string())?;
    let placement = Placement::from_scenario(&scenario, &topology, "", false)?
        .context("the scenario has no [[hosts]] section")?;
    let me = placement
        .host_named(&args.host)
        .with_context(|| format!("no host named {:?} in the scenario", args.host))?;
    let hosts = placement.hosts();
    // Each pair of agents has one connection, made by the later host: two
    // made at once are one too many, and Zenoh closes one of them, with
    // whatever was already written on it.
    // Over plain TCP every agent connects to every other, which rejoins
    // fastest after a cut.
    let others: Vec<String> = hosts
        .iter()
        .enumerate()
        .filter(|(g, _)| *g < me || (placement.plain_tcp() && *g != me))
        .map(|(_, h)| h.endpoint.clone())
        .collect();
    let security = Security::for_role(&placement, Role::Agent(&args.host))?;
    let shaping = super::relay_shaping(&placement, me);
    let linked = open_session(Some(&hosts[me].endpoint), &others, None, &security, shaping)?;
    let session = &linked.session;
    let commands = session
        .declare_subscriber(command_key(&args.host))
        .wait()
        .map_err(|e| anyhow::anyhow!("subscribing to commands: {e}"))?;
    // Declared last: the launcher sends its first command when it sees it.
    let _token = session
        .liveliness()
        .declare_token(liveliness_key(&args.host, &session.zid().to_string()))
        .wait()
        .map_err(|e| anyhow::anyhow!("declaring liveliness: {e}"))?;
    println!("agent {} listening on {}", args.host, hosts[me].endpoint);
    let mut agent = Agent {
        session,
        host: &args.host,
        dir: &args.dir,
        vocabulary,
        hosts: hosts.to_vec(),
        refused: 0,
    };
    loop {
        let setup = loop {
            let sample = match commands.recv_timeout(Duration::from_secs(1)) {
                Ok(Some(sample)) => sample,
                Ok(None) => continue,
                Err(e) => bail!("the command subscription ended: {e}"),
            };
            let Some(order) = decode::<Order>(&sample.payload().to_bytes()) else {
                agent.refuse("-", "a command that did not decode");
                continue;
            };
            match &order.command {
                ToAgent::Setup {
                    run,
                    scenario,
                    centralized,
                    ..
                } => {
                    if *run != order.run || args.run.as_ref().is_some_and(|r| r != run) {
                        agent.refuse(
                            &order.sender,
                            &format!(
                                "a setup of run {run:?}, which this agent was not started for"
                            ),
                        );
                    } else {
                        break (run.clone(), scenario.clone(), *centralized);
                    }
                }
                other => agent.refuse(
                    &order.sender,
                    &format!("{} with no run set up", other.name()),
                ),
            }
        };
        match agent.serve(&setup.0, &setup.1, setup.2, &commands) {
            Ok(Served::Finished) => {}
            Ok(Served::Interrupted) => return Ok(()),
            Ok(Served::Refused(why)) => {
                agent.refuse("-", &why);
                continue;
            }
            Err(e) => {
                agent.tell(&FromAgent::Failed {
                    message: format!("{e:#}"),
                });
                tracing::error!(error = %format!("{e:#}"), "run failed");
            }
        }
        if args.once {
            return Ok(());
        }
    }
}

struct Agent<'a> {
    session: &'a zenoh::Session,
    host: &'a str,
    dir: &'a Path,
    vocabulary: Vocabulary,
    /// The hosts of the agent's own scenario: a run's must be the same.
    hosts: Vec<fusion_graph::hosts::HostConfig>,
    /// Commands refused so far and not yet reported in a run's counts.
    refused: u64,
}

enum Served {
    Finished,
    Interrupted,
    /// The setup was not for this agent: why.
    Refused(String),
}

type Commands =
    zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>;

impl Agent<'_> {
    /// Counts and logs a command not taken, with who sent it.
    fn refuse(&mut self, sender: &str, what: &str) {
        self.refused += 1;
        tracing::warn!(sender, refused = self.refused, "refused: {what}");
    }

    fn tell(&self, event: &FromAgent) {
        if let Err(e) = put(self.session, &event_key(self.host), encode(event)) {
            tracing::warn!(error = %e, "could not tell the launcher");
        }
    }

    /// The bridge's counts with the commands refused so far.
    fn with_refused(
        &self,
        mut counts: fusion_graph::hosts::BridgeCounts,
    ) -> fusion_graph::hosts::BridgeCounts {
        counts.refused_commands += self.refused;
        counts
    }

    /// One run, from its setup to its shutdown.
    fn serve(
        &mut self,
        run: &str,
        scenario_text: &str,
        centralized: bool,
        commands: &Commands,
    ) -> anyhow::Result<Served> {
        let run_id = RunId::new(run)?;
        let scenario = Scenario::from_toml_in(
            self.vocabulary,
            scenario_text,
            "the launcher's scenario",
            &[],
        )?;
        let topology = Topology::from_scenario(&scenario, "the launcher's scenario")?;
        let placement = Placement::from_scenario(&scenario, &topology, "", centralized)?
            .context("the launcher's scenario has no [[hosts]]")?;
        let host = placement
            .host_named(self.host)
            .with_context(|| format!("the launcher's scenario has no host {:?}", self.host))?;
        // A run's hosts are the ones this agent was started with: a setup
        // cannot point its bridge at peers of the sender's choosing.
        let same = |a: &fusion_graph::hosts::HostConfig, b: &fusion_graph::hosts::HostConfig| {
            a.name == b.name && a.nodes == b.nodes && a.endpoint == b.endpoint
        };
        if placement.hosts().len() != self.hosts.len()
            || !placement
                .hosts()
                .iter()
                .zip(&self.hosts)
                .all(|(a, b)| same(a, b))
        {
            return Ok(Served::Refused(format!(
                "a setup of run {run:?} whose hosts are not this agent's scenario's"
            )));
        }
        // The actors a command may name: this run's, on this host.
        let mine: HashSet<ActorId> = placement.actors_on(host, &topology).into_iter().collect();
        // What a predecessor killed with its actors left in the domain is
        // swept as the bridge's nodes and the rejoining actors start (they
        // sweep dead nodes); the domain itself is not removed, for on the
        // launcher's host it holds the launcher's live ports.
        let domain = placement.domain(&run_id, host);
        let dir = self.dir.join(run);
        std::fs::create_dir_all(dir.join("logs"))?;
        std::fs::create_dir_all(dir.join("accounting"))?;
        let scenario_file = dir.join("scenario.toml");
        crate::results::write_atomically(&scenario_file, scenario_text.as_bytes())?;
        // The launcher's host has the launcher's world; another host its own.
        let world = (host != placement.host_of(ActorId::Launcher))
            .then(|| HostWorld::create(&domain, &scenario))
            .transpose()?;
        let setting = Setting {
            run: run.into(),
            domain: domain.clone(),
            placement: placement.clone(),
            host,
            topology: topology.clone(),
        };
        let bridge = Bridge::start(
            self.session,
            setting,
            &dir.join("accounting").join("bridge.counts"),
            world,
        )?;
        let spec = ChildSpec {
            program: crate::supervisor::ActorProgram::for_this_process()?,
            run_id: domain.as_str().into(),
            scenario_file,
            log_dir: dir.join("logs"),
            centralized,
            // A host's own cores are its business: its actors are left to
            // its scheduler.
            cores: None,
        };
        let (command_tx, command_rx) = tokio::sync::mpsc::unbounded_channel();
        let (event_tx, events) = mpsc::channel();
        // The children's parent-death signal is tied to the thread that
        // spawns them: this one lives until they are all reaped.
        let supervisor = std::thread::Builder::new()
            .name("supervisor".into())
            .spawn(move || {
                tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .map(|rt| rt.block_on(supervise(spec, command_rx, event_tx)))
            })?;
        self.tell(&FromAgent::SetUp { run: run.into() });
        let mut interrupted = false;
        // The actors started and not yet exited.
        let mut running: HashSet<ActorId> = HashSet::new();
        // Each file's length when it last went home in a progress report.
        let mut sent_lengths: std::collections::HashMap<String, usize> = Default::default();
        // Set up again after the launcher lost this host: the actors are
        // being stopped, and the answer waits until they are gone.
        let mut clearing: Option<Instant> = None;
        'run: loop {
            while let Ok(e) = events.try_recv() {
                match e {
                    Event::Ready(a) => {
                        running.insert(a);
                        self.tell(&FromAgent::Ready(a))
                    }
                    // The launcher counts a host's actors gone when it
                    // loses the host: their exits are not news to it.
                    Event::Exited { actor, .. } if clearing.is_some() => {
                        running.remove(&actor);
                    }
                    Event::Exited {
                        actor,
                        status,
                        stderr_tail,
                    } => {
                        running.remove(&actor);
                        self.tell(&FromAgent::Exited {
                            actor,
                            status,
                            stderr_tail,
                        })
                    }
                    Event::Interrupted => {
                        interrupted = true;
                        let _ = command_tx.send(Command::Shutdown);
                    }
                    Event::AllReaped => break 'run,
                    // Only the launcher's supervisor of several hosts says these.
                    Event::HostBack(_) | Event::Counts { .. } => {}
                }
            }
            if let Some(since) = clearing {
                if running.is_empty() || since.elapsed() > CLEARING_TIMEOUT {
                    if !running.is_empty() {
                        tracing::warn!(
                            left = running.len(),
                            "actors still running after the host was lost; answering anyway"
                        );
                    }
                    clearing = None;
                    self.tell(&FromAgent::SetUp { run: run.into() });
                }
            }
            let sample = match commands.recv_timeout(POLL) {
                Ok(Some(s)) => s,
                Ok(None) => continue,
                Err(e) => bail!("the command subscription ended: {e}"),
            };
            let Some(order) = decode::<Order>(&sample.payload().to_bytes()) else {
                self.refuse("-", "a command that did not decode");
                continue;
            };
            if order.run != run {
                self.refuse(
                    &order.sender,
                    &format!(
                        "{} for run {:?} while serving {run:?}",
                        order.command.name(),
                        order.run
                    ),
                );
                continue;
            }
            if let Some(actor) = order.command.actor() {
                if !mine.contains(&actor) {
                    self.refuse(
                        &order.sender,
                        &format!("{} of {actor}, not on this host", order.command.name()),
                    );
                    continue;
                }
            }
            let to_supervisor = match order.command {
                ToAgent::Setup {
                    run: again,
                    after_loss: true,
                    ..
                } if again == run => {
                    // Cut off longer than the lease, the launcher counts
                    // this host's actors gone and will start their
                    // successors: the ones still running here go first.
                    if clearing.is_none() {
                        tracing::warn!(
                            actors = running.len(),
                            "the launcher lost this host; stopping its actors for their successors"
                        );
                        clearing = Some(Instant::now());
                        for actor in &running {
                            let _ = command_tx.send(Command::Signal {
                                actor: *actor,
                                signal: fusion_graph::scenario::Signal::Kill,
                            });
                        }
                    }
                    None
                }
                ToAgent::Setup { run: again, .. } if again == run => {
                    self.tell(&FromAgent::SetUp { run: run.into() });
                    None
                }
                ToAgent::Setup { run: other, .. } => {
                    tracing::warn!(%other, "a second run while one is going; ignored");
                    None
                }
                ToAgent::Spawn { actor, rejoin } => Some(Command::Spawn { actor, rejoin }),
                ToAgent::Signal { actor, signal } => Some(Command::Signal { actor, signal }),
                ToAgent::Continue { actor } => Some(Command::Continue { actor }),
                ToAgent::Collect => {
                    self.tell(&FromAgent::Counts {
                        accounting_csv: host_accounting(&dir, &placement, host, &topology)
                            .to_csv_with_world_misses(),
                        bridge: self.with_refused(bridge.counts()),
                        home: host_files(&dir, &placement, host, &topology),
                    });
                    None
                }
                ToAgent::Progress => {
                    let mut home = host_files(&dir, &placement, host, &topology);
                    // Only what grew since the last report.
                    home.files.retain(|(path, bytes)| {
                        sent_lengths.insert(path.clone(), bytes.len()) != Some(bytes.len())
                    });
                    self.tell(&FromAgent::Progress {
                        accounting_csv: host_accounting(&dir, &placement, host, &topology)
                            .to_csv_with_world_misses(),
                        bridge: self.with_refused(bridge.counts()),
                        home,
                    });
                    None
                }
                ToAgent::Traffic => {
                    self.tell(&FromAgent::Traffic {
                        accounting_csv: host_accounting(&dir, &placement, host, &topology)
                            .to_csv_with_world_misses(),
                    });
                    None
                }
                ToAgent::Shutdown => Some(Command::Shutdown),
            };
            if let Some(c) = to_supervisor {
                let _ = command_tx.send(c);
            }
        }
        let _ = supervisor.join();
        bridge.stop();
        // The launcher's own ports live in its host's domain; it removes
        // that one itself once they are closed.
        if host != placement.host_of(fusion_graph::ActorId::Launcher) {
            remove_run_resources(&domain).context("removing the run's shared memory")?;
        }
        self.tell(&FromAgent::Finished);
        Ok(if interrupted {
            Served::Interrupted
        } else {
            Served::Finished
        })
    }
}

/// The most of an actor's log that comes home: its end, where a failure
/// is told.
const LOG_TAIL_BYTES: u64 = 256 << 10;

/// What of this host's run goes home: each actor's log (its last
/// [`LOG_TAIL_BYTES`]) and its memory and CPU files, by their paths in a
/// run's results folder, and the CPU the agent and its reaped actors used.
fn host_files(dir: &Path, placement: &Placement, host: usize, topology: &Topology) -> HostFiles {
    let mut files = Vec::new();
    for actor in placement.actors_on(host, topology) {
        let log = dir.join("logs").join(format!("{actor}.log"));
        if let Some(tail) = file_tail(&log, LOG_TAIL_BYTES) {
            files.push((format!("logs/{actor}.log"), tail));
        }
        for path in [memory_path(dir, actor), cpu_path(dir, actor)] {
            if let (Ok(bytes), Some(name)) = (std::fs::read(&path), path.file_name()) {
                files.push((format!("accounting/{}", name.to_string_lossy()), bytes));
            }
        }
    }
    HostFiles {
        files,
        cpu_seconds: crate::usage::own_cpu_seconds()
            .zip(crate::usage::children_cpu_seconds())
            .map(|(own, children)| own + children),
    }
}

/// The last `max` bytes of the file at `path`.
fn file_tail(path: &Path, max: u64) -> Option<Vec<u8>> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path).ok()?;
    let len = f.metadata().ok()?.len();
    f.seek(SeekFrom::Start(len.saturating_sub(max))).ok()?;
    let mut bytes = Vec::new();
    f.read_to_end(&mut bytes).ok()?;
    Some(bytes)
}

/// The byte counts of every actor of this host, from their ledgers.
fn host_accounting(
    dir: &Path,
    placement: &Placement,
    host: usize,
    topology: &Topology,
) -> Accounting {
    let mut total = Accounting::default();
    for actor in placement.actors_on(host, topology) {
        match read_ledger(&ledger_path(dir, actor), topology.payloads) {
            Ok(a) => total.merge(&a),
            Err(e) => tracing::warn!(%actor, error = %e, "byte counts not read"),
        }
    }
    total
}
