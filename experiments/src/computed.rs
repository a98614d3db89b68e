//! Experiments computed from a paper's formulas rather than run on a
//! network: their catalogue and their runner.

use std::path::PathBuf;

use anyhow::Context;

use launch::results::write_atomically;

use crate::claims::{claims_csv, Check};
use crate::runner::Options;
use crate::{
    allocation, bit_depth, censoring, compressive_sweep, consensus_at_scale, location,
    random_exchange_bounds, random_exchange_trackers, ungm,
};

/// An experiment computed from a paper's formulas rather than run on a
/// network: a table reproduced beside the paper's, with its CSV and SVG.
pub struct Computed {
    pub name: &'static str,
    pub source: &'static str,
    pub about: &'static str,
    /// Computes the tables and writes the CSV and SVG into the folder.
    pub run: fn(&Options, &std::path::Path) -> anyhow::Result<ComputedReport>,
}

/// What a computed experiment wrote, and its tables as printed text.
pub struct ComputedReport {
    pub check: Check,
    pub csv: PathBuf,
    pub svg: PathBuf,
    /// Ours beside the paper's, for the terminal and `tables.txt`.
    pub table: String,
}

impl ComputedReport {
    /// Writes `<dir>/<name>.csv` and draws `<dir>/<name>.svg`: how every
    /// computed experiment ends.
    pub fn write(
        dir: &std::path::Path,
        name: &str,
        csv: &str,
        draw: impl FnOnce(&std::path::Path) -> Result<(), Box<dyn std::error::Error>>,
        check: Check,
        table: String,
    ) -> anyhow::Result<Self> {
        let csv_path = dir.join(format!("{name}.csv"));
        let svg = dir.join(format!("{name}.svg"));
        write_atomically(&csv_path, csv.as_bytes())?;
        draw(&svg)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("drawing {}", svg.display()))?;
        Ok(Self {
            check,
            csv: csv_path,
            svg,
            table,
        })
    }
}

/// Every computed experiment.
pub fn computed_catalogue() -> Vec<Computed> {
    let mut all = allocation::experiments();
    all.extend(censoring::experiments());
    all.extend(bit_depth::experiments());
    all.extend(random_exchange_bounds::experiments());
    all.extend(random_exchange_trackers::experiments());
    all.extend(location::experiments());
    all.extend(ungm::experiments());
    all.extend(consensus_at_scale::experiments());
    all.extend(compressive_sweep::experiments());
    all
}

/// Runs a computed experiment into `<out>/<name>/`, with `tables.txt` and
/// `check.txt` beside its CSV and SVG.
pub fn run_computed(computed: &Computed, options: &Options) -> anyhow::Result<ComputedReport> {
    let dir = options.out.join(computed.name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let report = (computed.run)(options, &dir)?;
    write_atomically(&dir.join("tables.txt"), report.table.as_bytes())?;
    write_atomically(
        &dir.join("check.txt"),
        format!("{}\n", computed_verdict_line(computed, &report.check)).as_bytes(),
    )?;
    write_atomically(
        &dir.join("claims.csv"),
        claims_csv(&report.check).as_bytes(),
    )?;
    Ok(report)
}

/// "holds: …" or "does not hold: …" for a computed experiment.
pub fn computed_verdict_line(computed: &Computed, check: &Check) -> String {
    format!(
        "{} ({}): {}: {}",
        computed.name,
        computed.source,
        check.verdict.words(),
        check.statement
    )
}
