"""The mathematics of cqnet over NumPy arrays: the Fisher information of
quantized and raw observations, and the conditional posterior Cramér-Rao
bound's recursion, on any particle cloud (cqnet's own, or another
tracker's).

States are ``[x, y, vx, vy]``; a particle cloud is an ``(n, 4)`` array
with optional ``(n,)`` weights (uniform if omitted). The recursion, one
step from the posterior particles at k:

    L(k+1|k) = Q⁻¹ − B21 (L(k) + B11)⁻¹ B12
    L(k+1)   = L(k+1|k) + ΔL(k+1),   ΔL = Σ_j w_j Σ_s J_s(x_j)

over the predicted particles, and the position bound is
sqrt(tr[L⁻¹]_pos) metres, comparable with an RMSE.

A ``Sensor`` names its law by ``kind`` with the law's parameters, as a
scenario's ``[observation]`` table does, and ``Dynamics.of`` a motion
model by its ``[dynamics]`` table; ``observation_laws()`` and
``motion_models()`` list the kinds the package knows:

    laws     bearing (sigma_theta, d0, near_field), rss (p0, zeta, d0,
             sigma, near_field), amplitude (p0, alpha, exponent, sigma),
             linear (h, r)
    models   coordinated_turn (period, maneuver_accel, min_speed,
             sigma_v, process_noise)
"""

from typing import Any, Optional

from ._cqnet import (
    Dynamics,
    Quantizer,
    Sensor,
    conditional_bound_step,
    dynamics_terms,
    expected_information,
    greedy_selection,
    motion_models,
    observation_laws,
    position_bound,
    quantized_fisher_information,
    selection_cost,
)

__all__ = [
    "ConditionalBound",
    "Dynamics",
    "Quantizer",
    "Sensor",
    "conditional_bound_step",
    "dynamics_terms",
    "expected_information",
    "greedy_selection",
    "motion_models",
    "observation_laws",
    "position_bound",
    "quantized_fisher_information",
    "selection_cost",
]


class ConditionalBound:
    """The conditional PCRLB carried from step to step on a tracker's own
    particles: start from the prior covariance P₀ (L(0) = P₀⁻¹), then each
    step ``advance`` with the posterior particles at k (for B11, B12), the
    sensors that report at k+1 and the predicted particles at k+1 (for ΔL).
    ``bound`` is the position bound in metres after the last step."""

    def __init__(self, prior_covariance: Any, dynamics: Dynamics) -> None:
        import numpy as np

        self.information = np.linalg.inv(np.asarray(prior_covariance, dtype=float))
        self.dynamics = dynamics

    def advance(
        self,
        posterior: Any,
        sensors: Any,
        predicted: Any,
        posterior_weights: Optional[Any] = None,
        predicted_weights: Optional[Any] = None,
    ) -> float:
        """One step; returns the new position bound in metres."""
        delta = expected_information(list(sensors), predicted, predicted_weights)
        _, self.information = conditional_bound_step(
            self.information, self.dynamics, posterior, delta, posterior_weights
        )
        return self.bound

    @property
    def bound(self) -> float:
        b = position_bound(self.information)
        return float("nan") if b is None else b
