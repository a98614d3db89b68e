//! The world: the true target trajectory, which only the launcher and the
//! sensors see.

use bounds::{Dynamics, State};
use fusion_graph::scenario::Scenario;
use fusion_graph::transport::{Channel, Transport};
use fusion_graph::wire::{BitMask, Control, Message, Payload};
use fusion_graph::{stream_rng, ActorId, ScenarioError, SendError, Stream};
use rand_chacha::ChaCha8Rng;

pub struct World {
    dynamics: Dynamics,
    state: State,
    rng: ChaCha8Rng,
}

impl World {
    pub fn new(s: &Scenario) -> Result<Self, ScenarioError> {
        Ok(Self {
            dynamics: s.models()?.dynamics,
            state: State::from(s.target.initial_state()),
            rng: stream_rng(s.seed, ActorId::Launcher, 0, Stream::Truth),
        })
    }

    /// `x(k) = f(x(k−1)) + ξ(k)`: the truth of the next step.
    pub fn advance(&mut self) -> State {
        self.state = self.dynamics.propagate(&self.state, &mut self.rng);
        self.state
    }

    pub fn state(&self) -> State {
        self.state
    }
}

/// A sensor is woken by the tick once in this many steps, in turn by its
/// index, to drain its queues. An active sensor is woken by its activation
/// and finds the tick queued; one that is seldom active would otherwise
/// fill its subscriber queues (a tick and an activation a step). Draining
/// on an idle timer instead woke all 225 sensors ten times a second, and
/// would overflow the queues at more than 640 steps/s; in turn, a sensor's
/// queues are at most half full whatever the rate, and a step wakes one
/// sensor in 32.
pub const DRAIN_EVERY: u16 = 32;
const _: () = assert!(2 * DRAIN_EVERY as usize <= fusion_graph::transport::SUBSCRIBER_QUEUE);

/// The sensors among `live` whose turn it is at `step` to be woken by the
/// tick (see [`DRAIN_EVERY`]).
fn drained_at(step: u32, live: &[ActorId]) -> Vec<ActorId> {
    let turn = (step % DRAIN_EVERY as u32) as u16;
    live.iter()
        .copied()
        .filter(|a| matches!(a, ActorId::Sensor(s) if s % DRAIN_EVERY == turn))
        .collect()
}

/// The launcher's start of a step, the same in `sim` and `run`: the tick
/// with the truth to every live sensor (waking only those whose turn it is
/// to drain their queues, see [`DRAIN_EVERY`]), then, to every live node,
/// its membership view when it differs from the one it was last told (or
/// after any kill or restart), and `BeginStep`.
pub fn begin_step<T: Transport + ?Sized>(
    launcher: &mut T,
    step: u32,
    truth: State,
    sensors_alive: &[bool],
    views: &[Vec<bool>],
    told: &[Vec<bool>],
    process_faults: bool,
) -> Result<(), SendError> {
    let sensors: Vec<ActorId> = (0..sensors_alive.len() as u16)
        .filter(|s| sensors_alive[*s as usize])
        .map(ActorId::Sensor)
        .collect();
    let tick = Message::new(
        ActorId::Launcher,
        step,
        0,
        Payload::Tick {
            truth: truth.into(),
        },
    );
    launcher.send_waking(Channel::Tick, &tick, &sensors, &drained_at(step, &sensors))?;
    for (n, view) in views.iter().enumerate() {
        // A node is alive when its own view holds it.
        if !view.get(n).copied().unwrap_or(false) {
            continue;
        }
        let to = ActorId::Node(n as u16);
        if process_faults || told.get(n) != Some(view) {
            let alive = BitMask::from_bools(view);
            launcher.send(
                Channel::Control(to),
                &Message::new(
                    ActorId::Launcher,
                    step,
                    0,
                    Payload::Control(Control::Membership { alive }),
                ),
                &[to],
            )?;
        }
        launcher.send(
            Channel::Control(to),
            &Message::new(
                ActorId::Launcher,
                step,
                0,
                Payload::Control(Control::BeginStep),
            ),
            &[to],
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Over any `DRAIN_EVERY` steps in a row, every live sensor is woken
    /// once, and no step wakes more than its share.
    #[test]
    fn every_live_sensor_drains_once_in_drain_every_steps() {
        let live: Vec<ActorId> = (0..225u16)
            .filter(|s| s % 7 != 3)
            .map(ActorId::Sensor)
            .collect();
        for first in [0u32, 1, 5, 1000] {
            let mut woken = vec![0; 225];
            for step in first..first + DRAIN_EVERY as u32 {
                let these = drained_at(step, &live);
                assert!(these.len() <= 225usize.div_ceil(DRAIN_EVERY as usize));
                for a in these {
                    let ActorId::Sensor(s) = a else {
                        panic!("{a} is not a sensor")
                    };
                    woken[s as usize] += 1;
                }
            }
            for s in 0..225u16 {
                let expected = if s % 7 != 3 { 1 } else { 0 };
                assert_eq!(woken[s as usize], expected, "sensor {s} from step {first}");
            }
        }
    }
}
