//! Recordings → chirps → path differences (paper §IV), and a moving
//! listener's recording → echoes for a map.

use crate::error::{Error, Result};
use chirpmap_audio::doppler::{
    DopplerParams, MovingOptions, WavMethod, bank_scales, detect_moving, direct_rate_range, doppler_echoes,
};
use chirpmap_audio::filter::paper_highpass;
use chirpmap_audio::ranging::{ChirpResult, Estimate, RangedChirp, gap_floor_m, range_signal};
use chirpmap_audio::stats::{median, median_ci95};
use chirpmap_audio::synth::pattern_cycle;
use chirpmap_audio::{ChirpTemplate, Method, RangeLimits, wall_distance_m};
use chirpmap_core::error::Num;
use chirpmap_core::scene::SweepKind;
use chirpmap_core::{Echo, LinearChirp, Point, Scene};
use serde::Serialize;

/// Plausible speeds of sound (m/s): from cold air's ~330 with wide margins
/// for other gases, up to water's ~1500.
pub const SPEED_OF_SOUND_RANGE_MPS: (f64, f64) = (100.0, 2000.0);

/// The known chirp of a recording and the medium.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ChirpSpec {
    /// Start frequency (Hz). Paper: 10 kHz.
    pub f_start_hz: f64,
    /// End frequency (Hz). Paper: 0.2 kHz.
    pub f_end_hz: f64,
    /// Sweep duration T (s).
    pub duration_s: f64,
    /// Speed of sound (m/s).
    pub speed_of_sound_mps: f64,
    /// Largest path difference searched (m); `None`: min(60, a·T/2).
    pub max_delta_d_m: Option<f64>,
    /// Shape of the sweep (the scene's `[chirp] kind`); the paper's is linear.
    pub kind: SweepKind,
}

impl Default for ChirpSpec {
    /// The scene's defaults, so that `synth` on a scene without `[chirp]`
    /// and `range` with its defaults agree.
    fn default() -> Self {
        Self::from_scene(&Scene::default())
    }
}

impl ChirpSpec {
    /// The chirp and speed of sound of a scene (what `synth` renders).
    pub fn from_scene(scene: &Scene) -> Self {
        Self {
            f_start_hz: scene.chirp.f_start,
            f_end_hz: scene.chirp.f_end,
            duration_s: scene.chirp.duration,
            speed_of_sound_mps: scene.world.speed_of_sound,
            max_delta_d_m: None,
            kind: scene.chirp.kind,
        }
    }
}

/// One channel, high-passed as the paper does (100 Hz), with its chirp
/// template and search limits: the input of every ranging step.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// High-passed samples.
    pub x: Vec<f32>,
    /// The known chirp, sampled.
    pub tpl: ChirpTemplate,
    /// Path-difference search limits.
    pub lim: RangeLimits,
    /// Sample rate (Hz).
    pub sample_rate_hz: f64,
    /// Length of the channel (s).
    pub duration_s: f64,
}

/// Validates the chirp against the channel and prepares it for ranging.
pub fn prepare(x: Vec<f32>, sample_rate_hz: f64, chirp: &ChirpSpec) -> Result<Prepared> {
    prepare_inner(x, sample_rate_hz, chirp, false)
}

impl Prepared {
    /// [`prepare`] for a moving listener's recording: any sweep shape is
    /// accepted (the Doppler method ranges through the sweep's inverse; the
    /// template then only carries the band and duration).
    pub fn for_moving(x: Vec<f32>, sample_rate_hz: f64, chirp: &ChirpSpec) -> Result<Prepared> {
        prepare_inner(x, sample_rate_hz, chirp, true)
    }
}

/// The speed of sound, if plausible ([`SPEED_OF_SOUND_RANGE_MPS`]).
pub(crate) fn check_speed(a: f64) -> Result<f64> {
    let (lo, hi) = SPEED_OF_SOUND_RANGE_MPS;
    if !(a.is_finite() && (lo..=hi).contains(&a)) {
        return Err(Error::Field {
            field: "speed_of_sound",
            reason: format!("must be between {lo} and {hi} m/s (air: about 343), got {}", chirpmap_core::error::Num(a)),
        });
    }
    Ok(a)
}

fn prepare_inner(mut x: Vec<f32>, sample_rate_hz: f64, chirp: &ChirpSpec, any_sweep: bool) -> Result<Prepared> {
    check_speed(chirp.speed_of_sound_mps)?;
    if x.iter().all(|v| *v == 0.0) {
        return Err(Error::Invalid("the channel is silent (every sample is zero)".into()));
    }
    let (tpl, lim) = template_and_limits(x.len(), sample_rate_hz, chirp, any_sweep)?;
    paper_highpass(sample_rate_hz)?.filter_in_place(&mut x);
    let duration_s = x.len() as f64 / sample_rate_hz;
    Ok(Prepared { x, tpl, lim, sample_rate_hz, duration_s })
}

/// The chirp's template and search limits for a channel of `len` samples,
/// validated against it.
fn template_and_limits(
    len: usize,
    sample_rate_hz: f64,
    chirp: &ChirpSpec,
    any_sweep: bool,
) -> Result<(ChirpTemplate, RangeLimits)> {
    let a = chirp.speed_of_sound_mps;
    if chirp.kind != SweepKind::Linear && !any_sweep {
        return Err(Error::Field {
            field: "sweep",
            reason: format!("{:?} sweeps are not ranged by this pipeline; it needs a linear chirp", chirp.kind),
        });
    }
    let sweep = LinearChirp::new(chirp.f_start_hz, chirp.f_end_hz, chirp.duration_s)?;
    let tpl = ChirpTemplate::new(sweep, sample_rate_hz)?;
    if tpl.len() > len {
        return Err(Error::Field {
            field: "duration",
            reason: format!(
                "the chirp ({} s) is longer than the recording ({:.3} s)",
                chirp.duration_s,
                len as f64 / sample_rate_hz
            ),
        });
    }
    let mut lim = RangeLimits::for_chirp(chirp.duration_s, a);
    if let Some(m) = chirp.max_delta_d_m {
        if !(m.is_finite() && m > lim.min_delta_d_m) {
            return Err(Error::Field {
                field: "max_delta_d",
                reason: format!("must be > {} m", chirpmap_core::error::Num(lim.min_delta_d_m)),
            });
        }
        // A reflection later than one chirp no longer overlaps its direct
        // sound, and the search window would reach the next chirp.
        let most = a * chirp.duration_s;
        if m > most {
            return Err(Error::Field {
                field: "max_delta_d",
                reason: format!(
                    "{} m is longer than a·T = {most:.1} m (speed of sound × chirp duration); echoes that late are \
                     not ranged",
                    chirpmap_core::error::Num(m)
                ),
            });
        }
        lim.max_delta_d_m = m;
    }
    Ok((tpl, lim))
}

/// Where the speaker and the microphone stand, and optionally the wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeGeometry {
    /// Speaker position (m).
    pub speaker: Point,
    /// Microphone position (m).
    pub mic: Point,
    /// Direction from the speaker toward the wall; adds wall distances.
    pub wall_normal: Option<Point>,
}

impl RangeGeometry {
    /// Refuses coincident speaker and microphone and a zero wall normal.
    pub fn validate(&self) -> Result<()> {
        if self.speaker.dist(self.mic) < 1e-9 {
            return Err(Error::Invalid(format!(
                "speaker and mic are the same point ({}, {}); the direct distance must be > 0",
                self.speaker.x, self.speaker.y
            )));
        }
        if let Some(n) = self.wall_normal
            && !(n.x.is_finite() && n.y.is_finite() && n.x.hypot(n.y) >= 1e-12)
        {
            return Err(Error::Invalid("the wall normal must be finite and not zero".into()));
        }
        Ok(())
    }
}

/// Wall-distance statistics of one method (present with a wall normal).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WallStats {
    /// Median speaker-to-wall distance (m).
    pub wall_distance_median: Option<f64>,
    /// Its 95 % confidence interval (order statistics).
    pub wall_distance_ci95: Option<[f64; 2]>,
}

/// One method's result over all chirps (paper Fig. 9: median and 95 % CI).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodSummary {
    /// `gap`, `matched` or `dechirp`.
    pub method: &'static str,
    /// Chirps detected.
    pub chirps: usize,
    /// Chirps with a reflection found.
    pub estimates: usize,
    /// Median Δd (m).
    pub delta_d_median: Option<f64>,
    /// Its 95 % confidence interval.
    pub delta_d_ci95: Option<[f64; 2]>,
    /// Wall distances, with a wall normal.
    #[serde(flatten)]
    pub wall: Option<WallStats>,
}

/// Every chirp of a recording, ranged by one or more methods.
#[derive(Debug, Clone)]
pub struct RangeReport {
    /// The methods, in the order of the per-chirp estimates.
    pub methods: Vec<Method>,
    /// Per method, one row per detected chirp.
    pub per_method: Vec<Vec<ChirpResult>>,
    /// Per method, the summary.
    pub summaries: Vec<MethodSummary>,
    /// Detections with their estimates (one per method).
    pub chirps: Vec<RangedChirp>,
    /// The gap method's resolution floor for this chirp (m).
    pub gap_resolution_floor_m: f64,
}

/// Detects every chirp and ranges each one with every method (paper §IV.A).
pub fn range(prep: &Prepared, methods: &[Method], geom: &RangeGeometry) -> Result<RangeReport> {
    geom.validate()?;
    if methods.is_empty() {
        return Err(Error::Invalid("no ranging method given".into()));
    }
    let chirps = range_signal(&prep.x, &prep.tpl, methods, &prep.lim)?;
    Ok(report_of(chirps, methods, geom, prep.sample_rate_hz, &prep.tpl, &prep.lim))
}

/// A [`RangeReport`] of a WAV file read as a stream, with the samples the
/// figures of the middle chirp need.
#[derive(Debug, Clone)]
pub struct StreamedRange {
    /// The report, the same as [`prepare`] then [`range`] give.
    pub report: RangeReport,
    /// The recording's parameters; `x` holds only the middle chirp's
    /// window (from 50 ms before its onset to 150 ms after its end).
    pub prep: Prepared,
    /// Index in the recording of `prep.x[0]`.
    pub window_start: usize,
    /// Samples at full scale over all channels.
    pub clipped_samples: usize,
}

impl RangeReport {
    /// [`prepare`] then [`range`] on channel `channel` of a WAV file, in
    /// memory independent of the recording's length (issue 14, item 4):
    /// the file is read as a stream for the detection
    /// ([`chirpmap_audio::stream`]), then again for each chirp's window.
    /// The same report, bit for bit. `Ok(None)`: the recording's level
    /// changes too much along it for the streamed median; use [`prepare`].
    pub fn from_wav_stream(
        path: &std::path::Path,
        channel: usize,
        chirp: &ChirpSpec,
        methods: &[Method],
        geom: &RangeGeometry,
    ) -> Result<Option<StreamedRange>> {
        use chirpmap_audio::stream::{Filtered, PerThread, Visitor, for_windows, scan_visiting, select_reading};
        use chirpmap_audio::wav::WavStream;
        let open = || WavStream::open(path, channel);
        let wav = open()?;
        let fs = f64::from(wav.sample_rate_hz);
        let n = wav.frames;
        check_speed(chirp.speed_of_sound_mps)?;
        let (tpl, lim) = template_and_limits(n, fs, chirp, false)?;
        geom.validate()?;
        if methods.is_empty() {
            return Err(Error::Invalid("no ranging method given".into()));
        }
        let sos = paper_highpass(fs)?;
        let m = tpl.len();
        // What the methods read (matched: 64 samples before the onset to the
        // largest delay after the chirp) and the figures (50 ms before, 150 ms after).
        let dmax = (lim.max_delta_d_m / lim.speed_of_sound_mps * fs).ceil() as usize;
        let (plot_before, plot_after) = ((0.05 * fs) as usize, m + (0.15 * fs) as usize);
        let before = plot_before.max(64);
        let after = (m + dmax + 64).max(plot_after);
        // One ranging engine (FFT plans, cached direct-path models) per thread; estimates are
        // pure functions of the window, whichever engine computes them.
        let rangers: PerThread<chirpmap_audio::Ranger> = PerThread::default();
        let estimate = |x: &[f32], r: usize| -> Vec<Option<Estimate>> {
            rangers.with(|ranger| methods.iter().map(|&meth| ranger.estimate(meth, x, r, &tpl, &lim)).collect())
        };
        // One read ranges the likely chirps as the detection passes them.
        let delay_s = lim.max_delta_d_m / lim.speed_of_sound_mps;
        let Some(FirstPass { scan: (scan, mut visits), clipped, checkpoints }) =
            first_pass(wav, &sos, channel, |src| {
                scan_visiting(src, n, &tpl, delay_s, Visitor { before, after, visit: &estimate })
            })?
        else {
            return Ok(None);
        };
        let reopen = || Ok(Filtered::resume(open()?, &sos, checkpoints.clone()));
        let dets = select_reading(&scan, &mut visits.ncc, reopen)?;
        // A second read only for the chirps the first did not range, and the middle chirp's figures.
        let mid = dets.len() / 2;
        let mut estimates: Vec<Option<Vec<Option<Estimate>>>> =
            dets.iter().map(|d| visits.results.remove(&d.onset_sample)).collect();
        let want: Vec<usize> = (0..dets.len()).filter(|&k| k == mid || estimates[k].is_none()).collect();
        let ranges: Vec<(usize, usize)> =
            want.iter().map(|&k| (dets[k].onset_sample.saturating_sub(before), dets[k].onset_sample + after)).collect();
        let (mut window, mut window_start) = (Vec::new(), 0);
        for_windows(&mut reopen()?, n, &ranges, |i, x| {
            let k = want[i];
            let r = dets[k].onset_sample - ranges[i].0;
            if estimates[k].is_none() {
                estimates[k] = Some(estimate(x, r));
            }
            if k == mid {
                let s0 = r.saturating_sub(plot_before);
                window = x[s0..(r + plot_after).min(x.len())].to_vec();
                window_start = ranges[i].0 + s0; // where `window` starts in the recording
            }
        })?;
        let estimates: Vec<Vec<Option<Estimate>>> =
            estimates.into_iter().map(|e| e.unwrap_or_else(|| vec![None; methods.len()])).collect();
        let chirps: Vec<RangedChirp> = dets.into_iter().zip(estimates).collect();
        let report = report_of(chirps, methods, geom, fs, &tpl, &lim);
        let prep = Prepared { x: window, tpl, lim, sample_rate_hz: fs, duration_s: n as f64 / fs };
        Ok(Some(StreamedRange { report, prep, window_start, clipped_samples: clipped }))
    }
}

fn report_of(
    chirps: Vec<RangedChirp>,
    methods: &[Method],
    geom: &RangeGeometry,
    fs: f64,
    tpl: &ChirpTemplate,
    lim: &RangeLimits,
) -> RangeReport {
    let per_method: Vec<Vec<ChirpResult>> = (0..methods.len())
        .map(|k| {
            chirps
                .iter()
                .enumerate()
                .map(|(i, (d, e))| ChirpResult { index: i, onset_s: d.onset_sample as f64 / fs, estimate: e[k] })
                .collect()
        })
        .collect();
    let summaries = per_method.iter().zip(methods).map(|(rows, &m)| summarise(m, rows, geom)).collect();
    RangeReport {
        methods: methods.to_vec(),
        per_method,
        summaries,
        chirps,
        gap_resolution_floor_m: gap_floor_m(tpl, lim.speed_of_sound_mps),
    }
}

/// What `range` reports about a recording (the keys of its summary.json).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RangeSummary {
    /// The primary method's summary (its keys come first).
    #[serde(flatten)]
    pub primary: MethodSummary,
    /// Sample rate (Hz).
    pub sample_rate_hz: f64,
    /// Length of the recording (s).
    pub recording_s: f64,
    /// Speaker position `[x, y]` (m).
    pub speaker: [f64; 2],
    /// Microphone position `[x, y]` (m).
    pub mic: [f64; 2],
    /// The chirp: `f_start`, `f_end` (Hz), `duration` (s).
    pub chirp: ChirpSummary,
    /// Largest path difference searched (m).
    pub max_delta_d_m: f64,
    /// The gap method's resolution floor for this chirp (m).
    pub gap_resolution_floor_m: f64,
    /// Every method's summary, when several were run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compare: Option<Vec<MethodSummary>>,
}

/// The chirp as summaries record it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ChirpSummary {
    /// Start frequency (Hz).
    pub f_start: f64,
    /// End frequency (Hz).
    pub f_end: f64,
    /// Duration (s).
    pub duration: f64,
}

impl RangeReport {
    /// The summary with `methods[primary]` first (`compare` lists all
    /// methods when there are several).
    pub fn summary(&self, prep: &Prepared, chirp: &ChirpSpec, geom: &RangeGeometry, primary: usize) -> RangeSummary {
        RangeSummary {
            primary: self.summaries.get(primary).or(self.summaries.first()).cloned().unwrap_or(MethodSummary {
                method: "",
                chirps: 0,
                estimates: 0,
                delta_d_median: None,
                delta_d_ci95: None,
                wall: None,
            }),
            sample_rate_hz: prep.sample_rate_hz,
            recording_s: prep.duration_s,
            speaker: [geom.speaker.x, geom.speaker.y],
            mic: [geom.mic.x, geom.mic.y],
            chirp: ChirpSummary { f_start: chirp.f_start_hz, f_end: chirp.f_end_hz, duration: chirp.duration_s },
            max_delta_d_m: prep.lim.max_delta_d_m,
            gap_resolution_floor_m: self.gap_resolution_floor_m,
            compare: (self.summaries.len() > 1).then(|| self.summaries.clone()),
        }
    }
}

/// The speaker-to-wall distance of one Δd, with a wall normal.
pub fn wall_distance(geom: &RangeGeometry, delta_d_m: f64) -> Option<f64> {
    geom.wall_normal.and_then(|n| wall_distance_m(geom.speaker, geom.mic, n, delta_d_m))
}

fn summarise(method: Method, rows: &[ChirpResult], geom: &RangeGeometry) -> MethodSummary {
    let dds: Vec<f64> = rows.iter().filter_map(|r| r.estimate.map(|e| e.delta_d_m)).collect();
    let wall = geom.wall_normal.map(|_| {
        let ws: Vec<f64> = dds.iter().filter_map(|&d| wall_distance(geom, d)).collect();
        WallStats { wall_distance_median: median(&ws), wall_distance_ci95: median_ci95(&ws) }
    });
    MethodSummary {
        method: method.name(),
        chirps: rows.len(),
        estimates: dds.len(),
        delta_d_median: median(&dds),
        delta_d_ci95: median_ci95(&dds),
        wall,
    }
}

/// The largest ratio of the poses' span to the recording's length accepted
/// ([`PoseTrack::check_span`]). Poses may outlast a recording (a log started
/// earlier), but times in milliseconds against a recording in seconds give
/// a ratio near 1000.
pub const MAX_SPAN_RATIO: f64 = 100.0;

/// A listener's positions over time, linearly interpolated between poses.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseTrack {
    rows: Vec<(f64, Point)>,
}

impl PoseTrack {
    /// Poses `(t_s, position)`: finite, strictly increasing times (a repeated
    /// time with the same position is kept once; with another position it is
    /// a conflict).
    pub fn new(mut rows: Vec<(f64, Point)>) -> Result<Self> {
        if rows.is_empty() {
            return Err(Error::Invalid("no poses".into()));
        }
        if let Some((t, p)) = rows.iter().find(|(t, p)| !(t.is_finite() && p.x.is_finite() && p.y.is_finite())) {
            return Err(Error::Invalid(format!("pose at t = {t} s, ({}, {}) is not finite", p.x, p.y)));
        }
        if let Some((t, p)) = rows.iter().find(|(_, p)| !p.is_sane()) {
            return Err(Error::Invalid(format!(
                "pose at t = {} s: position {p} is beyond ±{} m",
                Num(*t),
                Num(chirpmap_core::geometry::MAX_COORD_M)
            )));
        }
        rows.sort_by(|a, b| a.0.total_cmp(&b.0));
        rows.dedup_by(|b, a| a.0 == b.0 && a.1 == b.1);
        if let Some(w) = rows.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(Error::Invalid(format!("two different poses at t = {} s", w[0].0)));
        }
        Ok(Self { rows })
    }

    /// Refuses poses between which the listener moves at or above
    /// `speed_of_sound_mps`: no echo can be ranged from such a walk (a scene
    /// refuses such a listener alike), and such poses are a unit or column
    /// mix-up (poses 30 m apart every 10 ms mapped garbage, 66 times as
    /// slowly as the true poses).
    pub fn check_speed(&self, speed_of_sound_mps: f64) -> Result<()> {
        let step = |w: &[(f64, Point)]| w[1].1.dist(w[0].1) / (w[1].0 - w[0].0);
        let fastest = self.rows.windows(2).max_by(|a, b| step(a).total_cmp(&step(b)));
        match fastest {
            Some(w) if step(w) >= speed_of_sound_mps => Err(Error::Invalid(format!(
                "the listener moves at {} m/s between the poses at t = {} s and {} s, at least the speed of sound \
                 ({} m/s): are the times in seconds and the positions in metres?",
                Num(step(w)),
                Num(w[0].0),
                Num(w[1].0),
                Num(speed_of_sound_mps)
            ))),
            _ => Ok(()),
        }
    }

    /// Checks the poses' times against a recording of `recording_s` seconds:
    /// they must overlap `[0, recording_s]`, and their span must not exceed
    /// [`MAX_SPAN_RATIO`] × the recording (times in milliseconds against a
    /// recording in seconds are refused instead of silently mapping nothing).
    pub fn check_span(&self, recording_s: f64) -> Result<()> {
        let (t0, t1) = self.span();
        if !(recording_s.is_finite() && recording_s > 0.0) {
            return Err(Error::Invalid(format!(
                "the recording's length must be finite and > 0 s, got {}",
                Num(recording_s)
            )));
        }
        if t0 > recording_s || t1 < 0.0 {
            return Err(Error::Invalid(format!(
                "the poses span {}–{} s but the recording lasts {} s: they do not overlap (are the times in \
                 seconds from the start of the recording?)",
                Num(t0),
                Num(t1),
                Num(recording_s)
            )));
        }
        if t1 - t0 > MAX_SPAN_RATIO * recording_s {
            return Err(Error::Invalid(format!(
                "the poses span {} s, more than {MAX_SPAN_RATIO} times the {} s recording: are the times in \
                 milliseconds?",
                Num(t1 - t0),
                Num(recording_s)
            )));
        }
        Ok(())
    }

    /// The poses, sorted by time.
    pub fn rows(&self) -> &[(f64, Point)] {
        &self.rows
    }

    /// First and last pose times (s).
    pub fn span(&self) -> (f64, f64) {
        (self.rows.first().map_or(0.0, |r| r.0), self.rows.last().map_or(0.0, |r| r.0))
    }

    /// Position at `t_s`; `None` outside the poses' span.
    pub fn at(&self, t_s: f64) -> Option<Point> {
        let k = self.rows.partition_point(|r| r.0 <= t_s);
        if k == 0 {
            return None;
        }
        let (t0, p0) = self.rows[k - 1];
        let Some(&(t1, p1)) = self.rows.get(k) else {
            return (t_s - t0 < 1e-9).then_some(p0);
        };
        let u = (t_s - t0) / (t1 - t0);
        Some(p0 + (p1 - p0) * u)
    }
}

/// How a moving listener's recording is cut into measurements.
pub type FrameParams = chirpmap_audio::frames::FrameParams;

/// Echoes of a moving listener's recording, with what was skipped.
#[derive(Debug, Clone)]
pub struct RecordingEchoes {
    /// One echo per reflection per measurement frame.
    pub echoes: Vec<Echo>,
    /// Chirps detected in the recording.
    pub chirps: usize,
    /// Chirps skipped because the poses do not cover them.
    pub chirps_without_pose: usize,
    /// Per echo (same order), the estimated rate of its path difference
    /// Δḋ (m/s) when the method estimates it (issue 11: `delta_d_rate`).
    pub delta_d_rates_mps: Vec<Option<f64>>,
}

/// Detects the chirps, then makes one measurement per period at the
/// listener's pose (paper §III.B's sampling period on a real recording).
pub fn echoes_from_recording(prep: &Prepared, poses: &PoseTrack, params: &FrameParams) -> Result<RecordingEchoes> {
    let mut cache = chirpmap_audio::spectrum::FftCache::default();
    let dets = chirpmap_audio::detect_chirps(
        &prep.x,
        &prep.tpl,
        &mut cache,
        prep.lim.max_delta_d_m / prep.lim.speed_of_sound_mps,
    )?;
    let fs = prep.sample_rate_hz;
    let covered = dets.iter().filter(|d| poses.at(d.onset_sample as f64 / fs).is_some()).count();
    if covered == 0 {
        let (p0, p1) = poses.span();
        let t_end = |d: &chirpmap_audio::Detection| (d.onset_sample + prep.tpl.len()) as f64 / fs;
        return Err(Error::Invalid(format!(
            "the poses span {p0:.3}–{p1:.3} s but the recording spans 0–{:.3} s and its {} chirp(s) lie at \
             {:.3}–{:.3} s: no chirp has a pose (wrong poses file?)",
            prep.duration_s,
            dets.len(),
            dets.first().map_or(0.0, |d| d.onset_sample as f64 / fs),
            dets.last().map_or(0.0, t_end),
        )));
    }
    let pose_at = |t: f64| poses.at(t);
    let echoes = chirpmap_audio::frames::extract_echoes(&prep.x, &prep.tpl, &prep.lim, &dets, &pose_at, params)?;
    let delta_d_rates_mps = vec![None; echoes.len()];
    Ok(RecordingEchoes { echoes, chirps: dets.len(), chirps_without_pose: dets.len() - covered, delta_d_rates_mps })
}

impl RecordingEchoes {
    /// Echoes of a moving listener's recording by any [`MovingOptions`]
    /// method (issue 11): `gap` and `dechirp` as [`echoes_from_recording`]
    /// (one sweep direction), `doppler` with template-bank detection and the
    /// range–Doppler correction of `chirpmap_audio::doppler`, for any
    /// pattern (alternating up/down sweeps give Δḋ in closed form).
    pub fn from_moving(
        prep: &Prepared,
        chirp: &ChirpSpec,
        poses: &PoseTrack,
        opts: &MovingOptions,
    ) -> Result<RecordingEchoes> {
        poses.check_speed(chirp.speed_of_sound_mps)?;
        poses.check_span(prep.duration_s)?;
        let scene_chirp = chirpmap_core::scene::ChirpSpec {
            f_start: chirp.f_start_hz,
            f_end: chirp.f_end_hz,
            duration: chirp.duration_s,
            kind: chirp.kind,
        };
        let cycle = pattern_cycle(&scene_chirp, opts.pattern);
        let most = chirpmap_audio::doppler::MAX_ECHOES_PER_FRAME;
        if !(1..=most).contains(&opts.echoes_per_frame) {
            return Err(Error::Field {
                field: "echoes per frame",
                reason: format!("must be in 1..={most}, got {}", opts.echoes_per_frame),
            });
        }
        if opts.method != WavMethod::Doppler {
            if opts.echoes_per_frame != 1 {
                return Err(Error::Field {
                    field: "echoes per frame",
                    reason: format!(
                        "{} ranges one echo per frame; use doppler for {} (it tracks each reflection's Doppler shift)",
                        opts.method.name(),
                        opts.echoes_per_frame
                    ),
                });
            }
            if cycle.len() != 1 || chirp.kind != SweepKind::Linear {
                return Err(Error::Field {
                    field: "method",
                    reason: format!(
                        "{} ranges one linear sweep direction; use doppler for {} patterns or {:?} sweeps",
                        opts.method.name(),
                        opts.pattern.map_or("this", |p| p.name()),
                        chirp.kind
                    ),
                });
            }
            let c = &cycle[0];
            let tpl = ChirpTemplate::new(LinearChirp::new(c.f_start, c.f_end, c.duration)?, prep.sample_rate_hz)?;
            let one = Prepared { tpl, ..prep.clone() };
            let params = FrameParams {
                method: if opts.method == WavMethod::Gap { Method::Gap } else { Method::Dechirp },
                period_s: opts.period_s,
                frame_s: opts.frame_s,
                speaker: opts.speaker,
                listener_id: opts.listener_id,
            };
            return echoes_from_recording(&one, poses, &params);
        }
        let sweeps: Vec<Box<dyn chirpmap_core::Sweep>> =
            cycle.iter().map(chirpmap_core::scene::ChirpSpec::build).collect::<Result<_, _>>()?;
        let refs: Vec<&dyn chirpmap_core::Sweep> = sweeps.iter().map(|b| b.as_ref()).collect();
        let a = prep.lim.speed_of_sound_mps;
        let scales = bank_scales(direct_rate_range(poses.rows(), opts.speaker), a);
        let mut cache = chirpmap_audio::spectrum::FftCache::default();
        let dets = detect_moving(&prep.x, prep.sample_rate_hz, &refs, &scales, &mut cache, prep.lim.max_delta_d_m / a)?;
        let fs = prep.sample_rate_hz;
        let covered = dets.iter().filter(|d| poses.at(d.detection.onset_sample as f64 / fs).is_some()).count();
        if covered == 0 {
            let (p0, p1) = poses.span();
            return Err(Error::Invalid(format!(
                "the poses span {p0:.3}–{p1:.3} s but none of the recording's {} chirp(s) (0–{:.3} s) has a pose \
                 (wrong poses file?)",
                dets.len(),
                prep.duration_s
            )));
        }
        let params = DopplerParams {
            period_s: opts.period_s,
            frame_s: opts.frame_s,
            speaker: opts.speaker,
            listener_id: opts.listener_id,
            echoes_per_frame: opts.echoes_per_frame,
        };
        let pose_at = |t: f64| poses.at(t);
        let got = doppler_echoes(&prep.x, fs, &refs, &prep.lim, &dets, &pose_at, &params)?;
        Ok(RecordingEchoes {
            echoes: got.iter().map(|m| m.echo).collect(),
            delta_d_rates_mps: got.iter().map(|m| m.delta_d_rate_mps).collect(),
            chirps: dets.len(),
            chirps_without_pose: dets.len() - covered,
        })
    }
}

/// What the first streamed pass over a recording found: the scan's result,
/// the clipped samples and the high-pass filter's checkpoints for a second
/// read of chirps' windows.
pub(crate) struct FirstPass<T> {
    pub scan: T,
    pub clipped: usize,
    pub checkpoints: Vec<chirpmap_audio::stream::Checkpoint>,
}

/// The first pass shared by the streamed `range` and `range --echoes`:
/// high-pass and `scan` the channel for chirps; a silent channel is an
/// error naming it; `None` when the scan must fall back to detection in memory.
pub(crate) fn first_pass<T>(
    wav: chirpmap_audio::wav::WavStream,
    sos: &chirpmap_audio::filter::Sos,
    channel: usize,
    scan: impl FnOnce(
        &mut chirpmap_audio::stream::Filtered<chirpmap_audio::wav::WavStream>,
    ) -> std::result::Result<T, chirpmap_audio::stream::ScanError>,
) -> Result<Option<FirstPass<T>>> {
    use chirpmap_audio::stream::{Filtered, ScanError};
    let n_channels = wav.n_channels;
    let mut src = Filtered::new(wav, sos);
    let scanned = scan(&mut src);
    // A damaged file is reported as such, not as the silence read before the damage.
    let damaged = matches!(
        scanned,
        Err(ScanError::Audio(chirpmap_audio::AudioError::Truncated(_) | chirpmap_audio::AudioError::NonFinite { .. }))
    );
    if !src.any_nonzero_input && !damaged {
        let hint =
            if n_channels > 1 { format!(" (it has {n_channels} channels: try --channel)") } else { String::new() };
        return Err(Error::Invalid(format!("channel {channel} is silent (every sample is zero){hint}")));
    }
    let clipped = src.inner().clipped_samples();
    let checkpoints = std::mem::take(&mut src.checkpoints);
    match scanned {
        Ok(scan) => Ok(Some(FirstPass { scan, clipped, checkpoints })),
        Err(ScanError::MedianLost) => Ok(None),
        Err(ScanError::Audio(e)) => Err(e.into()),
    }
}

#[cfg(test)]
mod tests {

    /// Poses checked as the CLI checks its poses file, for every caller of
    /// the facade (the Python package took poses at 10 km/s, 1e300 m away or
    /// in milliseconds without a word): positions within ±10⁶ m, a listener
    /// below the speed of sound, times overlapping the recording and
    /// spanning at most 100 times it.
    #[test]
    fn poses_are_checked_for_every_caller() {
        let p = |rows: &[(f64, f64)]| PoseTrack::new(rows.iter().map(|&(t, x)| (t, Point::new(x, 10.0))).collect());
        let e = p(&[(0.0, -3.0), (4.5, 1e300)]).unwrap_err().to_string();
        assert!(e.contains("pose at t = 4.5 s: position (1e300, 10) is beyond ±1000000 m"), "{e}");
        let walk = p(&[(0.0, -3.0), (4.5, 42.0)]).unwrap();
        walk.check_speed(343.0).unwrap();
        walk.check_span(4.5).unwrap();
        let fast = p(&[(0.0, -3000.0), (4.5, 42000.0)]).unwrap();
        let e = fast.check_speed(343.0).unwrap_err().to_string();
        assert!(e.starts_with("the listener moves at 10000 m/s between the poses at t = 0 s and 4.5 s"), "{e}");
        let ms = p(&[(0.0, -3.0), (4500.0, 42.0)]).unwrap();
        let e = ms.check_span(4.5).unwrap_err().to_string();
        assert!(e.contains("more than 100 times the 4.5 s recording: are the times in milliseconds?"), "{e}");
        let late = p(&[(10.0, -3.0), (14.5, 42.0)]).unwrap();
        assert!(late.check_span(4.5).unwrap_err().to_string().contains("they do not overlap"));
    }

    use super::*;

    #[test]
    fn pose_track_interpolates_and_refuses_conflicts() {
        let t = PoseTrack::new(vec![(1.0, Point::new(2.0, 0.0)), (0.0, Point::new(0.0, 0.0))]).expect("valid");
        assert_eq!(t.at(0.5), Some(Point::new(1.0, 0.0)));
        assert_eq!(t.at(-0.1), None);
        assert_eq!(t.at(1.5), None);
        assert_eq!(t.span(), (0.0, 1.0));
        assert!(PoseTrack::new(vec![(0.0, Point::new(0.0, 0.0)), (0.0, Point::new(1.0, 0.0))]).is_err());
        assert!(PoseTrack::new(vec![(0.0, Point::new(0.0, 0.0)), (0.0, Point::new(0.0, 0.0))]).is_ok());
        assert!(PoseTrack::new(vec![(f64::NAN, Point::new(0.0, 0.0))]).is_err());
    }

    #[test]
    fn chirp_defaults_agree_with_the_scene() {
        let c = ChirpSpec::default();
        let s = Scene::default();
        assert_eq!((c.f_start_hz, c.f_end_hz, c.duration_s), (s.chirp.f_start, s.chirp.f_end, s.chirp.duration));
    }
}
