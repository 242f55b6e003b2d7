"""Mapping 100 000 echoes from a numpy array: chirpmap.map_echoes (Python)
against chirpmap::map_echoes (the Rust library call) on the same echoes.

Interleaved repetitions (Python call, then one Rust run, repeated), median
of each; the ratio Python / Rust is what issue 12 bounds (within 10 %). The
Python time includes reading the numpy array into echoes and handing the
grid back as an array; the Rust time is the library call on a ready
`Vec<Echo>`.

    cargo build --release -p chirpmap --example map_bench
    python crates/chirpmap-py/bench/bench_map.py [--reps 7] [--n 100000]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import chirpmap

REPO = Path(__file__).resolve().parents[3]


def echoes(n: int, seed: int = 12) -> np.ndarray:
    """A listener at 10 m/s along y = 10 past a source at the origin (the
    paper's default geometry), one echo per row with Δd from 2 to 40 m."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, 0.7, n))
    lx = -2.0 + 10.0 * t
    out = np.zeros((n, 8))
    out[:, 2] = lx
    out[:, 3] = 10.0
    out[:, 4] = rng.uniform(2.0, 40.0, n)
    out[:, 5] = rng.uniform(0.5, 10.0, n)
    out[:, 6] = t
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--bin", default=str(REPO / "target" / "release" / "examples" / "map_bench"))
    a = ap.parse_args()
    e = echoes(a.n)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "echoes.f64"
        path.write_bytes(e.astype("<f8").tobytes())
        py_s, rust_s = [], []
        checks = set()
        for _ in range(a.reps):
            t0 = time.perf_counter()
            m = chirpmap.map_echoes(e)
            py_s.append(time.perf_counter() - t0)
            checks.add(sum(m.grid.ravel().tolist()) + len(m.highlights))  # left to right, as Rust sums
            out = subprocess.run([a.bin, str(path), "1"], capture_output=True, text=True, check=True).stdout.split()
            rust_s.append(float(out[0]))
            checks.add(float(out[2]))
    py_med, rust_med = statistics.median(py_s), statistics.median(rust_s)
    print(f"{a.n} echoes, grid {m.grid.shape[0]}x{m.grid.shape[1]}, {a.reps} interleaved repetitions")
    print("python s:", " ".join(f"{v:.4f}" for v in py_s))
    print("rust   s:", " ".join(f"{v:.4f}" for v in rust_s))
    print(f"median python {py_med:.4f} s, rust {rust_med:.4f} s, ratio {py_med / rust_med:.3f}")
    # The same map both ways: grid sum (same order) + highlight count.
    print("same map:", len(checks) == 1)


if __name__ == "__main__":
    main()
