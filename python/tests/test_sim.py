"""`sim` in process: the binary's results bit for bit, several runs, and
Ctrl-C between steps."""

import _thread
import json
import signal
import subprocess
import threading

import pytest

import cqnet
from conftest import small_scenario


def binary_sim(cqnet_bin, scenario, out, *extra):
    path = out / "scenario.toml"
    path.write_text(scenario.to_toml())
    subprocess.run(
        [str(cqnet_bin), "sim", str(path), "--out", str(out / "binary"), *extra],
        check=True,
        capture_output=True,
    )
    return out / "binary"


def test_sim_gives_the_binarys_results_bit_for_bit(cqnet_bin, tmp_out):
    s = small_scenario(steps=25)
    r = cqnet.sim(s, out=tmp_out / "python")
    b = binary_sim(cqnet_bin, s, tmp_out)
    for name in ["ticks.csv", "links.csv"]:
        assert (r.out / name).read_bytes() == (b / name).read_bytes(), name
    theirs = json.loads((b / "summary.json").read_text())
    assert r.summary["estimates"] == theirs["estimates"]
    assert r.summary["traffic"] == theirs["traffic"]


def test_the_default_scenarios_rmse_is_the_binarys(cqnet_bin, tmp_out):
    r = cqnet.sim(cqnet.Scenario.default(), out=tmp_out / "python")
    path = tmp_out / "scenario.toml"
    path.write_text(cqnet.Scenario.default().to_toml())
    printed = subprocess.run(
        [str(cqnet_bin), "sim", "--out", str(tmp_out / "binary")],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    theirs = json.loads((tmp_out / "binary" / "summary.json").read_text())
    assert r.summary["rmse"] == theirs["estimates"]["rmse"]
    # The table the command prints shows the same figure, to 3 decimals.
    line = next(l for l in printed.splitlines() if "position RMSE (fused)" in l)
    assert line.split()[-1] == f"{r.summary['rmse']:.3f}"


def test_seed_replaces_the_scenarios(tmp_out):
    s = small_scenario(steps=5)
    a = cqnet.sim(s, seed=7, out=tmp_out / "a")
    b = cqnet.sim(s.copy().set("seed", 7), out=tmp_out / "b")
    assert (a.out / "ticks.csv").read_bytes() == (b.out / "ticks.csv").read_bytes()
    assert s.seed == 1, "sim leaves the caller's scenario as it was"


def test_several_runs_average_their_seeds(tmp_out):
    s = small_scenario(steps=12)
    mc = cqnet.sim(s, runs=3, out=tmp_out, threads=2)
    assert mc.summary["runs"] == 3
    assert len(mc.runs) == 3
    rmses = [run.summary["rmse"] for run in mc.runs]
    assert mc.summary["rmse"] == pytest.approx(sum(rmses) / 3, rel=1e-12)
    one = cqnet.sim(s, seed=s.seed + 2, out=tmp_out / "alone")
    assert (one.out / "ticks.csv").read_bytes() == (mc.runs[2].out / "ticks.csv").read_bytes()


def test_ctrl_c_stops_a_sim_between_steps(tmp_out):
    s = small_scenario(steps=1_000_000)
    # A process started in the background by a shell without job control
    # inherits SIGINT ignored, and then `interrupt_main` does nothing and
    # the sim would run its million steps: Ctrl-C is made Python's own
    # for the test.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(1.0, _thread.interrupt_main)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            cqnet.sim(s, out=tmp_out, progress=False)
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    written = (tmp_out / "ticks.csv").read_text().splitlines()
    assert 1 < len(written) < 1_000_000 * 3


def test_the_gil_is_free_while_a_sim_works(tmp_out):
    """Another Python thread runs while the sim does: the sim holds the
    GIL only between its waits. Held for the whole call, the counter
    would stand still after the interpreter's first switch interval."""
    import time

    box = [0]
    stop = threading.Event()

    def count():
        while not stop.is_set():
            box[0] += 1

    other = threading.Thread(target=count)
    other.start()
    try:
        before, started = box[0], time.monotonic()
        cqnet.sim(small_scenario(steps=300), out=tmp_out, progress=False)
        counted, elapsed = box[0] - before, time.monotonic() - started
    finally:
        stop.set()
        other.join()
    assert elapsed > 0.05
    # About 4·10⁶ a second here while the sim works; a C call holding the
    # GIL lets it reach 10⁵.
    assert counted / elapsed > 500_000, (counted, elapsed)


def test_the_disagreement_after_consensus_is_a_column(tmp_out):
    # Nine nodes: two would agree after one round.
    r = cqnet.sim(cqnet.Scenario.default().update({"steps": 3}), out=tmp_out / "python")
    ticks = r.arrays("ticks")
    nodes = [i for i, n in enumerate(ticks["node"]) if n != "central"]
    values = [ticks["disagreement"][i] for i in nodes]
    assert all(0.0 <= v <= 2.0 for v in values), values
    assert any(v > 0.0 for v in values), "ten rounds leave some disagreement"
    assert r.summary["disagreement"]["largest"] == max(values)
