//! The checks a scenario's values go through, each error naming the file
//! and the full key: the scenario's own (`region.width`) and each fault's
//! (`faults[2].probability`).

use crate::ScenarioError;

pub struct Check<'a> {
    file: &'a str,
    /// What every key starts with: empty, or `faults[2]`.
    prefix: String,
}

impl<'a> Check<'a> {
    /// Keys as they stand, from the scenario's top.
    pub fn root(file: &'a str) -> Self {
        Self {
            file,
            prefix: String::new(),
        }
    }

    /// Keys under entry `index` of the fault schedule.
    pub fn fault(file: &'a str, index: usize) -> Self {
        Self {
            file,
            prefix: format!("faults[{index}]"),
        }
    }

    /// The full key of `field`, e.g. `faults[2].probability`.
    pub fn key(&self, field: &str) -> String {
        if self.prefix.is_empty() {
            field.to_string()
        } else {
            format!("{}.{field}", self.prefix)
        }
    }

    pub fn fail(
        &self,
        field: &str,
        expected: impl Into<String>,
        got: impl ToString,
    ) -> ScenarioError {
        ScenarioError::Invalid {
            file: self.file.into(),
            key: self.key(field),
            expected: expected.into(),
            got: got.to_string(),
        }
    }

    pub fn probability(&self, field: &str, p: f64) -> Result<(), ScenarioError> {
        if (0.0..=1.0).contains(&p) {
            Ok(())
        } else {
            Err(self.fail(field, "a probability in [0, 1]", p))
        }
    }

    pub fn non_negative(&self, field: &str, v: f64) -> Result<(), ScenarioError> {
        if v.is_finite() && v >= 0.0 {
            Ok(())
        } else {
            Err(self.fail(field, "a finite number >= 0", v))
        }
    }

    pub fn positive(&self, field: &str, v: f64) -> Result<(), ScenarioError> {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(self.fail(field, "a finite number > 0", v))
        }
    }

    pub fn non_empty(&self, field: &str, len: usize) -> Result<(), ScenarioError> {
        if len == 0 {
            Err(self.fail(field, "at least one entry", "none"))
        } else {
            Ok(())
        }
    }

    /// A duration, when given, of at least one step.
    pub fn duration(&self, duration: Option<u32>) -> Result<(), ScenarioError> {
        if duration == Some(0) {
            Err(self.fail("duration", "at least 1 step", 0))
        } else {
            Ok(())
        }
    }
}
