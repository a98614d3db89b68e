"""The bounds over NumPy arrays, against closed forms, the Kalman filter,
finite differences and the values the Rust tests check."""

import itertools
import math

import numpy as np
import pytest

from cqnet import bounds


def test_one_threshold_at_the_mean_gives_two_over_pi_sigma_squared():
    # The Rust test of the same name, through the Python API.
    for sigma in [0.1, 1.0, 7.0]:
        j = bounds.quantized_fisher_information([3.0], np.array(3.0), sigma)
        assert float(j) == pytest.approx(2.0 / (math.pi * sigma**2), rel=1e-13)


def test_quantized_information_grows_with_bits_towards_the_raw_value():
    sigma = 2.0
    raw = 1.0 / sigma**2
    means = np.array([0.37, -1.1, 2.5])
    previous = np.zeros(3)
    for bits in range(1, 13):
        q = bounds.Quantizer.uniform(bits, -6 * sigma, 6 * sigma)
        j = q.fisher_information(means, sigma)
        assert j.shape == (3,)
        assert np.all(j > previous) and np.all(j <= raw * (1 + 1e-12))
        previous = j
    assert np.all(previous / raw > 0.999)


def constant_velocity(period, sigma_v):
    """F and the continuous white-noise Q, written out independently."""
    t = period
    f = np.eye(4)
    f[0, 2] = f[1, 3] = t
    q = np.zeros((4, 4))
    block = sigma_v**2 * np.array([[t**3 / 3, t**2 / 2], [t**2 / 2, t]])
    for axis, (p, v) in enumerate([(0, 2), (1, 3)]):
        q[np.ix_([p, v], [p, v])] = block
    return f, q


def test_a_linear_gaussian_model_reproduces_the_kalman_information():
    dynamics = bounds.Dynamics(period=1.0, sigma_v=0.5, maneuver_accel=0.0)
    f, q = constant_velocity(1.0, 0.5)
    np.testing.assert_allclose(dynamics.q, q, rtol=1e-12)
    h = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    r = 4.0
    sensors = [
        bounds.Sensor({"kind": "linear", "h": list(row), "r": r}) for row in h
    ]
    rng = np.random.default_rng(3)
    information = np.linalg.inv(np.diag([100.0, 100.0, 4.0, 4.0]))
    kalman = information.copy()
    for _ in range(8):
        particles = rng.normal(size=(300, 4)) * [50, 50, 2, 2] + [0, 0, 5, 5]
        weights = rng.random(300)
        weights /= weights.sum()
        delta = bounds.expected_information(sensors, particles, weights)
        np.testing.assert_allclose(delta, h.T @ h / r, atol=1e-12)
        predicted, information = bounds.conditional_bound_step(
            information, dynamics, particles, delta, weights
        )
        kalman_predicted = np.linalg.inv(q + f @ np.linalg.inv(kalman) @ f.T)
        kalman = kalman_predicted + h.T @ h / r
        np.testing.assert_allclose(predicted, kalman_predicted, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(information, kalman, rtol=1e-9, atol=1e-12)
    cov = np.linalg.inv(kalman)
    assert bounds.position_bound(information) == pytest.approx(math.sqrt(cov[0, 0] + cov[1, 1]), rel=1e-9)


def test_raw_bearing_information_is_its_finite_difference_form():
    law = {"kind": "bearing", "sigma_theta": 0.02, "d0": 500.0}
    sensor = bounds.Sensor(law, position=(100.0, -50.0))
    states = np.array([[400.0, 300.0, 3.0, -1.0], [-200.0, 90.0, 0.0, 2.0]])
    js = sensor.information(states)
    assert js.shape == (2, 4, 4)
    h = 1e-4
    for x, j in zip(states, js):
        grad_g = np.zeros(4)
        grad_r = np.zeros(4)
        for i in range(4):
            step = np.zeros(4)
            step[i] = h
            gp, rp = sensor.mean_and_variance(x + step)
            gm, rm = sensor.mean_and_variance(x - step)
            grad_g[i] = (gp - gm) / (2 * h)
            grad_r[i] = (rp - rm) / (2 * h)
        _, r = sensor.mean_and_variance(x)
        expected = np.outer(grad_g, grad_g) / r + np.outer(grad_r, grad_r) / (2 * r * r)
        np.testing.assert_allclose(j, expected, rtol=1e-6, atol=1e-12)


def test_the_cloud_sum_is_the_weighted_sum_of_each_particles():
    law = {"kind": "bearing", "sigma_theta": 0.02, "d0": 500.0}
    quantizer = bounds.Quantizer.uniform_wrapped(6, -math.pi, math.pi)
    sensors = [bounds.Sensor(law, (x, y), quantizer) for x, y in [(0, 0), (300, 100), (-50, 400)]]
    rng = np.random.default_rng(5)
    particles = rng.normal(size=(150, 4)) * [80, 80, 2, 2] + [150, 150, 0, 0]
    weights = rng.random(150)
    weights /= weights.sum()
    total = bounds.expected_information(sensors, particles, weights)
    one_by_one = sum(np.einsum("n,nij->ij", weights, s.information(particles)) for s in sensors)
    np.testing.assert_allclose(total, one_by_one, rtol=1e-9, atol=1e-15)


def test_greedy_selection_is_the_greedy_on_selection_cost():
    rng = np.random.default_rng(11)
    predicted = np.diag([0.01, 0.01, 0.5, 0.5])
    candidates = []
    for node, sensor in itertools.product(range(3), range(4)):
        a = rng.normal(size=(2, 4)) * [1, 1, 0, 0]
        candidates.append((node, sensor, a.T @ a * rng.random()))
    chosen = bounds.greedy_selection(predicted, candidates, per_node_cap=2, n_max=4)
    # The same greedy, written here on selection_cost and on NumPy's inverse.
    mine, total = [], np.zeros((4, 4))
    while len(mine) < 4:
        best = None
        for node, sensor, j in candidates:
            if (node, sensor) in mine or sum(n == node for n, _ in mine) >= 2:
                continue
            cost = bounds.selection_cost(predicted, total, j)
            inverse = np.linalg.inv(predicted + total + j)
            assert cost == pytest.approx(inverse[0, 0] + inverse[1, 1], rel=1e-9)
            if best is None or (cost, node, sensor) < best[:3]:
                best = (cost, node, sensor, j)
        mine.append((best[1], best[2]))
        total = total + best[3]
    assert chosen == mine


def test_the_conditional_bound_class_tightens_with_information():
    s_dyn = bounds.Dynamics(period=1.0, sigma_v=0.05, maneuver_accel=0.1, min_speed=0.1)
    law = {"kind": "bearing", "sigma_theta": 0.02, "d0": 500.0}
    sensors = [bounds.Sensor(law, (x, y)) for x, y in [(0, 0), (1000, 0), (0, 1000)]]
    bound = bounds.ConditionalBound(np.diag([2500.0, 2500.0, 4.0, 4.0]), s_dyn)
    rng = np.random.default_rng(2)
    particles = rng.normal(size=(500, 4)) * [50, 50, 2, 2] + [500, 500, 5, -5]
    first = bound.bound
    for _ in range(5):
        predicted = s_dyn.transition(particles)
        bound.advance(particles, sensors, predicted)
        particles = predicted
    assert bound.bound < first / 2


def test_bad_arrays_are_value_errors():
    with pytest.raises(ValueError, match="shape"):
        bounds.position_bound(np.eye(3))
    with pytest.raises(ValueError, match="weights"):
        bounds.expected_information([], np.zeros((3, 4)), np.ones(2))
    with pytest.raises(ValueError, match="law"):
        bounds.Sensor({"kind": "bearing", "sigma_theta": -1.0, "d0": 1.0})
    with pytest.raises(ValueError):
        bounds.Quantizer.from_thresholds([1.0, 0.0])


def test_laws_and_models_are_named_by_kind_and_listed():
    assert bounds.observation_laws()[:4] == ["bearing", "rss", "amplitude", "linear"]
    assert "coordinated_turn" in bounds.motion_models()
    table = {"kind": "coordinated_turn", "period": 1.0, "maneuver_accel": 0.0,
             "min_speed": 1.0, "sigma_v": 0.5}
    of = bounds.Dynamics.of(table)
    direct = bounds.Dynamics(period=1.0, sigma_v=0.5)
    np.testing.assert_array_equal(of.q, direct.q)
    with pytest.raises(ValueError, match="dynamics.kind"):
        bounds.Dynamics.of({"kind": "brownian", "period": 1.0})
    with pytest.raises(ValueError, match="dynamics.sigma_v"):
        bounds.Dynamics.of(dict(table, sigma_v=-1.0))
    with pytest.raises(ValueError, match="observation.kind"):
        bounds.Sensor({"kind": "sonar"})
    with pytest.raises(ValueError, match="observation.sigma_theta"):
        bounds.Sensor({"kind": "bearing", "sigma_theta": -1.0, "d0": 10.0})
