"""``sim``, ``run`` and ``experiment``: the runtime's three ways to work,
each a job on a native thread that this waits for."""

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

from . import _cqnet
from ._cqnet import Scenario
from ._progress import follow
from .results import ExperimentResult, MonteCarloResults, Results

ScenarioLike = Union[Scenario, str, "os.PathLike[str]", None]


def _scenario(scenario: ScenarioLike) -> Scenario:
    """A Scenario as given, the default one for None, or a file's."""
    if scenario is None:
        return Scenario.default()
    if isinstance(scenario, Scenario):
        return scenario
    return Scenario.from_file(os.fspath(scenario))


def _prepared(
    scenario: ScenarioLike, seed: Optional[int], faults: Optional[Sequence[Dict[str, Any]]]
) -> Scenario:
    s = _scenario(scenario).copy()
    if seed is not None:
        s.set("seed", seed)
    if faults:
        s = s.with_faults(list(faults))
    return s


def _out(out: Union[str, "os.PathLike[str]", None], what: str) -> Path:
    """The results folder: as given, or a new temporary one (kept, so that
    the files stay for the user to read)."""
    if out is not None:
        path = Path(out)
        path.mkdir(parents=True, exist_ok=True)
        return path
    return Path(tempfile.mkdtemp(prefix=f"cqnet-{what}-"))


def sim(
    scenario: ScenarioLike = None,
    runs: int = 1,
    seed: Optional[int] = None,
    *,
    faults: Optional[Sequence[Dict[str, Any]]] = None,
    out: Union[str, "os.PathLike[str]", None] = None,
    threads: Optional[int] = None,
    centralized: Optional[bool] = None,
    progress: Optional[bool] = None,
) -> Union[Results, MonteCarloResults]:
    """Runs the scenario's network in this process on a virtual clock, as
    ``cqnet sim`` does, and returns its results.

    With ``runs > 1``, seeds ``seed, seed+1, …`` run over ``threads``
    threads and a ``MonteCarloResults`` averages them. ``seed`` replaces
    the scenario's; ``faults`` (dicts as ``[[faults]]`` tables) are added
    to its own. Results go to ``out`` (a new temporary folder if None).
    ``centralized``: run the centralized reference (the scenario's choice
    if None). ``progress``: a bar on a terminal by default, quiet in a
    notebook unless True. Ctrl-C stops it between steps.
    """
    if runs < 1:
        raise ValueError("runs must be at least 1")
    s = _prepared(scenario, seed, faults)
    folder = _out(out, "sim")
    job = _cqnet.start_sim(s, str(folder), runs, threads, centralized)
    summary = json.loads(follow(job, progress, "sim"))
    if runs == 1:
        return Results(folder, summary)
    return MonteCarloResults(folder, summary)


def _actor_command() -> Tuple[str, List[str]]:
    """How each actor of a run starts: this interpreter, isolated from the
    environment and without site-packages (-I -S), loading the native
    module alone and running cqnet's entry point. An actor needs nothing
    of the package's Python half, and skipping it takes a process's start
    from about 40 ms to 15 ms, which counts at hundreds of actors."""
    code = (
        "import importlib.util as u, signal, sys; "
        # Ctrl-C is the launcher's to handle; an actor dies of it, as the binary's does.
        "signal.signal(signal.SIGINT, signal.SIG_DFL); "
        "s = u.spec_from_file_location('cqnet._cqnet', {!r}); "
        "m = u.module_from_spec(s); s.loader.exec_module(m); "
        "sys.exit(m.cli_main(['cqnet', *sys.argv[1:]]))"
    ).format(_cqnet.__file__)
    return sys.executable, ["-I", "-S", "-c", code]


def run(
    scenario: ScenarioLike = None,
    lockstep: bool = False,
    faults: Optional[Sequence[Dict[str, Any]]] = None,
    *,
    seed: Optional[int] = None,
    out: Union[str, "os.PathLike[str]", None] = None,
    centralized: Optional[bool] = None,
    run_id: Optional[str] = None,
    progress: Optional[bool] = None,
    cores: str = "auto",
) -> Results:
    """Runs the scenario as a network of real processes over iceoryx2
    shared memory, as ``cqnet run`` does: one process per node and per
    sensor (each this Python interpreter running cqnet), faults injected,
    every byte counted.

    ``lockstep``: each step waits for every report instead of the clock,
    which gives ``sim``'s results bit for bit unless a consensus round
    ends at its deadline without a neighbour's value (``short_rounds`` in
    ``ticks``; the summary's ``timing_dependent`` says so). ``cores``:
    ``"auto"`` places each node with its sensors on one core when there are
    16 nodes a core or more, ``"off"`` leaves them to the kernel.
    ``faults``: dicts as
    ``[[faults]]`` tables, e.g. ``{"kind": "kill", "actor": "node-4",
    "at_step": 10, "signal": "SIGKILL", "restart_after": 5}``. Ctrl-C stops
    the run: its processes are stopped and reaped and its shared memory
    removed before ``KeyboardInterrupt`` is raised.
    """
    s = _prepared(scenario, seed, faults)
    folder = _out(out, "run")
    _cqnet.set_actor_program(*_actor_command())
    job = _cqnet.start_run(s, str(folder), lockstep, centralized, run_id, cores)
    summary = json.loads(follow(job, progress, "run"))
    return Results(folder, summary)


def experiments() -> List[Tuple[str, str, str]]:
    """Every experiment cqnet can run, as (name, source, what it shows)."""
    return _cqnet.list_experiments()


def experiment(
    name: str,
    runs: int = 20,
    *,
    steps: Optional[int] = None,
    out: Union[str, "os.PathLike[str]", None] = None,
    threads: Optional[int] = None,
    trajectories: int = 1000,
    progress: Optional[bool] = None,
) -> ExperimentResult:
    """Runs a paper's experiment (``experiments()`` lists them), as
    ``cqnet experiment NAME --runs RUNS`` does, and returns its data and
    its verdicts: each claim judged by its paired 95 % interval.

    Ctrl-C stops it between steps of its runs and raises
    ``KeyboardInterrupt``; what it wrote so far stays in ``out``.
    """
    folder = _out(out, "experiment")
    job = _cqnet.start_experiment(name, str(folder), runs, steps, threads, trajectories)
    return ExperimentResult(json.loads(follow(job, progress, name)))
