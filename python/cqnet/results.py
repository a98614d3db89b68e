"""What a ``sim``, a ``run`` or an experiment leaves: its folder's files as
Python values.

``ticks.csv`` and ``links.csv`` are parsed once, in Rust, into arrays that
NumPy takes over without a copy; a DataFrame (with pandas installed) is
built on those arrays without copying them again.
"""

import json
from pathlib import Path
from typing import Any, Dict, List, Optional, Union

from . import _cqnet

Columns = Dict[str, Any]


def _frame(columns: Columns) -> Any:
    """A DataFrame over the arrays if pandas is installed, else the dict."""
    try:
        import pandas as pd
    except ImportError:
        return columns
    return pd.DataFrame(columns, copy=False)


class Results:
    """A finished ``sim`` or ``run``.

    - ``ticks``: one row per step and node (and ``central``, the
      centralized reference): truth, estimate, ``error``, ``bound`` (the
      CQ/dPCRLB position bound, metres), ``local_bound``, ``aux_bound``,
      consensus ``rounds``, ``live_neighbours``, ``observations``,
      ``deadline_missed``, ``spread``, the ``active`` sensors and, for a
      fusion centre behind a multiple-access channel, the ``design``: each
      sensor's transmission probability, ``;``-separated; and the
      ``disagreement``: how far the node still was from its neighbours
      after its last consensus round, as a share (empty where its
      protocol does not measure it); ``short_rounds``: consensus rounds
      that ended at their deadline without a neighbour's value they
      awaited.
    - ``links``: per directed link (``from``, ``to``) and message ``kind``,
      messages and bytes sent, received, dropped, malformed and duplicated.
    - ``summary``: ``summary.json`` as a dict, with its ``estimates``
      (``rmse``, ``mean_bound``, ``centralized_rmse``, …) also at its top.

    ``ticks`` and ``links`` are DataFrames when pandas is installed, else
    dicts of NumPy arrays (text columns as lists); ``arrays("ticks")``
    always gives the dict.
    """

    def __init__(self, out: Union[str, Path], summary: Optional[Dict[str, Any]] = None) -> None:
        self.out = Path(out)
        self._summary = summary
        self._columns: Dict[str, Columns] = {}

    @classmethod
    def load(cls, out: Union[str, Path]) -> "Results":
        """The results a ``cqnet run`` or ``cqnet sim`` wrote into ``out``."""
        return cls(out)

    @property
    def summary(self) -> Dict[str, Any]:
        if self._summary is None:
            self._summary = json.loads((self.out / "summary.json").read_text())
        summary = dict(self._summary)
        for key, value in summary.get("estimates", {}).items():
            summary.setdefault(key, value)
        return summary

    def arrays(self, name: str) -> Columns:
        """``ticks`` or ``links`` as a dict of NumPy arrays (text as lists)."""
        if name not in ("ticks", "links"):
            raise ValueError(f"no table {name!r}: there are 'ticks' and 'links'")
        if name not in self._columns:
            self._columns[name] = _cqnet.read_columns(str(self.out / f"{name}.csv"))
        return self._columns[name]

    @property
    def ticks(self) -> Any:
        return _frame(self.arrays("ticks"))

    @property
    def links(self) -> Any:
        return _frame(self.arrays("links"))

    def bytes(
        self,
        sender: Optional[str] = None,
        receiver: Optional[str] = None,
        kind: Optional[str] = None,
        field: str = "sent_bytes",
    ) -> int:
        """The sum of ``field`` over the links from ``sender`` to
        ``receiver`` of ``kind`` (None: any), e.g.
        ``bytes("node-0", "node-1", "consensus")``."""
        links = self.arrays("links")
        total = 0
        for i, value in enumerate(links[field]):
            if sender is not None and links["from"][i] != sender:
                continue
            if receiver is not None and links["to"][i] != receiver:
                continue
            if kind is not None and links["kind"][i] != kind:
                continue
            total += int(value)
        return total

    def plot(self, ax: Any = None, nodes: Optional[List[str]] = None) -> Any:
        """Each node's position error (solid) and CQ/dPCRLB (dashed) against
        the step, the centralized reference in black, and each fault's
        window shaded. Needs matplotlib; returns the Axes."""
        import matplotlib.pyplot as plt
        import numpy as np

        if ax is None:
            _, ax = plt.subplots(figsize=(8, 4.5))
        t = self.arrays("ticks")
        names = np.asarray(t["node"], dtype=object)
        wanted = nodes if nodes is not None else sorted(
            {n for n in names if n != "central"}, key=_node_order
        )
        colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for i, node in enumerate(wanted):
            rows = names == node
            colour = colours[i % len(colours)]
            ax.plot(t["step"][rows], t["error"][rows], color=colour, lw=1, label=f"{node} error")
            ax.plot(t["step"][rows], t["bound"][rows], color=colour, lw=1, ls="--")
        central = names == "central"
        if central.any():
            ax.plot(t["step"][central], t["error"][central], color="black", lw=1.5, label="centralized error")
            ax.plot(t["step"][central], t["bound"][central], color="black", lw=1.5, ls="--", label="centralized bound")
        last = int(t["step"].max()) if len(t["step"]) else 0
        for fault in self.summary.get("faults", []):
            end = fault.get("until_step") or last
            ax.axvspan(fault["step"], end, color="tab:red", alpha=0.12, lw=0)
            ax.text(fault["step"], 1.0, fault["fault"], transform=ax.get_xaxis_transform(),
                    fontsize=7, va="top", color="tab:red", clip_on=True)
        ax.set_yscale("log")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_xlabel("step")
        ax.set_ylabel("position error, bound (m)")
        ax.set_title("error (solid) and CQ/dPCRLB (dashed) per node")
        if len(wanted) <= 10:
            ax.legend(fontsize=7, ncol=2)
        return ax

    def __repr__(self) -> str:
        s = self.summary
        return (f"Results({str(self.out)!r}: {s.get('command')} of {s.get('steps')} steps, "
                f"RMSE {s.get('rmse')}, bound {s.get('mean_bound')})")


def _node_order(name: str) -> Any:
    prefix, _, number = name.partition("-")
    return (prefix, int(number)) if number.isdigit() else (prefix, 0)


class MonteCarloResults:
    """``sim`` with several runs: ``summary`` averages them
    (``summary.json``), and ``runs[i]`` is run i's ``Results`` (seed + i)."""

    def __init__(self, out: Union[str, Path], summary: Dict[str, Any]) -> None:
        self.out = Path(out)
        self._summary = summary
        self.runs = [Results(self.out / f"run-{i:03}", s) for i, s in enumerate(summary.get("per_run", []))]

    @property
    def summary(self) -> Dict[str, Any]:
        summary = {k: v for k, v in self._summary.items() if k != "per_run"}
        for key, value in summary.get("estimates", {}).items():
            summary.setdefault(key, value)
        return summary

    def __repr__(self) -> str:
        s = self.summary
        return f"MonteCarloResults({str(self.out)!r}: {s.get('runs')} runs, RMSE {s.get('rmse')})"


class ExperimentResult:
    """A paper's experiment: ``verdict`` ("holds", "does not hold" or "not
    resolved"), ``claims`` (each with its paired mean difference, 95 %
    half-width, runs and verdict), ``statement``, and ``data``: the
    experiment's CSV as a DataFrame (or dict of arrays). ``svg`` is its
    figure, ``dir`` its folder."""

    def __init__(self, outcome: Dict[str, Any]) -> None:
        self.name: str = outcome["name"]
        self.source: str = outcome["source"]
        self.about: str = outcome["about"]
        self.line: str = outcome["line"]
        check = outcome["check"]
        self.verdict: str = check["verdict"]
        self.statement: str = check["statement"]
        self.claims: List[Dict[str, Any]] = check["claims"]
        self.table: Optional[str] = outcome.get("table")
        self.dir = Path(outcome["dir"])
        self.csv = Path(outcome["csv"])
        self.svg = Path(outcome["svg"])
        self.claims_csv = Path(outcome["claims_csv"])
        self._data: Optional[Columns] = None

    def arrays(self) -> Columns:
        if self._data is None:
            self._data = _cqnet.read_columns(str(self.csv))
        return self._data

    @property
    def data(self) -> Any:
        return _frame(self.arrays())

    def __repr__(self) -> str:
        return f"ExperimentResult({self.name!r}: {self.verdict}; {len(self.claims)} claims)"
