//! The parts a program hands to cqnet: what each name a scenario may give
//! in `consensus.protocol` and `sensors.manager` builds, what it needs of
//! the network, and the payloads its messages carry.
//!
//! A program lists its parts in one value, [`Parts`], and cqnet's own
//! parts go through the same list ([`Parts::new`] starts with them). There
//! is no table in the process: the value's [`Vocabulary`] is what the
//! program's scenarios are read in, and a scenario carries it to every
//! node it builds, so two programs' parts can live side by side (as they
//! do in tests). Each part is a factory, called once per node, that
//! declares what the network must give it:
//!
//! - a fusion protocol of the CF/DPF ([`ProtocolFactory`]): rounds over
//!   the consensus channels, and, if its [`Needs`] say so, a channel per
//!   pair of neighbours for sends to one chosen neighbour;
//! - a node of a kind of its own ([`NodeFactory`]): a tracker or a
//!   locator, with its own step, built around the node core;
//! - a sensor manager ([`ManagerFactory`]);
//! - an observation law ([`LawFactory`]), chosen by `[observation] kind`,
//!   and a motion model ([`MotionFactory`]), chosen by `[dynamics] kind`:
//!   built as the scenario is read, from their own keys of those tables.
//!
//! Every part reads its parameters the same way: what every protocol has
//! (`consensus.rounds`, `consensus.round_timeout_ms`,
//! `consensus.auxiliary_fim`) from [`Setup`], what only it has from
//! [`Params`] (`[consensus.params]`, `[sensors.manager_params]`).

mod built_in;
mod params;

pub use built_in::location_config;
pub use params::{ParamError, Params, Setup};

use std::sync::OnceLock;

pub use fusion_graph::vocabulary::{LawFactory, MotionFactory};
use fusion_graph::vocabulary::{LawPart, MotionPart, Part, Role, Shape, Vocabulary};
use fusion_graph::{Scenario, Topology};
use wire::payloads::{PayloadEntry, Payloads, ProtocolPayload, RegisterError};

use crate::fusion::{Fused, FusionProtocol, Handled, InformationFusion, InformationVector};
use crate::sensor_manager::Manager;
use crate::{AnyNode, NodeError, Start};

/// What a protocol or a negotiated sensor manager needs of the network
/// beyond messages to every neighbour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Needs {
    /// Sends to one chosen neighbour at a time: the network opens a
    /// channel for each pair of neighbours, and a message to one of them
    /// crosses only that link.
    pub pairs: bool,
}

impl Needs {
    /// Every message goes to every neighbour.
    pub const BROADCAST: Self = Self { pairs: false };
    /// Messages to one chosen neighbour, over the pair's own channel.
    pub const POINT_TO_POINT: Self = Self { pairs: true };
}

/// The parts of the information vector beyond the estimate's and ΔL that
/// a protocol carries to its neighbours.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Carries {
    /// ΔL_late, the information of observations that arrived a step late.
    pub late: bool,
    /// `S_obs`, the auxiliary-FIM baseline's second sum.
    pub s_obs: bool,
}

/// Builds a CF/DPF node's fusion protocol. A function
/// `Fn(&Setup) -> Result<InformationFusion, ParamError>` is one that only
/// broadcasts and carries neither ΔL_late nor `S_obs`.
pub trait ProtocolFactory: Send + Sync + 'static {
    /// What the protocol needs of the network.
    fn needs(&self) -> Needs {
        Needs::BROADCAST
    }

    /// What it carries beyond the estimate and ΔL. What it does not carry
    /// is taken care of for it: the node hands it a vector whose ΔL_late
    /// is zero (so its bound does not credit late observations, rather
    /// than mix a part its messages never held), and a scenario asking
    /// for the auxiliary FIM is refused by key.
    fn carries(&self) -> Carries {
        Carries::default()
    }

    /// The protocol of node `setup.node`.
    fn build(&self, setup: &Setup<'_>) -> Result<InformationFusion, ParamError>;
}

impl<F> ProtocolFactory for F
where
    F: Fn(&Setup<'_>) -> Result<InformationFusion, ParamError> + Send + Sync + 'static,
{
    fn build(&self, setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
        self(setup)
    }
}

/// Builds a node of a kind of its own (a tracker, a locator), chosen by
/// `consensus.protocol` as a fusion protocol is. A pair `(shape, f)` of a
/// [`Shape`] and a function `Fn(&Setup, Start) -> Result<AnyNode,
/// NodeError>` is one.
pub trait NodeFactory: Send + Sync + 'static {
    /// What the node is to the network: [`Shape::Tracker`] (with `pairs`
    /// if it talks to one neighbour at a time) or [`Shape::Locator`].
    fn shape(&self) -> Shape;

    /// Node `setup.node`, starting so.
    fn build(&self, setup: &Setup<'_>, start: Start) -> Result<AnyNode, NodeError>;
}

/// A node kind's factory as a plain function, to pair with its [`Shape`].
pub type BuildNode = fn(&Setup<'_>, Start) -> Result<AnyNode, NodeError>;

impl<F> NodeFactory for (Shape, F)
where
    F: Fn(&Setup<'_>, Start) -> Result<AnyNode, NodeError> + Send + Sync + 'static,
{
    fn shape(&self) -> Shape {
        self.0
    }

    fn build(&self, setup: &Setup<'_>, start: Start) -> Result<AnyNode, NodeError> {
        (self.1)(setup, start)
    }
}

/// Builds a node's sensor manager. A function `Fn(&Setup) ->
/// Result<Manager, ParamError>` is one.
pub trait ManagerFactory: Send + Sync + 'static {
    /// What the manager needs of the network: a negotiated manager that
    /// sends to one chosen neighbour at a time (its parent in a tree, say)
    /// rather than to every neighbour asks for
    /// [`Needs::POINT_TO_POINT`].
    fn needs(&self) -> Needs {
        Needs::BROADCAST
    }

    fn build(&self, setup: &Setup<'_>) -> Result<Manager, ParamError>;
}

impl<F> ManagerFactory for F
where
    F: Fn(&Setup<'_>) -> Result<Manager, ParamError> + Send + Sync + 'static,
{
    fn build(&self, setup: &Setup<'_>) -> Result<Manager, ParamError> {
        self(setup)
    }
}

/// What a part's name builds, as the vocabulary carries it.
enum Builder {
    Protocol(Box<dyn ProtocolFactory>),
    /// `sim`'s oracle of exact sums: built by the driver, not here.
    ExactSums,
    Node(Box<dyn NodeFactory>),
    Manager(Box<dyn ManagerFactory>),
}

/// Why a part could not be added.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PartsError {
    #[error("{role} {name:?} is built in or listed already")]
    Taken { role: &'static str, name: String },
    #[error("{role} {name:?}: a name is lowercase letters, digits and '_'")]
    BadName { role: &'static str, name: String },
    #[error("{role} {name:?}: a node of its own is a tracker or a locator, not {shape:?}")]
    BadShape {
        role: &'static str,
        name: String,
        shape: Shape,
    },
    #[error(transparent)]
    Payload(#[from] RegisterError),
}

/// The kinds cqnet's own motion models go by.
const BUILT_IN_MOTIONS: [&str; 1] = [bounds::CoordinatedTurn::KIND];

/// A program's parts: cqnet's own, then those it adds, and the payloads
/// its protocols send. Built by chaining; a mistake (a name taken twice,
/// a payload that does not fit) is kept and reported by
/// [`vocabulary`](Self::vocabulary), so that the chain reads as a list.
pub struct Parts {
    parts: Vec<Part>,
    payloads: Vec<PayloadEntry>,
    laws: Vec<LawPart>,
    motions: Vec<MotionPart>,
    error: Option<PartsError>,
    vocabulary: OnceLock<Vocabulary>,
}

impl Default for Parts {
    fn default() -> Self {
        Self::new()
    }
}

impl Parts {
    /// cqnet's own parts.
    pub fn new() -> Self {
        built_in::add(Self {
            parts: Vec::new(),
            payloads: Vec::new(),
            laws: Vec::new(),
            motions: Vec::new(),
            error: None,
            vocabulary: OnceLock::new(),
        })
    }

    /// A fusion protocol of the CF/DPF, chosen by `consensus.protocol =
    /// "name"`.
    pub fn protocol(self, name: &'static str, factory: impl ProtocolFactory) -> Self {
        let shape = Shape::Rounds {
            pairs: factory.needs().pairs,
        };
        self.add(
            Role::Protocol,
            name,
            shape,
            Builder::Protocol(Box::new(factory)),
        )
    }

    /// A node of a kind of its own (a tracker, a locator), chosen by
    /// `consensus.protocol = "name"`.
    pub fn node(self, name: &'static str, factory: impl NodeFactory) -> Self {
        let shape = factory.shape();
        if !matches!(shape, Shape::Tracker { .. } | Shape::Locator) {
            let error = PartsError::BadShape {
                role: Role::Protocol.what(),
                name: name.into(),
                shape,
            };
            return self.fail(error);
        }
        self.add(
            Role::Protocol,
            name,
            shape,
            Builder::Node(Box::new(factory)),
        )
    }

    /// A sensor manager, chosen by `sensors.manager = "name"`.
    pub fn manager(self, name: &'static str, factory: impl ManagerFactory) -> Self {
        let shape = Shape::Rounds {
            pairs: factory.needs().pairs,
        };
        let builder = Builder::Manager(Box::new(factory));
        self.add(Role::Manager, name, shape, builder)
    }

    /// A payload a protocol sends: the program gives it the next kind
    /// byte. A protocol finds its kind with [`Setup::payload`].
    pub fn payload<P: ProtocolPayload>(mut self) -> Self {
        match PayloadEntry::next::<P>(&self.payloads) {
            Ok(entry) => {
                self.payloads.push(entry);
                self.vocabulary = OnceLock::new();
                self
            }
            Err(e) => self.fail(e.into()),
        }
    }

    /// An observation law, chosen by `[observation] kind = "name"` and
    /// built from the table's other keys.
    pub fn law(mut self, name: &'static str, factory: impl LawFactory) -> Self {
        const ROLE: &str = "observation law";
        let taken =
            bounds::SensorLaw::KINDS.contains(&name) || self.laws.iter().any(|l| l.name == name);
        if let Err(e) = check_name(ROLE, name, taken) {
            return self.fail(e);
        }
        let build: &'static dyn LawFactory = Box::leak(Box::new(factory));
        self.laws.push(LawPart { name, build });
        self.vocabulary = OnceLock::new();
        self
    }

    /// A motion model, chosen by `[dynamics] kind = "name"` and built
    /// from `dynamics.period` and the table's other keys.
    pub fn motion(mut self, name: &'static str, factory: impl MotionFactory) -> Self {
        const ROLE: &str = "motion model";
        let taken = BUILT_IN_MOTIONS.contains(&name) || self.motions.iter().any(|m| m.name == name);
        if let Err(e) = check_name(ROLE, name, taken) {
            return self.fail(e);
        }
        let build: &'static dyn MotionFactory = Box::leak(Box::new(factory));
        self.motions.push(MotionPart { name, build });
        self.vocabulary = OnceLock::new();
        self
    }

    fn exact_sums(self, name: &'static str) -> Self {
        self.add(Role::Protocol, name, Shape::ExactSums, Builder::ExactSums)
    }

    fn add(mut self, role: Role, name: &'static str, shape: Shape, builder: Builder) -> Self {
        let taken = self.parts.iter().any(|p| p.role == role && p.name == name);
        if let Err(e) = check_name(role.what(), name, taken) {
            return self.fail(e);
        }
        // Kept as long as the program: the vocabulary lends it to every
        // scenario read in it.
        let build: &'static Builder = Box::leak(Box::new(builder));
        self.parts.push(Part {
            role,
            name,
            shape,
            build: Some(build),
        });
        self.vocabulary = OnceLock::new();
        self
    }

    fn fail(mut self, error: PartsError) -> Self {
        self.error.get_or_insert(error);
        self
    }

    /// What the program's scenarios are read in, or the first mistake in
    /// the list.
    pub fn vocabulary(&self) -> Result<Vocabulary, PartsError> {
        if let Some(e) = &self.error {
            return Err(e.clone());
        }
        Ok(*self.vocabulary.get_or_init(|| {
            let payloads = Payloads::new(self.payloads.clone());
            Vocabulary::new(
                self.parts.clone(),
                payloads,
                self.laws.clone(),
                self.motions.clone(),
            )
        }))
    }
}

fn check_name(role: &'static str, name: &'static str, taken: bool) -> Result<(), PartsError> {
    if !valid_name(name) {
        let name = name.into();
        return Err(PartsError::BadName { role, name });
    }
    if taken {
        let name = name.into();
        return Err(PartsError::Taken { role, name });
    }
    Ok(())
}

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
}

/// What builds `part`: the program's factory, or, for a scenario read in
/// cqnet's own vocabulary (whose parts carry none), cqnet's own.
fn builder(part: &Part) -> &'static Builder {
    static BUILT_IN: OnceLock<Vocabulary> = OnceLock::new();
    let part = match part.build {
        Some(_) => part,
        None => BUILT_IN
            .get_or_init(|| Parts::new().vocabulary().expect("cqnet's own parts list"))
            .part(part.role, part.name)
            .expect("a built-in name has a built-in part"),
    };
    part.build
        .and_then(|b| b.downcast_ref::<Builder>())
        .expect("a part of a Parts list carries its Builder")
}

fn setup<'a>(
    scenario: &'a Scenario,
    topology: &'a Topology,
    node: u16,
    params: Params<'a>,
) -> Setup<'a> {
    Setup {
        scenario,
        topology,
        node,
        params,
    }
}

fn protocol_params(scenario: &Scenario) -> Params<'_> {
    Params::new("consensus.params", &scenario.consensus.params)
}

/// The CF/DPF's fusion protocol the scenario names, for node `node`;
/// `None` for a protocol of another shape (exact sums come from `sim`'s
/// oracle, and a node of its own is [`node_of_its_own`]'s).
pub fn information_fusion(
    scenario: &Scenario,
    topology: &Topology,
    node: u16,
) -> Result<Option<InformationFusion>, ParamError> {
    let params = protocol_params(scenario);
    match builder(scenario.consensus.protocol.part()) {
        Builder::Protocol(factory) => {
            let carries = factory.carries();
            if scenario.consensus.auxiliary_fim && !carries.s_obs {
                return Err(ParamError {
                    key: "consensus.auxiliary_fim".into(),
                    expected: format!(
                        "false: `{}` carries no S_obs",
                        scenario.consensus.protocol.name()
                    ),
                    got: "true".into(),
                });
            }
            let protocol = factory.build(&setup(scenario, topology, node, params))?;
            Ok(Some(if carries.late {
                protocol
            } else {
                Box::new(WithoutLate(protocol))
            }))
        }
        Builder::ExactSums => params.only(&[]).map(|()| None),
        Builder::Node(_) | Builder::Manager(_) => Ok(None),
    }
}

/// A protocol that carries no ΔL_late, handed vectors without it.
struct WithoutLate(InformationFusion);

impl FusionProtocol for WithoutLate {
    type Value = InformationVector;
    type Output = Fused;

    fn expect_step(&mut self, step: u32) {
        self.0.expect_step(step)
    }

    fn start(
        &mut self,
        step: u32,
        value: InformationVector,
        view: &[bool],
        now: std::time::Duration,
        out: &mut Vec<crate::Outgoing>,
    ) {
        let value = InformationVector {
            delta_l_late: [0.0; 10],
            ..value
        };
        self.0.start(step, value, view, now, out)
    }

    fn handle(
        &mut self,
        message: &wire::Message,
        now: std::time::Duration,
        out: &mut Vec<crate::Outgoing>,
    ) -> Handled {
        self.0.handle(message, now, out)
    }

    fn poll_timeout(&self) -> Option<std::time::Duration> {
        self.0.poll_timeout()
    }

    fn handle_timeout(&mut self, now: std::time::Duration, out: &mut Vec<crate::Outgoing>) {
        self.0.handle_timeout(now, out)
    }

    fn poll_result(&mut self) -> Option<Fused> {
        self.0.poll_result()
    }

    fn finish_now(
        &mut self,
        now: std::time::Duration,
        out: &mut Vec<crate::Outgoing>,
    ) -> Option<Fused> {
        self.0.finish_now(now, out)
    }
}

/// Node `node`, if the scenario's `consensus.protocol` names a node of a
/// kind of its own (a tracker, a locator).
pub fn node_of_its_own(
    scenario: &Scenario,
    topology: &Topology,
    node: u16,
    start: Start,
) -> Result<Option<AnyNode>, NodeError> {
    match builder(scenario.consensus.protocol.part()) {
        Builder::Node(factory) => {
            let params = protocol_params(scenario);
            factory
                .build(&setup(scenario, topology, node, params), start)
                .map(Some)
        }
        _ => Ok(None),
    }
}

/// The sensor manager the scenario names, for node `node`.
pub fn manager(scenario: &Scenario, topology: &Topology, node: u16) -> Result<Manager, ParamError> {
    let Builder::Manager(factory) = builder(scenario.sensors.manager.part()) else {
        unreachable!("a manager's name builds a manager")
    };
    let params = Params::new("sensors.manager_params", &scenario.sensors.manager_params);
    factory.build(&setup(scenario, topology, node, params))
}

/// Checks the scenario's choice of protocol and manager and their
/// parameters by building both for every node, so that a bad parameter is
/// refused before any process starts, naming its key.
pub fn check(scenario: &Scenario, topology: &Topology) -> Result<(), NodeError> {
    for node in 0..topology.nodes() as u16 {
        information_fusion(scenario, topology, node)?;
        node_of_its_own(scenario, topology, node, Start::default())?;
        manager(scenario, topology, node)?;
    }
    Ok(())
}
#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::scenario::DEFAULT_SCENARIO;
    use std::time::Duration;

    use crate::fusion::average_consensus;

    fn scenario_in(vocabulary: Vocabulary, overrides: &[&str]) -> Result<Scenario, String> {
        let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        Scenario::from_toml_in(vocabulary, DEFAULT_SCENARIO, "d", &overrides)
            .map_err(|e| e.to_string())
    }

    fn scenario(overrides: &[&str]) -> Result<Scenario, String> {
        scenario_in(Vocabulary::BUILT_IN, overrides)
    }

    fn alone(setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
        setup.params.only(&["gain"])?;
        setup.params.number("gain", 0.0..=1.0, 0.5)?;
        Ok(Box::new(average_consensus(
            setup.node,
            setup.topology,
            1,
            Duration::from_millis(50),
            false,
        )))
    }

    #[test]
    fn the_locators_parameters_are_named_by_key() {
        let location = |set: &str| {
            Scenario::from_toml(
                fusion_graph::scenario::LOCATION_SCENARIO,
                "l",
                &[set.to_string()],
            )
            .map_err(|e| e.to_string())
        };
        for (set, key) in [
            (
                "consensus.params.thresholds=\"optimal\"",
                "consensus.params.thresholds",
            ),
            ("consensus.params.grid_x=2", "consensus.params.grid_x"),
            (
                "consensus.params.refinements=9",
                "consensus.params.refinements",
            ),
            ("consensus.params.zoom=2", "consensus.params.zoom"),
        ] {
            let s = location(set).unwrap();
            let e = location_config(&s).unwrap_err();
            assert_eq!(e.key, key, "{set}");
        }
        let s = location("consensus.params.refinements=1").unwrap();
        assert_eq!(location_config(&s).unwrap().refinements, 1);
    }

    #[test]
    fn a_programs_protocol_is_named_by_its_scenarios_and_checks_its_parameters() {
        let unknown = scenario(&["consensus.protocol=\"parts_test\""]).unwrap_err();
        assert!(
            unknown.contains("consensus.protocol") && unknown.contains("`average`"),
            "{unknown}"
        );
        let parts = Parts::new().protocol("parts_test", alone);
        let vocabulary = parts.vocabulary().unwrap();
        let s = scenario_in(
            vocabulary,
            &[
                "consensus.protocol=\"parts_test\"",
                "consensus.params.gain=0.25",
            ],
        )
        .unwrap();
        assert!(!s.consensus.protocol.is_built_in());
        assert_eq!(s.consensus.protocol.name(), "parts_test");
        let topology = Topology::from_scenario(&s, "d").unwrap();
        check(&s, &topology).unwrap();
        // The scenario a launcher writes for its children reads back the
        // same in the same program, and not in another.
        assert_eq!(
            Scenario::from_toml_in(vocabulary, &s.to_toml(), "child", &[]).unwrap(),
            s
        );
        assert!(Scenario::from_toml(&s.to_toml(), "other", &[]).is_err());
        for (set, key) in [
            ("consensus.params.gain=9", "consensus.params.gain"),
            ("consensus.params.gain=\"x\"", "consensus.params.gain"),
            ("consensus.params.other=1", "consensus.params.other"),
        ] {
            let bad = scenario_in(vocabulary, &["consensus.protocol=\"parts_test\"", set]).unwrap();
            let NodeError::Param(err) = check(&bad, &topology).unwrap_err() else {
                panic!("{set}: not a parameter's error");
            };
            assert_eq!(err.key, key, "{set}: {err}");
        }
    }

    #[test]
    fn two_programs_parts_live_side_by_side_and_a_name_is_taken_once() {
        let one = Parts::new().protocol("mine", alone).vocabulary().unwrap();
        let two = Parts::new().manager("mine", |_: &Setup<'_>| -> Result<Manager, ParamError> {
            unreachable!("never built here")
        });
        let two = two.vocabulary().unwrap();
        assert!(scenario_in(one, &["consensus.protocol=\"mine\""]).is_ok());
        assert!(scenario_in(two, &["consensus.protocol=\"mine\""]).is_err());
        assert!(matches!(
            Parts::new()
                .protocol("mine", alone)
                .protocol("mine", alone)
                .vocabulary(),
            Err(PartsError::Taken { .. })
        ));
        assert!(matches!(
            Parts::new().protocol("average", alone).vocabulary(),
            Err(PartsError::Taken { .. })
        ));
        assert!(matches!(
            Parts::new().protocol("Bad-Name", alone).vocabulary(),
            Err(PartsError::BadName { .. })
        ));
    }

    /// A manager that sends to one chosen neighbour at a time gets a
    /// channel for each pair of neighbours, as a protocol does.
    #[test]
    fn a_manager_that_talks_in_pairs_gets_the_pairs_channels() {
        struct InPairs;
        impl ManagerFactory for InPairs {
            fn needs(&self) -> Needs {
                Needs::POINT_TO_POINT
            }

            fn build(&self, setup: &Setup<'_>) -> Result<Manager, ParamError> {
                let scoring = crate::sensor_manager::Scoring::Conditional;
                let m = crate::sensor_manager::negotiated(
                    setup.scenario,
                    setup.topology,
                    setup.node,
                    scoring,
                );
                Ok(m)
            }
        }
        let vocabulary = Parts::new()
            .manager("in_pairs", InPairs)
            .vocabulary()
            .unwrap();
        let plain = scenario(&[]).unwrap();
        let s = scenario_in(vocabulary, &["sensors.manager=\"in_pairs\""]).unwrap();
        assert!(!plain.talks_in_pairs() && s.talks_in_pairs());
        let topology = Topology::from_scenario(&s, "d").unwrap();
        let pair_reads = |scenario: &Scenario| {
            let node = crate::processing_node(scenario, &topology, 4, Start::default()).unwrap();
            let wiring = crate::Actor::wiring(&node);
            wiring
                .reads
                .iter()
                .filter(|c| matches!(c, fusion_graph::Channel::Pair { to: 4, .. }))
                .count()
        };
        assert_eq!(pair_reads(&plain), 0);
        assert_eq!(pair_reads(&s), topology.neighbours[4].len());
    }

    /// A law or a motion model takes a name of its own: not a built-in
    /// kind, not one listed already, and a name a scenario can spell.
    #[test]
    fn a_law_or_a_model_takes_a_name_of_its_own() {
        let law = |_: &Params<'_>| -> Result<bounds::Law, ParamError> { unreachable!() };
        let motion =
            |_: f64, _: &Params<'_>| -> Result<bounds::Motion, ParamError> { unreachable!() };
        let taken = |parts: Parts| matches!(parts.vocabulary(), Err(PartsError::Taken { .. }));
        assert!(taken(Parts::new().law("bearing", law)));
        assert!(taken(Parts::new().law("range", law).law("range", law)));
        assert!(taken(Parts::new().motion("coordinated_turn", motion)));
        assert!(matches!(
            Parts::new().law("Range", law).vocabulary(),
            Err(PartsError::BadName { .. })
        ));
        let v = Parts::new()
            .law("range", law)
            .motion("ou", motion)
            .vocabulary()
            .unwrap();
        assert_eq!(v.law_names().collect::<Vec<_>>(), ["range"]);
        assert_eq!(v.motion_names().collect::<Vec<_>>(), ["ou"]);
        assert_ne!(v, Vocabulary::BUILT_IN);
    }

    /// cqnet's own parts are the scenario format's vocabulary, name for
    /// name and shape for shape.
    #[test]
    fn the_built_in_parts_are_the_formats_vocabulary() {
        assert_eq!(Parts::new().vocabulary().unwrap(), Vocabulary::BUILT_IN);
    }

    #[test]
    fn built_in_parts_take_no_parameters() {
        let s = scenario(&["consensus.params.rounds=3"]).unwrap();
        let topology = Topology::from_scenario(&s, "d").unwrap();
        let key = |e: NodeError| match e {
            NodeError::Param(e) => e.key,
            e => panic!("{e}"),
        };
        assert_eq!(
            key(check(&s, &topology).unwrap_err()),
            "consensus.params.rounds"
        );
        let s = scenario(&["sensors.manager_params.k=3"]).unwrap();
        assert_eq!(
            key(check(&s, &topology).unwrap_err()),
            "sensors.manager_params.k"
        );
        check(&scenario(&[]).unwrap(), &topology).unwrap();
    }

    #[test]
    fn scoring_by_the_auxiliary_fim_needs_the_auxiliary_fim() {
        let s = scenario(&["sensors.manager=pcrlb_aux", "sensors.max_active_total=4"]).unwrap();
        let topology = Topology::from_scenario(&s, "d").unwrap();
        match check(&s, &topology).unwrap_err() {
            NodeError::Param(e) => {
                assert_eq!(e.key, "consensus.auxiliary_fim");
                assert!(e.expected.contains("pcrlb_aux"), "{}", e.expected);
            }
            e => panic!("{e}"),
        }
        let s = scenario(&[
            "sensors.manager=pcrlb_aux",
            "sensors.max_active_total=4",
            "consensus.auxiliary_fim=true",
        ])
        .unwrap();
        check(&s, &topology).unwrap();
    }
}
