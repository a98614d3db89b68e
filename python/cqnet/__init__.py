"""cqnet: run a decentralized sensor network and compute, while it runs,
how well the network can possibly track its target (the CQ/dPCRLB).

>>> import cqnet
>>> r = cqnet.sim(cqnet.Scenario.default())
>>> r.summary["rmse"], r.summary["mean_bound"]
>>> r.ticks            # a DataFrame with pandas installed, else NumPy arrays

- ``Scenario``: a validated scenario; ``.set("filter.particles", 500)``
  changes a value with the checks of ``cqnet --set``.
- ``sim``: the network in this process on a virtual clock.
- ``run``: the network as real processes over shared memory.
- ``experiment``: a paper's experiment with its verdicts.
- ``cqnet.bounds``: the Fisher information and the conditional bound over
  NumPy arrays.

This module imports neither NumPy, pandas nor matplotlib until they are
needed: each actor of a ``run`` is a Python process that starts here.
"""

from ._cqnet import CqnetError, Scenario, ScenarioError, __version__
from ._api import experiment, experiments, run, sim
from .results import ExperimentResult, MonteCarloResults, Results
from . import bounds

__all__ = [
    "CqnetError",
    "ExperimentResult",
    "MonteCarloResults",
    "Results",
    "Scenario",
    "ScenarioError",
    "__version__",
    "bounds",
    "experiment",
    "experiments",
    "run",
    "sim",
]
