//! The scenario file: what network to build, what it observes, and how to
//! break it. TOML, every key checked: an unknown key is an error.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::vocabulary::{Part, Role, Shape, Vocabulary};
use crate::ScenarioError;

mod consensus;
mod law_and_motion;
mod mac;
mod overrides;
mod validate;

pub use crate::faults::{
    is_wildcard, BurstLoss, Corrupt, Delay, Duplicate, Fault, FaultySensors, Kill, LinkSelector,
    Loss, Partition, Reorder, SensorMode, Signal,
};
use consensus::default_accuracy;
pub use consensus::{RoundsAdvice, RoundsChoice, MAX_AUTO_ROUNDS};
pub use law_and_motion::{DynamicsConfig, ObservationConfig};
pub use mac::{MacConfig, MacDesign, MAX_SLOTS as MAX_MAC_SLOTS};
pub use overrides::apply_override;

/// A part a scenario names (a fusion protocol, a sensor manager): a part
/// of the [`Vocabulary`] it is read in, built in or the program's. An
/// unknown name is refused at its key, listing the names it could have
/// been.
macro_rules! named_part {
    ($(#[$doc:meta])* $ty:ident, $role:path) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy)]
        pub struct $ty(&'static Part);

        impl $ty {
            /// The name the scenario file spells it with.
            pub fn name(self) -> &'static str {
                self.0.name
            }

            /// The part, with what builds it.
            pub fn part(self) -> &'static Part {
                self.0
            }

            /// Whether it is one of the parts cqnet ships.
            pub fn is_built_in(self) -> bool {
                Vocabulary::BUILT_IN.part($role, self.0.name).is_some()
            }

            const fn built_in(name: &'static str) -> Self {
                // Found at compile time: a name missing from the table
                // does not build.
                let parts = Vocabulary::built_in_parts();
                let mut i = 0;
                while i < parts.len() {
                    if matches!(parts[i].role, $role) && const_eq(parts[i].name, name) {
                        return Self(&parts[i]);
                    }
                    i += 1;
                }
                panic!("not a built-in part")
            }
        }

        impl PartialEq for $ty {
            fn eq(&self, other: &Self) -> bool {
                self.0.name == other.0.name
            }
        }

        impl Eq for $ty {}

        impl Serialize for $ty {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.name())
            }
        }

        impl<'de> Deserialize<'de> for $ty {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let name = String::deserialize(d)?;
                let vocabulary = Vocabulary::current();
                vocabulary.part($role, &name).map(Self).ok_or_else(|| {
                    let expected: Vec<String> =
                        vocabulary.names($role).map(|n| format!("`{n}`")).collect();
                    serde::de::Error::custom(format!(
                        "unknown {} `{name}`, expected one of {}",
                        $role.what(),
                        expected.join(", ")
                    ))
                })
            }
        }
    };
}

/// `a == b`, at compile time.
const fn const_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

/// The built-in default scenario (docs/equations.md's table).
pub const DEFAULT_SCENARIO: &str = include_str!("../../scenarios/default.toml");
/// The selection paper's scenario (PCRLB sensor selection).
pub const SENSOR_SELECTION_SCENARIO: &str = include_str!("../../scenarios/sensor-selection.toml");
/// The random-exchange paper's network: 25 nodes, each with one co-located RSS sensor.
pub const RANDOM_EXCHANGE_SCENARIO: &str = include_str!("../../scenarios/random-exchange.toml");
/// A static target located from quantized amplitudes (ML over a shared grid).
pub const LOCATION_SCENARIO: &str = include_str!("../../scenarios/location.toml");

/// A fusion centre that hears 25 amplitude sensors through a
/// multiple-access channel and designs who transmits (compressive sensor
/// management).
pub const COMPRESSIVE_SCENARIO: &str = include_str!("../../scenarios/compressive.toml");

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    pub name: String,
    pub seed: u64,
    pub steps: u32,
    pub region: Region,
    pub nodes: NodeLayout,
    pub sensors: SensorLayout,
    pub fusion_graph: FusionGraphConfig,
    pub target: TargetConfig,
    pub dynamics: DynamicsConfig,
    /// What every sensor measures (`kind = "bearing"`, `"rss"`,
    /// `"amplitude"`, `"linear"`, or a law of the program's); the topology
    /// says where each stands.
    pub observation: ObservationConfig,
    pub quantizer: QuantizerConfig,
    pub filter: FilterConfig,
    pub consensus: ConsensusConfig,
    pub clock: ClockConfig,
    #[serde(default)]
    pub reference: ReferenceConfig,
    /// Whether active sensors stay silent when their measurement says
    /// little (dissertation ch. 3); off by default.
    #[serde(default)]
    pub censoring: CensoringConfig,
    #[serde(default)]
    pub faults: Vec<Fault>,
    /// Several hosts (`cqnet agent` on each): which nodes, with their
    /// sensors, each runs. Empty: one host.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub hosts: Vec<HostConfig>,
    /// How the hosts know each other: the keys of their TLS links, or
    /// plain TCP where asked for in so many words.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trust: Option<TrustConfig>,
    /// A multiple-access channel between the fusion centre's sensors and
    /// the centre (compressive sensor management); none by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel: Option<MacConfig>,
    /// The program's parts and payloads the scenario was read in (cqnet's
    /// own, unless read with [`Scenario::from_toml_in`]). Not in the file:
    /// a run's actors, being the same program, read it in the same one.
    #[serde(skip, default = "Vocabulary::current")]
    pub vocabulary: Vocabulary,
}

/// Censoring at the sensor: of the `active_per_node` sensors a node
/// activates, `budget` send on average.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CensoringConfig {
    #[serde(default)]
    pub policy: CensoringPolicy,
    /// Expected transmissions per node per step, at most `active_per_node`.
    #[serde(default = "default_budget")]
    pub budget: f64,
    /// For `policy = "nis"`: what the node feeds back with each activation.
    #[serde(default)]
    pub feedback: FeedbackKind,
    /// For `policy = "nis"`: the node ignores its silent sensors (CFoMD),
    /// to measure what their silence is worth.
    #[serde(default)]
    pub ignore_silence: bool,
    /// How long a node listens for its active sensors before it takes the
    /// quiet ones as silent: a sensor's slot. Without censoring the node
    /// waits up to the round timeout, since every active sensor should send.
    #[serde(default = "default_listen_ms")]
    pub listen_ms: f64,
}

fn default_listen_ms() -> f64 {
    20.0
}

fn default_budget() -> f64 {
    1.0
}

impl Default for CensoringConfig {
    fn default() -> Self {
        Self {
            policy: CensoringPolicy::Off,
            budget: default_budget(),
            feedback: FeedbackKind::Estimate,
            ignore_silence: false,
            listen_ms: default_listen_ms(),
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CensoringPolicy {
    /// Every active sensor sends.
    #[default]
    Off,
    /// A sensor sends when its normalized innovation squared, against the
    /// node's fed-back prediction, reaches χ²₁(budget / active_per_node);
    /// the node weighs each silent sensor's P(silent | x) (CFwMD).
    Nis,
    /// Each active sensor sends with probability budget / active_per_node,
    /// whatever it measured: the same traffic, missing at random.
    Random,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FeedbackKind {
    /// CFwMD: the fused estimate; each sensor keeps its own covariance.
    #[default]
    Estimate,
    /// CFwMD2: the fused estimate and its covariance.
    EstimateAndCovariance,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Region {
    pub width: f64,
    pub height: f64,
}

/// Most processing nodes a scenario may have: each is a process, and the
/// fusion graph is built by comparing every pair.
pub const MAX_NODES: u64 = 4096;
/// Most sensors a scenario may have: their index is a u16 on the wire.
pub const MAX_SENSORS: u64 = u16::MAX as u64;

/// Either a grid (one node at the centre of each cell) or explicit positions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeLayout {
    pub grid: Option<[u32; 2]>,
    pub positions: Option<Vec<[f64; 2]>>,
}

/// One host of the scenario: its name, the nodes it runs (and so their
/// sensors), and where its agent listens for Zenoh.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostConfig {
    /// Lowercase letters, digits and `-`, at most 8 characters: it becomes
    /// part of the host's iceoryx2 run id.
    pub name: String,
    pub nodes: Vec<u16>,
    /// A Zenoh endpoint, such as `quic/127.0.0.1:17447`.
    pub endpoint: String,
    /// What the network does to this host's link to the others.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub link: Option<HostLink>,
}

/// How the hosts of a run know each other. With `quic/` endpoints, `keys`
/// names a folder made by `cqnet hosts keys` (relative to the scenario
/// file): the authority's certificate and each host's key and certificate.
/// `tcp/` endpoints (no authentication, no encryption) need
/// `plain_tcp = true`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrustConfig {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keys: Option<String>,
    #[serde(default)]
    pub plain_tcp: bool,
}

/// What the network does to a host's link, both ways, done by the kernel
/// (`tc` on the link) where each host has a network namespace of its own
/// (cqnet-testkit's `SeparateHosts`); cqnet's own link faults act on
/// messages within a host. A run whose hosts share one network stack, or
/// runs on real machines, cannot apply it, and the launcher says so.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostLink {
    /// Added to every packet each way (netem `delay`), milliseconds.
    #[serde(default)]
    pub delay_ms: f64,
    /// Spread of the delay (netem's jitter), milliseconds.
    #[serde(default)]
    pub jitter_ms: f64,
    /// Share of packets dropped each way (netem `loss`), 0 to 1.
    #[serde(default)]
    pub loss: f64,
    /// The link's rate each way, Mbit/s; 0: no limit.
    #[serde(default)]
    pub rate_mbit: f64,
    /// The link is cut (down) from this step …
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cut_at_step: Option<u32>,
    /// … for this many steps of the run (which goes on without the host).
    #[serde(default)]
    pub cut_steps: u32,
}

impl HostLink {
    /// Whether it asks for anything `tc netem` alone can do.
    pub fn needs_netem(&self) -> bool {
        self.delay_ms > 0.0 || self.jitter_ms > 0.0 || self.loss > 0.0
    }
}

/// Either a grid inside each node's cell, or explicit positions (each sensor
/// then belongs to the nearest node).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorLayout {
    pub per_cell: Option<[u32; 2]>,
    pub positions: Option<Vec<[f64; 2]>>,
    pub active_per_node: u32,
    pub max_active_total: Option<u32>,
    /// Which sensors each node activates (the selection paper's comparison).
    #[serde(default)]
    pub manager: SensorManagerKind,
    /// The manager's own parameters, which it checks (`node::parts`).
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub manager_params: toml::Table,
}

named_part!(
    /// A sensor manager's name (`sensors.manager`).
    SensorManagerKind,
    Role::Manager
);

impl SensorManagerKind {
    /// `active_per_node` of the node's own sensors, uniformly at random.
    pub const RANDOM: Self = Self::built_in("random");
    /// The sensors nearest the predicted target position, network-wide, at
    /// most `active_per_node` per node (the closest-sensor baseline of
    /// sensor selection).
    pub const CLOSEST: Self = Self::built_in("closest");
    /// Greedy selection by the conditional PCRLB, made once at the fusion
    /// graph's centre on every node's candidates.
    pub const PCRLB: Self = Self::built_in("pcrlb");
    /// The same greedy selection scored by Tichavsky's recursion run at
    /// the fusion filter's estimates (data enter through x̂).
    pub const PCRLB_AT_ESTIMATE: Self = Self::built_in("pcrlb_at_estimate");
    /// The same greedy selection scored as the selection paper's eq. 32
    /// prints it: the prediction from the auxiliary FIM `J_AUX(k)` instead
    /// of `L_G(k)`. Needs `consensus.auxiliary_fim = true`.
    pub const PCRLB_AUX: Self = Self::built_in("pcrlb_aux");
    /// The conventional PCRLB manager: greedy on the offline
    /// (non-conditional) bound, averaged over trajectories from the prior,
    /// a schedule every node computes alike before the run; no messages.
    pub const PCRLB_OFFLINE: Self = Self::built_in("pcrlb_offline");
}

impl Default for SensorManagerKind {
    fn default() -> Self {
        Self::RANDOM
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FusionGraphConfig {
    pub radius: f64,
    #[serde(default)]
    pub allow_disconnected: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetConfig {
    pub position: [f64; 2],
    /// Degrees from north, clockwise.
    pub course_deg: f64,
    pub speed: f64,
    /// Where the truth starts: at the state above, or drawn from the prior.
    #[serde(default)]
    pub start: TargetStart,
    /// Whether the target moves by the dynamics or stays where it starts.
    #[serde(default)]
    pub motion: Motion,
}

/// How the true target moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Motion {
    /// By the scenario's dynamics, from its course and speed: a tracking
    /// problem.
    #[default]
    Moving,
    /// At its position for the whole run, its velocity zero: a location
    /// problem, which only the `ml_location` protocol's nodes solve (a
    /// tracker's prediction needs process noise it could invert).
    Static,
}

/// Where the true trajectory starts. Each run draws one offset
/// `P_0^{1/2} n`, `n ~ N(0, I)`, from its prior stream; the two choices put
/// it on different sides of the same comparison.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetStart {
    /// The truth starts at the target's state; the filters' prior mean is
    /// the state plus the offset.
    #[default]
    Fixed,
    /// The truth starts at the state plus the offset, `x_0 ~ N(m_0, P_0)`,
    /// and the filters' prior mean is the state itself: the Bayesian
    /// setting every PCRLB averages over, so a filter's error and the
    /// bound then describe the same population of runs.
    Prior,
}

impl TargetConfig {
    /// `[p_x, p_y, v_x, v_y]`: the scenario's nominal start, the prior's
    /// mean when the truth is drawn from the prior.
    pub fn initial_state(&self) -> [f64; 4] {
        let c = self.course_deg.to_radians();
        [
            self.position[0],
            self.position[1],
            self.speed * c.sin(),
            self.speed * c.cos(),
        ]
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuantizerConfig {
    pub bits: u8,
    #[serde(default)]
    pub raw: bool,
    /// Range of the uniform quantizer; bearings always use (−π, π].
    pub lo: Option<f64>,
    pub hi: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    pub particles: u32,
    pub prior_std: [f64; 4],
    /// The innovation gate's threshold on ν²/S (a χ²₁ quantile, 10.83 for
    /// 1 in 1000); 0: off, every observation is used.
    #[serde(default)]
    pub gate: f64,
    /// How a filter draws its particles anew from their weights.
    #[serde(default, skip_serializing_if = "is_systematic")]
    pub resampler: Resampling,
}

/// The resampling schemes a filter may use (`filter.resampler`). Each
/// copies particle i `N w_i` times in expectation; they differ in the
/// variance of the copies (Douc, Cappé and Moulines 2005).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Resampling {
    /// One uniform draw, N evenly spaced pointers.
    #[default]
    Systematic,
    /// One uniform draw within each of N equal strata.
    Stratified,
    /// `⌊N w_i⌋` copies each, the rest drawn multinomially from what is left.
    Residual,
    /// N independent draws from the weights.
    Multinomial,
}

fn is_systematic(r: &Resampling) -> bool {
    *r == Resampling::Systematic
}

named_part!(
    /// A fusion protocol's name (`consensus.protocol`).
    ConsensusProtocol,
    Role::Protocol
);

impl ConsensusProtocol {
    /// N_c rounds of average consensus with Metropolis weights.
    pub const AVERAGE: Self = Self::built_in("average");
    /// The exact network sum, as if consensus had converged: for checking.
    pub const EXACT: Self = Self::built_in("exact");
    /// RndEx-PF: a posterior swapped with one random neighbour, then the
    /// closed neighbourhood's measurements.
    pub const RANDOM_EXCHANGE: Self = Self::built_in("random_exchange");
    /// Consensus KL: `rounds` rounds of KL fusion on posteriors weighed
    /// with the node's own measurements only.
    pub const KL_CONSENSUS: Self = Self::built_in("kl_consensus");
    /// Non-iterative KL with local cooperation: the closed neighbourhood's
    /// measurements, then one round of KL fusion (K_max = 1).
    pub const KL_DIFFUSION: Self = Self::built_in("kl_diffusion");
    /// Iterative KL with local cooperation: the closed neighbourhood's
    /// measurements, then `rounds` rounds (K_max).
    pub const KL_ITERATIVE: Self = Self::built_in("kl_iterative");
    /// Average consensus with one round of memory (second-order):
    /// `x(t+1) = (1 + α) W x(t) − α x(t−1)`, α from the graph's λ₂, the
    /// same messages as `average`, fewer of them for the same accuracy.
    pub const SHORT_MEMORY: Self = Self::built_in("short_memory");

    /// What the protocol needs of the network.
    pub fn shape(self) -> Shape {
        self.0.shape
    }

    /// One of the random-exchange and KL trackers: one particle filter per
    /// node, summarized as a Gaussian, rather than the CF/DPF.
    pub fn is_diffusion(self) -> bool {
        matches!(self.shape(), Shape::Tracker { .. })
    }

    /// ML location of a static target over a shared grid, with its CRLB.
    pub const ML_LOCATION: Self = Self::built_in("ml_location");
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConsensusConfig {
    /// Rounds a step; `"auto"` in a file: the fewest that leave at most
    /// `accuracy` of the disagreement on this fusion graph
    /// ([`Scenario::choose_rounds`]), written back as a number.
    pub rounds: u32,
    /// The share of the initial disagreement that the rounds may leave:
    /// what `rounds = "auto"` aims at, and above which `sim` and `run`
    /// warn that the rounds are too few.
    #[serde(default = "default_accuracy")]
    pub accuracy: f64,
    /// How the rounds were chosen, when they were chosen (`"auto"`).
    #[serde(skip)]
    pub chosen: Option<RoundsChoice>,
    pub protocol: ConsensusProtocol,
    /// The protocol's own parameters, which it checks (`node::parts`).
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub params: toml::Table,
    #[serde(default)]
    pub auxiliary_fim: bool,
    pub round_timeout_ms: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockMode {
    Realtime,
    Lockstep,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClockConfig {
    pub mode: ClockMode,
    pub step_period_ms: f64,
    pub step_timeout_ms: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceConfig {
    pub centralized: bool,
}

impl Default for ReferenceConfig {
    fn default() -> Self {
        Self { centralized: true }
    }
}

impl Scenario {
    /// Whether a part the scenario names (its protocol, or its sensor
    /// manager) sends to one chosen neighbour at a time: the network then
    /// opens a channel for each pair of neighbours.
    pub fn talks_in_pairs(&self) -> bool {
        self.consensus.protocol.shape().pairs() || self.sensors.manager.part().shape.pairs()
    }

    /// The built-in default scenario.
    pub fn default_scenario() -> Self {
        Self::from_toml(DEFAULT_SCENARIO, "<built-in default>", &[])
            .expect("the built-in default scenario is valid")
    }

    /// Reads and validates a scenario file, applying `key=value` overrides,
    /// in cqnet's own vocabulary.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self, ScenarioError> {
        Self::load_in(Vocabulary::BUILT_IN, path, overrides)
    }

    /// Reads and validates a scenario file in a program's vocabulary.
    pub fn load_in(
        vocabulary: Vocabulary,
        path: &Path,
        overrides: &[String],
    ) -> Result<Self, ScenarioError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ScenarioError::Read {
            file: file.clone(),
            message: e.to_string(),
        })?;
        let mut scenario = Self::from_toml_in(vocabulary, &text, &file, overrides)?;
        // The keys are where the file says, wherever the program runs.
        if let Some(keys) = scenario.trust.as_mut().and_then(|t| t.keys.as_mut()) {
            if Path::new(keys.as_str()).is_relative() {
                let base = path.parent().unwrap_or(Path::new("."));
                *keys = base.join(keys.as_str()).display().to_string();
            }
        }
        Ok(scenario)
    }

    /// Parses and validates scenario text in cqnet's own vocabulary;
    /// `source` names it in errors.
    pub fn from_toml(
        text: &str,
        source: &str,
        overrides: &[String],
    ) -> Result<Self, ScenarioError> {
        Self::from_toml_in(Vocabulary::BUILT_IN, text, source, overrides)
    }

    /// Parses and validates scenario text in a program's vocabulary: the
    /// parts it names are the program's, and its payloads the program's.
    pub fn from_toml_in(
        vocabulary: Vocabulary,
        text: &str,
        source: &str,
        overrides: &[String],
    ) -> Result<Self, ScenarioError> {
        let mut value: toml::Table = toml::from_str(text).map_err(|e| ScenarioError::Parse {
            file: source.into(),
            message: e.to_string(),
        })?;
        for o in overrides {
            apply_override(&mut value, o)?;
        }
        let parse_error = |message: String| ScenarioError::Parse {
            file: source.into(),
            message,
        };
        let auto_rounds = consensus::take_auto_rounds(&mut value);
        let text = toml::to_string(&value).map_err(|e| parse_error(e.to_string()))?;
        // The path of the value that failed, so that `--set
        // filter.particles=-5` is told `filter.particles`, not only a line
        // of the merged document.
        let deserializer =
            toml::Deserializer::parse(&text).map_err(|e| parse_error(e.to_string()))?;
        let mut scenario: Scenario = vocabulary
            .reading(|| serde_path_to_error::deserialize(deserializer))
            .map_err(|e| {
                let path = e.path().to_string();
                parse_error(format!("`{path}`: {}", e.into_inner().message()))
            })?;
        scenario.vocabulary = vocabulary;
        scenario.validate(source)?;
        if auto_rounds {
            scenario.choose_rounds(source)?;
        }
        Ok(scenario)
    }

    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a scenario always serializes")
    }
}

#[cfg(test)]
mod tests {
    use super::overrides::is_optional_key;
    use super::*;

    #[test]
    fn default_and_sensor_selection_load() {
        let d = Scenario::default_scenario();
        assert_eq!(d.quantizer.bits, 8);
        assert_eq!(d.filter.particles, 1000);
        let s =
            Scenario::from_toml(SENSOR_SELECTION_SCENARIO, "sensor-selection.toml", &[]).unwrap();
        assert_eq!(s.dynamics.turn().unwrap().sigma_v, 0.16);
        assert_eq!(s.sensors.max_active_total, Some(18));
        // Round trip through TOML.
        assert_eq!(Scenario::from_toml(&d.to_toml(), "x", &[]).unwrap(), d);
    }

    #[test]
    fn overrides_change_values_and_reject_unknown_keys() {
        let s = Scenario::from_toml(
            DEFAULT_SCENARIO,
            "d",
            &["quantizer.bits=4".into(), "consensus.protocol=exact".into()],
        )
        .unwrap();
        assert_eq!(s.quantizer.bits, 4);
        assert_eq!(s.consensus.protocol, ConsensusProtocol::EXACT);
        let e = Scenario::from_toml(DEFAULT_SCENARIO, "d", &["quantizer.bitz=4".into()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("bitz"), "{e}");
    }

    /// A value of the wrong type or out of an enum's variants, given with
    /// `--set`, is named by its full key, not only by a line of the merged
    /// document (which says `particles = -5`, not which section).
    #[test]
    fn set_values_that_do_not_parse_name_their_full_key() {
        for (assignment, key) in [
            ("filter.particles=-5", "`filter.particles`"),
            ("observation.kind=\"sonar\"", "`observation.kind`"),
            ("quantizer.bits=\"x\"", "`quantizer.bits`"),
            ("sensors.manager=\"nearest\"", "`sensors.manager`"),
        ] {
            let e = Scenario::from_toml(DEFAULT_SCENARIO, "d", &[assignment.into()])
                .unwrap_err()
                .to_string();
            assert!(e.contains(key), "{assignment}: {e}");
        }
    }

    /// 100 active sensors per node where each node has 25 is refused by
    /// name, not silently capped.
    #[test]
    fn more_active_sensors_than_a_node_has_is_an_error() {
        let s = Scenario::from_toml(
            DEFAULT_SCENARIO,
            "d",
            &["sensors.active_per_node=100".into()],
        )
        .unwrap();
        let e = crate::Topology::from_scenario(&s, "d")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("sensors.active_per_node") && e.contains("25"),
            "{e}"
        );
        let ok = Scenario::from_toml(
            DEFAULT_SCENARIO,
            "d",
            &["sensors.active_per_node=25".into()],
        )
        .unwrap();
        assert!(crate::Topology::from_scenario(&ok, "d").is_ok());
    }

    /// Each broken file fails with a message naming the key that is wrong.
    #[test]
    fn broken_files_name_the_key() {
        let cases: &[(&str, &str, &str)] = &[
            ("bits = 8", "bits = 0", "quantizer.bits"),
            ("grid = [3, 3]", "grid = [1000, 1000]", "nodes.grid"),
            (
                "per_cell = [5, 5]",
                "per_cell = [100, 100]",
                "sensors.per_cell",
            ),
            ("bits = 8", "bits = 40", "quantizer.bits"),
            ("bits = 8", "bits = \"eight\"", "bits"),
            (
                "particles = 1000",
                "particles = 1000\nparticle_count = 5",
                "particle_count",
            ),
            ("sigma_v = 0.05", "sigma_v = -1.0", "dynamics.sigma_v"),
            (
                "[consensus]",
                "[censoring]\npolicy = \"nis\"\nbudget = 4.0\n\n[consensus]",
                "censoring.budget",
            ),
            (
                "[consensus]",
                "[censoring]\npolicy = \"sometimes\"\n\n[consensus]",
                "sometimes",
            ),
            (
                "sigma_v = 0.05",
                "sigma_v = 0.05\nprocess_noise = \"discrete\"",
                "dynamics.process_noise",
            ),
            (
                "sigma_v = 0.05",
                "sigma_v = 0.05\nprocess_noise = \"pink\"",
                "pink",
            ),
            ("radius = 550.0", "radius = 0.0", "fusion_graph.radius"),
            ("rounds = 10", "rounds = 0", "consensus.rounds"),
            ("kind = \"bearing\"", "kind = \"sonar\"", "sonar"),
            (
                "sigma_theta = 0.02",
                "sigma_theta = 0.0",
                "observation.sigma_theta",
            ),
            ("steps = 100", "steps = 0", "steps"),
            ("mode = \"realtime\"", "mode = \"sometimes\"", "sometimes"),
            (
                "active_per_node = 3",
                "active_per_node = 0",
                "sensors.active_per_node",
            ),
            (
                "prior_std = [50.0, 50.0, 2.0, 2.0]",
                "prior_std = [50.0, 50.0, 2.0]",
                "prior_std",
            ),
            (
                "grid = [3, 3]",
                "grid = [3, 3]\npositions = [[0.0, 0.0]]",
                "nodes",
            ),
        ];
        for (from, to, key) in cases {
            assert!(DEFAULT_SCENARIO.contains(from), "{from}");
            let text = DEFAULT_SCENARIO.replacen(from, to, 1);
            let err = Scenario::from_toml(&text, "broken.toml", &[])
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(key),
                "`{to}`: error does not name `{key}`: {err}"
            );
            assert!(
                err.contains("broken.toml"),
                "error does not name the file: {err}"
            );
        }
    }

    /// Every key a scenario may leave out (a serde default) can still be
    /// given with `--set`: the list of optional keys keeps up with the
    /// schema. (`filter.gate` was missing from it.)
    #[test]
    fn every_key_with_a_default_can_be_set() {
        for text in [
            DEFAULT_SCENARIO,
            SENSOR_SELECTION_SCENARIO,
            RANDOM_EXCHANGE_SCENARIO,
            LOCATION_SCENARIO,
        ] {
            keys_left_out_can_be_set(text);
        }
    }

    fn keys_left_out_can_be_set(text: &str) {
        let written: toml::Table = toml::from_str(text).unwrap();
        let scenario = Scenario::from_toml(text, "s", &[]).unwrap();
        let full: toml::Table = toml::from_str(&scenario.to_toml()).unwrap();
        fn leaves(t: &toml::Table, prefix: &str, out: &mut Vec<(String, String)>) {
            for (k, v) in t {
                match v {
                    toml::Value::Table(inner) => leaves(inner, &format!("{prefix}{k}."), out),
                    _ => out.push((format!("{prefix}{k}"), k.clone())),
                }
            }
        }
        let mut all = Vec::new();
        leaves(&full, "", &mut all);
        let mut present = Vec::new();
        leaves(&written, "", &mut present);
        for (path, key) in all {
            if !present.iter().any(|(p, _)| *p == path) {
                assert!(
                    is_optional_key(&key),
                    "`{path}` has a default but --set refuses it"
                );
            }
        }
    }

    /// The random-exchange paper's trackers have no sensor selection, censoring, auxiliary
    /// FIM or gate: asking for one is an error naming the key.
    #[test]
    fn random_exchange_trackers_refuse_the_cf_dpf_parts_by_name() {
        for (set, key) in [
            ("sensors.manager=\"pcrlb\"", "sensors.manager"),
            ("sensors.max_active_total=5", "sensors.max_active_total"),
            ("censoring.policy=\"nis\"", "censoring.policy"),
            ("consensus.auxiliary_fim=true", "consensus.auxiliary_fim"),
            ("filter.gate=10.0", "filter.gate"),
        ] {
            let overrides = [
                "consensus.protocol=\"kl_iterative\"".to_string(),
                set.to_string(),
            ];
            let err = Scenario::from_toml(RANDOM_EXCHANGE_SCENARIO, "s.toml", &overrides)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(key) && err.contains("kl_iterative"),
                "{set}: {err}"
            );
        }
        for protocol in [
            "random_exchange",
            "kl_consensus",
            "kl_diffusion",
            "kl_iterative",
        ] {
            let overrides = [format!("consensus.protocol=\"{protocol}\"")];
            let s = Scenario::from_toml(RANDOM_EXCHANGE_SCENARIO, "s.toml", &overrides).unwrap();
            assert!(s.consensus.protocol.is_diffusion());
        }
    }

    /// A static target goes with the locator and only with it, and the
    /// locator refuses the CF/DPF's parts and a centralized reference by key.
    #[test]
    fn the_locator_and_a_static_target_go_together() {
        for (set, key) in [
            ("sensors.manager=\"pcrlb\"", "sensors.manager"),
            ("censoring.policy=\"nis\"", "censoring.policy"),
            ("reference.centralized=true", "reference.centralized"),
            ("quantizer.bits=5", "quantizer.bits"),
            ("target.motion=\"moving\"", "target.motion"),
            ("consensus.protocol=\"average\"", "consensus.protocol"),
        ] {
            let err = Scenario::from_toml(LOCATION_SCENARIO, "l.toml", &[set.to_string()])
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(key) && err.contains("ml_location"),
                "{set}: {err}"
            );
        }
        let s = Scenario::from_toml(LOCATION_SCENARIO, "l.toml", &[]).unwrap();
        assert_eq!(s.target.motion, Motion::Static);
        assert_eq!(s.consensus.protocol, ConsensusProtocol::ML_LOCATION);
    }

    #[test]
    fn broken_faults_name_the_key() {
        let text = format!("{DEFAULT_SCENARIO}\n[[faults]]\nkind = \"loss\"\nlinks = [{{ from = \"*\", to = \"*\" }}]\nat_step = 5\nprobability = 1.5\n");
        let err = Scenario::from_toml(&text, "f.toml", &[])
            .unwrap_err()
            .to_string();
        assert!(err.contains("faults[0].probability"), "{err}");
        let text = format!("{DEFAULT_SCENARIO}\n[[faults]]\nkind = \"kill\"\nactor = \"node-4\"\nat_step = 500\nsignal = \"SIGKILL\"\n");
        let err = Scenario::from_toml(&text, "f.toml", &[])
            .unwrap_err()
            .to_string();
        assert!(err.contains("faults[0].at_step"), "{err}");
    }

    #[test]
    fn initial_state_follows_course_from_north() {
        let t = TargetConfig {
            position: [0.0, 0.0],
            course_deg: 90.0,
            speed: 10.0,
            start: TargetStart::Fixed,
            motion: Motion::Moving,
        };
        let s = t.initial_state();
        assert!((s[2] - 10.0).abs() < 1e-12 && s[3].abs() < 1e-12);
    }
}
