//! The `cqnet` command's library: everything the binary does, so that
//! integration tests can drive it too.

pub mod actor_process;
pub mod app;
pub mod cli;
pub mod montecarlo;
pub mod network;
pub mod results;
pub mod sim;
pub mod summary;
pub mod supervisor;
pub mod world;

/// A membership view as the bit mask the `Membership` message carries.
pub fn membership_mask(view: &[bool]) -> Vec<u8> {
    let mut mask = vec![0u8; view.len().div_ceil(8)];
    for (i, a) in view.iter().enumerate() {
        if *a {
            mask[i / 8] |= 1 << (i % 8);
        }
    }
    mask
}
