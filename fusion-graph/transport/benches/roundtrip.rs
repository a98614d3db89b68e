//! Round trip of one consensus-sized message between two processes: through
//! cqnet's iceoryx2 transport (encode, link shaper, decode, accounting,
//! wake-up event), and through bare iceoryx2 publish/subscribe with a
//! wake-up event, so the cost of our layer is visible. Bare iceoryx2 runs
//! twice: with the `ipc` service's event (a Unix datagram socket) and with
//! the futex event cqnet's transport uses (`transport/futex.rs`).
//!
//! `cargo bench -p transport --bench roundtrip` prints p50 and p99.
//! The benchmark spawns itself as the echoing process.

use std::process::{Child, Command};
use std::time::{Duration, Instant};

use fusion_graph::{ActorId, Scenario, Topology};
use iceoryx2::prelude::*;
use transport::futex;
use transport::iceoryx::remove_run_resources;
use transport::{Channel, IceoryxTransport, RunId, Transport};
use wire::{Message, WireFormat};

#[path = "common/consensus.rs"]
mod common;
use common::consensus_message;

const ROLE: &str = "CQNET_ROUNDTRIP_ROLE";
const RUN: &str = "CQNET_ROUNDTRIP_RUN";
const ROUNDS: usize = 5000;
const WARMUP: usize = 200;
const FORMAT: WireFormat = WireFormat {
    cell_bytes: 1,
    activation_bytes: 4,
    payloads: wire::payloads::Payloads::NONE,
};

fn topology() -> Topology {
    Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap()
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
    let child = Command::new(std::env::current_exe().unwrap())
        .env(ROLE, role)
        .env(RUN, run.as_str())
        .spawn()
        .unwrap();
    Echo(child, run.clone())
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
        t.send(
            Channel::Consensus(0),
            &consensus_message(0, 0, 1),
            &[ActorId::Node(1)],
        )
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
        t.send(
            Channel::Consensus(0),
            &consensus_message(0, i, 1),
            &[ActorId::Node(1)],
        )
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
    let bytes = consensus_message(0, 0, 1).to_bytes(&FORMAT);
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

fn main() {
    if let Ok(role) = std::env::var(ROLE) {
        let run = RunId::new(&std::env::var(RUN).unwrap()).unwrap();
        match role.as_str() {
            "cqnet" => cqnet_echo(&run),
            "futex" => bare_echo::<futex::Service>(&run),
            _ => bare_echo::<ipc::Service>(&run),
        }
        return;
    }
    let bytes = consensus_message(0, 0, 1).to_bytes(&FORMAT).len();
    let (b50, b99) = bare::<ipc::Service>("bare");
    let (f50, f99) = bare::<futex::Service>("futex");
    let (c50, c99) = cqnet_transport();
    println!(
        "round trip of a {bytes}-byte consensus message between two processes, {ROUNDS} rounds:"
    );
    println!("  bare iceoryx2, socket event (ipc):  p50 {b50:7.1} µs   p99 {b99:7.1} µs");
    println!("  bare iceoryx2, futex event:         p50 {f50:7.1} µs   p99 {f99:7.1} µs");
    println!("  cqnet's transport (futex event):    p50 {c50:7.1} µs   p99 {c99:7.1} µs");
}
