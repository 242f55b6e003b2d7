#!/usr/bin/env python3
"""Side-by-side timings of chirpmap against Python peers (issue 14), whole processes,
interleaved repetitions, medians and ratios. Run through run.sh (venv + release build).

Rows measured (--rows, default all):
- map: `chirpmap map` of 100 000 one-source echoes vs map_numpy.py --method rowspan (same
  algorithm vectorised, checked to give the same map) and vs --method band (a numpy band test,
  timed on the first N = --band-echoes echoes and on 2N and extrapolated linearly to 100 000,
  since it runs at a few milliseconds per echo);
- range: `chirpmap range --method gap|matched` of a 10-minute `chirpmap synth` recording
  (examples/wall/scene.toml with 300 chirps) vs range_scipy.py, the same pipeline in scipy
  (checked: median delta_d within 1 cm of chirpmap's);
- synth: `chirpmap synth` of that 10-minute scene (static listener) vs synth_pra.py
  (pyroomacoustics, first-order image sources, the same chirp train, wall and microphone;
  checked by ranging its output with chirpmap: median delta_d within 1 cm of the geometry's).
"""
import json
import math
import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def timed(cmd, capture=False):
    """Wall time of one whole process; its stderr (or, with capture, its stdout)."""
    t = time.perf_counter()
    r = subprocess.run(cmd, stdout=subprocess.PIPE if capture else subprocess.DEVNULL, stderr=subprocess.PIPE,
                       text=True)
    elapsed = time.perf_counter() - t
    if r.returncode != 0:
        sys.exit(f"failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    return elapsed, (r.stdout if capture else r.stderr).strip()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--chirpmap", default="target/release/chirpmap")
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--echoes", type=int, default=100_000)
    p.add_argument("--band-echoes", type=int, default=2_000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--rows", default="map,range,synth", help="comma-separated subset of map,range,synth")
    p.add_argument("--chirps", type=int, default=300, help="chirps of the range/synth recording (2 s each)")
    p.add_argument("--baseline", help="another chirpmap binary (e.g. an older build) timed in the same "
                   "interleaved range runs; its row and its speed-up are printed too")
    args = p.parse_args()
    rows = set(args.rows.split(","))
    if not rows <= {"map", "range", "synth"}:
        sys.exit(f"--rows: unknown row(s) {sorted(rows - {'map', 'range', 'synth'})}")
    with tempfile.TemporaryDirectory() as tmp:
        # A private copy: other builds of the same tree may replace target/release/chirpmap
        # while the bench runs, and every row must time one binary.
        pinned = os.path.join(tmp, "chirpmap")
        shutil.copy2(args.chirpmap, pinned)
        args.chirpmap = pinned
        args.baseline_name = args.baseline and os.path.basename(args.baseline)
        if args.baseline:
            base = os.path.join(tmp, "chirpmap-baseline")
            shutil.copy2(args.baseline, base)
            args.baseline = base
        if "map" in rows:
            bench_map(args, tmp)
        if rows & {"range", "synth"}:
            bench_audio(args, tmp, rows)


def bench_map(args, tmp):
    py = sys.executable
    # One source at the origin, listeners anywhere within 15 m, delta_d 1-40 m.
    rng = np.random.default_rng(args.seed)
    n = args.echoes
    e = np.column_stack([np.zeros(n), np.zeros(n), rng.uniform(-15, 15, n), rng.uniform(-15, 15, n),
                         rng.uniform(1.0, 40.0, n)])
    csv = os.path.join(tmp, "echoes.csv")
    np.savetxt(csv, e, delimiter=",", header="source_x,source_y,listener_x,listener_y,delta_d",
               comments="", fmt="%.17g")
    bounds = "-50,-50,50,50"
    times = {"chirpmap": [], "rowspan": [], "band": []}
    notes = []
    for rep in range(args.reps):
        out = os.path.join(tmp, f"c{rep}")
        t, _ = timed([args.chirpmap, "map", "--echoes", csv, "--bounds", bounds, "--out", out,
                      "--no-progress"])
        times["chirpmap"].append(t)
        t, msg = timed([py, os.path.join(HERE, "map_numpy.py"), csv, f"--bounds={bounds}", "--method",
                        "rowspan", "--out", os.path.join(tmp, f"r{rep}.npy"), "--compare",
                        os.path.join(out, "map.npy")])
        times["rowspan"].append(t)
        notes.append(msg)
        # The band test on N and 2N echoes, extrapolated linearly to n (so the
        # process start-up is counted once, not n/N times).
        t_n, t_2n = (timed([py, os.path.join(HERE, "map_numpy.py"), csv, f"--bounds={bounds}", "--method",
                            "band", "--limit", str(m * args.band_echoes), "--out",
                            os.path.join(tmp, f"b{rep}.npy")])[0] for m in (1, 2))
        times["band"].append(t_n + (t_2n - t_n) * (n - args.band_echoes) / args.band_echoes)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"{args.reps} interleaved repetitions, medians of whole-process wall times; {n} echoes, one source")
    print(f"(numpy {np.__version__}; {notes[-1]})")
    print()
    print("| task | chirpmap | peer | peer time | ratio peer/chirpmap |")
    print("|---|---|---|---|---|")
    print(f"| map {n} echoes (one source) | {med['chirpmap']:.3f} s | numpy, chirpmap's row-span "
          f"algorithm vectorised | {med['rowspan']:.3f} s | {med['rowspan'] / med['chirpmap']:.1f}x |")
    print(f"| map {n} echoes (one source) | {med['chirpmap']:.3f} s | numpy band test (timed on "
          f"{args.band_echoes} and {2 * args.band_echoes} echoes, extrapolated) | {med['band']:.1f} s | {med['band'] / med['chirpmap']:.0f}x |")

    print()


# The wall scene of the paper's Environment A (examples/wall/scene.toml), speaker at the
# origin, microphone at (1.5, 0.5), the wall's face on y = -6.
SPEAKER, MIC, WALL_Y = (0.0, 0.0), (1.5, 0.5), -6.0


def bench_audio(args, tmp, rows):
    py = sys.executable
    root = os.path.dirname(os.path.dirname(HERE))
    scene = open(os.path.join(root, "examples", "wall", "scene.toml")).read()
    if "chirps = 50" not in scene:
        sys.exit("examples/wall/scene.toml no longer has `chirps = 50`; update bench.py")
    scene_path = os.path.join(tmp, "wall-long.toml")
    with open(scene_path, "w") as f:
        f.write(scene.replace("chirps = 50", f"chirps = {args.chirps}"))
    wav = os.path.join(tmp, "wall-long.wav")
    timed([args.chirpmap, "synth", scene_path, "--out", wav])
    minutes = args.chirps * 2 / 60
    # Truth: the image of the speaker in the wall.
    truth = math.dist((SPEAKER[0], 2 * WALL_Y - SPEAKER[1]), MIC) - math.dist(SPEAKER, MIC)
    # The chirp given explicitly (range's --duration default is not the scene's 1 s).
    geom = ["--speaker", "%g,%g" % SPEAKER, "--mic", "%g,%g" % MIC, "--f-start", "10000", "--f-end", "200",
            "--duration", "1"]
    methods = ["gap", "matched"]
    times = {k: [] for k in ["range_c_gap", "range_c_matched", "range_py_gap", "range_py_matched",
                             "range_b_gap", "range_b_matched",
                             "synth_c", "synth_py"]}
    medians = {}
    for rep in range(args.reps):
        if "range" in rows:
            for m in methods:
                out = os.path.join(tmp, f"range-{m}-{rep}")
                t, _ = timed([args.chirpmap, "range", wav, *geom, "--method", m, "--out", out, "--no-progress"])
                times[f"range_c_{m}"].append(t)
                medians[("chirpmap", m)] = json.load(open(os.path.join(out, "summary.json")))["delta_d_median"]
                t, r = timed([py, os.path.join(HERE, "range_scipy.py"), wav, "--method", m], capture=True)
                times[f"range_py_{m}"].append(t)
                medians[("scipy", m)] = json.loads(r)["delta_d_median"]
                if args.baseline:
                    out = os.path.join(tmp, f"range-base-{m}-{rep}")
                    t, _ = timed([args.baseline, "range", wav, *geom, "--method", m, "--out", out, "--no-progress"])
                    times[f"range_b_{m}"].append(t)
                    medians[("baseline", m)] = json.load(open(os.path.join(out, "summary.json")))["delta_d_median"]
        if "synth" in rows:
            t, _ = timed([args.chirpmap, "synth", scene_path, "--out", os.path.join(tmp, f"synth-c-{rep}.wav")])
            times["synth_c"].append(t)
            t, _ = timed([py, os.path.join(HERE, "synth_pra.py"), "--out", os.path.join(tmp, f"synth-py-{rep}.wav"),
                          "--chirps", str(args.chirps), "--mic", "%g,%g" % MIC])
            times["synth_py"].append(t)
    med = {k: statistics.median(v) for k, v in times.items() if v}
    print(f"{args.reps} interleaved repetitions, medians of whole-process wall times; "
          f"{minutes:g} min at 48 kHz, {args.chirps} chirps 10 -> 0.2 kHz (examples/wall/scene.toml)")
    print()
    print("| task | chirpmap | peer | peer time | ratio peer/chirpmap |")
    print("|---|---|---|---|---|")
    if "range" in rows:
        for m in methods:
            dc, dp = medians[("chirpmap", m)], medians[("scipy", m)]
            if dc is None or dp is None or abs(dc - dp) > 0.01:
                sys.exit(f"range --method {m}: scipy median delta_d {dp} vs chirpmap {dc}: more than 1 cm apart")
        print(f"| range {minutes:g} min, gap / matched | {med['range_c_gap']:.3f} / {med['range_c_matched']:.3f} s "
              f"| scipy script of the same pipeline (range_scipy.py) | {med['range_py_gap']:.3f} / "
              f"{med['range_py_matched']:.3f} s | {med['range_py_gap'] / med['range_c_gap']:.1f}x / "
              f"{med['range_py_matched'] / med['range_c_matched']:.1f}x |")
        if args.baseline:
            print(f"| range {minutes:g} min, gap / matched, baseline ({args.baseline_name}) "
                  f"| {med['range_b_gap']:.3f} / {med['range_b_matched']:.3f} s | (same scipy runs) | "
                  f"{med['range_py_gap']:.3f} / {med['range_py_matched']:.3f} s | "
                  f"{med['range_py_gap'] / med['range_b_gap']:.1f}x / {med['range_py_matched'] / med['range_b_matched']:.1f}x |")
    if "synth" in rows:
        print(f"| synth {minutes:g} min, static listener | {med['synth_c']:.3f} s | pyroomacoustics "
              f"{pra_version(py)}, first-order image sources (synth_pra.py) | {med['synth_py']:.3f} s | "
              f"{med['synth_py'] / med['synth_c']:.1f}x |")
    print()
    if "range" in rows:
        who_all = ("chirpmap", "scipy", "baseline") if args.baseline else ("chirpmap", "scipy")
        print("median delta_d (m): " + ", ".join(f"{who} {m} {medians[(who, m)]:.4f}" for m in methods
                                                 for who in who_all) + f"; geometry {truth:.4f}")
    if "synth" in rows:
        # The peer's recording, ranged by chirpmap: its content must match the geometry.
        out = os.path.join(tmp, "range-pra")
        timed([args.chirpmap, "range", os.path.join(tmp, "synth-py-0.wav"), *geom, "--method", "matched",
               "--out", out, "--no-progress"])
        d = json.load(open(os.path.join(out, "summary.json")))["delta_d_median"]
        if d is None or abs(d - truth) > 0.01:
            sys.exit(f"pyroomacoustics recording: chirpmap range median delta_d {d} vs geometry {truth:.4f}")
        print(f"pyroomacoustics recording ranged by chirpmap (matched): median delta_d {d:.4f} m")


def pra_version(py):
    r = subprocess.run([py, "-c", "import pyroomacoustics; print(pyroomacoustics.__version__)"],
                       capture_output=True, text=True)
    return r.stdout.strip() or "(not installed)"


if __name__ == "__main__":
    main()
