"""Stone Soup's particle filter on cqnet's per-node workload: 1000
particles, a 4-D constant-velocity target, three bearing sensors updating
every step (each update weighs, and resamples when Stone Soup decides to),
timed per step with the filter alone (no bound). Prints one line:
`stonesoup <version>: <ms> ms per step (<steps> steps)`."""

import datetime
import sys
import time

import numpy as np
import stonesoup
from stonesoup.models.measurement.nonlinear import Cartesian2DToBearing
from stonesoup.models.transition.linear import (
    CombinedLinearGaussianTransitionModel,
    ConstantVelocity,
)
from stonesoup.predictor.particle import ParticlePredictor
from stonesoup.resampler.particle import SystematicResampler
from stonesoup.types.array import StateVectors
from stonesoup.types.detection import Detection
from stonesoup.types.hypothesis import SingleHypothesis
from stonesoup.types.state import ParticleState
from stonesoup.updater.particle import ParticleUpdater

PARTICLES = 1000
SECOND = datetime.timedelta(seconds=1)
STEPS = int(sys.argv[1]) if len(sys.argv) > 1 else 50
rng = np.random.default_rng(1)

# Stone Soup's state order is [x, vx, y, vy].
transition = CombinedLinearGaussianTransitionModel(
    [ConstantVelocity(0.05**2), ConstantVelocity(0.05**2)]
)
sensors = [np.array([[600.0], [100.0]]), np.array([[750.0], [400.0]]), np.array([[900.0], [100.0]])]
models = [
    Cartesian2DToBearing(
        ndim_state=4,
        mapping=(0, 2),
        noise_covar=np.array([[0.02**2]]),
        translation_offset=s,
    )
    for s in sensors
]
predictor = ParticlePredictor(transition)
updater = ParticleUpdater(measurement_model=None, resampler=SystematicResampler())

truth = np.array([[700.0], [0.0], [200.0], [10.0]])
particles = StateVectors(
    truth + rng.normal(size=(4, PARTICLES)) * np.array([[20.0], [2.0], [20.0], [2.0]])
)
state = ParticleState(
    particles,
    weight=np.full(PARTICLES, 1.0 / PARTICLES),
    timestamp=datetime.datetime(2026, 1, 1),
)

def step(state, truth, k):
    when = state.timestamp + SECOND
    state = predictor.predict(state, timestamp=when)
    for model in models:
        z = model.function(ParticleState(truth)) + rng.normal(0.0, 0.02)
        detection = Detection(z, timestamp=when, measurement_model=model)
        state = updater.update(SingleHypothesis(state, detection))
    return state

for k in range(5):  # warm-up: imports, caches
    truth = transition.function(ParticleState(truth), time_interval=SECOND)
    state = step(state, truth, k)

started = time.perf_counter()
for k in range(STEPS):
    truth = transition.function(ParticleState(truth), time_interval=SECOND)
    state = step(state, truth, k)
elapsed = time.perf_counter() - started
print(f"stonesoup {stonesoup.__version__}: {1e3 * elapsed / STEPS:.3f} ms per step ({STEPS} steps)")
