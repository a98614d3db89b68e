//! `cqnet experiment` as a user runs it: stopped by a signal.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

const CQNET: &str = env!("CARGO_BIN_EXE_cqnet-under-test");

/// SIGTERM (what `timeout`, systemd and CI send) stops an experiment at its
/// next step, saying so and where the runs so far are, rather than being
/// swallowed once a network experiment has run.
#[test]
fn sigterm_stops_an_experiment_between_steps() {
    let out = std::env::temp_dir().join(format!("cqnet-experiment-sigterm-{}", std::process::id()));
    let mut child = Command::new(CQNET)
        .args(["experiment", "bound-against-bits", "--runs", "50", "--out"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("cqnet starts");
    let (lines, heard) = mpsc::channel();
    let stderr = child.stderr.take().expect("piped");
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = lines.send(line.clone());
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    // A run has finished: the experiment is under way.
    let started = heard
        .iter()
        .any(|l| l.contains("bound-against-bits: ") && l.contains(" runs ("));
    assert!(started, "the experiment never reported a run");
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .expect("signal sent");
    // Generous: a loaded machine may take a while to finish a step.
    let mut status = None;
    for _ in 0..1200 {
        if let Some(s) = child.try_wait().expect("waitable") {
            status = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let Some(status) = status else {
        let _ = child.kill();
        let _ = child.wait();
        panic!("cqnet experiment did not stop on SIGTERM");
    };
    let stderr = reader.join().expect("reader");
    let _ = std::fs::remove_dir_all(&out);
    assert!(!status.success(), "a stopped experiment is not a success");
    assert!(stderr.contains("interrupted"), "{stderr}");
    assert!(
        stderr.contains("the runs' results so far are in"),
        "{stderr}"
    );
}
