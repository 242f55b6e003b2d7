#!/usr/bin/env python3
"""Issue 10's real-room benchmark: the ten dEchorate development RIRs
(crates/chirpmap-audio/tests/data/dechorate/) convolved with the paper's chirp
train (linear 10 -> 0.2 kHz, T = 1 s, 1 s gaps), white noise at 30 dB SNR
(relative to the mean power while the signal sounds, as `synth` does), then
`chirpmap range --echoes` on each recording; per recording: which planes were
found within 3 cm of the annotated path difference, the errors, and the share
of reported echoes below 0.45 m (the loudspeaker's ringing sits at 0.27-0.40 m).

A plane counts as found in a recording when, in at least half of its chirps,
an echo lies within TOL of the annotated Δd (dd_annot_<plane>). The error
column is the median over chirps of (nearest echo − annotation).

Also runs the baseline the issue names, a simple envelope-peak picker on
the raw RIRs (|hilbert(rir)|, local maxima after direct + 0.45 m up to 8 m,
the K strongest), with the same criterion (one "chirp": the RIR).

Usage: python3 scripts/rooms/dechorate_eval.py [--bin target/release/chirpmap]
       [--work /tmp/rooms-eval] [--chirps 10] [--snr 30] [--seed 1] [--echoes 10]
       [--extra "--ringing-ms 2"] [--input wav|rir] [--sweep linear|exponential]
Needs numpy and scipy. Deterministic for a given seed.
"""
import argparse, csv, json, os, subprocess, sys
import numpy as np
import scipy.io.wavfile as wavfile
import scipy.signal as ss

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, '..', '..', 'crates', 'chirpmap-audio', 'tests', 'data', 'dechorate')
A = 345.844
FS = 48000
PLANES = ['x0', 'xL', 'y0', 'yL', 'z0', 'zL']
SIDES = ['x0', 'xL', 'y0', 'yL']
TOL = 0.03


def chirp(T=1.0, f0=10000.0, f1=200.0, taper=0.005, kind='linear'):
    n = int(round(T * FS))
    t = np.arange(n) / FS
    if kind == 'linear':
        ph = f0 * t + 0.5 * (f1 - f0) / T * t * t
    else:  # exponential, as chirpmap_core::ExponentialChirp
        k = np.log(f1 / f0) / T
        ph = f0 * (np.exp(k * t) - 1.0) / k
    g = np.ones(n)
    m = int(taper * FS)
    edge = 0.5 - 0.5 * np.cos(np.pi * np.arange(m) / m)
    g[:m] = edge
    g[-m:] = edge[::-1]
    return g * np.sin(2 * np.pi * (ph - np.floor(ph)))


def recording(h, n_chirps, snr_db, seed, T=1.0, gap=1.0, start=0.5, tail=0.5, kind='linear'):
    s = chirp(T, kind=kind)
    period = int(round((T + gap) * FS))
    L = int(round(start * FS)) + n_chirps * period + int(round(tail * FS))
    x = np.zeros(L)
    for k in range(n_chirps):
        i = int(round(start * FS)) + k * period
        x[i:i + len(s)] += s
    y = ss.fftconvolve(x, h)[:L]
    on = np.abs(y) > 1e-6 * np.abs(y).max()
    pw = np.mean(y[on] ** 2)
    rng = np.random.default_rng(seed)
    y = y + rng.normal(0.0, np.sqrt(pw / 10 ** (snr_db / 10)), L)
    return (0.5 * y / np.abs(y).max()).astype(np.float32)


def rows():
    with open(os.path.join(DATA, 'rirs_index.csv')) as f:
        return list(csv.DictReader(f))


def plane_errors(per_chirp, r):
    """per_chirp: list of lists of path differences. -> {plane: (found, median error)}"""
    out = {}
    for p in PLANES:
        ann = float(r['dd_annot_' + p])
        near = [min(ch, key=lambda v: abs(v - ann)) - ann for ch in per_chirp if ch]
        hits = sum(abs(e) <= TOL for e in near)
        n = max(len(per_chirp), 1)
        out[p] = (hits >= 0.5 * n and hits > 0, float(np.median(near)) if near else float('nan'))
    return out


def baseline(r, K):
    fs, h = wavfile.read(os.path.join(DATA, r['file']))
    env = np.abs(ss.hilbert(h.astype(float)))
    p = int(np.argmax(env[:1000]))
    lo, hi = p + int(np.ceil(0.45 / A * fs)), p + int(8.0 / A * fs)
    pk, _ = ss.find_peaks(env[lo:hi])
    pk = pk + lo
    top = sorted(pk, key=lambda k: -env[k])[:K]
    return [[(k - p) / fs * A for k in sorted(top)]]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--bin', default=os.path.join(HERE, '..', '..', 'target', 'release', 'chirpmap'))
    ap.add_argument('--work', default='/tmp/rooms-eval')
    ap.add_argument('--chirps', type=int, default=10)
    ap.add_argument('--snr', type=float, default=30.0)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--echoes', type=int, default=10)
    ap.add_argument('--input', default='wav', choices=['wav', 'rir'])
    ap.add_argument('--extra', default='')
    ap.add_argument('--sweep', default='linear', choices=['linear', 'exponential'])
    args = ap.parse_args()
    os.makedirs(args.work, exist_ok=True)
    tally = {'ours': [0, 0, 0, 0], 'baseline': [0, 0, 0, 0]}
    low = [0, 0]
    print('| recording | method | echoes/chirp | ceiling zL (err m) | floor z0 (err m) | nearest side wall (err m) | other side walls found | below 0.45 m |')
    print('|---|---|---|---|---|---|---|---|')
    for i, r in enumerate(rows()):
        name = os.path.basename(r['file'])[:-4]
        fs, h = wavfile.read(os.path.join(DATA, r['file']))
        sp = '%s,%s,%s' % (r['src_x'], r['src_y'], r['src_z'])
        mic = '%s,%s,%s' % (r['mic_x'], r['mic_y'], r['mic_z'])
        if args.input == 'wav':
            wav = os.path.join(args.work, name + '.wav')
            wavfile.write(wav, FS, recording(h.astype(float), args.chirps, args.snr, args.seed + i, kind=args.sweep))
            cmd = [args.bin, 'range', wav, '--duration', '1', '--f-start', '10000', '--f-end', '200',
                   '--speed-of-sound', str(A), '--method', 'matched', '--max-delta-d', '8', '--sweep', args.sweep]
        else:
            wav = os.path.join(DATA, r['file'])
            cmd = [args.bin, 'range', wav, '--input', 'rir', '--speed-of-sound', str(A), '--max-delta-d', '8']
        out = os.path.join(args.work, name)
        cmd += ['--speaker', sp, '--mic', mic, '--echoes', str(args.echoes), '--out', out] + args.extra.split()
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            print(res.stderr, file=sys.stderr)
            sys.exit(1)
        per = {}
        n_low = n_all = 0
        with open(os.path.join(out, 'echoes.csv')) as f:
            for e in csv.DictReader(f):
                per.setdefault(int(e['chirp']), []).append(float(e['path_delta_m']))
                n_all += 1
                n_low += float(e['path_delta_m']) < 0.45
        n_chirps = json.load(open(os.path.join(out, 'summary.json')))['chirps']
        chirps = [per.get(k, []) for k in range(n_chirps)]
        low[0] += n_low
        low[1] += n_all
        side = min(SIDES, key=lambda p: float(r['dd_annot_' + p]))
        for meth, pc in (('ours', chirps), ('baseline', baseline(r, args.echoes))):
            pe = plane_errors(pc, r)
            others = [p for p in SIDES if p != side and pe[p][0]]
            t = tally[meth]
            t[0] += pe['zL'][0]
            t[1] += pe[side][0]
            t[2] += pe['zL'][0] or pe['z0'][0]
            t[3] += 1
            f = lambda p: ('yes' if pe[p][0] else 'no') + ' (%+.3f)' % pe[p][1]
            per_chirp = sum(len(c) for c in pc) / max(len(pc), 1)
            lowtxt = '%d/%d' % (n_low, n_all) if meth == 'ours' else '0 (by construction)'
            print('| %s | %s | %.1f | %s | %s | %s: %s | %s | %s |' % (
                name, 'range --echoes' if meth == 'ours' else 'envelope peaks (raw RIR)', per_chirp,
                f('zL'), f('z0'), side, f(side), ','.join(others) or '-', lowtxt))
    for meth, t in tally.items():
        print('%s: ceiling %d/%d, nearest side wall %d/%d, ceiling-or-floor %d/%d' % (
            meth, t[0], t[3], t[1], t[3], t[2], t[3]))
    print('ours: echoes below 0.45 m: %d of %d (%.1f %%)' % (low[0], low[1], 100.0 * low[0] / max(low[1], 1)))


if __name__ == '__main__':
    main()
