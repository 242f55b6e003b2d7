//! Waveform synthesizer (issue 5, item 1): what a listener's microphone
//! records when the Source plays a chirp train in a scene.
//!
//! Model (docs/architecture.md, physics notes): a static source and static reflectors
//! make image sources static, so a moving listener at `x_L(t)` records
//! exactly `y(t) = Σᵢ gᵢ · s(t − rᵢ(x_L(t))/a)` with `rᵢ` the length of path
//! i — Doppler follows from the geometry, with the exact propagation delay
//! per sample. Paths: the direct one and first-order specular reflections
//! (polygon edges by image sources; circles by their specular point, which
//! is recomputed every pose block; by Fermat's principle the path length is
//! stationary in the point, so per-sample delays stay exact to first order).
//! Gains (ours; the paper's field test gives none): spherical spreading 1/r
//! (r clamped at 0.1 m) and (1 − absorption) per bounce. Roughness is not
//! rendered (specular only) and occlusion is not modelled. Reflections are
//! first-order, or with `reflection_order = 2` also every ordered pair of
//! polygon edges (a room's corner echoes). A polygon around the source is a
//! room (its walls reflect inward), any other a solid obstacle.

mod streamed;

pub use streamed::{CHUNK_FRAMES, SynthStream, synthesize_streamed};

use crate::detect::taper_gain;
use crate::error::AudioError;
use crate::wav::SampleFormat;
use chirpmap_core::error::Num;
use chirpmap_core::geometry::{point_segment_distance, specular_point_on_circle};
use chirpmap_core::scene::{ChirpSpec, ListenerSpec, SweepKind};
use chirpmap_core::{Obstacle, Point, Scene, Shape};

/// Most chirps one rendering plays (the paper plays 50).
pub const MAX_CHIRPS: usize = 1_000_000;
/// Longest gap, lead-in or tail (s): a day.
pub const MAX_SPAN_S: f64 = 86_400.0;
/// Shortest pose period (s): a microsecond, far below any tracker.
pub const MIN_POSE_PERIOD_S: f64 = 1e-6;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// Most samples one listener's recording may have (a WAV's 32-bit data size
/// holds at most ~2.1·10⁹ 16-bit samples).
const MAX_SAMPLES: usize = 2_000_000_000;

/// The `[synth]` table of a scene file. It lives beside the core scene
/// schema (which rejects unknown keys) and is split off before the scene is
/// parsed, so the core schema does not change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SynthConfig {
    /// Number of chirps. Paper §IV.A: 50.
    pub chirps: usize,
    /// Silence between chirps (s). Paper §IV.A: 1 s.
    pub gap_s: f64,
    /// Time of the first chirp's emission (s after the recording starts).
    pub start_s: f64,
    /// Recording kept after the last chirp ends (s), for late echoes.
    pub tail_s: f64,
    /// Raised-cosine fade at each chirp end (s).
    pub taper_s: f64,
    /// Paper §IV.A (AudioMoth): 48 kHz.
    pub sample_rate_hz: u32,
    /// "16", "24", "32" (integer PCM) or "f32".
    pub bits: String,
    /// Signal-to-noise ratio (dB) of added white Gaussian noise, relative to
    /// the mean power of the signal while it sounds; none = no noise.
    pub snr_db: Option<f64>,
    /// Seed of the noise stream.
    pub noise_seed: u64,
    /// Peak level of the written signal (full scale = 1).
    pub peak: f64,
    /// Period of the rows written to the poses CSV (s).
    pub pose_period_s: f64,
    /// Direction of the chirps (issue 11): `"down"`, `"up"` or `"updown"`
    /// (alternating, starting down); none = every chirp as `[chirp]` writes it.
    pub pattern: Option<ChirpPattern>,
    /// Highest reflection order rendered: 1 (each reflector once) or 2 (also
    /// every pair of polygon edges: a room's corner echoes, issue 9).
    pub reflection_order: u32,
}

/// Sweep directions of a chirp train (issue 11, item 1). Alternating up and
/// down sweeps separate range from Doppler in closed form (a linear chirp's
/// Δd error is (f/k)·Δḋ, of opposite sign for the two directions).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChirpPattern {
    /// Every chirp sweeps from the higher frequency to the lower.
    Down,
    /// Every chirp sweeps from the lower frequency to the higher.
    Up,
    /// Chirps alternate down, up, down, …
    Updown,
}

impl ChirpPattern {
    /// Lower-case name, as a scene file spells it.
    pub fn name(self) -> &'static str {
        match self {
            ChirpPattern::Down => "down",
            ChirpPattern::Up => "up",
            ChirpPattern::Updown => "updown",
        }
    }
}

impl std::str::FromStr for ChirpPattern {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "down" => Ok(ChirpPattern::Down),
            "up" => Ok(ChirpPattern::Up),
            "updown" => Ok(ChirpPattern::Updown),
            o => Err(format!("unknown chirp pattern {o:?}: use down, up or updown")),
        }
    }
}

/// The cycle of chirps a pattern plays: chirp `i` of the train is
/// `cycle[i % cycle.len()]`. `None` plays `chirp` as written.
pub fn pattern_cycle(chirp: &ChirpSpec, pattern: Option<ChirpPattern>) -> Vec<ChirpSpec> {
    let (hi, lo) = (chirp.f_start.max(chirp.f_end), chirp.f_start.min(chirp.f_end));
    let down = ChirpSpec { f_start: hi, f_end: lo, ..chirp.clone() };
    let up = ChirpSpec { f_start: lo, f_end: hi, ..chirp.clone() };
    match pattern {
        None => vec![chirp.clone()],
        Some(ChirpPattern::Down) => vec![down],
        Some(ChirpPattern::Up) => vec![up],
        Some(ChirpPattern::Updown) => vec![down, up],
    }
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            chirps: 50,
            gap_s: 1.0,
            start_s: 0.5,
            tail_s: 0.5,
            taper_s: crate::detect::DEFAULT_TAPER_S,
            sample_rate_hz: 48_000,
            bits: "16".into(),
            snr_db: None,
            noise_seed: 1,
            peak: 0.5,
            pose_period_s: 0.01,
            pattern: None,
            reflection_order: 1,
        }
    }
}

impl SynthConfig {
    /// The WAV sample format named by `bits` (see [`SampleFormat::parse`]).
    pub fn format(&self) -> Result<SampleFormat, AudioError> {
        SampleFormat::parse(&self.bits)
    }
    /// Every field finite and within its range (errors name the field).
    pub fn validate(&self) -> Result<(), AudioError> {
        let bad = |field: &'static str, reason: String| Err(AudioError::InvalidParam { field, reason });
        if self.chirps == 0 || self.chirps > MAX_CHIRPS {
            return bad("synth.chirps", format!("must be in 1..={MAX_CHIRPS}, got {}", self.chirps));
        }
        for (f, v) in [("synth.gap_s", self.gap_s), ("synth.start_s", self.start_s), ("synth.tail_s", self.tail_s)] {
            if !(v.is_finite() && (0.0..=MAX_SPAN_S).contains(&v)) {
                return bad(f, format!("must be finite, >= 0 and at most {MAX_SPAN_S} s, got {}", Num(v)));
            }
        }
        if !(self.taper_s.is_finite() && self.taper_s >= 0.0) {
            return bad("synth.taper_s", format!("must be finite and >= 0, got {}", Num(self.taper_s)));
        }
        if !(8_000..=768_000).contains(&self.sample_rate_hz) {
            return bad("synth.sample_rate_hz", format!("must be in 8000..=768000, got {}", self.sample_rate_hz));
        }
        if !(1..=2).contains(&self.reflection_order) {
            return bad("synth.reflection_order", format!("must be 1 or 2, got {}", self.reflection_order));
        }
        if !(self.peak > 0.0 && self.peak <= 1.0) {
            return bad("synth.peak", format!("must be in (0, 1], got {}", Num(self.peak)));
        }
        if !(self.pose_period_s >= MIN_POSE_PERIOD_S && self.pose_period_s.is_finite()) {
            return bad(
                "synth.pose_period_s",
                format!("must be finite and at least {} s, got {}", Num(MIN_POSE_PERIOD_S), Num(self.pose_period_s)),
            );
        }
        // Beyond these the recording is all noise (below −100 dB the chirp is
        // 10⁵ times below it) or, past ~−3000 dB, the noise's scale overflows
        // and the file is silent; above 300 dB the noise is below f32's resolution.
        if let Some(s) = self.snr_db
            && !(s.is_finite() && (-100.0..=300.0).contains(&s))
        {
            return bad("synth.snr_db", format!("must be in [-100, 300] dB, got {}", Num(s)));
        }
        self.format().map(|_| ())
    }
}

/// Splits a scene file into the core scene and the `[synth]` table, and
/// validates both: the scene by the one validation every command shares
/// ([`Scene::validate`]; issue 8, item 11: `synth` used to accept NaN and
/// infinities that `simulate` refused), the table by its own bounds. TOML
/// errors quote a short excerpt of the offending line, once.
pub fn parse_scene_with_synth(text: &str) -> Result<(Scene, SynthConfig), AudioError> {
    let invalid = |m: String| AudioError::InvalidParam { field: "scene", reason: m };
    chirpmap_core::error::check_toml_values(text).map_err(invalid)?;
    let mut table: toml::Table =
        text.parse().map_err(|e: toml::de::Error| invalid(chirpmap_core::error::toml_error(text, &e)))?;
    if let Some(v) = table.get("synth").filter(|v| !v.is_table()) {
        return Err(invalid(format!("`synth` must be a table (`[synth]`), not {}", v.type_str())));
    }
    let split = if table.contains_key("synth") { split_synth_lines(text) } else { None };
    let (scene, cfg) = match (table.remove("synth"), split) {
        (None, _) => (Scene::from_toml_str(text)?, SynthConfig::default()),
        (Some(_), Some((scene_text, synth_text))) => {
            /// The `[synth]` table alone, with the file's line numbers.
            #[derive(Deserialize)]
            #[serde(deny_unknown_fields)]
            struct SynthOnly {
                #[serde(default)]
                synth: SynthConfig,
            }
            let synth: SynthOnly =
                toml::from_str(&synth_text).map_err(|e| invalid(chirpmap_core::error::toml_error(&synth_text, &e)))?;
            (Scene::from_toml_str(&scene_text)?, synth.synth)
        }
        (Some(synth), None) => {
            let cfg: SynthConfig = synth.try_into().map_err(|e: toml::de::Error| {
                invalid(format!("[synth]: {}", chirpmap_core::error::short_message(e.message())))
            })?;
            let rest = toml::to_string(&table).map_err(|e| invalid(e.to_string()))?;
            (Scene::from_toml_str(&rest)?, cfg)
        }
    };
    scene.validate()?;
    cfg.validate()?;
    Ok((scene, cfg))
}

/// Splits a scene file into its `[synth]` table (headers `[synth]` and
/// `[synth.*]` up to the next other header) and the rest, each with the
/// other's lines left empty, so errors in either name the file's own line
/// numbers (the scene used to be parsed from a re-serialised copy, whose
/// line numbers were not the file's). `None` when the table is not written
/// under its own header (an inline `synth = { … }`), or a multi-line string
/// could hide a header.
fn split_synth_lines(text: &str) -> Option<(String, String)> {
    if text.contains("\"\"\"") || text.contains("'''") {
        return None;
    }
    let (mut scene, mut synth) = (String::with_capacity(text.len()), String::new());
    let mut in_synth = false;
    let mut found = false;
    for line in text.split_inclusive('\n') {
        let t = line.trim_start();
        if t.starts_with('[') {
            let name = t.trim_start_matches('[').split(']').next().unwrap_or("").trim();
            in_synth = !t.starts_with("[[") && (name == "synth" || name.starts_with("synth."));
            found |= in_synth;
        }
        let end = if line.ends_with("\r\n") {
            "\r\n"
        } else if line.ends_with('\n') {
            "\n"
        } else {
            ""
        };
        let (mine, other) = if in_synth { (&mut synth, &mut scene) } else { (&mut scene, &mut synth) };
        mine.push_str(line);
        other.push_str(end);
    }
    found.then_some((scene, synth))
}

/// Bytes [`synthesize`] will hold at its peak for `scene` and `cfg`: one
/// `f32` channel per listener over the whole recording, plus the poses
/// (24 bytes each) and the chirp start list. Checked against
/// [`crate::error::MEMORY_CAP_BYTES`] before anything is allocated (issue 8,
/// item 9: 50 listeners over an hour needed 35 GB and aborted).
pub fn synth_memory_bytes(scene: &Scene, cfg: &SynthConfig) -> f64 {
    let (samples, poses) = synth_lengths(scene, cfg);
    let listeners = scene.listeners.len() as f64;
    listeners * (samples * 4.0 + poses * 24.0) + cfg.chirps as f64 * 8.0
}

/// Samples per channel and poses per listener of a rendering (as `f64`, so
/// absurd inputs do not overflow before they are refused).
pub fn synth_lengths(scene: &Scene, cfg: &SynthConfig) -> (f64, f64) {
    let period = scene.chirp.duration + cfg.gap_s;
    let total_s = cfg.start_s + cfg.chirps as f64 * period - cfg.gap_s + cfg.tail_s;
    ((total_s * f64::from(cfg.sample_rate_hz)).ceil(), (total_s / cfg.pose_period_s).floor() + 1.0)
}

/// Position of a listener `t_s` after the start: constant speed along a
/// heading that turns at `spin_rate` (rad/s, counter-clockwise positive).
pub fn listener_position(l: &ListenerSpec, t_s: f64) -> Point {
    let th0 = l.heading_deg.to_radians();
    let p0 = Point::new(l.start[0], l.start[1]);
    if l.spin_rate.abs() < 1e-12 {
        return p0 + Point::from_angle(th0) * (l.speed * t_s);
    }
    let r = l.speed / l.spin_rate;
    let th = th0 + l.spin_rate * t_s;
    p0 + Point::new(r * (th.sin() - th0.sin()), -r * (th.cos() - th0.cos()))
}

/// Listener `li`'s poses as [`synthesize`] returns them: `(t, position)`
/// every `pose_period_s` from 0 to the recording's end (none for a listener
/// the scene does not have).
pub fn listener_poses<'a>(scene: &'a Scene, cfg: &SynthConfig, li: usize) -> impl Iterator<Item = (f64, Point)> + 'a {
    let step = cfg.pose_period_s;
    let period = scene.chirp.duration + cfg.gap_s;
    let total_s = cfg.start_s + cfg.chirps as f64 * period - cfg.gap_s + cfg.tail_s;
    let n_pose = if li < scene.listeners.len() { (total_s / step).floor() as usize + 1 } else { 0 };
    (0..n_pose).map(move |k| {
        let t = k as f64 * step;
        (t, listener_position(&scene.listeners[li], t))
    })
}

/// One propagation path during a pose block: length `base + |x_L − q|`.
#[derive(Debug, Clone, Copy)]
struct Path {
    base_m: f64,
    q: Point,
    gain: f64,
}

/// A polygon edge as a mirror: its ends, the unit normal of its reflecting
/// side and the gain of one bounce. A polygon around the source is a room,
/// whose walls reflect on their inner side; any other is a solid obstacle,
/// reflecting on its outer side. (Only outer sides were rendered before: a
/// room's recording held the direct sound and no wall at all.)
#[derive(Debug, Clone, Copy)]
struct Mirror {
    a: Point,
    b: Point,
    n: Point,
    /// The edge's squared length, as `len · len`.
    len2: f64,
    gain: f64,
    /// Index of its polygon among the obstacles.
    obstacle: usize,
}

/// A source on an edge (a speaker on a wall) is neither inside nor outside
/// by the even–odd test (which puts some edges in, others out): there the
/// listener's side decides, at the first of its positions `listener_at(t)`
/// (every 50 ms of its first 10 s) off the polygon's edges (a listener
/// starting on the wall too got no echo at all: review, session 23).
fn mirrors(source: Point, obstacles: &[Obstacle], listener_at: &dyn Fn(f64) -> Point) -> Vec<Mirror> {
    let mut out = Vec::new();
    for (oi, o) in obstacles.iter().enumerate() {
        let Shape::Polygon(poly) = &o.shape else { continue };
        let on_edge = |p: Point| poly.edges().any(|(a, b)| point_segment_distance(p, a, b) <= 1e-9);
        let room = if on_edge(source) {
            let t0 = (0..200).map(|k| listener_at(0.05 * f64::from(k))).find(|&p| !on_edge(p));
            poly.contains(t0.unwrap_or_else(|| listener_at(0.0)))
        } else {
            poly.contains(source)
        };
        let ccw = (poly.signed_area() > 0.0) != room;
        for (a, b) in poly.edges() {
            let e = b - a;
            let len = e.norm();
            if len < 1e-12 {
                continue;
            }
            let n = if ccw { Point::new(e.y, -e.x) } else { Point::new(-e.y, e.x) } * (1.0 / len);
            out.push(Mirror { a, b, n, len2: len * len, gain: 1.0 - o.absorption, obstacle: oi });
        }
    }
    out
}

impl Mirror {
    /// Where the segment from `from` (behind the mirror, at depth `h_from`
    /// > 0) to `to` (in front, at height `h_to` > 0) crosses it, if on the edge.
    fn crossing(&self, from: Point, h_from: f64, to: Point, h_to: f64) -> Option<Point> {
        let hit = from + (to - from) * (h_from / (h_from + h_to));
        let along = (hit - self.a).dot(self.b - self.a) / self.len2;
        (0.0..=1.0).contains(&along).then_some(hit)
    }
}

/// Image sources (Allen and Berkley 1979) of the mirrors that reflect from
/// `source` to `listener`, each mirror once; the reflection point on its edge
/// (no occlusion).
fn first_order(source: Point, mirrors: &[Mirror], listener: Point, out: &mut Vec<Path>) {
    for m in mirrors {
        let (hs, hl) = ((source - m.a).dot(m.n), (listener - m.a).dot(m.n));
        if hs <= 0.0 || hl <= 0.0 {
            continue;
        }
        let image = source - m.n * (2.0 * hs);
        if m.crossing(image, hs, listener, hl).is_some() {
            out.push(Path { base_m: 0.0, q: image, gain: m.gain });
        }
    }
}

/// Second-order image sources: each ordered pair of different mirrors.
fn second_order(source: Point, mirrors: &[Mirror], listener: Point, out: &mut Vec<Path>) {
    for (i, m1) in mirrors.iter().enumerate() {
        let hs = (source - m1.a).dot(m1.n);
        if hs <= 0.0 {
            continue;
        }
        let i1 = source - m1.n * (2.0 * hs);
        for (j, m2) in mirrors.iter().enumerate() {
            if i == j {
                continue;
            }
            // The first image in front of the second mirror, the listener too.
            let (h1, hl) = ((i1 - m2.a).dot(m2.n), (listener - m2.a).dot(m2.n));
            if h1 <= 0.0 || hl <= 0.0 {
                continue;
            }
            let i2 = i1 - m2.n * (2.0 * h1);
            let Some(p2) = m2.crossing(i2, h1, listener, hl) else { continue };
            // The second bounce point in front of the first mirror.
            let hp2 = (p2 - m1.a).dot(m1.n);
            if hp2 <= 0.0 || m1.crossing(i1, hs, p2, hp2).is_none() {
                continue;
            }
            out.push(Path { base_m: 0.0, q: i2, gain: m1.gain * m2.gain });
        }
    }
}

/// The paths from `source` to `listener`: the direct one, then each
/// obstacle's first-order reflections in the scene's order, then (with
/// `order` 2) the wall–wall pairs, both bounce points on their edges (no
/// occlusion, and no circle in a second-order path).
fn paths_at(
    source: Point,
    obstacles: &[Obstacle],
    mirrors: &[Mirror],
    order: u32,
    listener: Point,
    out: &mut Vec<Path>,
) {
    out.clear();
    out.push(Path { base_m: 0.0, q: source, gain: 1.0 });
    for (oi, o) in obstacles.iter().enumerate() {
        match &o.shape {
            Shape::Circle(c) => {
                if let Some(p) = specular_point_on_circle(source, listener, c) {
                    out.push(Path { base_m: source.dist(p), q: p, gain: 1.0 - o.absorption });
                }
            }
            Shape::Polygon(_) => {
                let from = mirrors.partition_point(|m| m.obstacle < oi);
                let to = mirrors.partition_point(|m| m.obstacle <= oi);
                first_order(source, &mirrors[from..to], listener, out);
            }
        }
    }
    if order >= 2 {
        second_order(source, mirrors, listener, out);
    }
}

/// A rendered recording and the listeners' poses.
#[derive(Debug, Clone)]
pub struct Synthesized {
    /// Sampling rate (Hz).
    pub sample_rate_hz: u32,
    /// One channel per listener.
    pub channels: Vec<Vec<f32>>,
    /// Per listener: `(t, position)` every `pose_period_s`.
    pub poses: Vec<Vec<(f64, Point)>>,
    /// Emission time of each chirp's start (s, speaker clock = recorder clock here).
    pub chirp_starts_s: Vec<f64>,
}

/// Samples per pose block: the listener's position is taken at both ends
/// of every block and each path's delay is linear in between. Part of the
/// output's definition: changing it changes the samples.
pub const POSE_BLOCK: usize = 64;

/// `k as f64` for every sample index `k` of a pose block.
const BLOCK_INDEX: [f64; POSE_BLOCK] = {
    let mut t = [0.0; POSE_BLOCK];
    let mut k = 0;
    while k < POSE_BLOCK {
        t[k] = k as f64;
        k += 1;
    }
    t
};

/// `x.floor()` without a call into the C library (the x86-64 baseline has
/// no rounding instruction, and `floor` calls were 7 % of `synth`'s time in
/// a profile). Exact, as `floor` is: `x as i64` truncates exactly below 2⁵²,
/// and the sign of zero is kept.
#[inline(always)]
fn floor_exact(x: f64) -> f64 {
    if x.abs() < 4_503_599_627_370_496.0 {
        let t = x as i64 as f64;
        (if t > x { t - 1.0 } else { t }).copysign(x)
    } else {
        x
    }
}

/// `x.floor()` for `|x| < 2⁵¹`, without a branch: adding and subtracting
/// 1.5 · 2⁵² rounds to the nearest integer exactly in that range, and one
/// is taken off where that went up; the sign of zero is kept.
#[inline(always)]
fn floor_small(x: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    let r = (x + MAGIC) - MAGIC;
    (r - if r > x { 1.0 } else { 0.0 }).copysign(x)
}

/// Everything a rendering needs, checked once: the model of the module
/// documentation, rendered for any run of pose blocks of one listener, so
/// that a recording can be rendered in pieces that are, sample for sample,
/// the whole recording's (issue 14: `synth` streams).
pub(crate) struct Renderer<'a> {
    scene: &'a Scene,
    cfg: &'a SynthConfig,
    sweeps: Vec<Box<dyn chirpmap_core::Sweep>>,
    /// Per sweep of the cycle: `(f0, ½·rate)` of a linear sweep (inlined phase).
    linear: Vec<Option<(f64, f64)>>,
    obstacles: Vec<Obstacle>,
    /// The polygons' edges as mirrors, by obstacle, for each listener.
    mirrors: Vec<Vec<Mirror>>,
    source: Point,
    speed_of_sound: f64,
    fs: f64,
    period_s: f64,
    n: usize,
}

impl std::fmt::Debug for Renderer<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer").field("samples", &self.n).field("listeners", &self.scene.listeners.len()).finish()
    }
}

impl<'a> Renderer<'a> {
    /// Checks `scene` and `cfg` (not the memory cap: that is the caller's)
    /// and prepares the chirps, obstacles and lengths.
    pub fn new(scene: &'a Scene, cfg: &'a SynthConfig) -> Result<Self, AudioError> {
        // One channel per listener: a WAV the readers (`range`, `map --wav`)
        // refuse must not be written (300 listeners made one).
        let max_channels = usize::from(crate::wav::MAX_CHANNELS);
        if scene.listeners.len() > max_channels {
            return Err(AudioError::InvalidParam {
                field: "listeners",
                reason: format!(
                    "{} listeners, but a recording holds at most {max_channels} channels (one per listener); \
                     split them over several scenes",
                    scene.listeners.len()
                ),
            });
        }
        let cycle = pattern_cycle(&scene.chirp, cfg.pattern);
        let sweeps: Vec<Box<dyn chirpmap_core::Sweep>> =
            cycle.iter().map(ChirpSpec::build).collect::<Result<_, _>>()?;
        let obstacles = scene.explicit_obstacles()?;
        let a = scene.world.speed_of_sound;
        if !(a.is_finite() && a > 0.0) {
            return Err(AudioError::InvalidParam { field: "world.speed_of_sound", reason: format!("{a}") });
        }
        let fs = f64::from(cfg.sample_rate_hz);
        if scene.chirp.f_start.max(scene.chirp.f_end) >= fs / 2.0 {
            return Err(AudioError::InvalidParam {
                field: "chirp",
                reason: format!("the sweep exceeds the Nyquist frequency {} Hz", fs / 2.0),
            });
        }
        let t_chirp = scene.chirp.duration;
        let linear = cycle
            .iter()
            .map(|c| match c.kind {
                SweepKind::Linear => Some((c.f_start, 0.5 * (c.f_end - c.f_start) / t_chirp)),
                SweepKind::Exponential | SweepKind::Hyperbolic => None,
            })
            .collect();
        let period_s = t_chirp + cfg.gap_s;
        let total_s = cfg.start_s + cfg.chirps as f64 * period_s - cfg.gap_s + cfg.tail_s;
        let n = (total_s * fs).ceil() as usize;
        if n > MAX_SAMPLES {
            return Err(AudioError::InvalidParam {
                field: "synth.chirps",
                reason: format!(
                    "with gap_s, start_s and tail_s they make {} s of audio ({n} samples at {} Hz), more than the \
                     limit of {MAX_SAMPLES} samples per listener",
                    Num(total_s),
                    Num(fs)
                ),
            });
        }
        Ok(Self {
            scene,
            cfg,
            sweeps,
            linear,
            mirrors: scene
                .listeners
                .iter()
                .map(|l| mirrors(scene.source_position(), &obstacles, &|t| listener_position(l, t)))
                .collect(),
            obstacles,
            source: scene.source_position(),
            speed_of_sound: a,
            fs,
            period_s,
            n,
        })
    }

    /// Samples per channel.
    pub fn len_samples(&self) -> usize {
        self.n
    }

    /// Adds listener `li`'s noiseless signal for samples `start..start +
    /// out.len()` to `out` (zeros in, the recording's samples out).
    /// `start` is a multiple of [`POSE_BLOCK`] and the run ends at a
    /// multiple of it or at the recording's end.
    pub fn render(&self, li: usize, start: usize, out: &mut [f32]) {
        debug_assert!(start.is_multiple_of(POSE_BLOCK));
        let Some(l) = self.scene.listeners.get(li) else { return };
        let end = (start + out.len()).min(self.n);
        let (cfg, fs, a, period) = (self.cfg, self.fs, self.speed_of_sound, self.period_s);
        let t_chirp = self.scene.chirp.duration;
        let mut paths = Vec::new();
        let mut args = [0.0f32; POSE_BLOCK];
        let mut p_a = listener_position(l, start as f64 / fs);
        for b0 in (start..end).step_by(POSE_BLOCK) {
            let b1 = (b0 + POSE_BLOCK).min(self.n);
            let p_b = listener_position(l, b1 as f64 / fs);
            paths_at(self.source, &self.obstacles, &self.mirrors[li], cfg.reflection_order, p_a, &mut paths);
            let len = (b1 - b0) as f64;
            let y = &mut out[b0 - start..b1 - start];
            for p in &paths {
                // Path length at both block ends; the delay is linear in
                // between to well below a nanosecond (64 samples).
                let (ra, rb) = (p.base_m + p.q.dist(p_a), p.base_m + p.q.dist(p_b));
                let gain = p.gain / ra.max(0.1);
                // Emission time (relative to the first chirp) at the block ends.
                let te_a = b0 as f64 / fs - ra / a - cfg.start_s;
                let te_b = b1 as f64 / fs - rb / a - cfg.start_s;
                let dte = (te_b - te_a) / len;
                // Skip blocks in which this path carries no chirp.
                let (k_a, k_b) = (floor_exact(te_a / period), floor_exact(te_b / period));
                let silent = te_b < 0.0 || k_a >= cfg.chirps as f64 || (k_a == k_b && te_a - k_a * period > t_chirp);
                if silent {
                    continue;
                }
                // Fast path: the whole block inside one chirp, away from its
                // tapers. Every step from k to the sample's emission time,
                // chirp index and τ is monotone non-decreasing in k when
                // dte ≥ 0 (each is one correctly rounded operation), so the
                // first and last samples bound all others, and the per-sample
                // tests of the general loop below all pass.
                let last = y.len() - 1;
                let (te_0, te_1) = (te_a + dte * 0.0, te_a + dte * last as f64);
                if dte >= 0.0 && te_0 >= 0.0 {
                    let idx = floor_exact(te_0 / period);
                    let base = idx * period;
                    let (tau_0, tau_1) = (te_0 - base, te_1 - base);
                    if idx == floor_exact(te_1 / period)
                        && idx < cfg.chirps as f64
                        && tau_0 >= cfg.taper_s
                        && t_chirp - tau_1 >= cfg.taper_s
                    {
                        let which = (idx as usize) % self.sweeps.len();
                        let args = &mut args[..y.len()];
                        match self.linear[which] {
                            // |phase| ≤ τ₁(|f0| + |½rate|·τ₁) < 2⁵⁰: floor_small applies.
                            Some((f0, half_rate)) if tau_1 * (f0.abs() + half_rate.abs() * tau_1) < 1e15 => {
                                // k as f64 from a table: the loop vectorises.
                                for (arg, kf) in args.iter_mut().zip(BLOCK_INDEX.iter()) {
                                    let tau = (te_a + dte * kf) - base;
                                    let ph = tau * (f0 + half_rate * tau);
                                    *arg = std::f32::consts::TAU * (ph - floor_small(ph)) as f32;
                                }
                            }
                            Some((f0, half_rate)) => {
                                for (k, arg) in args.iter_mut().enumerate() {
                                    let tau = (te_a + dte * k as f64) - base;
                                    let ph = tau * (f0 + half_rate * tau);
                                    *arg = std::f32::consts::TAU * (ph - floor_exact(ph)) as f32;
                                }
                            }
                            None => {
                                for (k, arg) in args.iter_mut().enumerate() {
                                    let tau = (te_a + dte * k as f64) - base;
                                    let ph = self.sweeps[which].phase_cycles(tau);
                                    *arg = std::f32::consts::TAU * (ph - floor_exact(ph)) as f32;
                                }
                            }
                        }
                        for (out, arg) in y.iter_mut().zip(args.iter()) {
                            *out += (gain * f64::from(arg.sin())) as f32;
                        }
                        continue;
                    }
                }
                for (k, out) in y.iter_mut().enumerate() {
                    let te = te_a + dte * k as f64;
                    if te < 0.0 {
                        continue;
                    }
                    let idx = floor_exact(te / period);
                    if idx >= cfg.chirps as f64 {
                        continue;
                    }
                    let tau = te - idx * period;
                    if tau > t_chirp {
                        continue;
                    }
                    let which = (idx as usize) % self.sweeps.len();
                    let ph = match self.linear[which] {
                        Some((f0, half_rate)) => tau * (f0 + half_rate * tau),
                        None => self.sweeps[which].phase_cycles(tau),
                    };
                    let sv = (std::f32::consts::TAU * (ph - floor_exact(ph)) as f32).sin();
                    let g = if tau < cfg.taper_s || t_chirp - tau < cfg.taper_s {
                        gain * taper_gain(tau, t_chirp, cfg.taper_s)
                    } else {
                        gain
                    };
                    *out += (g * f64::from(sv)) as f32;
                }
            }
            p_a = p_b;
        }
    }

    /// Listener `li`'s poses: `(t, position)` every `pose_period_s` from 0
    /// to the recording's end.
    pub fn poses(&self, li: usize) -> impl Iterator<Item = (f64, Point)> + '_ {
        listener_poses(self.scene, self.cfg, li)
    }

    /// Emission time of each chirp's start (s).
    pub fn chirp_starts_s(&self) -> Vec<f64> {
        (0..self.cfg.chirps).map(|k| self.cfg.start_s + k as f64 * self.period_s).collect()
    }
}

/// Standard deviation of the noise added to a noiseless channel whose
/// sounding samples (the non-zero ones, in order) have power `power_sum`
/// over `sounding` samples: `None` without `snr_db` or without sound.
fn noise_sigma(cfg: &SynthConfig, power_sum: f64, sounding: usize) -> Option<f32> {
    let snr = cfg.snr_db?;
    (sounding > 0).then(|| ((power_sum / sounding as f64) / 10f64.powf(snr / 10.0)).sqrt() as f32)
}

/// The noise stream of listener `li` (ChaCha8, `noise_seed`, stream `li`).
fn noise_rng(cfg: &SynthConfig, li: usize) -> rand_chacha::ChaCha8Rng {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(cfg.noise_seed);
    rng.set_stream(li as u64);
    rng
}

/// Adds each sample's power to `(sum, count)` if it sounds (is non-zero),
/// in order.
fn accumulate_power(y: &[f32], acc: &mut (f64, usize)) {
    for v in y {
        if *v != 0.0 {
            acc.0 += f64::from(*v) * f64::from(*v);
            acc.1 += 1;
        }
    }
}

/// Renders the scene's chirp train as heard by every listener, in memory
/// (see [`synthesize_streamed`] for any length in constant memory).
pub fn synthesize(scene: &Scene, cfg: &SynthConfig) -> Result<Synthesized, AudioError> {
    scene.validate()?;
    cfg.validate()?;
    let (samples, poses) = synth_lengths(scene, cfg);
    crate::error::check_memory(
        || {
            format!(
                "synthesising {} listener(s) × {} samples ({} s at {} Hz, 4 bytes each) plus {} poses each",
                scene.listeners.len(),
                Num(samples),
                Num(samples / f64::from(cfg.sample_rate_hz)),
                cfg.sample_rate_hz,
                Num(poses)
            )
        },
        synth_memory_bytes(scene, cfg) as u128,
        "use fewer listeners, fewer or shorter chirps, or a longer synth.pose_period_s",
    )?;
    let r = Renderer::new(scene, cfg)?;
    let mut channels = Vec::new();
    let mut poses = Vec::new();
    for li in 0..scene.listeners.len() {
        let mut y = vec![0.0f32; r.len_samples()];
        r.render(li, 0, &mut y);
        let mut acc = (0.0, 0);
        accumulate_power(&y, &mut acc);
        if let Some(sigma) = noise_sigma(cfg, acc.0, acc.1) {
            let mut rng = noise_rng(cfg, li);
            for v in y.iter_mut() {
                let g: f32 = StandardNormal.sample(&mut rng);
                *v += sigma * g;
            }
        }
        poses.push(r.poses(li).collect());
        channels.push(y);
    }
    let peak = channels.iter().flat_map(|c| c.iter()).fold(0.0f32, |m, v| m.max(v.abs()));
    if peak > 0.0 {
        let g = cfg.peak as f32 / peak;
        for c in channels.iter_mut() {
            for v in c.iter_mut() {
                *v *= g;
            }
        }
    }
    Ok(Synthesized { sample_rate_hz: cfg.sample_rate_hz, channels, poses, chirp_starts_s: r.chirp_starts_s() })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    const FS: f64 = 48_000.0;
    const START_S: f64 = 0.1;

    /// One 0.25 s chirp 10 → 0.2 kHz, no taper, no noise, a static mic at
    /// (1.5, 0.5), the source at the origin and optionally a wall y = −h.
    fn render(wall_h: Option<f64>) -> (Scene, Vec<f32>) {
        let wall = wall_h.map_or(String::new(), |h| {
            format!(
                "[[obstacles]]\nvertices = [[-30.0, -{h}], [-30.0, -{h2}], [30.0, -{h2}], [30.0, -{h}]]\nabsorption = 0.2\n",
                h2 = h + 0.3
            )
        });
        let text = format!(
            "[chirp]\nf_start = 10000.0\nf_end = 200.0\nduration = 0.25\n[source]\nposition = [0.0, 0.0]\n{wall}\
             [[listeners]]\nstart = [1.5, 0.5]\nspeed = 0.0\n\
             [synth]\nchirps = 1\nstart_s = {START_S}\ntail_s = 0.2\ntaper_s = 0.0\npeak = 0.5\n"
        );
        let (scene, cfg) = parse_scene_with_synth(&text).unwrap();
        let mut syn = synthesize(&scene, &cfg).unwrap();
        (scene, syn.channels.remove(0))
    }

    /// The library-free floors and rounding equal `f64::floor` and
    /// `f64::round` bit for bit (sign of zero included) on edges and on a
    /// spread of values over their domains.
    #[test]
    fn floors_and_rounding_equal_the_library_ones() {
        let mut xs = vec![0.0, -0.0, 0.5, -0.5, 1.5, -1.5, 2.5, -2.5, 0.49999999999999994, -0.49999999999999994];
        xs.extend([1.0 - f64::EPSILON / 2.0, 4503599627370495.5, -4503599627370495.5, 2f64.powi(51) - 0.5]);
        xs.extend([f64::MIN_POSITIVE, -f64::MIN_POSITIVE, 1e300, -1e300, 3.0, -3.0, 1e-300]);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..200_000 {
            let m: f64 = StandardNormal.sample(&mut rng);
            let e: f64 = StandardNormal.sample(&mut rng);
            xs.push(m * 10f64.powf(4.0 * e));
        }
        for x in xs {
            assert_eq!(floor_exact(x).to_bits(), x.floor().to_bits(), "floor_exact({x:e})");
            if x.abs() < 2f64.powi(51) {
                assert_eq!(floor_small(x).to_bits(), x.floor().to_bits(), "floor_small({x:e})");
            }
            let r = crate::wav::round_half_away(x);
            if x.abs() < 9e18 {
                assert_eq!(r, x.round(), "round_half_away({x:e})");
            }
        }
        for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(floor_exact(x).to_bits(), x.floor().to_bits());
            let clamp = |v: f64| v.clamp(-32_768.0, 32_767.0) as i16;
            assert_eq!(clamp(crate::wav::round_half_away(x)), clamp(x.round()));
        }
    }

    fn first_nonzero(v: &[f32], from: usize, thr: f32) -> usize {
        from + v[from..].iter().position(|s| s.abs() > thr).unwrap()
    }

    /// `pattern = "updown"`: the second chirp is the up-sweep, sample for
    /// sample the analytic waveform (the direct path only, static mic).
    #[test]
    fn updown_alternates_and_the_pattern_is_validated() {
        let text = format!(
            "[chirp]\nf_start = 10000.0\nf_end = 200.0\nduration = 0.25\n[[listeners]]\nstart = [1.5, 0.5]\nspeed = 0.0\n\
             [synth]\nchirps = 2\ngap_s = 0.25\nstart_s = {START_S}\ntail_s = 0.2\ntaper_s = 0.0\npattern = \"updown\"\n"
        );
        let (scene, cfg) = parse_scene_with_synth(&text).unwrap();
        let syn = synthesize(&scene, &cfg).unwrap();
        let y = &syn.channels[0];
        let t0 = START_S + 0.5 + Point::new(1.5, 0.5).norm() / scene.world.speed_of_sound;
        let n = (t0 * FS).ceil() as usize + 3000;
        let tau = n as f64 / FS - t0;
        let rate = (10_000.0 - 200.0) / 0.25;
        let want = (std::f64::consts::TAU * (200.0 * tau + 0.5 * rate * tau * tau)).sin();
        let scale = f64::from(y[n]) / want;
        assert!((scale.abs() - 0.5).abs() < 2e-3, "y[{n}] = {} vs up-sweep {want}", y[n]);
        let bad = text.replace("updown", "sideways");
        let e = parse_scene_with_synth(&bad).unwrap_err().to_string();
        assert!(e.contains("sideways") || e.contains("pattern"), "{e}");
        assert_eq!(pattern_cycle(&scene.chirp, Some(ChirpPattern::Up))[0].f_start, 200.0);
        assert_eq!(pattern_cycle(&scene.chirp, None)[0], scene.chirp);
    }

    /// An SNR so low that the noise's scale overflows made a silent WAV (exit
    /// 0); a recording too long for a WAV named no field.
    #[test]
    fn extreme_snr_and_too_many_samples_name_their_field() {
        let base = "[[listeners]]\nstart = [1.5, 0.5]\nspeed = 0.0\n[synth]\n";
        for snr in ["-3100.0", "-100.1", "300.5", "-1e300"] {
            let e = parse_scene_with_synth(&format!("{base}chirps = 2\nsnr_db = {snr}\n")).unwrap_err().to_string();
            assert!(e.contains("synth.snr_db") && e.contains("[-100, 300]"), "{snr}: {e}");
        }
        assert!(parse_scene_with_synth(&format!("{base}chirps = 2\nsnr_db = -100.0\n")).is_ok());
        let (scene, cfg) = parse_scene_with_synth(&format!("{base}chirps = 1000000\n")).unwrap();
        let e = SynthStream::new(&scene, &cfg).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("synth.chirps") && e.contains("2000000000 samples"), "{e}");
    }

    /// More listeners than a WAV reader accepts channels are refused before
    /// any rendering, naming the field (synth wrote a 300-channel WAV that
    /// `range` and `map --wav` then refused).
    #[test]
    fn more_listeners_than_wav_channels_are_refused() {
        let scene_with = |n: usize| {
            let listeners = "[[listeners]]\nstart = [1.5, 0.5]\nspeed = 0.0\n".repeat(n);
            parse_scene_with_synth(&format!("{listeners}[synth]\nchirps = 1\n")).unwrap()
        };
        let max = usize::from(crate::wav::MAX_CHANNELS);
        let (scene, cfg) = scene_with(max + 1);
        let e = SynthStream::new(&scene, &cfg).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("listeners") && e.contains(&format!("at most {max} channels")), "{e}");
        let e = synthesize(&scene, &cfg).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("listeners"), "{e}");
        let (scene, cfg) = scene_with(max);
        assert_eq!(SynthStream::new(&scene, &cfg).unwrap().n_channels(), max);
    }

    #[test]
    fn direct_arrival_starts_at_d_over_a_with_the_analytic_waveform() {
        let (scene, y) = render(None);
        let a = scene.world.speed_of_sound;
        let d = Point::new(1.5, 0.5).dist(Point::new(0.0, 0.0));
        let t0 = START_S + d / a;
        let n0 = first_nonzero(&y, 0, 0.0);
        // The first sample at or after the arrival (its value may be tiny).
        let expect = (t0 * FS).ceil();
        assert!((n0 as f64 - expect).abs() <= 1.0, "onset {n0}, expected {expect}");
        // Analytic sample value: peak · sin(2π(f0 τ + ½ rate τ²)), τ = n/fs − t0.
        // The global scale is peak / max|sin| over the samples, within 1e-3 of peak.
        let n = n0 + 1234;
        let tau = n as f64 / FS - t0;
        let rate = (200.0 - 10_000.0) / 0.25;
        let want = 0.5 * (std::f64::consts::TAU * (10_000.0 * tau + 0.5 * rate * tau * tau)).sin();
        assert!((f64::from(y[n]) - want).abs() < 1e-3, "y[{n}] = {}, want {want}", y[n]);
        // The chirp ends T after it starts; nothing after it.
        let last = y.iter().rposition(|s| *s != 0.0).unwrap();
        assert!(((last as f64) / FS - (t0 + 0.25)).abs() <= 1.0 / FS, "last sample {last}");
    }

    /// A polygon obstacle (m) with absorption 0.2.
    fn polygon(v: &[(f64, f64)]) -> Obstacle {
        let shape =
            Shape::Polygon(chirpmap_core::Polygon::new(v.iter().map(|&(x, y)| Point::new(x, y)).collect()).unwrap());
        Obstacle { shape, roughness: 0.0, absorption: 0.2 }
    }

    /// A polygon around the source is a room: each wall's image source, for
    /// either winding (before, only outer sides reflected and a room's
    /// recording held no wall); a solid box beside the source reflects from
    /// its outer side only, from the face whose reflection point lies on it.
    #[test]
    fn a_room_reflects_inward_and_a_box_outward() {
        let (src, lis) = (Point::new(2.0, 2.5), Point::new(5.0, 4.0));
        let room = [(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)];
        let mut want = [(2.0, -2.5), (14.0, 2.5), (2.0, 9.5), (-2.0, 2.5)];
        want.sort_by(|a, b| a.partial_cmp(b).unwrap());
        for winding in [room.to_vec(), room.iter().rev().copied().collect()] {
            let mut out = Vec::new();
            let obs = [polygon(&winding)];
            paths_at(src, &obs, &mirrors(src, &obs, &|_| lis), 1, lis, &mut out);
            // The first path is the direct one.
            assert!(out[0].q == src && out[0].gain == 1.0);
            out.remove(0);
            let mut got: Vec<(f64, f64)> = out.iter().map(|p| (p.q.x, p.q.y)).collect();
            got.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(got.len(), 4, "{got:?}");
            for (g, w) in got.iter().zip(&want) {
                assert!((g.0 - w.0).abs() < 1e-12 && (g.1 - w.1).abs() < 1e-12, "{got:?}");
            }
            assert!(out.iter().all(|p| (p.gain - 0.8).abs() < 1e-12 && p.base_m == 0.0));
        }
        let mut out = Vec::new();
        let obs = [polygon(&[(3.0, 0.0), (6.0, 0.0), (6.0, 1.0), (3.0, 1.0)])];
        paths_at(src, &obs, &mirrors(src, &obs, &|_| Point::new(6.0, 2.5)), 1, Point::new(6.0, 2.5), &mut out);
        assert_eq!(out.len(), 2);
        assert!(out[1].q.dist(Point::new(2.0, -0.5)) < 1e-12, "{:?}", out[1].q);
        // A speaker on a wall, either side (the even–odd test puts the left
        // edge in and the right one out): the other three walls reflect.
        let obs = [polygon(&room)];
        for (src, lis) in [(Point::new(0.0, 3.0), Point::new(3.0, 3.5)), (Point::new(8.0, 3.0), Point::new(5.0, 3.5))] {
            let mut out = Vec::new();
            paths_at(src, &obs, &mirrors(src, &obs, &|_| lis), 1, lis, &mut out);
            assert_eq!(out.len(), 4, "speaker at {src:?}");
        }
        // The speaker and the listener's start both on the right wall: its
        // first position off the wall decides.
        let src = Point::new(8.0, 3.0);
        let walk = |t: f64| Point::new(8.0 - t, 4.5);
        let mut out = Vec::new();
        paths_at(src, &obs, &mirrors(src, &obs, &walk), 1, walk(1.0), &mut out);
        assert_eq!(out.len(), 4);
    }

    /// Second order against the exact module's corner echoes (images of
    /// images with every leg checked, its own code), first and second order,
    /// equal lengths merged as it merges them: an empty 8 m × 6 m room (60
    /// listener positions) and an open corner of two finite walls (thin
    /// boxes facing the source; 60 positions in front of both), where bounce
    /// points fall off the walls' ends.
    #[test]
    fn second_order_paths_are_the_exact_corner_echoes() {
        use chirpmap_core::exact::{ExactOptions, ExactScene, Pose, exact_echoes};
        let room = vec![polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)])];
        let corner = vec![
            polygon(&[(-3.0, -4.0), (3.0, -4.0), (3.0, -3.7), (-3.0, -3.7)]),
            polygon(&[(3.5, -2.0), (3.8, -2.0), (3.8, 2.0), (3.5, 2.0)]),
        ];
        let cases = [
            (room, Point::new(2.0, 2.5), (0.3, 7.4, 0.4, 5.2)),
            (corner, Point::new(0.0, 0.0), (-5.0, 8.0, -3.5, 6.0)),
        ];
        let mut second = 0;
        for (obs, src, (x0, wx, y0, wy)) in cases {
            let scene = ExactScene::from_obstacles(&obs);
            for k in 0..60 {
                let lis = Point::new(x0 + wx * f64::from(k % 10) / 9.0, y0 + wy * f64::from(k / 10) / 5.0);
                for order in [1, 2] {
                    let mut out = Vec::new();
                    paths_at(src, &obs, &mirrors(src, &obs, &|_| lis), order, lis, &mut out);
                    let mut got: Vec<f64> = out[1..].iter().map(|p| p.base_m + p.q.dist(lis) - src.dist(lis)).collect();
                    got.sort_by(f64::total_cmp);
                    got.dedup_by(|b, a| (*b - *a).abs() <= 1e-6);
                    let opts = ExactOptions { second_order: order == 2, ..ExactOptions::default() };
                    let pose = [Pose { t_s: 0.0, listener: lis }];
                    let mut want: Vec<f64> =
                        exact_echoes(src, &pose, &scene, &opts).unwrap().iter().map(|e| e.delta_d_m).collect();
                    want.sort_by(f64::total_cmp);
                    assert_eq!(got.len(), want.len(), "order {order} at {lis:?}: {got:?} vs {want:?}");
                    for (g, w) in got.iter().zip(&want) {
                        assert!((g - w).abs() < 1e-9, "order {order} at {lis:?}: {got:?} vs {want:?}");
                    }
                    if order == 2 {
                        second += out.len() - 1;
                    }
                }
            }
        }
        assert!(second > 500, "{second} paths");
    }

    #[test]
    fn wall_reflection_arrives_at_the_image_source_delay() {
        let h = 4.0;
        let (_, y_direct) = render(None);
        let (scene, y_wall) = render(Some(h));
        let a = scene.world.speed_of_sound;
        let mic = Point::new(1.5, 0.5);
        let (d, r) = (mic.dist(Point::new(0.0, 0.0)), mic.dist(Point::new(0.0, -2.0 * h)));
        let n0 = first_nonzero(&y_wall, 0, 0.0);
        assert_eq!(n0, first_nonzero(&y_direct, 0, 0.0));
        // Before the reflection both recordings hold only the direct sound,
        // up to the global level normalisation: find that ratio, subtract.
        let k = n0 + (0..200).max_by(|&i, &j| y_direct[n0 + i].abs().total_cmp(&y_direct[n0 + j].abs())).unwrap();
        let c = f64::from(y_wall[k]) / f64::from(y_direct[k]);
        let resid: Vec<f32> =
            y_wall.iter().zip(&y_direct).map(|(w, dd)| (f64::from(*w) - c * f64::from(*dd)) as f32).collect();
        let nr = first_nonzero(&resid, n0, 1e-4);
        let expect = (START_S + r / a) * FS;
        assert!((nr as f64 - expect.ceil()).abs() <= 1.0, "reflection onset {nr}, expected {expect}");
        // Its level: (1 − absorption) · D / R of the direct's, spreading 1/r.
        let amp = |v: &[f32], from: usize| v[from..from + 2000].iter().fold(0.0f32, |m, s| m.max(s.abs()));
        let ratio = f64::from(amp(&resid, nr)) / (c * f64::from(amp(&y_direct, n0)));
        let want = 0.8 * d / r;
        assert!((ratio - want).abs() < 0.01 * want, "level ratio {ratio}, want {want}");
    }
}
