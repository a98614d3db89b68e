//! What a run leaves that a test must not: its processes and its shared
//! memory, found by the run's id and removed, pass or fail.

use std::process::Command;

use fusion_graph::RunId;
use transport::iceoryx::remove_run_resources;

/// Kills whatever process still carries the run id and removes the run's
/// shared memory.
pub(crate) fn kill_and_clean(run_id: &RunId) {
    for pid in processes_with(run_id.as_str()) {
        let _ = Command::new("kill").arg("-9").arg(pid.to_string()).status();
    }
    let _ = remove_run_resources(run_id);
}

/// Processes whose command line carries run id `run_id` (as `--run-id
/// <id>`, so that run `x-1` is not mistaken for `x-10`).
pub(crate) fn processes_with(run_id: &str) -> Vec<u32> {
    processes_matching(&format!("--run-id {run_id} "))
}

/// Processes whose command line contains `needle`.
pub(crate) fn processes_matching(needle: &str) -> Vec<u32> {
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
