//! What a part is built from ([`Setup`]) and how it reads its own
//! parameters ([`Params`]), with errors that name the full key.

use fusion_graph::{Scenario, Topology};

/// What a part is built from: the run's scenario and topology, the node
/// it serves, and its own parameters.
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
        Ok(self.number_if_given(name, range)?.unwrap_or(default))
    }

    /// A finite number in `range`, or `None` when absent (a default the
    /// part works out itself).
    pub fn number_if_given(
        &self,
        name: &str,
        range: std::ops::RangeInclusive<f64>,
    ) -> Result<Option<f64>, ParamError> {
        let expected = || format!("a number in {}..={}", range.start(), range.end());
        let v = match self.table.get(name) {
            None => return Ok(None),
            Some(toml::Value::Float(v)) => *v,
            Some(toml::Value::Integer(v)) => *v as f64,
            Some(v) => return Err(self.error(name, &expected(), v)),
        };
        if v.is_finite() && range.contains(&v) {
            Ok(Some(v))
        } else {
            Err(self.error(name, &expected(), v))
        }
    }
}

impl<'a> Setup<'a> {
    /// `consensus.rounds`: the rounds a step every protocol of rounds runs
    /// (a part's own parameters are for what only it has).
    pub fn rounds(&self) -> u16 {
        self.scenario.consensus.rounds as u16
    }

    /// `consensus.round_timeout_ms`: how long a round waits for a
    /// neighbour it expects.
    pub fn round_timeout(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.scenario.consensus.round_timeout_ms / 1e3)
    }

    /// The kind the program gave payload `P`; an error, naming it, if the
    /// program did not declare it.
    pub fn payload<P: wire::payloads::ProtocolPayload>(
        &self,
    ) -> Result<wire::payloads::PayloadKind<P>, ParamError> {
        self.scenario
            .vocabulary
            .payloads()
            .of::<P>()
            .ok_or_else(|| ParamError {
                key: "consensus.protocol".into(),
                expected: format!("a program that declares payload {:?}", P::NAME),
                got: "a program without it".into(),
            })
    }
}
