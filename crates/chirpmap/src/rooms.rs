//! Real rooms (issue 10): every reflection of every chirp, in 3D, with the
//! loudspeaker's own response modelled so that its ringing is not an echo.
//!
//! Per chirp: the impulse response (matched filter for a linear sweep,
//! Farina's inverse filter for an exponential one;
//! [`chirpmap_audio::farina`]), then matching pursuit with the system
//! response cut from the direct sound or taken from a calibration
//! recording ([`chirpmap_audio::echoes`]). Each echo's path difference
//! `path_delta_m` is measured in 3D; with speaker and microphone heights,
//! `delta_d_m` is the horizontal path difference a vertical reflector
//! would give, `sqrt(d_r² − Δz²) − sqrt(d_d² − Δz²)` (its image source keeps
//! the speaker's height), which is what the 2D mapper (paper §II.C) needs;
//! echoes of the floor and the ceiling are labelled and left out of it.

use crate::error::{Error, Result};
use crate::recording::{ChirpSpec, FirstPass, check_speed, first_pass};
use chirpmap_audio::echoes::{Complex64, Pursuit, PursuitParams, SystemResponse, pursue};
use chirpmap_audio::farina::SweepKernel;
use chirpmap_audio::filter::paper_highpass;
use chirpmap_audio::rir::{IrExtractor, analytic};
use chirpmap_audio::stats::median;
use chirpmap_core::error::Num;
use chirpmap_core::{Echo, Point};
use serde::Serialize;

/// A recording prepared for echo picking: high-passed (paper §IV.A, 100 Hz)
/// with its sweep of any shape.
#[derive(Debug, Clone)]
pub struct RoomPrepared {
    /// High-passed samples.
    pub x: Vec<f32>,
    /// The sweep and its deconvolution kernel.
    pub kernel: SweepKernel,
    /// Sample rate (Hz).
    pub sample_rate_hz: f64,
    /// Length of the channel (s).
    pub duration_s: f64,
    /// Speed of sound (m/s).
    pub speed_of_sound_mps: f64,
    /// Largest path difference searched (m).
    pub max_delta_d_m: f64,
}

/// Validates the chirp against the channel and prepares it (linear,
/// exponential or any other sweep the scene format knows). The default
/// largest Δd is min(60 m, a·T/2) as for [`crate::prepare`]; for a
/// down-going exponential sweep it is also kept below 90 % of the second
/// harmonic's delay (Farina), where distortion would look like an echo.
pub fn prepare_room(mut x: Vec<f32>, sample_rate_hz: f64, chirp: &ChirpSpec) -> Result<RoomPrepared> {
    let a = check_speed(chirp.speed_of_sound_mps)?;
    if x.iter().all(|v| *v == 0.0) {
        return Err(Error::Invalid("the channel is silent (every sample is zero)".into()));
    }
    let kernel = SweepKernel::new(chirp.kind, chirp.f_start_hz, chirp.f_end_hz, chirp.duration_s, sample_rate_hz)?;
    if kernel.len() > x.len() {
        return Err(Error::Field {
            field: "duration",
            reason: format!(
                "the chirp ({} s) is longer than the recording ({:.3} s)",
                chirp.duration_s,
                x.len() as f64 / sample_rate_hz
            ),
        });
    }
    paper_highpass(sample_rate_hz)?.filter_in_place(&mut x);
    let max_dd = largest_delta_d(a, chirp, &kernel)?;
    let duration_s = x.len() as f64 / sample_rate_hz;
    Ok(RoomPrepared { x, kernel, sample_rate_hz, duration_s, speed_of_sound_mps: a, max_delta_d_m: max_dd })
}

/// The largest Δd searched: min(60 m, a·T/2), or the chirp's own, kept
/// below 90 % of a following harmonic's delay.
fn largest_delta_d(a: f64, chirp: &ChirpSpec, kernel: &SweepKernel) -> Result<f64> {
    let mut max_dd = (0.5 * a * chirp.duration_s).min(60.0);
    if let Some(m) = chirp.max_delta_d_m {
        let most = a * chirp.duration_s;
        if !(m.is_finite() && m > 0.0 && m <= most) {
            return Err(Error::Field {
                field: "max_delta_d",
                reason: format!("must be > 0 and at most a·T = {most:.1} m, got {}", Num(m)),
            });
        }
        max_dd = m;
    }
    if kernel.harmonics_follow()
        && let Some(lag) = kernel.harmonic_lag_s()
    {
        max_dd = max_dd.min(0.9 * a * lag);
    }
    Ok(max_dd)
}

/// Where the speaker and the microphone stand, in 2D or 3D, and where the
/// floor and the ceiling are (optional).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoomGeometry {
    /// Speaker position in the map's plane (m).
    pub speaker: Point,
    /// Microphone position in the map's plane (m).
    pub mic: Point,
    /// Speaker and microphone heights (m), both or neither.
    pub heights_m: Option<(f64, f64)>,
    /// Height of the floor (m): its echoes are labelled `floor`.
    pub floor_z_m: Option<f64>,
    /// Height of the ceiling (m): its echoes are labelled `ceiling`.
    pub ceiling_z_m: Option<f64>,
}

impl RoomGeometry {
    /// Refuses coincident positions, a floor or ceiling without heights,
    /// and a floor above (or a ceiling below) the speaker or microphone.
    pub fn validate(&self) -> Result<()> {
        let finite = [self.speaker.x, self.speaker.y, self.mic.x, self.mic.y]
            .into_iter()
            .chain(self.heights_m.map(|(a, b)| [a, b]).into_iter().flatten())
            .chain(self.floor_z_m)
            .chain(self.ceiling_z_m)
            .all(f64::is_finite);
        if !finite {
            return Err(Error::Invalid("positions and heights must be finite".into()));
        }
        let d = self.direct_m();
        if d.is_nan() || d <= 1e-9 {
            return Err(Error::Invalid("speaker and mic are the same point; the direct distance must be > 0".into()));
        }
        let Some((zs, zm)) = self.heights_m else {
            if self.floor_z_m.is_some() || self.ceiling_z_m.is_some() {
                return Err(Error::Invalid(
                    "--floor-z and --ceiling-z need heights: give --speaker X,Y,Z and --mic X,Y,Z".into(),
                ));
            }
            return Ok(());
        };
        if let Some(f) = self.floor_z_m
            && f >= zs.min(zm)
        {
            return Err(Error::Field {
                field: "floor_z",
                reason: format!("{} m is not below the speaker ({} m) and the mic ({} m)", Num(f), Num(zs), Num(zm)),
            });
        }
        if let Some(c) = self.ceiling_z_m
            && c <= zs.max(zm)
        {
            return Err(Error::Field {
                field: "ceiling_z",
                reason: format!("{} m is not above the speaker ({} m) and the mic ({} m)", Num(c), Num(zs), Num(zm)),
            });
        }
        Ok(())
    }

    fn dz(&self) -> f64 {
        self.heights_m.map_or(0.0, |(zs, zm)| zs - zm)
    }

    /// Direct distance in 3D (m).
    pub fn direct_m(&self) -> f64 {
        self.speaker.dist(self.mic).hypot(self.dz())
    }

    /// The horizontal path difference for the 2D map of a measured 3D one,
    /// assuming a vertical reflector: `sqrt(d_r² − Δz²) − sqrt(d_d² − Δz²)`
    /// with `d_r = d_d + path_delta`. Without heights, `path_delta` itself.
    pub fn horizontal_delta_d(&self, path_delta_m: f64) -> f64 {
        let dz2 = self.dz().powi(2);
        let d = self.direct_m();
        let r = d + path_delta_m;
        (r * r - dz2).max(0.0).sqrt() - (d * d - dz2).max(0.0).sqrt()
    }

    /// Predicted path differences of the floor's and the ceiling's echoes:
    /// `(label, Δd)`. The floor is at `floor_z_m`, or guessed at z = 0
    /// (label `floor?`) when neither floor nor ceiling is given.
    pub fn predicted(&self) -> Vec<(&'static str, f64)> {
        let Some((zs, zm)) = self.heights_m else { return Vec::new() };
        let h = self.speaker.dist(self.mic);
        let d = self.direct_m();
        let mut out = Vec::new();
        match self.floor_z_m {
            Some(f) => out.push(("floor", h.hypot(zs + zm - 2.0 * f) - d)),
            None if self.ceiling_z_m.is_none() => out.push(("floor?", h.hypot(zs + zm) - d)),
            None => {}
        }
        if let Some(c) = self.ceiling_z_m {
            out.push(("ceiling", h.hypot(2.0 * c - zs - zm) - d));
        }
        out
    }
}

/// How echoes are picked.
#[derive(Debug, Clone, PartialEq)]
pub struct EchoOptions {
    /// Most echoes reported per chirp (the strongest, then ordered by delay).
    pub max_echoes: usize,
    /// Weakest echo reported, relative to the direct sound (dB).
    pub threshold_db: f64,
    /// Length of the system response after the direct peak (s): the
    /// loudspeaker's ringing. Estimated from the direct sound, nothing
    /// closer than this is reported.
    pub ringing_s: f64,
    /// Length of the system response after its peak that is matched to
    /// echoes (s). Shorter than the ringing: overlapping echoes are told
    /// apart by their main lobes, and an echo's shape departs from the
    /// direct sound's further into its tail (measured on the dEchorate
    /// RIRs: 0.6 ms finds the nearest side wall in 7 of 10 recordings,
    /// the whole 2 ms in 4; docs/rooms.md).
    pub echo_atom_s: f64,
    /// The echo nearest a predicted floor or ceiling echo, if within this, is labelled
    /// (m). The dEchorate room's positions are good to about ±6 cm.
    pub plane_tolerance_m: f64,
    /// A system response measured separately (`--calibration`); `None`:
    /// each chirp's own direct sound.
    pub calibration: Option<SystemResponse>,
}

impl Default for EchoOptions {
    /// 20 echoes, −30 dB, 2 ms of ringing (the dEchorate loudspeaker's, issue 10), 8 cm.
    fn default() -> Self {
        Self {
            max_echoes: DEFAULT_MAX_ECHOES,
            threshold_db: -30.0,
            ringing_s: 0.002,
            echo_atom_s: 0.0006,
            plane_tolerance_m: 0.08,
            calibration: None,
        }
    }
}

/// Most echoes per chirp when `--echoes` is given without a number.
pub const DEFAULT_MAX_ECHOES: usize = 20;

/// Samples kept before the direct peak in the system response: about a
/// third of a millisecond, the main lobe of a 10 kHz-wide pulse several times over.
fn pre_samples(fs: f64) -> usize {
    ((0.00033 * fs).round() as usize).max(4)
}

impl EchoOptions {
    /// Refuses non-finite or out-of-range values (errors name the field).
    pub fn validate(&self) -> Result<()> {
        if self.max_echoes == 0 || self.max_echoes > 1000 {
            return Err(Error::Field {
                field: "echoes",
                reason: format!("must be in 1..=1000, got {}", self.max_echoes),
            });
        }
        if !(self.threshold_db.is_finite() && self.threshold_db < 0.0 && self.threshold_db >= -120.0) {
            return Err(Error::Field {
                field: "echo_threshold_db",
                reason: format!("must be in [-120, 0) dB, got {}", Num(self.threshold_db)),
            });
        }
        if !(self.ringing_s.is_finite() && self.ringing_s > 0.0 && self.ringing_s <= 0.1) {
            return Err(Error::Field {
                field: "ringing_ms",
                reason: format!("must be > 0 and at most 100 ms, got {} ms", Num(self.ringing_s * 1e3)),
            });
        }
        if !(self.echo_atom_s.is_finite() && self.echo_atom_s > 0.0 && self.echo_atom_s <= 0.1) {
            return Err(Error::Field {
                field: "echo_atom_ms",
                reason: format!("must be > 0 and at most 100 ms, got {} ms", Num(self.echo_atom_s * 1e3)),
            });
        }
        if !(self.plane_tolerance_m.is_finite() && self.plane_tolerance_m > 0.0) {
            return Err(Error::Field { field: "plane_tolerance", reason: "must be finite and > 0".into() });
        }
        Ok(())
    }
}

/// One reflection of one chirp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RoomEcho {
    /// Index of the chirp (0-based).
    pub chirp: usize,
    /// Rank by delay within the chirp (1 = the earliest).
    pub rank: usize,
    /// Onset of the chirp's direct arrival in the recording (s).
    pub t_s: f64,
    /// Measured (3D) path difference to the direct sound (m).
    pub path_delta_m: f64,
    /// Horizontal path difference for the 2D map (m), see [`RoomGeometry::horizontal_delta_d`].
    pub delta_d_m: f64,
    /// Amplitude relative to the direct sound (dB).
    pub strength_db: f64,
    /// `floor`, `ceiling`, `floor?` or none.
    pub plane: Option<&'static str>,
}

impl RoomEcho {
    /// Whether the echo belongs in the 2D map (not a labelled floor or ceiling).
    pub fn maps(&self) -> bool {
        !matches!(self.plane, Some("floor" | "ceiling"))
    }
}

/// Echoes seen in many chirps at the same path difference.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EchoCluster {
    /// Median path difference (m).
    pub path_delta_m: f64,
    /// Its horizontal path difference (m).
    pub delta_d_m: f64,
    /// Median strength (dB re direct).
    pub strength_db: f64,
    /// Chirps in which it was found.
    pub chirps: usize,
    /// Plane label, as for single echoes.
    pub plane: Option<&'static str>,
}

/// Every echo of every chirp, and what summarises them.
#[derive(Debug, Clone, PartialEq)]
pub struct RoomReport {
    /// Onsets of the chirps (s).
    pub chirp_onsets_s: Vec<f64>,
    /// Every echo, by chirp then delay.
    pub echoes: Vec<RoomEcho>,
    /// Echoes found in at least half of the chirps, by path difference.
    pub clusters: Vec<EchoCluster>,
    /// The echogram: `(path difference m, level dB re direct)`, median over
    /// chirps (at most [`ECHOGRAM_CHIRPS`], evenly spread).
    pub echogram: Vec<(f64, f64)>,
    /// Predicted floor/ceiling echoes `(label, Δd)`.
    pub predicted: Vec<(&'static str, f64)>,
    /// Smallest path difference searched (m): the ringing window, or with a
    /// calibration a third of a millisecond.
    pub min_delta_d_m: f64,
    /// Largest path difference searched (m).
    pub max_delta_d_m: f64,
    /// Whether the system response came from a calibration.
    pub calibrated: bool,
}

impl RoomReport {
    /// The echoes for the 2D map: one [`Echo`] per reflection, weight 1 for
    /// walls and 0 for labelled floor and ceiling echoes (kept in the file,
    /// out of the map).
    pub fn map_echoes(&self, geom: &RoomGeometry, listener_id: u32) -> Result<Vec<Echo>> {
        self.echoes
            .iter()
            .map(|e| {
                let w = if e.maps() { 1.0 } else { 0.0 };
                Echo::new(geom.speaker, geom.mic, e.delta_d_m, w, e.t_s, listener_id).map_err(Error::from)
            })
            .collect()
    }
}

/// The system response of a calibration recording (the direct sound
/// alone): its chirps' direct windows, averaged.
pub fn calibration_response(prep: &RoomPrepared, opts: &EchoOptions) -> Result<SystemResponse> {
    let fs = prep.sample_rate_hz;
    let (pre, ringing) = (pre_samples(fs), ringing_samples(opts, fs));
    let dets = detect(prep)?;
    let mut ex = IrExtractor::new(&prep.kernel, 4 * pre + 64, ringing + 4 * pre + 64);
    let responses: Vec<SystemResponse> = dets
        .iter()
        .filter_map(|&onset| {
            let ir = ex.extract(&prep.x, onset);
            SystemResponse::from_direct(&ir, direct_search(ex.pre(), pre), pre, ringing)
        })
        .collect();
    SystemResponse::average(&responses)
        .ok_or_else(|| Error::Invalid("the calibration recording gave no usable direct sound".into()))
}

/// The system response of a calibration impulse response (`--input rir`).
pub fn calibration_response_rir(rir: &[f32], sample_rate_hz: f64, opts: &EchoOptions) -> Result<SystemResponse> {
    check_rir_memory(rir, "the calibration impulse response")?;
    let ir = analytic(rir);
    let (pre, ringing) = (pre_samples(sample_rate_hz), ringing_samples(opts, sample_rate_hz));
    SystemResponse::from_direct(&ir, 0..ir.len().saturating_sub(ringing), pre, ringing)
        .ok_or_else(|| Error::Invalid("the calibration impulse response has no usable direct peak".into()))
}

/// The longest path difference searched in an impulse response by default
/// (m), as `range --input rir` searches it.
pub const RIR_DEFAULT_MAX_DELTA_D_M: f64 = 60.0;

/// The path difference (m) searched in an impulse response of `samples` at
/// `sample_rate_hz`: `max_delta_d_m` (default [`RIR_DEFAULT_MAX_DELTA_D_M`]),
/// but no more than the response covers. A given value that is not finite
/// and > 0 is refused: `f64::min` drops a NaN, so `--max-delta-d NaN`
/// searched the default without a word.
pub fn rir_max_delta_d(
    max_delta_d_m: Option<f64>,
    speed_of_sound_mps: f64,
    samples: usize,
    sample_rate_hz: f64,
) -> Result<f64> {
    if let Some(m) = max_delta_d_m.filter(|m| !(m.is_finite() && *m > 0.0)) {
        return Err(Error::Field { field: "max_delta_d", reason: format!("must be finite and > 0, got {}", Num(m)) });
    }
    Ok(max_delta_d_m.unwrap_or(RIR_DEFAULT_MAX_DELTA_D_M).min(speed_of_sound_mps * samples as f64 / sample_rate_hz))
}

/// Peak memory of searching an impulse response, per sample: its analytic
/// signal (FFT buffers of twice its length rounded up to a power of two)
/// and the copies around it; ~160 B measured (20 M samples peaked at
/// 3.2 GB, 50 M at 6.9 GB; session 20's review).
const RIR_BYTES_PER_SAMPLE: u128 = 160;

/// Refuses an impulse response whose search would exceed the audio memory
/// cap, before anything is allocated: only the first `max_delta_d` of it
/// is searched, yet all of it is transformed.
fn check_rir_memory(rir: &[f32], what: &str) -> Result<()> {
    chirpmap_audio::error::check_memory(
        || format!("{what} ({} samples)", rir.len()),
        rir.len() as u128 * RIR_BYTES_PER_SAMPLE,
        "cut it to the part that holds the echoes (the direct sound and max_delta_d beyond it)",
    )?;
    Ok(())
}

fn ringing_samples(opts: &EchoOptions, fs: f64) -> usize {
    ((opts.ringing_s * fs).round() as usize).max(1)
}

/// Where the direct peak is searched in a chirp's response: the detection
/// finds the onset to within the sweep's main lobe; a loudspeaker may put
/// its peak a few samples later.
fn direct_search(onset_index: usize, pre: usize) -> std::ops::Range<usize> {
    onset_index.saturating_sub(pre)..onset_index + 4 * pre
}

fn detect(prep: &RoomPrepared) -> Result<Vec<usize>> {
    let tpl = prep.kernel.detection_template()?;
    let mut cache = chirpmap_audio::spectrum::FftCache::default();
    let dets = chirpmap_audio::detect_chirps(&prep.x, &tpl, &mut cache, prep.max_delta_d_m / prep.speed_of_sound_mps)?;
    Ok(dets.into_iter().map(|d| d.onset_sample).collect())
}

/// Detects every chirp and picks every echo of each (issue 10, items 1–3).
pub fn room_echoes(prep: &RoomPrepared, geom: &RoomGeometry, opts: &EchoOptions) -> Result<RoomReport> {
    geom.validate()?;
    opts.validate()?;
    let fs = prep.sample_rate_hz;
    let a = prep.speed_of_sound_mps;
    let onsets = detect(prep)?;
    let pre = pre_samples(fs);
    let ringing = ringing_samples(opts, fs);
    let max_lag = prep.max_delta_d_m / a * fs;
    let atom_len = opts.calibration.as_ref().map_or(pre + ringing, |c| c.samples.len());
    let head = 4 * pre + 64;
    let tail = max_lag.ceil() as usize + atom_len + head;
    let mut ex = IrExtractor::new(&prep.kernel, head, tail);
    let mut picker = Picker::new(geom, opts, fs, a, prep.max_delta_d_m);
    picker.gram_every = onsets.len().div_ceil(ECHOGRAM_CHIRPS).max(1);
    for (k, &onset) in onsets.iter().enumerate() {
        let ir = ex.extract(&prep.x, onset);
        picker.add(k, onset as f64 / fs, &ir, direct_search(head, pre));
    }
    Ok(picker.finish(onsets.iter().map(|&o| o as f64 / fs).collect()))
}

/// A [`RoomReport`] computed from a WAV file read as a stream, with what
/// was learnt of the file on the way.
#[derive(Debug, Clone)]
pub struct StreamedRoom {
    /// The report, the same as [`prepare_room`] then [`room_echoes`] give.
    pub report: RoomReport,
    /// Sample rate (Hz).
    pub sample_rate_hz: f64,
    /// Samples at full scale over all channels.
    pub clipped_samples: usize,
    /// Largest path difference searched (m).
    pub max_delta_d_m: f64,
}

impl RoomReport {
    /// [`prepare_room`] then [`room_echoes`] on channel `channel` of a WAV
    /// file, in memory independent of the recording's length (issue 14,
    /// item 4): the file is read twice as a stream ([`chirpmap_audio::stream`]):
    /// once for the chirps' detection, once for the correlations the
    /// detection still needs and each chirp's impulse response from its own
    /// window. The same report, bit for bit. `Ok(None)`: the recording's
    /// level changes too much along it for the streamed median (see
    /// [`chirpmap_audio::stream`]); use the in-memory path.
    pub fn from_wav_stream(
        path: &std::path::Path,
        channel: usize,
        chirp: &ChirpSpec,
        geom: &RoomGeometry,
        opts: &EchoOptions,
    ) -> Result<Option<StreamedRoom>> {
        use chirpmap_audio::stream::{Filtered, scan_chirps, visit_chirps};
        use chirpmap_audio::wav::WavStream;
        let open = || WavStream::open(path, channel);
        let wav = open()?;
        let fs = f64::from(wav.sample_rate_hz);
        let n = wav.frames;
        let a = check_speed(chirp.speed_of_sound_mps)?;
        let kernel = SweepKernel::new(chirp.kind, chirp.f_start_hz, chirp.f_end_hz, chirp.duration_s, fs)?;
        if kernel.len() > n {
            return Err(Error::Field {
                field: "duration",
                reason: format!(
                    "the chirp ({} s) is longer than the recording ({:.3} s)",
                    chirp.duration_s,
                    n as f64 / fs
                ),
            });
        }
        let sos = paper_highpass(fs)?;
        let max_dd = largest_delta_d(a, chirp, &kernel)?;
        geom.validate()?;
        opts.validate()?;
        let tpl = kernel.detection_template()?;
        let Some(FirstPass { scan, clipped, checkpoints }) =
            first_pass(wav, &sos, channel, |src| scan_chirps(src, n, &tpl, max_dd / a))?
        else {
            return Ok(None);
        };
        let m = scan.template_len();
        let pre = pre_samples(fs);
        let ringing = ringing_samples(opts, fs);
        let max_lag = max_dd / a * fs;
        let atom_len = opts.calibration.as_ref().map_or(pre + ringing, |c| c.samples.len());
        let head = 4 * pre + 64;
        let tail = max_lag.ceil() as usize + atom_len + head;
        let mut ex = IrExtractor::new(&kernel, head, tail);
        let (dets, picker) = visit_chirps(
            &scan,
            || Ok(Filtered::resume(open()?, &sos, checkpoints.clone())),
            head,
            m + tail,
            |onsets: &[usize]| {
                let mut p = Picker::new(geom, opts, fs, a, max_dd);
                p.gram_every = onsets.len().div_ceil(ECHOGRAM_CHIRPS).max(1);
                (p, onsets.to_vec())
            },
            |(picker, onsets), k, x, r| {
                // The window starts `head` samples before the onset (or at 0): the extractor's own.
                let ir = ex.extract(x, r);
                picker.add(k, onsets[k] as f64 / fs, &ir, direct_search(head, pre));
            },
        )?;
        let report = picker.0.finish(dets.iter().map(|d| d.onset_sample as f64 / fs).collect());
        Ok(Some(StreamedRoom { report, sample_rate_hz: fs, clipped_samples: clipped, max_delta_d_m: max_dd }))
    }
}

/// Picks every echo of an impulse response given directly (`range --input
/// rir`): time zero is the emission; the direct sound is the strongest peak.
pub fn rir_echoes(
    rir: &[f32],
    sample_rate_hz: f64,
    speed_of_sound_mps: f64,
    max_delta_d_m: f64,
    geom: &RoomGeometry,
    opts: &EchoOptions,
) -> Result<RoomReport> {
    geom.validate()?;
    opts.validate()?;
    let a = check_speed(speed_of_sound_mps)?;
    if !(max_delta_d_m.is_finite() && max_delta_d_m > 0.0) {
        return Err(Error::Field {
            field: "max_delta_d",
            reason: format!("must be finite and > 0, got {}", Num(max_delta_d_m)),
        });
    }
    if rir.iter().all(|v| *v == 0.0) {
        return Err(Error::Invalid("the impulse response is silent (every sample is zero)".into()));
    }
    check_rir_memory(rir, "the impulse response")?;
    let ir = analytic(rir);
    let mut picker = Picker::new(geom, opts, sample_rate_hz, a, max_delta_d_m);
    picker.add(0, 0.0, &ir, 0..ir.len());
    if picker.found == 0 {
        return Err(Error::Invalid(
            "no direct peak with room for the system response after it (impulse response too short?)".into(),
        ));
    }
    Ok(picker.finish(vec![0.0]))
}

/// Accumulates per-chirp pursuits into a report.
struct Picker<'a> {
    geom: &'a RoomGeometry,
    opts: &'a EchoOptions,
    fs: f64,
    a: f64,
    max_dd: f64,
    pre: usize,
    ringing: usize,
    predicted: Vec<(&'static str, f64)>,
    echoes: Vec<RoomEcho>,
    /// Envelope in dB per lag bin (lag = index − pre relative to the direct), per chirp.
    gram: Vec<Vec<f64>>,
    /// Every how many chirps one enters the echogram (at most
    /// [`ECHOGRAM_CHIRPS`] do, so an hour's median stays small).
    gram_every: usize,
    found: usize,
}

/// Most chirps whose envelopes the echogram's median is taken over.
pub const ECHOGRAM_CHIRPS: usize = 101;

impl<'a> Picker<'a> {
    fn new(geom: &'a RoomGeometry, opts: &'a EchoOptions, fs: f64, a: f64, max_dd: f64) -> Self {
        Self {
            geom,
            opts,
            fs,
            a,
            max_dd,
            pre: pre_samples(fs),
            ringing: ringing_samples(opts, fs),
            predicted: geom.predicted(),
            echoes: Vec::new(),
            gram: Vec::new(),
            gram_every: 1,
            found: 0,
        }
    }

    fn min_lag(&self) -> f64 {
        match &self.opts.calibration {
            None => self.ringing as f64,
            Some(_) => self.pre as f64,
        }
    }

    fn add(&mut self, chirp: usize, t_s: f64, ir: &[Complex64], search: std::ops::Range<usize>) {
        let (pre, ringing) = (self.pre, self.ringing);
        let own;
        let atom = match &self.opts.calibration {
            Some(c) => c,
            None => {
                let Some(a) = SystemResponse::from_direct(ir, search.clone(), pre, ringing) else { return };
                own = a;
                &own
            }
        };
        let params = PursuitParams {
            direct_lo: search.start,
            direct_hi: search.end,
            min_lag: self.min_lag(),
            max_lag: self.max_dd / self.a * self.fs,
            max_echoes: self.opts.max_echoes,
            threshold_db: self.opts.threshold_db,
            self_estimated: self.opts.calibration.is_none(),
            echo_atom_after_peak: ((self.opts.echo_atom_s * self.fs).round() as usize).max(1),
        };
        let Some(Pursuit { direct_index, arrivals, .. }) = pursue(ir, atom, &params) else { return };
        self.found += 1;
        // Echogram: envelope re the direct peak, from `pre` samples before it.
        let d = direct_index.round().max(0.0) as usize;
        let peak = ir.get(d).map_or(0.0, |c| c.norm());
        if peak > 0.0 && chirp.is_multiple_of(self.gram_every) {
            let n = (params.max_lag.ceil() as usize + 1 + pre).min(ir.len().saturating_sub(d.saturating_sub(pre)));
            let lo = d.saturating_sub(pre);
            self.gram.push(ir[lo..lo + n].iter().map(|c| 20.0 * (c.norm() / peak).max(1e-9).log10()).collect());
        }
        let mut picked: Vec<(f64, f64)> =
            arrivals.iter().map(|r| (r.lag_samples / self.fs * self.a, 20.0 * r.amplitude.log10())).collect();
        picked.sort_by(|x, y| x.0.total_cmp(&y.0));
        let first = self.echoes.len();
        for (rank, (pd, db)) in picked.into_iter().enumerate() {
            self.echoes.push(RoomEcho {
                chirp,
                rank: rank + 1,
                t_s,
                path_delta_m: pd,
                delta_d_m: self.geom.horizontal_delta_d(pd),
                strength_db: db,
                plane: None,
            });
        }
        label(&mut self.echoes[first..], &self.predicted, self.opts.plane_tolerance_m);
    }

    fn finish(self, chirp_onsets_s: Vec<f64>) -> RoomReport {
        let min_delta_d_m = self.min_lag() / self.fs * self.a;
        let n_chirps = self.found.max(1);
        let clusters =
            cluster(&self.echoes, n_chirps, self.geom, &self.predicted, self.opts.plane_tolerance_m, self.fs, self.a);
        let bins = self.gram.iter().map(Vec::len).min().unwrap_or(0);
        let echogram = (0..bins)
            .map(|i| {
                let v: Vec<f64> = self.gram.iter().map(|g| g[i]).collect();
                ((i as f64 - self.pre as f64) / self.fs * self.a, median(&v).unwrap_or(f64::NAN))
            })
            .collect();
        RoomReport {
            chirp_onsets_s,
            echoes: self.echoes,
            clusters,
            echogram,
            predicted: self.predicted,
            min_delta_d_m,
            max_delta_d_m: self.max_dd,
            calibrated: self.opts.calibration.is_some(),
        }
    }
}

/// Labels one chirp's echoes: for each predicted floor or ceiling echo,
/// the nearest echo within `tol` (only one: a wall echo a few centimetres
/// away keeps its place in the map).
fn label(echoes: &mut [RoomEcho], predicted: &[(&'static str, f64)], tol: f64) {
    for &(name, dd) in predicted {
        let nearest = (0..echoes.len())
            .filter(|&i| echoes[i].plane.is_none() && (echoes[i].path_delta_m - dd).abs() <= tol)
            .min_by(|&i, &j| (echoes[i].path_delta_m - dd).abs().total_cmp(&(echoes[j].path_delta_m - dd).abs()));
        if let Some(i) = nearest {
            echoes[i].plane = Some(name);
        }
    }
}

/// Groups echoes of all chirps by path difference (a new group where
/// consecutive sorted values are more than 1.5 samples apart) and keeps
/// groups seen in at least half the chirps.
fn cluster(
    echoes: &[RoomEcho],
    n_chirps: usize,
    geom: &RoomGeometry,
    predicted: &[(&'static str, f64)],
    tol: f64,
    fs: f64,
    a: f64,
) -> Vec<EchoCluster> {
    let gap = 1.5 * a / fs;
    let mut sorted: Vec<&RoomEcho> = echoes.iter().collect();
    sorted.sort_by(|x, y| x.path_delta_m.total_cmp(&y.path_delta_m));
    let mut groups: Vec<Vec<&RoomEcho>> = Vec::new();
    for e in sorted {
        match groups.last_mut() {
            Some(g) if g.last().is_some_and(|l| e.path_delta_m - l.path_delta_m <= gap) => g.push(e),
            _ => groups.push(vec![e]),
        }
    }
    let need = n_chirps.div_ceil(2);
    let mut out: Vec<EchoCluster> = groups
        .into_iter()
        .filter_map(|g| {
            let mut chirps: Vec<usize> = g.iter().map(|e| e.chirp).collect();
            chirps.sort_unstable();
            chirps.dedup();
            if chirps.len() < need {
                return None;
            }
            let pd = median(&g.iter().map(|e| e.path_delta_m).collect::<Vec<_>>())?;
            let db = median(&g.iter().map(|e| e.strength_db).collect::<Vec<_>>())?;
            Some(EchoCluster {
                path_delta_m: pd,
                delta_d_m: geom.horizontal_delta_d(pd),
                strength_db: db,
                chirps: chirps.len(),
                plane: None,
            })
        })
        .collect();
    for &(name, dd) in predicted {
        let lim = tol;
        if let Some(c) = out
            .iter_mut()
            .filter(|c| c.plane.is_none() && (c.path_delta_m - dd).abs() <= lim)
            .min_by(|x, y| (x.path_delta_m - dd).abs().total_cmp(&(y.path_delta_m - dd).abs()))
        {
            c.plane = Some(name);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geom3(zs: f64, zm: f64) -> RoomGeometry {
        RoomGeometry {
            speaker: Point::new(0.0, 0.0),
            mic: Point::new(3.0, 0.0),
            heights_m: Some((zs, zm)),
            floor_z_m: Some(0.0),
            ceiling_z_m: Some(3.0),
        }
    }

    /// A given `max_delta_d` that is NaN is refused (it searched the default).
    #[test]
    fn a_nan_max_delta_d_is_refused() {
        let e = rir_max_delta_d(Some(f64::NAN), 343.0, 48_000, 48_000.0).unwrap_err().to_string();
        assert_eq!(e, "max_delta_d: must be finite and > 0, got NaN");
        assert_eq!(rir_max_delta_d(None, 343.0, 48_000, 48_000.0).unwrap(), 60.0);
        assert_eq!(rir_max_delta_d(Some(500.0), 343.0, 48_000, 48_000.0).unwrap(), 343.0);
    }

    /// An impulse response too long to search within the audio memory cap
    /// is refused before its transform is allocated (20 M samples took
    /// 3.2 GB, and the CLI's WAV cap allows 1 G samples).
    #[test]
    fn an_impulse_response_too_long_to_search_is_refused() {
        let mut rir = vec![0f32; 27_000_000];
        rir[200] = 1.0;
        let g = RoomGeometry { floor_z_m: None, ceiling_z_m: None, heights_m: None, ..geom3(1.0, 1.0) };
        let e = rir_echoes(&rir, 48_000.0, 343.0, 8.0, &g, &EchoOptions::default()).unwrap_err().to_string();
        assert!(e.contains("the impulse response (27000000 samples) would need about") && e.contains("cut it"), "{e}");
        let e = calibration_response_rir(&rir, 48_000.0, &EchoOptions::default()).unwrap_err().to_string();
        assert!(e.contains("the calibration impulse response (27000000 samples)"), "{e}");
    }

    /// A floor or ceiling on the wrong side of the speaker and mic is named
    /// with its height as a person writes it (1e300 printed 301 digits).
    #[test]
    fn a_floor_or_ceiling_on_the_wrong_side_is_refused_in_short() {
        let g = RoomGeometry { floor_z_m: Some(1e300), ..geom3(1.0, 1.25) };
        let e = g.validate().unwrap_err().to_string();
        assert!(e.contains("1e300 m is not below the speaker (1 m) and the mic (1.25 m)"), "{e}");
        let g = RoomGeometry { ceiling_z_m: Some(-1e300), ..geom3(1.0, 1.25) };
        let e = g.validate().unwrap_err().to_string();
        assert!(e.contains("-1e300 m is not above"), "{e}");
    }

    #[test]
    fn horizontal_delta_d_and_plane_predictions_follow_image_sources() {
        // Speaker and mic 1 m up, 3 m apart: floor image 2 m below →
        // sqrt(9 + 4) − 3 = 0.6056 m; ceiling at 3 m: image at z = 5, Δz = 4 → 5 − 3 = 2 m.
        let g = geom3(1.0, 1.0);
        let p = g.predicted();
        assert!((p[0].1 - (13f64.sqrt() - 3.0)).abs() < 1e-12, "{p:?}");
        assert!((p[1].1 - 2.0).abs() < 1e-12, "{p:?}");
        // Equal heights: horizontal = measured.
        assert!((g.horizontal_delta_d(1.7) - 1.7).abs() < 1e-12);
        // Different heights (Δz = 0.4): d = sqrt(9.16); a wall echo 2 m longer
        // is horizontally sqrt((d+2)² − 0.16) − 3.
        let g = geom3(1.4, 1.0);
        let d = 9.16f64.sqrt();
        assert!((g.horizontal_delta_d(2.0) - (((d + 2.0).powi(2) - 0.16).sqrt() - 3.0)).abs() < 1e-12);
    }

    #[test]
    fn geometry_refuses_a_floor_above_the_mic() {
        let mut g = geom3(1.0, 1.0);
        g.floor_z_m = Some(1.2);
        assert!(g.validate().is_err());
        let flat = RoomGeometry { heights_m: None, ..geom3(1.0, 1.0) };
        assert!(flat.validate().is_err(), "floor without heights");
    }
}
