#!/usr/bin/env bash
# `map` time with 300 000 echoes of one source vs 300 000 distinct sources
# (issue 14, item 2): same bounds, interleaved, whole processes.
# Usage: scripts/bench/distinct-sources.sh [target/release/chirpmap]
set -euo pipefail
bin=${1:-target/release/chirpmap}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 - "$tmp" <<'PY'
import random, sys
random.seed(1)
for name, distinct in [("one", False), ("distinct", True)]:
    with open(f"{sys.argv[1]}/{name}.csv", "w") as f:
        f.write("source_x,source_y,listener_x,listener_y,delta_d\n")
        for _ in range(300000):
            sx, sy = (random.uniform(-5, 5), random.uniform(-5, 5)) if distinct else (0.0, 0.0)
            f.write(f"{sx},{sy},{random.uniform(-5, 5)},{random.uniform(-5, 5)},{random.uniform(0.5, 3.0)}\n")
PY
for rep in 1 2 3; do
  for n in one distinct; do
    s=$( { /usr/bin/time -f "%e" "$bin" map --echoes "$tmp/$n.csv" --bounds -12,-12,12,12 --out "$tmp/out-$n-$rep" >/dev/null; } 2>&1 | tail -1)
    echo "$n $s"
  done
done
