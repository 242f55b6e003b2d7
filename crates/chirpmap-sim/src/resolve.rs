//! Scene → validated, fully resolved simulation plan.
//!
//! Everything random that is not per-particle is drawn here, in a fixed order
//! (obstacles, emission offsets, sampling instants), so both simulators run on
//! an identical plan and the resolved scene replays the run exactly.

use crate::error::{SimError, scene_err};
use crate::rng::{RunSeeds, stream};
use crate::trajectory::{Capsule, Trajectory};
use chirpmap_core::geometry::point_segment_distance;
use chirpmap_core::scene::{ObstacleSpec, Sampling};
use chirpmap_core::{Obstacle, Point, Scene, Shape, Sweep};
use rand::Rng;

/// Spectrum bin width (Hz), docs/parameters.md "ours".
pub const BIN_HZ: f64 = 10.0;
/// Random obstacles keep at least this gap (m) from the source.
pub const SOURCE_CLEARANCE_M: f64 = 1.0;
const MAX_PARTICLES: u64 = 2_000_000_000;
/// Particles per tick (checked by [`Scene::validate`]).
pub const MAX_PER_TICK: u32 = chirpmap_core::scene::MAX_PER_TICK;
/// Measurements over all listeners together (a measurement index is a `u32`).
pub const MAX_MEASUREMENTS: usize = 10_000_000;
/// Largest |spin_rate| (rad/s), checked by [`Scene::validate`].
pub const MAX_SPIN_RPS: f64 = chirpmap_core::scene::MAX_SPIN_RPS;
/// Largest total turn |spin_rate|·duration_s (rad) of a listener: its disc's
/// sweep is covered by one capsule per 0.1 rad, each tested per particle
/// segment, so this caps the work at 1000 capsules per listener.
pub const MAX_TURN_RAD: f64 = 100.0;
/// Largest listener radius, as a fraction of the world's smaller side
/// (checked by [`Scene::validate`]). The disc senses every particle inside
/// it, so the work grows with its area.
pub const MAX_RADIUS_FRACTION: f64 = chirpmap_core::scene::MAX_RADIUS_FRACTION;
/// Longest run, in ticks (10⁷ ticks = 10⁴ s at 1 ms): a guard against typos, not a physical limit.
const MAX_TICKS: f64 = 1e7;
const PLACEMENT_TRIES: u32 = 10_000;

/// One listener's trajectory and measurement instants.
#[derive(Debug, Clone, PartialEq)]
pub struct ListenerPlan {
    /// Listener id: its index in the scene's `listeners`.
    pub id: u32,
    /// Known motion of the listener.
    pub trajectory: Trajectory,
    /// Detection radius (m): particles within it are sensed.
    pub radius_m: f64,
    /// Measurement ticks, strictly increasing.
    pub ticks: Vec<u64>,
    /// Listener position and velocity at each measurement tick.
    pub positions: Vec<Point>,
    /// Listener velocity (m/s) at each measurement tick, for Doppler.
    pub velocities: Vec<Point>,
    /// Global index of this listener's first measurement.
    pub first_measurement: usize,
    /// Conservative cover of the disc's sweep over the whole run.
    pub capsules: Vec<Capsule>,
}

/// A validated scene, ready to simulate.
#[derive(Debug)]
pub struct Resolved {
    /// The fully resolved scene (random obstacles listed, duration explicit).
    pub scene: Scene,
    /// Source position (m).
    pub source: Point,
    /// Speed of sound a (m/s).
    pub speed_of_sound_mps: f64,
    /// World bounds `[xmin, ymin, xmax, ymax]` (m); particles leaving them are dropped.
    pub world: [f64; 4],
    /// The emitted sweep.
    pub sweep: Box<dyn Sweep>,
    /// All obstacles, random ones included.
    pub obstacles: Vec<Obstacle>,
    /// Particles emitted per tick.
    pub per_tick: u32,
    /// Tick length (s).
    pub tick_s: f64,
    /// Path length a particle covers per tick (m).
    pub step_m: f64,
    /// Emission happens at ticks `0..n_emit_ticks` (t < T).
    pub n_emit_ticks: u64,
    /// Last simulated tick (inclusive).
    pub last_tick: u64,
    /// Emission frequency (Hz) per emission tick.
    pub emit_freq_hz: Vec<f64>,
    /// Random angular offset (rad) per emission tick, in [0, 2π/per_tick).
    pub emit_offset_rad: Vec<f64>,
    /// `(cos, sin)` of each tick's offset.
    pub emit_rot: Vec<(f64, f64)>,
    /// Unit directions of one tick before the offset ([`crate::physics::direction_table`]).
    pub dir_table: Vec<Point>,
    /// Key of the counter-based generator drawn at bounces ([`crate::rng::RunSeeds::bounce_key`]).
    pub bounce_key: u64,
    /// Particles quieter than this (relative to emission) are dropped.
    pub min_loudness: f64,
    /// Whether heard frequencies are Doppler-shifted by the listener's motion.
    pub doppler: bool,
    /// Per listener, its trajectory and measurement instants.
    pub listeners: Vec<ListenerPlan>,
    /// Bins further apart than this are separate peaks: one more than the
    /// largest bin step between consecutive ticks' frequencies (the particle
    /// model samples the sweep once per tick, so one arrival occupies every
    /// first or second bin).
    pub merge_gap_bins: i64,
}

fn positive(field: &str, v: f64) -> Result<f64, SimError> {
    if v.is_finite() && v > 0.0 { Ok(v) } else { Err(scene_err(format!("{field} must be finite and > 0, got {v}"))) }
}

fn inside(world: &[f64; 4], p: Point) -> bool {
    p.x > world[0] && p.x < world[2] && p.y > world[1] && p.y < world[3]
}

fn check_rect(field: &str, r: &[f64; 4]) -> Result<(), SimError> {
    if r.iter().all(|v| v.is_finite()) && r[0] < r[2] && r[1] < r[3] {
        Ok(())
    } else {
        Err(scene_err(format!(
            "{field} must be [xmin, ymin, xmax, ymax] with finite xmin < xmax, ymin < ymax, got {r:?}"
        )))
    }
}

fn segments_intersect(a: Point, b: Point, c: Point, d: Point) -> bool {
    let o = |p: Point, q: Point, r: Point| (q - p).cross(r - p);
    let (d1, d2, d3, d4) = (o(c, d, a), o(c, d, b), o(a, b, c), o(a, b, d));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0)) && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0)) {
        return true;
    }
    point_segment_distance(a, c, d) == 0.0
        || point_segment_distance(b, c, d) == 0.0
        || point_segment_distance(c, a, b) == 0.0
        || point_segment_distance(d, a, b) == 0.0
}

/// Distance between segments `a`–`b` and `c`–`d`.
fn segment_distance(a: Point, b: Point, c: Point, d: Point) -> f64 {
    if segments_intersect(a, b, c, d) {
        return 0.0;
    }
    point_segment_distance(a, c, d)
        .min(point_segment_distance(b, c, d))
        .min(point_segment_distance(c, a, b))
        .min(point_segment_distance(d, a, b))
}

/// Whether an obstacle shape comes within a capsule (a listener's disc sweep).
fn shape_meets_capsule(shape: &Shape, c: &Capsule) -> bool {
    match shape {
        Shape::Circle(q) => point_segment_distance(q.center, c.a, c.b) < q.radius_m + c.radius_m,
        Shape::Polygon(p) => p.contains(c.a) || p.edges().any(|(u, v)| segment_distance(u, v, c.a, c.b) < c.radius_m),
    }
}

/// First time (s) in `[0, last_tick·tick_s]` at which the listener's centre
/// is no longer strictly inside the world, to within a µs; `None` if never.
/// Checked at every tick (positions between ticks only matter through the
/// capsules), then refined by bisection between the last tick inside and the
/// first outside.
fn leaves_world(t: &Trajectory, world: &[f64; 4], tick_s: f64, last_tick: u64) -> Option<f64> {
    let out = |k: u64| !inside(world, t.position(k as f64 * tick_s));
    let k = (1..=last_tick).find(|&k| out(k))?;
    let (mut lo, mut hi) = ((k - 1) as f64 * tick_s, k as f64 * tick_s);
    while hi - lo > 1e-6 {
        let mid = 0.5 * (lo + hi);
        if inside(world, t.position(mid)) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(hi)
}

/// Whether two obstacle shapes share interior points (touching is allowed).
pub fn shapes_overlap(a: &Shape, b: &Shape) -> bool {
    match (a, b) {
        (Shape::Circle(p), Shape::Circle(q)) => p.center.dist(q.center) < p.radius_m + q.radius_m,
        (Shape::Circle(c), Shape::Polygon(p)) | (Shape::Polygon(p), Shape::Circle(c)) => {
            p.contains(c.center) || p.edges().any(|(u, v)| point_segment_distance(c.center, u, v) < c.radius_m)
        }
        (Shape::Polygon(p), Shape::Polygon(q)) => {
            p.edges().any(|(a1, a2)| q.edges().any(|(b1, b2)| segments_intersect(a1, a2, b1, b2)))
                || p.vertices().first().is_some_and(|v| q.contains(*v))
                || q.vertices().first().is_some_and(|v| p.contains(*v))
        }
    }
}

fn build_sampling(
    field: &str,
    s: &Sampling,
    tick_s: f64,
    last_tick: u64,
    budget: usize,
    rng: &mut impl Rng,
) -> Result<Vec<u64>, SimError> {
    let to_ticks = |ms: f64| ((ms * 1e-3 / tick_s).round() as u64).max(1);
    let mut ticks = Vec::new();
    match (s.period_ms, s.random_ms) {
        (Some(p), None) => {
            let step = to_ticks(positive(&format!("{field}.period_ms"), p)?);
            let mut k = step;
            while k <= last_tick && ticks.len() <= budget {
                ticks.push(k);
                k += step;
            }
        }
        (None, Some([lo, hi])) => {
            positive(&format!("{field}.random_ms[0]"), lo)?;
            positive(&format!("{field}.random_ms[1]"), hi)?;
            if lo > hi {
                return Err(scene_err(format!(
                    "{field}.random_ms must be [low, high] with low <= high, got [{lo}, {hi}]"
                )));
            }
            let mut k = 0u64;
            loop {
                k += to_ticks(lo + (hi - lo) * rng.random::<f64>());
                if k > last_tick || ticks.len() > budget {
                    break;
                }
                ticks.push(k);
            }
        }
        _ => return Err(scene_err(format!("{field}: give exactly one of `period_ms` or `random_ms`"))),
    }
    if ticks.len() > budget {
        return Err(scene_err(format!(
            "{field}: more than {budget} measurements, which would exceed the cap of {MAX_MEASUREMENTS} \
             measurements over all listeners; raise period_ms or lower duration_s"
        )));
    }
    Ok(ticks)
}

/// Validates `scene` and resolves everything random outside the particles.
///
/// Errors name the offending field; nothing here panics on user data.
pub fn resolve(scene: &Scene) -> Result<Resolved, SimError> {
    // The one schema validation every command shares (issue 8, item 11).
    scene.validate()?;
    let seeds = RunSeeds::new(scene.seed, scene.run_index);
    let a = positive("world.speed_of_sound", scene.world.speed_of_sound)?;
    let world = scene.world.bounds;
    check_rect("world.bounds", &world)?;
    let sweep = scene.chirp.build()?;
    let source = scene.source_position();
    if !source.is_finite() || !inside(&world, source) {
        return Err(scene_err(format!("source.position {source} is not inside world.bounds {world:?}")));
    }
    let p = &scene.particles;
    if p.per_tick == 0 || p.per_tick > MAX_PER_TICK {
        return Err(scene_err(format!("particles.per_tick must be in 1..={MAX_PER_TICK}, got {}", p.per_tick)));
    }
    let tick_s = positive("particles.tick_ms", p.tick_ms)? * 1e-3;
    if !(p.min_loudness.is_finite() && (0.0..1.0).contains(&p.min_loudness)) {
        return Err(scene_err(format!("particles.min_loudness must be in [0, 1), got {}", p.min_loudness)));
    }
    scene.mapping.validate()?;
    let chirp_s = sweep.duration_s();
    let far_m = [(world[0], world[1]), (world[2], world[1]), (world[0], world[3]), (world[2], world[3])]
        .iter()
        .map(|&(x, y)| source.dist(Point::new(x, y)))
        .fold(0.0, f64::max);
    let duration_s = match scene.duration_s {
        Some(d) => positive("duration_s", d)?,
        None => chirp_s + far_m / a,
    };
    for (name, ticks) in [("chirp.duration", chirp_s / tick_s), ("duration_s", duration_s / tick_s)] {
        if ticks > MAX_TICKS {
            return Err(scene_err(format!(
                "{name} is {ticks:.3e} ticks of particles.tick_ms, more than the cap of {MAX_TICKS:e}"
            )));
        }
    }
    let last_tick = (duration_s / tick_s + 1e-9).floor() as u64;
    // Emission stops with the chirp, or with the run if that is shorter.
    let n_emit_ticks = (((chirp_s / tick_s) - 1e-9).ceil().max(1.0) as u64).min(last_tick + 1);
    if n_emit_ticks.saturating_mul(u64::from(p.per_tick)) > MAX_PARTICLES {
        return Err(scene_err(format!(
            "{} ticks x {} particles is more than the cap of {MAX_PARTICLES} particles; raise particles.tick_ms or lower per_tick",
            n_emit_ticks, p.per_tick
        )));
    }

    // Listeners.
    if scene.listeners.is_empty() {
        return Err(scene_err("at least one [[listeners]] is needed"));
    }
    let mut listeners = Vec::with_capacity(scene.listeners.len());
    let mut first = 0usize;
    let max_radius_m = MAX_RADIUS_FRACTION * (world[2] - world[0]).min(world[3] - world[1]);
    let run_s = last_tick as f64 * tick_s;
    for (i, l) in scene.listeners.iter().enumerate() {
        let field = format!("listeners[{i}]");
        let start = Point::new(l.start[0], l.start[1]);
        if !start.is_finite() || !inside(&world, start) {
            return Err(scene_err(format!("{field}.start {start} is outside world.bounds {world:?}")));
        }
        let speed = positive(&format!("{field}.speed"), l.speed)?;
        let radius_m = positive(&format!("{field}.radius"), l.radius)?;
        if radius_m > max_radius_m {
            return Err(scene_err(format!(
                "{field}.radius must be at most {max_radius_m} m ({MAX_RADIUS_FRACTION} of the world's smaller side), got {radius_m}"
            )));
        }
        if !l.heading_deg.is_finite() {
            return Err(scene_err(format!("{field}.heading_deg must be finite, got {}", l.heading_deg)));
        }
        if !l.spin_rate.is_finite() || l.spin_rate.abs() > MAX_SPIN_RPS {
            return Err(scene_err(format!(
                "{field}.spin_rate must be within ±{MAX_SPIN_RPS:.4} rad/s (one turn per second), got {}",
                l.spin_rate
            )));
        }
        let turn = l.spin_rate.abs() * run_s;
        if turn > MAX_TURN_RAD {
            return Err(scene_err(format!(
                "{field}.spin_rate × duration_s is {turn:.1} rad of turn, more than the cap of {MAX_TURN_RAD} rad; \
                 lower spin_rate or duration_s"
            )));
        }
        let trajectory =
            Trajectory { start, heading_rad: l.heading_deg.to_radians(), speed_mps: speed, spin_rate_rps: l.spin_rate };
        if let Some(t) = leaves_world(&trajectory, &world, tick_s, last_tick) {
            let at = trajectory.position(t);
            return Err(scene_err(format!(
                "{field} leaves world.bounds {world:?} at t = {t:.4} s (near ({:.3}, {:.3})) within the {run_s:.4} s run; \
                 change its start, heading_deg, speed or spin_rate, or shorten duration_s",
                at.x, at.y
            )));
        }
        let mut rng = stream(seeds.sampling, i as u64);
        let budget = MAX_MEASUREMENTS - first;
        let ticks = build_sampling(&format!("{field}.sampling"), &l.sampling, tick_s, last_tick, budget, &mut rng)?;
        if ticks.is_empty() {
            return Err(scene_err(format!(
                "{field} makes no measurement within the {} s run (its first comes one sampling period after the \
                 start); lengthen duration_s or shorten {field}.sampling",
                chirpmap_core::error::Num(run_s)
            )));
        }
        let capsules = trajectory.capsules(run_s, radius_m);
        let id = u32::try_from(i).map_err(|_| scene_err("too many listeners"))?;
        let n = ticks.len();
        let positions = ticks.iter().map(|&k| trajectory.position(k as f64 * tick_s)).collect();
        let velocities = ticks.iter().map(|&k| trajectory.velocity(k as f64 * tick_s)).collect();
        listeners.push(ListenerPlan {
            id,
            trajectory,
            radius_m,
            ticks,
            positions,
            velocities,
            first_measurement: first,
            capsules,
        });
        first += n;
    }

    // Obstacles: explicit, or random (paper §III: U(5, 10) m diameters, no overlaps).
    let mut resolved_scene = scene.clone();
    let obstacles: Vec<Obstacle> = if scene.obstacles.is_empty() {
        let specs = random_obstacles(scene, source, &listeners, seeds.obstacles)?;
        let obs = specs.iter().enumerate().map(|(i, o)| o.build(i)).collect::<Result<Vec<_>, _>>()?;
        resolved_scene.obstacles = specs;
        obs
    } else {
        scene.explicit_obstacles()?
    };
    for (i, o) in obstacles.iter().enumerate() {
        if o.shape.contains(source) || o.shape.surface_distance(source) < 1e-9 {
            return Err(scene_err(format!("obstacles[{i}] contains the source at {source}")));
        }
        for (k, l) in listeners.iter().enumerate() {
            if o.shape.contains(l.trajectory.start) {
                return Err(scene_err(format!("obstacles[{i}] contains the start of listeners[{k}]")));
            }
            if l.capsules.iter().any(|c| shape_meets_capsule(&o.shape, c)) {
                return Err(scene_err(format!(
                    "obstacles[{i}] is on the path of listeners[{k}]: its {} m disc would enter the obstacle \
                     within the {:.4} s run",
                    l.radius_m, run_s
                )));
            }
        }
        for (j, q) in obstacles.iter().enumerate().take(i) {
            if shapes_overlap(&o.shape, &q.shape) {
                return Err(scene_err(format!("obstacles[{i}] overlaps obstacles[{j}]")));
            }
        }
    }
    resolved_scene.duration_s = Some(duration_s);

    let emit_freq_hz: Vec<f64> =
        (0..n_emit_ticks).map(|k| sweep.freq_at(k as f64 * tick_s).unwrap_or_else(|| sweep.f_end_hz())).collect();
    let mut rng = stream(seeds.emission, 0);
    let slice = std::f64::consts::TAU / f64::from(p.per_tick);
    let emit_offset_rad: Vec<f64> = (0..n_emit_ticks).map(|_| rng.random::<f64>() * slice).collect();
    let max_step_hz = emit_freq_hz.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
    let merge_gap_bins = (max_step_hz / BIN_HZ).ceil() as i64 + 1;

    Ok(Resolved {
        scene: resolved_scene,
        source,
        speed_of_sound_mps: a,
        world,
        sweep,
        obstacles,
        per_tick: p.per_tick,
        tick_s,
        step_m: a * tick_s,
        n_emit_ticks,
        last_tick,
        emit_freq_hz,
        emit_rot: emit_offset_rad
            .iter()
            .map(|o| {
                let (s, c) = o.sin_cos();
                (c, s)
            })
            .collect(),
        emit_offset_rad,
        dir_table: crate::physics::direction_table(p.per_tick),
        bounce_key: seeds.bounce_key,
        min_loudness: p.min_loudness,
        doppler: p.doppler,
        listeners,
        merge_gap_bins,
    })
}

/// Non-overlapping random circles (paper §III), drawn from the run's obstacle
/// stream only, never covering the source (with [`SOURCE_CLEARANCE_M`]) or any
/// listener's swept disc.
fn random_obstacles(
    scene: &Scene,
    source: Point,
    listeners: &[ListenerPlan],
    seed: u64,
) -> Result<Vec<ObstacleSpec>, SimError> {
    let r = &scene.random_obstacles;
    let [d_lo, d_hi] = r.diameter;
    positive("random_obstacles.diameter[0]", d_lo)?;
    positive("random_obstacles.diameter[1]", d_hi)?;
    if d_lo > d_hi {
        return Err(scene_err(format!(
            "random_obstacles.diameter must be [low, high] with low <= high, got {:?}",
            r.diameter
        )));
    }
    check_rect("random_obstacles.region", &r.region)?;
    for (name, v) in [("roughness", r.roughness), ("absorption", r.absorption)] {
        if !(0.0..=1.0).contains(&v) {
            return Err(scene_err(format!("random_obstacles.{name} must be in [0, 1], got {v}")));
        }
    }
    let mut rng = stream(seed, 0);
    let mut placed: Vec<(Point, f64)> = Vec::new();
    for n in 0..r.count {
        let mut ok = false;
        for _ in 0..PLACEMENT_TRIES {
            let radius = 0.5 * (d_lo + (d_hi - d_lo) * rng.random::<f64>());
            let c = Point::new(
                r.region[0] + (r.region[2] - r.region[0]) * rng.random::<f64>(),
                r.region[1] + (r.region[3] - r.region[1]) * rng.random::<f64>(),
            );
            let clear = c.dist(source) > radius + SOURCE_CLEARANCE_M
                && placed.iter().all(|&(q, rq)| c.dist(q) >= radius + rq)
                && listeners
                    .iter()
                    .flat_map(|l| l.capsules.iter())
                    .all(|cap| point_segment_distance(c, cap.a, cap.b) > radius + cap.radius_m);
            if clear {
                placed.push((c, radius));
                ok = true;
                break;
            }
        }
        if !ok {
            return Err(scene_err(format!(
                "random_obstacles: could not place obstacle {} of {} without overlaps in {PLACEMENT_TRIES} tries; \
                 enlarge the region or lower count/diameter",
                n + 1,
                r.count
            )));
        }
    }
    Ok(placed
        .into_iter()
        .map(|(c, radius)| {
            let mut o = ObstacleSpec::circle(c, radius);
            o.roughness = r.roughness;
            o.absorption = r.absorption;
            o
        })
        .collect())
}

impl Resolved {
    /// Total number of measurements over all listeners.
    pub fn measurement_count(&self) -> usize {
        self.listeners.iter().map(|l| l.ticks.len()).sum()
    }

    /// Absolute time (s) of tick `k`.
    pub fn time_s(&self, tick: u64) -> f64 {
        tick as f64 * self.tick_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_scene_resolves_with_three_obstacles_clear_of_everything() {
        let r = resolve(&Scene::default()).unwrap();
        assert_eq!(r.obstacles.len(), 3);
        assert_eq!(r.n_emit_ticks, 500);
        assert_eq!(r.emit_freq_hz.len(), 500);
        assert!((r.emit_freq_hz[1] - r.emit_freq_hz[0] + 19.6).abs() < 1e-9);
        assert_eq!(r.merge_gap_bins, 3);
        // 0.5 s + 70.71 m / 343 m/s = 0.706 s.
        assert_eq!(r.last_tick, 706);
        assert_eq!(r.listeners[0].ticks.first(), Some(&10));
        for (i, o) in r.obstacles.iter().enumerate() {
            assert!(o.shape.surface_distance(r.source) > SOURCE_CLEARANCE_M);
            for q in &r.obstacles[..i] {
                assert!(!shapes_overlap(&o.shape, &q.shape));
            }
        }
        // Replaying the resolved scene gives the same plan.
        let again = resolve(&r.scene).unwrap();
        assert_eq!(again.obstacles, r.obstacles);
        assert_eq!(again.emit_offset_rad, r.emit_offset_rad);
        assert_eq!(again.listeners, r.listeners);
    }

    #[test]
    fn obstacles_do_not_depend_on_other_configuration() {
        let base = resolve(&Scene::default()).unwrap();
        let mut s = Scene::default();
        s.particles.per_tick = 100;
        s.listeners[0].spin_rate = std::f64::consts::FRAC_PI_4;
        s.listeners[0].sampling = Sampling { period_ms: None, random_ms: Some([10.0, 100.0]) };
        assert_eq!(resolve(&s).unwrap().obstacles, base.obstacles);
        s.run_index = 1;
        assert_ne!(resolve(&s).unwrap().obstacles, base.obstacles);
    }

    #[test]
    fn random_sampling_stays_in_range() {
        let mut s = Scene::default();
        s.listeners[0].sampling = Sampling { period_ms: None, random_ms: Some([10.0, 100.0]) };
        let r = resolve(&s).unwrap();
        let t = &r.listeners[0].ticks;
        assert!(t.len() > 5);
        assert!(t.windows(2).all(|w| (10..=100).contains(&(w[1] - w[0]))));
    }

    fn err_of(toml: &str) -> String {
        let s = Scene::from_toml_str(toml).unwrap();
        resolve(&s).unwrap_err().to_string()
    }

    #[test]
    fn bad_scenes_are_errors_naming_the_field() {
        assert!(err_of("[world]\nspeed_of_sound = 0.0\n").contains("speed_of_sound"));
        assert!(err_of("[chirp]\nf_start = 500.0\nf_end = 500.0\n").contains("f_start and f_end"));
        assert!(err_of("[particles]\nper_tick = 0\n").contains("per_tick"));
        assert!(err_of("[particles]\ntick_ms = -1.0\n").contains("tick_ms"));
        assert!(err_of("[[listeners]]\nstart = [80.0, 0.0]\n").contains("outside world"));
        assert!(err_of("[[listeners]]\nspeed = 0.0\n").contains("speed"));
        assert!(err_of("[[listeners]]\nradius = -0.5\n").contains("radius"));
        assert!(err_of("[[listeners]]\nsampling = { period_ms = 0.0 }\n").contains("period_ms"));
        assert!(err_of("[[obstacles]]\ncenter = [0.0, 1.0]\nradius = 2.0\n").contains("contains the source"));
        assert!(
            err_of("[[obstacles]]\ncenter = [0.0, -20.0]\nradius = 3.0\n[[obstacles]]\ncenter = [4.0, -20.0]\nradius = 3.0\n")
                .contains("overlaps")
        );
        assert!(err_of("[random_obstacles]\ncount = 50\ndiameter = [9.0, 10.0]\n").contains("could not place"));
        assert!(err_of("duration_s = 1e300\n").contains("cap"));
        assert!(err_of("[particles]\ntick_ms = 1e-12\n").contains("cap"));
    }
}
