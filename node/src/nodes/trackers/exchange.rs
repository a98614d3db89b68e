//! RndEx-PF (the random-exchange paper): a tracker that swaps its
//! posterior of the step before with one random neighbour, over the pair's
//! own channels, while its sensors measure; it then predicts from the
//! posterior it received and weighs with its closed neighbourhood's
//! measurements.

use std::time::Duration;

use crate::estimator::Observation;
use crate::fusion::{Exchanged, FusionProtocol, RandomExchange, RoundStats};
use crate::{Outgoing, Work};

use super::{Cooperation, StepAt, TrackerFilter};

/// RndEx-PF's part of a tracker's step, over a [`RandomExchange`].
#[derive(Debug, Default)]
pub struct ExchangeCooperation {
    /// The exchange's result this step.
    exchanged: Option<Exchanged>,
    weighed: bool,
}

impl Cooperation for ExchangeCooperation {
    type Protocol = RandomExchange;

    /// A node weighs its closed neighbourhood's measurements.
    fn uses_neighbourhood(&self) -> bool {
        true
    }

    /// Swaps the posterior of the step before, while the measurements of
    /// this one come in.
    fn begin(
        &mut self,
        exchange: &mut RandomExchange,
        filter: &TrackerFilter,
        at: StepAt<'_>,
        out: &mut Vec<Outgoing>,
    ) {
        self.exchanged = None;
        self.weighed = false;
        exchange.start(at.step, filter.tracker.summary(), at.view, at.now, out);
        self.poll(exchange);
    }

    fn poll(&mut self, exchange: &mut RandomExchange) {
        if let Some(e) = exchange.poll_result() {
            self.exchanged = Some(e);
        }
    }

    fn stats(&self) -> RoundStats {
        self.exchanged.map(|e| e.stats).unwrap_or_default()
    }

    fn pending(&self, measured: bool) -> Option<Work> {
        (measured && !self.weighed && self.exchanged.is_some()).then_some(Work::Weigh)
    }

    /// Predicts from the exchanged posterior (its own, if the partner's
    /// cannot be drawn from) and weighs with the measurements.
    fn run(&mut self, work: Work, filter: &mut TrackerFilter, observations: &[Observation]) {
        if work != Work::Weigh {
            return;
        }
        let from = self
            .exchanged
            .map_or_else(|| filter.tracker.summary(), |e| e.posterior);
        filter.assimilate_from(&from, observations);
        self.weighed = true;
    }

    /// An exchange still running ends with what it has, or with the node's
    /// own posterior (no partner).
    fn finish_now(
        &mut self,
        exchange: &mut RandomExchange,
        filter: &TrackerFilter,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) -> bool {
        if self.exchanged.is_some() {
            return false;
        }
        let stayed = Exchanged {
            posterior: filter.tracker.summary(),
            partner: None,
            stats: RoundStats::default(),
        };
        self.exchanged = Some(exchange.finish_now(now, out).unwrap_or(stayed));
        true
    }
}
