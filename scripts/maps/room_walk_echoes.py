#!/usr/bin/env python3
"""Echoes of the room walk (examples/room-walk) against exact first-order paths.

Independent of chirpmap's code: each wall's Δd by its image source (Allen and
Berkley 1979), the pillar's by a search over 20 000 points of its circle
(Fermat: the reflection point minimises the path). Each echo of `map --wav`'s
echoes.csv is matched to the nearest of the five within 0.3 m; per reflector,
the count, the median error and the share within 2 cm and 5 cm.

    python3 scripts/maps/room_walk_echoes.py DIR/echoes.csv

Needs numpy. EXPERIMENTS.md, session 23.
"""
import csv
import sys

import numpy as np

SOURCE = np.array([2.0, 2.5])
PILLAR, RADIUS = np.array([5.5, 3.8]), 0.3
WALLS = {"y = 0": (1, 0.0), "x = 8": (0, 8.0), "y = 6": (1, 6.0), "x = 0": (0, 0.0)}
THETA = np.linspace(0.0, 2.0 * np.pi, 20000, endpoint=False)
RIM = PILLAR[None, :] + RADIUS * np.c_[np.cos(THETA), np.sin(THETA)]


def exact(listener):
    direct = np.linalg.norm(listener - SOURCE)
    out = {}
    for name, (axis, value) in WALLS.items():
        image = SOURCE.copy()
        image[axis] = 2.0 * value - SOURCE[axis]
        out[name] = np.linalg.norm(listener - image) - direct
    paths = np.linalg.norm(RIM - SOURCE, axis=1) + np.linalg.norm(RIM - listener, axis=1)
    out["pillar"] = paths.min() - direct
    return out


def main(path):
    errors = {name: [] for name in list(WALLS) + ["pillar"]}
    unmatched = 0
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        listener = np.array([float(r["listener_x"]), float(r["listener_y"])])
        dd = float(r["delta_d"])
        name, value = min(exact(listener).items(), key=lambda kv: abs(kv[1] - dd))
        if abs(value - dd) <= 0.3:
            errors[name].append(dd - value)
        else:
            unmatched += 1
    print(f"{len(rows)} echoes, {unmatched} unmatched")
    print("reflector  echoes  median err (cm)  within 2 cm  within 5 cm")
    for name, e in errors.items():
        e = np.array(e)
        if e.size == 0:
            print(f"{name:9}  {0:6}")
            continue
        print(
            f"{name:9}  {e.size:6}  {100 * np.median(e):15.2f}  {np.mean(np.abs(e) < 0.02):10.0%}"
            f"  {np.mean(np.abs(e) < 0.05):10.0%}"
        )


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: room_walk_echoes.py ECHOES.csv")
    main(sys.argv[1])
