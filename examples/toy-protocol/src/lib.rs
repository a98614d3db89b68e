//! Two fusion protocols and a sensor manager of our own, handed to cqnet
//! in the program's [`App`], without a line of cqnet changed:
//!
//! - [`NeighbourhoodMean`]: a few rounds of plain averaging over each
//!   node's closed neighbourhood, broadcast, with a message kind of its own;
//! - [`PushSum`]: push-sum gossip, each round a node keeps half its value
//!   and weight and sends the other half to one neighbour, over the pair's
//!   own channel;
//! - a tracker of our own (`gossip_tracker`): the tracker node's particle
//!   filter, its posteriors fused by push-sum on their natural parameters
//!   over pair channels ([`PosteriorShare`]);
//! - [`FirstK`]: a node always activates its first `k` sensors;
//! - a sensor of our own, [`Range`] (`range`): range-only, quantized, its
//!   gradients by automatic differentiation;
//! - a motion model of our own, [`OrnsteinUhlenbeck`]
//!   (`ornstein_uhlenbeck`): a velocity that forgets its heading.
//!
//! A scenario chooses them by name:
//!
//! ```toml
//! [consensus]
//! protocol = "push_sum"     # or "neighbourhood_mean"
//! rounds = 10
//!
//! [sensors]
//! manager = "first_k"
//! manager_params = { k = 2 }
//!
//! [observation]
//! kind = "range"
//! sigma = 5.0
//! d0 = 1000.0
//!
//! [dynamics]
//! kind = "ornstein_uhlenbeck"
//! period = 1.0
//! sigma = 0.05
//! ```

mod drift;
mod first_k;
mod gossip_tracker;
mod neighbourhood_mean;
mod push_sum;
mod range;

pub use drift::OrnsteinUhlenbeck;
pub use first_k::FirstK;
pub use gossip_tracker::PosteriorShare;
pub use neighbourhood_mean::{NeighbourhoodMean, NeighbourhoodValue};
pub use push_sum::{gossip_target, Gossip, Mass, PushSum, PushSumValue};
pub use range::Range;

use cqnet::App;

/// cqnet with this crate's parts: what `main` runs, and what a test reads
/// the program's scenarios and results in (`app().vocabulary()`).
pub fn app() -> App {
    App::new()
        .payload::<NeighbourhoodValue>()
        .payload::<PushSumValue>()
        .payload::<PosteriorShare>()
        .protocol("neighbourhood_mean", neighbourhood_mean::build)
        .protocol("push_sum", PushSum)
        .node("gossip_tracker", gossip_tracker::factory())
        .manager("first_k", first_k::build)
        .law("range", range::build)
        .motion("ornstein_uhlenbeck", drift::build)
}
