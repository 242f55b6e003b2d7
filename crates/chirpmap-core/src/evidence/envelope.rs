//! Compact reflectors from the envelope of consecutive ellipses.
//!
//! The ellipses of one reflector heard from neighbouring poses touch it at
//! neighbouring points, so two of them cross next to the reflector (for a
//! circle of radius r seen over an angle δ between the two touching points,
//! r·δ²/8 outside it): the discrete envelope. Crossings of unrelated ellipses
//! land anywhere, and crossings in carved free space are dropped. Envelope
//! points that pile up within `point_radius_m`, from enough measurements,
//! are a compact reflector.

use super::{Ctx, Surface, SurfaceKind};
use crate::ellipse::Ellipse;
use crate::geometry::Point;
use std::collections::HashMap;

#[derive(Debug, Clone)]
pub(crate) struct PointOut {
    pub surface: Surface,
    /// Echoes explained, each with its envelope point.
    pub touches: Vec<(usize, Point)>,
    /// The small circle last fitted to them (`None` when no fit converged).
    pub model: Option<SmallCircle>,
}

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

pub(crate) fn find_points(ctx: &Ctx, skip: &[bool], max_points: usize) -> Vec<PointOut> {
    let p = ctx.params;
    let mut env: Vec<EnvPoint> = Vec::new();
    let mut buf = Vec::new();
    for (mi, m) in ctx.meas.iter().enumerate() {
        // The next pose of the same listener at least the baseline away
        // (within a few poses).
        let Some(next) = ctx.meas[mi + 1..]
            .iter()
            .take(8)
            .take_while(|n| n.listener_id == m.listener_id)
            .find(|n| n.listener.dist(m.listener) + n.source.dist(m.source) >= p.envelope_baseline_m)
        else {
            continue;
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
                crossings(&ea.ellipse, &eb.ellipse, &mut buf);
                for &q in &buf {
                    if ctx.spec.cell_of(q).is_some() && !ctx.is_free(q) {
                        env.push(EnvPoint { p: q, a: ka, b: kb });
                    }
                }
            }
        }
    }
    if env.is_empty() {
        return Vec::new();
    }
    // Density: envelope points within the cluster radius (spatial hash).
    let r = p.point_radius_m;
    let key = |q: Point| ((q.x / r).floor() as i64, (q.y / r).floor() as i64);
    let mut hash: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (i, e) in env.iter().enumerate() {
        hash.entry(key(e.p)).or_default().push(i);
    }
    let neighbours = |i: usize| -> Vec<usize> {
        let (kx, ky) = key(env[i].p);
        let mut v = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                if let Some(list) = hash.get(&(kx + dx, ky + dy)) {
                    v.extend(list.iter().copied().filter(|&j| env[j].p.dist(env[i].p) <= r));
                }
            }
        }
        v
    };
    let density: Vec<usize> = (0..env.len()).map(|i| neighbours(i).len()).collect();
    let mut order: Vec<usize> = (0..env.len()).collect();
    order.sort_by(|&a, &b| density[b].cmp(&density[a]).then(a.cmp(&b)));
    let mut taken = vec![false; env.len()];
    let mut echo_used = vec![false; ctx.preps.len()];
    let mut out = Vec::new();
    for seed in order {
        if out.len() >= max_points || density[seed] < p.min_support as usize {
            break;
        }
        if taken[seed] {
            continue;
        }
        let members: Vec<usize> = neighbours(seed).into_iter().filter(|&j| !taken[j]).collect();
        // Support: distinct measurements among the members' echoes.
        let mut touches: Vec<(usize, Point)> = Vec::new();
        let mut meas_seen = std::collections::BTreeSet::new();
        for &j in &members {
            for k in [env[j].a, env[j].b] {
                if !echo_used[k] && !touches.iter().any(|&(t, _)| t == k) {
                    touches.push((k, env[j].p));
                    meas_seen.insert(ctx.preps[k].meas);
                }
            }
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
        for &(k, _) in &touches {
            echo_used[k] = true;
        }
        let ks: Vec<usize> = touches.iter().map(|&(k, _)| k).collect();
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
    /// the circle, `|s − c| + |c − l| − 2ρ·cos(β/2)` with β the angle s–c–l
    /// (exact to first order in ρ over the distances), minus `|s − l|`.
    /// Also returns the path's gradient in (cx, cy, ρ), the ρ term's
    /// dependence on `c` left out (second order).
    pub(crate) fn predict(&self, s: Point, l: Point) -> Option<(f64, [f64; 3])> {
        let (ds, dl) = (s - self.c, l - self.c);
        let (ns, nl) = (ds.norm(), dl.norm());
        if !(ns > 1e-9 && nl > 1e-9) {
            return None;
        }
        let cos_beta = (ds.dot(dl) / (ns * nl)).clamp(-1.0, 1.0);
        let half = (0.5 * (1.0 + cos_beta)).sqrt();
        let path = ns + nl - 2.0 * self.rho_m * half;
        let grad = [-(ds.x / ns + dl.x / nl), -(ds.y / ns + dl.y / nl), -2.0 * half];
        Some((path - s.dist(l), grad))
    }

    /// The reflection point of an echo with foci `s` and `l`: on the circle,
    /// along the bisector of the directions to them.
    pub(crate) fn specular_point(&self, s: Point, l: Point) -> Point {
        let (ds, dl) = (s - self.c, l - self.c);
        let (ns, nl) = (ds.norm(), dl.norm());
        let bisector = if ns > 0.0 && nl > 0.0 { ds * (1.0 / ns) + dl * (1.0 / nl) } else { Point::new(0.0, 0.0) };
        let len = bisector.norm();
        if len > 1e-12 { self.c + bisector * (self.rho_m / len) } else { self.c }
    }

    /// Gauss–Newton fit of centre and radius to the echoes `ks`, from a
    /// point reflector at `start`; the radius is kept within `[0, max_rho_m]`.
    /// `None` when the echoes do not fix the three unknowns: a singular
    /// system, no convergence in the iterations, a centre more than
    /// 2·`max_rho_m` from `start` (the cluster lies next to the reflector's
    /// surface; along a straight pass the centre's distance and the radius
    /// trade against each other and an undamped step can run off), or an RMS
    /// residual above `band_sigmas` σ.
    fn fit(ctx: &Ctx, ks: &[usize], start: Point, max_rho_m: f64) -> Option<Self> {
        let mut model = Self { c: start, rho_m: 0.0 };
        let mut converged = false;
        for _ in 0..8 {
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
            model.rho_m = (model.rho_m + step[2]).clamp(0.0, max_rho_m);
            if step[0].hypot(step[1]) < 1e-6 && step[2].abs() < 1e-6 {
                converged = true;
                break;
            }
        }
        let finite = model.c.x.is_finite() && model.c.y.is_finite() && model.rho_m.is_finite();
        // (No echoes: the system was singular, so `ks` is not empty here.)
        if !(converged && finite && model.c.dist(start) <= 2.0 * max_rho_m) {
            return None;
        }
        let mut sse = 0.0;
        for &k in ks {
            let p = &ctx.preps[k];
            sse += ((p.ellipse.delta_d_m - model.predict(p.ellipse.focus_a, p.ellipse.focus_b)?.0) / p.sigma_m).powi(2);
        }
        ((sse / ks.len() as f64).sqrt() <= ctx.params.band_sigmas).then_some(model)
    }
}

/// Adds to `touches` echoes neither skipped nor used, of measurements not
/// yet touched, whose Δd a [`SmallCircle`] fitted to the touched echoes
/// predicts within kσ (one per measurement, the nearest: a measurement hears
/// one reflection of one reflector), each at its reflection point on the
/// circle, in two rounds (fit, extend, refit, extend); records their
/// measurements. Returns the last circle fitted.
fn explain_more(
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
        let Some(model) = SmallCircle::fit(ctx, &ks, at, p.point_radius_m) else { return last };
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
