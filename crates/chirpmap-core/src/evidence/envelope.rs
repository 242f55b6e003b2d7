//! Compact reflectors from the envelope of consecutive ellipses.
//!
//! The ellipses of one reflector heard from neighbouring poses touch it at
//! neighbouring points, so two of them cross next to the reflector (for a
//! circle of radius r seen over an angle δ between the two touching points,
//! r·δ²/8 outside it): the discrete envelope. Crossings of unrelated ellipses
//! land anywhere. Envelope points that pile up within `point_radius_m`, from
//! enough measurements, are a compact reflector, unless carved free space
//! outweighs it ([`Ctx::free_against`]).

use super::pile::Pile;
use super::vote::on_wall;
use super::{Ctx, Surface, SurfaceKind};
use crate::ellipse::Ellipse;
use crate::geometry::Point;

#[derive(Debug, Clone)]
pub(crate) struct PointOut {
    pub surface: Surface,
    /// Echoes explained, each with its envelope point.
    pub touches: Vec<(usize, Point)>,
    /// The small circle last fitted to them (`None` when no fit converged).
    pub model: Option<SmallCircle>,
}

/// Poses after a measurement searched first for the envelope's second pose.
const ENVELOPE_NEAR_POSES: usize = 8;

/// Then from where the path reaches the baseline, on until it has travelled
/// this many baselines (a bound on the search, whatever the poses' jitter).
const ENVELOPE_MAX_TRAVEL: f64 = 20.0;

/// Gauss–Newton iterations of a small circle's fit.
const FIT_ITERATIONS: usize = 20;

/// Newton steps allowed to find a reflection point on a small circle
/// (quadratic convergence from the bisector takes 3–6 in practice).
const SPECULAR_NEWTON_STEPS: usize = 30;

/// Samples per ellipse when looking for crossings.
const CROSSING_SAMPLES: usize = 96;

/// Crossings of two ellipses: sign changes of `b`'s focal excess along `a`,
/// refined by bisection in eccentric anomaly.
pub(crate) fn crossings(a: &Ellipse, b: &Ellipse, out: &mut Vec<Point>) {
    let samples = sample_angles();
    let g = |u: f64| inside(b, a.point_at(u));
    let mut g0 = inside(b, point_at_sc(a, samples[0]));
    for (s, &sc) in samples.iter().enumerate().skip(1) {
        let u1 = s as f64 * STEP;
        let g1 = inside(b, point_at_sc(a, sc));
        if g0 != g1 {
            let (mut lo, mut hi) = ((s - 1) as f64 * STEP, u1);
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if g(mid) == g0 {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            out.push(a.point_at(0.5 * (lo + hi)));
        }
        g0 = g1;
    }
}

/// Sample spacing in eccentric anomaly (rad).
const STEP: f64 = std::f64::consts::TAU / CROSSING_SAMPLES as f64;

/// `(sin u, cos u)` of the sample angles `u = s·STEP`, `s = 0..=CROSSING_SAMPLES`,
/// computed once (the same values `f64::sin_cos` gives at each call).
fn sample_angles() -> &'static [(f64, f64); CROSSING_SAMPLES + 1] {
    static TABLE: std::sync::OnceLock<[(f64, f64); CROSSING_SAMPLES + 1]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|s| (s as f64 * STEP).sin_cos()))
}

/// [`Ellipse::point_at`] from `(sin u, cos u)`: the same arithmetic.
#[inline]
fn point_at_sc(e: &Ellipse, (su, cu): (f64, f64)) -> Point {
    let (x, y) = (e.semi_major_m * cu, e.semi_minor_m * su);
    Point::new(e.center.x + x * e.cos_t - y * e.sin_t, e.center.y + x * e.sin_t + y * e.cos_t)
}

/// Whether `p` is strictly inside `b` (`b.focal_excess(p) < 0`, the same
/// answer bit for bit): distances by `sqrt` of the squared norm, within a
/// few ulps of `hypot`'s, so the sign is certain unless the excess is within
/// 10⁻¹² of the path length; only then (or on overflow) is it computed as
/// [`Ellipse::focal_excess`] does, with `hypot`.
#[inline]
fn inside(b: &Ellipse, p: Point) -> bool {
    let (ax, ay) = (p.x - b.focus_a.x, p.y - b.focus_a.y);
    let (bx, by) = (p.x - b.focus_b.x, p.y - b.focus_b.y);
    let (da, db) = ((ax * ax + ay * ay).sqrt(), (bx * bx + by * by).sqrt());
    let major = 2.0 * b.semi_major_m;
    let g = da + db - major;
    if g.abs() > 1e-12 * (da + db + major) { g < 0.0 } else { b.focal_excess(p) < 0.0 }
}

/// One envelope point and the two echoes whose ellipses cross there.
#[derive(Debug, Clone, Copy)]
struct EnvPoint {
    p: Point,
    a: usize,
    b: usize,
}

pub(crate) fn find_points(ctx: &Ctx, skip: &[bool], walls: &[super::vote::Wall], max_points: usize) -> Vec<PointOut> {
    let p = ctx.params;
    let (trusted, reach) = super::vote::trusted_reach(walls);
    let moved = |a: &super::Meas, b: &super::Meas| a.listener.dist(b.listener) + a.source.dist(b.source);
    // Path travelled (listener and source) up to each measurement, from its
    // listener's first, and where each listener's measurements end.
    let mut travelled = vec![0.0f64; ctx.meas.len()];
    let mut run_end = vec![ctx.meas.len(); ctx.meas.len()];
    for i in 1..ctx.meas.len() {
        if ctx.meas[i].listener_id == ctx.meas[i - 1].listener_id {
            travelled[i] = travelled[i - 1] + moved(&ctx.meas[i], &ctx.meas[i - 1]);
        }
    }
    for i in (0..ctx.meas.len().saturating_sub(1)).rev() {
        if ctx.meas[i].listener_id == ctx.meas[i + 1].listener_id {
            run_end[i] = run_end[i + 1];
        } else {
            run_end[i] = i + 1;
        }
    }
    // Each measurement's crossings with its partner's, on rayon's threads,
    // joined in measurement order: the same points in the same order
    // whatever the thread count.
    let pair = |buf: &mut Vec<Point>, mi: usize, m: &super::Meas| -> Vec<EnvPoint> {
        let mut env = Vec::new();
        // The next pose of the same listener at least the baseline away:
        // within a few poses, else the first few from where the path
        // travelled reaches the baseline (a straight line is no longer than
        // the path). Poses closer together than a baseline over eight (a
        // walk sampled every millimetre: `map --wav` at 1 ms) found none
        // within eight, and a pillar gave no crossings at all (the review of
        // session 22: 4 000 poses 3 mm apart, σ = 1 cm, no surface).
        let far_enough = |n: &&super::Meas| moved(n, m) >= p.envelope_baseline_m;
        let near = ctx.meas[mi + 1..run_end[mi]].iter().take(ENVELOPE_NEAR_POSES).find(far_enough);
        let next = near.or_else(|| {
            let ahead = &travelled[mi + 1..run_end[mi]];
            let from = mi + 1 + ahead.partition_point(|&t| t - travelled[mi] < p.envelope_baseline_m);
            // On until the path has travelled ENVELOPE_MAX_TRAVEL baselines:
            // with jittery poses (a tracker's, 3 mm) the path runs well ahead
            // of the straight distance, and the eight poses there were all
            // within 1–2 cm (the second review of session 22).
            let reach = travelled[mi] + ENVELOPE_MAX_TRAVEL * p.envelope_baseline_m;
            ctx.meas[from..run_end[mi]]
                .iter()
                .zip(&travelled[from..run_end[mi]])
                .take_while(|&(_, &t)| t <= reach)
                .map(|(n, _)| n)
                .find(far_enough)
        });
        let Some(next) = next else {
            return env;
        };
        let moved = 2.0 * (next.listener.dist(m.listener) + next.source.dist(m.source));
        for &ka in &m.echoes {
            if skip[ka] {
                continue;
            }
            let ea = &ctx.preps[ka];
            for &kb in &next.echoes {
                if skip[kb] {
                    continue;
                }
                let eb = &ctx.preps[kb];
                let slack = moved + p.band_sigmas * (ea.sigma_m + eb.sigma_m);
                if (ea.ellipse.delta_d_m - eb.ellipse.delta_d_m).abs() > slack {
                    continue;
                }
                buf.clear();
                crossings(&ea.ellipse, &eb.ellipse, buf);
                for &q in buf.iter() {
                    if ctx.spec.cell_of(q).is_some() {
                        env.push(EnvPoint { p: q, a: ka, b: kb });
                    }
                }
            }
        }
        env
    };
    let env: Vec<EnvPoint> = {
        use rayon::prelude::*;
        let parts: Vec<Vec<EnvPoint>> =
            ctx.meas.par_iter().enumerate().map_init(Vec::new, |buf, (mi, m)| pair(buf, mi, m)).collect();
        parts.concat()
    };
    if env.is_empty() {
        return Vec::new();
    }
    // Density: envelope points within the cluster radius ([`Pile`]), on
    // rayon's threads (the same counts whatever their number).
    let pts: Vec<Point> = env.iter().map(|e| e.p).collect();
    let pile = Pile::new(&pts, p.point_radius_m);
    let density: Vec<usize> = {
        use rayon::prelude::*;
        (0..env.len()).into_par_iter().map(|i| pile.count_within(i)).collect()
    };
    let mut order: Vec<usize> = (0..env.len()).collect();
    order.sort_by(|&a, &b| density[b].cmp(&density[a]).then(a.cmp(&b)));
    let mut taken = vec![false; env.len()];
    let mut echo_used = vec![false; ctx.preps.len()];
    let mut in_touches = vec![false; ctx.preps.len()];
    let mut out = Vec::new();
    for seed in order {
        if out.len() >= max_points || density[seed] < p.min_support as usize {
            break;
        }
        if taken[seed] {
            continue;
        }
        let members: Vec<usize> = pile.within(seed).into_iter().filter(|&j| !taken[j]).collect();
        // Support: distinct measurements among the members' echoes.
        let mut touches: Vec<(usize, Point)> = Vec::new();
        let mut meas_seen = std::collections::BTreeSet::new();
        for &j in &members {
            for k in [env[j].a, env[j].b] {
                // (A flag per echo: a search of the touches made a pile of n
                // crossings cost n², 8 s for 35 000 echoes 1 mm apart.)
                if !echo_used[k] && !in_touches[k] {
                    in_touches[k] = true;
                    touches.push((k, env[j].p));
                    meas_seen.insert(ctx.preps[k].meas);
                }
            }
        }
        for &(k, _) in &touches {
            in_touches[k] = false;
        }
        for &j in &members {
            taken[j] = true;
        }
        if meas_seen.len() < p.min_support as usize {
            continue;
        }
        let at = env[seed].p;
        // Every other free echo the reflector explains: without this, the
        // second crossings of its ellipses (on the far side of the foci) pile
        // up on a ghost curve and take the echoes its cluster radius missed.
        let model = explain_more(ctx, skip, &echo_used, at, &mut touches, &mut meas_seen);
        // In free space against what it explains (Ctx::free_against): its
        // echoes stay for the reflectors found after it.
        // (Tested where it is reported: with noise the seed crossing may lie
        // 0.2–0.3 m off a pole, in space truly carved free.)
        let at = model.map_or(at, |m| m.point_toward(at));
        if ctx.free_against(at, meas_seen.len()) {
            continue;
        }
        // On a found wall that is not ambiguous and explains ten times its
        // echoes: that wall's own echoes its runs missed, whose consecutive
        // ellipses cross next to it. Once poses closer than a baseline over
        // eight were paired, a walk in a room with clutter gave such a point
        // (16 echoes, 6 cm from a wall of 2 000; test
        // `room_walls_in_clutter_and_nothing_else`). Any point on a wall, as
        // the vote refuses it, would take the points on the loop past circles
        // whose short lines hug the circles (test `loop_past_three_circles`).
        let leftover = trusted
            .iter()
            .zip(&reach)
            .any(|(w, r)| w.support >= 10 * meas_seen.len() && on_wall(std::slice::from_ref(r), at, p.point_radius_m));
        if leftover {
            continue;
        }
        // Behind a found wall (beyond the cluster radius from its line, on
        // the far side for most of its echoes' paths): the image of a
        // higher-order reflection, as for lines and the vote's points. A walk
        // in a room with its second reflections (`synth`'s
        // `reflection_order = 2`, examples/room-walk) gave 58 points outside
        // the room and one inside it 0.4 m from a wall without this (now 9
        // small ones outside, none inside). A point within the radius of a
        // line is left alone: on the loop past circles short lines hug the
        // circles, and their points would go.
        let behind: Vec<(Point, Point)> =
            walls.iter().filter(|w| ((at - w.at).dot(w.normal)).abs() > p.point_radius_m).map(|w| w.extent).collect();
        let ks: Vec<usize> = touches.iter().map(|&(k, _)| k).collect();
        if super::vote::hidden(ctx, &ks, at, &behind) {
            continue;
        }
        for &(k, _) in &touches {
            echo_used[k] = true;
        }
        out.push(PointOut {
            surface: Surface {
                kind: SurfaceKind::Point,
                p0: at,
                p1: at,
                support: meas_seen.len(),
                ambiguous: point_ambiguous(ctx, &ks, at),
            },
            touches,
            model,
        });
    }
    out
}

/// A compact reflector as a small circle: centre `c`, radius `rho_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SmallCircle {
    /// Centre (m, world frame).
    pub c: Point,
    /// Radius (m), within `[0, point_radius_m]`.
    pub rho_m: f64,
}

impl SmallCircle {
    /// Predicted Δd of an echo with foci `s` and `l`: the specular path off
    /// the circle, `|s − q| + |q − l|` at the reflection point `q`
    /// ([`Self::specular_dir`]), minus `|s − l|`; with the path's gradient
    /// in (cx, cy, ρ). At the reflection point the path is stationary in
    /// `q`'s angle, so the gradient is that of the two legs with `q` held:
    /// `â + b̂` in the centre and `u·(â + b̂)` in the radius (`â`, `b̂` unit
    /// vectors from `s` and `l` to `q`, `u` the outward normal at `q`).
    ///
    /// The first-order formula used before, `|s − c| + |c − l| − 2ρ·cos(β/2)`,
    /// is off by up to 4.7 cm for a 0.3 m pillar passed at 0.85 m (the
    /// listener's loop of `map --wav` on a synthesized room, session 22):
    /// more than the band of echoes ranged to a centimetre, so one pillar
    /// came out as many points. When a focus lies inside the circle, the
    /// circle blocks the direct path, or the iteration fails, that formula
    /// stands in (never below 0).
    pub(crate) fn predict(&self, s: Point, l: Point) -> Option<(f64, [f64; 3])> {
        let (ds, dl) = (s - self.c, l - self.c);
        let (ns, nl) = (ds.dot(ds).sqrt(), dl.dot(dl).sqrt());
        if !(ns > 1e-9 && nl > 1e-9) {
            return None;
        }
        if let Some(u) = self.specular_dir(s, l) {
            let q = self.c + u * self.rho_m;
            let (a, b) = (q - s, q - l);
            let (na, nb) = (a.dot(a).sqrt(), b.dot(b).sqrt());
            let sum = a * (1.0 / na) + b * (1.0 / nb);
            return Some((na + nb - s.dist(l), [sum.x, sum.y, u.dot(sum)]));
        }
        let cos_beta = (ds.dot(dl) / (ns * nl)).clamp(-1.0, 1.0);
        let half = (0.5 * (1.0 + cos_beta)).sqrt();
        let path = ns + nl - 2.0 * self.rho_m * half;
        let grad = [-(ds.x / ns + dl.x / nl), -(ds.y / ns + dl.y / nl), -2.0 * half];
        // (A path the circle blocks is no reflection: the least ellipse
        // touching the circle is the direct segment, Δd = 0.)
        Some(((path - s.dist(l)).max(0.0), grad))
    }

    /// The direction (a unit vector from the centre) of the reflection point
    /// for foci `s` and `l`: where `|s − q| + |q − l|` is least along the
    /// near side (Fermat), by Newton's method on that length's derivative
    /// along the circle, started on the bisector of the directions to the
    /// foci (the exact point when ρ = 0, and within O(ρ/distance) of it
    /// otherwise). Each step turns the direction by the Newton step's angle
    /// `δ` as `u + δ·u⊥`, normalised (tan δ instead of δ: the same zero, and no
    /// sine or cosine per step). `None` with a focus inside the circle or the
    /// direct path through it (no reflection), foci in opposite directions
    /// (no bisector), or no convergence in [`SPECULAR_NEWTON_STEPS`].
    pub(crate) fn specular_dir(&self, s: Point, l: Point) -> Option<Point> {
        let (ds, dl) = (s - self.c, l - self.c);
        let (ns, nl) = (ds.dot(ds).sqrt(), dl.dot(dl).sqrt());
        let r = self.rho_m;
        if !(ns > r && nl > r) || crate::geometry::point_segment_distance(self.c, s, l) <= r {
            return None;
        }
        let bisector = ds * (1.0 / ns) + dl * (1.0 / nl);
        let len = bisector.dot(bisector).sqrt();
        if len <= 1e-9 || len.is_nan() {
            return None;
        }
        let mut u = bisector * (1.0 / len);
        if r == 0.0 {
            return Some(u);
        }
        for _ in 0..SPECULAR_NEWTON_STEPS {
            let perp = Point::new(-u.y, u.x);
            let t = perp * r;
            let q = self.c + u * r;
            let (a, b) = (q - s, q - l);
            let (na, nb) = (a.dot(a).sqrt(), b.dot(b).sqrt());
            let (ua, ub) = (a * (1.0 / na), b * (1.0 / nb));
            let d1 = t.dot(ua + ub);
            let d2 = -r * u.dot(ua + ub) + (r * r - ua.dot(t).powi(2)) / na + (r * r - ub.dot(t).powi(2)) / nb;
            if d2 <= 0.0 || d2.is_nan() {
                return None;
            }
            // Backtracking: with a focus within a few centimetres of the
            // circle the path has a sharp bend there, and plain Newton
            // jumped between two directions until it gave up (the review of
            // session 22); a step is halved while it lengthens the path.
            let mut step = (d1 / d2).clamp(-0.5, 0.5);
            let here = na + nb;
            let mut next = u;
            for _ in 0..SPECULAR_NEWTON_STEPS {
                let turned = u - perp * step;
                next = turned * (1.0 / turned.dot(turned).sqrt());
                let q = self.c + next * r;
                let (a, b) = (q - s, q - l);
                if a.dot(a).sqrt() + b.dot(b).sqrt() <= here * (1.0 + 1e-15) {
                    break;
                }
                step *= 0.5;
            }
            u = next;
            if step.abs() < 1e-12 {
                return Some(u);
            }
        }
        None
    }

    /// The circle's point nearest `p` (its centre when `p` is the centre):
    /// where a compact reflector is reported. The densest crossing that
    /// seeded it lies off the surface by the crossings' scatter, which noise
    /// makes large (consecutive ellipses cross at 0.1–2°), while the fitted
    /// circle is pinned by every echo it explains.
    pub(crate) fn point_toward(&self, p: Point) -> Point {
        let d = p - self.c;
        let n = d.norm();
        if n > 0.0 { self.c + d * (self.rho_m / n) } else { self.c }
    }

    /// The reflection point of an echo with foci `s` and `l` on the circle
    /// ([`Self::specular_dir`]; the bisector's direction where that has
    /// none).
    pub(crate) fn specular_point(&self, s: Point, l: Point) -> Point {
        if let Some(u) = self.specular_dir(s, l) {
            return self.c + u * self.rho_m;
        }
        let (ds, dl) = (s - self.c, l - self.c);
        let (ns, nl) = (ds.norm(), dl.norm());
        let bisector = if ns > 0.0 && nl > 0.0 { ds * (1.0 / ns) + dl * (1.0 / nl) } else { Point::new(0.0, 0.0) };
        let len = bisector.norm();
        if len > 1e-12 { self.c + bisector * (self.rho_m / len) } else { self.c }
    }

    /// Gauss–Newton fit of centre and radius to the echoes `ks`, from the
    /// circle `from`; the radius is kept within `[0, max_rho_m]`.
    /// Returns the last model (`None` on a singular system, or where an
    /// echo's path cannot be predicted) and whether it is one: converged, finite, and its centre within 2·`max_rho_m` of `start`
    /// (the cluster lies next to the reflector's surface; along a straight
    /// pass the centre's distance and the radius trade against each other
    /// and an undamped step can run off).
    fn gauss_newton(ctx: &Ctx, ks: &[usize], start: Point, from: Self, max_rho_m: f64) -> Option<(Self, bool)> {
        let mut model = from;
        let mut converged = false;
        for _ in 0..FIT_ITERATIONS {
            let (mut a, mut g) = ([[0.0f64; 3]; 3], [0.0f64; 3]);
            for &k in ks {
                let e = &ctx.preps[k].ellipse;
                let (pred, j) = model.predict(e.focus_a, e.focus_b)?;
                let r = e.delta_d_m - pred;
                for (u, ju) in j.iter().enumerate() {
                    g[u] += ju * r;
                    for (v, jv) in j.iter().enumerate() {
                        a[u][v] += ju * jv;
                    }
                }
            }
            let step = solve3(a, g)?;
            model.c = Point::new(model.c.x + step[0], model.c.y + step[1]);
            let rho_before = model.rho_m;
            model.rho_m = (model.rho_m + step[2]).clamp(0.0, max_rho_m);
            // Convergence by the radius's change as clamped: at a bound the
            // step keeps asking past it (a pillar as wide as the bound, fitted
            // to noisy echoes, never converged, and came out as many points).
            if step[0].hypot(step[1]) < 1e-6 && (model.rho_m - rho_before).abs() < 1e-6 {
                converged = true;
                break;
            }
        }
        let finite = model.c.x.is_finite() && model.c.y.is_finite() && model.rho_m.is_finite();
        Some((model, converged && finite && model.c.dist(start) <= 2.0 * max_rho_m))
    }

    /// [`Self::gauss_newton`] from a point reflector at `start`, with
    /// outliers trimmed: while any echo lies more than kσ off the fit, the
    /// worst of them go, an eighth of the echoes kept (at least one, at most
    /// those off), and the circle is refitted from the last one, keeping at least half the echoes and
    /// `min_support`. A fit that does not converge is refused at once:
    /// that is the echoes' geometry (a short arc, a circle wider than
    /// `max_rho_m`), which trimming does not mend. The envelope's clusters hold
    /// the crossings of every ellipse near the reflector, and echoes ranged
    /// from a recording stray by tens of σ now and then (a synthesized walk
    /// round a pillar, 13 % of them off by 5–76 cm, session 22). Before, a
    /// fit whose RMS residual exceeded kσ was refused whole, with no way to
    /// drop such an echo and keep the reflector. `None` when no fit remains;
    /// else the circle and the echoes it explains, in `ks`'s order.
    fn fit(ctx: &Ctx, ks: &[usize], start: Point, max_rho_m: f64) -> Option<(Self, Vec<usize>)> {
        let p = ctx.params;
        let min_keep = ks.len().div_ceil(2).max(p.min_support as usize);
        let mut keep = ks.to_vec();
        let mut from = Self { c: start, rho_m: 0.0 };
        while keep.len() >= min_keep {
            let (model, ok) = Self::gauss_newton(ctx, &keep, start, from, max_rho_m)?;
            if !ok {
                return None;
            }
            from = model;
            let mut z: Vec<(f64, usize)> = Vec::with_capacity(keep.len());
            for (i, &k) in keep.iter().enumerate() {
                let prep = &ctx.preps[k];
                let e = &prep.ellipse;
                let miss = model.predict(e.focus_a, e.focus_b).map_or(f64::INFINITY, |(pred, _)| e.delta_d_m - pred);
                // (A NaN counts as off.)
                let zi = miss.abs() / prep.sigma_m;
                z.push((if zi.is_nan() { f64::INFINITY } else { zi }, i));
            }
            let outliers = z.iter().filter(|(zi, _)| *zi > p.band_sigmas).count();
            if outliers == 0 {
                return Some((model, keep));
            }
            keep = super::without_worst(&keep, &mut z, (keep.len() / 8).max(1).min(outliers));
        }
        None
    }
}

/// Adds to `touches` echoes neither skipped nor used, of measurements not
/// yet touched, whose Δd a [`SmallCircle`] fitted to the touched echoes
/// predicts within kσ (one per measurement, the nearest: a measurement hears
/// one reflection of one reflector), each at its reflection point on the
/// circle, in two rounds (fit, extend, refit, extend); records their
/// measurements. Returns the last circle fitted.
pub(crate) fn explain_more(
    ctx: &Ctx,
    skip: &[bool],
    echo_used: &[bool],
    at: Point,
    touches: &mut Vec<(usize, Point)>,
    meas_seen: &mut std::collections::BTreeSet<usize>,
) -> Option<SmallCircle> {
    let p = ctx.params;
    let mut last = None;
    for _ in 0..2 {
        let ks: Vec<usize> = touches.iter().map(|&(k, _)| k).collect();
        let Some((model, kept)) = SmallCircle::fit(ctx, &ks, at, p.point_radius_m) else { return last };
        if kept.len() < ks.len() {
            // The echoes trimmed off are not this reflector's.
            let mut is_kept = vec![false; ctx.preps.len()];
            for &k in &kept {
                is_kept[k] = true;
            }
            touches.retain(|&(k, _)| is_kept[k]);
            meas_seen.clear();
            meas_seen.extend(touches.iter().map(|&(k, _)| ctx.preps[k].meas));
        }
        last = Some(model);
        // The nearest explained echo of each measurement not yet touched.
        let mut best: Vec<Option<(usize, f64)>> = vec![None; ctx.meas.len()];
        for (k, prep) in ctx.preps.iter().enumerate() {
            if skip[k] || echo_used[k] || meas_seen.contains(&prep.meas) {
                continue;
            }
            let e = &prep.ellipse;
            let Some((pred, _)) = model.predict(e.focus_a, e.focus_b) else { continue };
            let miss = (e.delta_d_m - pred).abs() / prep.sigma_m;
            if miss <= p.band_sigmas && best[prep.meas].is_none_or(|(_, m)| miss < m) {
                best[prep.meas] = Some((k, miss));
            }
        }
        for (meas, &(k, _)) in best.iter().enumerate().filter_map(|(m, b)| b.as_ref().map(|b| (m, b))) {
            let e = &ctx.preps[k].ellipse;
            touches.push((k, model.specular_point(e.focus_a, e.focus_b)));
            meas_seen.insert(meas);
        }
    }
    last
}

/// [`super::lines::solve3`] of the normal equations `a·x = b`, refused also
/// when `a` is near-singular relative to its own scale (or NaN): the
/// equations are weighted by 1/σ², so an absolute threshold alone means
/// nothing here.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    let d = super::lines::det3(a);
    if d.abs().partial_cmp(&(1e-12 * scale.powi(3))) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    super::lines::solve3(a, b)
}

/// Whether a point reflector at `at` is mirror-ambiguous for its echoes
/// `ks`: their moving foci lie on one line ([`Ctx::collinear`]) and the
/// point's mirror image across that line predicts every echo's Δd as well
/// (within kσ). Unlike a wall's twin, a point's mirror keeps the moving
/// focus's distances but not the fixed one's, so a walk past a pole is
/// ambiguous only when the fixed focus is on the walk's line (or as far from
/// both images).
pub(crate) fn point_ambiguous(ctx: &Ctx, ks: &[usize], at: Point) -> bool {
    if !ctx.collinear(ks) {
        return false;
    }
    let moving = ctx.moving_foci(ks);
    // With the moving foci in one place (within the tolerance) there is no
    // line to mirror across: as `collinear` says, ambiguous.
    if super::foci_spread(&moving) <= ctx.params.collinear_tol_m {
        return true;
    }
    let Some(axis) = super::principal_axis(&moving) else { return true };
    let mirror = super::reflect_across(at, axis);
    let path = |p: Point, e: &Ellipse| e.focus_a.dist(p) + p.dist(e.focus_b);
    ks.iter().all(|&k| {
        let prep = &ctx.preps[k];
        (path(at, &prep.ellipse) - path(mirror, &prep.ellipse)).abs() <= ctx.params.band_sigmas * prep.sigma_m
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Circle, point_segment_distance, specular_point_on_circle};
    use proptest::prelude::*;

    proptest! {
        /// The reflection point and path of a small circle against the
        /// geometry module's search (a 720-step scan of the circle, then
        /// bisection on the path's slope), foci from 0.1 mm outside the circle
        /// (half the cases within 2 cm, where plain Newton failed) to 30 m;
        /// and the path's gradient against central differences.
        #[test]
        fn specular_path_is_the_searched_shortest_path(
            cx in -5.0..5.0f64,
            cy in -5.0..5.0f64,
            r in 0.01..0.5f64,
            ang_s in 0.0..std::f64::consts::TAU,
            gap_s in prop_oneof![1e-4..0.02f64, 0.02..30.0f64],
            ang_l in 0.0..std::f64::consts::TAU,
            gap_l in prop_oneof![1e-4..0.02f64, 0.02..30.0f64],
        ) {
            let c = Point::new(cx, cy);
            let s = c + Point::from_angle(ang_s) * (r + gap_s);
            let l = c + Point::from_angle(ang_l) * (r + gap_l);
            let circle = Circle::new(c, r).expect("circle");
            // (None: the direct path is blocked, no reflection.)
            let Some(want) = specular_point_on_circle(s, l, &circle) else { return Ok(()) };
            let model = SmallCircle { c, rho_m: r };
            let (dd, grad) = model.predict(s, l).expect("prediction");
            let path = want.dist(s) + want.dist(l) - s.dist(l);
            prop_assert!((dd - path).abs() < 1e-8, "Δd {dd} against {path}");
            // Where the direct path grazes the circle, the path length is flat
            // along it over millimetres (Δd ≈ 0): only Δd is fixed there.
            if point_segment_distance(c, s, l) - r < 1e-3 {
                return Ok(());
            }
            let got = model.specular_point(s, l);
            prop_assert!(got.dist(want) < 1e-7, "point {got:?} against {want:?}");
            let h = 1e-6;
            let at = |m: SmallCircle| m.predict(s, l).expect("prediction").0;
            let numeric = [
                (at(SmallCircle { c: c + Point::new(h, 0.0), rho_m: r }) - at(SmallCircle { c: c - Point::new(h, 0.0), rho_m: r })) / (2.0 * h),
                (at(SmallCircle { c: c + Point::new(0.0, h), rho_m: r }) - at(SmallCircle { c: c - Point::new(0.0, h), rho_m: r })) / (2.0 * h),
                (at(SmallCircle { c, rho_m: r + h }) - at(SmallCircle { c, rho_m: r - h })) / (2.0 * h),
            ];
            for (g, n) in grad.iter().zip(numeric) {
                prop_assert!((g - n).abs() < 1e-5, "gradient {grad:?} against {numeric:?}");
            }
        }
    }
}
