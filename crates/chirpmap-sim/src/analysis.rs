//! Sensed particles → spectra → peaks → echoes (paper §II.B last paragraph,
//! Algorithm 1 lines 3–5).

use crate::Sensed;
use crate::resolve::{BIN_HZ, Resolved};
use chirpmap_core::{Echo, Point};

/// A peak of a spectrum: a run of occupied bins no more than
/// [`Resolved::merge_gap_bins`] apart, i.e. one arrival. The particle model
/// samples the sweep once per tick (19.6 Hz apart by default), so a single
/// arrival fills every first or second 10 Hz bin; without merging, one
/// arrival would read as several peaks a bin apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// Loudness-weighted mean frequency of the peak's bins (bin centres), Hz.
    pub f_hz: f64,
    /// Peak intensity: summed loudness of the peak's bins.
    pub intensity: f64,
    /// Lower edge of the lowest bin and upper edge of the highest bin (Hz).
    pub lo_hz: f64,
    pub hi_hz: f64,
}

/// One listener measurement: its spectrum, peaks and which peak is direct.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    pub listener_id: u32,
    pub tick: u64,
    pub t_s: f64,
    pub position: Point,
    /// Occupied bins: (bin index, summed loudness); bin i covers `[i, i+1)·BIN_HZ`.
    pub bins: Vec<(i64, f64)>,
    pub peaks: Vec<Peak>,
    /// Index into `peaks` of the direct arrival, when heard.
    pub direct: Option<usize>,
    /// Predicted direct frequency f(t − D/a) (Doppler-shifted when enabled).
    pub predicted_direct_hz: Option<f64>,
    pub n_sensed: u32,
}

/// Everything a simulation produces.
#[derive(Debug, Clone, PartialEq)]
pub struct SimOutput {
    pub measurements: Vec<Measurement>,
    pub echoes: Vec<Echo>,
}

/// Builds spectra, peaks and echoes from sensed particles (in any order).
///
/// Sums run in (measurement, particle id) order, so any two simulators that
/// sense the same particles produce bit-identical spectra.
pub fn analyse(r: &Resolved, mut sensed: Vec<Sensed>) -> SimOutput {
    sensed.sort_unstable_by_key(|s| (s.measurement, s.particle));
    let n = r.measurement_count();
    let mut measurements = Vec::with_capacity(n);
    let mut echoes = Vec::new();
    let mut cursor = 0usize;
    let mut pairs: Vec<(i64, f64)> = Vec::new();
    for l in &r.listeners {
        for (idx, (&tick, &pos)) in l.ticks.iter().zip(&l.positions).enumerate() {
            let m = (l.first_measurement + idx) as u32;
            let begin = cursor;
            while cursor < sensed.len() && sensed[cursor].measurement == m {
                cursor += 1;
            }
            let here = &sensed[begin..cursor];
            pairs.clear();
            pairs.extend(here.iter().map(|s| ((s.freq_hz / BIN_HZ).floor() as i64, s.loudness)));
            pairs.sort_by_key(|p| p.0); // stable: keeps particle order within a bin
            let mut bins: Vec<(i64, f64)> = Vec::new();
            for &(b, v) in &pairs {
                match bins.last_mut() {
                    Some(last) if last.0 == b => last.1 += v,
                    _ => bins.push((b, v)),
                }
            }
            let peaks = find_peaks(&bins, r.merge_gap_bins);
            let t_s = r.time_s(tick);
            let (direct, predicted) = direct_peak(r, &peaks, pos, l.velocities[idx], t_s);
            if let Some(d) = direct {
                let f_direct = peaks[d].f_hz;
                for (i, p) in peaks.iter().enumerate() {
                    if i == d {
                        continue;
                    }
                    let Some(dd) = r.sweep.delta_d_m(f_direct, p.f_hz, r.speed_of_sound_mps) else { continue };
                    // A reflection travelled further, so Δd > 0; a peak on the other
                    // side of the direct one cannot be an echo of this chirp.
                    if dd > 0.0 {
                        if let Ok(e) = Echo::new(r.source, pos, dd, p.intensity, t_s, l.id) {
                            echoes.push(e);
                        }
                    }
                }
            }
            measurements.push(Measurement {
                listener_id: l.id,
                tick,
                t_s,
                position: pos,
                bins,
                peaks,
                direct,
                predicted_direct_hz: predicted,
                n_sensed: here.len() as u32,
            });
        }
    }
    SimOutput { measurements, echoes }
}

/// Groups occupied bins into peaks (see [`Peak`]).
pub fn find_peaks(bins: &[(i64, f64)], merge_gap_bins: i64) -> Vec<Peak> {
    let mut peaks = Vec::new();
    let mut i = 0;
    while i < bins.len() {
        let mut j = i + 1;
        while j < bins.len() && bins[j].0 - bins[j - 1].0 <= merge_gap_bins {
            j += 1;
        }
        let run = &bins[i..j];
        let intensity: f64 = run.iter().map(|b| b.1).sum();
        let moment: f64 = run.iter().map(|b| (b.0 as f64 + 0.5) * BIN_HZ * b.1).sum();
        let f_hz = if intensity > 0.0 { moment / intensity } else { (run[0].0 as f64 + 0.5) * BIN_HZ };
        peaks.push(Peak {
            f_hz,
            intensity,
            lo_hz: run[0].0 as f64 * BIN_HZ,
            hi_hz: (run[run.len() - 1].0 + 1) as f64 * BIN_HZ,
        });
        i = j;
    }
    peaks
}

/// The direct peak, picked by prediction (DESIGN.md "Physics notes"): the
/// listener knows D, so the direct sound must be near f(t − D/a). The peak
/// whose span (widened by the merge gap) contains the prediction wins, the
/// nearest centre among several; no such peak (shadowed, not yet arrived, or
/// chirp over) means this measurement yields no echoes.
fn direct_peak(r: &Resolved, peaks: &[Peak], pos: Point, vel: Point, t_s: f64) -> (Option<usize>, Option<f64>) {
    let d_m = pos.dist(r.source);
    let Some(mut f) = r.sweep.freq_at(t_s - d_m / r.speed_of_sound_mps) else { return (None, None) };
    if r.doppler && d_m > 0.0 {
        f *= 1.0 - vel.dot((pos - r.source) * (1.0 / d_m)) / r.speed_of_sound_mps;
    }
    let tol = r.merge_gap_bins as f64 * BIN_HZ;
    let best = peaks
        .iter()
        .enumerate()
        .filter(|(_, p)| p.lo_hz - tol <= f && f <= p.hi_hz + tol)
        .min_by(|a, b| (a.1.f_hz - f).abs().total_cmp(&(b.1.f_hz - f).abs()))
        .map(|(i, _)| i);
    (best, Some(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alternate_bins_form_one_peak_and_gaps_split() {
        let bins = [(100, 1.0), (102, 1.0), (104, 2.0), (110, 0.5), (111, 0.5)];
        let p = find_peaks(&bins, 3);
        assert_eq!(p.len(), 2);
        assert!((p[0].intensity - 4.0).abs() < 1e-12);
        assert!((p[0].f_hz - (1005.0 + 1025.0 + 2.0 * 1045.0) / 4.0).abs() < 1e-9);
        assert_eq!((p[1].lo_hz, p[1].hi_hz), (1100.0, 1120.0));
    }
}
