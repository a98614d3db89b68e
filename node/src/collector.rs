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
        if let (ObservedValue::Cell(c), Some(cells)) = (value, self.cells) {
            if c as usize >= cells {
                return Offer::Invalid;
            }
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

#[cfg(test)]
mod tests {
    use super::*;

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
