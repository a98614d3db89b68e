//! cqnet's runtime: from a scenario to a running network, and what it
//! leaves behind. It knows nothing of papers or plots.
//!
//! - [`world`]: the truth and the step clock, and what the launcher tells
//!   the nodes (membership);
//! - the drivers: [`sim`] runs every actor in one process on a virtual
//!   clock, [`network`] runs each as its own process ([`actor_process`] is
//!   the child's side: one loop for every actor); both hand actors their
//!   inputs through [`drive`];
//! - [`supervisor`]: spawning, signalling and reaping the children;
//!   [`preflight`]: whether a network fits the machine;
//! - [`results`] and [`summary`]: the files a run writes and reads back;
//!   [`usage`]: the memory and CPU time a process has used;
//! - [`feed`]: the events a live view draws; [`progress`]: what long work
//!   shows while it runs; [`montecarlo`]: many seeds of `sim` in parallel;
//! - `hosts` (`--features zenoh`): agents and bridges between hosts.

pub mod actor_process;
pub mod cores;
pub mod drive;
pub mod feed;
#[cfg(feature = "zenoh")]
pub mod hosts;
pub mod montecarlo;
pub mod network;
pub mod preflight;
pub mod progress;
pub mod results;
pub mod sim;
pub mod spawner;
pub mod summary;
pub mod supervisor;
pub mod usage;
pub mod world;
