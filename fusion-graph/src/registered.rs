//! The vocabulary of a scenario's parts: the fusion protocols
//! (`consensus.protocol`) and sensor managers (`sensors.manager`) it may
//! name, those cqnet ships and those a program registers, and what each
//! protocol needs of the network.
//!
//! What a name builds (and how its parameters are checked) is the `node`
//! crate's registry; this crate keeps the names, so that a scenario naming
//! one parses and one naming neither a built-in nor a registered part is
//! refused at its key, listing what it could have been, and each
//! protocol's [`Shape`], so that the network is wired for it. Names are
//! registered once per program, before any scenario is read, and live as
//! long as it.

use std::sync::RwLock;

/// Which vocabulary a name belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `consensus.protocol`.
    Protocol,
    /// `sensors.manager`.
    Manager,
}

/// What a fusion protocol needs of the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Shape {
    /// Rounds on the CF/DPF's information vectors, over the consensus
    /// channels. Every registered protocol has this shape.
    #[default]
    Rounds,
    /// The exact network sums, from `sim`'s oracle: no messages, for checking.
    ExactSums,
    /// A tracker node of its own: one particle filter per node, summarized
    /// as a Gaussian, rather than the CF/DPF. `pairs`: it swaps posteriors
    /// with one neighbour at a time, over channels per pair of nodes.
    Tracker { pairs: bool },
    /// A locator node of its own, for a static target: each node's
    /// log-likelihood over a grid shared by all and its sensors' Fisher
    /// information, summed over the network by average consensus.
    Locator,
}

/// The parts cqnet ships: fusion protocols with their shapes, then sensor
/// managers.
const BUILT_IN: &[(Role, &str, Shape)] = &[
    (Role::Protocol, "average", Shape::Rounds),
    (Role::Protocol, "exact", Shape::ExactSums),
    (
        Role::Protocol,
        "random_exchange",
        Shape::Tracker { pairs: true },
    ),
    (
        Role::Protocol,
        "kl_consensus",
        Shape::Tracker { pairs: false },
    ),
    (
        Role::Protocol,
        "kl_diffusion",
        Shape::Tracker { pairs: false },
    ),
    (
        Role::Protocol,
        "kl_iterative",
        Shape::Tracker { pairs: false },
    ),
    (Role::Protocol, "ml_location", Shape::Locator),
    (Role::Manager, "random", Shape::Rounds),
    (Role::Manager, "closest", Shape::Rounds),
    (Role::Manager, "pcrlb", Shape::Rounds),
    (Role::Manager, "pcrlb_at_estimate", Shape::Rounds),
    (Role::Manager, "pcrlb_offline", Shape::Rounds),
];

static REGISTERED: RwLock<Vec<(Role, &'static str)>> = RwLock::new(Vec::new());

/// Adds `name` to `role`'s vocabulary (again: no change) and returns it with
/// the program's lifetime. A registered protocol has the shape
/// [`Shape::Rounds`].
pub fn register(role: Role, name: &str) -> &'static str {
    if let Some(known) = lookup(role, name) {
        return known;
    }
    let mut names = REGISTERED.write().unwrap_or_else(|p| p.into_inner());
    let name: &'static str = Box::leak(name.to_owned().into_boxed_str());
    names.push((role, name));
    name
}

/// The built-in or registered name equal to `name`, if any.
pub fn lookup(role: Role, name: &str) -> Option<&'static str> {
    built_in(role, name)
        .map(|(n, _)| n)
        .or_else(|| registered(role).find(|n| *n == name))
}

/// Whether `name` is one of the parts cqnet ships.
pub fn is_built_in(role: Role, name: &str) -> bool {
    built_in(role, name).is_some()
}

/// The shape of protocol `name`: its built-in one, else a registered
/// protocol's.
pub fn shape(name: &str) -> Shape {
    built_in(Role::Protocol, name).map_or(Shape::Rounds, |(_, s)| s)
}

/// Every name of `role`: the built-in ones, then those registered, in the
/// order registered.
pub fn names(role: Role) -> Vec<&'static str> {
    BUILT_IN
        .iter()
        .filter(|(r, _, _)| *r == role)
        .map(|(_, n, _)| *n)
        .chain(registered(role))
        .collect()
}

fn built_in(role: Role, name: &str) -> Option<(&'static str, Shape)> {
    BUILT_IN
        .iter()
        .find(|(r, n, _)| *r == role && *n == name)
        .map(|(_, n, s)| (*n, *s))
}

fn registered(role: Role) -> impl Iterator<Item = &'static str> {
    let names = REGISTERED.read().unwrap_or_else(|p| p.into_inner());
    names
        .iter()
        .filter(|(r, _)| *r == role)
        .map(|(_, n)| *n)
        .collect::<Vec<_>>()
        .into_iter()
}
