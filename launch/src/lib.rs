//! The `cqnet` command's library: everything the binary does, so that
//! integration tests can drive it too.

pub mod cli;
pub mod montecarlo;
pub mod results;
pub mod sim;
pub mod summary;
pub mod world;
