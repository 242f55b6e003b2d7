"""Shared fixtures: the CLI binary the Python results are compared with, and
readers of the files it writes (echoes.csv, highlights.csv, WAV)."""

from __future__ import annotations

import csv
import os
import struct
import subprocess
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
