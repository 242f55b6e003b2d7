#!/usr/bin/env bash
# Peak memory of `chirpmap range` on long recordings (issue 14, item 4: at most 200 MB whatever
# the length). Renders the hour benchmark (examples/bench-hour/scene.toml made static, as in
# BENCHMARKS.md), builds a 10-hour WAV from it without holding it in memory (the header, then the
# hour's data chunk ten times), and times `range --echoes` on both; also the whole-file path
# (CHIRPMAP_RANGE_IN_MEMORY=1, the pipeline before issue 14) on the hour, and checks that its
# outputs are byte for byte the streamed ones. Needs ~4 GB of disk in $DIR; not part of CI.
#
#   scripts/bench/range-memory.sh [DIR]      (default DIR: /tmp/chirpmap-range-memory)
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
DIR=${1:-/tmp/chirpmap-range-memory}
BIN=${CHIRPMAP:-$ROOT/target/release/chirpmap}
HOURS=${HOURS:-10}
[ -x "$BIN" ] || (cd "$ROOT" && cargo build --release -p chirpmap-cli)
mkdir -p "$DIR"
cd "$DIR"
sed -e 's/^speed = 0.5/speed = 0.0/' -e 's/^spin_rate = 0.1/spin_rate = 0.0/' \
    "$ROOT/examples/bench-hour/scene.toml" > scene-static.toml
[ -f hour-static.wav ] || "$BIN" synth scene-static.toml --out hour-static.wav --poses hour-static.csv
# N hours: the hour's header with the sizes scaled, then its data chunk N times, 16 MB at a time.
[ -f "hours-$HOURS.wav" ] || python3 - hour-static.wav "hours-$HOURS.wav" "$HOURS" <<'PY'
import struct, sys
src, dst, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
with open(src, "rb") as f:
    riff, _, wave = struct.unpack("<4sI4s", f.read(12))
    assert riff == b"RIFF" and wave == b"WAVE", "not a RIFF/WAVE file"
    chunks = b""
    while True:
        cid, size = struct.unpack("<4sI", f.read(8))
        if cid == b"data":
            break
        body = f.read(size + (size & 1))
        if cid == b"fmt ":
            chunks += struct.pack("<4sI", cid, size) + body
    data_at = f.tell()
total = size * n
assert total < 2**32 - 64, "too long for a RIFF file"
with open(dst, "wb") as out:
    out.write(struct.pack("<4sI4s", b"RIFF", 4 + len(chunks) + 8 + total, b"WAVE"))
    out.write(chunks + struct.pack("<4sI", b"data", total))
    for _ in range(n):
        with open(src, "rb") as f:
            f.seek(data_at)
            left = size
            while left:
                block = f.read(min(left, 1 << 24))
                out.write(block)
                left -= len(block)
PY
T='%e s wall, %U s user, %S s sys, %M KB peak RSS'
MODE=--echoes
run() { # label, out dir, wav, extra env
    local label=$1 out=$2 wav=$3; shift 3
    env "$@" /usr/bin/time -f "range $MODE, $label: $T" "$BIN" range "$wav" --scene scene-static.toml \
        --speaker 0,0 --mic 1.5,0.5 $MODE --out "$out" 2>&1 | tail -1
}
run "hour, streamed" out-hour hour-static.wav
run "hour, whole file (CHIRPMAP_RANGE_IN_MEMORY=1)" out-hour-mem hour-static.wav CHIRPMAP_RANGE_IN_MEMORY=1
for f in echoes.csv chirps.csv echogram.csv; do
    cmp out-hour/$f out-hour-mem/$f && echo "$f: streamed and whole-file outputs identical"
done
run "$HOURS hours, streamed" "out-$HOURS" "hours-$HOURS.wav"
# The first hour's chirps in the long recording against the hour alone.
python3 - out-hour/echoes.csv "out-$HOURS/echoes.csv" <<'PY'
import csv, sys
a = list(csv.DictReader(open(sys.argv[1])))
b = list(csv.DictReader(open(sys.argv[2])))
n = len(a)
same = sum(x == y for x, y in zip(a, b[:n]))
d = max(abs(float(x["path_delta_m"]) - float(y["path_delta_m"])) for x, y in zip(a, b[:n]))
print(f"{len(b)} echoes in the long recording ({len(b) / n:.2f}x the hour's {n}); first hour: {same} of {n} rows identical, largest path_delta_m difference {d:.6f} m")
PY
# Plain `range` (first reflection; --compare: all three methods).
MODE=--compare
run "hour, streamed" out-plain-hour hour-static.wav
run "hour, whole file (CHIRPMAP_RANGE_IN_MEMORY=1)" out-plain-hour-mem hour-static.wav CHIRPMAP_RANGE_IN_MEMORY=1
for f in chirps.csv compare.csv spectrogram.png spectrum.png; do
    cmp out-plain-hour/$f out-plain-hour-mem/$f && echo "$f: streamed and whole-file outputs identical"
done
run "$HOURS hours, streamed" "out-plain-$HOURS" "hours-$HOURS.wav"
