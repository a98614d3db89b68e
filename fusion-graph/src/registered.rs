//! The names a program adds to a scenario's vocabulary: fusion protocols
//! (`consensus.protocol`) and sensor managers (`sensors.manager`) beyond
//! the built-in ones.
//!
//! What a name means (how its protocol or manager is built and how its
//! parameters are checked) is the `node` crate's registry; this crate keeps
//! only the names, so that a scenario naming one parses, and one naming
//! neither a built-in nor a registered part is refused at its key, listing
//! what it could have been. Names are registered once per program, before
//! any scenario is read, and live as long as it.

use std::sync::RwLock;

/// Which vocabulary a name belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `consensus.protocol`.
    Protocol,
    /// `sensors.manager`.
    Manager,
}

static NAMES: RwLock<Vec<(Role, &'static str)>> = RwLock::new(Vec::new());

/// Adds `name` to `role`'s vocabulary (again: no change) and returns it with
/// the program's lifetime.
pub fn register(role: Role, name: &str) -> &'static str {
    if let Some(known) = lookup(role, name) {
        return known;
    }
    let mut names = NAMES.write().unwrap_or_else(|p| p.into_inner());
    let name: &'static str = Box::leak(name.to_owned().into_boxed_str());
    names.push((role, name));
    name
}

/// The registered name equal to `name`, if any.
pub fn lookup(role: Role, name: &str) -> Option<&'static str> {
    NAMES
        .read()
        .unwrap_or_else(|p| p.into_inner())
        .iter()
        .find(|(r, n)| *r == role && *n == name)
        .map(|(_, n)| *n)
}

/// Every name registered for `role`, in the order registered.
pub fn names(role: Role) -> Vec<&'static str> {
    NAMES
        .read()
        .unwrap_or_else(|p| p.into_inner())
        .iter()
        .filter(|(r, _)| *r == role)
        .map(|(_, n)| *n)
        .collect()
}
