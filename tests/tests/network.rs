//! Whole networks of real processes (`cqnet run`): one process per node and
//! per sensor, 235 with the launcher for the default scenario. Each test has
//! its own run id and leaves no process and no shared memory behind.

use fusion_graph::wire::MessageKind;
use tests::{exclusive, rmse, Invocation};

const CQNET: &str = env!("CARGO_BIN_EXE_cqnet-under-test");

/// Generous timeouts: with 235 processes on two cores a round can take a while,
/// and a timeout that fires changes the answer.
const PATIENT: [&str; 4] = [
    "--set",
    "consensus.round_timeout_ms=20000",
    "--set",
    "clock.step_timeout_ms=60000",
];

fn run(tag: &str, args: &[&str]) -> Invocation {
    let mut all: Vec<&str> = vec!["--lockstep"];
    all.extend_from_slice(args);
    Invocation::new(CQNET, tag, "run", &all, &[])
}

fn assert_clean(i: &Invocation) {
    assert_eq!(
        i.leftover_processes(),
        Vec::<u32>::new(),
        "processes of {} survived",
        i.run_id
    );
    assert_eq!(
        i.leftover_shared_memory(),
        Vec::<std::path::PathBuf>::new(),
        "shared memory of {} survived",
        i.run_id
    );
}

#[test]
fn lockstep_run_reproduces_sim_bit_for_bit() {
    let _guard = exclusive();
    let args = [&PATIENT[..], &["--set", "steps=10"]].concat();
    let r = run("same", &args);
    r.assert_success();
    let s = Invocation::new(CQNET, "same-sim", "sim", &args, &[]);
    s.assert_success();
    let mut a: Vec<String> = r.ticks().into_iter().map(|t| t.line).collect();
    let mut b: Vec<String> = s.ticks().into_iter().map(|t| t.line).collect();
    a.sort();
    b.sort();
    assert_eq!(
        a.len(),
        10 * 10,
        "nine nodes and the centralized reference, ten steps"
    );
    assert_eq!(a, b);
    assert_clean(&r);
}

#[test]
fn bytes_per_link_are_what_the_topology_and_message_sizes_predict() {
    let _guard = exclusive();
    let args = [
        &PATIENT[..],
        &["--set", "steps=6", "--set", "consensus.auxiliary_fim=true"],
    ]
    .concat();
    let r = run("bytes", &args);
    r.assert_success();
    let kinds = r.links().by_kind();
    let sent = |k: MessageKind| kinds.get(&k).map_or(0, |c| c.sent_bytes);
    let received = |k: MessageKind| kinds.get(&k).map_or(0, |c| c.received_bytes);
    let steps = 6;
    // 3 active sensors × 9 nodes, each observation (11 + 1 bytes) to its node and the centralized reference.
    assert_eq!(sent(MessageKind::Observation), steps * 27 * 2 * 12);
    // 24 directed fusion-graph links × 10 rounds: δη, δΛ, ΔL (11 + 192 bytes) and S_obs (11 + 80).
    assert_eq!(sent(MessageKind::Consensus), steps * 24 * 10 * 203);
    assert_eq!(sent(MessageKind::ConsensusAux), steps * 24 * 10 * 91);
    // The launcher's tick (11 + 32) and the nodes' activation (11 + 4) reach all 225 sensors.
    assert_eq!(sent(MessageKind::Tick), steps * 225 * 43);
    assert_eq!(sent(MessageKind::Activate), steps * 225 * 15);
    for k in [
        MessageKind::Observation,
        MessageKind::Consensus,
        MessageKind::ConsensusAux,
        MessageKind::Tick,
        MessageKind::Activate,
    ] {
        assert_eq!(received(k), sent(k), "{k:?}: every byte sent was received");
    }
    // Bound traffic: ΔL (80 bytes a message) against ΔL and S_obs: 1 : 2.
    let summary = r.summary();
    let cq = summary["bound_traffic"]["cq_dpcrlb_bytes"]
        .as_u64()
        .unwrap();
    assert_eq!(cq, steps * 24 * 10 * 80);
    assert_eq!(
        summary["bound_traffic"]["auxiliary_fim_bytes"]
            .as_u64()
            .unwrap(),
        2 * cq
    );
    assert_clean(&r);
}

#[test]
fn the_network_survives_sigkill_of_the_centre_node() {
    let _guard = exclusive();
    let base = ["--set", "steps=30", "--no-central"];
    let healthy = run("healthy", &base);
    healthy.assert_success();
    let kill = [
        &base[..],
        &[
            "--set",
            "faults=[{kind=\"kill\", actor=\"node-4\", at_step=10, signal=\"SIGKILL\"}]",
        ],
    ]
    .concat();
    let r = run("kill", &kill);
    r.assert_success();
    let ticks = r.ticks();
    for step in 10..=30 {
        let rows: Vec<_> = ticks.iter().filter(|t| t.step == step).collect();
        assert_eq!(
            rows.len(),
            8,
            "step {step}: {:?}",
            rows.iter().map(|t| &t.node).collect::<Vec<_>>()
        );
        assert!(
            rows.iter().all(|t| t.node != "node-4" && t.bound.is_some()),
            "step {step}"
        );
    }
    let (after, before) = (rmse(&ticks, 10..=30), rmse(&healthy.ticks(), 10..=30));
    assert!(
        after <= 3.0 * before,
        "RMSE after the kill {after} vs {before} without it"
    );
    assert_eq!(
        r.summary()["fault_cost"]["missing_node_steps"].as_u64(),
        Some(21)
    );
    assert_clean(&r);
    assert_clean(&healthy);
}

#[test]
fn delay_loss_and_a_healing_partition_are_survived_and_accounted() {
    let _guard = exclusive();
    let faults = "faults=[\
        {kind=\"delay\", links=[{from=\"node-0\", to=\"node-1\"}], at_step=5, duration=10, latency_ms=200.0},\
        {kind=\"loss\", links=[{from=\"*\", to=\"*\"}], at_step=10, duration=10, probability=0.3},\
        {kind=\"partition\", groups=[[\"node-0\", \"node-1\", \"node-3\", \"node-4\"], [\"node-2\", \"node-5\", \"node-6\", \"node-7\", \"node-8\"]], at_step=20, duration=10}]";
    let r = run(
        "linkfaults",
        &[
            "--set",
            "steps=45",
            "--no-central",
            "--set",
            "consensus.round_timeout_ms=100",
            "--set",
            "clock.step_timeout_ms=1500",
            "--set",
            faults,
        ],
    );
    r.assert_success();
    let s = r.summary();
    assert_eq!(s["steps"].as_u64(), Some(45));
    let cost = &s["fault_cost"];
    assert!(cost["dropped_messages"].as_u64().unwrap() > 100, "{cost}");
    assert!(cost["late_messages"].as_u64().unwrap() > 0, "{cost}");
    assert!(
        cost["rounds_with_fewer_neighbours"].as_u64().unwrap() > 0,
        "{cost}"
    );
    assert_eq!(s["faults"].as_array().unwrap().len(), 3);
    // Tracking recovers once the partition has healed.
    let late = rmse(&r.ticks(), 38..=45);
    assert!(late < 10.0, "RMSE over steps 38-45: {late}");
    assert_clean(&r);
}

#[test]
fn a_restarted_node_rejoins_and_tracks_again() {
    let _guard = exclusive();
    let faults = "faults=[{kind=\"kill\", actor=\"node-4\", at_step=8, signal=\"SIGKILL\", restart_after=6}]";
    let r = run(
        "restart",
        &["--set", "steps=30", "--no-central", "--set", faults],
    );
    r.assert_success();
    let ticks = r.ticks();
    let node4: Vec<_> = ticks.iter().filter(|t| t.node == "node-4").collect();
    assert!(
        node4.iter().all(|t| t.step < 8 || t.step >= 14),
        "node-4 reported while dead"
    );
    let first_back = node4
        .iter()
        .map(|t| t.step)
        .filter(|s| *s >= 14)
        .min()
        .expect("node-4 came back");
    assert!(
        first_back <= 16,
        "node-4 first reported again at step {first_back}"
    );
    let back: Vec<f64> = node4
        .iter()
        .filter(|t| t.step >= 18)
        .map(|t| t.error)
        .collect();
    let worst = back.iter().cloned().fold(0.0, f64::max);
    assert!(
        !back.is_empty() && worst < 15.0,
        "node-4's error after rejoining: {back:?}"
    );
    assert_clean(&r);
}

#[test]
fn two_runs_at_once_count_the_same_bytes_as_one_alone_and_leave_nothing() {
    let _guard = exclusive();
    let args = [&PATIENT[..], &["--set", "steps=5", "--no-central"]].concat();
    let alone = run("alone", &args);
    alone.assert_success();
    let (a, b) = std::thread::scope(|s| {
        let a = s.spawn(|| run("pair-a", &args));
        let b = s.spawn(|| run("pair-b", &args));
        (a.join().unwrap(), b.join().unwrap())
    });
    a.assert_success();
    b.assert_success();
    let sent = |i: &Invocation| {
        i.links()
            .by_kind()
            .into_iter()
            .filter(|(k, _)| *k != MessageKind::Control)
            .map(|(k, c)| (k, c.sent_bytes, c.received_bytes))
            .collect::<Vec<_>>()
    };
    assert_eq!(sent(&a), sent(&alone));
    assert_eq!(sent(&b), sent(&alone));
    for i in [&alone, &a, &b] {
        assert_clean(i);
    }
}

#[test]
fn bad_input_ends_the_run_with_a_clear_error() {
    let _guard = exclusive();
    // A malformed scenario file.
    let dir = std::env::temp_dir().join(format!("cqnet-tests/bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("broken.toml");
    std::fs::write(
        &file,
        fusion_graph::scenario::DEFAULT_SCENARIO.replace("bits = 8", "bits = 99"),
    )
    .unwrap();
    let r = run("badfile", &[file.to_str().unwrap()]);
    assert!(!r.output().status.success());
    assert!(
        r.stderr().contains("quantizer.bits") && r.stderr().contains("broken.toml"),
        "{}",
        r.stderr()
    );

    // A fault naming an actor the network does not have.
    let r = run(
        "badactor",
        &[
            "--set",
            "faults=[{kind=\"kill\", actor=\"node-42\", at_step=3, signal=\"SIGKILL\"}]",
        ],
    );
    assert!(!r.output().status.success());
    assert!(
        r.stderr().contains("faults[0].actor") && r.stderr().contains("node-42"),
        "{}",
        r.stderr()
    );

    // A child that fails at start: its name and the end of its stderr.
    let r = Invocation::new(
        CQNET,
        "badchild",
        "run",
        &["--lockstep", "--set", "steps=3"],
        &[("CQNET_FAIL_AT_START", "node-3")],
    );
    assert!(!r.output().status.success());
    let err = r.stderr();
    assert!(
        err.contains("node-3")
            && err.contains("before it was ready")
            && err.contains("failing at start"),
        "{err}"
    );
    assert_clean(&r);
}

/// SIGTERM (what `timeout`, systemd and CI send) and SIGHUP stop a run as
/// Ctrl-C does: every child stopped and reaped, the run's shared memory
/// removed, and the results so far written. Before, SIGTERM killed the
/// launcher on the spot and left 234 children and their shared memory.
#[test]
fn sigterm_and_sighup_stop_a_run_as_ctrl_c_does() {
    let _guard = exclusive();
    for signal in ["TERM", "HUP"] {
        let r = Invocation::signalled(
            CQNET,
            &format!("sig{}", signal.to_lowercase()),
            "run",
            &["--set", "steps=1000", "--no-central"],
            signal,
            None,
            1,
        );
        assert!(
            !r.output().status.success(),
            "SIG{signal}: a stopped run is not a success"
        );
        assert!(
            r.stderr().contains("interrupted at step"),
            "SIG{signal}: {}",
            r.stderr()
        );
        assert!(
            !r.ticks().is_empty(),
            "SIG{signal}: the rows so far are kept"
        );
        assert!(
            r.out.join("summary.json").exists(),
            "SIG{signal}: no summary"
        );
        assert_clean(&r);
    }
}

/// A SIGKILLed launcher cannot clean up. Its children die with it (their
/// parent-death signal), its shared memory stays, and `cqnet clean` removes
/// it, knowing the run by the lease its dead launcher left.
#[test]
fn cqnet_clean_removes_what_a_sigkilled_launcher_left() {
    let _guard = exclusive();
    let r = Invocation::signalled(
        CQNET,
        "sigkill",
        "run",
        &["--set", "steps=1000", "--no-central"],
        "KILL",
        None,
        1,
    );
    let start = std::time::Instant::now();
    while !r.leftover_processes().is_empty() && start.elapsed().as_secs() < 30 {
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    assert_eq!(
        r.leftover_processes(),
        Vec::<u32>::new(),
        "children outlived the launcher"
    );
    assert!(
        !r.leftover_shared_memory().is_empty(),
        "nothing was left to clean: the test shows nothing"
    );
    let clean = std::process::Command::new(CQNET)
        .arg("clean")
        .output()
        .unwrap();
    assert!(clean.status.success());
    let said = String::from_utf8_lossy(&clean.stdout);
    assert!(said.contains(&r.run_id), "{said}");
    assert_clean(&r);
}

/// An actor that dies on its own is a fault of the run: the summary lists
/// it. Here node-4, stopped by the scenario at step 5 until step 25, is
/// SIGKILLed from outside while stopped; at step 25 the launcher starts it
/// afresh (a SIGCONT would reach no one), and it reports again.
#[test]
fn an_actor_that_dies_unexpectedly_is_a_fault_and_its_restart_still_applies() {
    let _guard = exclusive();
    let faults = "faults=[{kind=\"kill\", actor=\"node-4\", at_step=5, signal=\"SIGSTOP\", restart_after=20}]";
    let r = Invocation::signalled(
        CQNET,
        "crash",
        "run",
        &["--set", "steps=45", "--no-central", "--set", faults],
        "KILL",
        Some("node-4"),
        10,
    );
    r.assert_success();
    let faults = r.summary()["faults"].to_string();
    assert!(faults.contains("node-4 died unexpectedly"), "{faults}");
    let back = r
        .ticks()
        .iter()
        .filter(|t| t.node == "node-4" && t.step >= 25)
        .map(|t| t.step)
        .min();
    assert!(
        back.is_some_and(|s| s <= 30),
        "node-4 did not report again after its restart: first at {back:?}"
    );
    assert_clean(&r);
}

/// A network that cannot fit the machine is refused before anything is
/// spawned, with what to change: 2·10⁹ particles per filter would need
/// hundreds of GiB.
#[test]
fn a_network_too_large_for_the_machine_is_refused_before_it_starts() {
    let _guard = exclusive();
    let r = run("toolarge", &["--set", "filter.particles=2000000000"]);
    assert!(!r.output().status.success());
    let stderr = r.stderr();
    assert!(
        stderr.contains("filter.particles")
            && stderr.contains("GiB")
            && stderr.contains("available"),
        "{stderr}"
    );
    assert!(
        !r.out.join("logs").exists()
            || std::fs::read_dir(r.out.join("logs"))
                .unwrap()
                .next()
                .is_none(),
        "children were started"
    );
    assert_clean(&r);
}

/// Seed 001's network with the conditional PCRLB manager, node-4 SIGKILLed
/// from outside. The helper polls `ticks.csv` every 2 ms, so the kill lands
/// within milliseconds of step 10's last report: inside step 11's
/// selection, which takes about 25 ms of a lockstep step. The step does not
/// stall: the others presume node-4 gone after two missed rounds and finish
/// without it (with that rule disabled, this test fails: "step 11 overran
/// its step timeout"); from the next step the membership view leaves it
/// out, and the eight survivors still agree on 18 sensors every step.
#[test]
fn a_node_killed_during_pcrlb_selection_does_not_stall_the_step() {
    let _guard = exclusive();
    let seed001 = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../fusion-graph/scenarios/seed001.toml"
    );
    let r = Invocation::signalled(
        CQNET,
        "select-kill",
        "run",
        &[seed001, "--lockstep", "--no-central", "--set", "steps=30"],
        "KILL",
        Some("node-4"),
        10,
    );
    r.assert_success();
    let faults = r.summary()["faults"].to_string();
    assert!(faults.contains("node-4 died unexpectedly"), "{faults}");
    let ticks = r.ticks();
    let observations =
        |t: &tests::Tick| -> u32 { t.line.split(',').nth(12).unwrap().parse().unwrap() };
    for step in 1..=30 {
        let rows: Vec<_> = ticks.iter().filter(|t| t.step == step).collect();
        let survivors = rows.iter().filter(|t| t.node != "node-4").count();
        assert_eq!(survivors, 8, "step {step}: a survivor did not report");
        assert!(rows.iter().all(|t| t.bound.is_some()), "step {step}");
        let overran = |t: &&tests::Tick| t.line.split(',').nth(13) == Some("1");
        assert!(
            !rows.iter().any(overran),
            "step {step} overran its step timeout"
        );
        if step < 10 || step > 11 {
            let total: u32 = rows.iter().map(|t| observations(t)).sum();
            assert_eq!(
                total, 18,
                "step {step}: the nodes did not agree on N_max sensors"
            );
        }
    }
    assert_clean(&r);
}
