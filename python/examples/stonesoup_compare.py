"""Stone Soup's particle filter beside cqnet's, with the conditional bound
computed on Stone Soup's own particles.

Both track the target of cqnet's default scenario with the same sensors:
at each step, the bearing sensors the cqnet network activated, quantized
to 8 bits as cqnet's sensors quantize them. Stone Soup runs a centralized
particle filter (its predictor, updater and resampler) with two models
written here on cqnet's: the coordinated turn of the scenario's dynamics,
and the quantized bearings' likelihood Σ_s ln h_{i_s}. Its measurements are drawn
here from the same truth and sensor law, not read from cqnet's run: the
two filters see the same sensors, not the same noise.

The CQ/PCRLB on Stone Soup's particles is the recursion

    L(k+1) = Q⁻¹ − B21 (L(k) + B11)⁻¹ B12 + Σ_j w_j Σ_s J_Y,s(x_j(k+1|k)),

with B11, B12 over its posterior particles at k and the Fisher information
over its predicted particles, for the sensors that report at k+1.

Run, in an environment with cqnet, Stone Soup and matplotlib installed:

    python python/examples/stonesoup_compare.py [--runs N] [--out FIGURE.png]
"""

import argparse
import datetime
import math

import numpy as np
from stonesoup.base import Property
from stonesoup.models.base import GaussianModel
from stonesoup.models.measurement.base import MeasurementModel
from stonesoup.models.transition.base import TransitionModel
from stonesoup.predictor.particle import ParticlePredictor
from stonesoup.regulariser.particle import MCMCRegulariser
from stonesoup.resampler.particle import SystematicResampler
from stonesoup.types.array import StateVector, StateVectors
from stonesoup.types.detection import Detection
from stonesoup.types.hypothesis import SingleHypothesis
from stonesoup.types.state import ParticleState
from stonesoup.updater.particle import ParticleUpdater

import cqnet
from cqnet import bounds

# States are in cqnet's order, [x, y, vx, vy], in Stone Soup as well.


class CoordinatedTurn(TransitionModel, GaussianModel):
    """The scenario's clockwise coordinated turn, x(k) = f(x(k−1)) + ξ,
    ξ ~ N(0, Q), through cqnet's model."""

    dynamics: bounds.Dynamics = Property(doc="cqnet's dynamics")

    @property
    def ndim_state(self):
        return 4

    def function(self, state, noise=False, **kwargs):
        x = np.asarray(state.state_vector, dtype=float)
        moved = self.dynamics.transition(np.ascontiguousarray(x.T)).T
        if noise is True:
            noise = self.rvs(num_samples=x.shape[1], **kwargs)
        elif noise is False:
            noise = 0
        return StateVectors(moved) + noise

    def covar(self, **kwargs):
        return self.dynamics.q


class QuantizedBearings(MeasurementModel):
    """The step's bearing sensors, each reporting the cell index of its
    quantizer: the likelihood of cells (i_s) at a state is Π_s h_{i_s},
    each cell's probability under N(g_s(x), R_s(x)), as cqnet's filters
    weigh them."""

    sensors: list = Property(doc="the sensors that report, with their quantizers")

    @property
    def ndim_meas(self):
        return len(self.sensors)

    def function(self, state, noise=False, **kwargs):
        particles = np.asarray(state.state_vector, dtype=float).T
        return StateVectors(np.array([s.mean_and_variance(particles)[0] for s in self.sensors]))

    def logpdf(self, state1, state2, **kwargs):
        cells = np.asarray(state1.state_vector, dtype=float).ravel().astype(np.uint32)
        particles = np.asarray(state2.state_vector, dtype=float).T
        total = np.zeros(len(particles))
        for sensor, cell in zip(self.sensors, cells):
            g, r = sensor.mean_and_variance(particles)
            total += sensor.quantizer.ln_probability(np.array(cell), g, r)
        return total

    def pdf(self, state1, state2, **kwargs):
        return np.exp(self.logpdf(state1, state2, **kwargs))

    def rvs(self, num_samples=1, **kwargs):
        raise NotImplementedError("measurements are drawn by `observe`")


def observe(sensor, truth, rng):
    """A quantized bearing of the true state: g(x) + √R·n, wrapped, encoded."""
    g, r = sensor.mean_and_variance(truth)
    z = math.remainder(g + math.sqrt(r) * rng.standard_normal(), 2 * math.pi)
    return int(sensor.quantizer.encode(np.array(z)))


def stone_soup_run(scenario, truth, active, particles, rng):
    """Stone Soup's centralized particle filter over the sensors cqnet
    activated; returns its errors and the CQ/PCRLB on its particles."""
    sensors = scenario.sensors()
    dynamics = scenario.dynamics()
    transition = CoordinatedTurn(dynamics=dynamics)
    predictor = ParticlePredictor(transition)
    # Resampled every step and moved by an MCMC step, as cqnet's filters
    # are by their Liu-West regulariser: without it the velocities collapse
    # and the track drifts away.
    updater = ParticleUpdater(
        measurement_model=None,
        resampler=SystematicResampler(),
        regulariser=MCMCRegulariser(transition_model=transition),
    )
    p0 = scenario.prior_covariance()
    start = scenario.initial_state()
    mean = rng.multivariate_normal(start, p0)
    t0 = datetime.datetime(2026, 1, 1)
    period = datetime.timedelta(seconds=scenario.get("dynamics.period"))
    state = ParticleState(
        StateVectors(rng.multivariate_normal(mean, p0, size=particles).T),
        log_weight=np.full(particles, -math.log(particles)),
        timestamp=t0,
    )
    bound = bounds.ConditionalBound(p0, dynamics)
    errors, bound_series = [], []
    for k, (x_true, sensors_k) in enumerate(zip(truth, active), start=1):
        prediction = predictor.predict(state, timestamp=t0 + k * period)
        posterior_particles = np.asarray(state.state_vector, dtype=float).T
        predicted_particles = np.asarray(prediction.state_vector, dtype=float).T
        bound_series.append(
            bound.advance(
                posterior_particles,
                [sensors[s] for s in sensors_k],
                predicted_particles,
                posterior_weights=np.exp(np.asarray(state.log_weight, dtype=float)),
                predicted_weights=np.exp(np.asarray(prediction.log_weight, dtype=float)),
            )
        )
        model = QuantizedBearings(ndim_state=4, mapping=(0, 1), sensors=[sensors[s] for s in sensors_k])
        cells = [observe(sensors[s], x_true, rng) for s in sensors_k]
        detection = Detection(StateVector(cells), timestamp=prediction.timestamp, measurement_model=model)
        state = updater.update(SingleHypothesis(prediction, detection))
        x = np.asarray(state.state_vector, dtype=float)
        w = np.exp(np.asarray(state.log_weight, dtype=float))
        estimate = x @ w / w.sum()
        errors.append(math.hypot(estimate[0] - x_true[0], estimate[1] - x_true[1]))
    return np.array(errors), np.array(bound_series)


def truth_and_sensors(run):
    """The true state at each step (velocity from the positions' change)
    and the sensors the network activated, from a cqnet run's ticks."""
    t = run.arrays("ticks")
    nodes = np.array(t["node"], dtype=object)
    steps = int(t["step"].max())
    central = nodes == "central"
    position = np.stack([t["true_x"][central], t["true_y"][central]], axis=1)
    active = [set() for _ in range(steps)]
    for step, node, ids in zip(t["step"], nodes, t["active"]):
        if node != "central" and ids:
            active[int(step) - 1].update(int(i) for i in ids.split(";"))
    return position, [sorted(a) for a in active]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--steps", type=int, default=100)
    # With 1,000 the cloud can collapse onto a few points, whose covariance
    # Stone Soup's MCMC regulariser cannot take (a LinAlgError).
    parser.add_argument("--particles", type=int, default=5000)
    parser.add_argument("--out", default="stonesoup_compare.png")
    args = parser.parse_args()

    scenario = cqnet.Scenario.default().set("steps", args.steps)
    period = scenario.get("dynamics.period")
    rng = np.random.default_rng(2026)
    # Stone Soup draws its process noise, resampling and MCMC moves from
    # NumPy's global generator.
    np.random.seed(2026)
    ours, ours_bound, theirs, theirs_bound = [], [], [], []
    for i in range(args.runs):
        run = cqnet.sim(scenario, seed=scenario.seed + i, progress=False)
        t = run.arrays("ticks")
        nodes = np.array(t["node"], dtype=object)
        central = nodes == "central"
        ours.append(t["error"][central])
        ours_bound.append(t["bound"][central])
        position, active = truth_and_sensors(run)
        velocity = np.gradient(position, period, axis=0)
        truth = np.hstack([position, velocity])
        errors, bound = stone_soup_run(scenario, truth, active, args.particles, rng)
        theirs.append(errors)
        theirs_bound.append(bound)
        print(f"run {i + 1}/{args.runs}: RMSE cqnet {np.sqrt(np.mean(ours[-1][10:] ** 2)):.2f} m, "
              f"Stone Soup {np.sqrt(np.mean(errors[10:] ** 2)):.2f} m; "
              f"bound on cqnet's particles {np.mean(ours_bound[-1][10:]):.2f} m, "
              f"on Stone Soup's {np.mean(bound[10:]):.2f} m")

    # The two filters' RMSE from step 10, compared run by run (each run's
    # pair shares its truth and sensors): the mean difference and its 95 %
    # interval, Student's t on runs − 1 degrees of freedom.
    if args.runs > 1:
        from scipy.stats import t as student

        per_run = lambda e: np.sqrt(np.mean(np.square(e)[10:]))  # noqa: E731
        d = np.array([per_run(a) - per_run(b) for a, b in zip(ours, theirs)])
        half = student.ppf(0.975, len(d) - 1) * d.std(ddof=1) / math.sqrt(len(d))
        verdict = "not resolved" if abs(d.mean()) <= half else (
            "cqnet lower" if d.mean() < 0 else "Stone Soup lower")
        print(f"RMSE cqnet − Stone Soup, paired over {len(d)} runs: "
              f"{d.mean():+.3f} ± {half:.3f} m ({verdict} at {len(d)} runs)")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.arange(1, args.steps + 1)
    rmse = lambda e: np.sqrt(np.mean(np.square(e), axis=0))  # noqa: E731
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.plot(steps, rmse(ours), color="tab:blue", label="cqnet centralized PF: RMSE")
    ax.plot(steps, np.mean(ours_bound, axis=0), color="tab:blue", ls="--",
            label="CQ/PCRLB on cqnet's particles")
    ax.plot(steps, rmse(theirs), color="tab:orange", label="Stone Soup PF: RMSE")
    ax.plot(steps, np.mean(theirs_bound, axis=0), color="tab:orange", ls="--",
            label="CQ/PCRLB on Stone Soup's particles")
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("position RMSE and bound (m)")
    ax.set_title(f"cqnet's default scenario, 8-bit bearings, {args.runs} runs")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"figure in {args.out}")


if __name__ == "__main__":
    main()
