//! Helpers for tests that launch whole process networks: run the program,
//! read its results, and make sure nothing of a run survives it.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use fusion_graph::accounting::Accounting;
use fusion_graph::transport::iceoryx::{remove_run_resources, run_resources};
use fusion_graph::transport::RunId;

/// Network tests take the machine's cores; they run one at a time.
pub fn exclusive() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// One invocation of the program, with its own run id and output folder.
/// Dropping it kills whatever process still carries the run id and removes
/// the run's shared memory, so a failing test leaves nothing behind.
pub struct Invocation {
    pub run_id: String,
    pub out: PathBuf,
    pub output: Option<Output>,
}

impl Invocation {
    pub fn new(
        executable: &str,
        tag: &str,
        subcommand: &str,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let run_id = format!("t{}-{tag}", std::process::id());
        let out = std::env::temp_dir().join(format!("cqnet-tests/{run_id}"));
        let _ = std::fs::remove_dir_all(&out);
        let mut cmd = Command::new(executable);
        cmd.arg(subcommand).arg("--out").arg(&out);
        if subcommand == "run" {
            cmd.arg("--run-id").arg(&run_id);
        }
        cmd.args(args);
        for (k, v) in env {
            cmd.env(k, v);
        }
        let child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run the program");
        let mut me = Self {
            run_id,
            out,
            output: None,
        };
        me.output = Some(wait_bounded(child, &me.run_id));
        me
    }

    /// Like [`new`](Self::new), but once the run has written rows up to
    /// step `at_step` of `ticks.csv` (polled every 2 ms, so the signal lands
    /// early in the next step; or after 60 s), `kill -<signal>` goes
    /// to the launcher, or to the actor named by `target` (`node-4`); then
    /// the program is waited for.
    pub fn signalled(
        executable: &str,
        tag: &str,
        subcommand: &str,
        args: &[&str],
        signal: &str,
        target: Option<&str>,
        at_step: u32,
    ) -> Self {
        let run_id = format!("t{}-{tag}", std::process::id());
        let out = std::env::temp_dir().join(format!("cqnet-tests/{run_id}"));
        let _ = std::fs::remove_dir_all(&out);
        let mut me = Self {
            run_id: run_id.clone(),
            out: out.clone(),
            output: None,
        };
        let child = Command::new(executable)
            .arg(subcommand)
            .arg("--out")
            .arg(&out)
            .arg("--run-id")
            .arg(&run_id)
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run the program");
        let ticks = out.join("ticks.csv");
        let start = std::time::Instant::now();
        while start.elapsed() < std::time::Duration::from_secs(60) {
            let reached = std::fs::read_to_string(&ticks).is_ok_and(|t| {
                t.lines()
                    .skip(1)
                    .filter_map(|l| l.split(',').next()?.parse::<u32>().ok())
                    .any(|s| s >= at_step)
            });
            if reached {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        let pids = match target {
            None => vec![child.id()],
            Some(actor) => processes_with(&format!("{run_id} --actor {actor} ")),
        };
        for pid in pids {
            let _ = Command::new("kill")
                .arg(format!("-{signal}"))
                .arg(pid.to_string())
                .status();
        }
        me.output = Some(wait_bounded(child, &run_id));
        me
    }

    pub fn output(&self) -> &Output {
        self.output.as_ref().expect("ran")
    }

    pub fn stderr(&self) -> String {
        String::from_utf8_lossy(&self.output().stderr).into_owned()
    }

    /// Panics with the program's stderr unless it exited successfully.
    pub fn assert_success(&self) -> &Self {
        assert!(
            self.output().status.success(),
            "{} failed: {}\n{}",
            self.run_id,
            self.output().status,
            self.stderr()
        );
        self
    }

    pub fn summary(&self) -> serde_json::Value {
        serde_json::from_str(
            &std::fs::read_to_string(self.out.join("summary.json")).expect("summary.json"),
        )
        .expect("valid JSON")
    }

    pub fn ticks(&self) -> Vec<Tick> {
        read_ticks(&self.out.join("ticks.csv"))
    }

    pub fn links(&self) -> Accounting {
        Accounting::from_csv(
            &std::fs::read_to_string(self.out.join("links.csv")).expect("links.csv"),
        )
        .expect("valid links.csv")
    }

    /// Processes still running with this run's id on their command line.
    pub fn leftover_processes(&self) -> Vec<u32> {
        processes_with(&self.run_id)
    }

    /// Files of this run's iceoryx2 resources that still exist.
    pub fn leftover_shared_memory(&self) -> Vec<PathBuf> {
        RunId::new(&self.run_id)
            .map(|r| run_resources(&r))
            .unwrap_or_default()
    }
}

impl Drop for Invocation {
    fn drop(&mut self) {
        for pid in processes_with(&self.run_id) {
            let _ = Command::new("kill").arg("-9").arg(pid.to_string()).status();
        }
        if let Ok(r) = RunId::new(&self.run_id) {
            let _ = remove_run_resources(&r);
        }
    }
}

/// The longest any one invocation may take. A run that hangs fails its
/// test after this long instead of holding CI until its limit; the
/// invocation's drop then kills what is left of it.
pub const INVOCATION_LIMIT: Duration = Duration::from_secs(300);

/// Waits for `child` and collects its output, killing it and panicking if it
/// outlives [`INVOCATION_LIMIT`].
fn wait_bounded(mut child: Child, run_id: &str) -> Output {
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut pipe) = pipe {
                let _ = pipe.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let stdout = drain(child.stdout.take().map(|p| Box::new(p) as _));
    let stderr = drain(child.stderr.take().map(|p| Box::new(p) as _));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("poll the program") {
            break status;
        }
        if start.elapsed() > INVOCATION_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{run_id} did not finish within {INVOCATION_LIMIT:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output {
        status,
        stdout: stdout.join().unwrap_or_default(),
        stderr: stderr.join().unwrap_or_default(),
    }
}

fn processes_with(needle: &str) -> Vec<u32> {
    let mut pids = Vec::new();
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return pids;
    };
    for e in entries.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        if pid == std::process::id() {
            continue;
        }
        if let Ok(cmdline) = std::fs::read(e.path().join("cmdline")) {
            let cmdline = String::from_utf8_lossy(&cmdline).replace('\0', " ");
            if cmdline.contains(needle) {
                pids.push(pid);
            }
        }
    }
    pids
}

/// A row of `ticks.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct Tick {
    pub step: u32,
    pub node: String,
    pub error: f64,
    pub bound: Option<f64>,
    pub line: String,
}

pub fn read_ticks(path: &Path) -> Vec<Tick> {
    let text = std::fs::read_to_string(path).expect("ticks.csv");
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Tick {
                step: f[0].parse().unwrap(),
                node: f[1].to_string(),
                error: f[6].parse().unwrap(),
                bound: f[7].parse().ok(),
                line: l.to_string(),
            }
        })
        .collect()
}

/// Position RMSE of the nodes' rows (not the centralized reference) over `steps`.
pub fn rmse(ticks: &[Tick], steps: std::ops::RangeInclusive<u32>) -> f64 {
    let e: Vec<f64> = ticks
        .iter()
        .filter(|t| t.node != "central" && steps.contains(&t.step))
        .map(|t| t.error * t.error)
        .collect();
    (e.iter().sum::<f64>() / e.len() as f64).sqrt()
}
