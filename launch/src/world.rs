//! The world: the true target trajectory, which only the launcher and the
//! sensors see (the launcher writes it, step by step, into memory the
//! sensors read: `fusion_graph::world_memory`).

use bounds::{Dynamics, State};
use fusion_graph::scenario::{Motion, Scenario};
use fusion_graph::{stream_rng, ActorId, ScenarioError, Stream};
use rand_chacha::ChaCha8Rng;
use transport::world_memory::TruthRing;
use transport::SendError;
use transport::{Channel, Transport};
use wire::{BitMask, Control, Message, Payload};

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

/// The launcher's start of a step, the same in `sim` and `run`: the truth
/// of `step` into the world's memory, where a sensor activated for it will
/// look, then, to every live node, its membership view when it differs
/// from the one it was last told (or after any kill or restart), and
/// `BeginStep`. The truth is written first: no node can activate a sensor
/// for a step before it is there.
pub fn begin_step<T: Transport + ?Sized>(
    launcher: &mut T,
    world: &TruthRing,
    step: u32,
    truth: &State,
    views: &[Vec<bool>],
    told: &[Vec<bool>],
    process_faults: bool,
) -> Result<(), SendError> {
    world.write(step, truth);
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
