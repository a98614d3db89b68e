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

/// The launcher's start of a step, the same in `sim` and `run`: the tick
/// with the truth to every live sensor (waking none: an active sensor is
/// woken by its activation and finds the tick queued), then, to every live
/// node, its membership view when it differs from the one it was last told
/// (or after any kill or restart), and `BeginStep`.
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
    launcher.send_waking(Channel::Tick, &tick, &sensors, &[])?;
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
