#!/usr/bin/env python3
"""Can the echoes of a straight pass tell a reflector from its mirror twin? An independent check
(numpy + scipy, not chirpmap's mapper) on `chirpmap simulate` output directories.

For each true obstacle (a circle of the run's scene.toml), the echoes of echoes.csv within 3 sigma of
its specular path (|S-C| + |C-L| - 2 r cos(beta/2), to first order in r) are fitted by a point
reflector (|S-P| + |P-L| - |S-L| = delta_d, weighted by sigma_m, scipy least_squares) twice: started on
the circle's near side, and started at that point's mirror across the listener's walk (the principal
axis of the listener positions). The mirror is only a starting point: with the source off the walk no
exact twin exists for a point, and the fit moves to the far-side point that best explains the same
echoes. Prints, per obstacle, the RMS residual (in sigma) of both fits and how far each lands from the
nearest obstacle surface; then a summary over all directories.

Usage: twin_fit.py DIR [DIR ...]   (each DIR from `chirpmap simulate SCENE --out DIR`)
"""
import csv
import math
import statistics
import sys
import tomllib

import numpy as np
from scipy.optimize import least_squares


def run(d):
    sc = tomllib.load(open(f"{d}/scene.toml", "rb"))
    obs = [(o["center"][0], o["center"][1], o["radius"]) for o in sc.get("obstacles", []) if "center" in o]
    rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(open(f"{d}/echoes.csv"))]
    if not rows or not obs:
        return []
    s = np.array([[e["source_x"], e["source_y"]] for e in rows])
    l = np.array([[e["listener_x"], e["listener_y"]] for e in rows])
    dd = np.array([e["delta_d"] for e in rows])
    sig = np.array([e["sigma_m"] for e in rows])
    base = np.linalg.norm(s - l, axis=1)
    # The walk's line: mean listener position and principal direction.
    lm = l.mean(axis=0)
    _, _, vt = np.linalg.svd(l - lm)
    u = vt[0]

    def mirror(p):
        q = p - lm
        along = np.dot(q, u) * u
        return lm + 2 * along - q

    def surface_dist(p):
        return min(abs(math.hypot(p[0] - a, p[1] - b) - c) for a, b, c in obs)

    out = []
    for cx, cy, r in obs:
        c = np.array([cx, cy])
        a, b = np.linalg.norm(s - c, axis=1), np.linalg.norm(l - c, axis=1)
        beta = np.arccos(np.clip(np.sum((s - c) * (l - c), axis=1) / (a * b), -1.0, 1.0))
        sel = np.abs((dd - (a + b - 2 * r * np.cos(beta / 2) - base)) / sig) < 3.0
        if sel.sum() < 5:
            continue
        ss, ls, ds, sgs, bs = s[sel], l[sel], dd[sel], sig[sel], base[sel]

        def resid(p):
            return (np.linalg.norm(ss - p, axis=1) + np.linalg.norm(ls - p, axis=1) - bs - ds) / sgs

        mid = 0.5 * (ss.mean(axis=0) + ls.mean(axis=0))
        near = c + r * (mid - c) / np.linalg.norm(mid - c)
        fits = [least_squares(resid, start) for start in (near, mirror(near))]
        rms = [math.sqrt(float(np.mean(f.fun ** 2))) for f in fits]
        off = [surface_dist(f.x) for f in fits]
        print(f"{d}: obstacle ({cx:.1f}, {cy:.1f}) r {r:.1f}, {int(sel.sum())} echoes: point fit {rms[0]:.3f} sigma "
              f"({off[0]:.2f} m off), its twin {rms[1]:.3f} sigma ({off[1]:.2f} m off)")
        out.append((rms[0], rms[1], off[0], off[1]))
    return out


def main():
    res = [r for d in sys.argv[1:] for r in run(d)]
    if not res:
        sys.exit("no obstacle with 5 echoes in the given directories")
    diff = [abs(a - b) for a, b, _, _ in res]
    print(f"{len(res)} obstacles: |RMS(true side) - RMS(twin)| median {statistics.median(diff):.3f} sigma, "
          f"max {max(diff):.3f}; true side fits better in {sum(a < b for a, b, _, _ in res)}; "
          f"twins more than 5 m from every obstacle: {sum(o > 5 for _, _, _, o in res)}")


if __name__ == "__main__":
    main()
