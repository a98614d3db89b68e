//! The heavy stages of a node's step, which the driver runs and times
//! apart from the message handling.

/// A heavy stage the driver runs and times.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Work {
    /// The PCRLB selection's scores: each own sensor's expected information
    /// and the predicted information they add to.
    SelectionScores,
    /// The local filter's update and the local bound.
    LocalFilter,
    /// The fusion filter and the global bounds.
    FusionFilter,
    /// A tracker's prediction and its weighing with the step's
    /// measurements (from the exchanged posterior, in RndEx-PF).
    Weigh,
    /// KL fusion: the particles redrawn from the fused Gaussian.
    Adopt,
    /// A locator's log-likelihood over the region's grid.
    GridLikelihood,
    /// A fusion centre's design of the step's slots: the prediction, each
    /// sensor's expected information, the transmission probabilities and
    /// the sensing matrix drawn from them.
    Design,
    /// A fusion centre's weighing of its particles with the channel's delivery.
    WeighDelivery,
}
