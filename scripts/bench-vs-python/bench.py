#!/usr/bin/env python3
"""Side-by-side timings of chirpmap against Python peers (issue 14), whole processes,
interleaved repetitions, medians and ratios. Run through run.sh (venv + release build).

Rows measured: `chirpmap map` of 100 000 one-source echoes vs map_numpy.py --method rowspan
(same algorithm vectorised, checked to give the same map) and vs --method band (a numpy
band test, timed on the first N = --band-echoes echoes and on 2N and extrapolated linearly to
100 000, since it runs at a few milliseconds per echo).
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def timed(cmd):
    t = time.perf_counter()
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - t
    if r.returncode != 0:
        sys.exit(f"failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    return elapsed, r.stderr.strip()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--chirpmap", default="target/release/chirpmap")
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--echoes", type=int, default=100_000)
    p.add_argument("--band-echoes", type=int, default=2_000)
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
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


if __name__ == "__main__":
    main()
