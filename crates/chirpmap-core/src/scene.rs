//! The scene file (TOML). Every field has a default, so an empty file is the
//! paper's default scene (docs/parameters.md). Unknown keys are errors.

use crate::chirp::{ExponentialChirp, LinearChirp, Sweep};
use crate::error::{CoreError, Num, toml_error};
use crate::geometry::{Circle, MAX_COORD_M, Obstacle, Point, Polygon, Shape};
use crate::mapper::MappingParams;
use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize};

/// Deserialises exactly `N` numbers: `position = [1, 2, 3]` is an error,
/// not silently truncated to `[1, 2]` (issue 8, item 12).
fn exact_array<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<[f64; N], D::Error> {
    let v: Vec<f64> = Vec::deserialize(d)?;
    let n = v.len();
    v.try_into().map_err(|_| D::Error::custom(format!("expected an array of {N} numbers, got {n}")))
}

fn exact_array_opt<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<Option<[f64; N]>, D::Error> {
    let Some(v) = Option::<Vec<f64>>::deserialize(d)? else { return Ok(None) };
    let n = v.len();
    v.try_into().map(Some).map_err(|_| D::Error::custom(format!("expected an array of {N} numbers, got {n}")))
}

fn exact_points_opt<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Vec<[f64; 2]>>, D::Error> {
    let Some(v) = Option::<Vec<Vec<f64>>>::deserialize(d)? else { return Ok(None) };
    v.into_iter()
        .enumerate()
        .map(|(i, p)| {
            let n = p.len();
            p.try_into().map_err(|_| D::Error::custom(format!("vertex {i}: expected [x, y], got {n} numbers")))
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// A complete simulation scene as read from a TOML file: world, chirp,
/// source, particles, obstacles, listeners and mapping parameters. Defaults
/// follow the paper's setup (§III).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Scene {
    /// Master seed of the run's random stream (docs/architecture.md: `ChaCha8Rng::seed_from_u64(seed)`).
    pub seed: u64,
    /// Run index: the stream of the master generator (`set_stream(run_index)`), so run i of a
    /// sweep draws the same obstacles in every configuration (paper §III).
    pub run_index: u64,
    /// Simulated time (s) from the start of the chirp. Default (absent): the chirp duration plus
    /// the time sound needs to cross the world from the source to its farthest corner.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// Speed of sound and bounds.
    pub world: World,
    /// The emitted sweep.
    pub chirp: ChirpSpec,
    /// Where the source stands.
    pub source: SourceSpec,
    /// Particle emission settings (paper §II.B).
    pub particles: ParticleSpec,
    /// Explicit obstacles; when empty, `random_obstacles` generates them.
    pub obstacles: Vec<ObstacleSpec>,
    /// Random circular obstacles, used when `obstacles` is empty.
    pub random_obstacles: RandomObstacles,
    /// The moving listeners.
    pub listeners: Vec<ListenerSpec>,
    /// Parameters of the mappers (Algorithm 1).
    pub mapping: MappingParams,
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            seed: 1,
            run_index: 0,
            duration_s: None,
            world: World::default(),
            chirp: ChirpSpec::default(),
            source: SourceSpec::default(),
            particles: ParticleSpec::default(),
            obstacles: Vec::new(),
            random_obstacles: RandomObstacles::default(),
            listeners: vec![ListenerSpec::default()],
            mapping: MappingParams::default(),
        }
    }
}

/// The simulated world: speed of sound and extent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct World {
    /// Speed of sound a (m/s). Paper: 343.
    pub speed_of_sound: f64,
    /// `[xmin, ymin, xmax, ymax]` (m): particles leave here; the map covers it.
    #[serde(deserialize_with = "exact_array")]
    pub bounds: [f64; 4],
}

impl Default for World {
    fn default() -> Self {
        Self { speed_of_sound: 343.0, bounds: [-50.0, -50.0, 50.0, 50.0] }
    }
}

/// Shape of the frequency sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SweepKind {
    /// Linear in time, [`LinearChirp`] (paper Eq. 1).
    #[default]
    Linear,
    /// Exponential in time, [`ExponentialChirp`].
    Exponential,
    /// Linear period (hyperbolic frequency), [`crate::chirp::HyperbolicChirp`]: bats' Doppler-tolerant sweep.
    Hyperbolic,
}

/// The emitted chirp, as written in a scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChirpSpec {
    /// Frequency at the start of the sweep (Hz). Paper: 10 kHz.
    pub f_start: f64,
    /// Frequency at the end of the sweep (Hz). Paper: 200 Hz.
    pub f_end: f64,
    /// Sweep duration T (s).
    pub duration: f64,
    /// Linear or exponential sweep.
    pub kind: SweepKind,
}

impl Default for ChirpSpec {
    fn default() -> Self {
        Self { f_start: 10_000.0, f_end: 200.0, duration: 0.5, kind: SweepKind::Linear }
    }
}

impl ChirpSpec {
    /// The sweep this spec describes; errors on invalid frequencies or duration.
    pub fn build(&self) -> Result<Box<dyn Sweep>, CoreError> {
        Ok(match self.kind {
            SweepKind::Linear => Box::new(LinearChirp::new(self.f_start, self.f_end, self.duration)?),
            SweepKind::Exponential => Box::new(ExponentialChirp::new(self.f_start, self.f_end, self.duration)?),
            SweepKind::Hyperbolic => {
                Box::new(crate::chirp::HyperbolicChirp::new(self.f_start, self.f_end, self.duration)?)
            }
        })
    }
}

/// The sound source, as written in a scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SourceSpec {
    /// Source position `[x, y]` (m).
    #[serde(deserialize_with = "exact_array")]
    pub position: [f64; 2],
}

impl Default for SourceSpec {
    fn default() -> Self {
        Self { position: [0.0, 0.0] }
    }
}

/// How sound is discretised into particles (paper §II.B).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ParticleSpec {
    /// Particles emitted per tick. Paper: 3600.
    pub per_tick: u32,
    /// Tick length (ms). Paper: 1.
    pub tick_ms: f64,
    /// Shift heard frequencies by the listener's motion (paper: supported, off).
    pub doppler: bool,
    /// Particles quieter than this (relative to emission) are dropped.
    pub min_loudness: f64,
}

impl Default for ParticleSpec {
    fn default() -> Self {
        Self { per_tick: 3600, tick_ms: 1.0, doppler: false, min_loudness: 1e-3 }
    }
}

/// A circle (`center` + `radius`) or a polygon (`vertices`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    /// Circle centre `[x, y]` (m); give with `radius`.
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact_array_opt")]
    pub center: Option<[f64; 2]>,
    /// Circle radius (m); give with `center`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Polygon vertices `[[x, y], …]` (m), in order; instead of a circle.
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact_points_opt")]
    pub vertices: Option<Vec<[f64; 2]>>,
    /// Fraction in [0, 1]: outgoing angle perturbed by ± roughness·90°. Default 0.1.
    #[serde(default = "default_roughness")]
    pub roughness: f64,
    /// Fraction in [0, 1] of loudness lost per bounce. Default 0.2.
    #[serde(default = "default_absorption")]
    pub absorption: f64,
}

fn default_roughness() -> f64 {
    0.1
}
fn default_absorption() -> f64 {
    0.2
}

impl ObstacleSpec {
    /// A circle spec at `center` with radius `radius_m` (m) and the default
    /// roughness and absorption.
    pub fn circle(center: Point, radius_m: f64) -> Self {
        Self {
            center: Some([center.x, center.y]),
            radius: Some(radius_m),
            vertices: None,
            roughness: default_roughness(),
            absorption: default_absorption(),
        }
    }

    /// The obstacle this spec describes; `index` names it in errors.
    pub fn build(&self, index: usize) -> Result<Obstacle, CoreError> {
        let ctx = |msg: String| CoreError::InvalidScene(format!("obstacles[{index}]: {msg}"));
        for (name, v) in [("roughness", self.roughness), ("absorption", self.absorption)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(ctx(format!("{name} must be in [0, 1], got {}", Num(v))));
            }
        }
        let shape = match (&self.center, self.radius, &self.vertices) {
            (Some(c), Some(r), None) => {
                Shape::Circle(Circle::new(Point::new(c[0], c[1]), r).map_err(|e| ctx(e.to_string()))?)
            }
            (None, None, Some(v)) => Shape::Polygon(
                Polygon::new(v.iter().map(|p| Point::new(p[0], p[1])).collect()).map_err(|e| ctx(e.to_string()))?,
            ),
            _ => return Err(ctx("give either `center` and `radius` (circle) or `vertices` (polygon)".into())),
        };
        Ok(Obstacle { shape, roughness: self.roughness, absorption: self.absorption })
    }
}

/// Randomly placed circular obstacles (paper §III: three circles).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RandomObstacles {
    /// How many obstacles to draw. Paper: 3.
    pub count: u32,
    /// Diameter range (m). Paper: U(5, 10).
    #[serde(deserialize_with = "exact_array")]
    pub diameter: [f64; 2],
    /// Region for centres `[xmin, ymin, xmax, ymax]` (m).
    #[serde(deserialize_with = "exact_array")]
    pub region: [f64; 4],
    /// Roughness of every drawn obstacle, in [0, 1].
    pub roughness: f64,
    /// Absorption of every drawn obstacle, in [0, 1].
    pub absorption: f64,
}

impl Default for RandomObstacles {
    fn default() -> Self {
        Self { count: 3, diameter: [5.0, 10.0], region: [-20.0, -35.0, 20.0, -10.0], roughness: 0.1, absorption: 0.2 }
    }
}

impl RandomObstacles {
    /// Checks the table even when explicit obstacles make it unused (a
    /// resolved scene copies it): count in 1..=[`MAX_RANDOM_OBSTACLES`],
    /// diameters finite and ordered, the centre region inside the world.
    pub fn validate(&self, world: &[f64; 4]) -> Result<(), CoreError> {
        let bad = |m: String| Err(CoreError::InvalidScene(m));
        if self.count == 0 || self.count > MAX_RANDOM_OBSTACLES {
            return bad(format!(
                "random_obstacles.count must be in 1..={MAX_RANDOM_OBSTACLES}, got {} (list [[obstacles]] to place \
                 obstacles yourself)",
                self.count
            ));
        }
        let [lo, hi] = self.diameter;
        for (k, v) in [lo, hi].into_iter().enumerate() {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("random_obstacles.diameter[{k}] must be finite and > 0, got {}", Num(v)));
            }
        }
        if lo > hi {
            return bad(format!(
                "random_obstacles.diameter must be [low, high] with low <= high, got [{}, {}]",
                Num(lo),
                Num(hi)
            ));
        }
        check_rect("random_obstacles.region", &self.region)?;
        let r = &self.region;
        if r[0] < world[0] || r[1] < world[1] || r[2] > world[2] || r[3] > world[3] {
            return bad(format!(
                "random_obstacles.region {} must lie inside world.bounds {}: obstacles outside the world reflect nothing",
                rect(r),
                rect(world)
            ));
        }
        for (name, v) in [("roughness", self.roughness), ("absorption", self.absorption)] {
            if !(0.0..=1.0).contains(&v) {
                return bad(format!("random_obstacles.{name} must be in [0, 1], got {}", Num(v)));
            }
        }
        Ok(())
    }
}

impl Sampling {
    /// Exactly one of `period_ms` or `random_ms`, finite, > 0, at most
    /// [`MAX_PERIOD_MS`], `random_ms` ordered. `field` names the table.
    pub fn validate(&self, field: &str) -> Result<(), CoreError> {
        let bad = |m: String| Err(CoreError::InvalidScene(m));
        let check = |name: String, v: f64| {
            if v.is_finite() && v > 0.0 && v <= MAX_PERIOD_MS {
                Ok(())
            } else {
                Err(CoreError::InvalidScene(format!(
                    "{name} must be finite and > 0 and at most {} ms, got {}",
                    Num(MAX_PERIOD_MS),
                    Num(v)
                )))
            }
        };
        match (self.period_ms, self.random_ms) {
            (Some(p), None) => check(format!("{field}.period_ms"), p),
            (None, Some([lo, hi])) => {
                check(format!("{field}.random_ms[0]"), lo)?;
                check(format!("{field}.random_ms[1]"), hi)?;
                if lo > hi {
                    return bad(format!(
                        "{field}.random_ms must be [low, high] with low <= high, got [{}, {}]",
                        Num(lo),
                        Num(hi)
                    ));
                }
                Ok(())
            }
            _ => bad(format!("{field}: give exactly one of `period_ms` or `random_ms`")),
        }
    }
}

/// Slowest and fastest speed of sound accepted (m/s): air is 343, water
/// 1480; the same range as `chirpmap range --speed-of-sound`. Beyond it a
/// typo (1e6, 1e-300) would give a run that measures nothing.
pub const MIN_SPEED_OF_SOUND_MPS: f64 = 100.0;
/// See [`MIN_SPEED_OF_SOUND_MPS`].
pub const MAX_SPEED_OF_SOUND_MPS: f64 = 2000.0;
/// Longest chirp (s); the paper's is 0.5 s.
pub const MAX_CHIRP_S: f64 = 60.0;
/// Shortest chirp: 0.1 ms, below the shortest bat calls (about 0.3 ms). A
/// far shorter sweep overlaps no reflection, so nothing is measured
/// (`chirp.duration = 1e-320` ran to 0 echoes and exit 0).
pub const MIN_CHIRP_S: f64 = 1e-4;
/// Highest chirp frequency (Hz): far above any recorder (AudioMoth: 384 kHz).
pub const MAX_FREQ_HZ: f64 = 1e6;
/// Particles per tick: the direction table holds one 16-byte entry each
/// (10⁶ = 16 MB; the paper uses 3600).
pub const MAX_PER_TICK: u32 = 1_000_000;
/// Random obstacles: placement tries every pair, so the work grows with the
/// square of the count (the paper uses 3).
pub const MAX_RANDOM_OBSTACLES: u32 = 100;
/// Explicit obstacles (pairwise overlap checks).
pub const MAX_OBSTACLES: usize = 1000;
/// Vertices of one polygon obstacle (every particle segment tests every edge).
pub const MAX_POLYGON_VERTICES: usize = 1000;
/// Listeners of one scene.
pub const MAX_LISTENERS: usize = 10_000;
/// Largest |spin_rate| (rad/s): one full turn per second (the paper uses π/4).
pub const MAX_SPIN_RPS: f64 = std::f64::consts::TAU;
/// Largest listener radius, as a fraction of the world's smaller side (the
/// paper's microphone is 0.5 m in a 100 m world).
pub const MAX_RADIUS_FRACTION: f64 = 0.1;
/// Longest sampling period (ms): 10⁷ ms is almost three hours.
pub const MAX_PERIOD_MS: f64 = 1e7;
/// The map must be at least this many cells across the world's smaller side.
pub const MIN_CELLS_ACROSS: f64 = 10.0;

fn inside(world: &[f64; 4], p: Point) -> bool {
    p.x > world[0] && p.x < world[2] && p.y > world[1] && p.y < world[3]
}

/// `[xmin, ymin, xmax, ymax]` with numbers as a person writes them.
fn rect(r: &[f64; 4]) -> String {
    format!("[{}, {}, {}, {}]", Num(r[0]), Num(r[1]), Num(r[2]), Num(r[3]))
}

fn check_rect(field: &str, r: &[f64; 4]) -> Result<(), CoreError> {
    if r.iter().all(|v| v.is_finite() && v.abs() <= MAX_COORD_M) && r[0] < r[2] && r[1] < r[3] {
        Ok(())
    } else {
        Err(CoreError::InvalidScene(format!(
            "{field} must be [xmin, ymin, xmax, ymax] with finite xmin < xmax, ymin < ymax within ±{} m, got {}",
            Num(MAX_COORD_M),
            rect(r)
        )))
    }
}

/// How often a listener measures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sampling {
    /// Constant period (ms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub period_ms: Option<f64>,
    /// Uniformly random period range (ms).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact_array_opt")]
    pub random_ms: Option<[f64; 2]>,
}

impl Default for Sampling {
    fn default() -> Self {
        Self { period_ms: Some(10.0), random_ms: None }
    }
}

/// One moving listener, as written in a scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ListenerSpec {
    /// Start position `[x, y]` (m).
    #[serde(deserialize_with = "exact_array")]
    pub start: [f64; 2],
    /// Initial heading (°), counter-clockwise from +x.
    pub heading_deg: f64,
    /// m/s. Paper: 10.
    pub speed: f64,
    /// rad/s; positive turns counter-clockwise. Paper: 0 or π/4.
    pub spin_rate: f64,
    /// Detection radius (m).
    pub radius: f64,
    /// When the listener records.
    pub sampling: Sampling,
}

impl Default for ListenerSpec {
    fn default() -> Self {
        Self {
            start: [-3.0, 10.0],
            heading_deg: 0.0,
            speed: 10.0,
            spin_rate: 0.0,
            radius: 0.5,
            sampling: Sampling::default(),
        }
    }
}

/// The keys of a scene that hold a table.
const SCENE_TABLES: [&str; 6] = ["world", "chirp", "source", "particles", "random_obstacles", "mapping"];

/// Refuses a scene table whose sections are not tables where tables belong
/// (`[mapping]`, `[[listeners]]`, a listener's `sampling`, …): serde fills a
/// struct from an array field by field, so `mapping = [0.5]` set the cell
/// to 0.5 and `listeners = [[[-2, 10]]]` a listener's start, without a word
/// (session 20's review). Shared by every reader of scenes (files, the
/// Python package's dicts, a sweep's configurations).
pub fn check_scene_tables(scene: &toml::Table) -> Result<(), String> {
    /// `path` names the value; `how` is the way to write it as a table.
    fn table(path: &str, how: &str, v: &toml::Value) -> Result<(), String> {
        if v.is_table() {
            return Ok(());
        }
        Err(format!("`{path}` must be a table (`{how}`), not {}", v.type_str()))
    }
    for key in SCENE_TABLES {
        if let Some(v) = scene.get(key) {
            table(key, &format!("[{key}]"), v)?;
        }
    }
    if let Some(v) = scene.get("mapping").and_then(|m| m.get("evidence")) {
        table("mapping.evidence", "[mapping.evidence]", v)?;
    }
    for list in ["obstacles", "listeners"] {
        let Some(v) = scene.get(list) else { continue };
        let items = v
            .as_array()
            .ok_or_else(|| format!("`{list}` must be an array of tables (`[[{list}]]`), not {}", v.type_str()))?;
        for (i, item) in items.iter().enumerate() {
            table(&format!("{list}[{i}]"), &format!("[[{list}]]"), item)?;
            if let Some(s) = item.get("sampling") {
                table(&format!("{list}[{i}].sampling"), "sampling = { ... }", s)?;
            }
        }
    }
    Ok(())
}

impl Scene {
    /// Parses a scene; TOML errors carry line and column and quote at most a
    /// short excerpt of the offending line ([`crate::error::toml_error`]).
    /// Parsing does not validate values: call [`Scene::validate`].
    pub fn from_toml_str(text: &str) -> Result<Self, CoreError> {
        crate::error::check_toml_values(text).map_err(CoreError::InvalidScene)?;
        // Text that does not parse gets the parser's error, with its line, below.
        if let Ok(table) = text.parse::<toml::Table>() {
            check_scene_tables(&table).map_err(CoreError::InvalidScene)?;
        }
        toml::from_str(text).map_err(|e| CoreError::InvalidScene(toml_error(text, &e)))
    }

    /// The one validation of the scene schema, shared by every command that
    /// reads a scene (`simulate`, `map --scene`, `synth`, sweeps; issue 8,
    /// items 11–12): every number finite and within its documented range,
    /// every size bounded, every position inside the world and within
    /// ±[`MAX_COORD_M`], tables that this run does not use included (a
    /// resolved scene copies them, so they must be valid too), and the
    /// combinations under which nothing could be measured refused (a
    /// particle step longer than a listener's disc, a map of fewer than
    /// [`MIN_CELLS_ACROSS`] cells, random obstacles outside the world).
    /// Errors name the field and the limit. Model-specific checks (a
    /// listener leaving the world, obstacles on its path) stay with the
    /// simulator (`chirpmap_sim::resolve`).
    pub fn validate(&self) -> Result<(), CoreError> {
        let bad = |m: String| Err(CoreError::InvalidScene(m));
        for (name, v) in [("seed", self.seed), ("run_index", self.run_index)] {
            if v > i64::MAX as u64 {
                return bad(format!(
                    "{name} must be at most {} (TOML integers are signed 64-bit, so scene.toml could not record it), got {v}",
                    i64::MAX
                ));
            }
        }
        let a = self.world.speed_of_sound;
        if !(a.is_finite() && (MIN_SPEED_OF_SOUND_MPS..=MAX_SPEED_OF_SOUND_MPS).contains(&a)) {
            return bad(format!(
                "world.speed_of_sound must be finite and > 0 and within {MIN_SPEED_OF_SOUND_MPS}–{MAX_SPEED_OF_SOUND_MPS} m/s \
                 (sound in air is 343 m/s), got {}",
                Num(a)
            ));
        }
        let world = self.world.bounds;
        check_rect("world.bounds", &world)?;
        let chirp = self.chirp.build()?;
        if !(MIN_CHIRP_S..=MAX_CHIRP_S).contains(&chirp.duration_s()) {
            return bad(format!(
                "chirp.duration must be within {MIN_CHIRP_S}–{MAX_CHIRP_S} s, got {}",
                Num(chirp.duration_s())
            ));
        }
        if self.chirp.f_start.max(self.chirp.f_end) > MAX_FREQ_HZ {
            return bad(format!(
                "chirp.f_start and chirp.f_end must be at most {} Hz, got {} and {}",
                Num(MAX_FREQ_HZ),
                Num(self.chirp.f_start),
                Num(self.chirp.f_end)
            ));
        }
        let source = self.source_position();
        if !source.is_finite() || !inside(&world, source) {
            return bad(format!("source.position {source} is not inside world.bounds {}", rect(&world)));
        }
        let p = &self.particles;
        if p.per_tick == 0 || p.per_tick > MAX_PER_TICK {
            return bad(format!("particles.per_tick must be in 1..={MAX_PER_TICK}, got {}", p.per_tick));
        }
        if !(p.tick_ms.is_finite() && p.tick_ms > 0.0) {
            return bad(format!("particles.tick_ms must be finite and > 0, got {}", Num(p.tick_ms)));
        }
        if !(p.min_loudness.is_finite() && (0.0..1.0).contains(&p.min_loudness)) {
            return bad(format!("particles.min_loudness must be in [0, 1), got {}", Num(p.min_loudness)));
        }
        if let Some(d) = self.duration_s {
            if !(d.is_finite() && d > 0.0) {
                return bad(format!("duration_s must be finite and > 0, got {}", Num(d)));
            }
            if d * 1e3 < p.tick_ms {
                return bad(format!(
                    "duration_s = {} s is shorter than one tick (particles.tick_ms = {} ms): nothing can be measured",
                    Num(d),
                    Num(p.tick_ms)
                ));
            }
        }
        self.mapping.validate()?;
        let min_side = (world[2] - world[0]).min(world[3] - world[1]);
        if min_side / self.mapping.cell < MIN_CELLS_ACROSS {
            return bad(format!(
                "mapping.cell = {} m leaves fewer than {MIN_CELLS_ACROSS} cells across the world's smaller side ({} m): \
                 the map could show nothing; use a cell of at most {} m (paper: 0.1)",
                Num(self.mapping.cell),
                Num(min_side),
                Num(min_side / MIN_CELLS_ACROSS)
            ));
        }
        let grid_bytes = (world[2] - world[0]) / self.mapping.cell
            * ((world[3] - world[1]) / self.mapping.cell)
            * 8.0
            * crate::grid::WORKING_COPIES as f64;
        if grid_bytes > crate::grid::DEFAULT_MEMORY_CAP_BYTES as f64 {
            return bad(format!(
                "mapping.cell = {} m over world.bounds {} needs about {} bytes to map, more than the cap of {} bytes; \
                 use a larger cell",
                Num(self.mapping.cell),
                rect(&world),
                Num(grid_bytes),
                crate::grid::DEFAULT_MEMORY_CAP_BYTES
            ));
        }
        self.random_obstacles.validate(&world)?;
        if self.obstacles.len() > MAX_OBSTACLES {
            return bad(format!("at most {MAX_OBSTACLES} [[obstacles]] are allowed, got {}", self.obstacles.len()));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            let n_vertices = o.vertices.as_ref().map_or(0, Vec::len);
            if n_vertices > MAX_POLYGON_VERTICES {
                return bad(format!(
                    "obstacles[{i}].vertices: at most {MAX_POLYGON_VERTICES} vertices are allowed, got {n_vertices}"
                ));
            }
            let ob = o.build(i)?;
            let (lo, hi) = ob.shape.bbox();
            if !lo.is_sane() || !hi.is_sane() {
                return bad(format!("obstacles[{i}]: coordinates must be within ±{} m", Num(MAX_COORD_M)));
            }
        }
        if self.listeners.is_empty() {
            return bad("at least one [[listeners]] is needed".into());
        }
        if self.listeners.len() > MAX_LISTENERS {
            return bad(format!("at most {MAX_LISTENERS} [[listeners]] are allowed, got {}", self.listeners.len()));
        }
        let max_radius_m = MAX_RADIUS_FRACTION * min_side;
        let step_m = a * p.tick_ms * 1e-3;
        for (i, l) in self.listeners.iter().enumerate() {
            let field = format!("listeners[{i}]");
            let start = Point::new(l.start[0], l.start[1]);
            if !start.is_finite() || !inside(&world, start) {
                return bad(format!("{field}.start {start} is outside world.bounds {}", rect(&world)));
            }
            if !l.heading_deg.is_finite() {
                return bad(format!("{field}.heading_deg must be finite, got {}", Num(l.heading_deg)));
            }
            if !(l.speed.is_finite() && l.speed >= 0.0 && l.speed < a) {
                return bad(format!(
                    "{field}.speed must be finite, >= 0 and below the speed of sound ({} m/s), got {}",
                    Num(a),
                    Num(l.speed)
                ));
            }
            if !l.spin_rate.is_finite() || l.spin_rate.abs() > MAX_SPIN_RPS {
                return bad(format!(
                    "{field}.spin_rate must be within ±{} rad/s (one turn per second), got {}",
                    Num(MAX_SPIN_RPS),
                    Num(l.spin_rate)
                ));
            }
            if !(l.radius.is_finite() && l.radius > 0.0) {
                return bad(format!("{field}.radius must be finite and > 0, got {}", Num(l.radius)));
            }
            if l.radius > max_radius_m {
                return bad(format!(
                    "{field}.radius must be at most {} m ({MAX_RADIUS_FRACTION} of the world's smaller side), got {}",
                    Num(max_radius_m),
                    Num(l.radius)
                ));
            }
            if step_m > 2.0 * l.radius {
                return bad(format!(
                    "particles.tick_ms = {} ms moves sound {} m per tick (world.speed_of_sound = {} m/s), more than \
                     the {} m diameter of {field}'s disc: particles would jump over it and nothing would be \
                     measured; use tick_ms <= {} (paper: 1)",
                    Num(p.tick_ms),
                    Num(step_m),
                    Num(a),
                    Num(2.0 * l.radius),
                    Num(2.0 * l.radius / a * 1e3)
                ));
            }
            l.sampling.validate(&format!("{field}.sampling"))?;
        }
        Ok(())
    }

    /// The scene as pretty TOML; a comment line if serialisation fails.
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# could not serialise scene: {e}\n"))
    }

    /// Source position as a [`Point`] (m).
    pub fn source_position(&self) -> Point {
        Point::new(self.source.position[0], self.source.position[1])
    }

    /// The explicitly listed obstacles, validated.
    pub fn explicit_obstacles(&self) -> Result<Vec<Obstacle>, CoreError> {
        self.obstacles.iter().enumerate().map(|(i, o)| o.build(i)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A section given as an array (or a number) where a table belongs is
    /// refused naming it: serde filled the struct from the array, field by
    /// field (`mapping = [0.5]` set the cell to 0.5).
    #[test]
    fn sections_that_are_not_tables_are_refused() {
        for (text, want) in [
            ("mapping = [0.5]\n", "`mapping` must be a table (`[mapping]`), not array"),
            ("world = 3\n", "`world` must be a table (`[world]`), not integer"),
            ("[mapping]\nevidence = [1, 2]\n", "`mapping.evidence` must be a table"),
            ("listeners = [[[-2.0, 10.0]]]\n", "`listeners[0]` must be a table (`[[listeners]]`), not array"),
            ("listeners = 1\n", "`listeners` must be an array of tables (`[[listeners]]`), not integer"),
            ("[[listeners]]\nsampling = [1.0]\n", "`listeners[0].sampling` must be a table (`sampling = { ... }`)"),
            ("obstacles = [[0.0, 1.0]]\n", "`obstacles[0]` must be a table"),
        ] {
            let e = Scene::from_toml_str(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
        // Inline tables are tables.
        Scene::from_toml_str("mapping = { cell = 0.5 }\n[[listeners]]\nsampling = { period_ms = 5.0 }\n").unwrap();
    }

    #[test]
    fn empty_file_is_default_scene() {
        assert_eq!(Scene::from_toml_str("").unwrap(), Scene::default());
    }

    #[test]
    fn unknown_keys_are_errors_with_position() {
        let err = Scene::from_toml_str("[world]\nspeed_of_sond = 1.0\n").unwrap_err().to_string();
        assert!(err.contains("speed_of_sond") && err.contains("line 2"), "{err}");
    }

    #[test]
    fn round_trips_through_toml() {
        let mut s = Scene::default();
        s.obstacles.push(ObstacleSpec::circle(Point::new(1.0, -20.0), 3.0));
        s.obstacles.push(ObstacleSpec {
            center: None,
            radius: None,
            vertices: Some(vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]),
            roughness: 0.0,
            absorption: 0.5,
        });
        s.listeners[0].sampling = Sampling { period_ms: None, random_ms: Some([10.0, 100.0]) };
        let back = Scene::from_toml_str(&s.to_toml_string()).unwrap();
        assert_eq!(back, s);
        assert_eq!(back.explicit_obstacles().unwrap().len(), 2);
    }

    fn invalid(toml: &str) -> String {
        match Scene::from_toml_str(toml) {
            Err(e) => e.to_string(),
            Ok(s) => s.validate().map(|()| String::from("(valid)")).unwrap_or_else(|e| e.to_string()),
        }
    }

    #[test]
    fn default_and_example_scenes_are_valid() {
        Scene::default().validate().unwrap();
        for ex in ["wall", "three-circles", "default-1ms", "bench-hour"] {
            let path = format!("{}/../../examples/{ex}/scene.toml", env!("CARGO_MANIFEST_DIR"));
            let text = std::fs::read_to_string(&path).unwrap();
            let mut table: toml::Table = text.parse().unwrap();
            table.remove("synth");
            let scene = Scene::from_toml_str(&toml::to_string(&table).unwrap()).unwrap();
            scene.validate().unwrap_or_else(|e| panic!("{path}: {e}"));
        }
    }

    /// Issue 8, items 11–12: each is refused by the one shared validation,
    /// with the field named.
    #[test]
    fn nonsense_scenes_are_refused_naming_the_field() {
        let cases = [
            ("[particles]\ntick_ms = 1000.0\n", "particles.tick_ms = 1000 ms"),
            ("duration_s = 1e-9\n", "duration_s = 1e-9 s is shorter than one tick"),
            ("[world]\nspeed_of_sound = 1e6\n", "world.speed_of_sound"),
            ("[world]\nspeed_of_sound = 1e-300\n", "world.speed_of_sound"),
            ("[world]\nspeed_of_sound = nan\n", "got NaN"),
            ("[random_obstacles]\nregion = [60.0, 60.0, 70.0, 70.0]\n", "must lie inside world.bounds"),
            ("[mapping]\ncell = 1e9\n", "mapping.cell = 1e9 m leaves fewer than 10 cells"),
            ("[mapping]\ncell = 0.0001\n", "bytes to map"),
            ("[mapping]\nellipse_points = 4294967295\n", "ellipse_points"),
            ("[source]\nposition = [1.0, 2.0, 3.0]\n", "expected an array of 2 numbers, got 3"),
            ("[source]\nposition = [1.0]\n", "expected an array of 2 numbers, got 1"),
            ("[world]\nbounds = [0.0, 0.0, 1.0, 1.0, 5.0]\n", "expected an array of 4 numbers, got 5"),
            ("[[obstacles]]\nvertices = [[0.0, 0.0, 1.0], [1.0, 0.0], [1.0, 1.0]]\n", "vertex 0"),
            ("[random_obstacles]\ncount = 0\n", "random_obstacles.count must be in 1..=100"),
            ("[random_obstacles]\ncount = 4294967295\n", "random_obstacles.count must be in 1..=100"),
            // An unused table is still validated (explicit obstacles make random_obstacles unused).
            (
                "[random_obstacles]\ndiameter = [nan, 1.0]\n[[obstacles]]\ncenter = [10.0, -20.0]\nradius = 2.0\n",
                "random_obstacles.diameter[0]",
            ),
            ("[[listeners]]\nspin_rate = nan\n", "listeners[0].spin_rate"),
            ("[[listeners]]\nspeed = inf\n", "listeners[0].speed"),
            ("[[listeners]]\nspeed = 400.0\n", "below the speed of sound"),
            ("[[listeners]]\nsampling = { period_ms = 1e300 }\n", "at most 10000000 ms, got 1e300"),
            ("[source]\nposition = [nan, 0.0]\n", "source.position (NaN, 0) is not inside"),
            ("[world]\nbounds = [-1e300, -50.0, 50.0, 50.0]\n", "within ±1000000 m"),
            ("[[obstacles]]\ncenter = [1e300, 0.0]\nradius = 1.0\n", "obstacles[0]"),
            // Every valid key is listed (the message was cut after the second).
            ("[mapping.evidence]\nfoo = 1\n", "`highlight_min_logodds`, `max_surfaces`"),
            ("[chirp]\nduration = 1e5\n", "chirp.duration must be within 0.0001–60 s, got 100000"),
            ("[chirp]\nduration = 1e-320\n", "chirp.duration must be within 0.0001–60 s, got 9.99989e-321"),
            ("[chirp]\nduration = 0.00005\n", "chirp.duration must be within 0.0001–60 s, got 5e-5"),
            ("seed = 18446744073709551615\n", "seed"),
        ];
        for (toml, want) in cases {
            let err = invalid(toml);
            assert!(err.contains(want), "{toml:?}: {err:?} should contain {want:?}");
            assert!(!err.contains("Point {") && err.len() < 400, "{err}");
        }
    }

    #[test]
    fn a_huge_value_is_quoted_as_a_short_excerpt() {
        let text = format!("[world]\nspeed_of_sound = {}\n", "9".repeat(1_000_000));
        let err = Scene::from_toml_str(&text).unwrap_err().to_string();
        assert!(err.len() < 300 && err.contains("line 2"), "{} chars", err.len());
    }

    #[test]
    fn half_specified_obstacle_is_an_error() {
        let s = Scene::from_toml_str("[[obstacles]]\ncenter = [1.0, 2.0]\n").unwrap();
        let err = s.explicit_obstacles().unwrap_err().to_string();
        assert!(err.contains("obstacles[0]"), "{err}");
    }
}
