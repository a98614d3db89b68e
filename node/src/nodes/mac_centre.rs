//! A fusion centre that hears its sensors through a multiple-access
//! channel (a scenario with a `[channel]`; dissertation ch. 4), as an
//! I/O-free state machine driven as every processing node is.
//!
//! A step: the launcher's `BeginStep` → [`Work::Design`]: the
//! particle filter's prediction, each sensor's `G_j = E[∇a_j ∇a_jᵀ]` over
//! the predicted particles, and the design of the step's slots (the
//! transmission probabilities that maximize `det J`, and a sensing matrix
//! drawn from them, by eq. 4.19's approximation or by the expected
//! information of the drawn matrix; or every sensor alike; or random
//! sensors; or all) → the schedule
//! (`activate_slots`) to the sensors and the channel → the channel's
//! delivery `z`, until it arrives or the listening deadline →
//! [`Work::WeighDelivery`]: the particles weighed by `N(z; Φa(x), rΦΦᵀ + εI)`
//! (eq. 4.13) → telemetry with the estimate, the design, and two bounds
//! from the recursion of eq. 4.8: the PCRLB given the drawn Φ (eq. 4.14,
//! carried to the next step) and, as the auxiliary bound, the one the
//! design promised: eq. 4.19's for `compressive`, the drawn matrix's
//! expected information (estimated from sample matrices) for
//! `counted_once` and `uniform`, and the exact one for `random` and
//! `all`.
//!
//! The centre does not know who was heard. A sensor that misses its slot
//! is absent from a sum the centre weighs as if it were there; a delivery
//! that never comes is a lost step: the centre reports its prediction,
//! and its information is the prediction's alone.

use std::time::Duration;

use bounds::compressive::{
    counted_once_probabilities, expected_outer_product, gamma_weights, optimal_probabilities,
    predicted_information, random_selection, with_observations, DesignProblem, DrawnMatrices,
    MacLikelihood, PositionBlock, SensingMatrix, SAMPLES,
};
use bounds::{Mat4, ObservationModel, State};
use fusion_graph::scenario::{MacConfig, MacDesign, Scenario};
use fusion_graph::{stream_rng, ActorId, Stream, Topology};
use fusion_graph::{Channel, Wiring};
use nalgebra::Cholesky;
use rand_chacha::ChaCha8Rng;
use wire::{Message, Payload, SlotColumn, Stage};

use crate::filter::ParticleFilter;
use crate::fusion::Handled;
use crate::{NodeError, ObservedValue, Outgoing, Work};

use super::{NodeCore, NodeKind, Report};

/// One step, from `BeginStep` to its telemetry.
struct Stepping {
    step: u32,
    /// The design, once [`Work::Design`] ran.
    design: Option<Design>,
    /// The listening deadline, from the schedule's sending.
    deadline: Option<Duration>,
    /// The channel's delivery.
    received: Option<Vec<f64>>,
    weighed: bool,
    estimate: State,
    select_time: Duration,
    weigh_time: Duration,
}

/// A step's design: who transmits where, and what it is worth.
struct Design {
    likelihood: MacLikelihood,
    /// Each sensor's transmission probability.
    probabilities: Vec<f64>,
    /// `J` before the step's observations; with those of the drawn Φ
    /// (eq. 4.14 given Φ); and with those the design promised.
    predicted: Mat4,
    information: Mat4,
    promised: Mat4,
}

pub struct MacCentre {
    core: NodeCore,
    index: u16,
    seed: u64,
    own: Vec<u16>,
    /// What it publishes on (see its [`Wiring`]).
    publications: Vec<Channel>,
    models: Vec<ObservationModel>,
    mac: MacConfig,
    /// The sensors' measurement noise variance r (eq. 4.2).
    r: f64,
    filter: ParticleFilter,
    rng: ChaCha8Rng,
    dynamics: bounds::Dynamics,
    /// `J` of the last step (eq. 4.8), from `P_0⁻¹`.
    information: Mat4,
    blocks: Vec<PositionBlock>,
    listen: Duration,
    stepping: Option<Box<Stepping>>,
}

impl MacCentre {
    pub fn new(scenario: &Scenario, topology: &Topology, index: u16) -> Result<Self, NodeError> {
        let models = scenario.models()?;
        let mac = scenario
            .channel
            .clone()
            .expect("a fusion centre is built for a scenario with a channel");
        let own = topology.node_sensors[index as usize].clone();
        let sensor_models: Vec<ObservationModel> = own
            .iter()
            .map(|s| models.law.at(topology.sensor_positions[*s as usize]))
            .collect();
        let r = sensor_models
            .first()
            .map_or(1.0, |m| m.evaluate(&State::zeros()).r);
        let prior = scenario.network_prior(&models);
        let id = ActorId::Node(index);
        let mut rng = stream_rng(scenario.seed, id, 0, Stream::FusionFilter);
        let filter_error = |source| NodeError::Filter {
            node: index,
            source,
        };
        let filter =
            ParticleFilter::from_gaussian(scenario.filter.particles as usize, &prior, &mut rng)
                .ok_or(filter_error(bounds::BoundError::NotPositiveDefinite(
                    "the prior covariance",
                )))?
                .with_resampling(scenario.filter.resampler);
        let information = Cholesky::new(prior.cov)
            .ok_or(filter_error(bounds::BoundError::NotPositiveDefinite(
                "the prior covariance",
            )))?
            .inverse();
        // Twice the channel's own wait: the centre hears the channel only
        // after the channel stops hearing its sensors.
        let listen = Duration::from_secs_f64(2.0 * mac.slot_timeout_ms / 1e3);
        Ok(Self {
            // Its sensors answer the channel, never the centre.
            core: NodeCore::new(scenario, topology, index, None),
            index,
            seed: scenario.seed,
            blocks: vec![[0.0; 3]; own.len()],
            own,
            publications: topology
                .activation_channels(index)
                .chain([Channel::Telemetry(index)])
                .collect(),
            models: sensor_models,
            mac,
            r,
            filter,
            rng,
            dynamics: models.dynamics,
            information,
            listen,
            stepping: None,
        })
    }

    /// [`Work::Design`]: the prediction, the sensors' `G_j` over
    /// it, and the step's design.
    fn design(&mut self) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        if s.design.is_some() {
            return;
        }
        self.filter.predict(&self.dynamics, &mut self.rng);
        let particles = self.filter.particles();
        let weights = self.filter.uniform_weights();
        for (block, model) in self.blocks.iter_mut().zip(&self.models) {
            *block = expected_outer_product(particles, weights, |x| model.evaluate(x).grad_g);
        }
        // The transition is linear (constant velocity): its Jacobian is F.
        let f = self.dynamics.jacobian(&State::zeros());
        let predicted = predicted_information(&self.information, &f, self.dynamics.q_inv())
            .unwrap_or(self.information);
        let n = self.own.len();
        let epsilon = self.mac.receiver_noise;
        let mut rng = stream_rng(
            self.seed,
            ActorId::Node(self.index),
            s.step,
            Stream::SensingMatrix,
        );
        let parallel = 1.0 / (self.r + epsilon);
        let slots = self.mac.slots as usize;
        let problem = DesignProblem {
            predicted,
            blocks: &self.blocks,
            slots,
            energy: self.mac.energy,
            r: self.r,
            epsilon,
        };
        let mut samples = stream_rng(
            self.seed,
            ActorId::Node(self.index),
            s.step,
            Stream::DesignSamples,
        );
        let (phi, probabilities, gains) = match self.mac.design {
            MacDesign::Compressive => {
                let p = optimal_probabilities(&problem).unwrap_or_else(|| vec![0.0; n]);
                let phi = SensingMatrix::draw(&p, slots, &mut rng);
                let gains = gamma_weights(&p, slots, self.r, epsilon);
                (phi, p, gains)
            }
            MacDesign::CountedOnce => {
                let (p, gains) = counted_once_probabilities(&problem, SAMPLES, &mut samples)
                    .map_or_else(
                        || (vec![0.0; n], vec![0.0; n]),
                        |d| (d.probabilities, d.weights),
                    );
                (SensingMatrix::draw(&p, slots, &mut rng), p, gains)
            }
            MacDesign::Uniform => {
                let p = vec![(problem.largest_total() / n as f64).min(1.0); n];
                let mut gains = vec![0.0; n];
                DrawnMatrices::draw(&p, slots, self.r, epsilon, SAMPLES, &mut samples)
                    .counted_once(&p, &mut gains);
                (SensingMatrix::draw(&p, slots, &mut rng), p, gains)
            }
            MacDesign::Random => {
                let chosen = random_selection(self.mac.energy as usize, n, &mut rng);
                let mut p = vec![0.0; n];
                for j in &chosen {
                    p[*j] = 1.0;
                }
                let gains = p.iter().map(|pj| pj * parallel).collect();
                (SensingMatrix::selection(&chosen, n), p, gains)
            }
            MacDesign::All => (SensingMatrix::identity(n), vec![1.0; n], vec![parallel; n]),
        };
        let promised = with_observations(&predicted, &self.blocks, &gains);
        let likelihood = MacLikelihood::new(phi, self.r, epsilon)
            .expect("validated: the receiver's noise is positive");
        let models = &self.models;
        let drawn = likelihood.information(particles, weights, |j, x| models[j].evaluate(x).grad_g);
        let information = with_observations(&predicted, &[drawn], &[1.0]);
        s.design = Some(Design {
            likelihood,
            probabilities,
            predicted,
            information,
            promised,
        });
    }
}

impl NodeKind for MacCentre {
    fn core(&mut self) -> &mut NodeCore {
        &mut self.core
    }

    /// Reported with what it has: its prediction, if nothing was weighed.
    fn finish_overrun(&mut self, _: Duration, out: &mut Vec<Outgoing>) {
        self.report(out)
    }

    fn begin_step(&mut self, step: u32, _: u32, _: Duration, _: &mut Vec<Outgoing>) {
        self.stepping = Some(Box::new(Stepping {
            step,
            design: None,
            deadline: None,
            received: None,
            weighed: false,
            estimate: State::zeros(),
            select_time: Duration::ZERO,
            weigh_time: Duration::ZERO,
        }));
    }

    /// Its sensors transmit to the channel, never to the centre.
    fn observe(&mut self, step: u32, sensor: u16, _: ObservedValue, _: &mut Vec<Outgoing>) {
        tracing::debug!(
            node = self.index,
            sensor,
            step,
            "ignored an observation sent past the channel"
        );
    }

    /// The channel's delivery; one for another step, or with another count
    /// of slots than the step's, is counted late and dropped.
    fn take(&mut self, message: &Message, _now: Duration, _out: &mut Vec<Outgoing>) {
        let step = message.header.step;
        match (&message.payload, message.header.sender) {
            (Payload::MacOutput { values }, ActorId::Mac(m)) if m == self.index => {
                let slots = self
                    .stepping
                    .as_ref()
                    .and_then(|s| s.design.as_ref())
                    .map(|d| d.likelihood.sensing_matrix().slots());
                match self.stepping.as_mut() {
                    Some(s)
                        if s.step == step
                            && s.received.is_none()
                            && slots == Some(values.len()) =>
                    {
                        s.received = Some(values.clone())
                    }
                    _ => self.core.count_late(),
                }
            }
            _ => {
                self.core.taken(Handled::NotMine, message);
            }
        }
    }

    /// It reads its control and its channel's deliveries, publishes an
    /// activation channel to each of its sensors and to its channel, and
    /// its telemetry, and wakes its sensors and its channel (the schedule)
    /// and the launcher.
    fn wiring(&mut self) -> Wiring {
        let mut wakes: Vec<ActorId> = self.own.iter().map(|s| ActorId::Sensor(*s)).collect();
        wakes.push(ActorId::Mac(self.index));
        wakes.push(ActorId::Launcher);
        Wiring {
            actor: self.core.id(),
            reads: vec![
                Channel::Control(self.core.id()),
                Channel::MacOutput(self.index),
            ],
            publishes: self.publications.clone(),
            wakes,
        }
    }

    fn poll_timeout(&self) -> Option<Duration> {
        let s = self.stepping.as_ref()?;
        s.received.is_none().then_some(s.deadline).flatten()
    }

    /// A delivery that did not come by the deadline: a lost step.
    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let lost = self
            .stepping
            .as_ref()
            .is_some_and(|s| s.received.is_none() && s.deadline.is_some_and(|d| now >= d));
        if lost {
            self.report(out);
        }
    }

    fn poll_work(&self) -> Option<Work> {
        let s = self.stepping.as_ref()?;
        match (&s.design, &s.received) {
            (None, _) => Some(Work::Design),
            (Some(_), Some(_)) if !s.weighed => Some(Work::WeighDelivery),
            _ => None,
        }
    }

    fn run_work(&mut self, work: Work) {
        match work {
            Work::Design => self.design(),
            Work::WeighDelivery => self.weigh(),
            _ => {}
        }
    }

    fn work_done(&mut self, work: Work, elapsed: Duration, now: Duration, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        match work {
            Work::Design if s.deadline.is_none() => {
                s.select_time = elapsed;
                s.deadline = Some(now + self.listen);
                let step = s.step;
                if let Some(d) = s.design.as_ref() {
                    out.extend(schedule(&self.core, &self.own, step, d));
                }
            }
            Work::WeighDelivery => {
                s.weigh_time = elapsed;
                self.report(out);
            }
            _ => {}
        }
    }
}

/// The schedule of node `index`'s step, each transmitting sensor's column:
/// to each transmitter and to the channel, each on its own activation
/// channel (a sensor that does not transmit hears nothing and sleeps).
fn schedule(core: &NodeCore, own: &[u16], step: u32, design: &Design) -> Vec<Outgoing> {
    let index = core.index();
    let phi = design.likelihood.sensing_matrix();
    let transmitters = design.likelihood.transmitters();
    let columns: Vec<SlotColumn> = transmitters
        .iter()
        .map(|&j| {
            let (slots, negative) = phi.column(j);
            SlotColumn {
                sensor: j as u16,
                slots,
                negative,
            }
        })
        .collect();
    let message = Message::new(
        ActorId::Node(index),
        step,
        0,
        Payload::ActivateSlots {
            slots: phi.slots() as u8,
            columns,
        },
    );
    let receivers = transmitters
        .iter()
        .map(|&j| ActorId::Sensor(own[j]))
        .chain([ActorId::Mac(index)]);
    core.to_each(&message, receivers).collect()
}

impl MacCentre {
    /// [`Work::WeighDelivery`]: the particles weighed by eq. 4.13; the estimate is
    /// the weighted mean, then they are resampled.
    fn weigh(&mut self) {
        let Some(s) = self.stepping.as_mut() else {
            return;
        };
        let (Some(design), Some(z)) = (&s.design, &s.received) else {
            return;
        };
        if s.weighed {
            return;
        }
        let (likelihood, models) = (&design.likelihood, &self.models);
        self.filter.update_batched(&mut self.rng, |particles, out| {
            for (l, x) in out.iter_mut().zip(particles) {
                *l = likelihood.ln_likelihood(z, |j| models[j].evaluate(x).g);
            }
        });
        s.estimate = self.filter.summary().mean;
        self.filter.resample(&mut self.rng);
        s.weighed = true;
    }

    /// The step's telemetry. A step without the channel's delivery reports
    /// its prediction, and carries the prediction's information alone.
    fn report(&mut self, out: &mut Vec<Outgoing>) {
        let Some(s) = self.stepping.take() else {
            return;
        };
        let heard = s.weighed;
        let estimate = if heard {
            s.estimate
        } else {
            // Uniform weights after the prediction: the prediction's mean.
            self.filter.summary().mean
        };
        let (bound, promised, active, design, slots) = match &s.design {
            Some(d) => {
                self.information = if heard { d.information } else { d.predicted };
                let active = d
                    .likelihood
                    .transmitters()
                    .iter()
                    .map(|&j| self.own[j])
                    .collect();
                let design = d
                    .probabilities
                    .iter()
                    .map(|p| (p.clamp(0.0, 1.0) * 1e4).round() as u16)
                    .collect();
                (
                    bounds::position_bound(&self.information),
                    bounds::position_bound(&d.promised),
                    active,
                    design,
                    d.likelihood.sensing_matrix().slots(),
                )
            }
            None => (None, None, Vec::new(), Vec::new(), 0),
        };
        let report = Report::of(&estimate)
            .bound(bound)
            // What eq. 4.19 promised the design: beside the bound of the
            // drawn Φ, it shows how far the approximation is off.
            .aux_bound(promised)
            .observations(if heard { slots as u16 } else { 0 })
            .stage(Stage::Global, s.weigh_time)
            .stage(Stage::Selection, s.select_time)
            // The design is its scoring, and runs in the step.
            .stage(Stage::Scoring, s.select_time)
            .active(active)
            .design(design);
        out.push(self.core.report(s.step, report));
    }
}
