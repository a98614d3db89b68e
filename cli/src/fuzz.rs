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
use fusion_graph::scenario::{
    Scenario, COMPRESSIVE_SCENARIO, DEFAULT_SCENARIO, LOCATION_SCENARIO, RANDOM_EXCHANGE_SCENARIO,
    SENSOR_SELECTION_SCENARIO,
};
use fusion_graph::Topology;
use node::ProcessingNode;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sensor::SensorActor;
use transport::world_memory::{TruthReader, TruthRing};
use wire::{examples, seal, Message, WireFormat};

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

/// Values that have broken parsers and validators before.
const INTERESTING: &[&str] = &[
    "0",
    "-1",
    "-5",
    "1",
    "2",
    "255",
    "256",
    "65535",
    "65536",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "99999999999999999999",
    "1e308",
    "-1e308",
    "1e-320",
    "0.0",
    "-0.0",
    "nan",
    "inf",
    "-inf",
    "0.5",
    "\"\"",
    "\"sonar\"",
    "\"bearing\"",
    "\"exact\"",
    "true",
    "[]",
    "[0,0]",
    "[1,0]",
    "[1000,1000]",
    "[-1,3]",
    "[1e9,1e9]",
    "[[]]",
    "{}",
    "{a=1}",
    "\"node-42\"",
    "\"node-0\"",
    "\"sensor-99999\"",
    "\"launcher\"",
    "[\"node-0\"]",
    "'",
    "\"",
    "[",
    "=",
    "#",
];

/// Runs one input through the target; its outcome (not its values) as a
/// small string, for the corpus's feedback.
fn exercise(target: Target, input: &[u8], actors: &mut Option<Actors>) -> String {
    match target {
        Target::Wire => {
            // As it came, and resealed: almost every mutation breaks the
            // checksum, and the decoding behind it must be reached too.
            let mut sealed = input.to_vec();
            seal(&mut sealed);
            let mut outcome = String::new();
            for bytes in [input, &sealed[..]] {
                for format in FORMATS {
                    outcome.push_str(&match Message::decode(bytes, &format) {
                        Ok(m) => format!("{:?};", m.header.kind),
                        Err(e) => format!("{};", shape(&e.to_string())),
                    });
                }
            }
            outcome
        }
        Target::Scenario => match std::str::from_utf8(input) {
            Ok(text) => scenario_outcome(text, &[]),
            Err(_) => "not utf-8".into(),
        },
        Target::Set => {
            let text = String::from_utf8_lossy(input);
            let overrides: Vec<String> = text.lines().map(str::to_string).collect();
            scenario_outcome(DEFAULT_SCENARIO, &overrides)
        }
        Target::Actor => actors.get_or_insert_with(Actors::new).handle(input),
    }
}

/// The formats of the scenarios we ship: 1- and 2-byte cells, a 4-byte
/// (≤ 32 sensors) and a 32-byte activation mask.
const FORMATS: [WireFormat; 3] = [
    WireFormat {
        cell_bytes: 1,
        activation_bytes: 4,
    },
    WireFormat {
        cell_bytes: 2,
        activation_bytes: 4,
    },
    WireFormat {
        cell_bytes: 1,
        activation_bytes: 32,
    },
];

/// What `cqnet run` does with a scenario before spawning anything.
fn scenario_outcome(text: &str, overrides: &[String]) -> String {
    let scenario = match Scenario::from_toml(text, "fuzz.toml", overrides) {
        Ok(s) => s,
        Err(e) => return shape(&e.to_string()),
    };
    let topology = match Topology::from_scenario(&scenario, "fuzz.toml") {
        Ok(t) => t,
        Err(e) => return format!("topology: {}", shape(&e.to_string())),
    };
    let models = match scenario.models() {
        Ok(m) => m,
        Err(e) => return format!("models: {}", shape(&e.to_string())),
    };
    let _ = scenario.network_prior(&models);
    let _ = scenario.wire_format(&topology);
    let _ = launch::preflight::estimated_memory(&scenario, &topology, true);
    "ok".into()
}

/// An error message with its particulars (numbers, quoted text) removed,
/// so that outcomes count kinds of error, not values.
fn shape(message: &str) -> String {
    let mut out = String::with_capacity(64);
    let mut quoted = false;
    // The first line only: TOML's errors go on to quote the offending source.
    let mut first = message.lines().next().unwrap_or_default();
    // `--set <assignment>: …` names the assignment unquoted.
    if let Some(rest) = first.strip_prefix("--set ") {
        first = rest.split_once(": ").map_or(rest, |(_, why)| why);
    }
    for c in first.chars().take(120) {
        match c {
            '`' | '"' | '\'' => {
                quoted = !quoted;
                out.push('_');
            }
            _ if quoted => {}
            '0'..='9' => {
                if !out.ends_with('#') {
                    out.push('#');
                }
            }
            c => out.push(c),
        }
    }
    out
}

/// A node and a sensor of a small default network, an interior node of
/// the random-exchange paper's lattice for each kind of its cooperation, a
/// locator node, and a fusion centre with its multiple-access channel,
/// handed every input that decodes as one message.
struct Actors {
    nodes: Vec<ProcessingNode>,
    sensor: SensorActor,
    /// The sensor's world: the truth of steps 1 to 16 only, so that a
    /// forged step exercises the refusal of a step it does not hold.
    world: TruthReader,
    mac: sensor::mac::MacActor,
    now: Duration,
}

impl Actors {
    fn new() -> Self {
        let overrides = vec!["filter.particles=64".to_string()];
        let scenario = Scenario::from_toml(DEFAULT_SCENARIO, "default", &overrides)
            .expect("the built-in scenario");
        let topology = Topology::from_scenario(&scenario, "default").expect("its topology");
        let mut nodes =
            vec![ProcessingNode::for_scenario(&scenario, &topology, 4).expect("node-4")];
        for protocol in ["random_exchange", "kl_iterative"] {
            let overrides = [
                "filter.particles=64".to_string(),
                format!("consensus.protocol=\"{protocol}\""),
            ];
            let random_exchange =
                Scenario::from_toml(RANDOM_EXCHANGE_SCENARIO, "random-exchange", &overrides)
                    .expect("the built-in random-exchange scenario");
            let lattice =
                Topology::from_scenario(&random_exchange, "random-exchange").expect("its topology");
            nodes.push(
                ProcessingNode::for_scenario(&random_exchange, &lattice, 12).expect("node-12"),
            );
        }
        let location = Scenario::from_toml(LOCATION_SCENARIO, "location", &[])
            .expect("the built-in location scenario");
        let ring = Topology::from_scenario(&location, "location").expect("its topology");
        nodes.push(ProcessingNode::for_scenario(&location, &ring, 1).expect("node-1"));
        let compressive = Scenario::from_toml(COMPRESSIVE_SCENARIO, "compressive", &overrides[..1])
            .expect("the built-in compressive scenario");
        let field = Topology::from_scenario(&compressive, "compressive").expect("its topology");
        nodes.push(ProcessingNode::for_scenario(&compressive, &field, 0).expect("node-0"));
        let (truths, seen) = TruthRing::on_heap(16);
        let mut truth = launch::world::World::new(&scenario).expect("the default world");
        for step in 1..=16 {
            truths.write(step, &truth.advance());
        }
        Self {
            nodes,
            sensor: SensorActor::new(&scenario, &topology, 0).expect("sensor-0"),
            world: seen,
            mac: sensor::mac::MacActor::new(&compressive, &field, 0)
                .expect("mac-0")
                .expect("the scenario has a channel"),
            now: Duration::ZERO,
        }
    }

    fn handle(&mut self, input: &[u8]) -> String {
        // Sealed, so that the actors see the mutations, not checksum errors.
        let mut sealed = input.to_vec();
        seal(&mut sealed);
        let Ok(message) = Message::decode(&sealed, &FORMATS[0]) else {
            return "undecodable".into();
        };
        self.now += Duration::from_millis(7);
        let mut out = Vec::new();
        let mut sent = 0;
        for node in &mut self.nodes {
            node.handle(&message, self.now, &mut out);
            let mut guard = 0;
            loop {
                while let Some(work) = node.poll_work() {
                    node.run_work(work);
                    node.work_done(work, Duration::ZERO, self.now, &mut out);
                }
                node.handle_timeout(self.now, &mut out);
                sent += out.len();
                out.clear();
                guard += 1;
                if node.poll_work().is_none() || guard > 4 {
                    break;
                }
            }
        }
        let observed = match self.sensor.handle(&message, &self.world) {
            Ok(observation) => observation.is_some(),
            Err(_) => false,
        };
        let delivered = self.mac.handle(&message, self.now).is_some()
            | self.mac.handle_timeout(self.now).is_some();
        let observed = observed || delivered;
        format!(
            "{:?} sent {} observed {observed}",
            message.header.kind,
            sent.min(3)
        )
    }
}

fn builtin_seeds(target: Target) -> Vec<Vec<u8>> {
    match target {
        Target::Wire | Target::Actor => examples()
            .iter()
            .flat_map(|m| FORMATS.iter().map(move |f| m.to_bytes(f)))
            .collect(),
        Target::Scenario => vec![
            DEFAULT_SCENARIO.as_bytes().to_vec(),
            SENSOR_SELECTION_SCENARIO.as_bytes().to_vec(),
            RANDOM_EXCHANGE_SCENARIO.as_bytes().to_vec(),
            LOCATION_SCENARIO.as_bytes().to_vec(),
            COMPRESSIVE_SCENARIO.as_bytes().to_vec(),
        ],
        Target::Set => vec![b"quantizer.bits=4".to_vec()],
    }
}

fn mutate_bytes(input: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let len = input.len();
    let at = |rng: &mut ChaCha8Rng| rng.random_range(0..=len);
    match rng.random_range(0..9) {
        0 if len > 0 => {
            let i = rng.random_range(0..len);
            input[i] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let i = rng.random_range(0..len);
            input[i] = [0, 1, 0x7f, 0x80, 0xfe, 0xff][rng.random_range(0..6)];
        }
        2 => {
            let i = at(rng);
            let n = rng.random_range(1..16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            input.splice(i..i, bytes);
        }
        3 if len > 0 => {
            let i = rng.random_range(0..len);
            let n = rng.random_range(1..=(len - i).min(16));
            input.drain(i..i + n);
        }
        4 => {
            let n = at(rng);
            input.truncate(n);
        }
        5 if len >= 8 => {
            // A float field made special.
            let i = rng.random_range(0..=len - 8);
            let v = [
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
                0.0,
                -0.0,
                f64::MAX,
                1e-310,
            ][rng.random_range(0..7)];
            input[i..i + 8].copy_from_slice(&v.to_le_bytes());
        }
        6 if len >= 2 => {
            let i = rng.random_range(0..=len - 2);
            let v = [0u16, 1, 0x7fff, 0x8000, 0xffff, 255, 256][rng.random_range(0..7)];
            input[i..i + 2].copy_from_slice(&v.to_le_bytes());
        }
        7 if len > 0 => {
            let i = rng.random_range(0..len);
            let n = rng.random_range(1..=(len - i).min(32));
            let copy = input[i..i + n].to_vec();
            let j = at(rng);
            input.splice(j..j, copy);
        }
        _ => input.push(rng.random()),
    }
}

/// Line- and value-level edits that keep a TOML file mostly TOML, so that
/// inputs get past the parser to the validation behind it.
fn mutate_text(input: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let text = String::from_utf8_lossy(input).into_owned();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    if lines.is_empty() {
        lines.push(String::new());
    }
    let i = rng.random_range(0..lines.len());
    match rng.random_range(0..6) {
        0 | 1 => {
            if let Some(eq) = lines[i].find('=') {
                let value = INTERESTING[rng.random_range(0..INTERESTING.len())];
                lines[i] = format!("{}= {value}", &lines[i][..eq]);
            }
        }
        2 => {
            lines.remove(i);
        }
        3 => {
            let copy = lines[rng.random_range(0..lines.len())].clone();
            lines.insert(i, copy);
        }
        4 => {
            let j = rng.random_range(0..lines.len());
            lines.swap(i, j);
        }
        _ => {
            // A number in the line scaled, negated or zeroed.
            let line = &lines[i];
            if let Some(start) = line.find(|c: char| c.is_ascii_digit()) {
                let end = line[start..]
                    .find(|c: char| !(c.is_ascii_digit() || c == '.'))
                    .map_or(line.len(), |e| start + e);
                let n = ["0", "-1", "100000", "1e20", "0.000001", "7"][rng.random_range(0..6)];
                lines[i] = format!("{}{n}{}", &line[..start], &line[end..]);
            }
        }
    }
    *input = lines.join("\n").into_bytes();
}

/// Every dotted key of a TOML document (`filter.particles`, …).
fn scenario_keys(text: &str) -> Vec<String> {
    fn walk(prefix: &str, v: &toml::Value, out: &mut Vec<String>) {
        if let toml::Value::Table(t) = v {
            for (k, v) in t {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                walk(&key, v, out);
                out.push(key);
            }
        }
    }
    let mut keys = Vec::new();
    if let Ok(t) = text.parse::<toml::Table>() {
        walk("", &toml::Value::Table(t), &mut keys);
    }
    keys
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
        assert!(w.panic_kinds.keys().next().unwrap().contains("fuzz.rs"));
        assert_eq!(w.crashes.len() as u64, w.panics.min(MAX_CRASHES as u64));
        assert!(w.crashes.iter().all(|c| c[0] % 4 == 0));
    }
}
