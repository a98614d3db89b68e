#!/usr/bin/env bash
# Stone Soup's particle filter against cqnet's, side by side, on one node's
# workload: 1000 particles, three bearing updates a step, the filter alone.
# Installs stonesoup from PyPI into a virtual environment under target/
# (once), times it, then runs cqnet's criterion bench of the same loop.
# Run it alone on an idle machine: `bash bench/peers/stonesoup.sh`.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$root/target/peers/stonesoup-venv"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet stonesoup==1.9.1
fi
echo "== Stone Soup (CV dynamics, raw bearings; updater resamples)"
"$venv/bin/python" "$root/bench/peers/stonesoup_pf.py" 100
echo "== cqnet (coordinated-turn dynamics, 8-bit quantized bearings, tempered updater)"
cd "$root"
cargo bench -p node --bench node_step -- "particle filter alone" 2>&1 | grep -E "^particle filter alone|time:"
