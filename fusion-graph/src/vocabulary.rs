//! The vocabulary a scenario is read in: the fusion protocols
//! (`consensus.protocol`) and sensor managers (`sensors.manager`) it may
//! name, what each protocol needs of the network (its [`Shape`]), and the
//! payloads the program's protocols send.
//!
//! A program hands its parts to cqnet as a value (the `node` crate's
//! `Parts`, the command line's `App`), and that value's [`Vocabulary`] is
//! what its scenarios are read in: a scenario naming a part the program
//! does not have is refused at its key, listing what it could have been.
//! There is no table in the process to register with; two programs'
//! vocabularies can live side by side, as they do in tests.
//!
//! cqnet's own parts are named here ([`Vocabulary::BUILT_IN`]), since the
//! scenario format documents them; what builds them is the `node` crate's,
//! which the vocabulary carries for it, type-erased ([`Part::build`]),
//! since this crate cannot name a node's types.

use std::any::Any;
use std::cell::Cell;
use std::fmt;

use bounds::dynamics::Motion;
use bounds::observation::Law;
use wire::payloads::Payloads;

use crate::params::{ParamError, Params};

/// Which vocabulary a name belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `consensus.protocol`.
    Protocol,
    /// `sensors.manager`.
    Manager,
}

impl Role {
    /// What the role is called in errors.
    pub fn what(self) -> &'static str {
        match self {
            Role::Protocol => "fusion protocol",
            Role::Manager => "sensor manager",
        }
    }
}

/// What a fusion protocol needs of the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// The CF/DPF node, whose protocol fuses its information vectors in
    /// rounds over the consensus channels. `pairs`: it also sends to one
    /// chosen neighbour at a time, over a channel per pair of nodes.
    Rounds { pairs: bool },
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

impl Shape {
    /// Broadcast rounds of the CF/DPF, no pair channels: average consensus.
    pub const ROUNDS: Self = Shape::Rounds { pairs: false };

    /// Whether the network opens a channel for each pair of neighbours.
    pub fn pairs(self) -> bool {
        matches!(
            self,
            Shape::Rounds { pairs: true } | Shape::Tracker { pairs: true }
        )
    }

    /// Whether the node is a tracker rather than the CF/DPF.
    pub fn is_tracker(self) -> bool {
        matches!(self, Shape::Tracker { .. })
    }
}

/// What builds a part: the `node` crate's builder, type-erased here.
pub type Build = &'static (dyn Any + Send + Sync);

/// One part a scenario may name.
#[derive(Clone, Copy)]
pub struct Part {
    pub role: Role,
    pub name: &'static str,
    /// What the part needs of the network: a protocol's shape; a
    /// manager's is [`Shape::Rounds`], with `pairs` if it sends to one
    /// chosen neighbour at a time.
    pub shape: Shape,
    /// What builds it; `None` in [`Vocabulary::BUILT_IN`], whose parts the
    /// `node` crate builds itself.
    pub build: Option<Build>,
}

impl fmt::Debug for Part {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?} {:?} ({:?})", self.role, self.name, self.shape)
    }
}

const fn built_in(role: Role, name: &'static str, shape: Shape) -> Part {
    Part {
        role,
        name,
        shape,
        build: None,
    }
}

/// The parts cqnet ships: fusion protocols with their shapes, then sensor
/// managers.
const BUILT_IN_PARTS: &[Part] = &[
    built_in(Role::Protocol, "average", Shape::ROUNDS),
    built_in(Role::Protocol, "exact", Shape::ExactSums),
    built_in(Role::Protocol, "short_memory", Shape::ROUNDS),
    built_in(
        Role::Protocol,
        "random_exchange",
        Shape::Tracker { pairs: true },
    ),
    built_in(
        Role::Protocol,
        "kl_consensus",
        Shape::Tracker { pairs: false },
    ),
    built_in(
        Role::Protocol,
        "kl_diffusion",
        Shape::Tracker { pairs: false },
    ),
    built_in(
        Role::Protocol,
        "kl_iterative",
        Shape::Tracker { pairs: false },
    ),
    built_in(Role::Protocol, "ml_location", Shape::Locator),
    built_in(Role::Manager, "random", Shape::ROUNDS),
    built_in(Role::Manager, "closest", Shape::ROUNDS),
    built_in(Role::Manager, "pcrlb", Shape::ROUNDS),
    built_in(Role::Manager, "pcrlb_at_estimate", Shape::ROUNDS),
    built_in(Role::Manager, "pcrlb_aux", Shape::ROUNDS),
    built_in(Role::Manager, "pcrlb_offline", Shape::ROUNDS),
];

/// Builds a program's observation law from its parameters, the keys of
/// `[observation]` but `kind`. A function `Fn(&Params) -> Result<Law,
/// ParamError>` is one.
pub trait LawFactory: Send + Sync + 'static {
    fn build(&self, params: &Params<'_>) -> Result<Law, ParamError>;
}

impl<F> LawFactory for F
where
    F: Fn(&Params<'_>) -> Result<Law, ParamError> + Send + Sync + 'static,
{
    fn build(&self, params: &Params<'_>) -> Result<Law, ParamError> {
        self(params)
    }
}

/// Builds a program's motion model from the sampling period
/// (`dynamics.period`, which every model has) and its own parameters, the
/// keys of `[dynamics]` but `kind` and `period`. A function `Fn(f64,
/// &Params) -> Result<Motion, ParamError>` is one.
pub trait MotionFactory: Send + Sync + 'static {
    fn build(&self, period: f64, params: &Params<'_>) -> Result<Motion, ParamError>;
}

impl<F> MotionFactory for F
where
    F: Fn(f64, &Params<'_>) -> Result<Motion, ParamError> + Send + Sync + 'static,
{
    fn build(&self, period: f64, params: &Params<'_>) -> Result<Motion, ParamError> {
        self(period, params)
    }
}

/// A program's observation law, by the name `[observation] kind` gives it.
#[derive(Clone, Copy)]
pub struct LawPart {
    pub name: &'static str,
    pub build: &'static dyn LawFactory,
}

/// A program's motion model, by the name `[dynamics] kind` gives it.
#[derive(Clone, Copy)]
pub struct MotionPart {
    pub name: &'static str,
    pub build: &'static dyn MotionFactory,
}

/// The parts a scenario may name and the payloads their messages carry.
#[derive(Clone, Copy)]
pub struct Vocabulary {
    parts: &'static [Part],
    payloads: Payloads,
    laws: &'static [LawPart],
    motions: &'static [MotionPart],
}

impl Vocabulary {
    /// cqnet's own parts, and no payloads of a program's.
    pub const BUILT_IN: Self = Self {
        parts: BUILT_IN_PARTS,
        payloads: Payloads::NONE,
        laws: &[],
        motions: &[],
    };

    /// The vocabulary of `parts` (which a program lists with cqnet's own
    /// first), `payloads`, and the program's own observation laws and
    /// motion models (cqnet's own are the scenario format's), kept for the
    /// rest of the program.
    pub fn new(
        parts: Vec<Part>,
        payloads: Payloads,
        laws: Vec<LawPart>,
        motions: Vec<MotionPart>,
    ) -> Self {
        Self {
            parts: Box::leak(parts.into_boxed_slice()),
            payloads,
            laws: Box::leak(laws.into_boxed_slice()),
            motions: Box::leak(motions.into_boxed_slice()),
        }
    }

    /// The program's observation law called `name`.
    pub fn law(self, name: &str) -> Option<&'static LawPart> {
        self.laws.iter().find(|l| l.name == name)
    }

    /// The program's motion model called `name`.
    pub fn motion(self, name: &str) -> Option<&'static MotionPart> {
        self.motions.iter().find(|m| m.name == name)
    }

    /// The names of the program's observation laws, in the order listed.
    pub fn law_names(self) -> impl Iterator<Item = &'static str> {
        self.laws.iter().map(|l| l.name)
    }

    /// The names of the program's motion models, in the order listed.
    pub fn motion_names(self) -> impl Iterator<Item = &'static str> {
        self.motions.iter().map(|m| m.name)
    }

    /// The built-in parts, for a program to list first.
    pub const fn built_in_parts() -> &'static [Part] {
        BUILT_IN_PARTS
    }

    /// The part of `role` called `name`, if the program has one.
    pub fn part(self, role: Role, name: &str) -> Option<&'static Part> {
        self.parts.iter().find(|p| p.role == role && p.name == name)
    }

    /// Every name of `role`, in the order listed.
    pub fn names(self, role: Role) -> impl Iterator<Item = &'static str> {
        self.parts
            .iter()
            .filter(move |p| p.role == role)
            .map(|p| p.name)
    }

    /// The payloads the program's protocols declared.
    pub fn payloads(self) -> Payloads {
        self.payloads
    }

    /// Runs `read` with this vocabulary as the one a scenario's names are
    /// resolved in on this thread (serde gives a `Deserialize` no context
    /// of its own), restoring the one before, whatever happens: for
    /// reading a file that holds a scenario (a run's `summary.json`, say)
    /// written by a program with parts of its own.
    pub fn reading<T>(self, read: impl FnOnce() -> T) -> T {
        struct Restore(Option<Vocabulary>);
        impl Drop for Restore {
            fn drop(&mut self) {
                READING_IN.with(|r| r.set(self.0));
            }
        }
        let _restore = Restore(READING_IN.with(|r| r.replace(Some(self))));
        read()
    }

    /// The vocabulary a scenario is being read in on this thread: the one
    /// [`reading`](Self::reading) set, else cqnet's own.
    pub fn current() -> Self {
        READING_IN.with(|r| r.get()).unwrap_or(Self::BUILT_IN)
    }
}

thread_local! {
    static READING_IN: Cell<Option<Vocabulary>> = const { Cell::new(None) };
}

impl Default for Vocabulary {
    fn default() -> Self {
        Self::BUILT_IN
    }
}

impl PartialEq for Vocabulary {
    /// Two vocabularies are alike when they name the same parts with the
    /// same shapes and the same payloads (what builds them aside).
    fn eq(&self, other: &Self) -> bool {
        let names = |v: &Self| {
            v.parts
                .iter()
                .map(|p| (p.role, p.name, p.shape))
                .collect::<Vec<_>>()
        };
        let models = |v: &Self| {
            (
                v.law_names().collect::<Vec<_>>(),
                v.motion_names().collect::<Vec<_>>(),
            )
        };
        names(self) == names(other)
            && self.payloads == other.payloads
            && models(self) == models(other)
    }
}

impl fmt::Debug for Vocabulary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Vocabulary")
            .field("parts", &self.parts)
            .field("payloads", &self.payloads)
            .field("laws", &self.law_names().collect::<Vec<_>>())
            .field("motions", &self.motion_names().collect::<Vec<_>>())
            .finish()
    }
}
