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
use fusion_graph::{stream_rng, ActorId, ScenarioError, Stream, Topology};
use fusion_graph::{Actor, Channel, Outgoing, Wiring};
use rand_distr::{Distribution, StandardNormal};
use wire::{Message, Payload, MAX_SLOTS};

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

    /// The launcher's lifecycle (the stop), the centre's schedule, and its
    /// sensors' transmissions.
    fn channels_read(&self) -> Vec<Channel> {
        let mut v = vec![
            Channel::Lifecycle,
            Channel::Activation {
                node: self.index,
                to: self.id(),
            },
        ];
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
    pub fn slots_end(&self) -> Option<Duration> {
        self.frame.as_ref()?.schedule.as_ref().map(|s| s.2)
    }

    /// Takes one message; returns the delivery to the centre when it ends
    /// the slots. A message of a later step ends the slots of an earlier
    /// one still open (their timeout not yet handled): that delivery is
    /// returned, and the later step's slots end at their own time.
    pub fn take(&mut self, message: &Message, now: Duration) -> Option<Message> {
        let step = message.header.step;
        if self.delivered.is_some_and(|d| step <= d) {
            if matches!(message.payload, Payload::SlotValues { .. }) {
                self.late += 1;
            }
            return None;
        }
        let overtaken = self
            .frame
            .as_ref()
            .is_some_and(|f| f.step < step && f.schedule.is_some());
        let earlier = if overtaken { self.deliver() } else { None };
        if !self.file(message, step, now) {
            return earlier;
        }
        // One delivery per call: slots this message completed after
        // ending earlier ones end at their own timeout.
        earlier.or_else(|| self.deliver_if_complete())
    }

    /// Files a schedule or a transmission; false for anything else.
    fn file(&mut self, message: &Message, step: u32, now: Duration) -> bool {
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
            _ => return false,
        }
        true
    }

    /// The delivery, once every scheduled sensor has been heard.
    fn deliver_if_complete(&mut self) -> Option<Message> {
        let frame = self.frame.as_ref()?;
        let (_, expected, _) = frame.schedule.as_ref()?;
        if expected.iter().all(|s| frame.heard.contains_key(s)) {
            return self.deliver();
        }
        None
    }

    /// Ends the slots whose time is up with what they heard.
    pub fn end_slots(&mut self, now: Duration) -> Option<Message> {
        if self.slots_end().is_some_and(|due| now >= due) {
            return self.deliver();
        }
        None
    }

    /// The frame of `step`, opening it; a frame of an earlier step still
    /// open here has no schedule (one with a schedule was delivered), so
    /// it has no slots to deliver and is dropped.
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

impl Actor for MacActor {
    /// Adding up a step's slots is too light to time apart.
    type Work = ();

    fn wiring(&self) -> Wiring {
        Wiring {
            actor: self.id(),
            reads: self.channels_read(),
            publishes: vec![self.publication()],
            wakes: vec![self.centre()],
        }
    }

    fn handle(&mut self, message: &Message, now: Duration, out: &mut Vec<Outgoing>) {
        if let Some(delivery) = self.take(message, now) {
            out.push(self.to_centre(delivery));
        }
    }

    fn poll_timeout(&self) -> Option<Duration> {
        self.slots_end()
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        if let Some(delivery) = self.end_slots(now) {
            out.push(self.to_centre(delivery));
        }
    }
}

impl MacActor {
    fn to_centre(&self, delivery: Message) -> Outgoing {
        Outgoing {
            channel: self.publication(),
            message: delivery,
            receivers: vec![self.centre()],
            wake: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::scenario::COMPRESSIVE_SCENARIO;
    use wire::SlotColumn;

    fn field() -> (Scenario, Topology) {
        let s = Scenario::from_toml(COMPRESSIVE_SCENARIO, "c", &[]).unwrap();
        let t = Topology::from_scenario(&s, "c").unwrap();
        (s, t)
    }

    fn schedule(step: u32, columns: Vec<SlotColumn>) -> Message {
        Message::new(
            ActorId::Node(0),
            step,
            0,
            Payload::ActivateSlots { slots: 3, columns },
        )
    }

    fn column(sensor: u16, slots: u32, negative: u32) -> SlotColumn {
        SlotColumn {
            sensor,
            slots,
            negative,
        }
    }

    fn sent(sensor: u16, step: u32, slots: u32, values: Vec<f64>) -> Message {
        Message::new(
            ActorId::Sensor(sensor),
            step,
            0,
            Payload::SlotValues { slots, values },
        )
    }

    /// The noise the channel adds at `step`, slot by slot.
    fn noise(s: &Scenario, step: u32) -> Vec<f64> {
        let mut rng = stream_rng(s.seed, ActorId::Mac(0), step, Stream::ReceiverNoise);
        let std = s.channel.as_ref().unwrap().receiver_noise.sqrt();
        (0..3)
            .map(|_| {
                let e: f64 = StandardNormal.sample(&mut rng);
                std * e
            })
            .collect()
    }

    /// Each slot's sum of what its sensors sent, plus the step's noise,
    /// delivered when the last scheduled sensor is heard, whatever the
    /// order of arrival.
    #[test]
    fn the_channel_delivers_each_slots_sum_when_every_sensor_is_heard() {
        let (s, t) = field();
        let e = noise(&s, 2);
        for order in [[0, 1, 2], [1, 2, 0], [2, 0, 1]] {
            let mut mac = MacActor::new(&s, &t, 0).unwrap().unwrap();
            let messages = [
                schedule(2, vec![column(3, 0b011, 0b010), column(7, 0b110, 0)]),
                sent(3, 2, 0b011, vec![4.0, -4.0]),
                sent(7, 2, 0b110, vec![1.5, 1.5]),
            ];
            let mut delivered = None;
            for (k, i) in order.iter().enumerate() {
                let out = mac.take(&messages[*i], Duration::ZERO);
                if k < 2 {
                    assert!(out.is_none(), "order {order:?}: delivered early");
                }
                delivered = delivered.or(out);
            }
            let m = delivered.expect("delivered once all are heard");
            assert_eq!(m.header.sender, ActorId::Mac(0));
            let Payload::MacOutput { values } = m.payload else {
                panic!("{m:?}")
            };
            assert_eq!(values, vec![4.0 + e[0], -4.0 + 1.5 + e[1], 1.5 + e[2]]);
        }
    }

    /// The next step's schedule, arriving before the slots' timeout was
    /// handled, ends the earlier slots with what they heard; the later
    /// ones end in their turn.
    #[test]
    fn a_later_schedule_ends_the_slots_still_open() {
        let (s, t) = field();
        let mut mac = MacActor::new(&s, &t, 0).unwrap().unwrap();
        let at = Duration::from_secs(1);
        mac.take(
            &schedule(3, vec![column(3, 0b001, 0), column(7, 0b010, 0)]),
            at,
        );
        mac.take(&sent(3, 3, 0b001, vec![2.0]), at);
        let ended = mac
            .take(&schedule(4, vec![column(7, 0b100, 0)]), at)
            .expect("step 3's slots end");
        assert_eq!(ended.header.step, 3);
        let e = noise(&s, 4);
        let Some(Message {
            payload: Payload::MacOutput { values },
            header,
        }) = mac.take(&sent(7, 4, 0b100, vec![1.0]), at)
        else {
            panic!("step 4's slots did not end")
        };
        assert_eq!(header.step, 4);
        assert_eq!(values, vec![e[0], e[1], 1.0 + e[2]]);
    }

    /// A scheduled sensor that is not heard is left out of the sums at
    /// the slots' end; what arrives after is late.
    #[test]
    fn a_silent_sensor_is_absent_from_the_sums_at_the_slots_end() {
        let (s, t) = field();
        let e = noise(&s, 5);
        let mut mac = MacActor::new(&s, &t, 0).unwrap().unwrap();
        let start = Duration::from_secs(1);
        assert!(mac
            .take(
                &schedule(5, vec![column(3, 0b001, 0), column(7, 0b001, 0)]),
                start
            )
            .is_none());
        assert!(mac.take(&sent(3, 5, 0b001, vec![2.0]), start).is_none());
        let due = mac.slots_end().expect("the slots end");
        assert!(mac.end_slots(due - Duration::from_millis(1)).is_none());
        let Some(Message {
            payload: Payload::MacOutput { values },
            ..
        }) = mac.end_slots(due)
        else {
            panic!("nothing delivered at the slots' end")
        };
        assert_eq!(values, vec![2.0 + e[0], e[1], e[2]]);
        assert!(mac.take(&sent(7, 5, 0b001, vec![9.0]), due).is_none());
        assert_eq!(mac.late_messages(), 1);
    }
}
