//! Sensors that misbehave: stuck on their last cell, biased, silent, or
//! Byzantine (reporting a phantom target). `sensors` names them (or `"*"`),
//! `fraction` takes a fixed share of those named.

use serde::{Deserialize, Serialize};

use super::effects::SensorFault;
use super::kind::{FaultKind, Targets, Window};
use super::select::{actor_word, in_share, matches};
use crate::check::Check;
use crate::ScenarioError;
use wire::ActorId;

/// What a faulty sensor does instead of measuring honestly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorMode {
    /// Repeats the cell it sent last before the fault.
    Stuck,
    /// Adds `bias` (the observation's unit: radians for bearings) before quantizing.
    Bias,
    /// Sends nothing.
    Dropout,
    /// Sends the cells of a phantom target displaced by `phantom` metres:
    /// consistent, plausible and false.
    Byzantine,
}

/// Spelled `kind = "sensor"` in a scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultySensors {
    pub sensors: Vec<String>,
    pub at_step: u32,
    pub duration: Option<u32>,
    pub mode: SensorMode,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fraction: Option<f64>,
    /// `bias`: what is added to each measurement.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bias: Option<f64>,
    /// `byzantine`: where the phantom target is, relative to the true one, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phantom: Option<[f64; 2]>,
}

impl FaultySensors {
    fn check_mode(&self, check: &Check) -> Result<(), ScenarioError> {
        match (self.mode, self.bias, self.phantom) {
            (SensorMode::Bias, None, _) => {
                Err(check.fail("bias", "a bias for mode \"bias\"", "none"))
            }
            (SensorMode::Bias, Some(b), _) if !b.is_finite() => {
                Err(check.fail("bias", "a finite number", b))
            }
            (SensorMode::Byzantine, _, None) => Err(check.fail(
                "phantom",
                "the phantom's offset [dx, dy] for mode \"byzantine\"",
                "none",
            )),
            (SensorMode::Byzantine, _, Some(p)) if !p.iter().all(|v| v.is_finite()) => {
                Err(check.fail("phantom", "finite numbers", format!("{p:?}")))
            }
            _ => Ok(()),
        }
    }
}

impl FaultKind for FaultySensors {
    fn window(&self) -> Window {
        Window::lasting(self.at_step, self.duration)
    }

    fn targets(&self) -> Targets<'_> {
        Targets {
            key: "sensors",
            names: self
                .sensors
                .iter()
                .map(String::as_str)
                .filter(|n| *n != "*")
                .collect(),
            sensors_only: true,
        }
    }

    fn check(&self, check: &Check) -> Result<(), ScenarioError> {
        check.non_empty("sensors", self.sensors.len())?;
        if let Some(p) = self.fraction {
            check.probability("fraction", p)?;
        }
        self.check_mode(check)?;
        check.duration(self.duration)
    }

    fn describe(&self) -> String {
        let what = match self.mode {
            SensorMode::Stuck => "stuck".to_string(),
            SensorMode::Dropout => "dropout".to_string(),
            SensorMode::Bias => format!("bias {}", self.bias.unwrap_or(0.0)),
            SensorMode::Byzantine => format!(
                "byzantine, phantom at {:?} m",
                self.phantom.unwrap_or_default()
            ),
        };
        let share = self
            .fraction
            .map_or(String::new(), |f| format!(" ({f} of them)"));
        format!("sensor {what} on {}{share}", self.sensors.join(", "))
    }

    fn sensor_fault(&self, fault: usize, sensor: ActorId) -> Option<SensorFault> {
        let chosen = self.sensors.iter().any(|s| matches(s, sensor))
            && in_share(self.fraction, &[fault as u64, actor_word(sensor)]);
        chosen.then(|| match self.mode {
            SensorMode::Stuck => SensorFault::Stuck,
            SensorMode::Bias => SensorFault::Bias(self.bias.unwrap_or(0.0)),
            SensorMode::Dropout => SensorFault::Dropout,
            SensorMode::Byzantine => SensorFault::Byzantine(self.phantom.unwrap_or([0.0, 0.0])),
        })
    }
}
