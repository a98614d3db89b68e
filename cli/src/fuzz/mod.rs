//! `cqnet fuzz`: generated inputs against everything that reads what comes
//! from outside a process, counting panics. Bad input must end in an error
//! or a counted drop, never in a panic.
//!
//! Four targets:
//! - `wire`: bytes as a subscriber takes them from shared memory, decoded
//!   in every wire format;
//! - `scenario`: scenario files, parsed, validated, their topology and
//!   models built and their memory estimated, as `cqnet run` does before it
//!   spawns anything;
//! - `set`: `--set KEY=VALUE` overrides on the built-in scenario, the same way;
//! - `actor`: messages that decode but carry whatever a broken or hostile
//!   peer might send, handled by a live node and sensor.
//!
//! Inputs are mutations of a corpus. Without coverage instrumentation (that
//! needs a nightly compiler), the feedback is the outcome: an input joins
//! the corpus when it ends in an outcome not seen before (a new error, a
//! message kind first decoded), so mutation builds on inputs that reach
//! deeper validation. `--corpus DIR` starts from a saved corpus and saves
//! what grew, and every panicking input, back into it.

use std::collections::{BTreeMap, HashSet};
use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use fusion_graph::scenario::DEFAULT_SCENARIO;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

mod mutate;
mod targets;

use mutate::{mutate_bytes, mutate_text, scenario_keys, INTERESTING};
use targets::{builtin_seeds, exercise, Actors};

/// What `cqnet fuzz` can aim at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum)]
pub enum Target {
    Wire,
    Scenario,
    Set,
    Actor,
}

impl Target {
    pub const ALL: [Target; 4] = [Target::Wire, Target::Scenario, Target::Set, Target::Actor];

    pub fn name(self) -> &'static str {
        match self {
            Target::Wire => "wire",
            Target::Scenario => "scenario",
            Target::Set => "set",
            Target::Actor => "actor",
        }
    }
}

/// What one target's campaign found.
#[derive(Debug, Clone, Default)]
pub struct Report {
    pub inputs: u64,
    pub panics: u64,
    /// Each distinct panic (its message and place) and how often it came.
    pub panic_kinds: BTreeMap<String, u64>,
    /// Distinct outcomes seen (a rough measure of how much was reached).
    pub outcomes: usize,
    pub corpus_size: usize,
    pub seconds: f64,
}

impl Report {
    pub fn inputs_per_second(&self) -> f64 {
        self.inputs as f64 / self.seconds.max(1e-9)
    }
}

/// How a campaign runs.
#[derive(Debug, Clone)]
pub struct Campaign {
    pub target: Target,
    pub inputs: u64,
    pub seed: u64,
    pub threads: usize,
    /// Seeds are read from `<corpus>/<target>/`.
    pub corpus: Option<PathBuf>,
    /// Whether inputs with new outcomes, and panicking ones, are saved
    /// into the corpus.
    pub save: bool,
}

/// Runs one campaign; `progress` is told the inputs done so far, now and
/// then, from the calling thread.
pub fn run(campaign: &Campaign, mut progress: impl FnMut(u64, u64)) -> anyhow::Result<Report> {
    let started = Instant::now();
    let mut seeds = builtin_seeds(campaign.target);
    if let Some(dir) = &campaign.corpus {
        seeds.extend(read_corpus(&dir.join(campaign.target.name()))?);
    }
    let known: HashSet<u64> = seeds.iter().map(|s| digest(s)).collect();
    let done = AtomicU64::new(0);
    let threads = campaign.threads.max(1);
    let _quiet = QuietPanics::install();
    let found: Vec<Found> = std::thread::scope(|scope| -> anyhow::Result<Vec<Found>> {
        let mut workers = Vec::new();
        for t in 0..threads {
            let share = campaign.inputs / threads as u64
                + u64::from((t as u64) < campaign.inputs % threads as u64);
            let (seeds, done) = (seeds.clone(), &done);
            let seed = campaign.seed.wrapping_add(t as u64 * 0x9e37_79b9_7f4a_7c15);
            let target = campaign.target;
            workers.push(
                std::thread::Builder::new()
                    .name(format!("fuzz-{t}"))
                    .spawn_scoped(scope, move || {
                        // A bug in the fuzzer itself is reported, not swallowed
                        // by the quiet hook with the thread.
                        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            let mut w = Worker::new(target, seed, seeds);
                            w.run(share, done);
                            w.found()
                        }))
                        .map_err(|_| {
                            anyhow::anyhow!(
                                "the fuzzer itself panicked: {}",
                                take_panic().unwrap_or_default()
                            )
                        })
                    })
                    .context("starting a fuzzing thread")?,
            );
        }
        while !workers.iter().all(|w| w.is_finished()) {
            progress(done.load(Ordering::Relaxed), campaign.inputs);
            std::thread::sleep(Duration::from_millis(200));
        }
        workers
            .into_iter()
            .map(|w| match w.join() {
                Ok(Ok(found)) => Ok(found),
                Ok(Err(e)) => Err(e),
                Err(_) => Err(anyhow::anyhow!("a fuzzing thread died")),
            })
            .collect()
    })?;
    progress(done.load(Ordering::Relaxed), campaign.inputs);
    let mut report = Report {
        seconds: started.elapsed().as_secs_f64(),
        ..Default::default()
    };
    let mut outcomes = HashSet::new();
    let mut grown: Vec<Vec<u8>> = Vec::new();
    let mut crashes: Vec<Vec<u8>> = Vec::new();
    let mut saved = known.clone();
    for w in found {
        report.inputs += w.inputs;
        report.panics += w.panics;
        for (k, n) in w.panic_kinds {
            *report.panic_kinds.entry(k).or_default() += n;
        }
        outcomes.extend(w.outcomes);
        for input in w.corpus {
            if grown.len() < MAX_SAVED && saved.insert(digest(&input)) {
                grown.push(input);
            }
        }
        crashes.extend(w.crashes);
    }
    report.outcomes = outcomes.len();
    report.corpus_size = saved.len();
    if let (Some(dir), true) = (&campaign.corpus, campaign.save) {
        let dir = dir.join(campaign.target.name());
        write_inputs(&dir, "", &grown)?;
        write_inputs(&dir.join("crashes"), "crash-", &crashes)?;
    }
    Ok(report)
}

/// Largest input the mutator makes: above any message or scenario we have.
const MAX_INPUT: usize = 16 * 1024;
/// Inputs kept per thread for their new outcomes.
const MAX_CORPUS: usize = 1024;
/// Inputs a campaign adds to a saved corpus, at most: it is kept in git.
const MAX_SAVED: usize = 256;
/// Panicking inputs kept per thread.
const MAX_CRASHES: usize = 64;

/// What a worker found, handed back to the campaign.
struct Found {
    inputs: u64,
    panics: u64,
    panic_kinds: BTreeMap<String, u64>,
    outcomes: HashSet<u64>,
    corpus: Vec<Vec<u8>>,
    crashes: Vec<Vec<u8>>,
}

/// One thread's campaign: its own corpus, generator and target state.
struct Worker {
    target: Target,
    rng: ChaCha8Rng,
    corpus: Vec<Vec<u8>>,
    outcomes: HashSet<u64>,
    inputs: u64,
    panics: u64,
    panic_kinds: BTreeMap<String, u64>,
    crashes: Vec<Vec<u8>>,
    actors: Option<Actors>,
    set_keys: Vec<String>,
    /// What an input is run through: [`exercise`], or a stand-in in tests.
    exercise: fn(Target, &[u8], &mut Option<Actors>) -> String,
}

impl Worker {
    fn new(target: Target, seed: u64, corpus: Vec<Vec<u8>>) -> Self {
        Self {
            target,
            rng: ChaCha8Rng::seed_from_u64(seed),
            corpus,
            outcomes: HashSet::new(),
            inputs: 0,
            panics: 0,
            panic_kinds: BTreeMap::new(),
            crashes: Vec::new(),
            actors: None,
            set_keys: scenario_keys(DEFAULT_SCENARIO),
            exercise,
        }
    }

    fn run(&mut self, inputs: u64, done: &AtomicU64) {
        for _ in 0..inputs {
            let input = self.generate();
            let (target, exercise) = (self.target, self.exercise);
            let actors = &mut self.actors;
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                exercise(target, &input, actors)
            }));
            self.inputs += 1;
            match outcome {
                Ok(outcome) => {
                    let mut h = DefaultHasher::new();
                    outcome.hash(&mut h);
                    if self.outcomes.insert(h.finish()) && self.corpus.len() < MAX_CORPUS {
                        self.corpus.push(input);
                    }
                }
                Err(_) => {
                    self.panics += 1;
                    let what = take_panic().unwrap_or_else(|| "a panic".into());
                    *self.panic_kinds.entry(what).or_default() += 1;
                    if self.crashes.len() < MAX_CRASHES {
                        self.crashes.push(input);
                    }
                    // Whatever the panic left half-done is not reused.
                    self.actors = None;
                }
            }
            done.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn found(self) -> Found {
        Found {
            inputs: self.inputs,
            panics: self.panics,
            panic_kinds: self.panic_kinds,
            outcomes: self.outcomes,
            corpus: self.corpus,
            crashes: self.crashes,
        }
    }

    fn generate(&mut self) -> Vec<u8> {
        if self.target == Target::Set && self.rng.random_bool(0.5) {
            return self.overrides();
        }
        if self.corpus.is_empty() || self.rng.random_ratio(1, 32) {
            let n = self.rng.random_range(0..400);
            return (0..n).map(|_| self.rng.random()).collect();
        }
        let mut input = self.corpus[self.rng.random_range(0..self.corpus.len())].clone();
        for _ in 0..self.rng.random_range(1..=6) {
            match self.target {
                Target::Scenario | Target::Set if self.rng.random_bool(0.7) => {
                    mutate_text(&mut input, &mut self.rng)
                }
                _ => mutate_bytes(&mut input, &mut self.rng),
            }
        }
        input.truncate(MAX_INPUT);
        input
    }

    /// Override lines: known keys (and some that are not), interesting values.
    fn overrides(&mut self) -> Vec<u8> {
        let mut lines = Vec::new();
        for _ in 0..self.rng.random_range(1..=4) {
            let key = if self.rng.random_ratio(1, 8) {
                [
                    "",
                    "filter",
                    "filter.",
                    ".",
                    "a..b",
                    "faults[0].actor",
                    "nodes.grid[0]",
                    "seed.x",
                ][self.rng.random_range(0..8)]
                .to_string()
            } else {
                self.set_keys[self.rng.random_range(0..self.set_keys.len())].clone()
            };
            let value = INTERESTING[self.rng.random_range(0..INTERESTING.len())];
            lines.push(if self.rng.random_ratio(1, 16) {
                key
            } else {
                format!("{key}={value}")
            });
        }
        lines.join("\n").into_bytes()
    }
}

fn digest(input: &[u8]) -> u64 {
    let mut h = DefaultHasher::new();
    input.hash(&mut h);
    h.finish()
}

fn read_corpus(dir: &Path) -> anyhow::Result<Vec<Vec<u8>>> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("reading the corpus {}", dir.display())),
    };
    let mut inputs = Vec::new();
    for e in entries.flatten() {
        if e.path().is_file() {
            inputs.push(
                std::fs::read(e.path())
                    .with_context(|| format!("reading {}", e.path().display()))?,
            );
        }
    }
    Ok(inputs)
}

/// The saved inputs of a corpus directory, crashes included: what a test
/// replays.
pub fn corpus_inputs(dir: &Path, target: Target) -> anyhow::Result<Vec<Vec<u8>>> {
    let dir = dir.join(target.name());
    let mut all = read_corpus(&dir)?;
    all.extend(read_corpus(&dir.join("crashes"))?);
    Ok(all)
}

/// Runs saved inputs through a target; returns the panics' descriptions.
pub fn replay(target: Target, inputs: &[Vec<u8>]) -> Vec<String> {
    let _quiet = QuietPanics::install();
    let mut actors = None;
    let mut panics = Vec::new();
    for input in inputs {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            exercise(target, input, &mut actors)
        }));
        if r.is_err() {
            panics.push(take_panic().unwrap_or_else(|| "a panic".into()));
            actors = None;
        }
    }
    panics
}

fn write_inputs(dir: &Path, prefix: &str, inputs: &[Vec<u8>]) -> anyhow::Result<()> {
    if inputs.is_empty() {
        return Ok(());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for input in inputs {
        let path = dir.join(format!("{prefix}{:016x}", digest(input)));
        std::fs::write(&path, input).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

thread_local! {
    static LAST_PANIC: std::cell::RefCell<Option<String>> = const { std::cell::RefCell::new(None) };
}

fn take_panic() -> Option<String> {
    LAST_PANIC.with(|p| p.borrow_mut().take())
}

type PanicHook = Box<dyn Fn(&std::panic::PanicHookInfo<'_>) + Sync + Send + 'static>;

/// While alive, panics are recorded (message and place) instead of printed:
/// a campaign of millions would otherwise flood the terminal.
struct QuietPanics {
    previous: Option<PanicHook>,
}

impl QuietPanics {
    fn install() -> Self {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(|info| {
            let message = info
                .payload()
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| info.payload().downcast_ref::<String>().cloned())
                .unwrap_or_default();
            let place = info
                .location()
                .map(|l| format!("{}:{}", l.file(), l.line()))
                .unwrap_or_default();
            let _ = LAST_PANIC.try_with(|p| *p.borrow_mut() = Some(format!("{place}: {message}")));
        }));
        Self {
            previous: Some(previous),
        }
    }
}

impl Drop for QuietPanics {
    fn drop(&mut self) {
        // The hook cannot be changed from a panicking thread (it aborts).
        if std::thread::panicking() {
            return;
        }
        if let Some(previous) = self.previous.take() {
            std::panic::set_hook(previous);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::targets::shape;
    use super::*;

    #[test]
    fn shapes_drop_particulars() {
        assert_eq!(
            shape("`filter.particles` = -5: expected u32 at line 12"),
            "__ = -#: expected u# at line #"
        );
    }

    #[test]
    fn scenario_keys_are_dotted_paths() {
        let keys = scenario_keys(DEFAULT_SCENARIO);
        assert!(keys.contains(&"filter.particles".to_string()), "{keys:?}");
        assert!(keys.contains(&"quantizer.bits".to_string()));
    }

    /// A target that panics on some inputs: each panic is counted, told
    /// apart by its message and place, and its input kept; the campaign
    /// goes on to the end.
    #[test]
    fn a_panicking_target_is_counted_not_fatal() {
        fn fragile(_: Target, input: &[u8], _: &mut Option<Actors>) -> String {
            if input.first().is_some_and(|b| b % 4 == 0) {
                panic!("boom");
            }
            input.len().to_string()
        }
        let quiet = QuietPanics::install();
        let mut w = Worker::new(Target::Wire, 1, vec![vec![1, 2, 3]]);
        w.exercise = fragile;
        let done = AtomicU64::new(0);
        w.run(2000, &done);
        // Failures below must be heard.
        drop(quiet);
        assert_eq!((w.inputs, done.load(Ordering::Relaxed)), (2000, 2000));
        assert!(w.panics > 0 && w.panics < 2000, "{}", w.panics);
        assert_eq!(w.panic_kinds.len(), 1);
        assert!(w.panic_kinds.keys().next().unwrap().contains(file!()));
        assert_eq!(w.crashes.len() as u64, w.panics.min(MAX_CRASHES as u64));
        assert!(w.crashes.iter().all(|c| c[0] % 4 == 0));
    }
}
