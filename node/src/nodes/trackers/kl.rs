//! The random-exchange paper's KL fusion trackers: each node weighs its own
//! measurements (consensus KL) or its closed neighbourhood's (the modified
//! forms, diffusion and iterative), then K_max rounds of consensus on the
//! natural parameters of the nodes' Gaussian posteriors fuse them, and the
//! node redraws its particles from the fused Gaussian.
//!
//! The fusion of the posteriors is a protocol of its own: KL fusion's
//! Metropolis rounds ([`kl_fusion_rounds`]), or a program's, which then
//! has a tracker of its own with the weighing and the adoption for free.

use std::marker::PhantomData;
use std::time::Duration;

use fusion_graph::{Scenario, Topology};

use crate::estimator::Observation;
use crate::fusion::{kl_fusion, FusionProtocol, KlFused, KlFusion, NaturalGaussian, RoundStats};
use crate::{Outgoing, Work};

use super::{round_timeout, Cooperation, Next, StepAt, TrackerFilter};

/// Any protocol that fuses the nodes' posteriors in natural parameters.
pub trait PosteriorFusion: FusionProtocol<Value = NaturalGaussian, Output = KlFused> {}

impl<P: FusionProtocol<Value = NaturalGaussian, Output = KlFused>> PosteriorFusion for P {}

/// KL fusion's Metropolis rounds for node `index`: `rounds` a step, a
/// neighbour silent for two rounds presumed gone.
pub fn kl_fusion_rounds(
    scenario: &Scenario,
    topology: &Topology,
    index: u16,
    rounds: u32,
) -> KlFusion {
    kl_fusion(index, topology, rounds as u16, round_timeout(scenario)).presume_gone_after(2)
}

/// The KL trackers' part of a step: weigh, fuse the posteriors over a
/// [`PosteriorFusion`] `P`, adopt the fused one.
pub struct KlCooperation<P: PosteriorFusion = KlFusion> {
    /// Weigh the closed neighbourhood's measurements before fusing (the
    /// modified forms) rather than the node's own only (consensus KL).
    neighbourhood: bool,
    /// The local posterior β⁰, until the fusion takes it.
    local: Option<NaturalGaussian>,
    /// The fusion's result, until adopted.
    fused: Option<KlFused>,
    /// The fusion is running.
    fusing: bool,
    weighed: bool,
    stats: RoundStats,
    fusion: PhantomData<fn() -> P>,
}

impl<P: PosteriorFusion> KlCooperation<P> {
    /// The posteriors fused after weighing the closed neighbourhood's
    /// measurements (`neighbourhood`) or the node's own only.
    pub fn new(neighbourhood: bool) -> Self {
        Self {
            neighbourhood,
            local: None,
            fused: None,
            fusing: false,
            weighed: false,
            stats: RoundStats::default(),
            fusion: PhantomData,
        }
    }
}

impl<P: PosteriorFusion> Cooperation for KlCooperation<P> {
    type Protocol = P;

    fn uses_neighbourhood(&self) -> bool {
        self.neighbourhood
    }

    fn begin(&mut self, _: &mut P, _: &TrackerFilter, _: StepAt<'_>, _: &mut Vec<Outgoing>) {
        self.local = None;
        self.fused = None;
        self.fusing = false;
        self.weighed = false;
        self.stats = RoundStats::default();
    }

    fn poll(&mut self, fusion: &mut P) {
        if self.fusing {
            if let Some(f) = fusion.poll_result() {
                self.fusing = false;
                self.fused = Some(f);
            }
        }
    }

    fn stats(&self) -> RoundStats {
        self.stats
    }

    fn pending(&self, measured: bool) -> Option<Work> {
        if measured && !self.weighed {
            Some(Work::Weigh)
        } else if self.fused.is_some() {
            Some(Work::Adopt)
        } else {
            None
        }
    }

    /// [`Work::Weigh`]: the local posterior, in natural parameters;
    /// [`Work::Adopt`]: the particles redrawn from the fused Gaussian.
    fn run(&mut self, work: Work, filter: &mut TrackerFilter, observations: &[Observation]) {
        match work {
            Work::Weigh => {
                let local = filter.local_posterior(observations);
                self.local = NaturalGaussian::from_moments(&local);
                if self.local.is_none() {
                    tracing::error!(
                        node = filter.node,
                        "the local posterior is degenerate; not fusing this step"
                    );
                }
                self.weighed = true;
            }
            Work::Adopt => {
                let Some(fused) = self.fused.take() else {
                    return;
                };
                self.stats = fused.stats;
                match fused.fused.to_moments() {
                    Some(g) => filter.adopt(&g),
                    None => tracing::error!(
                        node = filter.node,
                        "the fused information is not positive definite; keeping the local particles"
                    ),
                }
            }
            _ => {}
        }
    }

    /// After the weighing the fusion starts (a degenerate local posterior
    /// is reported as it is); after the adoption the step is done.
    fn done(
        &mut self,
        fusion: &mut P,
        work: Work,
        elapsed: Duration,
        at: StepAt<'_>,
        out: &mut Vec<Outgoing>,
    ) -> Next {
        match work {
            Work::Weigh => match self.local.take() {
                Some(local) => {
                    self.fusing = true;
                    fusion.start(at.step, local, at.view, at.now, out);
                    self.poll(fusion);
                    Next::Wait
                }
                None => Next::Report {
                    adopt_time: Duration::ZERO,
                },
            },
            Work::Adopt => Next::Report {
                adopt_time: elapsed,
            },
            _ => Next::Wait,
        }
    }

    /// A fusion still running ends with what it has.
    fn finish_now(
        &mut self,
        fusion: &mut P,
        _: &TrackerFilter,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) -> bool {
        if !self.fusing {
            return false;
        }
        self.fusing = false;
        self.fused = fusion.finish_now(now, out);
        self.fused.is_some()
    }
}
