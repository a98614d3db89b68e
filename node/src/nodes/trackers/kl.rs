//! The random-exchange paper's KL fusion trackers: each node weighs its own
//! measurements (consensus KL) or its closed neighbourhood's (the modified
//! forms, diffusion and iterative), then K_max rounds of consensus on the
//! natural parameters of the nodes' Gaussian posteriors fuse them, and the
//! node redraws its particles from the fused Gaussian.
//!
//! The fusion of the posteriors is a protocol of its own: KL fusion's
//! Metropolis rounds by default, or a program's
//! ([`KlCooperation::with_protocol`]), which then has a tracker of its own
//! with the weighing and the adoption for free.

use std::time::Duration;

use fusion_graph::{Scenario, Topology};

use crate::estimator::Observation;
use crate::fusion::{kl_fusion, FusionProtocol, KlFused, KlFusion, NaturalGaussian, RoundStats};
use crate::{Outgoing, Work};

use super::{round_timeout, Cooperation, Next, TrackerFilter};

/// Any protocol that fuses the nodes' posteriors in natural parameters.
pub trait PosteriorFusion: FusionProtocol<Value = NaturalGaussian, Output = KlFused> {}

impl<P: FusionProtocol<Value = NaturalGaussian, Output = KlFused>> PosteriorFusion for P {}

pub struct KlCooperation<P: PosteriorFusion = KlFusion> {
    fusion: P,
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
}

impl KlCooperation {
    /// KL fusion of the posteriors over `rounds` rounds, after weighing the
    /// closed neighbourhood's measurements (`neighbourhood`) or the node's
    /// own only.
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
        rounds: u32,
        neighbourhood: bool,
    ) -> Self {
        let fusion = kl_fusion(index, topology, rounds as u16, round_timeout(scenario))
            .presume_gone_after(2);
        Self::with_protocol(fusion, neighbourhood)
    }
}

impl<P: PosteriorFusion> KlCooperation<P> {
    /// The posteriors fused by `fusion`, after weighing the closed
    /// neighbourhood's measurements (`neighbourhood`) or the node's own.
    pub fn with_protocol(fusion: P, neighbourhood: bool) -> Self {
        Self {
            fusion,
            neighbourhood,
            local: None,
            fused: None,
            fusing: false,
            weighed: false,
            stats: RoundStats::default(),
        }
    }
}

impl<P: PosteriorFusion> Cooperation for KlCooperation<P> {
    type Protocol = P;

    fn protocol(&mut self) -> &mut P {
        &mut self.fusion
    }

    fn protocol_ref(&self) -> &P {
        &self.fusion
    }

    fn uses_neighbourhood(&self) -> bool {
        self.neighbourhood
    }

    fn begin(&mut self, _: u32, _: &TrackerFilter, _: &[bool], _: Duration, _: &mut Vec<Outgoing>) {
        self.local = None;
        self.fused = None;
        self.fusing = false;
        self.weighed = false;
        self.stats = RoundStats::default();
    }

    fn poll(&mut self) {
        if self.fusing {
            if let Some(f) = self.fusion.poll_result() {
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
        let TrackerFilter {
            tracker,
            model,
            rng,
            node,
        } = filter;
        match work {
            Work::Weigh => {
                let local = tracker.local_posterior(model, observations, rng);
                self.local = NaturalGaussian::from_moments(&local);
                if self.local.is_none() {
                    tracing::error!(
                        node = *node,
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
                    Some(g) => {
                        if let Err(e) = tracker.adopt(&g, rng) {
                            tracing::error!(node = *node, error = %e, "keeping the local particles");
                        }
                    }
                    None => tracing::error!(
                        node = *node,
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
        work: Work,
        elapsed: Duration,
        step: u32,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) -> Next {
        match work {
            Work::Weigh => match self.local.take() {
                Some(local) => {
                    self.fusing = true;
                    self.fusion.start(step, local, view, now, out);
                    self.poll();
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
    fn finish_now(&mut self, _: &TrackerFilter, now: Duration, out: &mut Vec<Outgoing>) -> bool {
        if !self.fusing {
            return false;
        }
        self.fusing = false;
        self.fused = self.fusion.finish_now(now, out);
        self.fused.is_some()
    }
}
