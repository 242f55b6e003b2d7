#!/usr/bin/env bash
# chirpmap against Python peers, side by side (issue 14): builds the release CLI, makes a
# venv with numpy, scipy and pyroomacoustics (requirements.txt), runs bench.py. Not part of CI.
# Usage: scripts/bench-vs-python/run.sh [--reps N] [--rows map,range,synth] [--echoes N] [--band-echoes N] [--chirps N]
# Environment: VENV (default target/bench-vs-python-venv), PYTHON (default python3).
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=${VENV:-target/bench-vs-python-venv}
if [ ! -x "$venv/bin/python" ]; then
  "${PYTHON:-python3}" -m venv "$venv"
fi
# Every run: an older venv gets what requirements.txt added since (no-op when satisfied).
"$venv/bin/pip" install --quiet -r scripts/bench-vs-python/requirements.txt
cargo build --release -p chirpmap-cli
"$venv/bin/python" scripts/bench-vs-python/bench.py --chirpmap target/release/chirpmap "$@"
