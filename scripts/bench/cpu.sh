#!/bin/bash
# Interleaved CPU-time comparison of two binaries on the same command:
#   scripts/bench/cpu.sh N BIN_A BIN_B ARGS...
# runs `BIN --no-progress`-style ARGS with a fresh `--out` directory under $TMPDIR, A then B, N times,
# and prints each binary's median and minimum user + system time and median wall time (seconds).
# CPU time is steadier than wall time on a shared machine, though stolen cycles still show in it.
set -euo pipefail
n=$1; a=$2; b=$3; shift 3
work=$(mktemp -d)
log="$work/times"
for _ in $(seq "$n"); do
  for x in A B; do
    bin=$a; [ "$x" = B ] && bin=$b
    /usr/bin/time -f "$x %U %S %e" -a -o "$log" "$bin" "$@" --out "$work/out-$x-$RANDOM$RANDOM" >/dev/null
  done
done
python3 - "$log" <<'PY'
import sys, statistics
d = {}
for line in open(sys.argv[1]):
    p = line.split()
    if len(p) == 4 and p[0] in ("A", "B"):
        d.setdefault(p[0], []).append((float(p[1]) + float(p[2]), float(p[3])))
for k in sorted(d):
    cpu = [c for c, _ in d[k]]
    print(f"{k}: cpu median {statistics.median(cpu):.3f} s, min {min(cpu):.3f} s; "
          f"wall median {statistics.median(w for _, w in d[k]):.3f} s ({len(cpu)} runs)")
PY
rm -rf "$work"
