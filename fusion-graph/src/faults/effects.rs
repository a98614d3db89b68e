//! What faults do to a process or a sensor, as the runtime and the sensor
//! see it: the schedule's answers.

use serde::{Deserialize, Serialize};

use wire::ActorId;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Signal {
    #[serde(rename = "SIGKILL")]
    Kill,
    #[serde(rename = "SIGTERM")]
    Term,
    #[serde(rename = "SIGSTOP")]
    Stop,
}

/// A process-level fault due at a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcessEvent {
    Kill {
        actor: ActorId,
        signal: Signal,
    },
    /// Restart a killed actor (SIGCONT for a stopped one).
    Restart {
        actor: ActorId,
        signal: Signal,
    },
}

/// What a faulty sensor does at a step, with its values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SensorFault {
    Stuck,
    Bias(f64),
    Dropout,
    /// Reports the phantom target at this offset from the true one.
    Byzantine([f64; 2]),
}
