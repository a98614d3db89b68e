//! The faults a scenario injects. Each kind is one type in its own file,
//! holding everything about it: its fields (parsed by serde), its checks,
//! what it does to a link, a sensor or a process, and how a run's summary
//! describes it. [`FaultSchedule`] evaluates the schedule at a step.
//!
//! Adding a kind is its file, its `mod` and `pub use` here, and its name
//! in `fault.rs`'s `fault_kinds!` list.

mod burst_loss;
mod corrupt;
mod delay;
mod duplicate;
mod effects;
mod fault;
mod kill;
mod kind;
mod loss;
mod on_links;
mod partition;
mod reorder;
mod schedule;
mod select;
mod sensor;

pub use crate::check::Check;
pub use burst_loss::BurstLoss;
pub use corrupt::Corrupt;
pub use delay::Delay;
pub use duplicate::Duplicate;
pub use effects::{ProcessEvent, SensorFault, Signal};
pub use fault::Fault;
pub use kill::Kill;
pub use kind::{FaultKind, Targets, Window};
pub use loss::Loss;
pub use on_links::LinkFault;
pub use partition::Partition;
pub use reorder::Reorder;
pub use schedule::FaultSchedule;
pub use select::{is_wildcard, LinkSelector};
pub use sensor::{FaultySensors, SensorMode};
