//! The `cqnet` command's library: everything the binary does, so that
//! integration tests can drive it too.

pub mod actor_process;
pub mod app;
pub mod cli;
pub mod drive;
pub mod experiment;
pub mod fuzz;
#[cfg(feature = "zenoh")]
pub mod hosts;
pub mod montecarlo;
pub mod network;
pub mod preflight;
pub mod progress;
pub mod results;
pub mod sim;
pub mod soak;
pub mod summary;
pub mod supervisor;
pub mod view;
pub mod world;
