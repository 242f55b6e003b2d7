#!/usr/bin/env python3
"""Reference values for tests/scipy_reference.rs (issue 5: filters and
smoothing are verified against scipy on the same input).

Run from this directory:  python3 gen_scipy_reference.py > scipy_reference.json
The committed JSON was produced with the scipy/numpy versions recorded in it,
so CI does not need Python.
"""
import json
import numpy as np
import scipy
from scipy import signal

fs = 48000.0
n = 3000
# Deterministic input: tones below and above 100 Hz, a DC step, and an LCG
# pseudo-noise sequence (no RNG library, so the input is reproducible anywhere).
t = np.arange(n) / fs
lcg = np.empty(n)
state = 12345
for i in range(n):
    state = (1103515245 * state + 12345) % 2**31
    lcg[i] = state / 2**31 - 0.5
x = 0.6 * np.sin(2 * np.pi * 30.0 * t) + 0.3 * np.sin(2 * np.pi * 2500.0 * t) + 0.2 * (t > 0.02) + 0.1 * lcg

sos = signal.butter(4, 100.0, "highpass", fs=fs, output="sos")
hp = signal.sosfilt(sos, x)
sg_11_3 = signal.savgol_filter(x, 11, 3)
sg_9_2 = signal.savgol_filter(x, 9, 2)

print(json.dumps({
    "source": "scipy.signal.butter(4, 100, 'highpass', fs=48000, output='sos') + sosfilt; "
              "scipy.signal.savgol_filter(x, 11, 3) and (x, 9, 2), mode='interp' (default)",
    "scipy_version": scipy.__version__,
    "numpy_version": np.__version__,
    "fs": fs,
    "x": x.tolist(),
    "highpass": hp.tolist(),
    "savgol_11_3": sg_11_3.tolist(),
    "savgol_9_2": sg_9_2.tolist(),
}))
