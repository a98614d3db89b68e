//! A fusion protocol and a sensor manager of our own, plugged into cqnet
//! through its registry, without a line of cqnet changed:
//!
//! - [`NeighbourhoodMean`]: a few rounds of plain averaging over each
//!   node's closed neighbourhood, with a message kind of its own;
//! - [`FirstK`]: a node always activates its first `k` sensors.
//!
//! A scenario chooses them by name:
//!
//! ```toml
//! [consensus]
//! protocol = "neighbourhood_mean"
//! params = { rounds = 3 }
//!
//! [sensors]
//! manager = "first_k"
//! manager_params = { k = 2 }
//! ```

mod first_k;
mod neighbourhood_mean;

pub use first_k::FirstK;
pub use neighbourhood_mean::{NeighbourhoodMean, NeighbourhoodValue};

use node::registry;
use wire::MessageKind;

/// Registers both parts and the protocol's payload, and returns the
/// payload's message kind. Call it first in `main`, and in a test before
/// reading a run's results (so that `links.csv` names the kind).
pub fn register() -> Result<MessageKind, String> {
    use std::sync::OnceLock;
    // Registering twice is refused (the name is taken), so a test that
    // calls this from several threads gets the first call's answer.
    static DONE: OnceLock<Result<MessageKind, String>> = OnceLock::new();
    let done = DONE.get_or_init(|| {
        let kind = registry::register_payload::<NeighbourhoodValue>().map_err(|e| e.to_string())?;
        registry::register_protocol("neighbourhood_mean", neighbourhood_mean::build)
            .map_err(|e| e.to_string())?;
        registry::register_manager("first_k", first_k::build).map_err(|e| e.to_string())?;
        Ok(MessageKind::Protocol(kind))
    });
    done.clone()
}
