"""Shared fixtures: a small network, the Rust binary to compare with, and
a run id per test so that tests can run side by side."""

import os
import shutil
import subprocess
import uuid
from pathlib import Path

import pytest

import cqnet

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def cqnet_bin() -> Path:
    """The `cqnet` binary the Python results are compared with:
    $CQNET_BIN, or the workspace's release build (built here if missing)."""
    given = os.environ.get("CQNET_BIN")
    if given:
        return Path(given)
    built = REPO / "target" / "release" / "cqnet"
    if not built.exists():
        subprocess.run(
            ["cargo", "build", "--release", "-p", "cqnet"], cwd=REPO, check=True
        )
    return built


def small_scenario(steps: int = 15) -> cqnet.Scenario:
    """Two nodes with four sensors each: a network of 11 processes."""
    return cqnet.Scenario.default().update(
        {
            "steps": steps,
            "nodes.grid": [2, 1],
            "fusion_graph.radius": 800.0,
            "sensors.per_cell": [2, 2],
            "filter.particles": 200,
        }
    )


@pytest.fixture
def small() -> cqnet.Scenario:
    return small_scenario()


@pytest.fixture
def run_id() -> str:
    return "py" + uuid.uuid4().hex[:10]


def processes_of(run_id: str) -> list:
    """Processes whose command line carries `--run-id <run_id>`."""
    found = []
    needle = f"--run-id\0{run_id}\0".encode()
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                if needle in f.read():
                    found.append(int(entry))
        except OSError:
            continue
    return found


@pytest.fixture
def tmp_out(tmp_path):
    yield tmp_path
    shutil.rmtree(tmp_path, ignore_errors=True)
