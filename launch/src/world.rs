//! The world: the true target trajectory, which only the launcher and the
//! sensors see.

use bounds::{Dynamics, State};
use fusion_graph::scenario::Scenario;
use fusion_graph::ActorId;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const TRUTH_STREAM: u64 = 7;

pub struct World {
    dynamics: Dynamics,
    state: State,
    rng: ChaCha8Rng,
}

impl World {
    pub fn new(s: &Scenario) -> Self {
        Self {
            dynamics: node::actor::dynamics(s),
            state: State::from(s.target.initial_state()),
            rng: ChaCha8Rng::seed_from_u64(sensor::stream_seed(
                s.seed,
                ActorId::Launcher,
                0,
                TRUTH_STREAM,
            )),
        }
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
