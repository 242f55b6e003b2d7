#!/usr/bin/env bash
# Evidence and paper mappers on long walks (issue 9's speed on large inputs):
# a listener wandering for N poses (10 ms apart) inside an 8 m x 6 m room,
# four first-order wall echoes per pose (image sources), Gaussian noise of
# 1 cm on each delta_d (sigma_m = 0.01). Prints each mapper's `elapsed_s`
# (summary.json: the mapper alone) and the time per echo, so growth faster
# than linear shows.
# Usage: scripts/bench/long-walk.sh [target/release/chirpmap] [POSES...]
set -euo pipefail
bin=${1:-target/release/chirpmap}
shift || true
poses=("$@")
[ $# -gt 0 ] || poses=(6000 20000 60000)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for n in "${poses[@]}"; do
  python3 - "$tmp/walk-$n.csv" "$n" <<'PY'
import math, random, sys
path, n = sys.argv[1], int(sys.argv[2])
random.seed(1)
sx, sy, w, h = 2.0, 1.5, 8.0, 6.0
images = [(-sx, sy), (2 * w - sx, sy), (sx, -sy), (sx, 2 * h - sy)]
with open(path, "w") as f:
    f.write("source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener,sigma_m\n")
    for i in range(n):
        t = 0.01 * i
        u = 0.2 * t
        lx = 4 + 2.6 * math.cos(u) + 0.3 * math.sin(3.1 * u)
        ly = 3 + 1.8 * math.sin(u) + 0.3 * math.cos(2.3 * u)
        direct = math.hypot(lx - sx, ly - sy)
        for ix, iy in images:
            dd = math.hypot(lx - ix, ly - iy) - direct + random.gauss(0.0, 0.01)
            f.write(f"{sx},{sy},{lx:.5f},{ly:.5f},{dd:.5f},1,{t:.3f},0,0.01\n")
PY
  for mapper in paper evidence; do
    out="$tmp/$mapper-$n"
    "$bin" --no-progress map --echoes "$tmp/walk-$n.csv" --mapper "$mapper" --bounds=-1,-1,9,7 --out "$out" >/dev/null
    python3 - "$out/summary.json" "$n" "$mapper" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); echoes = 4 * int(sys.argv[2])
print(f"{sys.argv[3]:8s} {echoes:7d} echoes  {s['elapsed_s']:7.3f} s  {1e6 * s['elapsed_s'] / echoes:6.2f} us/echo")
PY
  done
done
