//! Per-chirp ranging: the path difference Δd between the direct sound and
//! the first reflection (paper §II.A Eq. 2–3, §IV), by three methods.
//!
//! - [`Method::Gap`] — the paper's: short FFT frames across the chirp, each
//!   magnitude spectrum Savitzky–Golay-smoothed, the direct peak picked by
//!   prediction (f at the time since the direct onset), the reflected peak
//!   beside it (higher for a down-chirp), Δf = gap, Δd = a·Δf·T/B. The
//!   median over frames is the chirp's estimate. Ours, beyond the paper:
//!   before the reflected peak is picked, the direct sound is fitted (least
//!   squares, the known chirp at three one-sample shifts) and subtracted in
//!   the time domain, and the gap is measured from the template's own peak
//!   in the same frame; near the floor the reflected peak otherwise leans on
//!   the direct one's window leakage (+10 % at 2.1× the floor, now −0.9 %). Frames of `sqrt(T/B)`
//!   balance bin width against the sweep's smear within a frame, which
//!   gives the resolution floor a·sqrt(T/B) (docs/architecture.md, physics notes).
//! - [`Method::Matched`] — ours: correlate with the known chirp, take the
//!   envelope (analytic signal), Δt between the direct and the first
//!   reflection peaks, each refined to a fraction of a sample.
//! - [`Method::Dechirp`] — ours: multiply the recording by the conjugate
//!   reference aligned on the direct arrival; the direct becomes a tone near
//!   0 Hz and a reflection Δt later a tone at |rate|·Δt, measured over the
//!   whole chirp (resolution 1/T Hz instead of sqrt(B/T)). Taking the
//!   difference of the two tones cancels any residual misalignment.

use crate::detect::ChirpTemplate;
use crate::filter::SavitzkyGolay;
use crate::spectrum::{FftCache, abs_f64, hann, magnitude_bins, magnitude_spectrum, parabolic_offset, peak_in};
use chirpmap_core::{Point, Sweep};
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::Arc;

/// Ranging method (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The paper's frequency gap between direct and reflected sound in short FFT frames (§IV).
    Gap,
    /// Ours: matched filter, delay between the direct and the first reflection peaks.
    Matched,
    /// Ours: dechirping, beat frequency of the reflection over the whole chirp.
    Dechirp,
}

impl Method {
    /// Every method, in the order reports list them.
    pub const ALL: [Method; 3] = [Method::Gap, Method::Matched, Method::Dechirp];
    /// Lower-case name, as accepted by `FromStr` and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Gap => "gap",
            Method::Matched => "matched",
            Method::Dechirp => "dechirp",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "gap" => Ok(Method::Gap),
            "matched" => Ok(Method::Matched),
            "dechirp" => Ok(Method::Dechirp),
            o => Err(format!("unknown method {o:?}: use gap, matched or dechirp")),
        }
    }
}

/// Search limits for the reflection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeLimits {
    /// Speed of sound `a` (m/s) converting time or frequency differences to Δd.
    pub speed_of_sound_mps: f64,
    /// Largest Δd searched (m). Reflections later than this are ignored.
    pub max_delta_d_m: f64,
    /// Smallest Δd searched by the matched and dechirp methods (m); the gap
    /// method uses its resolution floor instead.
    pub min_delta_d_m: f64,
}

impl RangeLimits {
    /// Defaults (ours): Δd up to min(60 m, a·T/2), down to 0.3 m.
    pub fn for_chirp(duration_s: f64, speed_of_sound_mps: f64) -> Self {
        Self {
            speed_of_sound_mps,
            max_delta_d_m: (0.5 * speed_of_sound_mps * duration_s).min(60.0),
            min_delta_d_m: 0.3,
        }
    }
}

/// One chirp's estimate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Estimate {
    /// Frequency gap between the reflected and the direct sound (Hz); for
    /// matched filtering the gap equivalent to the measured delay.
    pub delta_f_hz: f64,
    /// Path difference Δd between the reflected and the direct sound (m), paper Eq. 2–3.
    pub delta_d_m: f64,
    /// Reflected-to-direct amplitude ratio.
    pub relative_level: f64,
}

/// The gap method's resolution floor a·sqrt(T/B) (m) (docs/architecture.md, physics notes). With
/// Hann frames of sqrt(T/B) the two peaks are reliably separate only from
/// about [`GAP_RELIABLE_FACTOR`] × this floor (measured, EXPERIMENTS.md).
pub fn gap_floor_m(tpl: &ChirpTemplate, speed_of_sound_mps: f64) -> f64 {
    speed_of_sound_mps / tpl.rate_abs().sqrt()
}

/// Multiple of [`gap_floor_m`] above which the gap method meets 5 %
/// (measured: −1.3 % at 2.03×, −6.8 % at 1.47×; EXPERIMENTS.md).
pub const GAP_RELIABLE_FACTOR: f64 = 2.0;

/// Index of the first local maximum in `v[lo..hi]` at least `frac` × the
/// largest value there and above `floor`. "First" = the earliest reflection
/// (issue 5: the first reflection after the direct path).
pub(crate) fn first_strong_peak(v: &[f64], lo: usize, hi: usize, frac: f64, floor: f64) -> Option<usize> {
    let hi = hi.min(v.len());
    if lo + 2 >= hi {
        return None;
    }
    let strongest = v[lo..hi].iter().copied().fold(0.0, f64::max);
    let level = (frac * strongest).max(floor);
    if !(strongest >= level && strongest > 0.0) {
        return None;
    }
    (lo.max(1)..hi.min(v.len() - 1)).find(|&i| v[i] >= level && v[i] >= v[i - 1] && v[i] >= v[i + 1])
}

/// The first `k` local maxima in `v[lo..hi]` (earliest first), each at least
/// `frac` × the largest value there and above `floor`, and each more than
/// `min_sep` indices after the one before (a flat top is one peak, and a
/// window's main lobe is one echo): several reflections per frame. The first
/// is [`first_strong_peak`]'s.
pub(crate) fn strong_peaks(
    v: &[f64],
    lo: usize,
    hi: usize,
    frac: f64,
    floor: f64,
    k: usize,
    min_sep: usize,
) -> Vec<usize> {
    let Some(first) = first_strong_peak(v, lo, hi, frac, floor) else { return Vec::new() };
    let hi = hi.min(v.len());
    let strongest = v[lo..hi].iter().copied().fold(0.0, f64::max);
    let level = (frac * strongest).max(floor);
    let mut out = vec![first];
    for i in first + 1..hi.min(v.len() - 1) {
        if out.len() >= k {
            break;
        }
        let last = out[out.len() - 1];
        if i > last + min_sep && v[i] >= level && v[i] >= v[i - 1] && v[i] >= v[i + 1] {
            out.push(i);
        }
    }
    out
}

pub(crate) fn median_of(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    let mid = s.len() / 2;
    *s.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Keeps `v[i]` only where it is at least `ratio` × the direct path's own
/// response `model` (scaled so that its value at the direct peak equals the
/// measured one); elsewhere 0. The direct sound is 10–30 dB louder than a
/// wall echo, and its sidelobes (matched filter) or smeared skirt (gap)
/// would otherwise be taken for the nearest reflection.
/// The model is first widened by a running maximum over ±`MODEL_SPREAD`
/// samples, so a fractional-sample offset between the model and the data
/// cannot slip a sidelobe through a ripple null.
/// Only `v[lo..hi]` is examined; the rest of the output is 0.
pub(crate) fn above_direct(v: &[f64], model: &[f64], scale: f64, ratio: f64, lo: usize, hi: usize) -> Vec<f64> {
    let mut out = vec![0.0; v.len()];
    let hi = hi.min(v.len());
    if lo >= hi {
        return out;
    }
    // The widened model over lo..hi: model[lo − S ..= hi − 1 + S] (0 outside
    // the model), then maxima of 2, 4 (2 + 2) and 2S + 1 = 7 (4 + 4, shifted
    // 3) neighbours, each an elementwise pass that vectorises; the sliding
    // fold it replaces was 3 % of a matched run. f64::max ignores NaN and
    // every magnitude is ≥ 0, so the grouping gives the fold's values.
    const _: () = assert!(MODEL_SPREAD == 3);
    let at = |j: usize| j.checked_sub(MODEL_SPREAD).and_then(|j| model.get(j)).copied().unwrap_or(0.0);
    let padded: Vec<f64> = (lo..hi + 2 * MODEL_SPREAD).map(at).collect();
    let pairs: Vec<f64> = padded.windows(2).map(|w| w[0].max(w[1])).collect();
    let fours: Vec<f64> = pairs.iter().zip(&pairs[2..]).map(|(a, b)| a.max(*b)).collect();
    for (k, i) in (lo..hi).enumerate() {
        let m = fours[k].max(fours[k + 3]).max(0.0);
        if v[i] >= ratio * scale * m {
            out[i] = v[i];
        }
    }
    out
}

const MODEL_SPREAD: usize = 3;

/// Samples of each waveform in a [`template_fingerprint`].
const FINGERPRINT_SAMPLES: usize = 64;

/// What tells templates apart for [`Ranger`]'s caches: the sweep's start,
/// end and duration, the rate, the length, and a hash of 64 evenly spaced
/// samples of each waveform (templates with one description can differ in
/// their samples: Doppler-scaled ones, exponential sweeps matched through a
/// linear description). A sample, not every one: the engine checks on every
/// gap frame, where hashing a whole second of samples would cost as much as
/// the frame.
fn template_fingerprint(tpl: &ChirpTemplate) -> [u64; 6] {
    let c = &tpl.chirp;
    // FNV-1a over the sampled values' bits.
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |bits: u32| {
        h ^= u64::from(bits);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    };
    let step = tpl.real.len().div_ceil(FINGERPRINT_SAMPLES).max(1);
    tpl.real.iter().step_by(step).for_each(|v| eat(v.to_bits()));
    let step = tpl.mix.len().div_ceil(FINGERPRINT_SAMPLES).max(1);
    tpl.mix.iter().step_by(step).for_each(|v| {
        eat(v.re.to_bits());
        eat(v.im.to_bits());
    });
    [
        c.f_start_hz().to_bits(),
        c.f_end_hz().to_bits(),
        c.duration_s().to_bits(),
        tpl.sample_rate_hz.to_bits(),
        tpl.len() as u64,
        h,
    ]
}

/// Ranging engine with cached FFT plans and direct-path responses.
#[derive(Debug, Default)]
pub struct Ranger {
    pub(crate) cache: FftCache,
    spectra: HashMap<usize, Vec<Complex32>>,
    /// Direct-only responses of the template, keyed by method and layout.
    models: HashMap<(Method, usize, usize), Vec<f64>>,
    /// Gram matrices of the gap method's direct-sound fit, by frame offset and length.
    grams: HashMap<(usize, usize), Option<[[f64; 3]; 3]>>,
    /// The matched method's FFT buffer, reused from chirp to chirp.
    buf: Vec<Complex32>,
    /// The gap method's smoothers by window: their coefficients come from a
    /// least-squares solve per window position, which per frame was ~4 % of a
    /// gap run's CPU (issue 14).
    savgol: HashMap<usize, Arc<SavitzkyGolay>>,
    /// Fingerprint of the template the caches above were built for
    /// ([`template_fingerprint`]): `spectra`, `models` and `grams` are keyed
    /// by sizes only, so another template empties them
    /// ([`Ranger::use_template`]) rather than reusing another chirp's spectrum.
    template: Option<[u64; 6]>,
}

/// Frames per chirp in the gap method (evenly spread; the median is taken).
pub const GAP_FRAMES_PER_CHIRP: usize = 24;

/// How far above the direct path's own response a reflection must stand.
const DIRECT_MARGIN: f64 = 3.0;

impl Ranger {
    /// An engine with empty caches.
    pub fn new() -> Self {
        Self::default()
    }

    /// Empties the template-dependent caches when `tpl` is not the template
    /// they were built for.
    fn use_template(&mut self, tpl: &ChirpTemplate) {
        let key = template_fingerprint(tpl);
        if self.template != Some(key) {
            self.spectra.clear();
            self.models.clear();
            self.grams.clear();
            self.template = Some(key);
        }
    }

    /// Estimates Δd for the chirp whose direct arrival starts at sample
    /// `onset` of `x` (high-passed). `None` when no reflection stands out or
    /// the chirp does not fit in `x`.
    pub fn estimate(
        &mut self,
        method: Method,
        x: &[f32],
        onset: usize,
        tpl: &ChirpTemplate,
        lim: &RangeLimits,
    ) -> Option<Estimate> {
        self.use_template(tpl);
        match method {
            Method::Gap => self.gap(x, onset, tpl, lim),
            Method::Matched => self.matched(x, onset, tpl, lim),
            Method::Dechirp => self.dechirp(x, onset, tpl, lim),
        }
    }

    fn gap(&mut self, x: &[f32], onset: usize, tpl: &ChirpTemplate, lim: &RangeLimits) -> Option<Estimate> {
        let fs = tpl.sample_rate_hz;
        let t = tpl.chirp.duration_s();
        let rate = tpl.rate_abs();
        let a = lim.speed_of_sound_mps;
        let frame = Self::gap_frame_len(tpl);
        let frame_s = frame as f64 / fs;
        // Frames start once every reflection up to max Δd has arrived.
        let t0 = lim.max_delta_d_m / a;
        let t1 = t - frame_s;
        if t1 <= t0 || onset + tpl.len() > x.len() {
            return None;
        }
        let n_frames = (((t1 - t0) / frame_s).floor() as usize + 1).min(GAP_FRAMES_PER_CHIRP);
        let mut gaps = Vec::with_capacity(n_frames);
        let mut levels = Vec::with_capacity(n_frames);
        for k in 0..n_frames {
            let ts = if n_frames == 1 { t0 } else { t0 + (t1 - t0) * k as f64 / (n_frames - 1) as f64 };
            let off = (ts * fs).round() as usize;
            if let Some((g, l)) = self.gap_frame_of_current(x, onset + off, off, frame, tpl, lim) {
                gaps.push(g);
                levels.push(l);
            }
        }
        if gaps.is_empty() {
            return None;
        }
        let delta_f_hz = median_of(&gaps);
        Some(Estimate { delta_f_hz, delta_d_m: a * delta_f_hz / rate, relative_level: median_of(&levels) })
    }

    /// Gap frame size for a template: sqrt(T/B) (see the module docs).
    pub fn gap_frame_len(tpl: &ChirpTemplate) -> usize {
        ((tpl.sample_rate_hz / tpl.rate_abs().sqrt()).round() as usize).max(32)
    }

    /// One frame of the gap method: the frame `x[start..start+frame]` holds
    /// the direct sound emitted `off` samples after the chirp began. Returns
    /// the frequency gap (Hz) and the reflected/direct level.
    pub fn gap_frame(
        &mut self,
        x: &[f32],
        start: usize,
        off: usize,
        frame: usize,
        tpl: &ChirpTemplate,
        lim: &RangeLimits,
    ) -> Option<(f64, f64)> {
        self.use_template(tpl);
        self.gap_frame_of_current(x, start, off, frame, tpl, lim)
    }

    /// [`Ranger::gap_frame`] for `tpl`, the template the caches were built
    /// for ([`Ranger::use_template`] already called, as [`Ranger::estimate`]
    /// does once per chirp for all its frames).
    fn gap_frame_of_current(
        &mut self,
        x: &[f32],
        start: usize,
        off: usize,
        frame: usize,
        tpl: &ChirpTemplate,
        lim: &RangeLimits,
    ) -> Option<(f64, f64)> {
        let fs = tpl.sample_rate_hz;
        let rate = tpl.rate_abs();
        let a = lim.speed_of_sound_mps;
        let nfft = (frame * 8).next_power_of_two();
        let bin_hz = fs / nfft as f64;
        let sg_window = (nfft / frame) | 1;
        let sg = match self.savgol.get(&sg_window) {
            Some(sg) => Arc::clone(sg),
            None => {
                let sg = Arc::new(SavitzkyGolay::new(sg_window, 2).ok()?);
                self.savgol.insert(sg_window, Arc::clone(&sg));
                sg
            }
        };
        let guard_hz = rate.sqrt();
        let df_max = rate * lim.max_delta_d_m / a;
        let dir = tpl.direction();
        let seg = x.get(start..start + frame)?;
        // nfft ≥ frame: the spectrum's bins.
        let n_bins = nfft / 2 + 1;
        let key = (Method::Gap, off, frame);
        if !self.models.contains_key(&key) {
            let tseg = tpl.real.get(off..off + frame)?;
            let m = sg.smooth(&magnitude_spectrum(&mut self.cache, tseg, nfft));
            self.models.insert(key, m);
        }
        let model = self.models.get(&key)?;
        // Smooth only the bins the search can touch (the rest is never read).
        let reach_hz = df_max + guard_hz + 2.0 * bin_hz * (nfft / frame) as f64;
        let f_mid = tpl.chirp.freq_at((off as f64 + 0.5 * frame as f64) / fs)?;
        let (s_lo, s_hi) = (
            (((f_mid - reach_hz) / bin_hz).floor().max(0.0) as usize).min(n_bins),
            (((f_mid + reach_hz) / bin_hz).ceil().max(0.0) as usize + 1).min(n_bins),
        );
        // Magnitudes of those bins only (a square root each; the rest was
        // 4 % of a gap run's CPU and never read).
        let mut spec = vec![0.0; n_bins];
        spec[s_lo..s_hi].copy_from_slice(&sg.smooth(&magnitude_bins(&mut self.cache, seg, nfft, s_lo..s_hi)));
        let tc = (off as f64 + 0.5 * frame as f64) / fs;
        let f_pred = tpl.chirp.freq_at(tc)?;
        let bin = |f: f64| (f / bin_hz).round().max(0.0) as usize;
        let (blo, bhi) = (bin(f_pred - 0.5 * guard_hz), bin(f_pred + 0.5 * guard_hz) + 1);
        let (pd, vd) = peak_in(&spec, blo, bhi)?;
        let (_, md) = peak_in(model, blo, bhi)?;
        let f_d = pd * bin_hz;
        let (lo_f, hi_f) = if dir > 0.0 { (f_d + guard_hz, f_d + df_max) } else { (f_d - df_max, f_d - guard_hz) };
        let (lo, hi) = (bin(lo_f.max(0.0)), (bin(hi_f.max(0.0)) + 1).min(spec.len()));
        if lo + 3 >= hi {
            return None;
        }
        if SUBTRACT_DIRECT
            && let Some(g) = *self.grams.entry((off, frame)).or_insert_with(|| direct_gram(tpl, off, frame))
            && let Some(res) = direct_residual(seg, tpl, off, frame, &g)
        {
            // The direct sound removed in the time domain: the reflection's
            // peak no longer leans on the direct's window leakage. Its
            // position is measured against the template's own peak in this
            // frame, so the smoothing and window biases cancel.
            let (pm, _) = peak_in(model, blo, bhi)?;
            let mut rspec = vec![0.0; n_bins];
            rspec[s_lo..s_hi].copy_from_slice(&sg.smooth(&magnitude_bins(&mut self.cache, &res, nfft, s_lo..s_hi)));
            let f_m = pm * bin_hz;
            let (lo_f, hi_f) =
                if dir > 0.0 { (f_m + 0.5 * guard_hz, f_m + df_max) } else { (f_m - df_max, f_m - 0.5 * guard_hz) };
            let (lo, hi) = (bin(lo_f.max(0.0)), (bin(hi_f.max(0.0)) + 1).min(rspec.len()));
            if lo + 3 >= hi {
                return None;
            }
            let floor = 4.0 * median_of(&rspec[lo..hi]);
            let i = if dir > 0.0 {
                first_strong_peak(&rspec, lo, hi, 0.3, floor)
            } else {
                let rev: Vec<f64> = rspec[lo..hi].iter().rev().copied().collect();
                first_strong_peak(&rev, 0, rev.len(), 0.3, floor).map(|i| hi - 1 - i)
            }?;
            let (pr, vr) = peak_in(&rspec, i.saturating_sub(1), i + 2)?;
            return Some(((pr - pm).abs() * bin_hz, vr / vd.max(1e-30)));
        }
        let floor = 4.0 * median_of(&spec[lo..hi]);
        let masked = above_direct(&spec, model, vd / md.max(1e-30), DIRECT_MARGIN, lo, hi);
        // Scan outward from the direct peak for the nearest strong peak.
        let i = if dir > 0.0 {
            first_strong_peak(&masked, lo, hi, 0.3, floor)
        } else {
            let rev: Vec<f64> = masked[lo..hi].iter().rev().copied().collect();
            first_strong_peak(&rev, 0, rev.len(), 0.3, floor).map(|i| hi - 1 - i)
        }?;
        let (pr, vr) = peak_in(&spec, i.saturating_sub(1), i + 2)?;
        Some(((pr * bin_hz - f_d).abs(), vr / vd.max(1e-30)))
    }

    /// One frame of the dechirp method: `x[start..start+frame]` mixed with
    /// the reference from template offset `off` (aligned on the direct
    /// sound). Returns the beat-frequency gap (Hz) and the relative level.
    pub fn dechirp_frame(
        &mut self,
        x: &[f32],
        start: usize,
        off: usize,
        frame: usize,
        tpl: &ChirpTemplate,
        lim: &RangeLimits,
    ) -> Option<(f64, f64)> {
        self.use_template(tpl);
        let fs = tpl.sample_rate_hz;
        let a = lim.speed_of_sound_mps;
        let rate = tpl.rate_abs();
        let nfft = (frame * 4).next_power_of_two();
        let bin_hz = fs / nfft as f64;
        let kmax = (((rate * lim.max_delta_d_m / a) / bin_hz).ceil() as usize + DECHIRP_OFF + 2).min(nfft / 2);
        let w = hann(frame);
        let mix = tpl.mix.get(off..off + frame)?;
        let down = tpl.direction() > 0.0;
        let spectrum_of = |cache: &mut FftCache, seg: &[f32]| -> Vec<f64> {
            let mut buf = vec![Complex32::new(0.0, 0.0); nfft];
            for i in 0..frame {
                buf[i] = mix[i] * (seg[i] * w[i]);
            }
            cache.forward(&mut buf);
            (0..kmax)
                .map(|j| {
                    let f = j as isize - DECHIRP_OFF as isize;
                    let f = if down { f } else { -f };
                    f64::from(buf[f.rem_euclid(nfft as isize) as usize].norm())
                })
                .collect()
        };
        let v = spectrum_of(&mut self.cache, x.get(start..start + frame)?);
        let model = spectrum_of(&mut self.cache, tpl.real.get(off..off + frame)?);
        let (pd, vd) = peak_in(&v, DECHIRP_OFF - 4, DECHIRP_OFF + 5)?;
        let lo = ((pd + (rate * lim.min_delta_d_m / a) / bin_hz).ceil() as usize).max(DECHIRP_OFF + 3);
        if lo + 3 >= v.len() {
            return None;
        }
        let floor = 6.0 * median_of(&v[lo..]);
        let masked = above_direct(&v, &model, vd / model[DECHIRP_OFF].max(1e-30), DIRECT_MARGIN, lo, v.len());
        let i = first_strong_peak(&masked, lo, v.len(), 0.3, floor)?;
        let (pr, vr) = peak_in(&v, i - 1, i + 2)?;
        Some(((pr - pd) * bin_hz, vr / vd.max(1e-30)))
    }

    /// Envelope of the correlation of `seg` with the template (analytic
    /// signal: negative frequencies removed), lags `0..=seg.len() − m`.
    fn matched_envelope(&mut self, seg: &[f32], tpl: &ChirpTemplate, nfft: usize) -> Vec<f64> {
        let m = tpl.len();
        // Borrowed, not copied (a copy was 512 KB per chirp at 48 kHz).
        let Self { cache, spectra, buf, .. } = self;
        let h = spectra.entry(nfft).or_insert_with(|| tpl.conj_spectrum(cache, nfft));
        // The analytic signal's spectrum: bins 0 and n/2 as they are, the
        // positive frequencies doubled, the negative ones 0. The segment is
        // real, so its bins 0..=n/2 come from a real-input FFT (about half a
        // complex one; the values differ from the complex FFT's at f32
        // rounding level; BENCHMARKS.md "Sixth round"). Each value of the
        // engine's buffer is written once (a fresh zeroed 512 KB buffer per
        // chirp cost a memset and page faults).
        let half = nfft / 2;
        buf.clear();
        if let Some(spec) = cache.forward_real(seg.iter().copied(), nfft) {
            buf.extend(spec.iter().zip(h.iter()).enumerate().map(|(k, (x, hh))| {
                let y = x * hh;
                if k == 0 || k == half { y } else { y * 2.0 }
            }));
        }
        buf.resize(nfft, Complex32::new(0.0, 0.0));
        cache.inverse(buf);
        let n_lags = (seg.len() + 1).saturating_sub(m).min(nfft);
        buf[..n_lags].iter().map(abs_f64).collect()
    }

    fn matched(&mut self, x: &[f32], onset: usize, tpl: &ChirpTemplate, lim: &RangeLimits) -> Option<Estimate> {
        let fs = tpl.sample_rate_hz;
        let a = lim.speed_of_sound_mps;
        let m = tpl.len();
        let pad = 64usize;
        let dmax = (lim.max_delta_d_m / a * fs).ceil() as usize;
        let start = onset.checked_sub(pad)?;
        let len = m + dmax + 2 * pad;
        let seg = x.get(start..(start + len).min(x.len()))?;
        if seg.len() < m + 2 * pad {
            return None;
        }
        let nfft = len.next_power_of_two();
        let env = self.matched_envelope(seg, tpl, nfft);
        let key = (Method::Matched, nfft, len);
        if !self.models.contains_key(&key) {
            // The template alone at lag `pad`, shifted to lag 0.
            let mut own = vec![0.0f32; len + pad];
            own[pad..pad + m].copy_from_slice(&tpl.real);
            let e = self.matched_envelope(&own, tpl, (len + pad).next_power_of_two());
            self.models.insert(key, e[pad..].to_vec());
        }
        // Borrowed, not copied (a copy was ~400 KB per chirp at 48 kHz).
        let model = self.models.get(&key)?;
        let (pd, vd) = peak_in(&env, 0, 2 * pad + 1)?;
        let shift = pd.round() as usize;
        let shifted: Vec<f64> = (0..env.len())
            .map(|i| i.checked_sub(shift).map_or(0.0, |j| model.get(j).copied().unwrap_or(0.0)))
            .collect();
        let lo = (pd + lim.min_delta_d_m / a * fs).ceil() as usize;
        let hi = ((pd + lim.max_delta_d_m / a * fs).floor() as usize).min(env.len());
        if lo + 3 >= hi {
            return None;
        }
        let floor = 6.0 * median_of(&env[lo..hi]);
        let masked = above_direct(&env, &shifted, vd / model[0].max(1e-30), DIRECT_MARGIN, lo, hi);
        let i = first_strong_peak(&masked, lo, hi, 0.3, floor)?;
        let (l, c, r) = (env[i - 1], env[i], env[i + 1]);
        let pr = i as f64 + parabolic_offset(l, c, r);
        let dt = (pr - pd) / fs;
        Some(Estimate { delta_f_hz: dt * tpl.rate_abs(), delta_d_m: a * dt, relative_level: c / vd.max(1e-30) })
    }

    /// Magnitude of the dechirped spectrum of `seg` (length m), re-indexed so
    /// that index `DECHIRP_OFF` is 0 Hz and reflections lie at higher indices.
    fn dechirp_spectrum(&mut self, seg: &[f32], tpl: &ChirpTemplate, kmax: usize) -> Vec<f64> {
        let m = tpl.len();
        let nfft = m.next_power_of_two();
        let w = hann(m);
        let mut buf = vec![Complex32::new(0.0, 0.0); nfft];
        for i in 0..m.min(seg.len()) {
            buf[i] = tpl.mix[i] * (seg[i] * w[i]);
        }
        self.cache.forward(&mut buf);
        let down = tpl.direction() > 0.0;
        (0..kmax.min(nfft / 2))
            .map(|j| {
                let f = j as isize - DECHIRP_OFF as isize;
                let f = if down { f } else { -f };
                f64::from(buf[f.rem_euclid(nfft as isize) as usize].norm())
            })
            .collect()
    }

    fn dechirp(&mut self, x: &[f32], onset: usize, tpl: &ChirpTemplate, lim: &RangeLimits) -> Option<Estimate> {
        let fs = tpl.sample_rate_hz;
        let a = lim.speed_of_sound_mps;
        let m = tpl.len();
        let seg = x.get(onset..onset + m)?;
        let nfft = m.next_power_of_two();
        let bin_hz = fs / nfft as f64;
        let rate = tpl.rate_abs();
        let kmax = ((rate * lim.max_delta_d_m / a) / bin_hz).ceil() as usize + DECHIRP_OFF + 2;
        let v = self.dechirp_spectrum(seg, tpl, kmax);
        let model = match self.models.get(&(Method::Dechirp, m, kmax)) {
            Some(v) => v.clone(),
            None => {
                let own = tpl.real.clone();
                let v = self.dechirp_spectrum(&own, tpl, kmax);
                self.models.insert((Method::Dechirp, m, kmax), v.clone());
                v
            }
        };
        let (pd, vd) = peak_in(&v, DECHIRP_OFF - 4, DECHIRP_OFF + 5)?;
        let lo = (pd + (rate * lim.min_delta_d_m / a) / bin_hz).ceil() as usize;
        if lo + 3 >= v.len() {
            return None;
        }
        let floor = 6.0 * median_of(&v[lo..]);
        let masked = above_direct(&v, &model, vd / model[DECHIRP_OFF].max(1e-30), DIRECT_MARGIN, lo, v.len());
        let i = first_strong_peak(&masked, lo, v.len(), 0.3, floor)?;
        let (pr, vr) = peak_in(&v, i - 1, i + 2)?;
        let delta_f_hz = (pr - pd) * bin_hz;
        Some(Estimate { delta_f_hz, delta_d_m: a * delta_f_hz / rate, relative_level: vr / vd.max(1e-30) })
    }
}

/// Whether the gap method subtracts the direct sound before picking the
/// reflected peak (see [`direct_residual`]).
const SUBTRACT_DIRECT: bool = true;

/// The template at offsets `off − 1`, `off`, `off + 1`, `frame` samples each
/// (the direct sound's regressors), or `None` at the template's edges.
fn direct_regressors(tpl: &ChirpTemplate, off: usize, frame: usize) -> Option<Vec<&[f32]>> {
    let base = off.checked_sub(1)?;
    (0..3).map(|k| tpl.real.get(base + k..base + k + frame)).collect()
}

/// The three regressors of [`direct_residual`] for template offset `off`
/// (`tpl.real[off−1+k ..]`, k = 0, 1, 2) and their Gram matrix; `None` at
/// the template's edges. The Gram matrix depends only on the template, so
/// [`Ranger`] computes it once per frame position.
fn direct_gram(tpl: &ChirpTemplate, off: usize, frame: usize) -> Option<[[f64; 3]; 3]> {
    let regs = direct_regressors(tpl, off, frame)?;
    let mut g = [[0.0f64; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            g[i][j] = dot_f64(regs[i], regs[j]);
        }
    }
    Some(g)
}

fn dot_f64(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| f64::from(*x) * f64::from(*y)).sum::<f64>()
}

/// `seg` minus its least-squares fit by the template's frame
/// `tpl.real[off−1+k ..]`, k = 0, 1, 2 (three one-sample shifts absorb the
/// direct arrival's sub-sample onset error), `g` their Gram matrix
/// ([`direct_gram`]). `None` at the template's edges.
fn direct_residual(seg: &[f32], tpl: &ChirpTemplate, off: usize, frame: usize, g: &[[f64; 3]; 3]) -> Option<Vec<f32>> {
    let regs = direct_regressors(tpl, off, frame)?;
    let mut r = [0.0f64; 3];
    for i in 0..3 {
        r[i] = dot_f64(regs[i], seg);
    }
    let c = crate::filter::solve_linear(g.iter().map(|row| row.to_vec()).collect(), r.to_vec())?;
    Some(
        (0..frame)
            .map(|n| {
                let fit: f64 = (0..3).map(|k| c[k] * f64::from(regs[k][n])).sum();
                (f64::from(seg[n]) - fit) as f32
            })
            .collect(),
    )
}

/// Index of 0 Hz in [`Ranger::dechirp_spectrum`]'s output.
const DECHIRP_OFF: usize = 8;

/// Perpendicular distance from the speaker to a flat wall, from Δd.
///
/// The wall is the line `{p : (p − S)·n = h}`, `n` the unit vector from the
/// speaker toward the wall. The image of S is `S + 2h·n`, and the reflected
/// path is `|S + 2h·n − M| = D + Δd`; solving the quadratic in h:
/// `h = (n·v + sqrt((n·v)² + (D+Δd)² − D²)) / 2` with `v = M − S`.
pub fn wall_distance_m(speaker: Point, mic: Point, wall_normal: Point, delta_d_m: f64) -> Option<f64> {
    let n = wall_normal.normalized();
    if !n.is_finite() || !delta_d_m.is_finite() || delta_d_m < 0.0 {
        return None;
    }
    let v = mic - speaker;
    let d = v.norm();
    let nv = n.dot(v);
    let disc = nv * nv + (d + delta_d_m).powi(2) - d * d;
    (disc >= 0.0).then(|| 0.5 * (nv + disc.sqrt()))
}

/// Path difference Δd that a wall at perpendicular distance `h` produces
/// (the inverse of [`wall_distance_m`]).
pub fn delta_d_for_wall(speaker: Point, mic: Point, wall_normal: Point, h_m: f64) -> f64 {
    let n = wall_normal.normalized();
    let image = speaker + n * (2.0 * h_m);
    image.dist(mic) - speaker.dist(mic)
}

#[cfg(test)]
mod tests {

    /// One engine ranging chirps of three templates of the same length (so
    /// the same FFT sizes; two of them with one description) in turn gives
    /// what a fresh engine gives for each: its cached spectra and
    /// direct-path models are the current template's. With the caches keyed
    /// by size only, the second template's matched filter used the first
    /// one's spectrum.
    #[test]
    fn an_engine_ranges_another_template_as_a_fresh_one() {
        let fs = 16_000.0;
        let tpls = [(6000.0, 1000.0), (1000.0, 7000.0)]
            .map(|(f0, f1)| ChirpTemplate::new(chirpmap_core::LinearChirp::new(f0, f1, 0.25).unwrap(), fs).unwrap());
        let lim = RangeLimits::for_chirp(0.25, 343.0);
        let onset = 800;
        // The direct sound and an echo 3.1 m longer, at half its amplitude.
        let delay = (3.1 / 343.0 * fs).round() as usize;
        let signal = |tpl: &ChirpTemplate| {
            let mut x = vec![0.0f32; onset + tpl.len() + delay + 2000];
            for (i, v) in tpl.real.iter().enumerate() {
                x[onset + i] += v;
                x[onset + delay + i] += 0.5 * v;
            }
            x
        };
        // A third with the first one's description and length but other
        // samples (a sweep 2 % faster, as a Doppler-scaled template has).
        let mut scaled = tpls[0].clone();
        let fast = ChirpTemplate::new(chirpmap_core::LinearChirp::new(6120.0, 1020.0, 0.25).unwrap(), fs).unwrap();
        scaled.real.clone_from(&fast.real);
        scaled.mix.clone_from(&fast.mix);
        let tpls = [tpls[0].clone(), tpls[1].clone(), scaled];
        let mut reused = Ranger::new();
        for round in 0..2 {
            for tpl in &tpls {
                let x = signal(tpl);
                let mut fresh = Ranger::new();
                for m in Method::ALL {
                    let want = fresh.estimate(m, &x, onset, tpl, &lim);
                    assert!(want.is_some(), "{m:?}: the echo is found");
                    let got = reused.estimate(m, &x, onset, tpl, &lim);
                    assert_eq!(got, want, "round {round}, {:?}, {m:?}", tpl.chirp);
                }
            }
        }
    }

    /// The matched envelope from a real-input FFT against the complex-FFT
    /// path it replaced (the oracle: the segment as complex values, the
    /// analytic spectrum built over all n bins, `norm` per lag), on chirps
    /// with an echo and noise, for segment lengths below, at and above a
    /// power of two. The two differ by f32 rounding only: ≤ 1e-5 of the peak
    /// for a mid-band chirp, ≤ 1e-6 for a full-band one over a DC offset,
    /// where doubling bin 0 or bin n/2 by mistake moves the envelope by
    /// 3e-4 or 3e-6 of the peak (both checked to fail).
    #[test]
    fn real_input_envelope_is_the_complex_paths() {
        fn oracle(seg: &[f32], tpl: &ChirpTemplate, nfft: usize) -> Vec<f64> {
            let mut cache = FftCache::default();
            let h = tpl.conj_spectrum(&mut cache, nfft);
            let mut buf: Vec<Complex32> = seg.iter().take(nfft).map(|v| Complex32::new(*v, 0.0)).collect();
            buf.resize(nfft, Complex32::new(0.0, 0.0));
            cache.forward(&mut buf);
            let half = nfft / 2;
            for (k, (b, hh)) in buf.iter_mut().zip(&h).enumerate() {
                *b = match k {
                    0 => *b * hh,
                    k if k < half => *b * hh * 2.0,
                    k if k == half => *b * hh,
                    _ => Complex32::new(0.0, 0.0),
                };
            }
            cache.inverse(&mut buf);
            let n_lags = (seg.len() + 1).saturating_sub(tpl.len()).min(nfft);
            buf[..n_lags].iter().map(|c| f64::from(c.norm())).collect()
        }
        let mut next = crate::test_rng::xorshift(11);
        let mut ranger = Ranger::new();
        // A mid-band chirp, and a full-band one (down to 5 Hz and up to
        // 7.99 kHz of 8 kHz) over a DC offset, whose spectra reach the edge
        // bins 0 and n/2 that the analytic spectrum does not double.
        let cases = [((6000.0, 1000.0), 0.0, 1e-5), ((5.0, 7990.0), 0.2, 1e-6)];
        for (((f0, f1), dc, tol), extra) in cases.into_iter().flat_map(|c| [200usize, 512 - 320, 700].map(|e| (c, e))) {
            let chirp = chirpmap_core::LinearChirp::new(f0, f1, 0.02).unwrap();
            let tpl = ChirpTemplate::new(chirp, 16_000.0).unwrap();
            let m = tpl.len();
            let len = m + extra;
            let mut seg: Vec<f32> =
                (0..len).map(|_| (next() % 2001) as f32 / 1000.0 - 1.0).map(|v| 0.01 * v + dc).collect();
            for (i, v) in tpl.real.iter().enumerate() {
                seg[i + 20] += v;
                if let Some(s) = seg.get_mut(i + 90) {
                    *s += 0.3 * v;
                }
            }
            let nfft = len.next_power_of_two();
            ranger.use_template(&tpl);
            let got = ranger.matched_envelope(&seg, &tpl, nfft);
            let want = oracle(&seg, &tpl, nfft);
            assert_eq!(got.len(), want.len(), "segment of {len}");
            let peak = want.iter().copied().fold(0.0, f64::max);
            assert!(peak > 0.0);
            let worst = got.iter().zip(&want).map(|(g, w)| (g - w).abs()).fold(0.0, f64::max);
            assert!(worst <= tol * peak, "{f0}-{f1} Hz, segment of {len}: worst difference {worst} of peak {peak}");
            // The echo is found where the oracle finds it.
            let arg = |v: &[f64]| v.iter().enumerate().skip(40).max_by(|a, b| a.1.total_cmp(b.1)).map(|p| p.0);
            assert_eq!(arg(&got), arg(&want));
        }
    }

    /// The model widened by pairwise maxima gives the sliding fold's mask
    /// (the definition, kept here as the oracle), with NaN, zeros, a model
    /// shorter or longer than the data and every window position.
    #[test]
    fn above_direct_matches_the_sliding_fold() {
        fn oracle(v: &[f64], model: &[f64], scale: f64, ratio: f64, lo: usize, hi: usize) -> Vec<f64> {
            let at = |i: usize| model.get(i).copied().unwrap_or(0.0);
            let mut out = vec![0.0; v.len()];
            for i in lo..hi.min(v.len()) {
                let m = (i.saturating_sub(MODEL_SPREAD)..=i + MODEL_SPREAD).map(at).fold(0.0, f64::max);
                if v[i] >= ratio * scale * m {
                    out[i] = v[i];
                }
            }
            out
        }
        let mut next = crate::test_rng::xorshift(7);
        for case in 0..400 {
            let n = (next() % 40) as usize;
            let n_model = (next() % 45) as usize;
            let mut val = |_| match next() % 10 {
                0 => 0.0,
                1 => f64::NAN,
                _ => (next() % 1000) as f64 / 100.0,
            };
            let v: Vec<f64> = (0..n).map(&mut val).collect();
            let model: Vec<f64> = (0..n_model).map(&mut val).collect();
            let (lo, hi) = ((next() % 45) as usize, (next() % 50) as usize);
            let got = above_direct(&v, &model, 0.7, 3.0, lo, hi);
            let want = oracle(&v, &model, 0.7, 3.0, lo, hi);
            assert_eq!(got.len(), want.len());
            assert!(got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()), "case {case}: {got:?} vs {want:?}");
        }
    }
    use super::*;

    #[test]
    fn wall_distance_inverts_geometry() {
        let s = Point::new(0.0, 0.0);
        let m = Point::new(2.0, 1.0);
        let n = Point::new(0.0, -1.0);
        for h in [3.0, 5.5, 10.0] {
            let dd = delta_d_for_wall(s, m, n, h);
            // Hand check for h = 3: image (0,-6), |(-2,-7)| = 7.2801, D = 2.2361.
            if h == 3.0 {
                assert!((dd - (53f64.sqrt() - 5f64.sqrt())).abs() < 1e-12);
            }
            assert!((wall_distance_m(s, m, n, dd).unwrap() - h).abs() < 1e-9);
        }
    }
}

/// One detected chirp and its estimate (if a reflection was found).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChirpResult {
    /// Index of the chirp among the detections (0-based).
    pub index: usize,
    /// Onset of its direct arrival in the recording (s).
    pub onset_s: f64,
    /// Δd estimate, `None` when no reflection stood out.
    pub estimate: Option<Estimate>,
}

/// A detected chirp and one estimate per requested method.
pub type RangedChirp = (crate::detect::Detection, Vec<Option<Estimate>>);

/// Detects every chirp in the high-passed signal `x` and ranges each one
/// with `method` (the paper's per-chirp processing, §IV.A).
pub fn range_signal(
    x: &[f32],
    tpl: &ChirpTemplate,
    methods: &[Method],
    lim: &RangeLimits,
) -> Result<Vec<RangedChirp>, crate::error::AudioError> {
    let mut ranger = Ranger::new();
    let dets = crate::detect::detect_chirps(x, tpl, &mut ranger.cache, lim.max_delta_d_m / lim.speed_of_sound_mps)?;
    Ok(dets
        .into_iter()
        .map(|d| {
            let est = methods.iter().map(|&m| ranger.estimate(m, x, d.onset_sample, tpl, lim)).collect();
            (d, est)
        })
        .collect())
}
