//! The fast simulator: each particle's path is traced once, at emission, and
//! each straight segment is tested only at the few measurement ticks at which
//! it can be inside a listener's disc.
//!
//! Exactness argument: a particle is sensed at tick m iff its position (path
//! length `σ = a·dt·(m − k)` along its path) is within the radius of the
//! listener's position at m. The listener's disc over the whole run lies in
//! the listener's capsules, so a segment can only be sensed while it is inside
//! them; [`capsule_interval`] gives that part of the segment exactly, and every
//! measurement tick in it is tested with the same distance test the stepper
//! uses. Particles whose first segment points away from every obstacle and
//! every capsule (an angular window seen from the source) fly straight out of
//! the world unsensed and are skipped without tracing. Likewise a particle
//! whose every possible outgoing direction after a bounce misses every
//! obstacle and every listener's capsules ([`Reach`]) stops there, before its
//! rough bounce is drawn.

use crate::Sensed;
use crate::analysis::{SimOutput, Spectra, analyse_spectra};
use crate::physics::{
    T_MIN_M, apply_bounce, capsule_interval, circle_hit, disc_window, emission_dir, nearest_hit, points_window,
    world_exit_m,
};
use crate::resolve::Resolved;
use crate::trajectory::Capsule;
use chirpmap_core::geometry::reflect;
use chirpmap_core::{Point, Shape};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Runs the fast simulator and extracts spectra, peaks and echoes.
///
/// Sensed particles go straight into per-measurement frequency bins, one
/// emission tick at a time, so memory does not grow with the number of
/// particles sensed; the spectra are bit-identical to
/// [`analyse`](crate::analyse)`(r, sense_fast(r))` (see [`Spectra`]).
pub fn simulate(r: &Resolved) -> SimOutput {
    let mut spectra = Spectra::new(r);
    sense_by_tick(r, |block| spectra.add(block));
    analyse_spectra(r, spectra)
}

/// Angular windows (centre, half-width) that contain every first segment that
/// can hit an obstacle; `None` = all directions.
fn windows(r: &Resolved) -> Option<Vec<(f64, f64)>> {
    let mut w = Vec::new();
    for o in &r.obstacles {
        w.push(match &o.shape {
            Shape::Circle(c) => disc_window(r.source, c.center, c.radius_m * (1.0 + 1e-9) + 1e-9)?,
            Shape::Polygon(p) => points_window(r.source, p.vertices())?,
        });
    }
    Some(w)
}

/// Width of the emission-angle bins of [`traced_windows`] (rad): about half
/// the angle between the default scene's particles (2π/3600).
const SILENT_BIN_RAD: f64 = 1e-3;

/// The windows of [`windows`] without the emission angles whose particles
/// are sure to bounce once, off a circle, and then meet nothing: their
/// particles are not traced at all. In the default 1 ms scene that is most
/// of the particles the windows hold ([`Reach`] stops the same particles
/// one at a time, after tracing their first segment).
///
/// A bin `[φa, φb]` of circle i's window is silent when both its ends hit
/// the circle, no other obstacle's window overlaps it (so every ray of the
/// bin first enters circle i), and the bounce cone of its first ray,
/// widened to cover the whole bin, meets no [`Reach`] target. The widening
/// is rigorous: as φ sweeps the bin, the entry point moves monotonically
/// along the near arc, so its normal turns by at most Δψ (the turn between
/// the ends' normals) and stays within R·Δψ of the first entry point, and
/// the specular direction (angle 2ψ − φ + π) turns by at most 2Δψ + Δφ.
fn traced_windows(r: &Resolved, windows: &[(f64, f64)], reach: &Reach) -> Vec<(f64, f64)> {
    let wrap = |a: f64| (a + PI).rem_euclid(TAU) - PI;
    let mut keep = Vec::new();
    for (i, (o, &(c, h))) in r.obstacles.iter().zip(windows).enumerate() {
        let (Shape::Circle(circle), Some((cos_a, _))) = (&o.shape, reach.cones[i]) else {
            keep.push((c, h));
            continue;
        };
        let half_cone_rad = cos_a.acos();
        let n_bins = ((2.0 * h / SILENT_BIN_RAD).ceil() as usize).clamp(1, 1 << 20);
        let bin_rad = 2.0 * h / n_bins as f64;
        let first_hit =
            |phi: f64| circle_hit(circle.center, circle.radius_m, r.source, Point::from_angle(phi), T_MIN_M);
        let silent = |lo: f64| -> bool {
            let hi = lo + bin_rad;
            let shadowed = windows.iter().enumerate().any(|(k, &(ck, hk))| {
                k != i && wrap(ck - (lo + hi) * 0.5).abs() <= hk + bin_rad * 0.5 + REACH_MARGIN_RAD
            });
            let (Some(a), Some(b)) = (first_hit(lo), first_hit(hi)) else { return false };
            if shadowed || !(is_unit(a.normal) && is_unit(b.normal)) {
                return false;
            }
            let turn_rad = a.normal.cross(b.normal).atan2(a.normal.dot(b.normal)).abs();
            let widened = half_cone_rad + 2.0 * turn_rad + bin_rad + REACH_MARGIN_RAD;
            if widened >= FRAC_PI_2 {
                return false;
            }
            let grown_m = circle.radius_m * turn_rad + REACH_MARGIN_M;
            let cone = (widened.cos(), widened.sin());
            !reach.cone_meets(i, a.point, reflect(Point::from_angle(lo), a.normal), cone, grown_m)
        };
        // Runs of traced bins become windows; silent runs are left out.
        let mut run_start: Option<f64> = None;
        for b in 0..=n_bins {
            let lo = c - h + b as f64 * bin_rad;
            let traced = b == n_bins || !silent(lo);
            match (traced && b < n_bins, run_start) {
                (true, None) => run_start = Some(lo),
                (false, Some(start)) => {
                    keep.push(((start + lo) * 0.5, (lo - start) * 0.5));
                    run_start = None;
                }
                _ => {}
            }
        }
    }
    keep
}

/// Merged, sorted index ranges `[lo, hi]` of one tick's particles inside the windows.
fn tick_ranges(windows: &[(f64, f64)], offset_rad: f64, per_tick: u32, out: &mut Vec<(u32, u32)>) {
    out.clear();
    let n = i64::from(per_tick);
    let slice = TAU / f64::from(per_tick);
    const MARGIN_RAD: f64 = 1e-6;
    for &(c, h) in windows {
        let lo_rad = (c - h - MARGIN_RAD - offset_rad).rem_euclid(TAU);
        let j_lo = (lo_rad / slice).floor() as i64 - 1;
        let j_hi = ((lo_rad + 2.0 * (h + MARGIN_RAD)) / slice).ceil() as i64 + 1;
        if j_hi - j_lo + 1 >= n {
            out.clear();
            out.push((0, per_tick - 1));
            return;
        }
        // j_lo ∈ [−1, n), j_hi < j_lo + n: at most one wrap either way.
        let (a, b) = (j_lo.rem_euclid(n), j_hi.rem_euclid(n));
        if a <= b && j_hi - j_lo < n {
            out.push((a as u32, b as u32));
        } else {
            out.push((a as u32, (n - 1) as u32));
            out.push((0, b as u32));
        }
    }
    out.sort_unstable();
    let mut merged: Vec<(u32, u32)> = Vec::with_capacity(out.len());
    for &(a, b) in out.iter() {
        match merged.last_mut() {
            Some(last) if a <= last.1.saturating_add(1) => last.1 = last.1.max(b),
            _ => merged.push((a, b)),
        }
    }
    *out = merged;
}

/// A capsule with its bounding circle, for a one-multiply early rejection.
#[derive(Debug, Clone, Copy)]
struct Cull {
    capsule: Capsule,
    center: Point,
    radius_m: f64,
}

fn culls(r: &Resolved) -> Vec<Vec<Cull>> {
    r.listeners
        .iter()
        .map(|l| {
            l.capsules
                .iter()
                .map(|c| Cull {
                    capsule: *c,
                    center: (c.a + c.b) * 0.5,
                    radius_m: 0.5 * c.a.dist(c.b) + c.radius_m + 1e-9,
                })
                .collect()
        })
        .collect()
}

/// What a particle leaving a bounce can still meet: a circle around each
/// obstacle and one around each listener's capsules, each a little larger
/// than what it holds. A bounce whose every possible outgoing direction
/// misses them all is the particle's last event: it flies out of the world
/// unsensed, so the tracer stops it before drawing its rough bounce (a
/// `sin_cos` of libm per bounce, 5 % of a default run's CPU) and tracing a
/// segment that senses nothing. The particles sensed, and so every output,
/// are unchanged (the simulator's oracle tests against the stepper).
#[derive(Debug)]
struct Reach {
    /// `(centre, radius)` of each target; obstacle `i` is target `i`.
    targets: Vec<(Point, f64)>,
    /// Per obstacle: cos and sin of the widest outgoing angle from the
    /// specular direction (`roughness · 90°` and a margin), or `None` when
    /// bounces off it are never stopped (a cone of 90° or more, or a concave
    /// polygon, which a particle may hit again).
    cones: Vec<Option<(f64, f64)>>,
}

/// Margins of [`Reach`]'s circles and cones: far above the rounding of a
/// bounce (~1e-16 relative) and far below any scene's scale.
const REACH_MARGIN_M: f64 = 1e-6;
const REACH_MARGIN_RAD: f64 = 1e-6;

impl Reach {
    fn new(r: &Resolved, culls: &[Vec<Cull>]) -> Self {
        let enclosing = |points: &[(Point, f64)]| {
            let n = points.len().max(1) as f64;
            let c = points.iter().fold(Point::new(0.0, 0.0), |acc, (p, _)| acc + *p) * (1.0 / n);
            let radius = points.iter().map(|(p, rad)| p.dist(c) + rad).fold(0.0, f64::max);
            (c, radius * (1.0 + 1e-9) + REACH_MARGIN_M)
        };
        let mut targets: Vec<(Point, f64)> = r
            .obstacles
            .iter()
            .map(|o| match &o.shape {
                Shape::Circle(c) => enclosing(&[(c.center, c.radius_m)]),
                Shape::Polygon(p) => enclosing(&p.vertices().iter().map(|v| (*v, 0.0)).collect::<Vec<_>>()),
            })
            .collect();
        for cull in culls.iter().filter(|c| !c.is_empty()) {
            targets.push(enclosing(&cull.iter().map(|c| (c.center, c.radius_m)).collect::<Vec<_>>()));
        }
        let cones = r
            .obstacles
            .iter()
            .map(|o| {
                let half_rad = o.roughness * FRAC_PI_2 + REACH_MARGIN_RAD;
                let convex = match &o.shape {
                    Shape::Circle(_) => true,
                    Shape::Polygon(p) => is_convex(p.vertices()),
                };
                (convex && half_rad < FRAC_PI_2).then(|| (half_rad.cos(), half_rad.sin()))
            })
            .collect();
        Self { targets, cones }
    }

    /// Whether a particle bouncing at `p` off obstacle `i` (outward unit
    /// `normal`), arriving along `dir`, can meet any target: any ray from
    /// `p` within the cone of half-angle a around the specular direction.
    /// [`bounce_dir`](crate::physics::bounce_dir)'s fold stays in the cone:
    /// with the specular direction e above the surface, a rotation by
    /// θ ∈ [−a, −e) folds to −(e + θ) above it, within |2e + θ| ≤ a of e.
    ///
    /// Only for unit `dir` and `normal` (to 1e-12): a direction's length
    /// drifts over many bounces off small far circles (`circle_hit`'s
    /// `b² − cc` loses digits), and then neither the reflection nor the fold
    /// is a rotation any more; such a bounce is never stopped (a review's
    /// scenes of 100 small circles lost particles before this test).
    #[inline]
    fn may_meet(&self, i: usize, p: Point, dir: Point, normal: Point) -> bool {
        let Some(cone) = self.cones[i] else { return true };
        !(is_unit(dir) && is_unit(normal)) || self.cone_meets(i, p, reflect(dir, normal), cone, 0.0)
    }

    /// Whether any ray from `p` within the cone `(cos a, sin a)` around
    /// `axis` meets a target other than obstacle `i`, each grown by `grown_m`.
    #[inline]
    fn cone_meets(&self, i: usize, p: Point, axis: Point, (cos_a, sin_a): (f64, f64), grown_m: f64) -> bool {
        self.targets.iter().enumerate().any(|(k, &(c, radius))| {
            if k == i {
                return false; // a convex obstacle is not met again
            }
            let radius = radius + grown_m;
            let w = c - p;
            let d2 = w.dot(w);
            if d2 <= radius * radius {
                return true;
            }
            // A ray at angle θ from w meets the circle iff θ ≤ asin(R/|w|); one
            // within the cone does iff the axis is within a + asin(R/|w|) of w,
            // i.e. axis·w ≥ cos a·√(|w|² − R²) − sin a·R (a + asin < π).
            let bound = cos_a * (d2 - radius * radius).sqrt() - sin_a * radius;
            axis.dot(w) >= bound
        })
    }
}

/// Whether `v`'s length is 1 to within 1e-12.
#[inline]
fn is_unit(v: Point) -> bool {
    (v.dot(v) - 1.0).abs() <= 1e-12
}

/// Whether a polygon is convex: every turn the same way and one turn in
/// all (a pentagram turns the same way at every vertex, but twice around,
/// and a particle leaving one spike can hit another).
fn is_convex(v: &[Point]) -> bool {
    let n = v.len();
    let (mut pos, mut neg, mut total_rad) = (false, false, 0.0f64);
    for k in 0..n {
        let (a, b) = (v[(k + 1) % n] - v[k], v[(k + 2) % n] - v[(k + 1) % n]);
        let t = a.cross(b);
        pos |= t > 0.0;
        neg |= t < 0.0;
        total_rad += t.atan2(a.dot(b));
    }
    !(pos && neg) && (total_rad.abs() - TAU).abs() < 1e-6
}

/// Every particle sensed by every listener at every measurement, from traced
/// paths: the list the oracle tests compare with the stepper's. Built by the
/// same code as [`simulate`]'s spectra.
pub fn sense_fast(r: &Resolved) -> Vec<Sensed> {
    let mut out = Vec::new();
    sense_by_tick(r, |block| out.extend_from_slice(block));
    out
}

/// One measurement's direct-sensing range: emission ticks `k_lo..=k_hi`
/// whose ring (radius σ = a·dt·(m − k) around the source) can touch the
/// listener's disc at measurement tick m, one tick of slack each side.
#[derive(Debug, Clone, Copy)]
struct DirectRange {
    k_lo: u64,
    k_hi: u64,
    listener: usize,
    idx: usize,
}

fn direct_ranges(r: &Resolved) -> Vec<DirectRange> {
    let mut v = Vec::with_capacity(r.measurement_count());
    if r.n_emit_ticks == 0 {
        return v;
    }
    for (listener, l) in r.listeners.iter().enumerate() {
        for (idx, &m) in l.ticks.iter().enumerate() {
            let d_m = (l.positions[idx] - r.source).norm();
            let lag_lo = (((d_m - l.radius_m) / r.step_m).floor().max(0.0) as u64).saturating_sub(1);
            let lag_hi = ((d_m + l.radius_m) / r.step_m).ceil() as u64 + 1;
            if m < lag_lo {
                continue;
            }
            let k_hi = (m - lag_lo).min(r.n_emit_ticks - 1);
            let k_lo = m.saturating_sub(lag_hi);
            if k_lo <= k_hi {
                v.push(DirectRange { k_lo, k_hi, listener, idx });
            }
        }
    }
    v.sort_by_key(|d| d.k_lo);
    v
}

/// Emission ticks traced per parallel task: enough work per task (2 500
/// particles per tick in the default scene) to hide rayon's scheduling,
/// small enough to balance two to eight threads.
const TICKS_PER_TASK: u64 = 4;

/// Ticks traced before their blocks are handed to the sink: bounds the
/// buffered sensed particles (memory does not grow with the run; with a
/// 4 m listener disc a tick senses ~7 000 particles, 64 ticks ~18 MB).
const TICKS_PER_WAVE: u64 = 64;

/// Senses every particle, handing `sink` each emission tick's sensed
/// particles sorted by (measurement, particle), ticks in increasing order.
///
/// Ticks are independent (a particle's path depends only on its tick and
/// index), so they are traced in parallel on rayon's pool, wave by wave,
/// and handed to `sink` in tick order: the blocks, and so the spectra, are
/// bit-identical whatever the thread count (issue 14: default run ≤ 50 ms).
fn sense_by_tick(r: &Resolved, mut sink: impl FnMut(&[Sensed])) {
    use rayon::prelude::*;
    let culls = culls(r);
    let reach = Reach::new(r, &culls);
    let windows = windows(r).map(|w| traced_windows(r, &w, &reach));
    let ctx = TickContext { r, windows, culls, reach, direct: direct_ranges(r) };
    let mut wave_start = 0;
    while wave_start < r.n_emit_ticks {
        let wave_end = (wave_start + TICKS_PER_WAVE).min(r.n_emit_ticks);
        let starts: Vec<u64> = (wave_start..wave_end).step_by(TICKS_PER_TASK as usize).collect();
        let blocks: Vec<Vec<Vec<Sensed>>> =
            starts.par_iter().map(|&k0| ctx.sense_ticks(k0..(k0 + TICKS_PER_TASK).min(wave_end))).collect();
        for block in blocks.iter().flatten() {
            sink(block);
        }
        wave_start = wave_end;
    }
}

/// What every tick's tracing reads: the run, the angular windows, the
/// listeners' capsules and the direct-sensing ranges.
struct TickContext<'a> {
    r: &'a Resolved,
    windows: Option<Vec<(f64, f64)>>,
    culls: Vec<Vec<Cull>>,
    reach: Reach,
    direct: Vec<DirectRange>,
}

impl TickContext<'_> {
    /// Each tick's sensed particles for `ticks`, sorted by (measurement,
    /// particle), in the same order within a tick as tracing every tick
    /// from 0 would give (the direct ranges active at a tick are those
    /// with `k_lo ≤ k ≤ k_hi`, in `direct`'s order).
    fn sense_ticks(&self, ticks: std::ops::Range<u64>) -> Vec<Vec<Sensed>> {
        let r = self.r;
        let mut ranges = Vec::new();
        let mut next_direct = self.direct.partition_point(|d| d.k_lo <= ticks.start);
        let mut active: Vec<DirectRange> =
            self.direct[..next_direct].iter().filter(|d| d.k_hi >= ticks.start).copied().collect();
        let mut blocks = Vec::with_capacity((ticks.end - ticks.start) as usize);
        for k in ticks {
            let mut block = Vec::new();
            // First segments: the measurements whose direct range contains k.
            active.retain(|d| d.k_hi >= k);
            while next_direct < self.direct.len() && self.direct[next_direct].k_lo <= k {
                if self.direct[next_direct].k_hi >= k {
                    active.push(self.direct[next_direct]);
                }
                next_direct += 1;
            }
            for d in &active {
                sense_direct(r, d.listener, d.idx, k, &mut ranges, &mut block);
            }
            // Reflected segments.
            let offset = r.emit_offset_rad[k as usize];
            match &self.windows {
                Some(w) => tick_ranges(w, offset, r.per_tick, &mut ranges),
                None => {
                    ranges.clear();
                    ranges.push((0, r.per_tick - 1));
                }
            }
            for &(a, b) in &ranges {
                for j in a..=b {
                    trace_particle(r, &self.culls, &self.reach, k, j, &mut block);
                }
            }
            block.sort_unstable_by_key(|s| (s.measurement, s.particle));
            blocks.push(block);
        }
        blocks
    }
}

/// Senses first segments (straight from the source, not yet reflected) of
/// emission tick `k` at measurement `idx` of listener `li` by inverting the
/// geometry: at measurement tick m, the particles of tick k are on the
/// circle of radius σ = a·dt·(m − k) around the source, and those inside the
/// listener's disc lie within the angle δ of the listener's bearing,
/// cos δ = (σ² + D² − r²)/(2σD). Only those few (plus a margin) are tested,
/// with the same distance test as everywhere else, and kept if their first
/// segment has not yet ended (obstacle or world edge) at σ.
fn sense_direct(r: &Resolved, li: usize, idx: usize, k: u64, ranges: &mut Vec<(u32, u32)>, out: &mut Vec<Sensed>) {
    let l = &r.listeners[li];
    let m = l.ticks[idx];
    let r2 = l.radius_m * l.radius_m;
    let centre = l.positions[idx];
    let to_l = centre - r.source;
    let d_m = to_l.norm();
    let bearing = to_l.y.atan2(to_l.x);
    let sigma = r.step_m * (m - k) as f64;
    let all = sigma < 1e-12 || d_m < 1e-12 || {
        let cos_d = (sigma * sigma + d_m * d_m - r2) / (2.0 * sigma * d_m);
        if cos_d > 1.0 {
            return;
        }
        cos_d <= -1.0 || {
            tick_ranges(&[(bearing, cos_d.acos())], r.emit_offset_rad[k as usize], r.per_tick, ranges);
            false
        }
    };
    if all {
        ranges.clear();
        ranges.push((0, r.per_tick - 1));
    }
    for &(a, b) in ranges.iter() {
        for j in a..=b {
            let dir = emission_dir(r.dir_table[j as usize], r.emit_rot[k as usize]);
            let w = r.source + dir * sigma - centre;
            let d2 = w.dot(w);
            if d2 > r2 {
                continue;
            }
            let exit = world_exit_m(r.source, dir, &r.world);
            let end = nearest_hit(&r.obstacles, r.source, dir, T_MIN_M).map_or(exit, |(h, _)| h.t.min(exit));
            if sigma < end {
                out.push(Sensed {
                    measurement: (l.first_measurement + idx) as u32,
                    particle: k * u64::from(r.per_tick) + u64::from(j),
                    freq_hz: heard_hz(r, r.emit_freq_hz[k as usize], dir, l.velocities[idx]),
                    loudness: 1.0,
                    dist_m: d2.sqrt(),
                });
            }
        }
    }
}

fn trace_particle(r: &Resolved, culls: &[Vec<Cull>], reach: &Reach, k: u64, j: u32, out: &mut Vec<Sensed>) {
    let id = k * u64::from(r.per_tick) + u64::from(j);
    let freq = r.emit_freq_hz[k as usize];
    let mut dir = emission_dir(r.dir_table[j as usize], r.emit_rot[k as usize]);
    let mut pos = r.source;
    let mut s0 = 0.0f64;
    let mut loud = 1.0f64;
    let mut bounces = 0u32;
    let s_max = r.step_m * (r.last_tick - k) as f64;
    loop {
        let exit = world_exit_m(pos, dir, &r.world);
        let hit = nearest_hit(&r.obstacles, pos, dir, T_MIN_M).filter(|(h, _)| h.t < exit);
        let len = hit.map_or(exit, |(h, _)| h.t);
        if bounces > 0 {
            sense_segment(r, culls, k, id, pos, dir, s0, len, freq, loud, out);
        }
        let Some((h, i)) = hit else { break };
        s0 += h.t;
        if s0 >= s_max {
            break;
        }
        pos = h.point;
        if !reach.may_meet(i, pos, dir, h.normal) {
            break;
        }
        (dir, loud) = apply_bounce(&r.obstacles[i], dir, h.normal, loud, r.bounce_key, id, bounces);
        bounces += 1;
        if loud < r.min_loudness {
            break;
        }
    }
}

/// Senses one straight segment: path lengths `[s0, s0 + len)` starting at `p`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn sense_segment(
    r: &Resolved,
    culls: &[Vec<Cull>],
    k: u64,
    id: u64,
    p: Point,
    u: Point,
    s0: f64,
    len: f64,
    freq: f64,
    loud: f64,
    out: &mut Vec<Sensed>,
) {
    for (l, cull) in r.listeners.iter().zip(culls) {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for c in cull {
            let w = c.center - p;
            let along = w.dot(u);
            if along < -c.radius_m || along > len + c.radius_m || u.cross(w).abs() > c.radius_m {
                continue;
            }
            if let Some((a, b)) = capsule_interval(p, u, &c.capsule) {
                lo = lo.min(a);
                hi = hi.max(b);
            }
        }
        let (a, b) = (lo.max(0.0), hi.min(len));
        if a > b {
            continue;
        }
        // Ticks m with σ = step·(m − k) ∈ [s0 + a, s0 + b], one tick of slack each side.
        let m_lo = k + (((s0 + a) / r.step_m).floor() as u64).saturating_sub(1);
        let m_hi = k + ((s0 + b) / r.step_m).ceil() as u64 + 1;
        let r2 = l.radius_m * l.radius_m;
        let start = l.ticks.partition_point(|&m| m < m_lo);
        for (idx, &m) in l.ticks.iter().enumerate().skip(start) {
            if m > m_hi {
                break;
            }
            if m < k {
                continue;
            }
            let sigma = r.step_m * (m - k) as f64;
            if sigma < s0 || sigma >= s0 + len {
                continue;
            }
            let w = p + u * (sigma - s0) - l.positions[idx];
            let d2 = w.dot(w);
            if d2 <= r2 {
                out.push(Sensed {
                    measurement: (l.first_measurement + idx) as u32,
                    particle: id,
                    freq_hz: heard_hz(r, freq, u, l.velocities[idx]),
                    loudness: loud,
                    dist_m: d2.sqrt(),
                });
            }
        }
    }
}

/// Heard frequency: with Doppler on, `f·(1 − v·u/a)` for a listener moving at
/// `v` and a particle travelling along `u` (moving into the sound raises it).
#[inline]
pub(crate) fn heard_hz(r: &Resolved, freq: f64, u: Point, v: Point) -> f64 {
    if r.doppler { freq * (1.0 - v.dot(u) / r.speed_of_sound_mps) } else { freq }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::bounce_dir;
    use proptest::prelude::*;

    proptest! {
        /// A bounce [`Reach::may_meet`] stops never leaves towards a target:
        /// every outgoing direction the bounce can draw (201 of them across
        /// its random number's range, the ends included) misses every other
        /// circle, measured by the ray's exact closest approach.
        #[test]
        fn a_stopped_bounce_meets_nothing(
            at_rad in 0.0..TAU, rough in prop_oneof![Just(0.0), 0.0..0.99f64],
            // Grazing arrivals often, where the bounce folds back off the surface.
            elevation_rad in prop_oneof![0.0..0.3f64, 0.0..FRAC_PI_2], leftwards in any::<bool>(),
            others in proptest::collection::vec((-30.0..30.0f64, -30.0..30.0f64, 0.05..6.0f64), 1..4),
        ) {
            let (c0, r0) = (Point::new(1.0, -2.0), 3.0);
            let normal = Point::from_angle(at_rad);
            let p = c0 + normal * r0;
            let tangent = Point::new(-normal.y, normal.x) * if leftwards { -1.0 } else { 1.0 };
            let dir = tangent * elevation_rad.cos() - normal * elevation_rad.sin();
            let mut circles = vec![(c0, r0)];
            circles.extend(others.iter().map(|&(x, y, r)| (Point::new(x, y), r)).filter(|&(c, r)| c.dist(p) > r));
            let half_rad = rough * FRAC_PI_2 + REACH_MARGIN_RAD;
            let reach = Reach {
                targets: circles.iter().map(|&(c, r)| (c, r * (1.0 + 1e-9) + REACH_MARGIN_M)).collect(),
                cones: vec![Some((half_rad.cos(), half_rad.sin()))],
            };
            prop_assume!(!reach.may_meet(0, p, dir, normal));
            for k in 0..=200 {
                let out = bounce_dir(dir, normal, rough, f64::from(k) / 200.0);
                for &(c, r) in &circles[1..] {
                    let closest = ray_distance(p, out, c);
                    prop_assert!(closest > r, "u = {} meets ({:?}, {r}) at {closest}", f64::from(k) / 200.0, c);
                }
            }
        }
    }

    /// Closest approach of the ray `p + t·u` (t ≥ 0, `u` unit) to `c`.
    fn ray_distance(p: Point, u: Point, c: Point) -> f64 {
        let w = c - p;
        (w - u * w.dot(u).max(0.0)).norm()
    }

    /// Closest approach of the ray `p + t·u` (t ≥ 0, `u` unit) to the
    /// segment `ab`: 0 where they cross, else the nearest of the segment's
    /// ends to the ray and of the ray's origin to the segment.
    fn ray_segment_distance(p: Point, u: Point, a: Point, b: Point) -> f64 {
        let e = b - a;
        let denom = u.cross(e);
        if denom != 0.0 {
            let (t, s) = ((a - p).cross(e) / denom, (a - p).cross(u) / denom);
            if t >= 0.0 && (0.0..=1.0).contains(&s) {
                return 0.0;
            }
        }
        let to_segment = chirpmap_core::geometry::point_segment_distance(p, a, b);
        to_segment.min(ray_distance(p, u, a)).min(ray_distance(p, u, b))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Every emission angle [`traced_windows`] leaves out, in scenes of
        /// random rough circles and listener walks, is one whose ray first
        /// enters a circle and whose every bounce direction (201 across the
        /// random number's range) then misses every obstacle and comes no
        /// nearer than its radius to any of the listener's capsules: a
        /// naive trace of the particle would sense nothing.
        #[test]
        fn particles_left_out_meet_nothing_after_their_bounce(
            seed in 0u64..10_000, rough in 0.0..0.9f64, x in -15.0..15.0f64, y in -5.0..20.0f64,
            heading in 0.0..360.0f64, radius in 0.2..3.0f64,
        ) {
            let mut scene = chirpmap_core::Scene { seed, ..chirpmap_core::Scene::default() };
            scene.random_obstacles.roughness = rough;
            scene.chirp.duration = 0.2;
            scene.listeners[0].start = [x, y];
            scene.listeners[0].heading_deg = heading;
            scene.listeners[0].radius = radius;
            let Ok(r) = crate::resolve(&scene) else { return Ok(()) };
            let Some(all) = windows(&r) else { return Ok(()) };
            let culls = culls(&r);
            let reach = Reach::new(&r, &culls);
            let traced = traced_windows(&r, &all, &reach);
            let inside = |phi: f64, w: &[(f64, f64)], margin: f64| {
                w.iter().any(|&(c, h)| ((phi - c + PI).rem_euclid(TAU) - PI).abs() <= h + margin)
            };
            let mut left_out = 0;
            for k in 0..5_000 {
                let phi = f64::from(k) * TAU / 5_000.0;
                if !inside(phi, &all, 0.0) || inside(phi, &traced, 1e-6) {
                    continue;
                }
                left_out += 1;
                let dir = Point::from_angle(phi);
                let (hit, i) = nearest_hit(&r.obstacles, r.source, dir, T_MIN_M).expect("a left-out ray hits");
                for u in 0..=200 {
                    let out = bounce_dir(dir, hit.normal, r.obstacles[i].roughness, f64::from(u) / 200.0);
                    for (k, o) in r.obstacles.iter().enumerate().filter(|(k, _)| *k != i) {
                        let Shape::Circle(c) = &o.shape else { continue };
                        prop_assert!(ray_distance(hit.point, out, c.center) > c.radius_m, "meets obstacle {}", k);
                    }
                    for cap in &r.listeners[0].capsules {
                        let d = ray_segment_distance(hit.point, out, cap.a, cap.b);
                        prop_assert!(d > cap.radius_m, "meets the listener");
                    }
                }
            }
            // Scenes where nothing is left out check nothing; the default
            // scene's test below shows that most scenes leave much out.
            let _ = left_out;
        }
    }

    /// The default scene measured every 1 ms: most particles of the
    /// obstacles' windows need no tracing (the point of [`traced_windows`]).
    #[test]
    fn most_of_the_default_scenes_windows_are_silent() {
        let mut scene = chirpmap_core::Scene::default();
        scene.listeners[0].sampling.period_ms = Some(1.0);
        let r = crate::resolve(&scene).unwrap();
        let all = windows(&r).unwrap();
        let culls = culls(&r);
        let traced = traced_windows(&r, &all, &Reach::new(&r, &culls));
        let width = |w: &[(f64, f64)]| w.iter().map(|&(_, h)| 2.0 * h).sum::<f64>();
        let kept = width(&traced) / width(&all);
        assert!(kept < 0.6, "{kept} of the windows traced");
    }

    #[test]
    fn convexity() {
        let p = Point::new;
        assert!(is_convex(&[p(0.0, 0.0), p(2.0, 0.0), p(2.0, 1.0), p(0.0, 1.0)]));
        assert!(is_convex(&[p(0.0, 1.0), p(2.0, 1.0), p(2.0, 0.0), p(0.0, 0.0)]));
        assert!(!is_convex(&[p(0.0, 0.0), p(2.0, 0.0), p(1.0, 0.3), p(2.0, 1.0), p(0.0, 1.0)]));
        // A pentagram (the review's): every turn the same way, twice around.
        let star = [p(0.0, -12.0), p(5.878, -28.09), p(-9.511, -16.91), p(9.511, -16.91), p(-5.878, -28.09)];
        assert!(!is_convex(&star));
    }

    #[test]
    fn tick_ranges_wrap_and_merge() {
        let mut out = Vec::new();
        // A window straddling angle 0 with 360 particles per tick.
        tick_ranges(&[(0.0, 0.05)], 0.0, 360, &mut out);
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].0, 0);
        assert_eq!(out[1].1, 359);
        tick_ranges(&[(1.0, 0.1), (1.05, 0.1)], 0.001, 360, &mut out);
        assert_eq!(out.len(), 1);
        let (a, b) = out[0];
        let slice = TAU / 360.0;
        assert!(f64::from(a) * slice < 0.9 - 0.001 && f64::from(b) * slice > 1.15 - 0.001);
        tick_ranges(&[(1.0, 4.0)], 0.0, 360, &mut out);
        assert_eq!(out, vec![(0, 359)]);
    }
}
