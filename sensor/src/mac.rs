//! A multiple-access channel as an I/O-free state machine (dissertation
//! ch. 4): the medium between a fusion centre's sensors and the centre.
//!
//! It reads the centre's schedule of the step's slots (the same
//! activation the sensors read), adds up what each sensor transmits in
//! each slot, and at the slot's end (when every scheduled sensor has been
//! heard, or `slot_timeout_ms` after the schedule) delivers each slot's
//! sum plus the receiver's noise, `z = Φs + e`, to the centre. It does not
//! know which sensors were heard: a sensor that misses its slot is simply
//! absent from the sum, as on a real channel.
//!
//! The sums are taken in sensor order when the slot ends, not in arrival
//! order, and the noise of step k comes from the stream of (scenario seed,
//! channel, k): `sim` and every run give the same values to the bit.

use std::collections::BTreeMap;
use std::time::Duration;

use fusion_graph::scenario::Scenario;
use fusion_graph::transport::Channel;
use fusion_graph::wire::{Message, Payload, MAX_SLOTS};
use fusion_graph::{stream_rng, ActorId, ScenarioError, Stream, Topology};
use rand_distr::{Distribution, StandardNormal};

#[derive(Debug, Clone)]
pub struct MacActor {
    index: u16,
    /// The node's sensors, by their place in its list.
    sensors: Vec<u16>,
    seed: u64,
    noise_std: f64,
    slot_timeout: Duration,
    frame: Option<Frame>,
    /// The last step delivered: what arrives for it or before is late.
    delivered: Option<u32>,
    late: u64,
}

/// One step's slots while they are open.
#[derive(Debug, Clone)]
struct Frame {
    step: u32,
    /// From the centre's schedule, once it arrived: the slots, the sensors
    /// it expects, and when the slots end.
    schedule: Option<(usize, Vec<u16>, Duration)>,
    /// What each sensor heard so far transmitted: its slots and values.
    heard: BTreeMap<u16, (u32, Vec<f64>)>,
}

impl MacActor {
    /// The channel in front of node `index`; `None` if the scenario has no
    /// channel.
    pub fn new(
        scenario: &Scenario,
        topology: &Topology,
        index: u16,
    ) -> Result<Option<Self>, ScenarioError> {
        let Some(mac) = &scenario.channel else {
            return Ok(None);
        };
        Ok(Some(Self {
            index,
            sensors: topology.node_sensors[index as usize].clone(),
            seed: scenario.seed,
            noise_std: mac.receiver_noise.sqrt(),
            slot_timeout: Duration::from_secs_f64(mac.slot_timeout_ms / 1e3),
            frame: None,
            delivered: None,
            late: 0,
        }))
    }

    pub fn id(&self) -> ActorId {
        ActorId::Mac(self.index)
    }

    /// The launcher's tick (for the step and the stop), the centre's
    /// schedule, and its sensors' transmissions.
    pub fn subscriptions(&self) -> Vec<Channel> {
        let mut v = vec![Channel::Tick, Channel::Activation(self.index)];
        v.extend(self.sensors.iter().map(|s| Channel::Observation(*s)));
        v
    }

    pub fn publication(&self) -> Channel {
        Channel::MacOutput(self.index)
    }

    /// The one actor it delivers to.
    pub fn centre(&self) -> ActorId {
        ActorId::Node(self.index)
    }

    /// Transmissions that arrived after their slots had ended.
    pub fn late_messages(&self) -> u64 {
        self.late
    }

    /// When the open slots end, if a schedule opened them.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.frame.as_ref()?.schedule.as_ref().map(|s| s.2)
    }

    /// Takes one message; returns the delivery to the centre when it ends
    /// the slots.
    pub fn handle(&mut self, message: &Message, now: Duration) -> Option<Message> {
        let step = message.header.step;
        if self.delivered.is_some_and(|d| step <= d) {
            if matches!(message.payload, Payload::SlotValues { .. }) {
                self.late += 1;
            }
            return None;
        }
        match (&message.payload, message.header.sender) {
            (Payload::ActivateSlots { slots, columns }, ActorId::Node(n)) if n == self.index => {
                let expected = columns
                    .iter()
                    .filter_map(|c| self.sensors.get(c.sensor as usize).copied())
                    .collect();
                let schedule = (*slots as usize, expected, now + self.slot_timeout);
                self.frame_for(step).schedule = Some(schedule);
            }
            (Payload::SlotValues { slots, values }, ActorId::Sensor(s))
                if self.sensors.contains(&s) =>
            {
                self.frame_for(step)
                    .heard
                    .insert(s, (*slots, values.clone()));
            }
            _ => return None,
        }
        let frame = self.frame.as_ref()?;
        let (_, expected, _) = frame.schedule.as_ref()?;
        if expected.iter().all(|s| frame.heard.contains_key(s)) {
            return self.deliver();
        }
        None
    }

    /// Ends the slots whose time is up with what they heard.
    pub fn handle_timeout(&mut self, now: Duration) -> Option<Message> {
        if self.poll_timeout().is_some_and(|due| now >= due) {
            return self.deliver();
        }
        None
    }

    /// The frame of `step`, opening it; a frame of an earlier step still
    /// open is dropped (its schedule never came, so it has no slots).
    fn frame_for(&mut self, step: u32) -> &mut Frame {
        if self.frame.as_ref().is_none_or(|f| f.step != step) {
            self.frame = Some(Frame {
                step,
                schedule: None,
                heard: BTreeMap::new(),
            });
        }
        self.frame.as_mut().expect("opened above")
    }

    /// Each slot's sum, in sensor order, plus the receiver's noise.
    fn deliver(&mut self) -> Option<Message> {
        let frame = self.frame.take()?;
        let (slots, _, _) = frame.schedule?;
        let slots = slots.min(MAX_SLOTS);
        let mut sums = vec![0.0; slots];
        for (mask, values) in frame.heard.values() {
            let mut v = values.iter();
            for (i, sum) in sums.iter_mut().enumerate() {
                if mask & (1 << i) != 0 {
                    *sum += v.next().copied().unwrap_or(0.0);
                }
            }
        }
        let mut rng = stream_rng(self.seed, self.id(), frame.step, Stream::ReceiverNoise);
        for sum in &mut sums {
            let e: f64 = StandardNormal.sample(&mut rng);
            *sum += self.noise_std * e;
        }
        self.delivered = Some(frame.step);
        Some(Message::new(
            self.id(),
            frame.step,
            0,
            Payload::MacOutput { values: sums },
        ))
    }
}
