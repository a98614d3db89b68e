//! What this process and its reaped children have used of the machine:
//! memory and CPU time, read from the kernel.

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

/// CPU time this process has used, user and system, in seconds (its own
/// threads, not its children).
pub fn own_cpu_seconds() -> Option<f64> {
    use nix::sys::resource::{getrusage, UsageWho};
    let u = getrusage(UsageWho::RUSAGE_SELF).ok()?;
    let seconds = |t: nix::sys::time::TimeVal| t.tv_sec() as f64 + t.tv_usec() as f64 / 1e6;
    Some(seconds(u.user_time()) + seconds(u.system_time()))
}

/// CPU time the children this process has reaped used, user and system,
/// in seconds.
pub fn children_cpu_seconds() -> Option<f64> {
    use nix::sys::resource::{getrusage, UsageWho};
    let u = getrusage(UsageWho::RUSAGE_CHILDREN).ok()?;
    let seconds = |t: nix::sys::time::TimeVal| t.tv_sec() as f64 + t.tv_usec() as f64 / 1e6;
    Some(seconds(u.user_time()) + seconds(u.system_time()))
}
