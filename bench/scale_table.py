"""The scale table of docs/performance.md: the default network and two
larger grids of the same spacing (235, 937 and 2,601 processes), each with
the consensus rounds its fusion graph needs (`consensus.rounds = "auto"`,
unless --rounds says), run by `sim`, by `run --lockstep` and by `run` at the
scenario's clock (10 Hz), one run at a time. Prints a Markdown table.
"Short rounds" are consensus rounds that ended at their deadline without a
neighbour's value: a run with any depends on timing.

    python3 bench/scale_table.py [--cqnet target/release/cqnet] [--steps 100]
        [--sizes 235,937,2601] [--clocks lockstep,realtime] [--rounds auto]

Build first (`cargo build --release --bin cqnet`) and run it alone on an
idle machine: every figure is one run's, and the runs take the machine.
"""

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

# Nodes 500 m apart, 25 sensors each, as in the default scenario: processes
# are nodes × 26 + the launcher.
GRIDS = {
    235: ([3, 3], 1500),
    937: ([6, 6], 3000),
    2601: ([10, 10], 5000),
}


def run(cqnet, command, grid, width, steps, rounds, out):
    """Runs one cqnet command and returns its summary.json."""
    args = [cqnet, *command, "--no-central", "--out", str(out)]
    sets = [
        f"nodes.grid=[{grid[0]},{grid[1]}]",
        f"region.width={width}",
        f"region.height={width}",
        f"steps={steps}",
        f"consensus.rounds={rounds}",
    ]
    for s in sets:
        args += ["--set", s]
    started = time.monotonic()
    done = subprocess.run(args, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(
            f"`{' '.join(args)}` failed ({done.returncode}):\n{done.stderr[-2000:]}"
        )
    summary = json.loads((out / "summary.json").read_text())
    print(
        f"  {' '.join(command)} {grid[0]}x{grid[1]}: "
        f"{time.monotonic() - started:.0f} s",
        file=sys.stderr,
    )
    return summary


def row(processes, clock, s, sim):
    nodes = s["scenario"]["nodes"]["grid"][0] * s["scenario"]["nodes"]["grid"][1]
    steps = max(s["steps"], 1)
    # Reports that reached the launcher at all, late ones included.
    reported = nodes * s["steps"] - s["fault_cost"]["missing_node_steps"]
    cpu = s.get("children_cpu") or {}
    lat = s.get("round_latency_micros") or {}
    # Against the clock, steps/s is the clock's: only lockstep compares.
    ratio = s["steps_per_second"] / sim["steps_per_second"]
    against_sim = f" ({ratio:.2f}×)" if clock == "lockstep" else ""
    cells = [
        f"{processes:,}",
        clock,
        str(s["scenario"]["consensus"]["rounds"]),
        f"{s['startup_seconds']:.1f} s",
        f"{s['steps_per_second']:.1f}",
        f"{sim['steps_per_second']:.1f}{against_sim}",
        f"{s['deadline_misses']:,}",
        f"{reported:,} / {nodes * s['steps']:,}",
        f"{s['fault_cost'].get('short_rounds', 0):,}",
        f"{s['estimates']['rmse']:.2f} / {s['estimates']['mean_bound']:.2f} m",
        f"{lat.get('p50', 0) / 1e3:.2f} / {lat.get('p99', 0) / 1e3:.2f} ms",
        f"{cpu.get('user_seconds', 0):.1f} / {cpu.get('system_seconds', 0):.1f} s",
        f"{cpu.get('voluntary_switches', 0) / steps:,.0f} / "
        f"{cpu.get('involuntary_switches', 0) / steps:,.0f}",
    ]
    return "| " + " | ".join(cells) + " |"


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cqnet", default="target/release/cqnet")
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--sizes", default="235,937,2601")
    p.add_argument("--clocks", default="lockstep,realtime")
    p.add_argument("--rounds", default='"auto"')
    a = p.parse_args()
    sizes = [int(x) for x in a.sizes.split(",")]
    unknown = [s for s in sizes if s not in GRIDS]
    if unknown:
        sys.exit(f"--sizes: {unknown} not among {sorted(GRIDS)}")
    clocks = a.clocks.split(",")
    if any(c not in ("lockstep", "realtime") for c in clocks):
        sys.exit("--clocks: each is lockstep or realtime")
    if not pathlib.Path(a.cqnet).is_file():
        sys.exit(f"--cqnet: no {a.cqnet} (cargo build --release --bin cqnet)")
    rows = []
    with tempfile.TemporaryDirectory(prefix="cqnet-scale-") as tmp:
        for size in sizes:
            grid, width = GRIDS[size]
            out = pathlib.Path(tmp) / str(size)
            sim = run(a.cqnet, ["sim"], grid, width, a.steps, a.rounds, out / "sim")
            for clock in clocks:
                command = ["run", "--lockstep"] if clock == "lockstep" else ["run"]
                s = run(a.cqnet, command, grid, width, a.steps, a.rounds, out / clock)
                label = "lockstep" if clock == "lockstep" else (
                    f"{1000 / s['scenario']['clock']['step_period_ms']:.0f} Hz"
                )
                rows.append(row(size, label, s, sim))
    print(
        "| processes | clock | rounds | start-up | steps/s | `sim` steps/s "
        "| deadline misses | node-steps reported | short rounds | RMSE / bound "
        "| round p50 / p99 | children user / kernel CPU | context switches "
        "per step, voluntary / involuntary |"
    )
    print("|" + "---|" * 13)
    for r in rows:
        print(r)


if __name__ == "__main__":
    main()
