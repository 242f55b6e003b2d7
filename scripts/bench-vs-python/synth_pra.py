#!/usr/bin/env python3
"""The peer of issue 14's "synth" row: what `chirpmap synth` renders for a static listener,
done with pyroomacoustics' image-source model (first order), the same content as
`chirpmap synth` of examples/wall/scene.toml with more chirps:

- the chirp train: linear chirps f_start -> f_end of `duration` s, raised-cosine taper of
  5 ms at each end, `gap` s of silence between chirps, `start` s before the first and `tail` s
  after the last, at 48 kHz (as crates/chirpmap-audio/src/synth.rs);
- a 2-D polygon room (pyroomacoustics Room.from_corners, max_order=1): the wall
  y = -6 (x in -30..30) reflecting with amplitude 1 - absorption (chirpmap's per-bounce
  factor; pyroomacoustics takes the energy absorption 1 - (1 - absorption)^2), the other three
  walls (x = +-30, y = 30) absorbing everything, speed of sound 343 m/s;
- source at the origin, one microphone at the listener's position;
- white Gaussian noise at `snr` dB relative to the signal's power while it sounds, peak
  normalised to 0.5, written as 16-bit mono WAV (scipy.io.wavfile).

Usage: synth_pra.py --out REC.wav [--chirps 300] [--mic 1.5,0.5] [--snr 20] [--seed 1]
"""
import argparse

import numpy as np
import pyroomacoustics as pra
from scipy.io import wavfile

TAPER_S = 0.005


def chirp(f0, f1, dur, fs):
    n = int(round(dur * fs))
    t = np.arange(n) / fs
    ph = f0 * t + 0.5 * (f1 - f0) / dur * t * t
    edge = np.minimum(t, dur - t)
    gain = np.where(edge >= TAPER_S, 1.0, 0.5 - 0.5 * np.cos(np.pi * edge / TAPER_S))
    return gain * np.sin(2 * np.pi * (ph - np.floor(ph)))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--chirps", type=int, default=300)
    p.add_argument("--f-start", type=float, default=10000.0)
    p.add_argument("--f-end", type=float, default=200.0)
    p.add_argument("--duration", type=float, default=1.0)
    p.add_argument("--gap", type=float, default=1.0)
    p.add_argument("--start", type=float, default=0.5)
    p.add_argument("--tail", type=float, default=0.5)
    p.add_argument("--fs", type=int, default=48000)
    p.add_argument("--mic", default="1.5,0.5")
    p.add_argument("--absorption", type=float, default=0.2)
    p.add_argument("--snr", type=float, default=20.0)
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    fs = args.fs
    c = chirp(args.f_start, args.f_end, args.duration, fs)
    period = int(round((args.duration + args.gap) * fs))
    start = int(round(args.start * fs))
    n = start + (args.chirps - 1) * period + len(c) + int(round(args.tail * fs))
    train = np.zeros(n)
    for k in range(args.chirps):
        train[start + k * period:start + k * period + len(c)] = c
    corners = np.array([[-30.0, 30.0, 30.0, -30.0], [-6.0, -6.0, 30.0, 30.0]])  # anticlockwise
    refl = 1.0 - args.absorption
    materials = [pra.Material(1.0 - refl * refl)] + [pra.Material(1.0)] * 3
    room = pra.Room.from_corners(corners, fs=fs, max_order=1, materials=materials, air_absorption=False)
    room.add_source([0.0, 0.0], signal=train)
    room.add_microphone(np.array([float(v) for v in args.mic.split(",")]))
    room.simulate()
    y = room.mic_array.signals[0]
    # Noise relative to the signal's power while the chirps sound (chirpmap synth's snr_db).
    on = np.zeros(len(y), dtype=bool)
    for k in range(args.chirps):
        on[start + k * period:start + k * period + len(c)] = True
    power = float(np.mean(y[:len(on)][on[:len(y)]] ** 2))
    rng = np.random.default_rng(args.seed)
    y = y + rng.standard_normal(len(y)) * np.sqrt(power / 10 ** (args.snr / 10))
    y *= 0.5 / np.max(np.abs(y))
    wavfile.write(args.out, fs, np.round(y * 32767).astype(np.int16))


if __name__ == "__main__":
    main()
