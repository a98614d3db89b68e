//! The collector: a step's observations from the sensors activated for it,
//! gathered until every one has arrived or the deadline passes. What it
//! hands on says which active sensors stayed silent, so that silence is an
//! input the estimator can reason about (a censoring sensor's silence is
//! information; a lost message's is not).

use std::time::Duration;

use crate::estimator::{Observation, ObservedValue};

/// What became of an offered observation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Offer {
    Taken,
    /// For another step, from a sensor not activated, or a second copy.
    Late,
    /// A cell index the quantizer does not have.
    Invalid,
}

/// A closed step's observations, sorted by sensor so that the result does
/// not depend on arrival order, and the active sensors not heard from.
#[derive(Debug, Clone, PartialEq)]
pub struct Collected {
    pub step: u32,
    pub observations: Vec<Observation>,
    pub silent: Vec<u16>,
}

/// Whether a cell index is one the quantizer has (raw values always are).
pub(crate) fn in_range(value: ObservedValue, cells: Option<usize>) -> bool {
    match (value, cells) {
        (ObservedValue::Cell(c), Some(cells)) => (c as usize) < cells,
        _ => true,
    }
}

#[derive(Debug, Clone)]
pub struct Collector {
    step: u32,
    active: Vec<u16>,
    received: Vec<Observation>,
    deadline: Duration,
    /// The quantizer's cell count (`None`: raw observations).
    cells: Option<usize>,
}

impl Collector {
    pub fn new(step: u32, active: Vec<u16>, deadline: Duration, cells: Option<usize>) -> Self {
        Self {
            step,
            active,
            received: Vec::new(),
            deadline,
            cells,
        }
    }

    pub fn deadline(&self) -> Duration {
        self.deadline
    }

    pub fn offer(&mut self, step: u32, sensor: u16, value: ObservedValue) -> Offer {
        if step != self.step
            || !self.active.contains(&sensor)
            || self.received.iter().any(|o| o.sensor == sensor)
        {
            return Offer::Late;
        }
        if !in_range(value, self.cells) {
            return Offer::Invalid;
        }
        self.received.push(Observation { sensor, value });
        Offer::Taken
    }

    /// Every active sensor has been heard.
    pub fn is_complete(&self) -> bool {
        self.received.len() == self.active.len()
    }

    pub fn close(mut self) -> Collected {
        self.received.sort_by_key(|o| o.sensor);
        let silent = self
            .active
            .iter()
            .copied()
            .filter(|s| !self.received.iter().any(|o| o.sensor == *s))
            .collect();
        Collected {
            step: self.step,
            observations: self.received,
            silent,
        }
    }
}

/// Observations of a closed step from sensors it was still waiting for,
/// arriving after it closed (a slow link, say). The next step weighs them
/// at the time they were taken, on each particle's path; they are never
/// used as if they were fresh. Later than that, they are dropped.
#[derive(Debug, Clone)]
pub struct Lagging {
    step: Option<u32>,
    awaited: Vec<u16>,
    arrived: Vec<Observation>,
    cells: Option<usize>,
}

impl Lagging {
    pub fn new(cells: Option<usize>) -> Self {
        Self {
            step: None,
            awaited: Vec::new(),
            arrived: Vec::new(),
            cells,
        }
    }

    /// Takes an observation of the last closed step from a sensor it
    /// still awaited.
    pub fn offer(&mut self, step: u32, sensor: u16, value: ObservedValue) -> Offer {
        if self.step != Some(step) {
            return Offer::Late;
        }
        let Some(i) = self.awaited.iter().position(|s| *s == sensor) else {
            return Offer::Late;
        };
        if !in_range(value, self.cells) {
            return Offer::Invalid;
        }
        self.awaited.swap_remove(i);
        self.arrived.push(Observation { sensor, value });
        Offer::Taken
    }

    /// Step `step` closed with `silent` unheard: returns what came late for
    /// the step before it (sorted by sensor), and from now on awaits
    /// `silent`, unless their silence was itself a measurement (censoring),
    /// which a late report would contradict.
    pub fn close(&mut self, step: u32, silent: &[u16], await_silent: bool) -> Vec<Observation> {
        let mut lagged = std::mem::take(&mut self.arrived);
        if self.step.map(|s| s + 1) != Some(step) {
            lagged.clear();
        }
        lagged.sort_by_key(|o| o.sensor);
        self.step = await_silent.then_some(step);
        self.awaited.clear();
        if await_silent {
            self.awaited.extend_from_slice(silent);
        }
        lagged
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_straggler_goes_with_the_next_step_and_no_later() {
        let mut l = Lagging::new(Some(256));
        assert!(l.close(4, &[7, 9], true).is_empty());
        assert_eq!(l.offer(4, 9, ObservedValue::Cell(3)), Offer::Taken);
        assert_eq!(
            l.offer(4, 9, ObservedValue::Cell(3)),
            Offer::Late,
            "a second copy"
        );
        assert_eq!(
            l.offer(4, 2, ObservedValue::Cell(3)),
            Offer::Late,
            "not awaited"
        );
        assert_eq!(
            l.offer(3, 7, ObservedValue::Cell(3)),
            Offer::Late,
            "older step"
        );
        assert_eq!(l.offer(4, 7, ObservedValue::Cell(300)), Offer::Invalid);
        let lagged = l.close(5, &[1], true);
        assert_eq!(
            lagged,
            vec![Observation {
                sensor: 9,
                value: ObservedValue::Cell(3)
            }]
        );
        // Step 4's last straggler is now too late.
        assert_eq!(l.offer(4, 7, ObservedValue::Cell(3)), Offer::Late);
        assert_eq!(l.offer(5, 1, ObservedValue::Cell(8)), Offer::Taken);
        // A skipped step: what came for step 5 is not step 7's lag.
        assert!(l.close(7, &[], true).is_empty());
        // Censoring: silence is not awaited.
        l.close(8, &[3], false);
        assert_eq!(l.offer(8, 3, ObservedValue::Cell(1)), Offer::Late);
    }

    #[test]
    fn reports_what_arrived_in_sensor_order_and_who_stayed_silent() {
        let mut c = Collector::new(4, vec![7, 2, 9], Duration::from_millis(50), Some(256));
        assert_eq!(c.offer(4, 9, ObservedValue::Cell(3)), Offer::Taken);
        assert_eq!(
            c.offer(4, 9, ObservedValue::Cell(3)),
            Offer::Late,
            "a second copy"
        );
        assert_eq!(
            c.offer(3, 2, ObservedValue::Cell(3)),
            Offer::Late,
            "another step"
        );
        assert_eq!(
            c.offer(4, 5, ObservedValue::Cell(3)),
            Offer::Late,
            "not activated"
        );
        assert_eq!(c.offer(4, 7, ObservedValue::Cell(256)), Offer::Invalid);
        assert_eq!(c.offer(4, 2, ObservedValue::Cell(10)), Offer::Taken);
        assert!(!c.is_complete());
        let done = c.close();
        assert_eq!(
            done.observations
                .iter()
                .map(|o| o.sensor)
                .collect::<Vec<_>>(),
            vec![2, 9]
        );
        assert_eq!(done.silent, vec![7]);
    }
}

/// Which of a node's own sensors have ever answered an activation. A
/// sensor that is activated again and again and never answers (a dead
/// process the launcher thinks alive, a link that loses everything) leaves
/// a hole the launcher must hear of: the node's telemetry names it.
#[derive(Debug, Clone)]
pub struct SensorAnswers {
    own: Vec<u16>,
    activated: Vec<u16>,
    answered: Vec<bool>,
}

/// Activations without an answer before a sensor counts as unanswering:
/// some may be lost, or late at a step's end (under 30 % loss each way, 5
/// in a row go unanswered for one sensor in 30).
pub const UNANSWERED_AFTER: u16 = 5;

impl SensorAnswers {
    pub fn new(own: &[u16]) -> Self {
        Self {
            own: own.to_vec(),
            activated: vec![0; own.len()],
            answered: vec![false; own.len()],
        }
    }

    fn slot(&self, sensor: u16) -> Option<usize> {
        self.own.iter().position(|s| *s == sensor)
    }

    pub fn activated(&mut self, sensors: &[u16]) {
        for s in sensors {
            if let Some(i) = self.slot(*s) {
                self.activated[i] = self.activated[i].saturating_add(1);
            }
        }
    }

    /// An observation from `sensor` arrived, in time or late.
    pub fn answered(&mut self, sensor: u16) {
        if let Some(i) = self.slot(sensor) {
            self.answered[i] = true;
        }
    }

    /// How many own sensors were activated at least [`UNANSWERED_AFTER`]
    /// times and never answered, and the first of them.
    pub fn unanswered(&self) -> (u16, Option<u16>) {
        let mut silent = self
            .own
            .iter()
            .zip(&self.activated)
            .zip(&self.answered)
            .filter(|((_, n), answered)| **n >= UNANSWERED_AFTER && !**answered)
            .map(|((s, _), _)| *s);
        let first = silent.next();
        (first.map_or(0, |_| 1 + silent.count() as u16), first)
    }
}

#[cfg(test)]
mod answer_tests {
    use super::*;

    #[test]
    fn a_sensor_activated_again_and_again_without_an_answer_is_named() {
        let mut a = SensorAnswers::new(&[10, 11, 12]);
        for _ in 0..UNANSWERED_AFTER - 1 {
            a.activated(&[10, 11]);
        }
        assert_eq!(a.unanswered(), (0, None), "one activation short");
        a.activated(&[10, 11]);
        a.answered(10);
        assert_eq!(a.unanswered(), (1, Some(11)));
        a.activated(&[12; UNANSWERED_AFTER as usize]);
        assert_eq!(a.unanswered(), (2, Some(11)));
        a.answered(11);
        a.answered(99); // not ours
        assert_eq!(a.unanswered(), (1, Some(12)));
    }
}
