//! Round trip of one consensus-sized message between two processes: through
//! cqnet's iceoryx2 transport (encode, link shaper, decode, accounting,
//! wake-up event), and through bare iceoryx2 publish/subscribe with a
//! wake-up event, so the cost of our layer is visible. Bare iceoryx2 runs
//! twice: with the `ipc` service's event (a Unix datagram socket) and with
//! the futex event cqnet's transport uses (`transport/futex.rs`).
//!
//! Then the consensus round itself without its arithmetic: the default
//! scenario's nine nodes, each its own process, exchange the same
//! consensus message with their neighbours through cqnet's transport, ten
//! rounds a step, combining nothing and waiting as a node does (a short
//! poll, yielding, then sleep). Its
//! time per round is measured as `cqnet run` measures it (rounds 2 to 10
//! of each step, per round), so it is the floor that scheduling nine
//! processes on the machine's cores sets under the network's round p50;
//! the CPU the nine spend per round is the floor under the network's CPU
//! per step beyond `sim`'s.
//!
//! `cargo bench -p fusion-graph --bench roundtrip` prints p50 and p99.
//! The benchmark spawns itself as the echoing processes.

use std::process::{Child, Command};
use std::time::{Duration, Instant};

use fusion_graph::transport::futex;
use fusion_graph::transport::iceoryx::remove_run_resources;
use fusion_graph::transport::{Channel, IceoryxTransport, RunId, Transport};
use fusion_graph::wire::{ConsensusValues, Message, Payload, WireFormat};
use fusion_graph::{ActorId, Scenario, Topology};
use iceoryx2::prelude::*;

const ROLE: &str = "CQNET_ROUNDTRIP_ROLE";
const RUN: &str = "CQNET_ROUNDTRIP_RUN";
const NODE: &str = "CQNET_ROUNDTRIP_NODE";
const OUT: &str = "CQNET_ROUNDTRIP_OUT";
/// Steps of the nine-node round, and rounds a step (the default scenario's).
const STEPS: u32 = 2000;
const ROUNDS_A_STEP: u16 = 10;
/// A node's poll before it sleeps (`SPIN_BEFORE_SLEEP` in the runtime).
const SPIN: Duration = Duration::from_micros(50);
const ROUNDS: usize = 5000;
const WARMUP: usize = 200;
const FORMAT: WireFormat = WireFormat {
    cell_bytes: 1,
    activation_bytes: 4,
};

fn topology() -> Topology {
    Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap()
}

fn consensus(step: u32) -> Message {
    Message::new(
        ActorId::Node(0),
        step,
        1,
        Payload::Consensus(ConsensusValues {
            delta_eta: [1.0; 4],
            delta_lambda: [2.0; 10],
            delta_l: [3.0; 10],
            delta_l_late: None,
        }),
    )
}

fn percentiles(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[(v.len() as f64 * 0.99) as usize])
}

struct Echo(Child, RunId);

impl Drop for Echo {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        let _ = remove_run_resources(&self.1);
    }
}

fn spawn(role: &str, run: &RunId) -> Echo {
    spawn_with(role, run, &[])
}

fn spawn_with(role: &str, run: &RunId, env: &[(&str, String)]) -> Echo {
    let mut command = Command::new(std::env::current_exe().unwrap());
    command.env(ROLE, role).env(RUN, run.as_str());
    for (k, v) in env {
        command.env(k, v);
    }
    Echo(command.spawn().unwrap(), run.clone())
}

/// Node 0 sends on its consensus channel; node 1 echoes on its own.
fn cqnet_transport() -> (f64, f64) {
    let run = RunId::new(&format!("bench-cq-{}", std::process::id())).unwrap();
    let _echo;
    let mut t = IceoryxTransport::new(&run, ActorId::Node(0), &topology(), FORMAT, 1).unwrap();
    t.publish_on(Channel::Consensus(0)).unwrap();
    t.subscribe(Channel::Consensus(1)).unwrap();
    t.notify(ActorId::Node(1)).unwrap();
    _echo = spawn("cqnet", &run);
    let mut inbox = Vec::new();
    let mut times = Vec::with_capacity(ROUNDS);
    // Until the echo is up, resend.
    'connect: loop {
        t.update_connections();
        t.send(Channel::Consensus(0), &consensus(0), &[ActorId::Node(1)])
            .unwrap();
        let deadline = Instant::now() + Duration::from_millis(50);
        while Instant::now() < deadline {
            let now = t.now();
            t.receive(now, &mut inbox).unwrap();
            if !inbox.is_empty() {
                break 'connect;
            }
            t.wait(Duration::from_millis(5)).unwrap();
        }
    }
    for i in 1..=(ROUNDS + WARMUP) as u32 {
        inbox.clear();
        let start = Instant::now();
        t.send(Channel::Consensus(0), &consensus(i), &[ActorId::Node(1)])
            .unwrap();
        loop {
            let now = t.now();
            t.receive(now, &mut inbox).unwrap();
            if inbox.iter().any(|m| m.header.step == i) {
                break;
            }
            t.wait(Duration::from_millis(100)).unwrap();
        }
        if i as usize > WARMUP {
            times.push(start.elapsed().as_secs_f64() * 1e6);
        }
    }
    // Our ports go before the echo's guard removes the run's files.
    drop(t);
    percentiles(times)
}

fn cqnet_echo(run: &RunId) {
    let mut t = IceoryxTransport::new(run, ActorId::Node(1), &topology(), FORMAT, 2).unwrap();
    t.publish_on(Channel::Consensus(1)).unwrap();
    t.subscribe(Channel::Consensus(0)).unwrap();
    t.notify(ActorId::Node(0)).unwrap();
    let mut inbox = Vec::new();
    loop {
        t.wait(Duration::from_millis(100)).unwrap();
        inbox.clear();
        let now = t.now();
        t.receive(now, &mut inbox).unwrap();
        t.update_connections();
        for m in &inbox {
            let reply = Message::new(ActorId::Node(1), m.header.step, 1, m.payload.clone());
            t.send(Channel::Consensus(1), &reply, &[ActorId::Node(0)])
                .unwrap();
        }
    }
}

type Ports<S> = (
    Node<S>,
    iceoryx2::port::publisher::Publisher<S, [u8], ()>,
    iceoryx2::port::subscriber::Subscriber<S, [u8], ()>,
    iceoryx2::port::notifier::Notifier<S>,
    iceoryx2::port::listener::Listener<S>,
);

/// Bare iceoryx2: `[u8]` publish/subscribe plus an event to wake the peer.
fn bare_ports<S: Service>(run: &RunId, me: &str, peer: &str) -> Ports<S> {
    let mut config = Config::default();
    config.global.prefix = FileName::new(run.prefix().as_bytes()).unwrap();
    let node = NodeBuilder::new().config(&config).create::<S>().unwrap();
    let open = |name: &str| {
        node.service_builder(&ServiceName::new(&format!("bare/{}/{name}", run.as_str())).unwrap())
            .publish_subscribe::<[u8]>()
            .open_or_create()
            .unwrap()
    };
    let event = |name: &str| {
        node.service_builder(
            &ServiceName::new(&format!("bare/{}/wake/{name}", run.as_str())).unwrap(),
        )
        .event()
        // As few ids as our wake-up services have, for which iceoryx2
        // drains a counter each at every wait.
        .event_id_max_value(27)
        .open_or_create()
        .unwrap()
    };
    let publisher = open(me)
        .publisher_builder()
        .initial_max_slice_len(256)
        .create()
        .unwrap();
    let subscriber = open(peer).subscriber_builder().create().unwrap();
    let notifier = event(peer).notifier_builder().create().unwrap();
    let listener = event(me).listener_builder().create().unwrap();
    (node, publisher, subscriber, notifier, listener)
}

fn bare_send<S: Service>(p: &iceoryx2::port::publisher::Publisher<S, [u8], ()>, bytes: &[u8]) {
    p.loan_slice_uninit(bytes.len())
        .unwrap()
        .write_from_slice(bytes)
        .send()
        .unwrap();
}

/// The round trip through bare iceoryx2 with service type `S`, whose
/// echoing process takes `role`.
fn bare<S: Service>(role: &str) -> (f64, f64) {
    let run = RunId::new(&format!("bench-{role}-{}", std::process::id())).unwrap();
    // Declared first so that it drops last, after our ports.
    let _echo;
    let (_node, publisher, subscriber, notifier, listener) = bare_ports::<S>(&run, "a", "b");
    _echo = spawn(role, &run);
    let bytes = consensus(0).to_bytes(&FORMAT);
    'connect: loop {
        use iceoryx2::port::update_connections::UpdateConnections;
        let _ = publisher.update_connections();
        bare_send(&publisher, &bytes);
        let _ = notifier.notify();
        let deadline = Instant::now() + Duration::from_millis(50);
        while Instant::now() < deadline {
            if subscriber.receive().unwrap().is_some() {
                break 'connect;
            }
            let _ = listener.timed_wait(|_| {}, Duration::from_millis(5));
        }
    }
    while subscriber.receive().unwrap().is_some() {}
    let mut times = Vec::with_capacity(ROUNDS);
    for i in 0..ROUNDS + WARMUP {
        let start = Instant::now();
        bare_send(&publisher, &bytes);
        let _ = notifier.notify();
        loop {
            if subscriber.receive().unwrap().is_some() {
                break;
            }
            let _ = listener.timed_wait(|_| {}, Duration::from_millis(100));
        }
        if i >= WARMUP {
            times.push(start.elapsed().as_secs_f64() * 1e6);
        }
    }
    percentiles(times)
}

fn bare_echo<S: Service>(run: &RunId) {
    let (_node, publisher, subscriber, notifier, listener) = bare_ports::<S>(run, "b", "a");
    loop {
        let _ = listener.timed_wait(|_| {}, Duration::from_millis(100));
        use iceoryx2::port::update_connections::UpdateConnections;
        let _ = publisher.update_connections();
        while let Some(sample) = subscriber.receive().unwrap() {
            bare_send(&publisher, sample.payload());
            let _ = notifier.notify();
        }
    }
}

/// A consensus message heard: (step, round, from).
type Heard = (u32, u16, u16);

/// One node of the nine-node round: its transport, connected to its
/// neighbours both ways before it returns, and the rounds already heard.
fn round_node(run: &RunId, node: u16) -> (IceoryxTransport, Vec<u16>, Vec<Heard>) {
    let topology = topology();
    let neighbours = topology.neighbours[node as usize].clone();
    let mut t =
        IceoryxTransport::new(run, ActorId::Node(node), &topology, FORMAT, node as u64).unwrap();
    t.publish_on(Channel::Consensus(node)).unwrap();
    for m in &neighbours {
        t.subscribe(Channel::Consensus(*m)).unwrap();
        t.notify(ActorId::Node(*m)).unwrap();
    }
    // Round 0 says "I hear you all" in its step field (1) or not yet (0);
    // a node goes on once every neighbour has heard it, which a 1 (or a
    // round already begun) from each of them proves.
    let receivers: Vec<ActorId> = neighbours.iter().map(|m| ActorId::Node(*m)).collect();
    let mut heard = vec![false; neighbours.len()];
    let mut heard_back = vec![false; neighbours.len()];
    let mut inbox = Vec::new();
    let mut early = Vec::new();
    while !heard_back.iter().all(|h| *h) {
        t.update_connections();
        let all = heard.iter().all(|h| *h) as u32;
        t.send(
            Channel::Consensus(node),
            &round_message(node, all, 0),
            &receivers,
        )
        .unwrap();
        t.wait(Duration::from_millis(2)).unwrap();
        inbox.clear();
        let now = t.now();
        t.receive(now, &mut inbox).unwrap();
        for m in &inbox {
            let ActorId::Node(from) = m.header.sender else {
                continue;
            };
            let Some(i) = neighbours.iter().position(|n| *n == from) else {
                continue;
            };
            heard[i] = true;
            heard_back[i] |= m.header.round > 0 || m.header.step == 1;
            if m.header.round > 0 {
                early.push((m.header.step, m.header.round, from));
            }
        }
    }
    (t, neighbours, early)
}

fn round_message(node: u16, step: u32, round: u16) -> Message {
    let mut m = consensus(step);
    m.header.sender = ActorId::Node(node);
    m.header.round = round;
    m
}

/// Polls for a wake-up for up to [`SPIN`], yielding between polls, then
/// sleeps: the node's wait.
fn wait_as_a_node(t: &mut IceoryxTransport) {
    let started = Instant::now();
    while started.elapsed() < SPIN {
        if t.poll_wake().unwrap() {
            return;
        }
        std::thread::yield_now();
    }
    t.wait(Duration::from_millis(100)).unwrap();
}

/// [`STEPS`] steps of [`ROUNDS_A_STEP`] rounds with the neighbours; each
/// step's time per round over rounds 2 to the last, in µs.
fn run_rounds(
    t: &mut IceoryxTransport,
    node: u16,
    neighbours: &[u16],
    mut heard: Vec<Heard>,
) -> Vec<f64> {
    let receivers: Vec<ActorId> = neighbours.iter().map(|m| ActorId::Node(*m)).collect();
    let mut inbox = Vec::new();
    let mut per_round = Vec::with_capacity(STEPS as usize);
    for step in 1..=STEPS {
        let mut first_done = Instant::now();
        for round in 1..=ROUNDS_A_STEP {
            t.send(
                Channel::Consensus(node),
                &round_message(node, step, round),
                &receivers,
            )
            .unwrap();
            loop {
                inbox.clear();
                let now = t.now();
                t.receive(now, &mut inbox).unwrap();
                for m in &inbox {
                    if let ActorId::Node(from) = m.header.sender {
                        if m.header.round > 0 {
                            heard.push((m.header.step, m.header.round, from));
                        }
                    }
                }
                let in_now = heard.iter().filter(|h| h.0 == step && h.1 == round).count();
                if in_now == neighbours.len() {
                    break;
                }
                wait_as_a_node(t);
            }
            heard.retain(|h| !(h.0 == step && h.1 == round));
            if round == 1 {
                first_done = Instant::now();
            }
        }
        let later = first_done.elapsed().as_secs_f64() * 1e6;
        per_round.push(later / f64::from(ROUNDS_A_STEP - 1));
    }
    per_round
}

/// CPU time of this process so far (user and system).
fn cpu_time() -> Duration {
    // SAFETY: getrusage fills the struct it is given.
    let usage = unsafe {
        let mut u = std::mem::zeroed::<libc::rusage>();
        assert_eq!(libc::getrusage(libc::RUSAGE_SELF, &mut u), 0);
        u
    };
    let tv = |t: libc::timeval| Duration::new(t.tv_sec as u64, t.tv_usec as u32 * 1000);
    tv(usage.ru_utime) + tv(usage.ru_stime)
}

/// [`run_rounds`] and the CPU this process spent in them.
fn timed_rounds(
    t: &mut IceoryxTransport,
    node: u16,
    neighbours: &[u16],
    early: Vec<Heard>,
) -> (Vec<f64>, Duration) {
    let before = cpu_time();
    let times = run_rounds(t, node, neighbours, early);
    (times, cpu_time() - before)
}

/// A spawned node of the nine: its CPU in µs on the first line of its
/// output, then its times per round.
fn round_echo(run: &RunId) {
    let node: u16 = std::env::var(NODE).unwrap().parse().unwrap();
    let (mut t, neighbours, early) = round_node(run, node);
    let (times, cpu) = timed_rounds(&mut t, node, &neighbours, early);
    let mut text = vec![(cpu.as_secs_f64() * 1e6).to_string()];
    text.extend(times.iter().map(|x| x.to_string()));
    std::fs::write(std::env::var(OUT).unwrap(), text.join("\n")).unwrap();
}

/// The nine-node round: node 0 here, the others spawned; percentiles of
/// every node's per-step time per round, and the CPU all nine spent per
/// round in µs.
fn nine_node_round() -> (f64, f64, f64) {
    let run = RunId::new(&format!("bench-rounds-{}", std::process::id())).unwrap();
    let dir = std::env::temp_dir().join(format!("cqnet-rounds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let nodes = topology().neighbours.len() as u16;
    let mut children: Vec<(Echo, std::path::PathBuf)> = (1..nodes)
        .map(|n| {
            let out = dir.join(format!("{n}.txt"));
            let env = [(NODE, n.to_string()), (OUT, out.display().to_string())];
            (spawn_with("rounds", &run, &env), out)
        })
        .collect();
    let (mut t, neighbours, early) = round_node(&run, 0);
    let (mut all, cpu) = timed_rounds(&mut t, 0, &neighbours, early);
    let mut cpu_micros = cpu.as_secs_f64() * 1e6;
    for (child, out) in &mut children {
        assert!(child.0.wait().unwrap().success(), "a round node failed");
        let text = std::fs::read_to_string(&*out).unwrap();
        let mut lines = text.lines().map(|l| l.parse::<f64>().unwrap());
        cpu_micros += lines.next().unwrap();
        all.extend(lines);
    }
    drop(t);
    drop(children);
    let _ = std::fs::remove_dir_all(&dir);
    let (p50, p99) = percentiles(all);
    let rounds = f64::from(STEPS) * f64::from(ROUNDS_A_STEP);
    (p50, p99, cpu_micros / rounds)
}

fn main() {
    if let Ok(role) = std::env::var(ROLE) {
        let run = RunId::new(&std::env::var(RUN).unwrap()).unwrap();
        match role.as_str() {
            "rounds" => round_echo(&run),
            "cqnet" => cqnet_echo(&run),
            "futex" => bare_echo::<futex::Service>(&run),
            _ => bare_echo::<ipc::Service>(&run),
        }
        return;
    }
    let bytes = consensus(0).to_bytes(&FORMAT).len();
    let (b50, b99) = bare::<ipc::Service>("bare");
    let (f50, f99) = bare::<futex::Service>("futex");
    let (c50, c99) = cqnet_transport();
    println!(
        "round trip of a {bytes}-byte consensus message between two processes, {ROUNDS} rounds:"
    );
    println!("  bare iceoryx2, socket event (ipc):  p50 {b50:7.1} µs   p99 {b99:7.1} µs");
    println!("  bare iceoryx2, futex event:         p50 {f50:7.1} µs   p99 {f99:7.1} µs");
    println!("  cqnet's transport (futex event):    p50 {c50:7.1} µs   p99 {c99:7.1} µs");
    let (r50, r99, cpu) = nine_node_round();
    println!(
        "consensus round among the default scenario's {} nodes, each a process, \
         no arithmetic, {STEPS} steps of {ROUNDS_A_STEP} rounds:",
        topology().neighbours.len()
    );
    println!("  cqnet's transport, time per round:  p50 {r50:7.1} µs   p99 {r99:7.1} µs");
    println!(
        "  CPU of all nine per round:          {cpu:7.1} µs ({:.2} ms a step of {ROUNDS_A_STEP} rounds)",
        cpu * f64::from(ROUNDS_A_STEP) / 1e3
    );
}
