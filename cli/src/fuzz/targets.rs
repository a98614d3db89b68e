//! The four targets: what each does with an input, and the outcome it
//! reports for the corpus's feedback.

use fusion_graph::scenario::{
    Scenario, COMPRESSIVE_SCENARIO, DEFAULT_SCENARIO, LOCATION_SCENARIO, RANDOM_EXCHANGE_SCENARIO,
    SENSOR_SELECTION_SCENARIO,
};
use std::time::Duration;

use fusion_graph::Actor;
use fusion_graph::Topology;
use node::{processing_node, AnyNode, Start};
use sensor::SensorActor;
use transport::world_memory::{TruthReader, TruthRing};
use wire::payloads::Payloads;
use wire::{examples, seal, Message, WireFormat};

use super::Target;

/// Runs one input through the target; its outcome (not its values) as a
/// small string, for the corpus's feedback.
pub(super) fn exercise(target: Target, input: &[u8], actors: &mut Option<Actors>) -> String {
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
        payloads: Payloads::NONE,
    },
    WireFormat {
        cell_bytes: 2,
        activation_bytes: 4,
        payloads: Payloads::NONE,
    },
    WireFormat {
        cell_bytes: 1,
        activation_bytes: 32,
        payloads: Payloads::NONE,
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
pub(super) fn shape(message: &str) -> String {
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
pub(super) struct Actors {
    nodes: Vec<AnyNode>,
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
            vec![processing_node(&scenario, &topology, 4, Start::default()).expect("node-4")];
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
                processing_node(&random_exchange, &lattice, 12, Start::default()).expect("node-12"),
            );
        }
        let location = Scenario::from_toml(LOCATION_SCENARIO, "location", &[])
            .expect("the built-in location scenario");
        let ring = Topology::from_scenario(&location, "location").expect("its topology");
        nodes.push(processing_node(&location, &ring, 1, Start::default()).expect("node-1"));
        let compressive = Scenario::from_toml(COMPRESSIVE_SCENARIO, "compressive", &overrides[..1])
            .expect("the built-in compressive scenario");
        let field = Topology::from_scenario(&compressive, "compressive").expect("its topology");
        nodes.push(processing_node(&compressive, &field, 0, Start::default()).expect("node-0"));
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
        let observed = match self.sensor.answer(&message, &self.world) {
            Ok(observation) => observation.is_some(),
            Err(_) => false,
        };
        let delivered =
            self.mac.take(&message, self.now).is_some() | self.mac.end_slots(self.now).is_some();
        let observed = observed || delivered;
        format!(
            "{:?} sent {} observed {observed}",
            message.header.kind,
            sent.min(3)
        )
    }
}

pub(super) fn builtin_seeds(target: Target) -> Vec<Vec<u8>> {
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
