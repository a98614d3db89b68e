//! RndEx-PF (the random-exchange paper): a tracker that swaps its
//! posterior of the step before with one random neighbour, over the pair's
//! own channels, while its sensors measure; it then predicts from the
//! posterior it received and weighs with its closed neighbourhood's
//! measurements.

use std::time::Duration;

use fusion_graph::{Scenario, Topology};

use crate::estimator::Observation;
use crate::fusion::{Exchanged, FusionProtocol, RandomExchange, RoundStats};
use crate::{Outgoing, Work};

use super::{round_timeout, Cooperation, Next, TrackerFilter};

pub struct ExchangeCooperation {
    exchange: RandomExchange,
    /// The exchange's result this step.
    exchanged: Option<Exchanged>,
    weighed: bool,
}

impl ExchangeCooperation {
    pub fn new(scenario: &Scenario, topology: &Topology, index: u16) -> Self {
        Self {
            exchange: RandomExchange::new(index, topology, round_timeout(scenario), scenario.seed),
            exchanged: None,
            weighed: false,
        }
    }
}

impl Cooperation for ExchangeCooperation {
    type Protocol = RandomExchange;

    fn protocol(&mut self) -> &mut RandomExchange {
        &mut self.exchange
    }

    fn protocol_ref(&self) -> &RandomExchange {
        &self.exchange
    }

    fn uses_neighbourhood(&self) -> bool {
        true
    }

    /// Swaps the posterior of the step before, while the measurements of
    /// this one come in.
    fn begin(
        &mut self,
        step: u32,
        filter: &TrackerFilter,
        view: &[bool],
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        self.exchanged = None;
        self.weighed = false;
        self.exchange
            .start(step, filter.tracker.summary(), view, now, out);
        self.poll();
    }

    fn poll(&mut self) {
        if let Some(e) = self.exchange.poll_result() {
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
        let TrackerFilter {
            tracker,
            model,
            rng,
            node,
        } = filter;
        if let Err(e) = tracker.assimilate_from(&from, model, observations, rng) {
            tracing::error!(node = *node, error = %e, "cannot draw from the exchanged posterior; weighing the node's own particles");
            tracker.local_posterior(model, observations, rng);
        }
        self.weighed = true;
    }

    fn done(
        &mut self,
        _: Work,
        _: Duration,
        _: u32,
        _: &[bool],
        _: Duration,
        _: &mut Vec<Outgoing>,
    ) -> Next {
        Next::Report {
            adopt_time: Duration::ZERO,
        }
    }

    /// An exchange still running ends with what it has, or with the node's
    /// own posterior (no partner).
    fn finish_now(
        &mut self,
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
        self.exchanged = Some(self.exchange.finish_now(now, out).unwrap_or(stayed));
        true
    }
}
