//! Frame-wise echo extraction for moving listeners (issue 5, item 4; the
//! paper's future work: one pipeline from a recording to a map).
//!
//! A listener that moves during a chirp hears a different geometry in every
//! frame, so instead of one estimate per chirp it makes one measurement per
//! period (the paper's "sample rate", §III.B) at its pose at that time. The
//! frame is aligned on the direct sound using the known poses: the direct
//! sound heard at `t` left the speaker `D(t)/a` earlier.
//!
//! Doppler: the listener's motion changes the direct and the reflected
//! path lengths at different rates; a linear chirp turns that rate
//! difference Δv into a frequency error f·Δv/a, i.e. a Δd bias of
//! f·Δv/|rate| (range–Doppler coupling, paper §VI). It is not corrected
//! here; keep listeners slow or chirps fast (EXPERIMENTS.md).

use crate::detect::{ChirpTemplate, Detection};
use crate::error::AudioError;
use crate::ranging::{Method, RangeLimits, Ranger};
use chirpmap_core::error::Num;
use chirpmap_core::{Echo, Point};

/// Most measurements (frames) one extraction makes: the same cap as the
/// simulator's 10⁷ measurements (`chirpmap_sim::resolve::MAX_MEASUREMENTS`).
pub const MAX_MEASUREMENTS: usize = 10_000_000;

/// How [`extract_echoes`] cuts a recording into measurement frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameParams {
    /// Ranging method applied to each frame.
    pub method: Method,
    /// Time between measurements (s).
    pub period_s: f64,
    /// Frame length (s); `None` = the method's default (gap: sqrt(T/B);
    /// dechirp: 4·sqrt(T/B)).
    pub frame_s: Option<f64>,
    /// Speaker position (m), for the direct path length `D(t)` at each pose.
    pub speaker: Point,
    /// Listener id written into the extracted echoes.
    pub listener_id: u32,
}

/// Echoes from every measurement frame of every detected chirp.
/// `pose_at(t)` gives the listener's position at recording time `t` (s).
pub fn extract_echoes(
    x: &[f32],
    tpl: &ChirpTemplate,
    lim: &RangeLimits,
    detections: &[Detection],
    pose_at: &dyn Fn(f64) -> Option<Point>,
    p: &FrameParams,
) -> Result<Vec<Echo>, AudioError> {
    if !(p.period_s > 0.0 && p.period_s.is_finite()) {
        return Err(AudioError::InvalidParam {
            field: "period",
            reason: format!("must be finite and > 0, got {}", Num(p.period_s)),
        });
    }
    let fs = tpl.sample_rate_hz;
    // Bound the work before any of it (issue 8, item 10: `--period-ms 1e-9`
    // ran for hours): a period shorter than a sample repeats frames, and the
    // number of measurements is capped.
    if p.period_s * fs < 1.0 {
        return Err(AudioError::InvalidParam {
            field: "period",
            reason: format!(
                "{} ms is shorter than one sample ({} ms at {} Hz)",
                Num(p.period_s * 1e3),
                Num(1e3 / fs),
                Num(fs)
            ),
        });
    }
    let per_chirp = (tpl.len() as f64 / (p.period_s * fs)).ceil() + 1.0;
    let planned = per_chirp * detections.len() as f64;
    if planned > MAX_MEASUREMENTS as f64 {
        return Err(AudioError::InvalidParam {
            field: "period",
            reason: format!(
                "{} ms gives about {} measurements over {} chirp(s), more than the cap of {MAX_MEASUREMENTS}; \
                 use a longer period",
                Num(p.period_s * 1e3),
                Num(planned),
                detections.len()
            ),
        });
    }
    let a = lim.speed_of_sound_mps;
    let gap_len = Ranger::gap_frame_len(tpl);
    let frame = match (p.frame_s, p.method) {
        (Some(s), _) => (s * fs).round() as usize,
        (None, Method::Gap) => gap_len,
        (None, Method::Dechirp) => 4 * gap_len,
        (None, Method::Matched) => {
            return Err(AudioError::InvalidParam {
                field: "method",
                reason: "matched filtering ranges whole chirps; for a moving listener use gap or dechirp".into(),
            });
        }
    };
    if frame < 16 || frame >= tpl.len() {
        return Err(AudioError::InvalidParam {
            field: "frame",
            reason: format!("{frame} samples: must be >= 16 and shorter than the chirp ({} samples)", tpl.len()),
        });
    }
    let mut ranger = Ranger::new();
    let mut echoes = Vec::new();
    let rate = tpl.rate_abs();
    for d in detections {
        let t_on = d.onset_sample as f64 / fs;
        let Some(p_on) = pose_at(t_on) else { continue };
        let d_on = p.speaker.dist(p_on);
        let mut t_rel = 0.0;
        while ((t_rel * fs).round() as usize) + frame < tpl.len() {
            let off = (t_rel * fs).round() as usize;
            t_rel += p.period_s;
            let t_mid = t_on + (off + frame / 2) as f64 / fs;
            let Some(pos) = pose_at(t_mid) else { continue };
            let shift_s = (p.speaker.dist(pos) - d_on) / a;
            let start = d.onset_sample as f64 + off as f64 + shift_s * fs;
            if start < 0.0 {
                continue;
            }
            let start = start.round() as usize;
            let got = match p.method {
                Method::Gap => ranger.gap_frame(x, start, off, frame, tpl, lim),
                _ => ranger.dechirp_frame(x, start, off, frame, tpl, lim),
            };
            let Some((gap_hz, _level)) = got else { continue };
            let dd = a * gap_hz / rate;
            if let Ok(e) = Echo::new(p.speaker, pos, dd, 1.0, t_mid, p.listener_id) {
                echoes.push(e);
            }
        }
    }
    Ok(echoes)
}
