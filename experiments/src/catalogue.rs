//! Every experiment by name: the network ones and the computed ones, and
//! the names they once went by, refused.

use crate::computed::{computed_catalogue, Computed};
use crate::model::Experiment;
use crate::{censoring, compressive, distributed_bound, faults, sensor_selection};

/// One name of `cqnet experiment`: run on a network, or computed.
pub enum Entry {
    Network(Experiment),
    Computed(Computed),
}

/// The network experiment or computed one of that name, or an error that
/// lists every name.
pub fn find_entry(name: &str) -> anyhow::Result<Entry> {
    if let Some(c) = computed_catalogue().into_iter().find(|c| c.name == name) {
        return Ok(Entry::Computed(c));
    }
    find(name).map(Entry::Network)
}

/// Every experiment, in the order `cqnet experiment` lists them.
pub fn catalogue() -> Vec<Experiment> {
    let mut all = distributed_bound::experiments();
    all.extend(sensor_selection::experiments());
    all.extend(compressive::experiments());
    all.extend(censoring::network_experiments());
    all.extend(faults::experiments());
    all
}

/// The experiment of that name, or an error that lists the names.
pub fn find(name: &str) -> anyhow::Result<Experiment> {
    let mut all = catalogue();
    match all.iter().position(|e| e.name == name) {
        Some(i) => Ok(all.swap_remove(i)),
        None => anyhow::bail!(
            "no experiment named `{name}`; there are: {}",
            all.iter()
                .map(|e| e.name)
                .chain(computed_catalogue().iter().map(|c| c.name))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}
