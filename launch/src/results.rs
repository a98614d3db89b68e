//! Result files, written row by row as a run goes so that a crash loses
//! nothing already written: `ticks.csv`, `links.csv`, `summary.json`.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::Context;
use fusion_graph::accounting::Accounting;
use fusion_graph::wire::{MessageKind, Telemetry};
use serde::Serialize;

/// Steps before this are left out of the averages (the filters' transient).
pub const AVERAGE_FROM_STEP: u32 = 10;

/// One row of `ticks.csv`: a node's (or the centralized reference's) step.
#[derive(Debug, Clone, PartialEq)]
pub struct TickRow {
    pub step: u32,
    /// `node-<i>` or `central`.
    pub node: String,
    pub truth: [f64; 4],
    pub telemetry: Telemetry,
}

impl TickRow {
    pub fn error(&self) -> f64 {
        (self.telemetry.estimate[0] - self.truth[0])
            .hypot(self.telemetry.estimate[1] - self.truth[1])
    }
}

const TICKS_HEADER: &str = "step,node,true_x,true_y,est_x,est_y,error,bound,local_bound,aux_bound,rounds,live_neighbours,observations,deadline_missed\n";

pub struct ResultsWriter {
    dir: PathBuf,
    ticks: BufWriter<File>,
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x}"))
}

impl ResultsWriter {
    pub fn create(dir: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating the output folder {}", dir.display()))?;
        let path = dir.join("ticks.csv");
        let mut ticks = BufWriter::new(
            File::create(&path).with_context(|| format!("creating {}", path.display()))?,
        );
        ticks.write_all(TICKS_HEADER.as_bytes())?;
        Ok(Self {
            dir: dir.to_path_buf(),
            ticks,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Appends rows and flushes them to disk.
    pub fn write_ticks(&mut self, rows: &[TickRow]) -> anyhow::Result<()> {
        for r in rows {
            let t = &r.telemetry;
            writeln!(
                self.ticks,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                r.step,
                r.node,
                r.truth[0],
                r.truth[1],
                t.estimate[0],
                t.estimate[1],
                r.error(),
                opt(t.bound),
                opt(t.local_bound),
                opt(t.aux_bound),
                t.rounds_completed,
                t.live_neighbours,
                t.observations,
                t.deadline_missed as u8
            )?;
        }
        self.ticks.flush()?;
        Ok(())
    }

    pub fn write_links(&self, accounting: &Accounting) -> anyhow::Result<()> {
        write_atomically(&self.dir.join("links.csv"), accounting.to_csv().as_bytes())
    }

    pub fn write_summary<S: Serialize>(&self, summary: &S) -> anyhow::Result<()> {
        write_atomically(
            &self.dir.join("summary.json"),
            serde_json::to_string_pretty(summary)?.as_bytes(),
        )
    }
}

/// Writes through a temporary file and a rename, so a reader never sees half a file.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(())
}

/// Running sums for the summary's averages.
#[derive(Debug, Clone, Default)]
pub struct Averages {
    sq_error: f64,
    errors: u64,
    bound: (f64, u64),
    local_bound: (f64, u64),
    aux_bound: (f64, u64),
    central_sq_error: f64,
    central_errors: u64,
    central_bound: (f64, u64),
    pub deadline_misses: u64,
    pub rows: u64,
}

fn add(acc: &mut (f64, u64), v: Option<f64>) {
    if let Some(v) = v {
        acc.0 += v;
        acc.1 += 1;
    }
}

fn mean(acc: (f64, u64)) -> Option<f64> {
    (acc.1 > 0).then(|| acc.0 / acc.1 as f64)
}

impl Averages {
    pub fn add(&mut self, r: &TickRow) {
        self.rows += 1;
        self.deadline_misses += r.telemetry.deadline_missed as u64;
        if r.step < AVERAGE_FROM_STEP {
            return;
        }
        let e2 = r.error().powi(2);
        if r.node == "central" {
            self.central_sq_error += e2;
            self.central_errors += 1;
            add(&mut self.central_bound, r.telemetry.bound);
        } else {
            self.sq_error += e2;
            self.errors += 1;
            add(&mut self.bound, r.telemetry.bound);
            add(&mut self.local_bound, r.telemetry.local_bound);
            add(&mut self.aux_bound, r.telemetry.aux_bound);
        }
    }

    pub fn estimates(&self) -> Estimates {
        Estimates {
            from_step: AVERAGE_FROM_STEP,
            rmse: (self.errors > 0).then(|| (self.sq_error / self.errors as f64).sqrt()),
            mean_bound: mean(self.bound),
            mean_local_bound: mean(self.local_bound),
            mean_aux_bound: mean(self.aux_bound),
            centralized_rmse: (self.central_errors > 0)
                .then(|| (self.central_sq_error / self.central_errors as f64).sqrt()),
            mean_centralized_bound: mean(self.central_bound),
        }
    }
}

/// Accuracy figures, averaged over nodes and steps from `from_step` on.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Estimates {
    pub from_step: u32,
    /// Position RMSE of the nodes' fused estimates, metres.
    pub rmse: Option<f64>,
    /// Mean CQ/dPCRLB position bound, metres.
    pub mean_bound: Option<f64>,
    pub mean_local_bound: Option<f64>,
    /// Mean auxiliary-FIM baseline bound, when it ran.
    pub mean_aux_bound: Option<f64>,
    pub centralized_rmse: Option<f64>,
    pub mean_centralized_bound: Option<f64>,
}

/// Bytes sent per message kind, in total and per step.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Traffic {
    pub kind: String,
    pub messages: u64,
    pub bytes: u64,
    pub bytes_per_step: f64,
    pub dropped_messages: u64,
    pub malformed_messages: u64,
    /// Sent but neither received, dropped by an injected fault nor rejected as
    /// malformed: lost to a full subscriber queue or to a receiver that died
    /// (whose counts since its last flush are gone with it).
    pub unaccounted_messages: i64,
}

/// Bytes of bound information carried by consensus: ΔL (10 numbers) per
/// consensus message for CQ/dPCRLB; the auxiliary-FIM baseline needs S_obs
/// (10 more) per round as well.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct BoundTraffic {
    pub cq_dpcrlb_bytes: u64,
    pub auxiliary_fim_bytes: Option<u64>,
}

pub fn traffic(accounting: &Accounting, steps: u32) -> (Vec<Traffic>, BoundTraffic) {
    let kinds = accounting.by_kind();
    let rows = kinds
        .iter()
        .map(|(k, c)| Traffic {
            kind: k.name().into(),
            messages: c.sent_messages,
            bytes: c.sent_bytes,
            bytes_per_step: c.sent_bytes as f64 / steps.max(1) as f64,
            dropped_messages: c.dropped_messages,
            malformed_messages: c.malformed_messages,
            unaccounted_messages: c.sent_messages as i64
                - (c.received_messages + c.dropped_messages) as i64,
        })
        .collect();
    let consensus = kinds
        .get(&MessageKind::Consensus)
        .map_or(0, |c| c.sent_messages);
    let aux = kinds
        .get(&MessageKind::ConsensusAux)
        .map(|c| c.sent_messages);
    let bound = BoundTraffic {
        cq_dpcrlb_bytes: consensus * 80,
        auxiliary_fim_bytes: aux.map(|a| consensus * 80 + a * 80),
    };
    (rows, bound)
}

/// Proportional set size of this process now, kilobytes (Linux
/// `smaps_rollup`): shared pages divided among the processes sharing them,
/// so that summing it over processes gives their joint footprint.
pub fn proportional_memory_kb() -> Option<u64> {
    let rollup = std::fs::read_to_string("/proc/self/smaps_rollup").ok()?;
    rollup
        .lines()
        .find(|l| l.starts_with("Pss:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

/// Peak resident memory of this process, kilobytes (Linux `VmHWM`).
pub fn peak_memory_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}
