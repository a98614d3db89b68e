//! How a part a scenario names reads its own parameters ([`Params`]): a
//! fusion protocol its `[consensus.params]`, a sensor manager its
//! `[sensors.manager_params]`, an observation law its `[observation]`, a
//! motion model its `[dynamics]`, each with errors that name the full key.

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
