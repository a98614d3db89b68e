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
fn in_range(value: ObservedValue, cells: Option<usize>) -> bool {
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
