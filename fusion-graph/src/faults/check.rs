//! The checks a fault kind runs on its values, each error naming the key
//! under `faults[i]` and the file.

use crate::ScenarioError;

pub struct Check<'a> {
    file: &'a str,
    index: usize,
}

impl<'a> Check<'a> {
    pub fn new(file: &'a str, index: usize) -> Self {
        Self { file, index }
    }

    /// The full key of `field`, e.g. `faults[2].probability`.
    pub fn key(&self, field: &str) -> String {
        format!("faults[{}].{field}", self.index)
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
