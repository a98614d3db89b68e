//! The consensus round without its arithmetic: the default scenario's nine
//! nodes, each its own process, exchange a consensus message with their
//! neighbours through cqnet's transport, ten rounds a step, combining
//! nothing and waiting as a node does (`actor_process::wait_as_a_node`).
//! Its time per round is measured as `cqnet run` measures its round
//! latency (rounds 2 to 10 of each step, per round), so it is the floor
//! that scheduling nine processes on the machine's cores sets under the
//! network's round p50; the CPU the nine spend per round is the floor
//! under the network's CPU per step beyond `sim`'s.
//!
//! `cargo bench -p launch --bench rounds` prints p50, p99 and the CPU.
//! The benchmark spawns itself as the other eight nodes.

use std::path::PathBuf;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use fusion_graph::{ActorId, Scenario, Topology};
use launch::actor_process::wait_as_a_node;
use launch::usage::own_cpu_seconds;
use transport::iceoryx::remove_run_resources;
use transport::{Channel, IceoryxTransport, RunId, Transport};
use wire::WireFormat;

// The transport's benchmarks' message, so that both measure the same bytes.
#[path = "../../fusion-graph/transport/benches/common/consensus.rs"]
mod common;
use common::consensus_message;

const RUN: &str = "CQNET_ROUNDS_RUN";
const NODE: &str = "CQNET_ROUNDS_NODE";
const OUT: &str = "CQNET_ROUNDS_OUT";
const STEPS: u32 = 2000;
/// The default scenario's rounds a step.
const ROUNDS_A_STEP: u16 = 10;
const FORMAT: WireFormat = WireFormat {
    cell_bytes: 1,
    activation_bytes: 4,
    payloads: wire::payloads::Payloads::NONE,
};

/// A consensus message heard: (step, round, from).
type Heard = (u32, u16, u16);

fn topology() -> Topology {
    Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap()
}

/// A spawned node, killed and reaped if the benchmark ends first; the
/// run's shared memory goes with the last.
struct Peer(Child, RunId);

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        let _ = remove_run_resources(&self.1);
    }
}

/// One node: its transport, connected to its neighbours both ways before
/// it returns, and the rounds already heard.
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
            &consensus_message(node, all, 0),
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

/// [`STEPS`] steps of [`ROUNDS_A_STEP`] rounds with the neighbours: each
/// step's time per round over rounds 2 to the last in µs, and the CPU this
/// process spent in them in µs.
fn run_rounds(
    t: &mut IceoryxTransport,
    node: u16,
    neighbours: &[u16],
    mut heard: Vec<Heard>,
) -> (Vec<f64>, f64) {
    let cpu_before = own_cpu_seconds().unwrap();
    let receivers: Vec<ActorId> = neighbours.iter().map(|m| ActorId::Node(*m)).collect();
    let mut inbox = Vec::new();
    let mut per_round = Vec::with_capacity(STEPS as usize);
    for step in 1..=STEPS {
        let mut first_done = Instant::now();
        for round in 1..=ROUNDS_A_STEP {
            t.send(
                Channel::Consensus(node),
                &consensus_message(node, step, round),
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
                wait_as_a_node(t, Duration::from_millis(100)).unwrap();
            }
            heard.retain(|h| !(h.0 == step && h.1 == round));
            if round == 1 {
                first_done = Instant::now();
            }
        }
        let later = first_done.elapsed().as_secs_f64() * 1e6;
        per_round.push(later / f64::from(ROUNDS_A_STEP - 1));
    }
    let cpu = (own_cpu_seconds().unwrap() - cpu_before) * 1e6;
    (per_round, cpu)
}

/// A spawned node: its CPU in µs on the first line of its output, then
/// its times per round.
fn peer(run: &RunId) {
    let node: u16 = std::env::var(NODE).unwrap().parse().unwrap();
    let (mut t, neighbours, early) = round_node(run, node);
    let (times, cpu) = run_rounds(&mut t, node, &neighbours, early);
    let mut text = vec![cpu.to_string()];
    text.extend(times.iter().map(|x| x.to_string()));
    std::fs::write(std::env::var(OUT).unwrap(), text.join("\n")).unwrap();
}

fn percentiles(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[(v.len() as f64 * 0.99) as usize])
}

fn main() {
    if let Ok(run) = std::env::var(RUN) {
        return peer(&RunId::new(&run).unwrap());
    }
    let run = RunId::new(&format!("bench-rounds-{}", std::process::id())).unwrap();
    let dir = std::env::temp_dir().join(format!("cqnet-rounds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let nodes = topology().neighbours.len() as u16;
    let mut peers: Vec<(Peer, PathBuf)> = (1..nodes)
        .map(|n| {
            let out = dir.join(format!("{n}.txt"));
            let child = Command::new(std::env::current_exe().unwrap())
                .env(RUN, run.as_str())
                .env(NODE, n.to_string())
                .env(OUT, &out)
                .spawn()
                .unwrap();
            (Peer(child, run.clone()), out)
        })
        .collect();
    let (mut t, neighbours, early) = round_node(&run, 0);
    let (mut all, mut cpu) = run_rounds(&mut t, 0, &neighbours, early);
    for (peer, out) in &mut peers {
        assert!(peer.0.wait().unwrap().success(), "a node failed");
        let text = std::fs::read_to_string(&*out).unwrap();
        let mut lines = text.lines().map(|l| l.parse::<f64>().unwrap());
        cpu += lines.next().unwrap();
        all.extend(lines);
    }
    // Our ports go before the peers' guards remove the run's files.
    drop(t);
    drop(peers);
    let _ = std::fs::remove_dir_all(&dir);
    let (p50, p99) = percentiles(all);
    let per_round = cpu / (f64::from(STEPS) * f64::from(ROUNDS_A_STEP));
    println!(
        "consensus round among the default scenario's {nodes} nodes, each a process, \
         no arithmetic, {STEPS} steps of {ROUNDS_A_STEP} rounds:"
    );
    println!("  time per round:             p50 {p50:7.1} µs   p99 {p99:7.1} µs");
    println!(
        "  CPU of all {nodes} per round:     {per_round:7.1} µs ({:.2} ms a step)",
        per_round * f64::from(ROUNDS_A_STEP) / 1e3
    );
}
