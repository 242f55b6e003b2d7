//! Chirp detection by matched filter (issue 5): the recorder's clock is not
//! the speaker's, so every chirp's arrival is found in the recording itself,
//! by correlating with the known sweep.

use crate::error::AudioError;
use crate::spectrum::FftCache;
use chirpmap_core::{LinearChirp, Sweep};
use rustfft::num_complex::Complex32;
use std::collections::BTreeMap;

/// Length (s) of the raised-cosine fade at each end of a rendered chirp.
/// Ours (the paper is silent): 5 ms removes the clicks of a hard start
/// without changing the sweep.
pub const DEFAULT_TAPER_S: f64 = 0.005;

/// Raised-cosine fade-in/out gain at `t_s` within a sweep of `duration_s`.
pub fn taper_gain(t_s: f64, duration_s: f64, taper_s: f64) -> f64 {
    if !(0.0..=duration_s).contains(&t_s) {
        return 0.0;
    }
    let edge = t_s.min(duration_s - t_s);
    if taper_s <= 0.0 || edge >= taper_s { 1.0 } else { 0.5 - 0.5 * (std::f64::consts::PI * edge / taper_s).cos() }
}

/// The known sweep sampled at the recorder's rate: the real waveform (for
/// the matched filter) and the complex conjugate phasor (for dechirping).
#[derive(Debug, Clone)]
pub struct ChirpTemplate {
    /// The known linear sweep (start/end frequency, duration) the template samples.
    pub chirp: LinearChirp,
    /// Sampling rate of the recording the template is matched against (Hz).
    pub sample_rate_hz: f64,
    /// `taper · sin(2π φ(t))`, t = n / fs.
    pub real: Vec<f32>,
    /// `exp(-i 2π φ(t))`, for mixing the recording down to beat frequencies.
    pub mix: Vec<Complex32>,
}

impl ChirpTemplate {
    /// Samples the waveform and the mixing phasor at `sample_rate_hz`; refuses a chirp reaching
    /// the Nyquist frequency, an invalid rate and templates shorter than [`MIN_TEMPLATE_SAMPLES`].
    pub fn new(chirp: LinearChirp, sample_rate_hz: f64) -> Result<Self, AudioError> {
        if chirp.f_start_hz().max(chirp.f_end_hz()) >= sample_rate_hz / 2.0 {
            return Err(AudioError::InvalidParam {
                field: "chirp",
                reason: format!(
                    "the sweep reaches {} Hz, at or above the Nyquist frequency {} Hz of this recording",
                    chirp.f_start_hz().max(chirp.f_end_hz()),
                    sample_rate_hz / 2.0
                ),
            });
        }
        if !(sample_rate_hz.is_finite()
            && sample_rate_hz > 0.0
            && sample_rate_hz <= crate::wav::MAX_SAMPLE_RATE_HZ as f64)
        {
            return Err(AudioError::InvalidParam {
                field: "sample rate",
                reason: format!(
                    "must be in 1..={} Hz, got {}",
                    crate::wav::MAX_SAMPLE_RATE_HZ,
                    chirpmap_core::error::Num(sample_rate_hz)
                ),
            });
        }
        let n_f = (chirp.duration_s() * sample_rate_hz).round();
        // Real (4 bytes) and mix (8 bytes) per sample, checked before allocating:
        // `--duration 1e5` asked for 57 GB (issue 8, item 8).
        crate::error::check_memory(
            || {
                format!(
                    "a {} s chirp template at {} Hz",
                    chirpmap_core::error::Num(chirp.duration_s()),
                    chirpmap_core::error::Num(sample_rate_hz)
                )
            },
            (n_f * 12.0) as u128,
            "check --duration (the chirp's length in seconds)",
        )?;
        let n = n_f as usize;
        if n < MIN_TEMPLATE_SAMPLES {
            return Err(AudioError::InvalidParam {
                field: "chirp duration",
                reason: format!(
                    "a {} s chirp is only {n} sample(s) at {} Hz; need at least {MIN_TEMPLATE_SAMPLES} samples \
                     ({:.6} s) for a matched filter (check --duration)",
                    chirp.duration_s(),
                    sample_rate_hz,
                    MIN_TEMPLATE_SAMPLES as f64 / sample_rate_hz
                ),
            });
        }
        let (mut real, mut mix) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for i in 0..n {
            let t = i as f64 / sample_rate_hz;
            let ph = chirp.phase_cycles(t);
            let ang = std::f64::consts::TAU * (ph - ph.floor());
            real.push((taper_gain(t, chirp.duration_s(), DEFAULT_TAPER_S) * ang.sin()) as f32);
            mix.push(Complex32::new(ang.cos() as f32, -ang.sin() as f32));
        }
        Ok(Self { chirp, sample_rate_hz, real, mix })
    }

    /// Template length in samples (the chirp's duration × sample rate).
    pub fn len(&self) -> usize {
        self.real.len()
    }
    /// Whether the template has no samples.
    pub fn is_empty(&self) -> bool {
        self.real.is_empty()
    }
    /// |df/dt| (Hz/s).
    pub fn rate_abs(&self) -> f64 {
        self.chirp.rate_hz_per_s().abs()
    }
    /// +1 for a down-chirp (reflections heard higher), −1 for an up-chirp.
    pub fn direction(&self) -> f64 {
        if self.chirp.f_start_hz() > self.chirp.f_end_hz() { 1.0 } else { -1.0 }
    }
    /// Conjugate spectrum of the zero-padded real template, for correlation.
    pub fn conj_spectrum(&self, cache: &mut FftCache, nfft: usize) -> Vec<Complex32> {
        let mut h = vec![Complex32::new(0.0, 0.0); nfft];
        for (d, s) in h.iter_mut().zip(&self.real) {
            d.re = *s;
        }
        cache.forward(&mut h);
        h.iter().map(|c| c.conj()).collect()
    }
}

/// Shortest chirp template (samples) accepted: below this a matched-filter
/// peak is not distinguishable from a click (ours).
pub const MIN_TEMPLATE_SAMPLES: usize = 64;

/// One detected chirp: the sample at which its direct arrival begins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// First sample of the chirp's direct arrival in the recording.
    pub onset_sample: usize,
    /// Matched-filter peak relative to the recording's typical level.
    pub strength: f64,
    /// Normalised correlation `|c| / (‖x_seg‖·‖template‖)` at the onset, in
    /// [0, 1]: 1 for the template alone, lower with echoes and noise, and
    /// low for a chirp of another duration or band.
    pub ncc: f64,
}

/// Smallest normalised correlation [`Detection::ncc`] of a chirp (ours).
/// The right chirp in examples/wall (20 dB SNR, a wall echo) scores 0.96;
/// half the duration, or 3 kHz instead of 10 kHz at the start, scores
/// 0.03 (measured with `chirpmap range`). 0.2 leaves room for noisier
/// recordings (about −7 dB broadband SNR).
pub const MIN_NCC: f64 = 0.2;

/// Lags per stored maximum: the full correlation of an hour (173 M lags) is
/// never held, only the maximum of each chunk and its lag.
const CHUNK: usize = 16;

/// Peak-to-typical ratio below which a recording is said to hold no chirp.
pub const MIN_PEAK_RATIO: f64 = 12.0;

/// Finds every chirp in `x` (high-passed). A chirp is a matched-filter peak
/// that is the largest from 0.9 T before it to T + `max_echo_delay_s` after
/// it (chirps do not overlap, and an echo up to the largest searched delay
/// is not another chirp), at least [`MIN_PEAK_RATIO`] × the median chunk
/// maximum, at least 1 % of the strongest chirp (a moving listener's level
/// changes with its distance), and whose normalised correlation is at least
/// [`MIN_NCC`] (the right sweep, not a partial match of another one).
/// Only chirps whose full template fits in `x` are returned.
///
/// A peak at least half as strong as a chirp, later than 0.9 T but within
/// that chirp's echo window, is another chirp: the window is too long for
/// the chirp spacing, and an [`AudioError::InvalidParam`] names
/// `--max-delta-d`.
pub fn detect_chirps(
    x: &[f32],
    tpl: &ChirpTemplate,
    cache: &mut FftCache,
    max_echo_delay_s: f64,
) -> Result<Vec<Detection>, AudioError> {
    let m = tpl.len();
    if m == 0 || m > x.len() {
        return Err(AudioError::ChirpLongerThanRecording {
            chirp_s: tpl.chirp.duration_s(),
            recording_s: x.len() as f64 / tpl.sample_rate_hz,
        });
    }
    if x.iter().all(|v| *v == 0.0) {
        return Err(AudioError::Silent);
    }
    let nfft = (4 * m).next_power_of_two().max(1 << 14);
    let step = nfft - m + 1;
    let h = tpl.conj_spectrum(cache, nfft);
    let last_lag = x.len() - m; // inclusive
    let n_lags = last_lag + 1;
    let n_chunks = n_lags.div_ceil(CHUNK);
    let mut chunk_max = vec![0.0f32; n_chunks];
    let mut chunk_arg = vec![0u32; n_chunks];
    let fwd = cache.plan(nfft, false);
    let inv = cache.plan(nfft, true);
    let mut buf = vec![Complex32::new(0.0, 0.0); nfft];
    let mut scratch = vec![Complex32::new(0.0, 0.0); fwd.get_inplace_scratch_len().max(inv.get_inplace_scratch_len())];
    // Two real blocks share one complex FFT: the template is real, so the
    // correlation of (x1 + i·x2) is c1 + i·c2.
    let mut s = 0usize;
    while s < n_lags {
        let s2 = s + step;
        for (k, b) in buf.iter_mut().enumerate() {
            let re = x.get(s + k).copied().unwrap_or(0.0);
            let im = if s2 < n_lags { x.get(s2 + k).copied().unwrap_or(0.0) } else { 0.0 };
            *b = Complex32::new(re, im);
        }
        fwd.process_with_scratch(&mut buf, &mut scratch);
        for (b, hh) in buf.iter_mut().zip(&h) {
            *b *= hh;
        }
        inv.process_with_scratch(&mut buf, &mut scratch);
        for (start, part) in [(s, 0usize), (s2, 1usize)] {
            if start >= n_lags {
                continue;
            }
            let end = (start + step).min(n_lags);
            for lag in start..end {
                let c = buf[lag - start];
                let v = if part == 0 { c.re } else { c.im }.abs();
                let ci = lag / CHUNK;
                if v > chunk_max[ci] {
                    chunk_max[ci] = v;
                    chunk_arg[ci] = (lag % CHUNK) as u32;
                }
            }
        }
        s += 2 * step;
    }
    let global = chunk_max.iter().copied().fold(0.0f32, f32::max);
    let mut sorted = chunk_max.clone();
    let mid = sorted.len() / 2;
    let median = *sorted.select_nth_unstable_by(mid, f32::total_cmp).1;
    let ratio = f64::from(global) / f64::from(median).max(1e-30);
    if ratio.is_nan() || ratio < MIN_PEAK_RATIO {
        return Err(AudioError::NoChirp { ratio: if ratio.is_finite() { ratio } else { 0.0 }, need: MIN_PEAK_RATIO });
    }
    let thr = (MIN_PEAK_RATIO as f32 * median).max(0.01 * global);
    let mut cands: Vec<usize> = (0..n_chunks).filter(|&i| chunk_max[i] >= thr).collect();
    cands.sort_by(|&a, &b| chunk_max[b].total_cmp(&chunk_max[a]));
    let before = ((0.9 * m as f64) as usize).max(1);
    let echo = (max_echo_delay_s.max(0.0) * tpl.sample_rate_hz).ceil();
    if !echo.is_finite() || echo > x.len() as f64 {
        return Err(AudioError::InvalidParam {
            field: "--max-delta-d",
            reason: format!("an echo delay of {max_echo_delay_s} s is longer than the recording"),
        });
    }
    let after = m + echo as usize;
    let tpl_norm = tpl.real.iter().map(|v| f64::from(*v) * f64::from(*v)).sum::<f64>().sqrt();
    // Normalised correlation at `lag`, computed only for the few candidates
    // that could be accepted (a prefix-sum table of x² would cost 8 bytes per
    // sample: 1.4 GB for an hour at 48 kHz).
    let ncc_at = |lag: usize, c: f32| {
        let energy: f64 = x[lag..(lag + m).min(x.len())].iter().map(|v| f64::from(*v) * f64::from(*v)).sum();
        // rustfft's inverse is unnormalised: the stored values are nfft × the correlation.
        let e = energy.sqrt() * tpl_norm * nfft as f64;
        if e > 0.0 { (f64::from(c) / e).min(1.0) } else { 0.0 }
    };
    let mut accepted: BTreeMap<usize, f32> = BTreeMap::new();
    let mut out = Vec::new();
    let mut best_ncc = 0.0f64;
    for ci in cands {
        let lag = ci * CHUNK + chunk_arg[ci] as usize;
        let c = chunk_max[ci];
        let mut near = accepted.range(lag.saturating_sub(after)..=lag + before).peekable();
        if near.peek().is_some() {
            // Within a stronger chirp's echo window: skipped, unless it is a
            // chirp-shaped arrival starting after that chirp (chirps too close).
            if let Some((&a, _)) = near.find(|&(&a, &ca)| a + before < lag && c >= 0.5 * ca) {
                let ncc = ncc_at(lag, c);
                best_ncc = best_ncc.max(ncc);
                if ncc >= MIN_NCC {
                    return Err(AudioError::InvalidParam {
                        field: "--max-delta-d",
                        reason: format!(
                            "chirps {:.3} s apart but the echo window is T + max Δd/a = {:.3} s; \
                             lower --max-delta-d below a·(chirp spacing − T)",
                            (lag - a) as f64 / tpl.sample_rate_hz,
                            after as f64 / tpl.sample_rate_hz
                        ),
                    });
                }
            }
            continue;
        }
        let ncc = ncc_at(lag, c);
        best_ncc = best_ncc.max(ncc);
        if ncc < MIN_NCC {
            continue;
        }
        accepted.insert(lag, c);
        out.push(Detection { onset_sample: lag, strength: f64::from(c) / f64::from(median).max(1e-30), ncc });
    }
    if out.is_empty() {
        return Err(AudioError::NoChirpShape { ncc: best_ncc, need: MIN_NCC });
    }
    out.sort_by_key(|d| d.onset_sample);
    Ok(out)
}
