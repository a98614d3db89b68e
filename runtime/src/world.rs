//! The world: the true target trajectory, which only the launcher and the
//! sensors see.

use bounds::{Dynamics, State};
use fusion_graph::scenario::{Motion, Scenario};
use fusion_graph::transport::iceoryx::QUEUE_DEPTH;
use fusion_graph::transport::{Channel, Transport};
use fusion_graph::wire::{BitMask, Control, Message, Payload};
use fusion_graph::{stream_rng, ActorId, ScenarioError, SendError, Stream};
use rand_chacha::ChaCha8Rng;

pub struct World {
    /// `None`: the target stays where it starts.
    dynamics: Option<Dynamics>,
    state: State,
    rng: ChaCha8Rng,
}

impl World {
    pub fn new(s: &Scenario) -> Result<Self, ScenarioError> {
        let mut state = s.true_initial_state();
        let dynamics = match s.target.motion {
            Motion::Moving => Some(s.models()?.dynamics),
            Motion::Static => {
                state[2] = 0.0;
                state[3] = 0.0;
                None
            }
        };
        Ok(Self {
            dynamics,
            state,
            rng: stream_rng(s.seed, ActorId::Launcher, 0, Stream::Truth),
        })
    }

    /// `x(k) = f(x(k−1)) + ξ(k)`: the truth of the next step.
    pub fn advance(&mut self) -> State {
        if let Some(d) = &self.dynamics {
            self.state = d.propagate(&self.state, &mut self.rng);
        }
        self.state
    }

    pub fn state(&self) -> State {
        self.state
    }
}

/// A live sensor is woken by the tick once in this many steps, a few
/// sensors a step, so that one its node does not activate drains its
/// queues before they fill: they hold `QUEUE_DEPTH` ticks and as many
/// activations, and the oldest are overwritten. Left to its idle timeout
/// (100 ms), such a sensor lost ticks and activations whenever a run went
/// faster than 640 steps/s (18 of each in 2,000 steps at 640 steps/s, with
/// `filter.particles = 300`).
pub const DRAIN_PERIOD: u32 = 32;
const _: () = assert!(DRAIN_PERIOD as usize <= QUEUE_DEPTH / 2);

/// Where each sensor's process stands, as the launcher knows it.
#[derive(Debug, Clone)]
pub struct SensorStates {
    /// Running: it reads its queue.
    pub alive: Vec<bool>,
    /// Stopped (SIGSTOP): its queue takes messages, read when it continues.
    pub stopped: Vec<bool>,
}

impl SensorStates {
    pub fn all_running(sensors: usize) -> Self {
        Self {
            alive: vec![true; sensors],
            stopped: vec![false; sensors],
        }
    }

    /// Records a kill (`stopped`: by SIGSTOP) or a restart of sensor `i`.
    pub fn set(&mut self, i: u16, alive: bool, stopped: bool) {
        self.alive[i as usize] = alive;
        self.stopped[i as usize] = stopped;
    }
}

/// The live sensors the tick of `step` wakes: those whose turn it is to
/// drain (each once in [`DRAIN_PERIOD`] steps).
pub fn drain_wakes(step: u32, sensors_alive: &[bool]) -> Vec<ActorId> {
    (0..sensors_alive.len() as u16)
        .filter(|&s| sensors_alive[s as usize])
        .filter(|&s| (step.wrapping_add(u32::from(s))) % DRAIN_PERIOD == 0)
        .map(ActorId::Sensor)
        .collect()
}

/// The launcher's start of a step, the same in `sim` and `run`: the tick
/// with the truth to every live sensor (waking only those whose turn it is
/// to drain, [`drain_wakes`]: an active sensor is woken by its activation
/// and finds the tick queued), then, to every live node, its membership
/// view when it differs from the one it was last told (or after any kill
/// or restart), and `BeginStep`.
///
/// A stopped sensor (SIGSTOP) is not live but keeps its queue: the tick
/// reaches it there, to be read when it continues, so it is counted as
/// sent to it too (it is not woken). A dead sensor's queue is gone. The
/// multiple-access channels (`macs`) read the tick as well, for the
/// launcher's stop on it; it does not wake them.
#[allow(clippy::too_many_arguments)]
pub fn begin_step<T: Transport + ?Sized>(
    launcher: &mut T,
    step: u32,
    truth: State,
    sensors: &SensorStates,
    macs: &[ActorId],
    views: &[Vec<bool>],
    told: &[Vec<bool>],
    process_faults: bool,
) -> Result<(), SendError> {
    let sensors_alive = &sensors.alive;
    let queued: Vec<ActorId> = (0..sensors_alive.len() as u16)
        .filter(|s| sensors_alive[*s as usize] || sensors.stopped[*s as usize])
        .map(ActorId::Sensor)
        .chain(macs.iter().copied())
        .collect();
    let tick = Message::new(
        ActorId::Launcher,
        step,
        0,
        Payload::Tick {
            truth: truth.into(),
        },
    );
    launcher.send_waking(
        Channel::Tick,
        &tick,
        &queued,
        &drain_wakes(step, sensors_alive),
    )?;
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

    /// Over any `DRAIN_PERIOD` steps in a row every live sensor is woken
    /// exactly once, a dead one never, and no step wakes more than its share.
    #[test]
    fn every_live_sensor_is_woken_once_a_drain_period() {
        let alive: Vec<bool> = (0..225).map(|s| s % 17 != 3).collect();
        for first in [1u32, 5, 1000, u32::MAX - 40] {
            let mut woken = vec![0; alive.len()];
            for k in 0..DRAIN_PERIOD {
                let wakes = drain_wakes(first.wrapping_add(k), &alive);
                assert!(wakes.len() <= alive.len().div_ceil(DRAIN_PERIOD as usize));
                for w in wakes {
                    let ActorId::Sensor(s) = w else {
                        panic!("{w} is not a sensor")
                    };
                    woken[s as usize] += 1;
                }
            }
            for (s, n) in woken.iter().enumerate() {
                assert_eq!(*n, usize::from(alive[s]), "sensor-{s} from step {first}");
            }
        }
    }
}
