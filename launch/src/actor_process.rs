//! `cqnet actor`: one actor of a `cqnet run` network in its own process.
//! The shell around the same state machines the in-process driver runs:
//! iceoryx2 in, state machine, iceoryx2 out, and nothing else.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use fusion_graph::faults::FaultSchedule;
use fusion_graph::hosts::Placement;
use fusion_graph::scenario::ClockMode;
use fusion_graph::vocabulary::Vocabulary;
use fusion_graph::Actor;
use fusion_graph::{link_fault_seed, ActorId, Scenario, Topology};
use node::{processing_node, Start};
use sensor::mac::MacActor;
use sensor::SensorActor;
use transport::iceoryx::map_run_memory;
use transport::world_memory::TruthReader;
use transport::{DeadNodeSweep, IceoryxTransport, RunId, Transport};
use wire::{Control, Message, Payload};

use crate::drive::{deliver, time_passes};
use crate::results::write_atomically;
use crate::usage::Usage;

/// Longest sleep between checks that the launcher is still there.
const IDLE_WAIT: Duration = Duration::from_millis(100);

/// A sensor's: it is woken by its activation alone, and a sensor its node
/// never activates should cost nothing. The check is a backstop: the
/// kernel kills an actor whose parent dies (`PR_SET_PDEATHSIG`).
const SENSOR_IDLE_WAIT: Duration = Duration::from_secs(1);

/// How long a node polls for a wake-up before it sleeps, while it waits for
/// a message due within the step (a neighbour's round, its sensors'
/// observations, a selection proposal). Sleeping costs the notifier a
/// system call and the sleeper two context switches, ten or more times a
/// step, and a round waits for its slowest wake-up. Between polls the node
/// yields, so that any other process runnable on its core goes first: the
/// polling costs a core only when it would have idled. It took the round
/// p50 of `cqnet run --lockstep --no-central` from 177–202 µs to 145–163
/// (2026-12-02, alternately with and without; 50 µs was among the best of
/// 20 to 300).
const SPIN_BEFORE_SLEEP: Duration = Duration::from_micros(50);

/// Test hook: an actor named in this variable fails at start, so the
/// launcher's handling of a child that cannot start can be tested.
pub const FAIL_AT_START_ENV: &str = "CQNET_FAIL_AT_START";

/// Where an actor keeps its byte counts: a ledger it updates on every send
/// and receive, which the launcher reads (see `transport::ledger`).
pub fn ledger_path(out: &Path, actor: ActorId) -> PathBuf {
    out.join("accounting").join(format!("{actor}.ledger"))
}

/// `vocabulary`: the program's parts, which the run's scenario may name
/// (every actor is the same program as the launcher).
pub fn run_actor(args: &ActorArgs, vocabulary: Vocabulary) -> anyhow::Result<()> {
    close_inherited_descriptors().context("closing inherited descriptors")?;
    // Die with the launcher, whatever happens to it.
    nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGKILL)
        .context("prctl(PR_SET_PDEATHSIG)")?;
    // Ctrl-C in a terminal reaches the whole process group: leave it to the
    // launcher, which stops every actor in order.
    // SAFETY: ignoring a signal installs no handler code.
    unsafe {
        nix::sys::signal::signal(
            nix::sys::signal::Signal::SIGINT,
            nix::sys::signal::SigHandler::SigIgn,
        )
    }
    .context("ignoring SIGINT")?;
    let actor: ActorId = args.actor.parse().map_err(anyhow::Error::msg)?;
    if let Some(core) = args.core {
        // Before anything else: start-up's work is on the core too. A core
        // refused (taken away since the launcher looked) costs only time.
        if let Err(e) = crate::cores::settle_on(core) {
            tracing::warn!(core, error = %e, "not settled on its core");
        }
    }
    if std::env::var(FAIL_AT_START_ENV).is_ok_and(|v| v == args.actor) {
        anyhow::bail!("failing at start as {FAIL_AT_START_ENV} asks");
    }
    let (scenario, topology) = load_child_scenario(&args.scenario, vocabulary)?;
    anyhow::ensure!(
        topology.contains(actor) && actor != ActorId::Launcher,
        "{actor} is not an actor of this scenario"
    );
    let run = RunId::new(&args.run_id)?;
    let out = args
        .scenario
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    std::fs::create_dir_all(out.join("accounting"))?;
    // Only a restarted actor has a dead predecessor to sweep up after.
    let sweep = if args.rejoin {
        DeadNodeSweep::On
    } else {
        DeadNodeSweep::Off
    };
    let mut transport = IceoryxTransport::with_sweep(
        &run,
        actor,
        &topology,
        scenario.wire_format(&topology),
        link_fault_seed(scenario.seed, actor),
        sweep,
    )?;
    transport.keep_counts_in(&ledger_path(&out, actor))?;
    if let Some(p) = Placement::from_scenario(&scenario, &topology, "", args.centralized)? {
        transport.place_on(&p, p.host_of(actor));
    }
    let schedule = FaultSchedule::new(&scenario.faults);
    match actor {
        ActorId::Sensor(i) => {
            let world = TruthReader::open(&run).with_context(|| {
                format!("{actor} cannot see the world (the run's truth in shared memory)")
            })?;
            let sensor =
                SensorActor::new(&scenario, &topology, i)?.in_world(world, args.centralized);
            schedule.follow_link_faults(transport.me(), transport.shaper(), &topology);
            let pace = Pace::at_rest(SENSOR_IDLE_WAIT);
            actor_loop(sensor, transport, &pace, &out)
        }
        ActorId::Mac(i) => {
            let mac = MacActor::new(&scenario, &topology, i)?
                .context("a channel actor in a scenario without a [channel]")?;
            schedule.follow_link_faults(transport.me(), transport.shaper(), &topology);
            actor_loop(mac, transport, &Pace::at_rest(IDLE_WAIT), &out)
        }
        ActorId::Node(i) => {
            share_table_rows(&run);
            let start = Start {
                rejoin: args.rejoin,
                step_period: (scenario.clock.mode == ClockMode::Realtime)
                    .then(|| Duration::from_secs_f64(scenario.clock.step_period_ms / 1e3)),
            };
            let node = processing_node(&scenario, &topology, i, start)?;
            if !args.rejoin {
                // A neighbour's first values can come before this node reads
                // its first `BeginStep`: they meet the first step's faults,
                // as in `sim`, where every node has begun the step before any
                // value of it is sent.
                schedule.apply_link_faults(1, transport.me(), transport.shaper(), &topology);
            }
            let pace = Pace {
                idle: IDLE_WAIT,
                spin: SPIN_BEFORE_SLEEP,
                give_way: topology.neighbours[i as usize].len(),
                faults: Some((schedule, topology.clone())),
            };
            actor_loop(node, transport, &pace, &out)
        }
        ActorId::Launcher => unreachable!("checked above"),
    }
}

/// Puts this node's table rows in memory the run's nodes share, so that
/// between them they build each row once (`bounds::shared_rows`). A
/// failure costs only time: the node builds its own rows, as `sim` does.
fn share_table_rows(run: &RunId) {
    let len = bounds::table_memory::shared_table_bytes();
    let shared = map_run_memory(run, "table_rows", len)
        .map_err(anyhow::Error::from)
        .and_then(|memory| {
            // Rows are read until the process ends: so is the mapping kept.
            let memory = Box::leak(Box::new(memory));
            // SAFETY: the run's own file, zeroed when made, mapped for the
            // rest of the process; the run's nodes are this executable and
            // write it only through the shared tables.
            unsafe { bounds::table_memory::share_table_rows(memory.as_mut_ptr(), memory.len()) }
                .map_err(anyhow::Error::from)
        });
    if let Err(e) = shared {
        tracing::warn!(error = %e, "table rows not shared; this node builds its own");
    }
}

/// Closes every descriptor this process was started with beyond stdin,
/// stdout and stderr. iceoryx2 makes its event sockets without
/// close-on-exec, so a child starts with every socket its launcher held at
/// that moment: each restarted actor kept about ten, some connected to
/// listeners long dead, and the soak's descriptors grew with every restart.
/// Nothing else in an actor has opened a descriptor this early.
fn close_inherited_descriptors() -> std::io::Result<()> {
    // SAFETY: close_range only closes descriptors; none above 2 is in use yet.
    let closed = unsafe { libc::syscall(libc::SYS_close_range, 3u32, u32::MAX, 0u32) };
    if closed == 0 {
        return Ok(());
    }
    let error = std::io::Error::last_os_error();
    if error.raw_os_error() != Some(libc::ENOSYS) {
        return Err(error);
    }
    // Kernels before 5.9 have no close_range: one by one.
    let open: Vec<i32> = std::fs::read_dir("/proc/self/fd")?
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse().ok())
        .filter(|fd| *fd > 2)
        .collect();
    for fd in open {
        // SAFETY: as above; the directory's own descriptor is already closed
        // (EBADF, ignored).
        unsafe { libc::close(fd) };
    }
    Ok(())
}

fn announce_ready() {
    // The launcher reads this line from our stdout.
    println!("ready");
}

/// Whether the launcher is gone, asked of the kernel at most every
/// [`PARENT_CHECK`]: a node loops once per consensus round, thousands of
/// times a second across a network, and a system call per loop was the
/// most frequent one `run` made (`getppid`, more often than the polls'
/// `sched_yield`). The launcher's death also kills its children
/// (`PR_SET_PDEATHSIG`); this is the fallback when it cannot.
struct LauncherWatch {
    checked: Instant,
}

/// The least time between two of those questions (an actor asleep asks
/// when it wakes, at the latest after its idle wait).
const PARENT_CHECK: Duration = Duration::from_millis(20);

impl LauncherWatch {
    fn new() -> Self {
        Self {
            checked: Instant::now(),
        }
    }

    fn launcher_gone(&mut self) -> bool {
        if self.checked.elapsed() < PARENT_CHECK {
            return false;
        }
        self.checked = Instant::now();
        nix::unistd::getppid() == nix::unistd::Pid::from_raw(1)
    }
}

/// On the launcher's Stop: the memory used, and the CPU time and context
/// switches from `ready` on (`since_ready`: what the run's steps cost,
/// start-up left out). Measured only here: reading `smaps_rollup` walks
/// every mapping (about 0.3 ms), too much to do every few steps in 234
/// processes. (Byte counts need no last write: the ledger holds them as
/// they happen.)
fn write_usage(me: ActorId, out: &Path, since_ready: Option<Usage>) -> anyhow::Result<()> {
    if let (Some(peak), Some(pss)) = (
        crate::usage::peak_memory_kb(),
        crate::usage::proportional_memory_kb(),
    ) {
        let mut line = format!("{peak} {pss}");
        if let Some(u) = since_ready.zip(Usage::own()).map(|(r, now)| now.since(&r)) {
            line += &format!(
                " {} {} {} {}",
                u.user.as_micros(),
                u.system.as_micros(),
                u.voluntary_switches,
                u.involuntary_switches
            );
        }
        write_atomically(&memory_path(out, me), line.as_bytes())?;
    }
    Ok(())
}

/// Where an actor writes `<peak RSS kB> <PSS kB>`, then, over the run
/// from its `ready` to the Stop, `<user CPU µs> <system CPU µs>
/// <voluntary context switches> <involuntary ones>`.
pub fn memory_path(out: &Path, actor: ActorId) -> PathBuf {
    out.join("accounting").join(format!("{actor}.memory"))
}

/// Where a node writes `<CPU µs> <steps>`: the user and system CPU time it
/// spent from its first `BeginStep` to the launcher's Stop, and the steps
/// begun in it (the random-exchange paper's duty cycle).
pub fn cpu_path(out: &Path, actor: ActorId) -> PathBuf {
    out.join("accounting").join(format!("{actor}.cpu"))
}

/// This process's user and system CPU time so far.
fn process_cpu_time() -> Duration {
    Usage::own().map_or(Duration::ZERO, |u| u.user + u.system)
}

/// A node's CPU time over the steps, as [`cpu_path`] describes.
#[derive(Debug, Clone, Copy, Default)]
struct CpuOverSteps {
    at_first_step: Option<Duration>,
    steps: u32,
}

impl CpuOverSteps {
    fn step_begun(&mut self) {
        self.at_first_step.get_or_insert_with(process_cpu_time);
        self.steps += 1;
    }

    fn write(&self, me: ActorId, out: &Path) -> anyhow::Result<()> {
        let Some(first) = self.at_first_step else {
            return Ok(());
        };
        let cpu = process_cpu_time().saturating_sub(first);
        write_atomically(
            &cpu_path(out, me),
            format!("{} {}", cpu.as_micros(), self.steps).as_bytes(),
        )
    }
}

/// A node's CPU seconds per step begun, as it wrote them at the Stop.
pub fn read_cpu_per_step(out: &Path, actor: ActorId) -> Option<f64> {
    let text = std::fs::read_to_string(cpu_path(out, actor)).ok()?;
    let mut f = text.split_whitespace().map(|v| v.parse::<u64>().ok());
    let (micros, steps) = (f.next()??, f.next()??);
    (steps > 0).then(|| micros as f64 / 1e6 / steps as f64)
}

/// How an actor of one kind waits in its process, and what its driver
/// does for it besides handing it messages.
struct Pace {
    /// Its longest sleep: between checks that the launcher is still there.
    idle: Duration,
    /// How long it polls for a wake-up before it sleeps, while a message is
    /// due within its step ([`SPIN_BEFORE_SLEEP`] for a node, none else).
    spin: Duration,
    /// How many times it gives its core away before a stage it asks to
    /// give way for: a node, once per neighbour, before its fusion filter.
    /// Its own rounds are over, but its neighbours may still be in their
    /// last ones, runnable on the same core and waiting for each other;
    /// those rounds are on every node's way to the step's end, the fusion
    /// filter (tens of microseconds) only on this node's report.
    /// Alternately on two cores, it took the round p50 of `cqnet run
    /// --lockstep --no-central` from 58–65 µs to 41–45 (a single yield:
    /// 46–53; CPU and steps per second not resolved); yielding before the
    /// local filter as well did not help.
    give_way: usize,
    /// A node's links take the faults of the step each `BeginStep` begins.
    /// (Sensors and channels follow each message's own step's faults,
    /// set up once before the loop.)
    faults: Option<(FaultSchedule, Topology)>,
}

impl Pace {
    /// An actor woken by its messages alone, which never polls.
    fn at_rest(idle: Duration) -> Self {
        Self {
            idle,
            spin: Duration::ZERO,
            give_way: 0,
            faults: None,
        }
    }
}

/// The one loop of every actor process: wait for a wake-up or the actor's
/// next timeout, hand it each message and the passing of time, run its
/// work, send what it emitted; until the launcher's stop.
fn actor_loop<A: Actor, T: Transport>(
    mut actor: A,
    mut t: T,
    pace: &Pace,
    out: &Path,
) -> anyhow::Result<()> {
    let wiring = actor.wiring();
    for c in wiring.publishes {
        t.publish_on(c)?;
    }
    for c in wiring.reads {
        t.subscribe(c)?;
    }
    for p in wiring.wakes {
        t.notify(p)?;
    }
    announce_ready();
    let ready = Usage::own();
    let give_way = || {
        for _ in 0..pace.give_way {
            std::thread::yield_now();
        }
    };
    let mut inbox = Vec::new();
    let mut outgoing = Vec::new();
    let mut cpu = CpuOverSteps::default();
    let mut launcher = LauncherWatch::new();
    loop {
        let now = t.now();
        match actor.poll_timeout() {
            Some(due) => wait_spinning(&mut t, due.saturating_sub(now).min(pace.idle), pace.spin)?,
            None => t.wait(pace.idle)?,
        }
        inbox.clear();
        let now = t.now();
        t.receive(now, &mut inbox)?;
        for m in inbox.drain(..) {
            match (&m.payload, m.header.sender) {
                (Payload::Control(Control::Stop), ActorId::Launcher) => {
                    cpu.write(t.me(), out)?;
                    return write_usage(t.me(), out, ready);
                }
                (Payload::Control(Control::BeginStep), ActorId::Launcher) => {
                    cpu.step_begun();
                    if let Some((schedule, topology)) = &pace.faults {
                        schedule.apply_link_faults(m.header.step, t.me(), t.shaper(), topology);
                        t.update_connections();
                    }
                }
                _ => {}
            }
            // The time each message is handled at, not the batch's: a local
            // filter run for an earlier message of the batch takes milliseconds.
            let now = t.now();
            deliver(&mut actor, &mut t, &m, now, &mut outgoing, give_way)?;
        }
        let now = t.now();
        time_passes(&mut actor, &mut t, now, &mut outgoing, give_way)?;
        if launcher.launcher_gone() {
            return Ok(());
        }
    }
}

/// How a node waits for a message due within its step: it polls for
/// `SPIN_BEFORE_SLEEP` (50 µs), yielding, then sleeps for what is left of
/// `timeout`. Public so that a benchmark can wait exactly as a node does.
pub fn wait_as_a_node<T: Transport>(
    t: &mut T,
    timeout: Duration,
) -> Result<(), transport::WaitError> {
    wait_spinning(t, timeout, SPIN_BEFORE_SLEEP)
}

/// Polls for a wake-up for up to `spin`, yielding between polls, then
/// sleeps for what is left of `timeout` if none came. The spin is timed by
/// the wall clock, not the transport's, which a backend may hold still.
fn wait_spinning<T: Transport>(
    t: &mut T,
    timeout: Duration,
    spin: Duration,
) -> Result<(), transport::WaitError> {
    let started = Instant::now();
    while started.elapsed() < spin.min(timeout) {
        if t.poll_wake()? {
            return Ok(());
        }
        std::thread::yield_now();
    }
    t.wait(timeout.saturating_sub(started.elapsed()))
}

/// The message that tells every sensor and channel to stop (sent on the
/// lifecycle channel).
pub fn stop_message(step: u32) -> Message {
    Message::new(ActorId::Launcher, step, 0, Payload::Control(Control::Stop))
}

#[cfg(test)]
mod tests {
    use super::*;
    use transport::{MemoryBus, MemoryTransport};
    use wire::WireFormat;

    /// The memory transport has no wake-ups and a clock that stands still
    /// between the driver's steps: the spin still ends, by the wall clock.
    #[test]
    fn a_spin_ends_though_the_transport_clock_stands_still() {
        let (done, finished) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let format = WireFormat {
                cell_bytes: 1,
                activation_bytes: 4,
                payloads: wire::payloads::Payloads::NONE,
            };
            let mut t = MemoryTransport::new(ActorId::Node(0), MemoryBus::new(), format, 1);
            let waited = wait_spinning(&mut t, Duration::from_secs(1), Duration::from_millis(2));
            let _ = done.send(waited.is_ok());
        });
        assert_eq!(
            finished.recv_timeout(Duration::from_secs(20)),
            Ok(true),
            "the spin did not end"
        );
    }
}

#[derive(Debug, clap::Args)]
pub struct ActorArgs {
    #[arg(long)]
    pub run_id: String,
    #[arg(long)]
    pub actor: String,
    /// The run's effective scenario, written by the launcher.
    #[arg(long)]
    pub scenario: PathBuf,
    /// Sensors: also send observations to the launcher's centralized reference.
    #[arg(long)]
    pub centralized: bool,
    /// Started mid-run (a restart): a node rejoins from a neighbour's fused
    /// posterior, and every actor first sweeps the iceoryx2 resources its
    /// dead predecessor left.
    #[arg(long)]
    pub rejoin: bool,
    /// The core to run on (see `launch::cores`).
    #[arg(long)]
    pub core: Option<usize>,
}

/// Loads the scenario file a launcher wrote for its children.
pub fn load_child_scenario(
    path: &std::path::Path,
    vocabulary: Vocabulary,
) -> anyhow::Result<(Scenario, Topology)> {
    let scenario = Scenario::load_in(vocabulary, path, &[])
        .with_context(|| format!("scenario {}", path.display()))?;
    let topology = Topology::from_scenario(&scenario, &path.display().to_string())?;
    Ok((scenario, topology))
}
