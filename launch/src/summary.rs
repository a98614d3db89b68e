//! `summary.json`: what a run was, what it measured and what it cost.

use serde::{Deserialize, Serialize};

use fusion_graph::scenario::{Fault, Scenario};

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct AppliedFault {
    pub step: u32,
    pub until_step: Option<u32>,
    pub fault: String,
    /// What it did to tracking: the nodes' position RMSE, metres, over the
    /// [`BEFORE_STEPS`] steps before it, while it held, and from its end on.
    #[serde(default)]
    pub rmse_before: Option<f64>,
    #[serde(default)]
    pub rmse_during: Option<f64>,
    #[serde(default)]
    pub rmse_after: Option<f64>,
    /// Steps from its end until the step's RMSE is back within
    /// [`RECOVERY_FACTOR`] of `rmse_before` for [`RECOVERY_HOLD`] steps
    /// running; `None` if it never ends or never recovers.
    #[serde(default)]
    pub recovered_after: Option<u32>,
}

/// The window before a fault its RMSE is compared with.
pub const BEFORE_STEPS: u32 = 10;
/// Recovered: within this factor of the reference RMSE…
pub const RECOVERY_FACTOR: f64 = 2.0;
/// …for this many steps running.
pub const RECOVERY_HOLD: u32 = 3;

impl AppliedFault {
    /// A fault with no measurements yet.
    pub fn new(step: u32, until_step: Option<u32>, fault: String) -> Self {
        Self {
            step,
            until_step,
            fault,
            rmse_before: None,
            rmse_during: None,
            rmse_after: None,
            recovered_after: None,
        }
    }

    pub fn from_fault(f: &Fault) -> Self {
        Self::new(f.at_step(), f.end_step(), f.kind().describe())
    }

    /// Fills in the RMSE figures from the run's per-step means.
    pub fn measure(&mut self, means: &[StepMeans]) {
        let start = self.step;
        let end = self.until_step.unwrap_or(u32::MAX);
        self.rmse_before = window_rmse(means, start.saturating_sub(BEFORE_STEPS), start);
        self.rmse_during = window_rmse(means, start, end);
        self.rmse_after = self
            .until_step
            .and_then(|e| window_rmse(means, e, u32::MAX));
        self.recovered_after = match (self.until_step, self.rmse_before) {
            (Some(e), Some(before)) => steps_to_recover(means, e, RECOVERY_HOLD, |_, rmse| {
                rmse <= RECOVERY_FACTOR * before
            }),
            _ => None,
        };
    }
}

/// What the faults cost, over the whole run.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct FaultCost {
    /// Messages dropped by injected loss and partitions.
    pub dropped_messages: u64,
    /// Messages that arrived after their round or step had passed.
    pub late_messages: u64,
    /// Node-steps whose last round heard fewer neighbours than the fusion
    /// protocol expected (every neighbour, for average consensus).
    pub rounds_with_fewer_neighbours: u64,
    /// Node-steps with no telemetry (dead, stopped or too late).
    pub missing_node_steps: u64,
    /// Extra copies made by `duplicate` faults.
    #[serde(default)]
    pub duplicated_messages: u64,
    /// Messages of a known kind that failed their checksum (`corrupt` faults).
    #[serde(default)]
    pub corrupted_messages: u64,
    /// Observations the nodes' innovation gate left out (`filter.gate`).
    #[serde(default)]
    pub gated_observations: u64,
    /// Observations that missed their step's listening window and were
    /// weighed a step late, at the time they were taken (slow links).
    #[serde(default)]
    pub lagged_observations: u64,
    /// Node-steps a negotiated sensor selection's choice did not reach, so
    /// that the node activated none of its sensors (its root lost, or the
    /// step's deadline first).
    #[serde(default)]
    pub node_steps_without_choice: u64,
    /// Consensus rounds that ended at their deadline without a
    /// neighbour's value they awaited (a slow or lost neighbour), and the
    /// node-steps they were in: results then depend on timing.
    #[serde(default)]
    pub short_rounds: u64,
    #[serde(default)]
    pub node_steps_with_short_rounds: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Summary {
    pub command: String,
    pub run_id: String,
    pub scenario: Scenario,
    pub steps: u32,
    pub estimates: Estimates,
    pub traffic: Vec<Traffic>,
    pub bound_traffic: BoundTraffic,
    /// On a multiple-access channel: the sensors' transmissions, one unit
    /// of energy each. None without a channel.
    #[serde(default)]
    pub energy: Option<Energy>,
    pub deadline_misses: u64,
    /// Activations a sensor could not answer because the world's memory
    /// did not hold their step (not written yet, or no longer held): each
    /// is an observation missing, never a stale one.
    #[serde(default)]
    pub world_misses: u64,
    pub faults: Vec<AppliedFault>,
    pub fault_cost: FaultCost,
    /// What can make this run's results depend on when messages arrive,
    /// so that `run --lockstep` need not reproduce `sim` bit for bit: a
    /// wait that can end by the clock (a message lost on purpose, an actor
    /// killed, a host cut off, or the real-time clock itself). Empty: a
    /// lockstep run of this scenario is `sim`'s to the bit.
    #[serde(default)]
    pub timing_dependent: Vec<String>,
    /// How far consensus got, step by step; `None` if no node's protocol
    /// measures it.
    #[serde(default)]
    pub disagreement: Option<Disagreement>,
    pub wall_seconds: f64,
    pub steps_per_second: f64,
    /// Mean microseconds per node-step: local filter (with local bound),
    /// fusion filter (with global bound), the whole consensus (round 1
    /// included, which waits for the slowest neighbour's local filter).
    pub stage_micros: StageTimes,
    /// Latency of one consensus round once every neighbour is exchanging
    /// (rounds 2..N_c of each node-step), percentiles over node-steps
    /// (multi-process runs).
    pub round_latency_micros: Option<Percentiles>,
    pub processes: usize,
    /// `run`: seconds from the launcher's start to every actor's `ready`.
    #[serde(default)]
    pub startup_seconds: Option<f64>,
    /// Peak resident memory of the launcher (or the one `sim` process), kB.
    pub peak_memory_kb: Option<u64>,
    /// CPU seconds of the launcher (or the one `sim` process) itself.
    #[serde(default)]
    pub cpu_seconds: Option<f64>,
    /// `run`: the children's memory, kB.
    pub children_memory_kb: Option<ChildrenMemory>,
    /// `run`: the children's CPU time and context switches from their
    /// `ready` to the Stop (start-up left out).
    #[serde(default)]
    pub children_cpu: Option<ChildrenCpu>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct StageTimes {
    pub local_filter: f64,
    pub fusion_filter: f64,
    pub consensus: f64,
    /// From `BeginStep` to the activation: the PCRLB selection's gather and
    /// choice, and its scoring when it ran in the step (zero for managers
    /// that choose alone).
    #[serde(default)]
    pub selection: f64,
    /// The selection's scoring, wherever it ran: a node scores the next
    /// step's candidates once it has reported a step, and only scores in
    /// the step when it could not (the step before overran, or it missed
    /// steps).
    #[serde(default)]
    pub scoring: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ChildrenMemory {
    /// The largest peak resident set of one child.
    pub largest_peak_rss: u64,
    /// The children's proportional set sizes, summed: their joint footprint
    /// (shared pages counted once), as of each child's last flush.
    pub total_pss: u64,
}

/// What a run's children spent from their `ready` to the Stop, summed over
/// those that reported it (an actor killed on the way does not).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ChildrenCpu {
    /// How many children reported.
    pub actors: usize,
    pub user_seconds: f64,
    /// In the kernel, on the children's behalf.
    pub system_seconds: f64,
    /// Switches away to wait (a sleep).
    pub voluntary_switches: u64,
    /// Switches away while runnable (preempted, or yielded).
    pub involuntary_switches: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Percentiles {
    pub p50: f64,
    pub p99: f64,
}

impl Percentiles {
    pub fn of(values: &mut [f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        values.sort_by(f64::total_cmp);
        let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
        Some(Self {
            p50: at(0.5),
            p99: at(0.99),
        })
    }
}

/// Round latencies in fixed memory, however long the run: every whole
/// microsecond below `LatencyHistogram::EXACT` has its own bucket, and
/// each octave above it `LatencyHistogram::PER_OCTAVE` buckets, so a
/// percentile is off by under 1.6 %. A list of every round grew by 72 bytes
/// a step, which the soak counts as a leak.
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    counts: Vec<u64>,
    n: u64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            counts: vec![0; Self::EXACT as usize + Self::OCTAVES * Self::PER_OCTAVE],
            n: 0,
        }
    }
}

impl LatencyHistogram {
    const EXACT: u64 = 1024;
    const PER_OCTAVE: usize = 64;
    /// From 2¹⁰ µs to 2⁴² µs (about 50 days): anything longer is counted there.
    const OCTAVES: usize = 32;

    pub fn add(&mut self, micros: f64) {
        let i = Self::bucket(micros).min(self.counts.len() - 1);
        self.counts[i] += 1;
        self.n += 1;
    }

    fn bucket(micros: f64) -> usize {
        let v = micros.max(0.0) as u64;
        if v < Self::EXACT {
            return v as usize;
        }
        let octave = (63 - v.leading_zeros()) as usize - Self::EXACT.trailing_zeros() as usize;
        let shift = octave + Self::EXACT.trailing_zeros() as usize
            - Self::PER_OCTAVE.trailing_zeros() as usize;
        let within = ((v >> shift) as usize) - Self::PER_OCTAVE;
        Self::EXACT as usize + octave * Self::PER_OCTAVE + within
    }

    /// The middle of bucket `i`'s range.
    fn value(i: usize) -> f64 {
        if i < Self::EXACT as usize {
            return i as f64;
        }
        let octave = (i - Self::EXACT as usize) / Self::PER_OCTAVE;
        let within = (i - Self::EXACT as usize) % Self::PER_OCTAVE;
        let width = (Self::EXACT << octave) as f64 / Self::PER_OCTAVE as f64;
        (Self::EXACT << octave) as f64 + (within as f64 + 0.5) * width
    }

    /// The nearest-rank p50 and p99, as [`Percentiles::of`] takes them.
    pub fn percentiles(&self) -> Option<Percentiles> {
        if self.n == 0 {
            return None;
        }
        let at = |q: f64| {
            let rank = ((self.n - 1) as f64 * q).round() as u64;
            let mut seen = 0;
            for (i, c) in self.counts.iter().enumerate() {
                seen += c;
                if seen > rank {
                    return Self::value(i);
                }
            }
            Self::value(self.counts.len() - 1)
        };
        Some(Percentiles {
            p50: at(0.5),
            p99: at(0.99),
        })
    }
}

/// Sums of stage times over node-steps, for [`StageTimes`].
#[derive(Debug, Clone, Default)]
pub struct StageSums {
    sums: [f64; 6],
    n: u64,
}

impl StageSums {
    pub fn add(&mut self, micros: [u32; 6]) {
        for (s, m) in self.sums.iter_mut().zip(micros) {
            *s += m as f64;
        }
        self.n += 1;
    }

    pub fn means(&self) -> StageTimes {
        let n = self.n.max(1) as f64;
        StageTimes {
            local_filter: self.sums[0] / n,
            fusion_filter: self.sums[1] / n,
            consensus: self.sums[3] / n,
            selection: self.sums[4] / n,
            scoring: self.sums[5] / n,
        }
    }
}

/// What the nodes' bound is called: the CQ/dPCRLB of a tracking network,
/// the CRLB of a static target's locator.
pub fn bound_name(scenario: &fusion_graph::Scenario) -> &'static str {
    if scenario.consensus.protocol == fusion_graph::scenario::ConsensusProtocol::ML_LOCATION {
        "CRLB"
    } else if scenario.channel.is_some() {
        "PCRLB given Φ"
    } else {
        "CQ/dPCRLB"
    }
}

/// A one-screen table of the summary for the terminal.
pub fn print_table(s: &Summary) {
    let m = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.3}"));
    let e = &s.estimates;
    println!(
        "cqnet {} — scenario `{}`, run {}, {} steps",
        s.command, s.scenario.name, s.run_id, s.steps
    );
    println!("  averages over steps {}..{}", e.from_step, s.steps);
    println!("  {:<34} {:>12}", "position RMSE (fused), m", m(e.rmse));
    let bound = format!("{} bound, m", bound_name(&s.scenario));
    println!("  {:<34} {:>12}", bound, m(e.mean_bound));
    println!("  {:<34} {:>12}", "local bound, m", m(e.mean_local_bound));
    let aux = if s.scenario.channel.is_some() {
        "bound eq. 4.19 promised, m"
    } else {
        "auxiliary-FIM baseline, m"
    };
    println!("  {:<34} {:>12}", aux, m(e.mean_aux_bound));
    println!(
        "  {:<34} {:>12}",
        "centralized RMSE, m",
        m(e.centralized_rmse)
    );
    println!(
        "  {:<34} {:>12}",
        "centralized bound, m",
        m(e.mean_centralized_bound)
    );
    // What the network sent: sensors see the target in the world's
    // memory, which is not traffic.
    println!("  bytes per step by kind (the truth sensors see is not a message):");
    for t in &s.traffic {
        println!("    {:<28} {:>12.1} B/step {:>10} msgs {:>8} dropped {:>6} malformed {:>6} unaccounted", t.kind, t.bytes_per_step, t.messages, t.dropped_messages, t.malformed_messages, t.unaccounted_messages);
    }
    if let Some(e) = &s.energy {
        println!(
            "  {:<34} {:>12.2}",
            "energy, transmissions per step", e.per_step
        );
    }
    println!("  {:<34} {:>12}", "deadline misses", s.deadline_misses);
    for why in &s.timing_dependent {
        println!("  results may depend on message timing (lockstep need not equal sim): {why}");
    }
    if s.world_misses > 0 {
        println!(
            "  activations whose step the world did not hold (no observation): {}",
            s.world_misses
        );
    }
    let metres = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.1} m"));
    for f in &s.faults {
        println!(
            "  fault at step {}{}: {}",
            f.step,
            f.until_step.map_or(String::new(), |u| format!("..{u}")),
            f.fault
        );
        println!(
            "    RMSE before {}, during {}, after {}{}",
            metres(f.rmse_before),
            metres(f.rmse_during),
            metres(f.rmse_after),
            match (f.until_step, f.recovered_after) {
                (None, _) => String::new(),
                (Some(_), Some(k)) => format!("; recovered {k} steps after it ended"),
                (Some(_), None) => "; did not recover".to_string(),
            }
        );
    }
    if !s.faults.is_empty() {
        let c = &s.fault_cost;
        println!("  fault cost: {} dropped, {} duplicated, {} corrupted, {} late, {} gated, {} observations weighed a step late, {} node-steps with fewer neighbours, {} node-steps missing", c.dropped_messages, c.duplicated_messages, c.corrupted_messages, c.late_messages, c.gated_observations, c.lagged_observations, c.rounds_with_fewer_neighbours, c.missing_node_steps);
    }
    if s.fault_cost.node_steps_without_choice > 0 {
        println!(
            "  node-steps without the selection's choice (none of their sensors activated): {}",
            s.fault_cost.node_steps_without_choice
        );
    }
    println!("  {:<34} {:>12.1}", "steps per second", s.steps_per_second);
    let st = &s.stage_micros;
    println!(
        "  {:<34} {:>12}",
        "µs per node-step: local/fusion/cons",
        format!(
            "{:.0}/{:.0}/{:.0}",
            st.local_filter, st.fusion_filter, st.consensus
        )
    );
    if st.selection > 0.0 || st.scoring > 0.0 {
        println!(
            "  {:<34} {:>12}",
            "µs per node-step: selection/scoring",
            format!("{:.0}/{:.0}", st.selection, st.scoring)
        );
    }
    if let Some(d) = &s.disagreement {
        println!(
            "  {:<34} {:>12}",
            "disagreement after consensus",
            format!(
                "{:.1} %/{:.1} %",
                100.0 * d.mean_of_step_largest,
                100.0 * d.largest
            )
        );
        println!("  {:<34}", "  (largest per step: mean/worst)");
    }
    if let Some(p) = &s.round_latency_micros {
        println!(
            "  {:<34} {:>12}",
            "consensus round p50/p99, µs",
            format!("{:.0}/{:.0}", p.p50, p.p99)
        );
    }
    println!("  {:<34} {:>12}", "processes", s.processes);
    if let Some(cpu) = s.cpu_seconds {
        let whose = if s.command.starts_with("run") {
            "launcher CPU, s"
        } else {
            "CPU, s"
        };
        println!("  {:<34} {:>12.1}", whose, cpu);
    }
    if let Some(seconds) = s.startup_seconds {
        println!("  {:<34} {:>12.1}", "start-up, s", seconds);
    }
    if let Some(c) = &s.children_cpu {
        println!(
            "  {:<34} {:>12}",
            "children from ready: user/kernel s",
            format!("{:.1}/{:.1}", c.user_seconds, c.system_seconds)
        );
        let steps = s.steps.max(1) as f64;
        println!(
            "  {:<34} {:>12}",
            "  context switches/step: vol/invol",
            format!(
                "{:.0}/{:.0}",
                c.voluntary_switches as f64 / steps,
                c.involuntary_switches as f64 / steps
            )
        );
    }
    if let Some(m) = &s.children_memory_kb {
        println!(
            "  {:<34} {:>12}",
            "children: largest RSS, total PSS",
            format!(
                "{} MB, {} MB",
                m.largest_peak_rss / 1024,
                m.total_pss / 1024
            )
        );
    }
}

/// One step's means: over nodes and runs; the RMSEs are root mean squares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepMeans {
    pub step: u32,
    pub rmse: Option<f64>,
    pub bound: Option<f64>,
    pub aux_bound: Option<f64>,
    pub centralized_rmse: Option<f64>,
    pub centralized_bound: Option<f64>,
    /// The largest disagreement any node reported after its last round.
    pub largest_disagreement: Option<f64>,
}

/// How far consensus got: the disagreement the nodes reported after their
/// last round (each the largest relative difference from a neighbour
/// heard, in its protocol's measure).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Disagreement {
    /// The largest over every node and step.
    pub largest: f64,
    /// The mean over steps of each step's largest.
    pub mean_of_step_largest: f64,
    /// Each step's largest, from step 1 (`null`: no node said).
    pub by_step: Vec<Option<f64>>,
}

impl Disagreement {
    /// From each step's largest; `None` if no node ever said.
    pub fn of_steps(means: &[StepMeans]) -> Option<Self> {
        let by_step: Vec<Option<f64>> = means.iter().map(|m| m.largest_disagreement).collect();
        let said: Vec<f64> = by_step.iter().flatten().copied().collect();
        let largest = said.iter().copied().reduce(f64::max)?;
        Some(Self {
            largest,
            mean_of_step_largest: said.iter().sum::<f64>() / said.len() as f64,
            by_step,
        })
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

/// The root mean square of the per-step RMSEs of steps `from..to` (steps
/// with no report left out); `None` if there are none.
pub fn window_rmse(means: &[StepMeans], from: u32, to: u32) -> Option<f64> {
    let squares: Vec<f64> = means
        .iter()
        .filter(|m| (from..to).contains(&m.step))
        .filter_map(|m| m.rmse.map(|r| r * r))
        .collect();
    (!squares.is_empty()).then(|| (squares.iter().sum::<f64>() / squares.len() as f64).sqrt())
}

/// Steps from `end` until `recovered(step, rmse)` holds for `hold` steps
/// running; `None` if the run ends first.
pub fn steps_to_recover(
    means: &[StepMeans],
    end: u32,
    hold: u32,
    recovered: impl Fn(u32, f64) -> bool,
) -> Option<u32> {
    let mut run_start = None;
    for m in means.iter().filter(|m| m.step >= end) {
        match m.rmse {
            Some(r) if recovered(m.step, r) => {
                let start = *run_start.get_or_insert(m.step);
                if m.step + 1 - start >= hold {
                    return Some(start - end);
                }
            }
            _ => run_start = None,
        }
    }
    None
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
    /// Extra copies an injected `duplicate` fault made.
    #[serde(default)]
    pub duplicated_messages: u64,
    /// See [`Counters::unaccounted_messages`](transport::accounting::Counters::unaccounted_messages).
    pub unaccounted_messages: i64,
}

/// Bytes of bound information carried by consensus: ΔL (10 numbers) per
/// consensus message for CQ/dPCRLB, and in a protocol's own messages the
/// bytes its payload declares (`ProtocolPayload::BOUND_BYTES`); the
/// auxiliary-FIM baseline needs S_obs (10 more) per round as well.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct BoundTraffic {
    pub cq_dpcrlb_bytes: u64,
    pub auxiliary_fim_bytes: Option<u64>,
}

/// The energy sensors spent transmitting on a multiple-access channel: a
/// unit for each slot a sensor transmitted in (a non-zero entry of Φ it
/// acted on), counted from the `slot_values` messages sent.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
pub struct Energy {
    pub transmissions: u64,
    pub per_step: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_histogram_percentiles_are_the_exact_ones_to_its_resolution() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for scale in [50.0, 700.0, 5_000.0, 3e6] {
            let mut values: Vec<f64> = (0..20_000)
                .map(|_| 4.0 * scale * rng.random::<f64>().powi(3))
                .collect();
            let mut histogram = LatencyHistogram::default();
            for v in &values {
                histogram.add(*v);
            }
            let exact = Percentiles::of(&mut values).unwrap();
            let approx = histogram.percentiles().unwrap();
            for (a, e) in [(approx.p50, exact.p50), (approx.p99, exact.p99)] {
                // Below 1024 µs the whole microsecond; above it, half a
                // bucket of 1/64 octave.
                assert!(
                    (a - e).abs() <= 1.0_f64.max(e / 64.0),
                    "scale {scale}: {a} against {e}"
                );
            }
        }
        assert_eq!(LatencyHistogram::default().percentiles(), None);
    }
}
