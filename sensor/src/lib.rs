//! The sensor actor as an I/O-free state machine.
//!
//! A sensor wakes when its node activates it for step k. It then looks at
//! the target: it reads the true state of step k from the world
//! ([`WorldView`], the launcher's ring in shared memory), measures through
//! its observation model, quantizes (or not) and emits one observation
//! message. The truth is never a message. The noise of step k
//! is drawn from a generator seeded by (scenario seed, sensor, k), so the
//! observation does not depend on message timing: the in-process driver and
//! the multi-process runtime see the same values.
//!
//! A `sensor` fault in the scenario makes it misbehave for a while: stuck at
//! its last honest value, biased, silent, or Byzantine (measuring a phantom
//! target). Every sensor evaluates the schedule itself, as links do.
//!
//! Behind a multiple-access channel ([`mac`]), a sensor's activation is its
//! column of the sensing matrix: it transmits its raw measurement, signed
//! as the column says, in each of its slots, to the channel.

pub mod mac;

use bounds::censoring::{CensoringRule, Feedback, NisCensor};
use bounds::{Dynamics, ObservationModel, Quantizer, State};
use fusion_graph::faults::{FaultSchedule, SensorFault};
use fusion_graph::scenario::{CensoringPolicy, Scenario};
use fusion_graph::world::{TruthMissing, WorldView};
use std::time::Duration;

use fusion_graph::{stream_rng, ActorId, ScenarioError, Stream, Topology};
use fusion_graph::{Actor, Channel, Outgoing, Wiring};
use rand::Rng;
use wire::{unpack_mat4, Message, Payload};

#[derive(Debug, Clone)]
pub struct SensorActor {
    index: u16,
    owner: u16,
    /// This sensor's place in its node's list: its bit in the activation mask.
    slot: usize,
    model: ObservationModel,
    quantizer: Option<Quantizer>,
    seed: u64,
    /// The latest step this sensor was activated for.
    activated: Option<u32>,
    last_sent: Option<u32>,
    faults: FaultSchedule,
    /// The last honest measurement, which a stuck sensor repeats.
    last_honest: Option<Payload>,
    censor: Censor,
    /// The node's feedback with the latest activation, for NIS censoring.
    feedback: Option<(u32, Feedback)>,
    /// The quantizer the node sent with the latest activation, for its
    /// step (a locator designs its sensors' thresholds).
    sent_quantizer: Option<(u32, Quantizer)>,
    /// The latest step's column of a sensing matrix: (step, slots, slots
    /// negated), when this sensor transmits on a multiple-access channel.
    column: Option<(u32, u32, u32)>,
    /// The last honest raw measurement, which a stuck sensor repeats on a
    /// channel.
    last_honest_value: Option<f64>,
    /// Its node, or the channel in front of it.
    reports_to: ActorId,
}

/// A sensor as its drivers run it: with the world it looks at and the
/// actors its observations go to (its node or channel, and in a run with
/// a centralized reference the launcher too).
pub struct SensorInWorld<W> {
    sensor: SensorActor,
    world: W,
    receivers: Vec<ActorId>,
    world_misses: u32,
}

impl SensorActor {
    /// This sensor looking at `world`; `and_launcher` also sends its
    /// observations to the launcher's centralized reference.
    pub fn in_world<W: WorldView>(self, world: W, and_launcher: bool) -> SensorInWorld<W> {
        let mut receivers = vec![self.reports_to];
        if and_launcher {
            receivers.push(ActorId::Launcher);
        }
        SensorInWorld {
            sensor: self,
            world,
            receivers,
            world_misses: 0,
        }
    }
}

impl<W: WorldView> Actor for SensorInWorld<W> {
    /// A sensor's work is its answer, too light to time apart.
    type Work = ();

    fn wiring(&self) -> Wiring {
        Wiring {
            actor: self.sensor.id(),
            reads: self.sensor.subscriptions().to_vec(),
            publishes: vec![self.sensor.publication()],
            wakes: self.receivers.clone(),
        }
    }

    /// A step the world does not hold is counted ([`Actor::take_world_misses`])
    /// and logged; the sensor stays silent for that step.
    fn handle(&mut self, message: &Message, _now: Duration, out: &mut Vec<Outgoing>) {
        match self.sensor.answer(message, &self.world) {
            Ok(Some(observation)) => out.push(Outgoing {
                channel: self.sensor.publication(),
                message: observation,
                receivers: self.receivers.clone(),
                wake: None,
            }),
            Ok(None) => {}
            Err(missing) => {
                tracing::warn!(sensor = %self.sensor.id(), error = %missing, "no observation this step");
                self.world_misses += 1;
            }
        }
    }

    fn take_world_misses(&mut self) -> u32 {
        std::mem::take(&mut self.world_misses)
    }
}

/// Whether this sensor stays silent when activated.
#[derive(Debug, Clone)]
enum Censor {
    Never,
    /// When the NIS against the fed-back prediction is below threshold.
    Nis {
        censor: Box<NisCensor>,
        dynamics: Box<Dynamics>,
    },
    /// At random, sending with this probability.
    Random(f64),
}

impl SensorActor {
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
    ) -> Result<Self, ScenarioError> {
        let models = scenario.models()?;
        let owner = topology.sensor_owner[index as usize];
        let slot = topology.node_sensors[owner as usize]
            .iter()
            .position(|s| *s == index)
            .expect("the topology lists every sensor under its owner");
        Ok(Self {
            index,
            owner,
            slot,
            model: models.law.at(topology.sensor_positions[index as usize]),
            quantizer: models.quantizer,
            seed: scenario.seed,
            activated: None,
            last_sent: None,
            faults: FaultSchedule::new(&scenario.faults),
            last_honest: None,
            censor: censor(scenario)?,
            feedback: None,
            sent_quantizer: None,
            column: None,
            last_honest_value: None,
            reports_to: topology.reports_to(index),
        })
    }

    pub fn id(&self) -> ActorId {
        ActorId::Sensor(self.index)
    }

    /// The node this sensor belongs to.
    pub fn owner(&self) -> ActorId {
        ActorId::Node(self.owner)
    }

    /// Whom its observations go to: its node, or the multiple-access
    /// channel in front of it.
    pub fn reports_to(&self) -> ActorId {
        self.reports_to
    }

    /// The channels this sensor reads: the launcher's lifecycle (the stop)
    /// and its own activation.
    pub fn subscriptions(&self) -> [Channel; 2] {
        [
            Channel::Lifecycle,
            Channel::Activation {
                node: self.owner,
                to: self.id(),
            },
        ]
    }

    /// The channel its observations go out on.
    pub fn publication(&self) -> Channel {
        Channel::Observation(self.index)
    }

    /// Answers one message: its node's activation, with the observation
    /// of the activation's step, looking at the target in `world`;
    /// anything else is ignored. A step the world does not hold is an
    /// error, never a stale observation.
    pub fn answer(
        &mut self,
        message: &Message,
        world: &dyn WorldView,
    ) -> Result<Option<Message>, TruthMissing> {
        let step = message.header.step;
        match (&message.payload, message.header.sender) {
            (Payload::Activate { mask }, ActorId::Node(n)) if n == self.owner => {
                if mask.contains(self.slot) {
                    self.activated = Some(step);
                }
            }
            (
                Payload::ActivateWithFeedback {
                    mask,
                    estimate,
                    covariance,
                },
                ActorId::Node(n),
            ) if n == self.owner => {
                if mask.contains(self.slot) {
                    self.activated = Some(step);
                    self.feedback = Some((
                        step,
                        Feedback {
                            estimate: State::from(*estimate),
                            covariance: covariance.as_ref().map(unpack_mat4),
                        },
                    ));
                }
            }
            (Payload::ActivateThresholds { mask, thresholds }, ActorId::Node(n))
                if n == self.owner =>
            {
                if mask.contains(self.slot) {
                    // Thresholds for another quantizer than the scenario's
                    // (a count that does not match its bits) would send
                    // cells the node cannot read: the activation is refused.
                    let cells = self.quantizer.as_ref().map_or(0, Quantizer::cells);
                    match Quantizer::from_thresholds(thresholds) {
                        Ok(q) if q.cells() == cells => {
                            self.activated = Some(step);
                            self.sent_quantizer = Some((step, q));
                        }
                        _ => {
                            tracing::warn!(
                                sensor = self.index,
                                step,
                                "thresholds for another quantizer; activation ignored"
                            );
                            return Ok(None);
                        }
                    }
                }
            }
            (Payload::ActivateSlots { columns, .. }, ActorId::Node(n)) if n == self.owner => {
                let mine = columns.iter().find(|c| c.sensor as usize == self.slot);
                if let Some(c) = mine {
                    self.activated = Some(step);
                    self.column = Some((step, c.slots, c.negative));
                }
            }
            _ => return Ok(None),
        }
        if self.activated != Some(step) || self.last_sent == Some(step) {
            return Ok(None);
        }
        // Once a step, whether or not the world holds it: a duplicated
        // activation is not a second look.
        self.last_sent = Some(step);
        let truth = world.truth(step)?;
        Ok(self.observe(step, &truth))
    }

    /// The message that answers step `step`'s activation, the target being
    /// at `truth`: an observation as this sensor's faults make it, or its
    /// transmissions on a multiple-access channel; none when it is silent.
    fn observe(&mut self, step: u32, truth: &State) -> Option<Message> {
        let truth = *truth;
        if let Some((_, slots, negative)) = self.column.filter(|c| c.0 == step) {
            return self.transmit(step, &truth, slots, negative);
        }
        let payload = match self.faults.sensor_fault(step, self.index) {
            None => {
                let z = self.measure_raw(step, &truth, 0.0);
                if !self.sends(step, z) {
                    return None;
                }
                let honest = self.encode(step, z);
                self.last_honest = Some(honest.clone());
                honest
            }
            Some(SensorFault::Dropout) => return None,
            // Stuck from its first step, if it never measured before.
            Some(SensorFault::Stuck) => {
                if self.last_honest.is_none() {
                    self.last_honest = Some(self.measure(step, &truth, 0.0));
                }
                self.last_honest.clone().expect("set above")
            }
            Some(SensorFault::Bias(bias)) => self.measure(step, &truth, bias),
            Some(SensorFault::Byzantine([dx, dy])) => {
                let mut phantom = truth;
                phantom[0] += dx;
                phantom[1] += dy;
                self.measure(step, &phantom, 0.0)
            }
        };
        Some(Message::new(self.id(), step, 0, payload))
    }

    /// Its transmissions on a multiple-access channel: the raw measurement
    /// (as its faults make it) in each of its slots, negated where the
    /// column says.
    fn transmit(&mut self, step: u32, truth: &State, slots: u32, negative: u32) -> Option<Message> {
        let value = match self.faults.sensor_fault(step, self.index) {
            None => {
                let z = self.measure_raw(step, truth, 0.0);
                self.last_honest_value = Some(z);
                z
            }
            Some(SensorFault::Dropout) => return None,
            Some(SensorFault::Stuck) => match self.last_honest_value {
                Some(z) => z,
                None => *self
                    .last_honest_value
                    .insert(self.measure_raw(step, truth, 0.0)),
            },
            Some(SensorFault::Bias(bias)) => self.measure_raw(step, truth, bias),
            Some(SensorFault::Byzantine([dx, dy])) => {
                let mut phantom = *truth;
                phantom[0] += dx;
                phantom[1] += dy;
                self.measure_raw(step, &phantom, 0.0)
            }
        };
        let values = (0..32)
            .filter(|i| slots & (1 << i) != 0)
            .map(|i| {
                if negative & (1 << i) != 0 {
                    -value
                } else {
                    value
                }
            })
            .collect();
        Some(Message::new(
            self.id(),
            step,
            0,
            Payload::SlotValues { slots, values },
        ))
    }

    /// A measurement of `truth`, plus `bias`, with step `step`'s noise.
    fn measure(&self, step: u32, truth: &State, bias: f64) -> Payload {
        self.encode(step, self.measure_raw(step, truth, bias))
    }

    fn measure_raw(&self, step: u32, truth: &State, bias: f64) -> f64 {
        let mut rng = stream_rng(self.seed, self.id(), step, Stream::SensorNoise);
        let z = self.model.sample(truth, &mut rng) + bias;
        if self.model.is_angular() {
            bounds::wrap_angle(z)
        } else {
            z
        }
    }

    /// The report of `z`: its cell under the quantizer the node sent for
    /// this step, else the scenario's; `z` itself when raw.
    fn encode(&self, step: u32, z: f64) -> Payload {
        let sent = self
            .sent_quantizer
            .as_ref()
            .filter(|(s, _)| *s == step)
            .map(|(_, q)| q);
        match sent.or(self.quantizer.as_ref()) {
            Some(q) => Payload::Observation { cell: q.encode(z) },
            None => Payload::RawObservation { value: z },
        }
    }

    /// The censoring decision on the unquantized measurement. A NIS sensor
    /// without this step's feedback sends: silence it cannot justify would
    /// mislead its node.
    fn sends(&mut self, step: u32, z: f64) -> bool {
        match &mut self.censor {
            Censor::Never => true,
            Censor::Random(p) => {
                let mut rng = stream_rng(
                    self.seed,
                    ActorId::Sensor(self.index),
                    step,
                    Stream::Censoring,
                );
                rng.random::<f64>() < *p
            }
            Censor::Nis { censor, dynamics } => match &self.feedback {
                Some((s, feedback)) if *s == step => {
                    let innovation = censor.innovation(step, feedback, &self.model, dynamics);
                    censor.rule.sends(innovation.nis(z))
                }
                _ => true,
            },
        }
    }
}

/// The scenario's censoring, as this sensor applies it.
fn censor(scenario: &Scenario) -> Result<Censor, ScenarioError> {
    let c = &scenario.censoring;
    let active = scenario.sensors.active_per_node as usize;
    Ok(match c.policy {
        CensoringPolicy::Off => Censor::Never,
        CensoringPolicy::Random => Censor::Random(c.budget / active as f64),
        CensoringPolicy::Nis => {
            let models = scenario.models()?;
            let rule = CensoringRule::for_budget(c.budget, active, 1).map_err(|e| {
                ScenarioError::Invalid {
                    file: scenario.name.clone(),
                    key: "censoring.budget".into(),
                    expected: e.expected.into(),
                    got: e.value.to_string(),
                }
            })?;
            Censor::Nis {
                censor: Box::new(NisCensor::new(rule, models.prior_cov)),
                dynamics: Box::new(models.dynamics),
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use bounds::Mat4;
    use fusion_graph::BitMask;

    fn actor() -> SensorActor {
        let s = Scenario::default_scenario();
        let t = Topology::from_scenario(&s, "d").unwrap();
        SensorActor::new(&s, &t, 12).unwrap()
    }

    use fusion_graph::world::StillTarget as Still;

    /// Sensor 12 is the 13th of node 0's sensors.
    fn activation(step: u32, active: bool) -> Message {
        let mask = BitMask::from_indices(active.then_some(12));
        Message::new(ActorId::Node(0), step, 0, Payload::Activate { mask })
    }

    fn censoring_actor(overrides: &[&str]) -> SensorActor {
        let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
        let s =
            Scenario::from_toml(fusion_graph::scenario::DEFAULT_SCENARIO, "d", &overrides).unwrap();
        let t = Topology::from_scenario(&s, "d").unwrap();
        SensorActor::new(&s, &t, 12).unwrap()
    }

    fn activation_with_feedback(step: u32, estimate: State, variance: f64) -> Message {
        let cov = Mat4::identity() * variance;
        Message::new(
            ActorId::Node(0),
            step,
            0,
            Payload::ActivateWithFeedback {
                mask: BitMask::from_indices([12]),
                estimate: estimate.into(),
                covariance: Some(wire::pack_mat4(&cov)),
            },
        )
    }

    /// CFwMD2 with a budget of 1 of 3: a sensor whose measurement matches
    /// the fed-back prediction stays silent, and one fed a prediction far
    /// off sends; without this step's feedback it sends.
    #[test]
    fn a_nis_sensor_sends_only_what_the_prediction_did_not_foresee() {
        let censoring = [
            "censoring.policy=nis",
            "censoring.budget=1",
            "censoring.feedback=estimate_and_covariance",
        ];
        let truth = State::new(1000.0, 900.0, -6.0, -7.0);
        // The estimate one step back, so that its prediction is the truth.
        let before = State::new(1006.0, 907.0, -6.0, -7.0);
        let (mut silent, mut sent) = (0, 0);
        for step in 1..=40 {
            let mut a = censoring_actor(&censoring);
            match a
                .answer(&activation_with_feedback(step, before, 1.0), &Still(truth))
                .unwrap()
            {
                Some(_) => sent += 1,
                None => silent += 1,
            }
        }
        // NIS ~ χ²₁ scaled by r/s < 1: sending (p ≤ 1/3) is rarer still.
        assert!(silent > 25, "{silent} silent, {sent} sent");
        let far = State::new(1200.0, 700.0, -6.0, -7.0);
        for step in 1..=10 {
            let mut a = censoring_actor(&censoring);
            assert!(
                a.answer(&activation_with_feedback(step, far, 1.0), &Still(truth))
                    .unwrap()
                    .is_some(),
                "a prediction 280 m off must not silence the sensor"
            );
        }
        let mut a = censoring_actor(&censoring);
        assert!(
            a.answer(&activation(3, true), &Still(truth))
                .unwrap()
                .is_some(),
            "no feedback: send"
        );
    }

    #[test]
    fn a_random_censor_sends_with_the_budgets_probability() {
        let truth = State::new(1000.0, 900.0, -6.0, -7.0);
        let mut a = censoring_actor(&["censoring.policy=random", "censoring.budget=0.6"]);
        let steps = 3000;
        let sent = (1..=steps)
            .filter(|&step| {
                a.answer(&activation(step, true), &Still(truth))
                    .unwrap()
                    .is_some()
            })
            .count() as f64;
        // p = 0.6 / 3 = 0.2; five standard errors.
        let (p, n) = (0.2, steps as f64);
        assert!(
            (sent / n - p).abs() < 5.0 * (p * (1.0 - p) / n).sqrt(),
            "{}",
            sent / n
        );
    }

    /// Behind a channel a sensor transmits its raw measurement in each of
    /// its slots, negated where its column says, to the channel; a sensor
    /// whose column is not in the schedule stays silent.
    #[test]
    fn a_sensor_transmits_its_measurement_signed_in_each_of_its_slots() {
        let s =
            Scenario::from_toml(fusion_graph::scenario::COMPRESSIVE_SCENARIO, "c", &[]).unwrap();
        let t = Topology::from_scenario(&s, "c").unwrap();
        let truth = State::new(7.0, 9.0, 2.0, 2.0);
        let schedule = |sensor: u16| {
            Message::new(
                ActorId::Node(0),
                3,
                0,
                Payload::ActivateSlots {
                    slots: 4,
                    columns: vec![wire::SlotColumn {
                        sensor,
                        slots: 0b1011,
                        negative: 0b0010,
                    }],
                },
            )
        };
        let mut a = SensorActor::new(&s, &t, 6).unwrap();
        assert_eq!(a.reports_to(), ActorId::Mac(0));
        let Some(Message {
            payload: Payload::SlotValues { slots, values },
            ..
        }) = a.answer(&schedule(6), &Still(truth)).unwrap()
        else {
            panic!("no transmission")
        };
        let z = a.measure_raw(3, &truth, 0.0);
        assert_eq!(slots, 0b1011);
        assert_eq!(values, vec![z, -z, z]);
        let mut other = SensorActor::new(&s, &t, 7).unwrap();
        assert!(
            other.answer(&schedule(6), &Still(truth)).unwrap().is_none(),
            "not scheduled: silent"
        );
    }

    /// A world that holds only step 1.
    struct OnlyStepOne(State);

    impl WorldView for OnlyStepOne {
        fn truth(&self, step: u32) -> Result<State, TruthMissing> {
            match step {
                1 => Ok(self.0),
                0 => Err(TruthMissing::Overwritten {
                    step,
                    latest: 1,
                    held: 1,
                }),
                _ => Err(TruthMissing::NotYetWritten { step, latest: 1 }),
            }
        }
    }

    #[test]
    fn measures_once_per_step_and_never_a_step_the_world_does_not_hold() {
        let truth = State::new(1000.0, 900.0, -6.0, -7.0);
        let world = OnlyStepOne(truth);
        let mut a = actor();
        let first = a.answer(&activation(1, true), &world).unwrap().unwrap();
        assert_eq!(
            a.answer(&activation(1, true), &world),
            Ok(None),
            "one observation per step"
        );
        let second = actor().answer(&activation(1, true), &Still(truth)).unwrap();
        assert_eq!(Some(first), second, "the same look at the same target");
        // Not activated: silent, and the world is not read.
        assert_eq!(a.answer(&activation(2, false), &world), Ok(None));
        // Activated for a step the world has not written: an error, once.
        assert_eq!(
            a.answer(&activation(2, true), &world),
            Err(TruthMissing::NotYetWritten { step: 2, latest: 1 })
        );
        assert_eq!(a.answer(&activation(2, true), &world), Ok(None));
    }

    #[test]
    fn quantized_observation_lands_near_the_true_bearing() {
        let truth = State::new(1000.0, 900.0, -6.0, -7.0);
        let mut a = actor();
        let q = Scenario::default_scenario()
            .models()
            .unwrap()
            .quantizer
            .unwrap();
        let e = a.model.evaluate(&truth);
        let mut misses = 0;
        for step in 1..=200 {
            let Some(Message {
                payload: Payload::Observation { cell },
                ..
            }) = a.answer(&activation(step, true), &Still(truth)).unwrap()
            else {
                panic!("no observation")
            };
            let err = bounds::wrap_angle(q.representative(cell) - e.g).abs();
            if err > 4.0 * e.r.sqrt() + 0.025 {
                misses += 1;
            }
        }
        assert!(misses <= 1, "{misses} of 200 beyond 4σ");
    }

    fn faulty(fault: &str) -> SensorActor {
        let text = format!(
            "{}\n[[faults]]\nkind = \"sensor\"\nsensors = [\"sensor-12\"]\nat_step = 3\nduration = 2\n{fault}\n",
            fusion_graph::scenario::DEFAULT_SCENARIO
        );
        let s = Scenario::from_toml(&text, "f", &[]).unwrap();
        let t = Topology::from_scenario(&s, "f").unwrap();
        SensorActor::new(&s, &t, 12).unwrap()
    }

    /// Steps 1..=6 with the sensor active each step: what it sent.
    fn six_steps(a: &mut SensorActor, truth: State) -> Vec<Option<Payload>> {
        (1..=6)
            .map(|k| {
                a.answer(&activation(k, true), &Still(truth))
                    .unwrap()
                    .map(|m| m.payload)
            })
            .collect()
    }

    fn cell(p: &Option<Payload>) -> i64 {
        match p {
            Some(Payload::Observation { cell }) => *cell as i64,
            other => panic!("not a cell: {other:?}"),
        }
    }

    #[test]
    fn sensor_faults_hold_for_their_window_only() {
        // Sensor 12 sits at the centre of node 0's cell, (250, 250); the
        // target is 900 m north-east of it: bearing 45 degrees.
        let truth = State::new(886.4, 886.4, 0.0, 0.0);
        let honest = six_steps(&mut actor(), truth);

        let dropout = six_steps(&mut faulty("mode = \"dropout\""), truth);
        assert!(dropout[2].is_none() && dropout[3].is_none());
        assert_eq!(
            [&dropout[..2], &dropout[4..]].concat(),
            [&honest[..2], &honest[4..]].concat()
        );

        let stuck = six_steps(&mut faulty("mode = \"stuck\""), truth);
        assert_eq!(stuck[2], honest[1], "repeats step 2's value");
        assert_eq!(stuck[3], honest[1]);
        assert_eq!(stuck[4], honest[4]);

        // 0.2 rad is 8.1 cells of 2π/256.
        let biased = six_steps(&mut faulty("mode = \"bias\"\nbias = 0.2"), truth);
        for k in [2, 3] {
            let shift = cell(&biased[k]) - cell(&honest[k]);
            assert!((7..=9).contains(&shift), "step {}: {shift} cells", k + 1);
        }
        assert_eq!(biased[4], honest[4]);

        // A phantom 600 m east of the target: bearing atan2(1236.4, 636.4)
        // from north, 62.8 degrees, against the true 45: 17.8 degrees more,
        // give or take the noise (the same draw, scaled by a σ that grows
        // with range: about 1 degree apart) and a cell (1.4 degrees).
        let byzantine = six_steps(
            &mut faulty("mode = \"byzantine\"\nphantom = [600.0, 0.0]"),
            truth,
        );
        let q = Scenario::default_scenario()
            .models()
            .unwrap()
            .quantizer
            .unwrap();
        let bearing = |p: &Option<Payload>| q.representative(cell(p) as u32);
        for k in [2, 3] {
            let moved = (bearing(&byzantine[k]) - bearing(&honest[k])).to_degrees();
            assert!(
                (14.0..=21.5).contains(&moved),
                "step {}: {moved} degrees",
                k + 1
            );
        }
        assert_eq!(byzantine[5], honest[5]);
    }
}
