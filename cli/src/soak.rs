//! `cqnet soak`: a long real-time run with periodic kills and restarts,
//! sampling what would betray a leak: the resident memory of the launcher
//! and every child, their open file descriptors, and the run's entries in
//! /dev/shm and iceoryx2's folder. All three must stay flat.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use fusion_graph::faults::{Fault, Kill, Signal};
use fusion_graph::scenario::Scenario;
use fusion_graph::RunId;
use fusion_graph::Topology;
use transport::iceoryx::run_resources;

/// One sample of the run's footprint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub seconds: f64,
    pub step: u32,
    pub processes: usize,
    pub rss_kb: u64,
    /// The part of `rss_kb` that is the processes' own (heap, stacks:
    /// `RssAnon`). The rest is mapped files and shared memory, which grows
    /// as pages of segments sized at start are first touched, up to their
    /// size, and is counted once per process that maps them.
    pub private_kb: u64,
    /// The launcher's own `RssAnon`.
    pub launcher_private_kb: u64,
    pub fds: usize,
    pub shm_entries: usize,
}

/// Adds, every `every` steps, a SIGKILL of the next node (restarted
/// `down` steps later) and of a sensor (restarted too), round-robin.
pub fn add_periodic_kills(scenario: &mut Scenario, topology: &Topology, every: u32, down: u32) {
    let mut at = every;
    let mut k = 0usize;
    while at + down < scenario.steps {
        for actor in [
            format!("node-{}", k % topology.nodes()),
            format!("sensor-{}", (k * 37) % topology.sensors()),
        ] {
            scenario.faults.push(Fault::Kill(Kill {
                actor,
                at_step: at,
                signal: Signal::Kill,
                restart_after: Some(down),
            }));
        }
        at += every;
        k += 1;
    }
}

/// Samples the footprint of the launcher (this process) and its children
/// every `period` until stopped; the samples go to `out/soak.csv` as well.
pub struct Sampler {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Vec<Sample>>>,
}

impl Sampler {
    pub fn start(run: RunId, step: Arc<AtomicU32>, period: Duration) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::Builder::new()
            .name("soak-sampler".into())
            .spawn(move || {
                let started = Instant::now();
                let mut samples = Vec::new();
                while !stopping.load(Ordering::Relaxed) {
                    samples.push(sample(&run, step.load(Ordering::Relaxed), started));
                    let until = Instant::now() + period;
                    while Instant::now() < until && !stopping.load(Ordering::Relaxed) {
                        std::thread::sleep(Duration::from_millis(50));
                    }
                }
                samples
            })
            .expect("starting the sampler");
        Self {
            stop,
            thread: Some(thread),
        }
    }

    pub fn finish(mut self) -> Vec<Sample> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default()
    }
}

fn sample(run: &RunId, step: u32, started: Instant) -> Sample {
    let me = std::process::id();
    let mut pids = vec![me];
    pids.extend(children_of(me));
    let footprints: Vec<Memory> = pids.iter().filter_map(|p| memory(*p)).collect();
    Sample {
        seconds: started.elapsed().as_secs_f64(),
        step,
        processes: pids.len(),
        rss_kb: footprints.iter().map(|m| m.rss_kb).sum(),
        private_kb: footprints.iter().map(|m| m.private_kb).sum(),
        launcher_private_kb: memory(me).map_or(0, |m| m.private_kb),
        fds: pids.iter().filter_map(|p| open_fds(*p)).sum(),
        shm_entries: run_resources(run).len(),
    }
}

/// Every process whose parent is `pid`.
fn children_of(pid: u32) -> Vec<u32> {
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    entries
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|p| parent_of(*p) == Some(pid))
        .collect()
}

fn parent_of(pid: u32) -> Option<u32> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    stat[stat.rfind(')')? + 2..]
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

struct Memory {
    rss_kb: u64,
    private_kb: u64,
}

fn memory(pid: u32) -> Option<Memory> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| -> Option<u64> {
        let line = status.lines().find(|l| l.starts_with(name))?;
        line.split_whitespace().nth(1)?.parse().ok()
    };
    Some(Memory {
        rss_kb: field("VmRSS:")?,
        private_kb: field("RssAnon:")?,
    })
}

fn open_fds(pid: u32) -> Option<usize> {
    Some(std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count())
}

/// `soak.csv`, one row per sample.
pub fn write_samples(path: &Path, samples: &[Sample]) -> anyhow::Result<()> {
    let mut text = String::from(
        "seconds,step,processes,rss_kb,private_kb,launcher_private_kb,fds,shm_entries\n",
    );
    for s in samples {
        text.push_str(&format!(
            "{:.1},{},{},{},{},{},{},{}\n",
            s.seconds,
            s.step,
            s.processes,
            s.rss_kb,
            s.private_kb,
            s.launcher_private_kb,
            s.fds,
            s.shm_entries
        ));
    }
    launch::results::write_atomically(path, text.as_bytes())
}

/// How one figure moved over the run: the mean of the samples in the
/// second tenth of the steps (after start-up) against the last tenth, and
/// the least-squares slope per 1000 steps over everything in between.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trend {
    pub early: f64,
    pub late: f64,
    pub per_1000_steps: f64,
}

pub fn trend(samples: &[Sample], steps: u32, f: impl Fn(&Sample) -> f64) -> Option<Trend> {
    let window = |lo: f64, hi: f64| -> Vec<&Sample> {
        samples
            .iter()
            .filter(|s| {
                let x = s.step as f64 / steps as f64;
                x >= lo && x < hi
            })
            .collect()
    };
    let mean = |v: &[&Sample]| v.iter().map(|s| f(s)).sum::<f64>() / v.len() as f64;
    // The last step's samples are left out: they include the shutdown,
    // when processes and their shared memory go away.
    let (early, late, body) = (window(0.1, 0.2), window(0.9, 1.0), window(0.1, 1.0));
    if early.is_empty() || late.is_empty() || body.len() < 2 {
        return None;
    }
    let (mx, my) = (
        body.iter().map(|s| s.step as f64).sum::<f64>() / body.len() as f64,
        mean(&body),
    );
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for s in &body {
        sxy += (s.step as f64 - mx) * (f(s) - my);
        sxx += (s.step as f64 - mx).powi(2);
    }
    Some(Trend {
        early: mean(&early),
        late: mean(&late),
        per_1000_steps: if sxx > 0.0 { 1000.0 * sxy / sxx } else { 0.0 },
    })
}

/// Where `cqnet soak` writes.
pub fn samples_path(out: &Path) -> PathBuf {
    out.join("soak.csv")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(step: u32, rss: u64) -> Sample {
        Sample {
            seconds: step as f64,
            step,
            processes: 1,
            rss_kb: rss,
            private_kb: rss,
            launcher_private_kb: rss,
            fds: 3,
            shm_entries: 0,
        }
    }

    #[test]
    fn a_flat_series_has_no_slope_and_a_leak_has_its_own() {
        let flat: Vec<Sample> = (0..=100).map(|i| s(i * 10, 5000)).collect();
        let t = trend(&flat, 1000, |s| s.rss_kb as f64).unwrap();
        assert_eq!((t.early, t.late, t.per_1000_steps), (5000.0, 5000.0, 0.0));
        // 2 kB more every 10 steps: 200 kB per 1000 steps.
        let leak: Vec<Sample> = (0..=100).map(|i| s(i * 10, 5000 + 2 * i as u64)).collect();
        let t = trend(&leak, 1000, |s| s.rss_kb as f64).unwrap();
        assert!((t.per_1000_steps - 200.0).abs() < 1e-9, "{t:?}");
        assert!(t.late > t.early);
    }

    #[test]
    fn this_process_is_sampled() {
        let run = RunId::new("soak-unit").unwrap();
        let x = sample(&run, 0, Instant::now());
        assert!(x.processes >= 1 && x.rss_kb > 0 && x.fds >= 3, "{x:?}");
        assert!(x.private_kb > 0 && x.private_kb <= x.rss_kb, "{x:?}");
    }

    #[test]
    fn kills_come_round_robin_and_each_restarts_before_the_end() {
        let mut scenario = Scenario::default_scenario();
        scenario.steps = 100;
        let t = Topology::from_scenario(&scenario, "d").unwrap();
        add_periodic_kills(&mut scenario, &t, 20, 5);
        let kills: Vec<(String, u32)> = scenario
            .faults
            .iter()
            .map(|f| match f {
                Fault::Kill(k) => (k.actor.clone(), k.at_step),
                _ => unreachable!(),
            })
            .collect();
        assert_eq!(kills.len(), 8, "{kills:?}");
        assert_eq!(kills[0], ("node-0".into(), 20));
        assert_eq!(kills[2], ("node-1".into(), 40));
        assert!(Topology::from_scenario(&scenario, "d").is_ok());
    }
}
