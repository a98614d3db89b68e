//! The registry of fusion protocols and sensor managers: what each name a
//! scenario may give in `consensus.protocol` and `sensors.manager` builds,
//! and how its own parameters (`[consensus.params]`,
//! `[sensors.manager_params]`) are checked.
//!
//! The built-in parts are registered here; a program adds its own at
//! start-up, before it reads a scenario, with [`register_protocol`],
//! [`register_manager`] and, for a protocol's own messages,
//! [`register_payload`]. The actors of a run are the same program, so
//! they register the same parts. `examples/toy-protocol` is a whole
//! program that does it.

use std::collections::BTreeMap;
use std::sync::{LazyLock, RwLock};
use std::time::Duration;

use fusion_graph::registered::{self, Role, Shape};
use fusion_graph::{Scenario, Topology};
use wire::payloads::{ProtocolKind, ProtocolPayload, RegisterError};

use crate::fusion::{average_consensus, InformationFusion};
use crate::location::{LocationConfig, ThresholdDesign};
use crate::nodes::trackers::{ExchangeCooperation, KlCooperation, Tracker};
use crate::sensor_manager::{self, Closest, Manager, OfflinePcrlb, Scoring, UniformRandom};

/// What a protocol or manager is built from: the run's scenario and
/// topology, the node it serves, and its own parameters.
pub struct Setup<'a> {
    pub scenario: &'a Scenario,
    pub topology: &'a Topology,
    pub node: u16,
    pub params: Params<'a>,
}

/// A part's own parameters, read with errors that name the full key.
#[derive(Debug, Clone, Copy)]
pub struct Params<'a> {
    /// Where the table sits in the scenario: `consensus.params`, say.
    section: &'static str,
    table: &'a toml::Table,
}

/// A parameter that is missing, of the wrong type, out of range or unknown.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{key}`: expected {expected}, got {got}")]
pub struct ParamError {
    /// The full key, `consensus.params.rounds` say.
    pub key: String,
    pub expected: String,
    pub got: String,
}

impl<'a> Params<'a> {
    pub fn new(section: &'static str, table: &'a toml::Table) -> Self {
        Self { section, table }
    }

    /// A parameter's full key, for an error of the caller's own.
    pub fn key(&self, name: &str) -> String {
        format!("{}.{name}", self.section)
    }

    /// The error for parameter `name`.
    pub fn error(&self, name: &str, expected: &str, got: impl ToString) -> ParamError {
        ParamError {
            key: self.key(name),
            expected: expected.into(),
            got: got.to_string(),
        }
    }

    /// Refuses any parameter not in `known`.
    pub fn only(&self, known: &[&str]) -> Result<(), ParamError> {
        match self.table.keys().find(|k| !known.contains(&k.as_str())) {
            None => Ok(()),
            Some(k) if known.is_empty() => Err(self.error(k, "no parameters", "one")),
            Some(k) => Err(self.error(k, &format!("one of {known:?}"), "an unknown key")),
        }
    }

    /// An integer parameter in `range`, or `default` when absent.
    pub fn integer(
        &self,
        name: &str,
        range: std::ops::RangeInclusive<i64>,
        default: i64,
    ) -> Result<i64, ParamError> {
        let expected = || format!("an integer in {}..={}", range.start(), range.end());
        match self.table.get(name) {
            None => Ok(default),
            Some(toml::Value::Integer(v)) if range.contains(v) => Ok(*v),
            Some(v) => Err(self.error(name, &expected(), v)),
        }
    }

    /// A string parameter, or `default` when absent.
    pub fn text(&self, name: &str, default: &'a str) -> Result<&'a str, ParamError> {
        match self.table.get(name) {
            None => Ok(default),
            Some(toml::Value::String(v)) => Ok(v.as_str()),
            Some(v) => Err(self.error(name, "a string", v)),
        }
    }

    /// A finite number in `range`, or `default` when absent.
    pub fn number(
        &self,
        name: &str,
        range: std::ops::RangeInclusive<f64>,
        default: f64,
    ) -> Result<f64, ParamError> {
        let expected = || format!("a number in {}..={}", range.start(), range.end());
        let v = match self.table.get(name) {
            None => return Ok(default),
            Some(toml::Value::Float(v)) => *v,
            Some(toml::Value::Integer(v)) => *v as f64,
            Some(v) => return Err(self.error(name, &expected(), v)),
        };
        if v.is_finite() && range.contains(&v) {
            Ok(v)
        } else {
            Err(self.error(name, &expected(), v))
        }
    }
}

/// Builds a node's fusion protocol.
pub type ProtocolBuilder = fn(&Setup<'_>) -> Result<InformationFusion, ParamError>;
/// Builds a node's sensor manager.
pub type ManagerBuilder = fn(&Setup<'_>) -> Result<Manager, ParamError>;
/// Builds a tracker node's cooperation (the random-exchange and KL trackers).
type TrackerBuilder = fn(&Setup<'_>) -> Result<Tracker, ParamError>;

/// Why a registration or a scenario's choice was refused.
#[derive(Debug, thiserror::Error)]
pub enum RegistryError {
    #[error("{role} {name:?} is built in or registered already")]
    Taken { role: &'static str, name: String },
    #[error("{role} {name:?}: a name is lowercase letters, digits and '_'")]
    BadName { role: &'static str, name: String },
    #[error(transparent)]
    Payload(#[from] RegisterError),
    #[error(transparent)]
    Param(#[from] ParamError),
}

/// What every name builds: the parts cqnet ships, then the program's.
struct Parts {
    protocols: BTreeMap<&'static str, ProtocolBuilder>,
    trackers: BTreeMap<&'static str, TrackerBuilder>,
    managers: BTreeMap<&'static str, ManagerBuilder>,
}

impl Parts {
    fn built_in() -> Self {
        let protocols = BTreeMap::from([("average", average as ProtocolBuilder)]);
        let trackers = BTreeMap::from([
            ("random_exchange", random_exchange as TrackerBuilder),
            ("kl_consensus", kl_consensus),
            ("kl_diffusion", kl_diffusion),
            ("kl_iterative", kl_iterative),
        ]);
        let managers = BTreeMap::from([
            ("random", random as ManagerBuilder),
            ("closest", closest),
            ("pcrlb", pcrlb),
            ("pcrlb_at_estimate", pcrlb_at_estimate),
            ("pcrlb_offline", pcrlb_offline),
        ]);
        Self {
            protocols,
            trackers,
            managers,
        }
    }
}

static PARTS: LazyLock<RwLock<Parts>> = LazyLock::new(|| RwLock::new(Parts::built_in()));

fn parts() -> std::sync::RwLockReadGuard<'static, Parts> {
    PARTS.read().unwrap_or_else(|p| p.into_inner())
}

// The built-in parts take no parameters.

fn average(setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
    setup.params.only(&[])?;
    let c = &setup.scenario.consensus;
    Ok(Box::new(
        average_consensus(
            setup.node,
            setup.topology,
            c.rounds as u16,
            Duration::from_secs_f64(c.round_timeout_ms / 1e3),
            c.auxiliary_fim,
        )
        .stop_awaiting_the_late(),
    ))
}

fn random_exchange(setup: &Setup<'_>) -> Result<Tracker, ParamError> {
    setup.params.only(&[])?;
    Ok(Tracker::Exchange(Box::new(ExchangeCooperation::new(
        setup.scenario,
        setup.topology,
        setup.node,
    ))))
}

fn kl_consensus(setup: &Setup<'_>) -> Result<Tracker, ParamError> {
    kl(setup, setup.scenario.consensus.rounds, false)
}

fn kl_diffusion(setup: &Setup<'_>) -> Result<Tracker, ParamError> {
    kl(setup, 1, true)
}

fn kl_iterative(setup: &Setup<'_>) -> Result<Tracker, ParamError> {
    kl(setup, setup.scenario.consensus.rounds, true)
}

fn kl(setup: &Setup<'_>, rounds: u32, neighbourhood: bool) -> Result<Tracker, ParamError> {
    setup.params.only(&[])?;
    Ok(Tracker::Kl(Box::new(KlCooperation::new(
        setup.scenario,
        setup.topology,
        setup.node,
        rounds,
        neighbourhood,
    ))))
}

fn random(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(Manager::Alone(Box::new(UniformRandom::for_scenario(
        setup.scenario,
    ))))
}

fn closest(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(Manager::Alone(Box::new(Closest::for_scenario(
        setup.scenario,
    ))))
}

fn pcrlb(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(sensor_manager::negotiated(
        setup.scenario,
        setup.topology,
        setup.node,
        Scoring::Conditional,
    ))
}

fn pcrlb_at_estimate(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(sensor_manager::negotiated(
        setup.scenario,
        setup.topology,
        setup.node,
        Scoring::AtEstimate,
    ))
}

fn pcrlb_offline(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    let manager =
        OfflinePcrlb::for_scenario(setup.scenario, setup.topology).map_err(|e| ParamError {
            key: "sensors.manager".into(),
            expected: "a scenario whose offline PCRLB can be computed".into(),
            got: e.to_string(),
        })?;
    Ok(Manager::Alone(Box::new(manager)))
}

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
}

/// Registers a fusion protocol on the CF/DPF's information vectors under
/// `name`, the value of `consensus.protocol` that chooses it.
pub fn register_protocol(name: &str, build: ProtocolBuilder) -> Result<(), RegistryError> {
    register(Role::Protocol, "fusion protocol", name, |parts, n| {
        parts.protocols.insert(n, build);
    })
}

/// Registers a sensor manager under `name`, the value of `sensors.manager`
/// that chooses it.
pub fn register_manager(name: &str, build: ManagerBuilder) -> Result<(), RegistryError> {
    register(Role::Manager, "sensor manager", name, |parts, n| {
        parts.managers.insert(n, build);
    })
}

/// Registers a protocol's own message payload (see
/// [`wire::payloads`]): its messages are then decoded, counted
/// per link under its name, and sized like the built-in ones.
pub fn register_payload<P: ProtocolPayload>() -> Result<ProtocolKind, RegistryError> {
    Ok(wire::payloads::register::<P>()?)
}

fn register(
    role: Role,
    what: &'static str,
    name: &str,
    insert: impl FnOnce(&mut Parts, &'static str),
) -> Result<(), RegistryError> {
    if !valid_name(name) {
        return Err(RegistryError::BadName {
            role: what,
            name: name.into(),
        });
    }
    let mut parts = PARTS.write().unwrap_or_else(|p| p.into_inner());
    // Under the lock, so that two threads cannot both take a name.
    if registered::lookup(role, name).is_some() {
        return Err(RegistryError::Taken {
            role: what,
            name: name.into(),
        });
    }
    insert(&mut parts, registered::register(role, name));
    Ok(())
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
/// oracle, and a tracker is a node of its own, [`cooperation`]).
pub fn information_fusion(
    scenario: &Scenario,
    topology: &Topology,
    node: u16,
) -> Result<Option<InformationFusion>, ParamError> {
    let protocol = scenario.consensus.protocol;
    let params = protocol_params(scenario);
    match protocol.shape() {
        Shape::Rounds => {
            let build = *parts()
                .protocols
                .get(protocol.name())
                .expect("a protocol of rounds has a builder");
            build(&setup(scenario, topology, node, params)).map(Some)
        }
        Shape::ExactSums | Shape::Tracker { .. } => params.only(&[]).map(|()| None),
        Shape::Locator => location_config(scenario).map(|_| None),
    }
}

/// `consensus.params` of `ml_location`: `grid_x`, `grid_y` (5 to 61
/// points, default 21), `refinements` (0 to 4, default 2) and `thresholds`
/// (`"designed"`, the default for amplitude sensors, or `"uniform"`).
pub fn location_config(scenario: &Scenario) -> Result<LocationConfig, ParamError> {
    let params = protocol_params(scenario);
    params.only(&["grid_x", "grid_y", "refinements", "thresholds"])?;
    let axis = |name| params.integer(name, 5..=61, 21).map(|v| v as usize);
    let amplitude = matches!(scenario.observation, bounds::SensorLaw::Amplitude { .. });
    let default = if amplitude { "designed" } else { "uniform" };
    let thresholds = match params.text("thresholds", default)? {
        "designed" if amplitude || scenario.quantizer.raw => ThresholdDesign::Designed,
        "designed" => {
            return Err(params.error(
                "thresholds",
                "\"uniform\": the designed thresholds are for amplitude sensors",
                "\"designed\"",
            ))
        }
        "uniform" => ThresholdDesign::Uniform,
        other => {
            return Err(params.error(
                "thresholds",
                "\"designed\" or \"uniform\"",
                format!("\"{other}\""),
            ))
        }
    };
    Ok(LocationConfig {
        grid: [axis("grid_x")?, axis("grid_y")?],
        refinements: params.integer("refinements", 0..=4, 2)? as usize,
        thresholds,
    })
}

/// How tracker node `node` cooperates, if the scenario names one of the
/// random-exchange and KL trackers.
pub fn cooperation(
    scenario: &Scenario,
    topology: &Topology,
    node: u16,
) -> Result<Option<Tracker>, ParamError> {
    let protocol = scenario.consensus.protocol;
    let Some(build) = parts().trackers.get(protocol.name()).copied() else {
        return Ok(None);
    };
    build(&setup(scenario, topology, node, protocol_params(scenario))).map(Some)
}

/// The sensor manager the scenario names, for node `node`.
pub fn manager(scenario: &Scenario, topology: &Topology, node: u16) -> Result<Manager, ParamError> {
    let name = scenario.sensors.manager.name();
    let build = *parts()
        .managers
        .get(name)
        .expect("every manager a scenario can name has a builder");
    let params = Params::new("sensors.manager_params", &scenario.sensors.manager_params);
    build(&setup(scenario, topology, node, params))
}

/// Checks the scenario's choice of protocol and manager and their
/// parameters by building both for every node, so that a bad parameter is
/// refused before any process starts, naming its key.
pub fn check(scenario: &Scenario, topology: &Topology) -> Result<(), ParamError> {
    for node in 0..topology.nodes() as u16 {
        information_fusion(scenario, topology, node)?;
        cooperation(scenario, topology, node)?;
        manager(scenario, topology, node)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::scenario::DEFAULT_SCENARIO;

    fn scenario(overrides: &[&str]) -> Result<Scenario, String> {
        let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        Scenario::from_toml(DEFAULT_SCENARIO, "d", &overrides).map_err(|e| e.to_string())
    }

    fn alone(setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
        setup.params.only(&["rounds", "gain"])?;
        setup.params.integer("rounds", 1..=5, 1)?;
        setup.params.number("gain", 0.0..=1.0, 0.5)?;
        information_fusion_of_average(setup)
    }

    fn information_fusion_of_average(setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
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
    fn a_registered_protocol_is_named_by_the_scenario_and_checks_its_parameters() {
        let unknown = scenario(&["consensus.protocol=\"registry_test\""]).unwrap_err();
        assert!(
            unknown.contains("consensus.protocol") && unknown.contains("`average`"),
            "{unknown}"
        );
        register_protocol("registry_test", alone).unwrap();
        assert!(matches!(
            register_protocol("registry_test", alone),
            Err(RegistryError::Taken { .. })
        ));
        assert!(matches!(
            register_protocol("average", alone),
            Err(RegistryError::Taken { .. })
        ));
        assert!(matches!(
            register_protocol("Bad-Name", alone),
            Err(RegistryError::BadName { .. })
        ));
        let s = scenario(&[
            "consensus.protocol=\"registry_test\"",
            "consensus.params.rounds=3",
        ])
        .unwrap();
        assert!(!s.consensus.protocol.is_built_in());
        assert_eq!(s.consensus.protocol.name(), "registry_test");
        let topology = Topology::from_scenario(&s, "d").unwrap();
        check(&s, &topology).unwrap();
        // The scenario a launcher writes for its children reads back the same.
        assert_eq!(Scenario::from_toml(&s.to_toml(), "child", &[]).unwrap(), s);
        for (set, key) in [
            ("consensus.params.rounds=9", "consensus.params.rounds"),
            ("consensus.params.gain=\"x\"", "consensus.params.gain"),
            ("consensus.params.other=1", "consensus.params.other"),
        ] {
            let bad = scenario(&["consensus.protocol=\"registry_test\"", set]).unwrap();
            let err = check(&bad, &topology).unwrap_err();
            assert_eq!(err.key, key, "{set}: {err}");
        }
    }

    #[test]
    fn built_in_parts_take_no_parameters() {
        let s = scenario(&["consensus.params.rounds=3"]).unwrap();
        let topology = Topology::from_scenario(&s, "d").unwrap();
        assert_eq!(
            check(&s, &topology).unwrap_err().key,
            "consensus.params.rounds"
        );
        let s = scenario(&["sensors.manager_params.k=3"]).unwrap();
        assert_eq!(
            check(&s, &topology).unwrap_err().key,
            "sensors.manager_params.k"
        );
        check(&scenario(&[]).unwrap(), &topology).unwrap();
    }
}
