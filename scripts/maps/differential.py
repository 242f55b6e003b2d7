#!/usr/bin/env python3
"""Two chirpmap binaries' evidence maps, compared on generated scenes.

A speed change to the evidence mapper that claims "the same output" is checked
by `chirpmap benchmark maps` on its fixed suite; this script checks it on
scenes the suite does not have. It generates exact first-order echoes (image
sources off wall segments, with occlusion by the other segments; specular
points on circles by a scan and a ternary search), optionally with Gaussian
noise, writes each as an echoes CSV, runs `map --echoes E.csv --mapper
evidence` with both binaries and compares surfaces.csv, highlights.csv and
map.npy byte for byte. Cases whose outputs differ, or where either binary
failed, are kept in the work directory (spec.json, e.csv, both outputs); the
others are removed. Exit status: 0 when every scene maps the same with both,
1 when some differ, 2 when a binary failed (a bad --param, a broken build),
no scene was generated, or the arguments were bad.

Scene kinds:
  room     a rectangular room (2-10 m by 2-8 m), 1-2 legs of 3-100 poses,
           0-2 short walls inside
  headon   a 0.3-3 m wall walked toward along its normal, 0-3 short walls
  clutter  2-8 walls of 0.3-2 m, 1-3 legs of 5-100 poses
  dense    a room with 1-2 pillars, a loop of 400-2500 poses round one
           (those inside the room)

The generator is independent of chirpmap's own code (pure Python). A review of
session 24 found, with this script's first version, 25 of 3 153 scenes whose
maps a screen of Hough peaks changed (BENCHMARKS.md, session 24).

With --threads A,B the two runs get RAYON_NUM_THREADS=A and =B: one binary
given twice then checks that the maps do not depend on the thread count.

--param writes a scene file of settings only ([source], [mapping]). Binaries
before session 25 (4410281) took it for the default scene and grew the grid to
hold its three random obstacles; later ones do not, so --param runs compare
across that commit only with that difference in the grid.

With --tol M a change that claims "the same surfaces" rather than the same
bits is checked: surfaces.csv and highlights.csv must have the same rows, with
equal kinds, supports and ambiguity flags, coordinates within M metres and
highlight values within a relative 1e-9; map.npy is not compared. Whatever the mode, the script also counts the true
walls each binary finds (a non-ambiguous line within 5 cm and 2 degrees of the
wall, its midpoint on the wall) and prints both totals, so a change that loses
walls shows even where it is allowed to change bits.

The echoes have no sigma_m column (the mapper's default σ of 2 cm) unless
--sigma-m S gives every echo σ = S (noisy scenes then get noise of σ = S):
precise echoes narrow the bands, and a heuristic tuned at 2 cm can fail at
1 mm (session 17's fan screen, EXPERIMENTS.md).

Usage:
  scripts/maps/differential.py A_BIN B_BIN [--n 100] [--start 0]
      [--kinds room,headon,clutter,dense] [--param min_line_length_m=1.0]
      [--threads 1,2] [--sigma-m 0.001] [--tol 1e-6] [--work /tmp/differential]
"""
import argparse
import hashlib
import json
import math
import os
import random
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

FILES = ["surfaces.csv", "highlights.csv", "map.npy"]
KINDS = ("room", "headon", "clutter", "dense")


def crosses(a, b, c, d):
    """Whether segments ab and cd cross properly (strictly, 1e-12 slack)."""
    def cr(o, p, q):
        return (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])
    d1, d2, d3, d4 = cr(c, d, a), cr(c, d, b), cr(a, b, c), cr(a, b, d)
    return ((d1 > 1e-12 and d2 < -1e-12) or (d1 < -1e-12 and d2 > 1e-12)) and (
        (d3 > 1e-12 and d4 < -1e-12) or (d3 < -1e-12 and d4 > 1e-12))


def echoes(src, walls, circles, lis):
    """Δd of every first-order reflection heard at `lis`."""
    out = []
    direct = math.dist(src, lis)
    for wi, (x0, y0, x1, y1) in enumerate(walls):
        dx, dy = x1 - x0, y1 - y0
        ln = math.hypot(dx, dy)
        nx, ny = -dy / ln, dx / ln
        ds = (src[0] - x0) * nx + (src[1] - y0) * ny
        dl = (lis[0] - x0) * nx + (lis[1] - y0) * ny
        if ds * dl <= 0:
            continue
        img = (src[0] - 2 * ds * nx, src[1] - 2 * ds * ny)
        di = (img[0] - x0) * nx + (img[1] - y0) * ny
        t = di / (di - dl)
        r = (img[0] + t * (lis[0] - img[0]), img[1] + t * (lis[1] - img[1]))
        u = ((r[0] - x0) * dx + (r[1] - y0) * dy) / ln ** 2
        if u < 0 or u > 1:
            continue
        if any(crosses(src, r, w[:2], w[2:]) or crosses(r, lis, w[:2], w[2:])
               for wj, w in enumerate(walls) if wj != wi):
            continue
        out.append(math.dist(img, lis) - direct)
    for (cx, cy, rad) in circles:
        def path(a):
            q = (cx + rad * math.cos(a), cy + rad * math.sin(a))
            return math.dist(src, q) + math.dist(q, lis)
        best = min(range(720), key=lambda k: path(2 * math.pi * k / 720))
        lo, hi = 2 * math.pi * (best - 1) / 720, 2 * math.pi * (best + 1) / 720
        for _ in range(100):
            m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
            if path(m1) < path(m2):
                hi = m2
            else:
                lo = m1
        a = 0.5 * (lo + hi)
        q = (cx + rad * math.cos(a), cy + rad * math.sin(a))
        if any(crosses(src, q, w[:2], w[2:]) or crosses(q, lis, w[:2], w[2:]) for w in walls):
            continue
        out.append(path(a) - direct)
    return out


def short_wall(rng, xlo, xhi, ylo, yhi, lmin, lmax):
    length, ang = rng.uniform(lmin, lmax), rng.uniform(0, 2 * math.pi)
    x, y = rng.uniform(xlo, xhi), rng.uniform(ylo, yhi)
    return [x, y, x + length * math.cos(ang), y + length * math.sin(ang)]


def scene(rng, kind):
    """A scene spec: source, walls, circles, poses, noise, seed."""
    walls, circles, poses = [], [], []

    def leg(p, q, n):
        poses.extend([p[0] + (q[0] - p[0]) * i / n, p[1] + (q[1] - p[1]) * i / n] for i in range(n))

    if kind == "headon":
        length, a = rng.uniform(0.3, 3.0), rng.uniform(0, 2 * math.pi)
        c = (rng.uniform(-2, 2), rng.uniform(-2, 2))
        d, n = (math.cos(a), math.sin(a)), (-math.sin(a), math.cos(a))
        walls.append([c[0] - d[0] * length / 2, c[1] - d[1] * length / 2,
                      c[0] + d[0] * length / 2, c[1] + d[1] * length / 2])
        off = rng.uniform(-0.3 * length, 0.3 * length)
        away = rng.uniform(0.5, 5)
        src = [c[0] + n[0] * away + d[0] * (off + rng.uniform(-0.3, 0.3)),
               c[1] + n[1] * away + d[1] * (off + rng.uniform(-0.3, 0.3))]
        far, near, lat = rng.uniform(2, 8), rng.uniform(0.2, 1.0), off + rng.uniform(-0.2, 0.2)
        p0 = [c[0] + n[0] * far + d[0] * lat, c[1] + n[1] * far + d[1] * lat]
        lat1 = lat + rng.uniform(-0.3, 0.3)
        p1 = [c[0] + n[0] * near + d[0] * lat1, c[1] + n[1] * near + d[1] * lat1]
        leg(p0, p1, rng.choice([6, 10, 20, 40, 80, 150]))
        walls += [short_wall(rng, -5, 5, -5, 5, 0.3, 2.0) for _ in range(rng.choice([0, 0, 1, 2, 3]))]
    elif kind == "room":
        w, h = rng.uniform(2, 10), rng.uniform(2, 8)
        walls += [[0, 0, w, 0], [w, 0, w, h], [w, h, 0, h], [0, h, 0, 0]]
        src = [rng.uniform(0.2, w - 0.2), rng.uniform(0.2, h - 0.2)]
        pts = [[rng.uniform(0.2, w - 0.2), rng.uniform(0.2, h - 0.2)] for _ in range(rng.choice([2, 2, 3]))]
        for p, q in zip(pts, pts[1:]):
            leg(p, q, rng.choice([3, 5, 8, 12, 20, 40, 100]))
        walls += [short_wall(rng, 0.5, w - 0.5, 0.5, h - 0.5, 0.3, 1.5) for _ in range(rng.choice([0, 1, 2]))]
    elif kind == "dense":
        w, h = rng.uniform(4, 9), rng.uniform(3, 7)
        walls += [[0, 0, w, 0], [w, 0, w, h], [w, h, 0, h], [0, h, 0, 0]]
        src = [rng.uniform(0.5, w - 0.5), rng.uniform(0.5, h - 0.5)]
        circles = [[rng.uniform(1, w - 1), rng.uniform(1, h - 1), rng.uniform(0.05, 0.4)]
                   for _ in range(rng.choice([1, 1, 2]))]
        cx, cy, rad = circles[0]
        rad += rng.uniform(0.05, 0.6)
        n = rng.choice([400, 1000, 2500])
        loop = ([cx + rad * math.cos(2 * math.pi * k / n), cy + rad * math.sin(2 * math.pi * k / n)] for k in range(n))
        poses += [p for p in loop if 0.1 < p[0] < w - 0.1 and 0.1 < p[1] < h - 0.1]
    else:
        src = [0.0, 0.0]
        walls += [short_wall(rng, -6, 6, -6, 6, 0.3, 2.0) for _ in range(rng.randint(2, 8))]
        p = [rng.uniform(-4, 4), rng.uniform(-4, 4)]
        for _ in range(rng.randint(1, 3)):
            q = [rng.uniform(-4, 4), rng.uniform(-4, 4)]
            leg(p, q, rng.choice([5, 10, 20, 50, 100]))
            p = q
    noise = rng.choice([0.0, 0.002, 0.01]) if kind == "dense" else rng.choice([0.0, 0.0, 0.005, 0.02])
    return {"source": src, "walls": walls, "circles": circles, "poses": poses,
            "noise": noise, "seed": rng.randrange(10 ** 6)}


def write_echoes(spec, path, sigma_m=None):
    """The scene's echoes as an echoes CSV; with `sigma_m`, every echo says its
    σ in a sigma_m column and a noisy scene's noise has that σ."""
    rng = random.Random(spec["seed"])
    noise = spec["noise"] if sigma_m is None or not spec["noise"] else sigma_m
    rows = 0
    with open(path, "w") as f:
        f.write("source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener")
        f.write(",sigma_m\n" if sigma_m is not None else "\n")
        tail = f",{sigma_m!r}\n" if sigma_m is not None else "\n"
        for i, lis in enumerate(spec["poses"]):
            for dd in echoes(spec["source"], spec["walls"], spec["circles"], lis):
                dd += rng.gauss(0, noise) if noise else 0.0
                if dd > 0:
                    s = spec["source"]
                    f.write(f"{s[0]!r},{s[1]!r},{lis[0]!r},{lis[1]!r},{dd!r},1,{i * 0.1!r},0{tail}")
                    rows += 1
    return rows


def read_rows(path):
    with open(path) as f:
        return [line.rstrip("\n").split(",") for line in f][1:]


def near_same(a_dir, b_dir, tol):
    """Whether both outputs hold the same surfaces and highlights: coordinates
    within `tol` metres, highlight values (log-odds) within a relative 1e-9,
    every other field equal."""
    for name, coords, values in (("surfaces.csv", (1, 2, 3, 4), ()), ("highlights.csv", (0, 1), (2,))):
        ra, rb = read_rows(os.path.join(a_dir, name)), read_rows(os.path.join(b_dir, name))
        if len(ra) != len(rb):
            return False
        for x, y in zip(ra, rb):
            if len(x) != len(y):
                return False
            for j, (u, v) in enumerate(zip(x, y)):
                if j in coords and u and v:
                    if abs(float(u) - float(v)) > tol:
                        return False
                elif j in values:
                    if abs(float(u) - float(v)) > 1e-9 * max(abs(float(u)), abs(float(v))):
                        return False
                elif u != v:
                    return False
    return True


def walls_found(spec, out_dir):
    """How many of the scene's true walls a non-ambiguous line of the map lies on:
    both ends within 5 cm of the wall's line, within 2 degrees of it, its
    midpoint between the wall's ends."""
    lines = []
    for r in read_rows(os.path.join(out_dir, "surfaces.csv")):
        if r[0] == "line" and (len(r) < 7 or r[6] != "true"):
            lines.append([float(v) for v in r[1:5]])
    found = 0
    for x0, y0, x1, y1 in spec["walls"]:
        ln = math.hypot(x1 - x0, y1 - y0)
        ux, uy = (x1 - x0) / ln, (y1 - y0) / ln
        for a0, b0, a1, b1 in lines:
            la = math.hypot(a1 - a0, b1 - b0)
            if la == 0:
                continue
            off = max(abs((a0 - x0) * uy - (b0 - y0) * ux), abs((a1 - x0) * uy - (b1 - y0) * ux))
            cos = abs(((a1 - a0) * ux + (b1 - b0) * uy) / la)
            t = ((a0 + a1) / 2 - x0) * ux + ((b0 + b1) / 2 - y0) * uy
            if off <= 0.05 and cos >= math.cos(math.radians(2)) and 0 <= t <= ln:
                found += 1
                break
    return found


def run(case, args):
    i, kind = case
    rng = random.Random(f"{kind}-{i}")  # a str seed is hashed the same in every process
    d = os.path.join(args.work, f"{kind}-{i}")
    os.makedirs(d)  # a new folder: only what this script created is removed
    spec = scene(rng, kind)
    json.dump(spec, open(os.path.join(d, "spec.json"), "w"))
    if write_echoes(spec, os.path.join(d, "e.csv"), args.sigma_m) < 2:
        shutil.rmtree(d)
        return None
    extra = []
    if args.param:
        toml = f"[source]\nposition = [{spec['source'][0]!r}, {spec['source'][1]!r}]\n"
        toml += "[mapping]\nmapper = \"evidence\"\ncell = 0.1\n[mapping.evidence]\n" + "".join(f"{p}\n" for p in args.param)
        open(os.path.join(d, "scene.toml"), "w").write(toml)
        extra = ["--scene", os.path.join(d, "scene.toml")]
    got = {}
    for name, binary, threads in (("a", args.a, args.threads[0]), ("b", args.b, args.threads[1])):
        out = os.path.join(d, name)
        env = dict(os.environ)
        if threads:
            env["RAYON_NUM_THREADS"] = threads
        r = subprocess.run([binary, "--no-progress", "map", "--echoes", os.path.join(d, "e.csv"),
                            "--mapper", "evidence", "--out", out] + extra, capture_output=True, text=True, env=env)
        if r.returncode != 0:
            got[name] = ("error", r.stderr.strip()[-300:])
        else:
            got[name] = tuple(hashlib.md5(open(os.path.join(out, f), "rb").read()).hexdigest() for f in FILES)
    failed = any(v[0] == "error" for v in got.values())
    walls = None
    if not failed:
        walls = (walls_found(spec, os.path.join(d, "a")), walls_found(spec, os.path.join(d, "b")), len(spec["walls"]))
    if args.tol is None:
        same = not failed and got["a"] == got["b"]
    else:
        same = not failed and near_same(os.path.join(d, "a"), os.path.join(d, "b"), args.tol)
    if same:
        shutil.rmtree(d)
    return d, same, failed, got, walls


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", help="first chirpmap binary (e.g. the build before a change)")
    ap.add_argument("b", help="second chirpmap binary")
    ap.add_argument("--n", type=int, default=100, help="scenes per kind")
    ap.add_argument("--start", type=int, default=0, help="first scene number")
    ap.add_argument("--kinds", default="room,headon,clutter,dense")
    ap.add_argument("--param", action="append", default=[],
                    help="a [mapping.evidence] line for both runs, e.g. min_line_length_m=1.0 (repeatable)")
    ap.add_argument("--threads", default="", help="RAYON_NUM_THREADS for A and B, e.g. 1,2")
    ap.add_argument("--sigma-m", type=float, default=None,
                    help="give every echo this sigma_m (m; noisy scenes get noise of this sigma), e.g. 0.001")
    ap.add_argument("--tol", type=float, default=None,
                    help="compare surfaces and highlights within this many metres, not map.npy's bits")
    ap.add_argument("--work", default="/tmp/differential", help="where differing cases are kept")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    args.param = [p.replace("=", " = ", 1) for p in args.param]
    threads = args.threads.split(",") if args.threads else ["", ""]
    if len(threads) != 2 or not all(t == "" or (t.isdigit() and int(t) > 0) for t in threads):
        print(f"differential.py: --threads wants two positive counts, e.g. 1,2 (got {args.threads})", file=sys.stderr)
        sys.exit(2)
    args.threads = threads
    if args.sigma_m is not None and not (args.sigma_m > 0 and math.isfinite(args.sigma_m)):
        print(f"differential.py: --sigma-m wants a positive sigma in metres (got {args.sigma_m})", file=sys.stderr)
        sys.exit(2)
    if args.tol is not None and not (args.tol >= 0 and math.isfinite(args.tol)):
        print(f"differential.py: --tol wants a distance in metres, 0 or more (got {args.tol})", file=sys.stderr)
        sys.exit(2)
    kinds = args.kinds.split(",")
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        print(f"differential.py: unknown --kinds {','.join(unknown)} (known: {','.join(KINDS)})", file=sys.stderr)
        sys.exit(2)
    if os.path.exists(args.work) and os.listdir(args.work):
        print(f"differential.py: {args.work} is not empty; give another --work", file=sys.stderr)
        sys.exit(2)
    os.makedirs(args.work, exist_ok=True)
    cases = [(i, k) for k in kinds for i in range(args.start, args.start + args.n)]
    total = differ = failed = 0
    walls = [0, 0, 0]
    with ThreadPoolExecutor(args.jobs) as ex:
        for res in ex.map(lambda c: run(c, args), cases):
            if res is None:
                continue
            total += 1
            d, same, broke, got, w = res
            if w:
                walls = [x + y for x, y in zip(walls, w)]
                if w[0] != w[1]:
                    print(f"walls found: {d} A {w[0]}, B {w[1]} of {w[2]}", flush=True)
            if broke:
                failed += 1
                print("failed:", d, got, flush=True)
            elif not same:
                differ += 1
                print("differs:", d, got, flush=True)
    print(f"walls found: A {walls[0]}, B {walls[1]} of {walls[2]}")
    print(f"{total} scenes, {differ} differ, {failed} failed")
    if failed or total == 0:
        sys.exit(2)
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
