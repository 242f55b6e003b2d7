//! Doppler-corrected ranging for moving listeners (issue 11).
//!
//! A listener moving at `v` hears path `i` (length `rᵢ(t)`) as
//! `s(t − rᵢ(t)/a)`: every path's sweep is time-scaled by `1 − ṙᵢ/a`, so the
//! heard frequency is `f(τᵢ)·(1 − ṙᵢ/a)` with `τᵢ = t − rᵢ/a` the emission
//! time. With a linear chirp of rate `k`, the frequency gap of the paper's
//! Eq. 2 then reads `Δd + (f/k)·Δḋ` instead of `Δd` (range–Doppler coupling,
//! paper §VI; Δḋ = Ṙ − Ḋ is the rate of the path difference). This module:
//!
//! 1. **Detects** chirps with a small bank of Doppler-scaled templates
//!    (`s(σt)`, σ = 1 − Ḋ/a over the radial speeds the poses show, 0.5 m/s
//!    apart), so a listener at 10 m/s (the paper's speed) loses no chirp: an
//!    unscaled template's normalised correlation falls to 0.2 at 2 m/s and
//!    0.1 at 10 m/s (measured for the 0.25 s 10 → 0.2 kHz chirp).
//! 2. **Dechirps each frame along the direct path**: the reference is the
//!    sweep's phase at the direct sound's exact emission time
//!    `τ_D(t) = t − D(t)/a − E` (D from the poses, E from the detection), so
//!    the direct sound is a tone at 0 Hz whatever the listener's speed and a
//!    reflection a tone at `f_R − f_D`, the heard frequencies' difference.
//! 3. **Inverts the heard frequencies exactly**: `f(τ_D) = f_D/(1 − Ḋ/a)`,
//!    `f(τ_R) = f_R/(1 − (Ḋ + Δḋ)/a)`, `Δd = a·(τ_D − τ_R)` through the
//!    sweep's inverse (any monotonic sweep). The direct path's rate Ḋ is
//!    known exactly from the poses; the reflected path's rate is Ḋ + Δḋ.
//! 4. **Estimates Δḋ from the echo's own track** and iterates: over a group
//!    of frames the corrected Δd must follow `Δd₀ + Δḋ·(t − t₀)`. Linearised
//!    about the current Δḋ′, `Δdᵢ(Δḋ) ≈ mᵢ + hᵢ·(Δḋ − Δḋ′)` with
//!    `hᵢ = ∂Δdᵢ/∂Δḋ ≈ −fᵢ/kᵢ`, so `yᵢ = mᵢ − hᵢΔḋ′` is linear in
//!    `gᵢ = tᵢ − t₀ − hᵢ` with slope Δḋ; the median of the pairwise slopes
//!    (Theil 1950, Sen 1968) is robust to a stray frame. Within one linear
//!    sweep `g` advances twice as fast as `t` (the gap track's slope is 2Δḋ).
//!    With alternating up and down sweeps, `h` changes sign between the two
//!    chirps of a pair and each cross pair gives Δḋ (and then Δd) in closed
//!    form: `Δḋ = (m_up − m_down)/(g_up − g_down)`.
//! 5. Frames whose corrected Δd strays from their group's line by more than
//!    [`TRACK_GATE_M`] (or 5 robust σ) are dropped as spurious: within a
//!    quarter second a real reflector's Δd moves along a line.

use crate::detect::{ChirpTemplate, DEFAULT_TAPER_S, Detection, detect_chirps, taper_gain};
use crate::error::AudioError;
use crate::ranging::{RangeLimits, above_direct, median_of, strong_peaks};
use crate::spectrum::{FftCache, hann, peak_in};
use chirpmap_core::error::Num;
use chirpmap_core::{Echo, LinearChirp, Point, Sweep};
use rustfft::num_complex::Complex32;

/// Spacing of the template bank in radial speed (m/s). An unscaled 0.25 s
/// 10 → 0.2 kHz template keeps a normalised correlation of 0.62 with a chirp
/// heard at 0.25 m/s (measured; 0.45 at 0.5 m/s, 0.28 at 1 m/s), so a bank
/// 0.5 m/s apart never falls below about 0.6 of the matched peak.
pub const BANK_STEP_MPS: f64 = 0.5;

/// Largest radial speed the bank covers (m/s): well above the paper's 10 m/s.
pub const MAX_RADIAL_SPEED_MPS: f64 = 40.0;

/// Frames whose corrected Δd is further than this from their group's robust
/// line (and 5 robust σ) are dropped as spurious (ours).
pub const TRACK_GATE_M: f64 = 0.15;

/// Fewest frames a group needs for its own Δḋ estimate; smaller groups take
/// the nearest group's.
pub const MIN_GROUP_FRAMES: usize = 5;

/// A detected chirp of a moving listener's recording.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovingDetection {
    /// The matched-filter detection of the best-matching template.
    pub detection: Detection,
    /// Index of the chirp's sweep in the pattern's cycle (down/up).
    pub sweep: usize,
    /// Time scale σ = 1 − Ḋ/a of the best-matching template.
    pub scale: f64,
}

/// A template of `sweep` heard time-scaled by `scale` (σ = 1 − Ḋ/a):
/// `taper(σt)·sin(2πφ(σt))` for `t < T/σ`. `descriptor` names the band and
/// duration in messages (detection uses only the samples).
pub fn scaled_template(
    sweep: &dyn Sweep,
    descriptor: LinearChirp,
    sample_rate_hz: f64,
    scale: f64,
) -> Result<ChirpTemplate, AudioError> {
    if !(scale.is_finite() && scale > 0.5 && scale < 1.5) {
        return Err(AudioError::InvalidParam {
            field: "doppler scale",
            reason: format!("{} is not near 1", Num(scale)),
        });
    }
    let mut tpl = ChirpTemplate::new(descriptor, sample_rate_hz)?;
    let t_s = sweep.duration_s();
    let n = ((t_s / scale) * sample_rate_hz).round() as usize;
    tpl.real = (0..n)
        .map(|i| {
            let tau = scale * i as f64 / sample_rate_hz;
            let ph = sweep.phase_cycles(tau);
            (taper_gain(tau, t_s, DEFAULT_TAPER_S) * (std::f64::consts::TAU * (ph - ph.floor())).sin()) as f32
        })
        .collect();
    tpl.mix = Vec::new();
    Ok(tpl)
}

/// Smallest and largest rate of the direct path length Ḋ (m/s) over a pose
/// track (`(t, position)` rows), for sizing the template bank.
pub fn direct_rate_range(poses: &[(f64, Point)], speaker: Point) -> (f64, f64) {
    let mut lo = 0.0f64;
    let mut hi = 0.0f64;
    for w in poses.windows(2) {
        let dt = w[1].0 - w[0].0;
        if dt > 0.0 {
            let r = (speaker.dist(w[1].1) - speaker.dist(w[0].1)) / dt;
            if r.is_finite() {
                lo = lo.min(r);
                hi = hi.max(r);
            }
        }
    }
    (lo.max(-MAX_RADIAL_SPEED_MPS), hi.min(MAX_RADIAL_SPEED_MPS))
}

/// The bank's time scales σ = 1 − Ḋ/a for Ḋ at the multiples of
/// [`BANK_STEP_MPS`] that enclose `rate_range` (m/s) and 0, so every rate in
/// the range is within half a step of a template (a static listener gets the
/// unscaled template alone).
pub fn bank_scales(rate_range: (f64, f64), speed_of_sound_mps: f64) -> Vec<f64> {
    let lo = rate_range.0.clamp(-MAX_RADIAL_SPEED_MPS, 0.0);
    let hi = rate_range.1.clamp(0.0, MAX_RADIAL_SPEED_MPS);
    let k_lo = (lo / BANK_STEP_MPS).floor() as i64;
    let k_hi = (hi / BANK_STEP_MPS).ceil() as i64;
    (k_lo..=k_hi).map(|k| 1.0 - k as f64 * BANK_STEP_MPS / speed_of_sound_mps).collect()
}

/// Detects the chirps of every sweep in `sweeps` (the pattern's cycle) with
/// a template bank over `scales`; overlapping detections (less than half a
/// chirp apart) keep the best normalised correlation. Errors only when no
/// template finds a chirp (the error of the unscaled first sweep).
pub fn detect_moving(
    x: &[f32],
    sample_rate_hz: f64,
    sweeps: &[&dyn Sweep],
    scales: &[f64],
    cache: &mut FftCache,
    max_echo_delay_s: f64,
) -> Result<Vec<MovingDetection>, AudioError> {
    let mut all = Vec::new();
    let mut first_err = None;
    for (si, sweep) in sweeps.iter().enumerate() {
        let descr = LinearChirp::new(sweep.f_start_hz(), sweep.f_end_hz(), sweep.duration_s())?;
        for &scale in scales {
            let tpl = scaled_template(*sweep, descr, sample_rate_hz, scale)?;
            match detect_chirps(x, &tpl, cache, max_echo_delay_s) {
                Ok(d) => all.extend(d.into_iter().map(|detection| MovingDetection { detection, sweep: si, scale })),
                Err(e) => {
                    if first_err.is_none() || (scale - 1.0).abs() < 1e-12 && si == 0 {
                        first_err = Some(e);
                    }
                }
            }
        }
    }
    if all.is_empty() {
        return Err(first_err.unwrap_or(AudioError::NoChirp { ratio: 0.0, need: crate::detect::MIN_PEAK_RATIO }));
    }
    let half = sweeps.iter().map(|s| s.duration_s()).fold(f64::INFINITY, f64::min) * sample_rate_hz * 0.5;
    all.sort_by(|a, b| b.detection.ncc.total_cmp(&a.detection.ncc));
    let mut kept: Vec<MovingDetection> = Vec::new();
    for d in all {
        let clash =
            kept.iter().any(|k| (k.detection.onset_sample as f64 - d.detection.onset_sample as f64).abs() < half);
        if !clash {
            kept.push(d);
        }
    }
    kept.sort_by_key(|d| d.detection.onset_sample);
    Ok(kept)
}

/// One echo of a moving listener, with the rate of its path difference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovingEcho {
    /// The echo (Δd corrected for Doppler), at the listener's pose mid-frame.
    pub echo: Echo,
    /// Estimated rate of the path difference Δḋ = Ṙ − Ḋ (m/s); `None` when
    /// the method does not estimate it.
    pub delta_d_rate_mps: Option<f64>,
    /// Index of the chirp among the detections.
    pub chirp: usize,
}

/// How [`doppler_echoes`] cuts the chirps into frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DopplerParams {
    /// Time between measurements (s, emission time of the direct sound).
    pub period_s: f64,
    /// Frame length (s); `None`: 4·sqrt(T/B), the dechirp method's.
    pub frame_s: Option<f64>,
    /// Speaker position (m).
    pub speaker: Point,
    /// Listener id written into the echoes.
    pub listener_id: u32,
    /// Most echoes taken from one frame, earliest first (1: the first strong
    /// reflection only, the paper's §IV measurement). Several echoes per
    /// frame are tracked across the chirp's frames, each track with its own
    /// Δḋ: in a room every wall moves at its own rate.
    pub echoes_per_frame: usize,
}

/// The frame length (s) when none is given: 4·sqrt(T/B), the dechirp
/// method's, for one echo per frame or a non-linear sweep; twice that (at
/// most a quarter of the chirp, at least the former) for several echoes of a
/// linear one. A Hann frame of length F resolves beats 2/F apart,
/// reflections 2a/(|k|F) apart in Δd: 0.87 m at 20 ms and 0.43 m at 40 ms for
/// the 0.25 s 10 → 0.2 kHz chirp, and a neighbour's main lobe pulls each
/// peak. Measured on a synthesized walk in a room with a pillar
/// (EXPERIMENTS.md, session 23): the echoes within 2 cm of their true Δd
/// went from 35–51 % per wall at 20 ms to 74–77 % at 40 ms, and the four
/// walls from 0–2 of 4 found to 4. An exponential sweep's local rate varies
/// along it, and the longer frame smeared it: on the moving wall at 1 m/s,
/// median error 1.9 cm at 20 ms, 7.1 cm at 40 ms (review, session 23).
pub fn default_frame_s(chirp_s: f64, band_hz: f64, echoes_per_frame: usize, linear: bool) -> f64 {
    let single = 4.0 * (chirp_s / band_hz).sqrt();
    if echoes_per_frame <= 1 || !linear { single } else { (2.0 * single).min(0.25 * chirp_s).max(single) }
}

/// Whether `sweep`'s frequency is linear in time (at a quarter, half and
/// three quarters of its duration, to 10⁻⁹ of its band).
fn is_linear(sweep: &dyn Sweep) -> bool {
    let (t, f0, f1) = (sweep.duration_s(), sweep.f_start_hz(), sweep.f_end_hz());
    let tol = 1e-9 * (f1 - f0).abs();
    [0.25, 0.5, 0.75].iter().all(|&u| sweep.freq_at(u * t).is_some_and(|f| (f - (f0 + u * (f1 - f0))).abs() <= tol))
}

/// With several echoes per frame, a peak counts from this fraction of the
/// frame's strongest (one echo per frame: 0.3, the first strong reflection).
/// In a room the walls and their corners are louder than a pillar: at 0.3
/// the pillar's echo was missed in 310 of 1 249 frames of a walk round it,
/// each of which carved free space through it, and with corner echoes it
/// was lost (EXPERIMENTS.md, session 23). At 0.1 it was found and the
/// moving-wall benchmark's doppler rows stayed the same.
pub const MULTI_PEAK_FRAC: f64 = 0.1;

/// Largest [`DopplerParams::echoes_per_frame`]: a frame's spectrum resolves
/// a few tens of reflections at most (a 20 ms frame separates beats 100 Hz apart).
pub const MAX_ECHOES_PER_FRAME: usize = 64;

/// One frame's measurement before the Doppler correction.
#[derive(Debug, Clone, Copy)]
struct FrameMeas {
    chirp: usize,
    t_mid_s: f64,
    pos: Point,
    /// Heard direct and reflected frequencies (Hz).
    f_direct_hz: f64,
    f_reflected_hz: f64,
    /// Direct path rate Ḋ (m/s) at mid-frame, from the poses.
    d_rate_mps: f64,
}

/// Index of 0 Hz in a frame's re-indexed spectrum.
const OFF: usize = 8;

/// `Δd` of one frame for a path-difference rate `dd_rate` (m/s): the heard
/// frequencies mapped back to emission times through the sweep's inverse
/// (extrapolated linearly beyond the band for linear sweeps).
fn frame_delta_d(m: &FrameMeas, sweep: &dyn Sweep, a: f64, dd_rate: f64) -> Option<f64> {
    let sd = 1.0 - m.d_rate_mps / a;
    let sr = 1.0 - (m.d_rate_mps + dd_rate) / a;
    if sd <= 0.0 || sr <= 0.0 {
        return None;
    }
    let (fd, fr) = (m.f_direct_hz / sd, m.f_reflected_hz / sr);
    let t_of = |f: f64| {
        sweep.time_of(f).or_else(|| {
            // Linear extrapolation from the nearer end (a reflection heard
            // just beyond the band near the sweep's ends).
            let t_end = sweep.duration_s();
            let (f0, f1) = (sweep.f_start_hz(), sweep.f_end_hz());
            let slope = (f1 - f0) / t_end;
            Some(if (f - f0).abs() < (f - f1).abs() { (f - f0) / slope } else { t_end + (f - f1) / slope })
        })
    };
    Some(a * (t_of(fd)? - t_of(fr)?))
}

/// Most points [`theil_sen`] pairs up: a larger group is thinned to this many
/// evenly spaced points. The pairs' slopes are stored, so memory and time grow
/// with the square of the points: `--period-ms 0.05` on a 1 s chirp gave 20 000
/// frames and a 2 GB allocation. 2048 points (at most 2.1 million pairs, 17 MB)
/// cover every group at the default 10 ms period up to 20 s chirps (6.8 s with
/// up/down partners), whose slopes stay exactly those of all pairs.
pub const MAX_THEIL_SEN_POINTS: usize = 2048;

/// Theil–Sen slope of `(g, y)` over the pairs `ok(i, j)` with `|g_j − g_i|`
/// at least `min_dg`; `None` without such a pair. Beyond
/// [`MAX_THEIL_SEN_POINTS`] points only that many evenly spaced ones are paired.
fn theil_sen(g: &[f64], y: &[f64], min_dg: f64, ok: &dyn Fn(usize, usize) -> bool) -> Option<f64> {
    let n = g.len();
    let picked: Vec<usize> = if n <= MAX_THEIL_SEN_POINTS {
        (0..n).collect()
    } else {
        (0..MAX_THEIL_SEN_POINTS).map(|k| k * n / MAX_THEIL_SEN_POINTS).collect()
    };
    let mut s = Vec::new();
    for (a, &i) in picked.iter().enumerate() {
        for &j in &picked[a + 1..] {
            let dg = g[j] - g[i];
            if dg.abs() >= min_dg && ok(i, j) {
                s.push((y[j] - y[i]) / dg);
            }
        }
    }
    (!s.is_empty()).then(|| median_of(&s))
}

/// Echoes of every frame of every detected chirp, Doppler-corrected (see the
/// module docs). `sweeps` is the pattern's cycle (as in [`detect_moving`]),
/// `pose_at(t)` the listener's position at recording time `t` (s).
pub fn doppler_echoes(
    x: &[f32],
    sample_rate_hz: f64,
    sweeps: &[&dyn Sweep],
    lim: &RangeLimits,
    dets: &[MovingDetection],
    pose_at: &dyn Fn(f64) -> Option<Point>,
    p: &DopplerParams,
) -> Result<Vec<MovingEcho>, AudioError> {
    let fs = sample_rate_hz;
    let a = lim.speed_of_sound_mps;
    let bad = |field: &'static str, reason: String| AudioError::InvalidParam { field, reason };
    if !(1..=MAX_ECHOES_PER_FRAME).contains(&p.echoes_per_frame) {
        return Err(bad(
            "echoes per frame",
            format!("must be in 1..={MAX_ECHOES_PER_FRAME}, got {}", p.echoes_per_frame),
        ));
    }
    if !(p.period_s.is_finite() && p.period_s * fs >= 1.0) {
        return Err(bad("period", format!("must be at least one sample, got {} s", Num(p.period_s))));
    }
    let Some(first) = sweeps.first() else { return Err(bad("chirp", "no sweep given".into())) };
    let t_chirp = first.duration_s();
    let band = (first.f_start_hz() - first.f_end_hz()).abs();
    let frame = match p.frame_s {
        Some(s) => (s * fs).round(),
        None => (default_frame_s(t_chirp, band, p.echoes_per_frame, sweeps.iter().all(|s| is_linear(*s))) * fs).round(),
    };
    let n_chirp = t_chirp * fs;
    if !(frame >= 16.0 && frame < n_chirp) {
        return Err(bad("frame", format!("{} samples: must be >= 16 and shorter than the chirp", Num(frame))));
    }
    let frame = frame as usize;
    let planned = (t_chirp / p.period_s).ceil() * dets.len() as f64;
    if planned > crate::frames::MAX_MEASUREMENTS as f64 {
        return Err(bad("period", format!("about {} measurements exceed the cap", Num(planned))));
    }
    // Each frame holds up to `echoes_per_frame` echoes in memory until the
    // tracks are corrected: the same cap on their number.
    if planned * p.echoes_per_frame as f64 > crate::frames::MAX_MEASUREMENTS as f64 {
        return Err(bad(
            "echoes per frame",
            format!(
                "{} per frame over about {} measurements exceed the cap of {} echoes",
                p.echoes_per_frame,
                Num(planned),
                crate::frames::MAX_MEASUREMENTS
            ),
        ));
    }
    let nfft = (frame * 4).next_power_of_two();
    let bin_hz = fs / nfft as f64;
    let win = hann(frame);
    // Model of the direct sound alone: the window's own spectrum at 0 Hz.
    let model = {
        let mut cache = FftCache::default();
        let mut buf = vec![Complex32::new(0.0, 0.0); nfft];
        for (b, w) in buf.iter_mut().zip(&win) {
            b.re = *w;
        }
        cache.forward(&mut buf);
        let mut m = vec![0.0f64; nfft / 2];
        for (j, v) in m.iter_mut().enumerate() {
            if j >= OFF {
                *v = f64::from(buf[j - OFF].norm());
            } else {
                *v = f64::from(buf[nfft - (OFF - j)].norm());
            }
        }
        m
    };
    let mut cache = FftCache::default();
    let mut meas: Vec<FrameMeas> = Vec::new();
    let f_max = sweeps.iter().map(|s| s.f_start_hz().max(s.f_end_hz())).fold(0.0, f64::max);
    let mut buf = vec![Complex32::new(0.0, 0.0); nfft];
    for (ci, d) in dets.iter().enumerate() {
        let Some(sweep) = sweeps.get(d.sweep) else { continue };
        let t_on = d.detection.onset_sample as f64 / fs;
        let Some(p_on) = pose_at(t_on) else { continue };
        // Emission start of this chirp on the recorder's clock, refined on
        // the direct path's exact (pose-warped) waveform.
        let e_s = refine_emission(x, fs, *sweep, t_on - p.speaker.dist(p_on) / a, pose_at, p.speaker, a);
        let rate_mid = (sweep.f_end_hz() - sweep.f_start_hz()) / t_chirp;
        let dir = if rate_mid < 0.0 { 1.0 } else { -1.0 };
        // The beat of the furthest reflection, widened by the largest
        // Doppler term f·2v/a at the fastest radial speed.
        let beat_max = rate_mid.abs() * lim.max_delta_d_m / a + f_max * 2.0 * MAX_RADIAL_SPEED_MPS.min(20.0) / a;
        let kmax = ((beat_max / bin_hz).ceil() as usize + OFF + 2).min(nfft / 2);
        // The chirp's analytic signal (negative frequencies removed: the
        // direct sound's mirror at −2f_D would otherwise read as a reflection
        // of an up-sweep's low end), over its reception span and a frame
        // either side, so that the transform's edges stay out of the frames.
        let (z0, z) = {
            let end_s = e_s + t_chirp + p.speaker.dist(pose_at(e_s + t_chirp).unwrap_or(p_on)) / a;
            let s0 = (t_on * fs - 2.0 * frame as f64).max(0.0) as usize;
            let s1 = ((end_s * fs) as usize + 2 * frame).min(x.len());
            if s1 <= s0 + frame {
                continue;
            }
            (s0, analytic(&mut cache, &x[s0..s1]))
        };
        let mut tau0 = 0.0;
        while tau0 + frame as f64 / fs <= t_chirp {
            let this_tau = tau0;
            tau0 += p.period_s;
            // Reception time at which the direct sound emitted at `this_tau` arrives.
            let mut t = e_s + this_tau + p.speaker.dist(p_on) / a;
            let mut ok = true;
            for _ in 0..4 {
                match pose_at(t) {
                    Some(q) => t = e_s + this_tau + p.speaker.dist(q) / a,
                    None => ok = false,
                }
            }
            if !ok {
                continue;
            }
            let n0 = (t * fs).round();
            if n0 < 0.0 || n0 as usize + frame > x.len() {
                continue;
            }
            let n0 = n0 as usize;
            if n0 < z0 || n0 + frame > z0 + z.len() {
                continue;
            }
            let tau_at = |n: usize| -> Option<f64> {
                let tt = n as f64 / fs;
                Some(tt - p.speaker.dist(pose_at(tt)?) / a - e_s)
            };
            let (Some(tau_a), Some(tau_b), Some(tau_m)) = (tau_at(n0), tau_at(n0 + frame), tau_at(n0 + frame / 2))
            else {
                continue;
            };
            // τ_D across the frame: the quadratic through its ends and middle
            // (D(t) is smooth over a frame; per-sample poses cost more than
            // the rest of the frame together).
            let u_m = (frame / 2) as f64 / frame as f64;
            let tau_q = |i: usize| {
                let u = i as f64 / frame as f64;
                tau_a * (u - u_m) * (u - 1.0) / (u_m * 1.0)
                    + tau_m * u * (u - 1.0) / (u_m * (u_m - 1.0))
                    + tau_b * u * (u - u_m) / (1.0 - u_m)
            };
            let good = true;
            for (i, b) in buf.iter_mut().enumerate() {
                if i < frame {
                    let tau = tau_q(i);
                    let ph = sweep.phase_cycles(tau);
                    let (sin, cos) = (std::f64::consts::TAU * (ph - ph.floor())).sin_cos();
                    let mix = Complex32::new(cos as f32, -sin as f32);
                    *b = mix * z[n0 - z0 + i] * win[i];
                } else {
                    *b = Complex32::new(0.0, 0.0);
                }
            }
            if !good {
                continue;
            }
            let sigma_d = (tau_b - tau_a) / (frame as f64 / fs);
            let Some(f_em) = sweep.freq_at(tau_m.clamp(0.0, t_chirp)) else { continue };
            let f_pred = f_em * sigma_d;
            cache.forward(&mut buf);
            let v: Vec<f64> = (0..kmax)
                .map(|j| {
                    let f = (j as isize - OFF as isize) * if dir > 0.0 { 1 } else { -1 };
                    f64::from(buf[f.rem_euclid(nfft as isize) as usize].norm())
                })
                .collect();
            let Some((pd, vd)) = peak_in(&v, OFF - 4, OFF + 5) else { continue };
            let lo = ((pd + (rate_mid.abs() * lim.min_delta_d_m / a) / bin_hz).ceil() as usize).max(OFF + 3);
            // Only beats a reflection of this chirp can make: it left at
            // τ_D − Δd/a ≥ 0 (so Δd ≤ a·τ_D), shifted by at most f·2|v|/a
            // (|Δḋ| ≤ 2|v|, v the listener's speed). Beyond, the band holds
            // only noise (or nothing, below an up-sweep's start), and a
            // floor taken there would let noise through.
            let t_mid0 = (n0 as f64 + 0.5 * frame as f64) / fs;
            let speed = match (pose_at(t_mid0 - 0.005), pose_at(t_mid0 + 0.005)) {
                (Some(q0), Some(q1)) => q0.dist(q1) / 0.01,
                _ => MAX_RADIAL_SPEED_MPS,
            };
            let dd_reach = lim.max_delta_d_m.min(a * tau_b.max(0.0));
            let beat_reach = rate_mid.abs() * dd_reach / a + f_pred * 2.0 * (speed + 0.5) / a;
            let hi = ((pd + beat_reach / bin_hz).ceil() as usize + 2).min(v.len());
            if lo + 3 >= hi {
                continue;
            }
            let floor = 6.0 * median_of(&v[lo..hi]);
            let masked = above_direct(&v, &model, vd / model[OFF].max(1e-30), 3.0, lo, hi);
            let t_mid = (n0 as f64 + 0.5 * frame as f64) / fs;
            let Some(pos) = pose_at(t_mid) else { continue };
            let d_rate = a * (1.0 - sigma_d);
            let frac = if p.echoes_per_frame > 1 { MULTI_PEAK_FRAC } else { 0.3 };
            for i in strong_peaks(&masked, lo, hi, frac, floor, p.echoes_per_frame, 2) {
                let Some((pr, _)) = peak_in(&v, i - 1, i + 2) else { continue };
                meas.push(FrameMeas {
                    chirp: ci,
                    t_mid_s: t_mid,
                    pos,
                    f_direct_hz: f_pred + dir * (pd - OFF as f64) * bin_hz,
                    f_reflected_hz: f_pred + dir * (pr - OFF as f64) * bin_hz,
                    d_rate_mps: d_rate,
                });
            }
        }
    }
    Ok(correct(&meas, sweeps, dets, a, fs, p))
}

/// The analytic signal of `x` (FFT, negative frequencies zeroed, inverse).
fn analytic(cache: &mut FftCache, x: &[f32]) -> Vec<Complex32> {
    let nfft = (2 * x.len()).next_power_of_two();
    let mut buf: Vec<Complex32> = (0..nfft).map(|i| Complex32::new(x.get(i).copied().unwrap_or(0.0), 0.0)).collect();
    cache.forward(&mut buf);
    let scale = 1.0 / nfft as f32;
    for (j, b) in buf.iter_mut().enumerate() {
        *b *= if j == 0 || j == nfft / 2 {
            scale
        } else if j < nfft / 2 {
            2.0 * scale
        } else {
            0.0
        };
    }
    cache.inverse(&mut buf);
    buf.truncate(x.len());
    buf
}

/// Largest correction (s) [`refine_emission`] searches.
const REFINE_S: f64 = 0.004;

/// The chirp's emission start `e_s` (recorder clock) refined by correlating
/// the recording with the direct sound's exact waveform: the sweep at the
/// emission times `t − D(t)/a − e_s`, `D` from the poses. A template of one
/// Doppler scale cannot follow a listener whose radial speed changes within
/// the chirp (passing the speaker), and its range–Doppler coupling shifts
/// the detected onset by up to f·δσ/|k|. Lags within ±[`REFINE_S`], every
/// second one and then the best one's neighbours; the products are summed
/// on every 16th sample (near the match they vary slowly: a lag L leaves a
/// beat of |k|·L, below 160 Hz within ±4 ms for the paper's sweeps).
fn refine_emission(
    x: &[f32],
    fs: f64,
    sweep: &dyn Sweep,
    e_s: f64,
    pose_at: &dyn Fn(f64) -> Option<Point>,
    speaker: Point,
    a: f64,
) -> f64 {
    let t_chirp = sweep.duration_s();
    // Reception span of the direct sound and the model on it.
    let (Some(q0), Some(q1)) = (pose_at(e_s), pose_at(e_s + t_chirp)) else { return e_s };
    let n_a = ((e_s + speaker.dist(q0) / a) * fs).floor();
    let n_b = ((e_s + t_chirp + speaker.dist(q1) / a) * fs).ceil();
    let lmax = (REFINE_S * fs).ceil();
    if n_a - lmax < 0.0 || n_b + lmax >= x.len() as f64 {
        return e_s;
    }
    let (n_a, n_b, lmax) = (n_a as usize, n_b as usize, lmax as i64);
    let mut model = Vec::new();
    for n in (n_a..n_b).step_by(16) {
        let t = n as f64 / fs;
        let Some(q) = pose_at(t) else { continue };
        let tau = t - speaker.dist(q) / a - e_s;
        if !(0.0..=t_chirp).contains(&tau) {
            continue;
        }
        let ph = sweep.phase_cycles(tau);
        let ang = std::f64::consts::TAU * (ph - ph.floor());
        model.push((n, Complex32::new(ang.cos() as f32, -ang.sin() as f32)));
    }
    if model.len() < 16 {
        return e_s;
    }
    let corr = |l: i64| {
        let mut c = Complex32::new(0.0, 0.0);
        for &(n, m) in &model {
            c += m * x[(n as i64 + l) as usize];
        }
        f64::from(c.norm())
    };
    let coarse = (-lmax..=lmax).step_by(2).map(|l| (l, corr(l))).max_by(|a, b| a.1.total_cmp(&b.1));
    let Some((best, _)) = coarse else { return e_s };
    let lo = (best - 3).max(-lmax);
    let env: Vec<f64> = (lo..=(best + 3).min(lmax)).map(corr).collect();
    match peak_in(&env, 1, env.len().saturating_sub(1)) {
        Some((k, _)) => e_s + (k + lo as f64) / fs,
        None => e_s + best as f64 / fs,
    }
}

/// Frames a track may skip (a reflection lost under the noise for a frame
/// or two) and still be continued.
const LINK_MAX_SKIP: f64 = 2.0;

/// The reflections' tracks within one chirp (several echoes per frame): each
/// frame's echoes are linked to the tracks so far by their uncorrected Δd
/// (Δḋ = 0), predicted along each track's last slope, within
/// [`TRACK_GATE_M`], closest pairs first; an echo left over starts a track.
/// Within a linear sweep a reflection's uncorrected Δd moves by 2Δḋ per
/// second (module docs, 4), and |Δḋ| ≤ 2|v|: under 4 cm per 10 ms frame at
/// a walker's 1 m/s, while a 40 ms frame separates reflections about 0.43 m
/// apart in Δd (2a/(|k|F)). A track of one echo has no slope yet: its gate
/// also covers that bound, 4 × the listener's move since (plus 5 cm), or a
/// listener at 8 m/s toward a wall (Δḋ ≈ −16 m/s, 0.31 m per frame) linked
/// no frame and lost the wall (review, session 23).
fn link_tracks(meas: &[FrameMeas], chirp: &[usize], sweep: &dyn Sweep, a: f64, period_s: f64) -> Vec<Vec<usize>> {
    struct Track {
        idx: Vec<usize>,
        t_s: f64,
        d_m: f64,
        slope_mps: f64,
        pos: Point,
    }
    let mut tracks: Vec<Track> = Vec::new();
    let mut k = 0;
    while k < chirp.len() {
        // One frame: the echoes sharing its mid-time (pushed together).
        let t_s = meas[chirp[k]].t_mid_s;
        let pos = meas[chirp[k]].pos;
        let mut end = k;
        while end < chirp.len() && meas[chirp[end]].t_mid_s == t_s {
            end += 1;
        }
        let frame: Vec<(usize, f64)> =
            chirp[k..end].iter().filter_map(|&i| frame_delta_d(&meas[i], sweep, a, 0.0).map(|d| (i, d))).collect();
        k = end;
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (j, tr) in tracks.iter().enumerate() {
            let dt = t_s - tr.t_s;
            if dt > (LINK_MAX_SKIP + 1.5) * period_s {
                continue;
            }
            let pred = tr.d_m + tr.slope_mps * dt;
            let gate = if tr.idx.len() == 1 { TRACK_GATE_M.max(4.0 * pos.dist(tr.pos) + 0.05) } else { TRACK_GATE_M };
            for (q, &(_, d)) in frame.iter().enumerate() {
                let cost = (d - pred).abs();
                if cost <= gate {
                    pairs.push((cost, j, q));
                }
            }
        }
        pairs.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
        let mut track_taken = vec![false; tracks.len()];
        let mut echo_taken = vec![false; frame.len()];
        for (_, j, q) in pairs {
            if track_taken[j] || echo_taken[q] {
                continue;
            }
            track_taken[j] = true;
            echo_taken[q] = true;
            let (i, d) = frame[q];
            let tr = &mut tracks[j];
            tr.slope_mps = (d - tr.d_m) / (t_s - tr.t_s);
            tr.idx.push(i);
            (tr.t_s, tr.d_m, tr.pos) = (t_s, d, pos);
        }
        for (q, &(i, d)) in frame.iter().enumerate() {
            if !echo_taken[q] {
                tracks.push(Track { idx: vec![i], t_s, d_m: d, slope_mps: 0.0, pos });
            }
        }
    }
    tracks.into_iter().map(|t| t.idx).collect()
}

/// Δḋ of each reflection's track (module docs, 4–5) and the corrected
/// echoes. One echo per frame: a chirp is one track, paired with the
/// adjacent chirps of the other direction, and a chirp without an estimate
/// of its own takes the nearest chirp's. Several: each track within its
/// chirp ([`link_tracks`]) is fitted alone (the slope within one sweep gives
/// Δḋ), and a track of fewer than [`MIN_GROUP_FRAMES`] frames is dropped:
/// there is no telling which other track's rate it shares.
fn correct(
    meas: &[FrameMeas],
    sweeps: &[&dyn Sweep],
    dets: &[MovingDetection],
    a: f64,
    fs: f64,
    p: &DopplerParams,
) -> Vec<MovingEcho> {
    let n_chirps = dets.len();
    let by_chirp: Vec<Vec<usize>> = {
        let mut v = vec![Vec::new(); n_chirps];
        for (i, m) in meas.iter().enumerate() {
            v[m.chirp].push(i);
        }
        v
    };
    let dirs: Vec<f64> =
        dets.iter().map(|d| sweeps.get(d.sweep).map_or(1.0, |s| (s.f_start_hz() - s.f_end_hz()).signum())).collect();
    let onset = |c: usize| dets[c].detection.onset_sample;
    let single = p.echoes_per_frame <= 1;
    // (chirp, the track's measurements in time order)
    let tracks: Vec<(usize, Vec<usize>)> = if single {
        by_chirp.iter().cloned().enumerate().collect()
    } else {
        let mut out = Vec::new();
        for (c, ms) in by_chirp.iter().enumerate() {
            let Some(sw) = sweeps.get(dets[c].sweep) else { continue };
            out.extend(link_tracks(meas, ms, *sw, a, p.period_s).into_iter().map(|t| (c, t)));
        }
        out
    };
    let mut rates: Vec<Option<f64>> = vec![None; tracks.len()];
    for (ti, (c, own)) in tracks.iter().enumerate() {
        let c = *c;
        // The group: this track, plus (one echo per frame) the neighbouring
        // chirps of the other direction (alternating sweeps: the closed-form pairs).
        let mut group: Vec<usize> = own.clone();
        let mut partners = Vec::new();
        for nb in [c.wrapping_sub(1), c + 1] {
            if single && nb < n_chirps && dirs[nb] != dirs[c] {
                let gap = (onset(nb) as f64 - onset(c) as f64).abs();
                let span = sweeps.get(dets[c].sweep).map_or(0.0, |s| s.duration_s());
                // Only the adjacent chirp of a train (not one across a pause).
                if gap < 4.0 * span * fs {
                    partners.push(nb);
                    group.extend(&by_chirp[nb]);
                }
            }
        }
        if own.len() < 2 || group.len() < MIN_GROUP_FRAMES {
            continue;
        }
        let t0 = meas[own[own.len() / 2]].t_mid_s;
        let paired = !partners.is_empty();
        let mut rate = 0.0f64;
        for _ in 0..4 {
            let mut g = Vec::with_capacity(group.len());
            let mut y = Vec::with_capacity(group.len());
            let mut keep = Vec::with_capacity(group.len());
            for &i in &group {
                let m = &meas[i];
                let Some(sw) = sweeps.get(dets[m.chirp].sweep) else { continue };
                let (Some(d0), Some(d1)) = (frame_delta_d(m, *sw, a, rate), frame_delta_d(m, *sw, a, rate + 0.01))
                else {
                    continue;
                };
                let h = (d1 - d0) / 0.01;
                g.push(m.t_mid_s - t0 - h);
                y.push(d0 - h * rate);
                keep.push(i);
            }
            let ok = |i: usize, j: usize| !paired || meas[keep[i]].chirp != meas[keep[j]].chirp;
            match theil_sen(&g, &y, 0.05, &ok) {
                Some(s) if s.is_finite() => rate = s,
                _ => break,
            }
        }
        rates[ti] = Some(rate);
    }
    if single {
        // Chirps without their own estimate take the nearest chirp's.
        let own = rates.clone();
        for c in 0..n_chirps {
            if own[c].is_none() {
                let near = (0..n_chirps)
                    .filter(|&o| own[o].is_some())
                    .min_by_key(|&o| (onset(o) as i64 - onset(c) as i64).unsigned_abs());
                rates[c] = near.and_then(|o| own[o]);
            }
        }
    }
    let mut out = Vec::new();
    for ((c, own), rate) in tracks.iter().zip(&rates) {
        let (c, Some(rate)) = (*c, *rate) else { continue };
        let Some(sw) = sweeps.get(dets[c].sweep) else { continue };
        let vals: Vec<(usize, f64)> =
            own.iter().filter_map(|&i| frame_delta_d(&meas[i], *sw, a, rate).map(|d| (i, d))).collect();
        if vals.is_empty() {
            continue;
        }
        let t0 = meas[vals[vals.len() / 2].0].t_mid_s;
        let base: Vec<f64> = vals.iter().map(|&(i, d)| d - rate * (meas[i].t_mid_s - t0)).collect();
        let center = median_of(&base);
        let resid: Vec<f64> = base.iter().map(|b| (b - center).abs()).collect();
        let mad = 1.4826 * median_of(&resid);
        let gate = TRACK_GATE_M.max(5.0 * mad);
        for (k, &(i, dd)) in vals.iter().enumerate() {
            if resid[k] > gate || dd <= 0.0 {
                continue;
            }
            let m = &meas[i];
            if let Ok(echo) = Echo::new(p.speaker, m.pos, dd, 1.0, m.t_mid_s, p.listener_id) {
                out.push(MovingEcho { echo, delta_d_rate_mps: Some(rate), chirp: c });
            }
        }
    }
    // A frame's echoes together, earliest first (one measurement: the first
    // echo bounds its free space); one echo per frame is already in this order.
    out.sort_by(|x, y| {
        x.chirp
            .cmp(&y.chirp)
            .then(x.echo.t_s.total_cmp(&y.echo.t_s))
            .then(x.echo.delta_d_m.total_cmp(&y.echo.delta_d_m))
    });
    out
}

/// How `map --wav` turns a moving listener's recording into echoes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WavMethod {
    /// The paper's frequency gap in short frames (§IV), no Doppler correction.
    Gap,
    /// Ours: dechirped frames aligned on the direct sound by the poses, no Doppler correction.
    Dechirp,
    /// Ours (issue 11): template-bank detection, frames dechirped along the
    /// direct path, Δd corrected for range–Doppler coupling (module docs).
    Doppler,
}

impl WavMethod {
    /// Every method, in the order reports list them.
    pub const ALL: [WavMethod; 3] = [WavMethod::Gap, WavMethod::Dechirp, WavMethod::Doppler];
    /// Echoes per frame when none is asked for: 8 for [`WavMethod::Doppler`],
    /// which tracks each reflection's Doppler shift (a room's walls and a
    /// pillar: five at once), 1 for the uncorrected methods, which range
    /// the first reflection alone (the paper's §IV).
    pub fn default_echoes_per_frame(self) -> usize {
        match self {
            WavMethod::Doppler => 8,
            WavMethod::Gap | WavMethod::Dechirp => 1,
        }
    }
    /// Lower-case name, as accepted on the command line.
    pub fn name(self) -> &'static str {
        match self {
            WavMethod::Gap => "gap",
            WavMethod::Dechirp => "dechirp",
            WavMethod::Doppler => "doppler",
        }
    }
}

impl std::str::FromStr for WavMethod {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "gap" => Ok(WavMethod::Gap),
            "dechirp" => Ok(WavMethod::Dechirp),
            "doppler" => Ok(WavMethod::Doppler),
            o => Err(format!("unknown method {o:?}: use doppler, gap or dechirp")),
        }
    }
}

/// Everything a moving listener's recording needs besides the samples, the
/// chirp and the poses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovingOptions {
    /// Echo extraction method.
    pub method: WavMethod,
    /// The chirp train's sweep directions (`None`: as the chirp is written).
    pub pattern: Option<crate::synth::ChirpPattern>,
    /// Time between measurements (s).
    pub period_s: f64,
    /// Frame length (s); `None`: the method's default.
    pub frame_s: Option<f64>,
    /// Speaker position (m).
    pub speaker: Point,
    /// Listener id written into the echoes.
    pub listener_id: u32,
    /// Most echoes per frame ([`DopplerParams::echoes_per_frame`]; more than
    /// one only with [`WavMethod::Doppler`]).
    pub echoes_per_frame: usize,
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use chirpmap_core::chirp::{ExponentialChirp, HyperbolicChirp};
    use proptest::prelude::*;

    /// A frame as the physics makes it: the direct sound emitted at `tau_d`
    /// heard at f(τ_D)(1 − Ḋ/a), the reflection emitted Δd/a earlier heard
    /// at f(τ_D − Δd/a)(1 − (Ḋ + Δḋ)/a) (the heard frequency of s(t − r(t)/a)).
    fn frame(sweep: &dyn Sweep, tau_d: f64, dd: f64, d_rate: f64, dd_rate: f64) -> FrameMeas {
        FrameMeas {
            chirp: 0,
            t_mid_s: 0.0,
            pos: Point::new(1.0, 1.0),
            f_direct_hz: sweep.freq_at(tau_d).unwrap() * (1.0 - d_rate / A),
            f_reflected_hz: sweep.freq_at(tau_d - dd / A).unwrap() * (1.0 - (d_rate + dd_rate) / A),
            d_rate_mps: d_rate,
        }
    }

    const A: f64 = 343.0;

    proptest! {
        /// With the true Δḋ the inversion returns the true Δd exactly, for
        /// every sweep shape; with Δḋ = 0 a linear chirp shows the issue's
        /// coupling Δd + (f/k)·Δḋ (to first order in v/a).
        #[test]
        fn frame_inversion_is_exact(
            tau in 0.1..0.24f64, dd in 0.5..30.0f64, d_rate in -10.0..10.0f64, dd_rate in -10.0..10.0f64,
            down in any::<bool>(),
        ) {
            prop_assume!(tau - dd / A > 0.0);
            let (f0, f1) = if down { (10_000.0, 200.0) } else { (200.0, 10_000.0) };
            let sweeps: [Box<dyn Sweep>; 3] = [
                Box::new(LinearChirp::new(f0, f1, 0.25).unwrap()),
                Box::new(ExponentialChirp::new(f0, f1, 0.25).unwrap()),
                Box::new(HyperbolicChirp::new(f0, f1, 0.25).unwrap()),
            ];
            for s in &sweeps {
                let m = frame(s.as_ref(), tau, dd, d_rate, dd_rate);
                let got = frame_delta_d(&m, s.as_ref(), A, dd_rate).unwrap();
                prop_assert!((got - dd).abs() < 1e-6, "{s:?}: {got} vs {dd}");
            }
            let lin = LinearChirp::new(f0, f1, 0.25).unwrap();
            let m = frame(&lin, tau, dd, d_rate, dd_rate);
            let uncorrected = frame_delta_d(&m, &lin, A, 0.0).unwrap();
            let f = lin.freq_at(tau).unwrap();
            let coupled = dd + f / lin.rate_hz_per_s() * dd_rate;
            // Second-order terms: Δd·Ṙ/a and (f/k)·Δḋ·Ḋ/a, both ≤ 30·20/343.
            prop_assert!((uncorrected - coupled).abs() < 0.1 * (dd + 1.0) * (dd_rate.abs() + d_rate.abs()) / A * 20.0 + 1e-6,
                "{uncorrected} vs {coupled}");
        }

        /// Theil–Sen against the naive oracle: an exact line with under a
        /// quarter of its points moved anywhere keeps its slope.
        #[test]
        fn theil_sen_ignores_a_few_outliers(slope in -20.0..20.0f64, icpt in -5.0..5.0f64,
                                             bad in proptest::collection::vec((0usize..24, -50.0..50.0f64), 0..5)) {
            let g: Vec<f64> = (0..24).map(|i| -0.3 + 0.03 * i as f64).collect();
            let mut y: Vec<f64> = g.iter().map(|x| icpt + slope * x).collect();
            for (i, v) in &bad {
                y[*i] = *v;
            }
            let s = theil_sen(&g, &y, 0.05, &|_, _| true).unwrap();
            let tol = if bad.is_empty() { 1e-9 } else { 0.6 * slope.abs().max(1.0) };
            prop_assert!((s - slope).abs() <= tol, "{s} vs {slope}");
        }
    }

    /// A group of any size pairs at most `MAX_THEIL_SEN_POINTS` points (all
    /// pairs of 20 000 frames took 2 GB), and still finds the line's slope.
    #[test]
    fn theil_sen_pairs_a_bounded_number_of_points() {
        let n = 3 * MAX_THEIL_SEN_POINTS + 7;
        let g: Vec<f64> = (0..n).map(|i| 0.001 * i as f64).collect();
        let mut y: Vec<f64> = g.iter().map(|x| 0.5 - 1.25 * x).collect();
        for v in y.iter_mut().step_by(10) {
            *v += 40.0;
        }
        let pairs = std::cell::Cell::new(0usize);
        let s = theil_sen(&g, &y, 0.05, &|_, _| {
            pairs.set(pairs.get() + 1);
            true
        })
        .unwrap();
        assert!(pairs.get() <= MAX_THEIL_SEN_POINTS * (MAX_THEIL_SEN_POINTS - 1) / 2, "{} pairs", pairs.get());
        assert!((s + 1.25).abs() < 1e-6, "{s}");
    }

    /// Two reflections heard in every frame of one chirp, their path
    /// differences changing at +1.5 and −1.0 m/s (a room's walls as the
    /// listener walks): each is tracked and corrected with its own Δḋ, and
    /// every echo's Δd is the true one. One rate for the chirp (one echo per
    /// frame's model) misses both by centimetres.
    #[test]
    fn each_tracked_reflection_gets_its_own_doppler_correction() {
        let sweep = LinearChirp::new(10_000.0, 200.0, 0.25).unwrap();
        let refl = [(3.0, 1.5), (5.0, -1.0)];
        let (t0, d_rate) = (0.13, 0.7);
        let mut meas = Vec::new();
        let mut truth = Vec::new();
        for i in 0..15 {
            let tau = 0.06 + 0.01 * f64::from(i);
            for &(dd0, rate) in &refl {
                let dd = dd0 + rate * (tau - t0);
                meas.push(FrameMeas { t_mid_s: tau, ..frame(&sweep, tau, dd, d_rate, rate) });
                truth.push((tau, dd));
            }
        }
        let det = Detection { onset_sample: 0, strength: 1.0, ncc: 1.0 };
        let dets = [MovingDetection { detection: det, sweep: 0, scale: 1.0 }];
        let sweeps: [&dyn Sweep; 1] = [&sweep];
        let p = |k| DopplerParams {
            period_s: 0.01,
            frame_s: None,
            speaker: Point::new(0.0, 0.0),
            listener_id: 0,
            echoes_per_frame: k,
        };
        let got = correct(&meas, &sweeps, &dets, A, 48_000.0, &p(2));
        assert_eq!(got.len(), truth.len());
        let mut want = truth.clone();
        want.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
        for (g, w) in got.iter().zip(&want) {
            assert!(
                g.echo.t_s == w.0 && (g.echo.delta_d_m - w.1).abs() < 1e-4,
                "{} {} vs {w:?}",
                g.echo.t_s,
                g.echo.delta_d_m
            );
        }
        // One rate for the whole chirp: the echoes it keeps are off.
        let one = correct(&meas, &sweeps, &dets, A, 48_000.0, &p(1));
        let worst = one
            .iter()
            .map(|g| {
                truth
                    .iter()
                    .filter(|w| w.0 == g.echo.t_s)
                    .map(|w| (g.echo.delta_d_m - w.1).abs())
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(0.0, f64::max);
        assert!(one.is_empty() || worst > 0.01, "{worst}");
    }

    /// A listener at 8 m/s heading for a wall: the path difference changes at
    /// 16 m/s and the uncorrected Δd by 0.31 m per 10 ms frame, beyond the
    /// 0.15 m gate. Its one track must still form (it gave no echo at all).
    #[test]
    fn a_fast_changing_reflection_is_still_tracked() {
        let sweep = LinearChirp::new(10_000.0, 200.0, 0.25).unwrap();
        let sweeps: [&dyn Sweep; 1] = [&sweep];
        let det = Detection { onset_sample: 0, strength: 1.0, ncc: 1.0 };
        let dets = [MovingDetection { detection: det, sweep: 0, scale: 1.0 }];
        for (speed, rate) in [(1.0, 1.5), (4.0, 7.9), (8.0, -16.0), (8.0, 16.0)] {
            let mut meas = Vec::new();
            for i in 0..15 {
                let tau = 0.06 + 0.01 * f64::from(i);
                let dd = 12.0 + rate * (tau - 0.13);
                let pos = Point::new(1.0 + speed * tau, 1.0);
                meas.push(FrameMeas { t_mid_s: tau, pos, ..frame(&sweep, tau, dd, 0.5, rate) });
            }
            let p = DopplerParams {
                period_s: 0.01,
                frame_s: None,
                speaker: Point::new(0.0, 0.0),
                listener_id: 0,
                echoes_per_frame: 8,
            };
            let got = correct(&meas, &sweeps, &dets, A, 48_000.0, &p);
            assert_eq!(got.len(), 15, "{speed} m/s, Δḋ {rate}");
            for g in &got {
                let want = 12.0 + rate * (g.echo.t_s - 0.13);
                assert!((g.echo.delta_d_m - want).abs() < 1e-4, "{speed} m/s: {} vs {want}", g.echo.delta_d_m);
            }
        }
    }

    /// `strong_peaks` against the peaks it is built to find: three lobes of
    /// 1, 0.5 and 0.2 over a floor; at 0.3 of the strongest the first two,
    /// earliest first; one when one is asked for; a flat top is one peak.
    #[test]
    fn strong_peaks_are_the_lobes_above_the_level_earliest_first() {
        let lobe = |x: f64, c: f64, a: f64| a * (-(x - c).powi(2) / 8.0).exp();
        let mut v: Vec<f64> = (0..200)
            .map(|i| 0.01 + lobe(i as f64, 150.0, 1.0) + lobe(i as f64, 60.0, 0.5) + lobe(i as f64, 100.0, 0.2))
            .collect();
        assert_eq!(strong_peaks(&v, 10, 190, 0.3, 0.05, 8, 2), vec![60, 150]);
        assert_eq!(strong_peaks(&v, 10, 190, 0.1, 0.05, 8, 2), vec![60, 100, 150]);
        assert_eq!(strong_peaks(&v, 10, 190, 0.3, 0.05, 1, 2), vec![60]);
        assert_eq!(strong_peaks(&v, 10, 190, 0.3, 0.6, 8, 2), vec![150]);
        v[61] = v[60];
        assert_eq!(strong_peaks(&v, 10, 190, 0.3, 0.05, 8, 2), vec![60, 150]);
    }

    #[test]
    fn bank_covers_the_poses_radial_speeds_and_includes_no_shift() {
        let poses: Vec<(f64, Point)> = (0..100).map(|k| (k as f64 * 0.1, Point::new(-50.0 + k as f64, 3.0))).collect();
        let (lo, hi) = direct_rate_range(&poses, Point::new(0.0, 0.0));
        assert!(lo < -9.0 && hi > 9.0 && lo >= -10.0 && hi <= 10.0, "{lo} {hi}");
        let s = bank_scales((lo, hi), A);
        assert!(s.iter().any(|v| (v - 1.0).abs() < 1e-12));
        for v in [lo, hi, 0.3] {
            let want = 1.0 - v / A;
            let nearest = s.iter().map(|x| (x - want).abs()).fold(f64::INFINITY, f64::min);
            assert!(nearest <= 0.5 * BANK_STEP_MPS / A + 1e-12, "{v}: {nearest}");
        }
        // A static listener needs only the unscaled template.
        assert_eq!(bank_scales((0.0, 0.0), A), vec![1.0]);
    }

    #[test]
    fn method_names_round_trip() {
        for m in WavMethod::ALL {
            assert_eq!(m.name().parse::<WavMethod>().unwrap(), m);
        }
        assert!("fast".parse::<WavMethod>().unwrap_err().contains("doppler, gap or dechirp"));
    }
}
