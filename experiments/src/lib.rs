//! `cqnet experiment`: the papers' figures as commands that draw them.
//!
//! An experiment is data, not code: overrides of the default scenario, the
//! arms it runs (each a Monte Carlo of its own), the figure (which series of
//! which arm to draw) and a check that says in words whether the paper's
//! qualitative result holds. Adding one is adding an entry to a catalogue
//! (`distributed_bound.rs` is the first); the runner, the CSV, the SVG and the
//! command line are shared.

mod allocation;
mod bit_depth;
mod censoring;
mod compressive;
mod compressive_sweep;
mod consensus_at_scale;
pub mod diagnostics;
mod distributed_bound;
pub mod faults;
mod figure;
mod location;
pub mod paired;
pub use paired::{Order, Paired, Verdict};
mod catalogue;
mod claims;
mod computed;
mod model;
mod parallel;
mod random_exchange_bounds;
mod random_exchange_trackers;
mod runner;
mod sensor_selection;
mod ungm;

pub use catalogue::*;
pub use claims::*;
pub use computed::*;
pub use model::*;
pub use runner::*;

use launch::results::write_atomically;
