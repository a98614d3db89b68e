//! How an actor looks at the world: the target's true state at a step, and
//! why it may not be there. Where the truth is kept (the run's shared
//! memory, or `sim`'s heap) is the transport's business; a sensor sees only
//! this face of it.

use bounds::State;

/// Why the truth of a step cannot be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TruthMissing {
    #[error("the truth of step {step} is not written yet (the latest is step {latest})")]
    NotYetWritten { step: u32, latest: u32 },
    #[error("the truth of step {step} is no longer held (the ring holds {held} steps, the latest is step {latest})")]
    Overwritten { step: u32, latest: u32, held: usize },
    #[error("the truth of step {step} was being written and never finished")]
    Torn { step: u32 },
}

/// Where an actor reads the truth of a step.
pub trait WorldView {
    fn truth(&self, step: u32) -> Result<State, TruthMissing>;
}

impl<W: WorldView + ?Sized> WorldView for std::rc::Rc<W> {
    fn truth(&self, step: u32) -> Result<State, TruthMissing> {
        (**self).truth(step)
    }
}

/// A world in which the target stands still at one state: the truth of
/// every step. For a sensor looked at on its own (tests, examples).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StillTarget(pub State);

impl WorldView for StillTarget {
    fn truth(&self, _step: u32) -> Result<State, TruthMissing> {
        Ok(self.0)
    }
}
