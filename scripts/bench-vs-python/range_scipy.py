#!/usr/bin/env python3
"""`chirpmap range` (methods gap and matched) written again in scipy + numpy: the peer of
issue 14's "range" row. Same pipeline, step for step, as
crates/chirpmap/src/recording.rs (prepare, range), crates/chirpmap-audio/src/filter.rs,
detect.rs (detect_chirps) and ranging.rs (Ranger::gap, gap_frame, matched):

1. WAV (16/24/32-bit PCM or float) -> float32, one channel; 4th-order 100 Hz Butterworth
   high-pass (scipy.signal.butter + sosfilt, bilinear with pre-warping as filter.rs).
2. Chirp detection by matched filter: correlation of the whole recording with the tapered
   chirp template (scipy.signal.oaconvolve, float32), maxima of |c| per 16 lags, threshold
   max(12 x median chunk maximum, 1 % of the global maximum), candidates strongest first,
   greedy acceptance outside the (0.9 T before, T + max delta_d / a after) window of accepted
   chirps, normalised correlation >= 0.2.
3. Per chirp:
   - gap: 24 frames of round(fs / sqrt(|rate|)) samples, Hann, zero-padded real FFT
     (8x), Savitzky-Golay smoothing (quadratic; the edges from the fit of the first/last
     window, as savgol_filter's mode "interp"; coefficients from scipy.signal.savgol_coeffs
     once), the
     direct peak by prediction, the direct sound fitted (three shifted template copies,
     least squares) and subtracted, the first strong reflected peak beside it; median
     gap over frames -> delta_d = a * gap / |rate|;
   - matched: envelope of the matched-filter output (analytic signal, real FFTs),
     direct peak within the first 129 lags, first strong peak above 3x the template's own
     envelope (shifted to the direct peak), parabolic interpolation -> delta_d = a * dt.
4. Prints a JSON summary (chirps, estimates, delta_d_median) to stdout.

Usage: range_scipy.py REC.wav [--method gap|matched] [--f-start 10000 --f-end 200
       --duration 1.0] [--speed-of-sound 343] [--channel 0] [--max-delta-d M]
"""
import argparse
import bisect
import json
import math
import sys

import numpy as np
import scipy.fft as sfft
from scipy.io import wavfile
from scipy.ndimage import maximum_filter1d
from scipy.signal import butter, oaconvolve, savgol_coeffs, sosfilt

TAPER_S = 0.005  # detect.rs DEFAULT_TAPER_S
CHUNK = 16  # detect.rs CHUNK
MIN_PEAK_RATIO = 12.0
MIN_NCC = 0.2
GAP_FRAMES_PER_CHIRP = 24
DIRECT_MARGIN = 3.0
MODEL_SPREAD = 3
MIN_DELTA_D_M = 0.3


def rnd(v):
    """Rust's f64::round (half away from zero) for non-negative values."""
    return int(math.floor(v + 0.5))


def next_pow2(n):
    return 1 << max(0, (int(n) - 1).bit_length())


def read_channel(path, channel):
    fs, data = wavfile.read(path, mmap=False)
    if data.ndim == 2:
        data = data[:, channel]
    if data.dtype == np.int16:
        x = data.astype(np.float32) / np.float32(32768.0)
    elif data.dtype == np.int32:  # 24-bit is read left-justified into int32 by scipy
        x = (data.astype(np.float64) / 2147483648.0).astype(np.float32)
    else:
        x = data.astype(np.float32)
    return float(fs), x


def template(f0, f1, dur, fs):
    n = int(round(dur * fs))
    t = np.arange(n) / fs
    rate = (f1 - f0) / dur
    ph = f0 * t + 0.5 * rate * t * t
    ang = 2 * np.pi * (ph - np.floor(ph))
    edge = np.minimum(t, dur - t)
    gain = np.where(edge >= TAPER_S, 1.0, 0.5 - 0.5 * np.cos(np.pi * edge / TAPER_S))
    return (gain * np.sin(ang)).astype(np.float32)


def median_of(v):
    """ranging.rs median_of: the upper median (element len/2 after selection)."""
    if len(v) == 0:
        return 0.0
    k = len(v) // 2
    return float(np.partition(v, k)[k])


def parabolic_offset(l, m, r):
    den = l - 2.0 * m + r
    if abs(den) < 1e-300 or not math.isfinite(den):
        return 0.0
    return min(0.5, max(-0.5, 0.5 * (l - r) / den))


def peak_in(v, lo, hi):
    hi = min(hi, len(v))
    if lo >= hi:
        return None
    i = lo + int(np.argmax(v[lo:hi]))
    m = float(v[i])
    if not m > 0.0:
        return None
    if i == 0 or i + 1 >= len(v):
        return float(i), m
    lg = lambda x: math.log(max(float(x), m * 1e-12))
    return i + parabolic_offset(lg(v[i - 1]), lg(m), lg(v[i + 1])), m


def first_strong_peak(v, lo, hi, frac, floor):
    hi = min(hi, len(v))
    if lo + 2 >= hi:
        return None
    strongest = max(0.0, float(v[lo:hi].max()))
    level = max(frac * strongest, floor)
    if not (strongest >= level and strongest > 0.0):
        return None
    a, b = max(lo, 1), min(hi, len(v) - 1)
    if a >= b:
        return None
    c = v[a:b]
    ok = (c >= level) & (c >= v[a - 1:b - 1]) & (c >= v[a + 1:b + 1])
    idx = np.flatnonzero(ok)
    return a + int(idx[0]) if len(idx) else None


def above_direct(v, model, scale, ratio, lo, hi):
    out = np.zeros(len(v))
    hi = min(hi, len(v))
    if lo >= hi:
        return out
    # max of model over i-3..=i+3 (model is >= 0, so zero padding is the same as skipping)
    mp = np.zeros(hi + MODEL_SPREAD + 1)
    k = min(len(model), len(mp))
    mp[:k] = model[:k]
    mx = maximum_filter1d(mp, 2 * MODEL_SPREAD + 1, mode="constant", cval=0.0)[lo:hi]
    keep = v[lo:hi] >= ratio * scale * mx
    out[lo:hi] = np.where(keep, v[lo:hi], 0.0)
    return out


def detect(x, tpl, fs, max_echo_delay_s):
    m = len(tpl)
    c = np.abs(oaconvolve(x, tpl[::-1], mode="valid"))  # c[lag] = sum x[lag+k] tpl[k]
    n_lags = len(c)
    n_chunks = -(-n_lags // CHUNK)
    cp = np.zeros(n_chunks * CHUNK, dtype=c.dtype)
    cp[:n_lags] = c
    cp = cp.reshape(n_chunks, CHUNK)
    arg = cp.argmax(axis=1)
    cmax = cp[np.arange(n_chunks), arg]
    glob = float(cmax.max())
    median = float(np.partition(cmax, n_chunks // 2)[n_chunks // 2])
    ratio = glob / max(median, 1e-30)
    if not ratio >= MIN_PEAK_RATIO:
        sys.exit(f"no chirp found (peak ratio {ratio:.1f}, need {MIN_PEAK_RATIO})")
    thr = max(MIN_PEAK_RATIO * median, 0.01 * glob)
    cands = np.flatnonzero(cmax >= thr)
    cands = cands[np.argsort(-cmax[cands], kind="stable")]
    lags = cands * CHUNK + arg[cands]
    vals = cmax[cands].astype(np.float64)
    # Normalised correlation of every candidate at once (a rejected candidate changes nothing).
    e2 = np.concatenate([[0.0], np.cumsum(x.astype(np.float64) ** 2)])
    energy = e2[np.minimum(lags + m, len(x))] - e2[lags]
    tpl_norm = math.sqrt(float(np.sum(tpl.astype(np.float64) ** 2)))
    den = np.sqrt(energy) * tpl_norm
    ncc = np.where(den > 0, np.minimum(vals / np.where(den > 0, den, 1.0), 1.0), 0.0)
    before = max(int(0.9 * m), 1)
    after = m + int(math.ceil(max(max_echo_delay_s, 0.0) * fs))
    accepted = []  # sorted onsets
    for lag, cc in zip(lags[ncc >= MIN_NCC].tolist(), ncc[ncc >= MIN_NCC].tolist()):
        j = bisect.bisect_left(accepted, max(lag - after, 0))
        if j < len(accepted) and accepted[j] <= lag + before:
            continue
        accepted.insert(j, lag)
    if not accepted:
        sys.exit("no chirp shape found")
    return accepted


class Ranger:
    def __init__(self, tpl, fs, f0, f1, dur, a, max_dd):
        self.tpl, self.fs, self.f0, self.dur, self.a, self.max_dd = tpl, fs, f0, dur, a, max_dd
        self.rate = abs((f1 - f0) / dur)
        self.k = (f1 - f0) / dur
        self.dir = 1.0 if f0 > f1 else -1.0
        self.frame = max(rnd(fs / math.sqrt(self.rate)), 32)
        self.nfft_gap = next_pow2(self.frame * 8)
        self.sg_win = (self.nfft_gap // self.frame) | 1
        self.hann = np.hanning(self.frame).astype(np.float32)  # symmetric, as spectrum.rs hann
        self.models = {}
        self.tpl_spec = {}
        w, h = self.sg_win, self.sg_win // 2
        # proj[j] evaluates the window's quadratic fit at position j (filter.rs SavitzkyGolay).
        self.sg_proj = np.stack([savgol_coeffs(w, 2, pos=j, use="dot") for j in range(w)])
        self.sg_centre = self.sg_proj[h][::-1].copy()
        self.gap_plan = None

    def freq_at(self, t):
        return self.f0 + self.k * t if 0.0 <= t <= self.dur else None

    def smooth(self, v):
        w, h, n = self.sg_win, self.sg_win // 2, len(v)
        if n < w:
            return v
        out = np.empty(n)
        out[h:n - h] = np.convolve(v, self.sg_centre, mode="valid")
        out[:h] = self.sg_proj[:h] @ v[:w]
        out[n - h:] = self.sg_proj[w - h:] @ v[n - w:]
        return out

    def mag(self, seg):
        return np.abs(sfft.rfft(seg * self.hann, self.nfft_gap)).astype(np.float64)

    def plan_gap(self):
        """Per frame of a chirp (the same for every chirp): offset, search bins, the
        template's smoothed spectrum and the direct-sound fit (three shifted copies)."""
        fs, a, frame, nfft, rate, tpl = self.fs, self.a, self.frame, self.nfft_gap, self.rate, self.tpl
        frame_s = frame / fs
        t0, t1 = self.max_dd / a, self.dur - frame_s
        bin_hz = fs / nfft
        guard = math.sqrt(rate)
        df_max = rate * self.max_dd / a
        reach = df_max + guard + 2.0 * bin_hz * (nfft // frame)
        b = lambda f: max(rnd(f / bin_hz), 0) if f > 0 else 0
        plan = []
        if t1 > t0:
            n = min(int(math.floor((t1 - t0) / frame_s)) + 1, GAP_FRAMES_PER_CHIRP)
            for k in range(n):
                ts = t0 if n == 1 else t0 + (t1 - t0) * k / (n - 1)
                off = rnd(ts * fs)
                f_mid = self.freq_at((off + 0.5 * frame) / fs)
                if f_mid is None or off + frame > len(tpl):
                    continue
                model = self.smooth(self.mag(tpl[off:off + frame]))
                n_bins = len(model)
                s_lo = min(max(int(math.floor((f_mid - reach) / bin_hz)), 0), n_bins)
                s_hi = min(max(int(math.ceil((f_mid + reach) / bin_hz)), 0) + 1, n_bins)
                blo, bhi = b(f_mid - 0.5 * guard), b(f_mid + 0.5 * guard) + 1
                fit = None
                if off >= 1 and off + 1 + frame <= len(tpl):
                    regs = np.stack([tpl[off - 1 + j:off - 1 + j + frame] for j in range(3)]).astype(np.float64)
                    try:
                        fit = (regs, np.linalg.inv(regs @ regs.T))
                    except np.linalg.LinAlgError:
                        fit = None
                plan.append((off, s_lo, s_hi, blo, bhi, model, fit))
        self.gap_plan = (plan, bin_hz, guard, df_max, b)

    def gap(self, x, onset):
        """Ranger::gap: all frames of one chirp transformed at once (real FFTs along rows)."""
        if self.gap_plan is None:
            self.plan_gap()
        plan, bin_hz, guard, df_max, b = self.gap_plan
        frame = self.frame
        if not plan or onset + len(self.tpl) > len(x):
            return None
        offs = np.array([q[0] for q in plan])
        segs = x[onset + offs[:, None] + np.arange(frame)[None, :]]
        raws = np.abs(sfft.rfft(segs * self.hann, self.nfft_gap, axis=1)).astype(np.float64)
        # Direct sound fitted by least squares and subtracted (ranging.rs direct_residual).
        res = np.zeros_like(segs)
        has_fit = np.array([q[6] is not None for q in plan])
        for i, q in enumerate(plan):
            if q[6] is not None:
                regs, ginv = q[6]
                s64 = segs[i].astype(np.float64)
                c = ginv @ (regs @ s64)
                res[i] = (s64 - c @ regs).astype(np.float32)
        rraws = np.abs(sfft.rfft(res * self.hann, self.nfft_gap, axis=1)).astype(np.float64)
        gaps = []
        for i, (off, s_lo, s_hi, blo, bhi, model, fit) in enumerate(plan):
            g = self.gap_frame(raws[i], rraws[i] if has_fit[i] else None, s_lo, s_hi, blo, bhi, model,
                               bin_hz, guard, df_max, b)
            if g is not None:
                gaps.append(g)
        if not gaps:
            return None
        return self.a * median_of(np.array(gaps)) / self.rate

    def gap_frame(self, raw, rraw, s_lo, s_hi, blo, bhi, model, bin_hz, guard, df_max, b):
        spec = np.zeros(len(raw))
        spec[s_lo:s_hi] = self.smooth(raw[s_lo:s_hi])
        p = peak_in(spec, blo, bhi)
        q = peak_in(model, blo, bhi)
        if p is None or q is None:
            return None
        (pd, vd), (pm, md) = p, q
        f_d = pd * bin_hz
        lo_f, hi_f = (f_d + guard, f_d + df_max) if self.dir > 0 else (f_d - df_max, f_d - guard)
        lo, hi = b(max(lo_f, 0.0)), min(b(max(hi_f, 0.0)) + 1, len(spec))
        if lo + 3 >= hi:
            return None
        if rraw is not None:
            rspec = np.zeros(len(rraw))
            rspec[s_lo:s_hi] = self.smooth(rraw[s_lo:s_hi])
            f_m = pm * bin_hz
            lo_f, hi_f = (f_m + 0.5 * guard, f_m + df_max) if self.dir > 0 else (f_m - df_max, f_m - 0.5 * guard)
            lo, hi = b(max(lo_f, 0.0)), min(b(max(hi_f, 0.0)) + 1, len(rspec))
            if lo + 3 >= hi:
                return None
            floor = 4.0 * median_of(rspec[lo:hi])
            if self.dir > 0:
                i = first_strong_peak(rspec, lo, hi, 0.3, floor)
            else:
                rev = rspec[lo:hi][::-1].copy()
                j = first_strong_peak(rev, 0, len(rev), 0.3, floor)
                i = None if j is None else hi - 1 - j
            if i is None:
                return None
            r = peak_in(rspec, max(i - 1, 0), i + 2)
            return None if r is None else abs(r[0] - pm) * bin_hz
        floor = 4.0 * median_of(spec[lo:hi])
        masked = above_direct(spec, model, vd / max(md, 1e-30), DIRECT_MARGIN, lo, hi)
        if self.dir > 0:
            i = first_strong_peak(masked, lo, hi, 0.3, floor)
        else:
            rev = masked[lo:hi][::-1].copy()
            j = first_strong_peak(rev, 0, len(rev), 0.3, floor)
            i = None if j is None else hi - 1 - j
        if i is None:
            return None
        r = peak_in(spec, max(i - 1, 0), i + 2)
        return None if r is None else abs(r[0] * bin_hz - f_d)

    def envelope(self, seg, nfft):
        h = self.tpl_spec.get(nfft)
        if h is None:
            h = self.tpl_spec[nfft] = np.conj(sfft.rfft(self.tpl, nfft))
        xs = sfft.rfft(seg, nfft) * h
        z = np.zeros(nfft, dtype=np.complex128)
        z[0] = xs[0]
        z[1:nfft // 2] = 2.0 * xs[1:nfft // 2]
        z[nfft // 2] = xs[nfft // 2]
        n_lags = min(max(len(seg) + 1 - len(self.tpl), 0), nfft)
        return np.abs(sfft.ifft(z)[:n_lags]) * nfft  # rustfft's inverse is unnormalised

    def matched(self, x, onset):
        fs, a, tpl = self.fs, self.a, self.tpl
        m, pad = len(tpl), 64
        dmax = int(math.ceil(self.max_dd / a * fs))
        start = onset - pad
        if start < 0:
            return None
        ln = m + dmax + 2 * pad
        seg = x[start:min(start + ln, len(x))]
        if len(seg) < m + 2 * pad:
            return None
        nfft = next_pow2(ln)
        env = self.envelope(seg, nfft)
        model = self.models.get(("matched", nfft, ln))
        if model is None:
            own = np.zeros(ln + pad, dtype=np.float32)
            own[pad:pad + m] = tpl
            model = self.models[("matched", nfft, ln)] = self.envelope(own, next_pow2(ln + pad))[pad:]
        p = peak_in(env, 0, 2 * pad + 1)
        if p is None:
            return None
        pd, vd = p
        shift = rnd(pd)
        shifted = np.zeros(len(env))
        k = max(0, min(len(env) - shift, len(model)))
        shifted[shift:shift + k] = model[:k]
        lo = int(math.ceil(pd + MIN_DELTA_D_M / a * fs))
        hi = min(int(math.floor(pd + self.max_dd / a * fs)), len(env))
        if lo + 3 >= hi:
            return None
        floor = 6.0 * median_of(env[lo:hi])
        masked = above_direct(env, shifted, vd / max(model[0], 1e-30), DIRECT_MARGIN, lo, hi)
        i = first_strong_peak(masked, lo, hi, 0.3, floor)
        if i is None:
            return None
        pr = i + parabolic_offset(env[i - 1], env[i], env[i + 1])
        return a * (pr - pd) / fs


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("wav")
    p.add_argument("--method", choices=["gap", "matched"], default="gap")
    p.add_argument("--f-start", type=float, default=10000.0)
    p.add_argument("--f-end", type=float, default=200.0)
    p.add_argument("--duration", type=float, default=1.0)
    p.add_argument("--speed-of-sound", type=float, default=343.0)
    p.add_argument("--channel", type=int, default=0)
    p.add_argument("--max-delta-d", type=float, default=None)
    args = p.parse_args()
    fs, x = read_channel(args.wav, args.channel)
    a = args.speed_of_sound
    tpl = template(args.f_start, args.f_end, args.duration, fs)
    x = sosfilt(butter(4, 100.0, "highpass", fs=fs, output="sos"), x.astype(np.float64)).astype(np.float32)
    max_dd = args.max_delta_d if args.max_delta_d is not None else min(0.5 * a * args.duration, 60.0)
    onsets = detect(x, tpl, fs, max_dd / a)
    r = Ranger(tpl, fs, args.f_start, args.f_end, args.duration, a, max_dd)
    est = [r.gap(x, o) if args.method == "gap" else r.matched(x, o) for o in onsets]
    dds = np.array([e for e in est if e is not None and math.isfinite(e)])
    print(json.dumps({"method": args.method, "chirps": len(onsets), "estimates": int(len(dds)),
                      "delta_d_median": float(np.median(dds)) if len(dds) else None,
                      "onsets_s": [o / fs for o in onsets[:3]]}))


if __name__ == "__main__":
    main()
