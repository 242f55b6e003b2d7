"""Shared fixtures: the CLI binary the Python results are compared with, and
readers of the files it writes (echoes.csv, highlights.csv, WAV)."""

from __future__ import annotations

import csv
import os
import struct
import subprocess
import threading
import time
from pathlib import Path
from typing import List

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def cli() -> Path:
    """The `chirpmap` binary: $CHIRPMAP_BIN, else target/release/chirpmap.

    With CHIRPMAP_BIN set (as .ci/run sets it) a missing binary fails the
    tests; without it they are skipped, with the reason, when no release
    binary has been built."""
    env = os.environ.get("CHIRPMAP_BIN")
    path = Path(env) if env else REPO / "target" / "release" / "chirpmap"
    if not path.is_file():
        if env:
            pytest.fail(f"CHIRPMAP_BIN={env} does not exist")
        pytest.skip(f"no CLI binary at {path}: build it (cargo build --release --bin chirpmap) or set CHIRPMAP_BIN")
    return path


def run_cli(cli: Path, *args: object) -> subprocess.CompletedProcess:
    """Runs the CLI; a failure shows its stderr."""
    p = subprocess.run([str(cli), *map(str, args)], capture_output=True, text=True)
    assert p.returncode == 0, f"chirpmap {' '.join(map(str, args))} failed:\n{p.stderr}"
    return p


def read_table(path: Path, columns: List[str]) -> np.ndarray:
    """The named columns of a CSV as float64 (empty cell = NaN), parsed with
    Python's float(), which reads the CLI's shortest round-trip output exactly."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    out = np.full((len(rows), len(columns)), np.nan)
    for i, r in enumerate(rows):
        for j, c in enumerate(columns):
            if r[c] != "":
                out[i, j] = float(r[c])
    return out


def read_wav_f32(path: Path) -> np.ndarray:
    """Samples `(n, channels)` of a 32-bit float WAV (format 3, or
    extensible with the float sub-format), read without the library."""
    data = path.read_bytes()
    assert data[:4] == b"RIFF" and data[8:12] == b"WAVE", "not a RIFF/WAVE file"
    pos, fmt, channels, samples = 12, None, None, None
    while pos + 8 <= len(data):
        tag, size = data[pos : pos + 4], struct.unpack("<I", data[pos + 4 : pos + 8])[0]
        body = data[pos + 8 : pos + 8 + size]
        if tag == b"fmt ":
            fmt, channels = struct.unpack("<HH", body[:4])
            bits = struct.unpack("<H", body[14:16])[0]
            if fmt == 0xFFFE:
                fmt = struct.unpack("<H", body[24:26])[0]
            assert (fmt, bits) == (3, 32), f"not 32-bit float: format {fmt}, {bits} bits"
        elif tag == b"data":
            samples = np.frombuffer(body, dtype="<f4")
        pos += 8 + size + (size & 1)
    assert channels and samples is not None, "no fmt or data chunk"
    return samples.reshape(-1, channels)


def assert_main_thread_runs_during(call) -> None:
    """Runs `call` on a second thread and checks that this thread keeps
    running Python meanwhile: the GIL is released during the call.

    Judged by the main thread's longest pause, not its speed: the library
    keeps both cores busy (rayon), so the loop may run slower, but with the
    GIL held it could not run at all for the call."""
    inside, done = threading.Event(), threading.Event()

    def work():
        inside.set()
        call()
        done.set()

    th = threading.Thread(target=work)
    th.start()
    inside.wait()
    t_start = time.perf_counter()
    last, longest, count = t_start, 0.0, 0
    while not done.is_set():
        now = time.perf_counter()
        longest = max(longest, now - last)
        last, count = now, count + 1
    th.join()
    took = time.perf_counter() - t_start
    assert count > 100, f"the main thread ran {count} times in {took:.3f} s"
    assert longest < 0.5 * took, f"the main thread stood still for {longest:.3f} s of {took:.3f} s"
