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
    Usage::own().map(|u| u.cpu_seconds())
}

/// CPU time the children this process has reaped used, user and system,
/// in seconds.
pub fn children_cpu_seconds() -> Option<f64> {
    Usage::of(nix::sys::resource::UsageWho::RUSAGE_CHILDREN).map(|u| u.cpu_seconds())
}

/// CPU time and context switches of this process so far (`getrusage`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Usage {
    pub user: std::time::Duration,
    pub system: std::time::Duration,
    /// Switches away because the process waited (a sleep, a blocking call).
    pub voluntary_switches: u64,
    /// Switches away while it could have run on: preempted, or yielded.
    pub involuntary_switches: u64,
}

impl Usage {
    /// This process's, so far.
    pub fn own() -> Option<Self> {
        Self::of(nix::sys::resource::UsageWho::RUSAGE_SELF)
    }

    /// `getrusage(who)`.
    fn of(who: nix::sys::resource::UsageWho) -> Option<Self> {
        let u = nix::sys::resource::getrusage(who).ok()?;
        let time = |t: nix::sys::time::TimeVal| {
            std::time::Duration::new(t.tv_sec().max(0) as u64, t.tv_usec().max(0) as u32 * 1000)
        };
        Some(Self {
            user: time(u.user_time()),
            system: time(u.system_time()),
            voluntary_switches: u.voluntary_context_switches().max(0) as u64,
            involuntary_switches: u.involuntary_context_switches().max(0) as u64,
        })
    }

    /// User and system CPU, in seconds.
    pub fn cpu_seconds(&self) -> f64 {
        (self.user + self.system).as_secs_f64()
    }

    /// What was used between `earlier` and `self`.
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            user: self.user.saturating_sub(earlier.user),
            system: self.system.saturating_sub(earlier.system),
            voluntary_switches: self
                .voluntary_switches
                .saturating_sub(earlier.voluntary_switches),
            involuntary_switches: self
                .involuntary_switches
                .saturating_sub(earlier.involuntary_switches),
        }
    }
}
