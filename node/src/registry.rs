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
use std::sync::RwLock;
use std::time::Duration;

use fusion_graph::payloads::{ProtocolKind, ProtocolPayload, RegisterError};
use fusion_graph::registered::{self, Role};
use fusion_graph::scenario::{ConsensusProtocol, SensorManagerKind};
use fusion_graph::{Scenario, Topology};

use crate::fusion::{average_consensus, InformationFusion};
use crate::sensor_manager::{self, Manager};

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

#[derive(Default)]
struct Parts {
    protocols: BTreeMap<&'static str, ProtocolBuilder>,
    managers: BTreeMap<&'static str, ManagerBuilder>,
}

static PARTS: RwLock<Option<Parts>> = RwLock::new(None);

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
}

/// Registers a fusion protocol on the CF/DPF's information vectors under
/// `name`, the value of `consensus.protocol` that chooses it.
pub fn register_protocol(name: &str, build: ProtocolBuilder) -> Result<(), RegistryError> {
    let taken = ConsensusProtocol::from_name(name).is_some();
    register(
        Role::Protocol,
        "fusion protocol",
        name,
        taken,
        |parts, n| {
            parts.protocols.insert(n, build);
        },
    )
}

/// Registers a sensor manager under `name`, the value of `sensors.manager`
/// that chooses it.
pub fn register_manager(name: &str, build: ManagerBuilder) -> Result<(), RegistryError> {
    let taken = SensorManagerKind::from_name(name).is_some();
    register(Role::Manager, "sensor manager", name, taken, |parts, n| {
        parts.managers.insert(n, build);
    })
}

/// Registers a protocol's own message payload (see
/// [`fusion_graph::payloads`]): its messages are then decoded, counted
/// per link under its name, and sized like the built-in ones.
pub fn register_payload<P: ProtocolPayload>() -> Result<ProtocolKind, RegistryError> {
    Ok(fusion_graph::payloads::register::<P>()?)
}

fn register(
    role: Role,
    what: &'static str,
    name: &str,
    taken: bool,
    insert: impl FnOnce(&mut Parts, &'static str),
) -> Result<(), RegistryError> {
    if !valid_name(name) {
        return Err(RegistryError::BadName {
            role: what,
            name: name.into(),
        });
    }
    if taken {
        return Err(RegistryError::Taken {
            role: what,
            name: name.into(),
        });
    }
    let mut parts = PARTS.write().unwrap_or_else(|p| p.into_inner());
    insert(
        parts.get_or_insert_with(Parts::default),
        registered::register(role, name),
    );
    Ok(())
}

/// The fusion protocol the scenario names, for node `node`: average
/// consensus, or a registered protocol. The other built-ins are not built
/// here: exact sums need `sim`'s oracle, and the random-exchange and KL trackers are nodes
/// of their own.
pub fn information_fusion(
    scenario: &Scenario,
    topology: &Topology,
    node: u16,
) -> Result<Option<InformationFusion>, ParamError> {
    let c = &scenario.consensus;
    let params = Params::new("consensus.params", &c.params);
    match c.protocol {
        ConsensusProtocol::Average => {
            params.only(&[])?;
            Ok(Some(Box::new(average_consensus(
                node,
                topology,
                c.rounds as u16,
                Duration::from_secs_f64(c.round_timeout_ms / 1e3),
                c.auxiliary_fim,
            ))))
        }
        ConsensusProtocol::Registered(name) => {
            let build = protocol_builder(name);
            build(&Setup {
                scenario,
                topology,
                node,
                params,
            })
            .map(Some)
        }
        _ => {
            params.only(&[])?;
            Ok(None)
        }
    }
}

/// The sensor manager the scenario names, for node `node`.
pub fn manager(scenario: &Scenario, topology: &Topology, node: u16) -> Result<Manager, ParamError> {
    let params = Params::new("sensors.manager_params", &scenario.sensors.manager_params);
    match scenario.sensors.manager {
        SensorManagerKind::Registered(name) => {
            let build = {
                let parts = PARTS.read().unwrap_or_else(|p| p.into_inner());
                *parts
                    .as_ref()
                    .and_then(|p| p.managers.get(name))
                    .expect("a registered name has a builder")
            };
            build(&Setup {
                scenario,
                topology,
                node,
                params,
            })
        }
        _ => {
            params.only(&[])?;
            Ok(sensor_manager::for_scenario(scenario, topology, node))
        }
    }
}

fn protocol_builder(name: &'static str) -> ProtocolBuilder {
    let parts = PARTS.read().unwrap_or_else(|p| p.into_inner());
    *parts
        .as_ref()
        .and_then(|p| p.protocols.get(name))
        .expect("a registered name has a builder")
}

/// Checks the scenario's choice of protocol and manager and their
/// parameters by building both for every node, so that a bad parameter is
/// refused before any process starts, naming its key.
pub fn check(scenario: &Scenario, topology: &Topology) -> Result<(), ParamError> {
    for node in 0..topology.nodes() as u16 {
        information_fusion(scenario, topology, node)?;
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
        assert_eq!(
            s.consensus.protocol,
            ConsensusProtocol::Registered("registry_test")
        );
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
