//! The iceoryx2 transport between two real processes. The test binary spawns
//! itself as the child (selected by an environment variable), so nothing
//! needs installing. Every test uses its own run id and removes its child
//! process and shared memory, pass or fail.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use fusion_graph::{ActorId, LinkRule, Scenario, Topology};
use transport::accounting::Accounting;
use transport::iceoryx::{remove_run_resources, run_resources, sweep_abandoned_runs, RunLease};
use transport::{Channel, IceoryxTransport, RunId, Transport};
use wire::{Message, MessageKind, Payload, WireFormat};

const ROLE: &str = "CQNET_FG_CHILD_ROLE";
const RUN: &str = "CQNET_FG_CHILD_RUN";
const FORMAT: WireFormat = WireFormat {
    cell_bytes: 1,
    activation_bytes: 4,
    payloads: wire::payloads::Payloads::NONE,
};
const SENSOR: ActorId = ActorId::Sensor(0);
const NODE: ActorId = ActorId::Node(0);

fn topology() -> Topology {
    Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap()
}

fn unique_run(tag: &str) -> RunId {
    let n = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    RunId::new(&format!("t{}-{tag}-{n:x}", std::process::id())).unwrap()
}

/// The child process and the run's resources, removed on drop.
struct Run {
    id: RunId,
    child: Option<Child>,
}

impl Run {
    fn new(tag: &str) -> Self {
        Self {
            id: unique_run(tag),
            child: None,
        }
    }

    fn spawn(&mut self, role: &str) {
        let child = Command::new(std::env::current_exe().unwrap())
            .args([
                "child_process_entry",
                "--exact",
                "--nocapture",
                "--test-threads=1",
                "--quiet",
            ])
            .env(ROLE, role)
            .env(RUN, self.id.as_str())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn the test binary as a child");
        self.child = Some(child);
    }

    /// Waits for the child and returns the accounting it printed. A child
    /// still running after a minute has hung: the test fails (and drop
    /// kills it) rather than holding the whole suite.
    fn finish(&mut self) -> Accounting {
        let start = Instant::now();
        let child = self.child.as_mut().unwrap();
        while child.try_wait().unwrap().is_none() {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "the child of {} hung",
                self.id
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        let out = self.child.take().unwrap().wait_with_output().unwrap();
        assert!(out.status.success(), "child failed: {:?}", out.status);
        let text = String::from_utf8_lossy(&out.stdout);
        let csv = text
            .split("ACCOUNTING-BEGIN\n")
            .nth(1)
            .and_then(|s| s.split("ACCOUNTING-END").next())
            .expect("child printed its accounting");
        Accounting::from_csv(csv, wire::payloads::Payloads::NONE).unwrap()
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        let _ = remove_run_resources(&self.id);
    }
}

fn node_transport(run: &RunId) -> IceoryxTransport {
    let mut t = IceoryxTransport::new(run, NODE, &topology(), FORMAT, 7).unwrap();
    t.subscribe(Channel::Observation(0)).unwrap();
    t
}

/// Receives until `done` says so or ten seconds pass.
fn receive_until(
    t: &mut IceoryxTransport,
    mut done: impl FnMut(&[Message], &IceoryxTransport) -> bool,
) -> Vec<Message> {
    let mut got = Vec::new();
    let start = Instant::now();
    while !done(&got, t) && start.elapsed() < Duration::from_secs(10) {
        let now = t.now();
        t.receive(now, &mut got).unwrap();
        t.wait(Duration::from_millis(20)).unwrap();
    }
    got
}

fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

#[test]
fn delivers_with_byte_counts_on_both_sides() {
    let mut run = Run::new("deliver");
    let mut node = node_transport(&run.id);
    run.spawn("send-20");
    let got = receive_until(&mut node, |g, _| g.len() >= 20);
    let child = run.finish();
    assert_eq!(got.len(), 20);
    assert!(got
        .iter()
        .enumerate()
        .all(|(i, m)| m.header.step == i as u32 + 1 && m.header.sender == SENSOR));
    let recv = node
        .accounting()
        .get(SENSOR, NODE, MessageKind::Observation);
    let sent = child.get(SENSOR, NODE, MessageKind::Observation);
    assert_eq!((sent.sent_messages, sent.sent_bytes), (20, 280));
    assert_eq!((recv.received_messages, recv.received_bytes), (20, 280));
    drop(node);
    drop(run);
}

#[test]
fn delay_holds_each_message_for_at_least_its_latency() {
    let mut run = Run::new("delay");
    let mut node = node_transport(&run.id);
    node.shaper().set_rule(
        SENSOR,
        LinkRule {
            latency: Duration::from_millis(40),
            ..Default::default()
        },
    );
    run.spawn("send-timestamps");
    let mut lateness = Vec::new();
    let start = Instant::now();
    while lateness.len() < 10 && start.elapsed() < Duration::from_secs(10) {
        let mut got = Vec::new();
        let now = node.now();
        node.receive(now, &mut got).unwrap();
        for m in got {
            if let Payload::RawObservation { value } = m.payload {
                lateness.push(unix_now() - value);
            }
        }
        node.wait(Duration::from_millis(5)).unwrap();
    }
    run.finish();
    assert_eq!(lateness.len(), 10);
    assert!(lateness.iter().all(|l| *l >= 0.040), "{lateness:?}");
}

#[test]
fn loss_drops_the_expected_fraction() {
    let mut run = Run::new("loss");
    let mut node = node_transport(&run.id);
    node.shaper().set_rule(
        SENSOR,
        LinkRule {
            loss: 0.3,
            ..Default::default()
        },
    );
    run.spawn("send-1000");
    receive_until(&mut node, |_, t| {
        let c = t.accounting().get(SENSOR, NODE, MessageKind::Observation);
        c.received_messages + c.dropped_messages >= 1000
    });
    let child = run.finish();
    let c = node
        .accounting()
        .get(SENSOR, NODE, MessageKind::Observation);
    assert_eq!(
        child
            .get(SENSOR, NODE, MessageKind::Observation)
            .sent_messages,
        1000
    );
    // What reached the receiver went through the shaper; on a loaded machine
    // a few may have been overwritten in a full queue before that, and show
    // as sent but not accounted for.
    let arrived = c.received_messages + c.dropped_messages;
    assert!(arrived >= 950, "{c:?}");
    // 3.5 standard deviations of a binomial(arrived, 0.3).
    let expected = 0.3 * arrived as f64;
    let sd = (arrived as f64 * 0.3 * 0.7).sqrt();
    assert!(
        (c.dropped_messages as f64 - expected).abs() < 3.5 * sd,
        "{c:?}"
    );
}

#[test]
fn garbage_is_counted_as_malformed_and_dropped() {
    let mut run = Run::new("garbage");
    let mut node = node_transport(&run.id);
    run.spawn("send-garbage");
    let got = receive_until(&mut node, |_, t| {
        t.accounting()
            .get(SENSOR, NODE, MessageKind::Malformed)
            .malformed_messages
            >= 50
    });
    run.finish();
    assert!(got.is_empty(), "garbage was delivered: {got:?}");
    assert_eq!(
        node.accounting()
            .get(SENSOR, NODE, MessageKind::Malformed)
            .malformed_messages,
        50
    );
}

#[test]
fn runs_with_different_ids_never_see_each_other() {
    let mut run = Run::new("iso-a");
    let other = Run::new("iso-b");
    let mut node_a = node_transport(&run.id);
    let mut node_b = node_transport(&other.id);
    run.spawn("send-20");
    let got = receive_until(&mut node_a, |g, _| g.len() >= 20);
    run.finish();
    assert_eq!(got.len(), 20);
    std::thread::sleep(Duration::from_millis(50));
    let mut seen_by_b = Vec::new();
    let now = node_b.now();
    node_b.receive(now, &mut seen_by_b).unwrap();
    assert!(seen_by_b.is_empty());
    assert_eq!(node_b.accounting().iter().count(), 0);
}

/// The iceoryx2 node directories that hold files of `run`: named by node
/// id, without the run's prefix.
fn node_directories(run: &RunId) -> Vec<std::path::PathBuf> {
    let dirs: std::collections::BTreeSet<std::path::PathBuf> = run_resources(run)
        .iter()
        .filter_map(|f| f.parent())
        .filter(|d| d.parent().is_some_and(|p| p.ends_with("nodes")))
        .map(std::path::Path::to_path_buf)
        .collect();
    dirs.into_iter().collect()
}

#[test]
fn cleanup_removes_every_resource_of_the_run() {
    let (id, node_dirs) = {
        let mut run = Run::new("cleanup");
        let node = node_transport(&run.id);
        run.spawn("send-20");
        run.finish();
        let files = run_resources(&run.id);
        assert!(
            !files.is_empty(),
            "the run created no files under its prefix"
        );
        let node_dirs = node_directories(&run.id);
        assert!(!node_dirs.is_empty(), "no node directory among {files:?}");
        drop(node);
        (run.id.clone(), node_dirs)
    };
    assert_eq!(run_resources(&id), Vec::<std::path::PathBuf>::new());
    let left: Vec<_> = node_dirs.iter().filter(|d| d.exists()).collect();
    assert!(left.is_empty(), "node directories left: {left:?}");
}

/// A SIGKILLed process cannot remove its iceoryx2 node directory (named by
/// node id, without the run's prefix): the run's cleanup must, or every
/// killed actor leaves one behind (15,297 had piled up on the development machine).
#[test]
fn cleanup_removes_the_node_directory_of_a_killed_process() {
    let mut run = Run::new("killed-dir");
    run.spawn("wait-then-send");
    let start = Instant::now();
    let mut dirs = node_directories(&run.id);
    while dirs.is_empty() {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the child made no node"
        );
        std::thread::sleep(Duration::from_millis(10));
        dirs = node_directories(&run.id);
    }
    let mut child = run.child.take().unwrap();
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    remove_run_resources(&run.id).unwrap();
    assert_eq!(run_resources(&run.id), Vec::<std::path::PathBuf>::new());
    let left: Vec<_> = dirs.iter().filter(|d| d.exists()).collect();
    assert!(left.is_empty(), "node directories left: {left:?}");
}

/// A wait interrupted by a signal (here SIGSTOP then SIGCONT, which Linux
/// lets interrupt a timed wait even with no handler installed) is a
/// spurious wake-up, not an error: the child, blocked in `wait`, is
/// stopped and continued, and must go on to send its message and exit well.
#[test]
fn a_wait_interrupted_by_sigstop_and_sigcont_goes_on() {
    let mut run = Run::new("sigcont");
    let mut node = node_transport(&run.id);
    run.spawn("wait-then-send");
    let pid = run.child.as_ref().unwrap().id().to_string();
    let signal = |name: &str| {
        let status = Command::new("kill").args([name, &pid]).status().unwrap();
        assert!(status.success(), "kill {name} {pid}");
    };
    std::thread::sleep(Duration::from_millis(300));
    signal("-STOP");
    std::thread::sleep(Duration::from_millis(200));
    signal("-CONT");
    let got = receive_until(&mut node, |g, _| !g.is_empty());
    let child = run.finish();
    assert_eq!(got.len(), 1);
    assert_eq!(
        child
            .get(SENSOR, NODE, MessageKind::Observation)
            .sent_messages,
        1
    );
}

/// The sweep removes a run whose launcher is gone (a child that took a
/// lease and exited without giving it back, as a SIGKILLed launcher does)
/// and leaves alone a run whose launcher lives (this test process).
#[test]
fn the_sweep_removes_abandoned_runs_and_only_those() {
    let mut gone = Run::new("gone");
    let live = unique_run("live");
    let fake = |run: &RunId| std::path::PathBuf::from(format!("/dev/shm/{}fake", run.prefix()));
    std::fs::write(fake(&gone.id), b"x").unwrap();
    std::fs::write(fake(&live), b"x").unwrap();
    let _lease = RunLease::acquire(&live).unwrap();
    gone.spawn("lease-and-exit");
    let status = gone.child.take().unwrap().wait().unwrap();
    assert!(status.success());

    let cleaned = sweep_abandoned_runs().unwrap();
    let live_left = fake(&live).exists();
    let _ = std::fs::remove_file(fake(&live));
    assert!(cleaned.contains(&gone.id), "{cleaned:?}");
    assert!(!cleaned.contains(&live), "a live run was swept");
    assert!(
        !fake(&gone.id).exists(),
        "the abandoned run's file survived"
    );
    assert!(live_left, "the live run's file was removed");
}

/// Not a test: the body of the child process, run when the parent spawns
/// this binary with `CQNET_FG_CHILD_ROLE` set. Without it, it does nothing.
#[test]
fn child_process_entry() {
    let Ok(role) = std::env::var(ROLE) else {
        return;
    };
    let run = RunId::new(&std::env::var(RUN).unwrap()).unwrap();
    if role == "lease-and-exit" {
        // A launcher that dies without cleaning up: the lease stays behind.
        std::mem::forget(RunLease::acquire(&run).unwrap());
        return;
    }
    let mut t = IceoryxTransport::new(&run, SENSOR, &topology(), FORMAT, 1).unwrap();
    t.publish_on(Channel::Observation(0)).unwrap();
    t.notify(NODE).unwrap();
    t.update_connections();
    let send = |t: &mut IceoryxTransport, step: u32, payload: Payload| {
        t.send(
            Channel::Observation(0),
            &Message::new(SENSOR, step, 0, payload),
            &[NODE],
        )
        .unwrap()
    };
    match role.as_str() {
        "send-20" => (1..=20).for_each(|s| send(&mut t, s, Payload::Observation { cell: s })),
        "send-1000" => (1..=1000).for_each(|s| {
            send(&mut t, s, Payload::Observation { cell: s % 256 });
            if s % 10 == 0 {
                // Stay within the subscriber's queue.
                std::thread::sleep(Duration::from_millis(1));
            }
        }),
        "send-timestamps" => (1..=10).for_each(|s| {
            send(&mut t, s, Payload::RawObservation { value: unix_now() });
            std::thread::sleep(Duration::from_millis(3));
        }),
        "send-garbage" => {
            let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
            for i in 0..50 {
                let len = 1 + i % 40;
                let bytes: Vec<u8> = (0..len)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 7;
                        x ^= x << 17;
                        x as u8
                    })
                    .collect();
                t.inject_raw(Channel::Observation(0), &bytes).unwrap();
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        "wait-then-send" => {
            // Blocked in `wait` for over a second, through the parent's
            // SIGSTOP and SIGCONT; an error from `wait` ends the child badly.
            let start = Instant::now();
            while start.elapsed() < Duration::from_millis(1200) {
                t.wait(Duration::from_millis(400)).unwrap();
            }
            send(&mut t, 1, Payload::Observation { cell: 1 });
        }
        other => panic!("unknown child role {other}"),
    }
    // A publisher's samples live in its own shared memory and vanish when it
    // exits: stay until the parent has read them.
    std::thread::sleep(Duration::from_millis(500));
    print!(
        "ACCOUNTING-BEGIN\n{}ACCOUNTING-END\n",
        t.accounting().to_csv()
    );
}
