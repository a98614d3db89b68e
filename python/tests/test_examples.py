"""The Stone Soup example runs (small), where Stone Soup is installed."""

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "stonesoup_compare.py"


def test_the_stone_soup_example_runs_and_draws_its_figure(tmp_out):
    pytest.importorskip("stonesoup")
    pytest.importorskip("matplotlib")
    figure = tmp_out / "compare.png"
    done = subprocess.run(
        [sys.executable, str(EXAMPLE), "--runs", "2", "--steps", "12", "--particles", "5000",
         "--out", str(figure)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert sum(line.startswith("run ") for line in lines) == 2
    assert any("paired over 2 runs" in line for line in lines)
    assert figure.stat().st_size > 10_000
