//! Walls as common tangents: Hough vote in (normal angle θ, offset ρ) with the
//! closed-form far tangents of each ellipse, least-squares refinement, ghost
//! rejection and a greedy one-surface-per-echo assignment.

use super::tangent::{far_offset, far_tangent};
use super::{Ctx, Surface, SurfaceKind};
use crate::geometry::Point;
use std::f64::consts::TAU;

/// An accepted wall: the surface and, per explained echo, its tangency point.
#[derive(Debug, Clone)]
pub(crate) struct LineOut {
    pub surface: Surface,
    pub touches: Vec<(usize, Point)>,
}

#[derive(Debug, Clone, Default)]
pub(crate) struct LinesResult {
    pub accepted: Vec<LineOut>,
    /// Echoes of rejected ghost lines (higher-order reflections): they are
    /// neither rings nor envelope evidence.
    pub ghost_echoes: Vec<usize>,
}

/// A refined line candidate.
#[derive(Debug, Clone)]
struct Cand {
    theta: f64,
    rho: f64,
    /// Echoes tangent to the line, one per measurement, inside runs of
    /// consecutive poses, with their tangency points.
    touches: Vec<(usize, Point)>,
    p0: Point,
    p1: Point,
}

impl Cand {
    fn normal(&self) -> Point {
        Point::from_angle(self.theta)
    }
    fn support(&self) -> usize {
        self.touches.len()
    }
    fn length(&self) -> f64 {
        self.p0.dist(self.p1)
    }
}

fn origin_of(ctx: &Ctx) -> Point {
    let s = &ctx.spec;
    Point::new(0.5 * (s.x_min_m + s.x_max_m()), 0.5 * (s.y_min_m + s.y_max_m()))
}

fn tau(ctx: &Ctx, k: usize) -> f64 {
    ctx.params.band_sigmas * ctx.preps[k].sigma_m
}

fn rho_of(ctx: &Ctx, k: usize, theta: f64, origin: Point) -> f64 {
    far_tangent(&ctx.preps[k].ellipse, Point::from_angle(theta), origin).0
}

fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    let (_, m, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    *m
}

/// Robust fit quality of the line at angle `theta` for `set`: truncated
/// squared residuals (in σ) about the median offset.
fn objective(ctx: &Ctx, set: &[usize], theta: f64, origin: Point, buf: &mut Vec<f64>) -> f64 {
    buf.clear();
    buf.extend(set.iter().map(|&k| rho_of(ctx, k, theta, origin)));
    let mut sorted = buf.clone();
    let med = median(&mut sorted);
    let cap = ctx.params.band_sigmas * ctx.params.band_sigmas;
    set.iter().zip(buf.iter()).map(|(&k, r)| (((r - med) / ctx.preps[k].sigma_m).powi(2)).min(cap)).sum()
}

/// Golden-section minimum of `f` on `[lo, hi]`.
fn golden(mut lo: f64, mut hi: f64, mut f: impl FnMut(f64) -> f64) -> f64 {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..40 {
        if f1 <= f2 {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - g * (hi - lo);
            f1 = f(x1);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + g * (hi - lo);
            f2 = f(x2);
        }
    }
    0.5 * (lo + hi)
}

/// Echoes whose far tangent at `theta` lies within their band of `rho`.
fn gather(ctx: &Ctx, theta: f64, rho: f64, origin: Point, extra: f64) -> Vec<usize> {
    (0..ctx.preps.len()).filter(|&k| (rho_of(ctx, k, theta, origin) - rho).abs() <= tau(ctx, k) + extra).collect()
}

/// Keeps, per measurement, the echo closest to the line, and only
/// measurements inside runs of ≥ `min_run` consecutive poses of one listener
/// (tangency by neighbouring poses, issue 9 item 3). Returns touches and the
/// segment spanned by them.
fn touches_in_runs(ctx: &Ctx, set: &[usize], theta: f64, rho: f64, origin: Point) -> Vec<(usize, Point)> {
    let n = Point::from_angle(theta);
    let mut best: std::collections::BTreeMap<usize, (f64, usize, Point)> = Default::default();
    for &k in set {
        let (r, p) = far_tangent(&ctx.preps[k].ellipse, n, origin);
        let res = (r - rho).abs() / ctx.preps[k].sigma_m;
        let m = ctx.preps[k].meas;
        if best.get(&m).is_none_or(|b| res < b.0) {
            best.insert(m, (res, k, p));
        }
    }
    // Runs over (listener, seq); measurements are sorted by (listener, t), so
    // consecutive measurement indices of one listener are consecutive poses.
    let ms: Vec<usize> = best.keys().copied().collect();
    let min_run = ctx.params.min_run as usize;
    let mut keep = Vec::new();
    let mut start = 0;
    for i in 1..=ms.len() {
        let breaks = i == ms.len() || {
            let (a, b) = (&ctx.meas[ms[i - 1]], &ctx.meas[ms[i]]);
            a.listener_id != b.listener_id || b.seq != a.seq + 1
        };
        if breaks {
            if i - start >= min_run {
                keep.extend_from_slice(&ms[start..i]);
            }
            start = i;
        }
    }
    keep.iter().filter_map(|m| best.get(m).map(|&(_, k, p)| (k, p))).collect()
}

fn segment_of(theta: f64, rho: f64, origin: Point, touches: &[(usize, Point)]) -> (Point, Point) {
    let n = Point::from_angle(theta);
    let d = Point::new(-n.y, n.x);
    let foot = origin + n * rho;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &(_, p) in touches {
        let t = d.dot(p - origin);
        lo = lo.min(t);
        hi = hi.max(t);
    }
    if lo > hi {
        return (foot, foot);
    }
    (foot + d * lo, foot + d * hi)
}

/// Refines a Hough peak by robust least squares over the angle (golden
/// section) with the offset the mean of the inliers' tangent offsets.
fn refine(ctx: &Ctx, theta0: f64, rho0: f64, origin: Point, bin: f64, rho_bin: f64) -> Option<Cand> {
    let mut set = gather(ctx, theta0, rho0, origin, rho_bin);
    let (mut theta, mut rho) = (theta0, rho0);
    let mut span = bin;
    let mut buf = Vec::new();
    for _ in 0..4 {
        if set.len() < 2 {
            return None;
        }
        theta = golden(theta - span, theta + span, |th| objective(ctx, &set, th, origin, &mut buf));
        let rs: Vec<f64> = set.iter().map(|&k| rho_of(ctx, k, theta, origin)).collect();
        let med = median(&mut rs.clone());
        let (mut sum, mut cnt) = (0.0, 0usize);
        for (&k, r) in set.iter().zip(&rs) {
            if (r - med).abs() <= tau(ctx, k) {
                sum += r;
                cnt += 1;
            }
        }
        if cnt == 0 {
            return None;
        }
        rho = sum / cnt as f64;
        set = gather(ctx, theta, rho, origin, 0.0);
        span *= 0.3;
    }
    let theta = theta.rem_euclid(TAU);
    let touches = touches_in_runs(ctx, &set, theta, rho, origin);
    let (p0, p1) = segment_of(theta, rho, origin, &touches);
    Some(Cand { theta, rho, touches, p0, p1 })
}

/// Whether segments `a`–`b` and `c`–`d` cross, `a`–`b` excluding a small
/// neighbourhood of `b` (the tangency point itself).
fn crosses(a: Point, b: Point, c: Point, d: Point) -> bool {
    let r = b - a;
    let s = d - c;
    let denom = r.cross(s);
    if denom.abs() < 1e-12 {
        return false;
    }
    let t = (c - a).cross(s) / denom;
    let u = (c - a).cross(r) / denom;
    let eps = 1e-3 / r.norm().max(1e-9);
    (0.0..=1.0 - eps).contains(&t) && (0.0..=1.0).contains(&u)
}

/// Fraction of `c`'s tangency points hidden from the source or the listener
/// behind one of `occluders` (each extended by 1 m plus a quarter of its
/// length, since the ends of a wall are rarely observed).
fn occluded_fraction(ctx: &Ctx, c: &Cand, occluders: &[&Cand]) -> f64 {
    if c.touches.is_empty() || occluders.is_empty() {
        return 0.0;
    }
    let ext: Vec<(Point, Point)> = occluders
        .iter()
        .map(|o| {
            let len = o.length();
            let dir = if len > 0.0 { (o.p1 - o.p0) * (1.0 / len) } else { Point::new(-o.normal().y, o.normal().x) };
            let grow = 1.0 + 0.25 * len;
            (o.p0 - dir * grow, o.p1 + dir * grow)
        })
        .collect();
    let hidden = c
        .touches
        .iter()
        .filter(|&&(k, p)| {
            let e = &ctx.preps[k].ellipse;
            ext.iter().any(|&(q0, q1)| crosses(e.focus_a, p, q0, q1) || crosses(e.focus_b, p, q0, q1))
        })
        .count();
    hidden as f64 / c.touches.len() as f64
}

/// Fraction of the segment's samples (every half cell) carved free.
fn free_fraction(ctx: &Ctx, c: &Cand) -> f64 {
    let len = c.length();
    let n = ((len / (0.5 * ctx.spec.cell_m)).ceil() as usize).clamp(1, 100_000);
    let free = (0..=n).filter(|&s| ctx.is_free(c.p0 + (c.p1 - c.p0) * (s as f64 / n as f64))).count();
    free as f64 / (n + 1) as f64
}

fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(TAU);
    d.min(TAU - d)
}

/// The Hough vote, candidate refinement, ghost rejection and assignment.
pub(crate) fn find_lines(ctx: &Ctx) -> LinesResult {
    let p = ctx.params;
    if ctx.preps.is_empty() {
        return LinesResult::default();
    }
    let origin = origin_of(ctx);
    let spec = &ctx.spec;
    let r_max = 0.5 * (spec.x_max_m() - spec.x_min_m).hypot(spec.y_max_m() - spec.y_min_m) + spec.cell_m;
    let rho_bin = spec.cell_m;
    let n_rho = ((2.0 * r_max / rho_bin).ceil() as usize + 1).min(1 << 20);
    let k_bins = p.angle_bins as usize;
    let bin = TAU / k_bins as f64;
    let trig: Vec<(f64, f64)> = (0..k_bins).map(|t| (t as f64 * bin).sin_cos()).map(|(s, c)| (c, s)).collect();
    let mut acc = vec![0u32; k_bins * n_rho];
    for (k, prep) in ctx.preps.iter().enumerate() {
        let e = &prep.ellipse;
        let (a2, b2) = (e.semi_major_m * e.semi_major_m, e.semi_minor_m * e.semi_minor_m);
        let c = e.center - origin;
        let half = tau(ctx, k) + rho_bin;
        for (t, &(nx, ny)) in trig.iter().enumerate() {
            let nu = nx * e.cos_t + ny * e.sin_t;
            let nv = -nx * e.sin_t + ny * e.cos_t;
            let rho = far_offset(a2, b2, nu, nv, nx * c.x + ny * c.y);
            let lo = ((rho - half + r_max) / rho_bin).ceil().max(0.0);
            let hi = ((rho + half + r_max) / rho_bin).floor().min(n_rho as f64 - 1.0);
            if lo > hi {
                continue;
            }
            let row = &mut acc[t * n_rho..(t + 1) * n_rho];
            for v in &mut row[lo as usize..=hi as usize] {
                *v += 1;
            }
        }
    }
    // Peaks: ≥ min_support and maximal among the 8 neighbours (θ wraps);
    // equal neighbours earlier in scan order win.
    let mut peaks: Vec<(u32, usize, usize)> = Vec::new();
    let min_votes = p.min_support;
    for t in 0..k_bins {
        for b in 0..n_rho {
            let v = acc[t * n_rho + b];
            if v < min_votes {
                continue;
            }
            let mut is_max = true;
            'nb: for dt in [k_bins - 1, 0, 1] {
                let tt = (t + dt) % k_bins;
                for bb in b.saturating_sub(1)..=(b + 1).min(n_rho - 1) {
                    if (tt, bb) == (t, b) {
                        continue;
                    }
                    let w = acc[tt * n_rho + bb];
                    let earlier = tt < t || (tt == t && bb < b);
                    if w > v || (w == v && earlier) {
                        is_max = false;
                        break 'nb;
                    }
                }
            }
            if is_max {
                peaks.push((v, t, b));
            }
        }
    }
    peaks.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    peaks.truncate(4 * p.max_surfaces as usize);

    // Refine, keep lines, drop duplicates (same orientation, shared echoes).
    let mut cands: Vec<Cand> = peaks
        .iter()
        .filter_map(|&(_, t, b)| refine(ctx, t as f64 * bin, b as f64 * rho_bin - r_max, origin, bin, rho_bin))
        .filter(|c| c.support() >= p.min_support as usize && c.length() >= p.min_line_length_m)
        .collect();
    cands.sort_by(|a, b| b.support().cmp(&a.support()).then(a.theta.total_cmp(&b.theta)));
    let mut uniq: Vec<Cand> = Vec::new();
    for c in cands {
        let dup = uniq.iter().any(|u| {
            angle_diff(u.theta, c.theta) < 3.0 * bin && {
                let shared = c.touches.iter().filter(|(k, _)| u.touches.iter().any(|(j, _)| j == k)).count();
                2 * shared >= c.support()
            }
        });
        if !dup {
            uniq.push(c);
        }
    }

    // Ghosts: mostly in free space, or mostly behind a stronger line.
    let mut ghost: Vec<bool> = uniq.iter().map(|c| free_fraction(ctx, c) > p.ghost_fraction).collect();
    for _ in 0..6 {
        let next: Vec<bool> = uniq
            .iter()
            .enumerate()
            .map(|(i, c)| {
                if free_fraction(ctx, c) > p.ghost_fraction {
                    return true;
                }
                let occ: Vec<&Cand> = uniq
                    .iter()
                    .enumerate()
                    .filter(|&(j, o)| j != i && !ghost[j] && 2 * o.support() >= c.support())
                    .map(|(_, o)| o)
                    .collect();
                occluded_fraction(ctx, c, &occ) > p.ghost_fraction
            })
            .collect();
        if next == ghost {
            break;
        }
        ghost = next;
    }
    let mut out = LinesResult::default();
    for (c, g) in uniq.iter().zip(&ghost) {
        if *g {
            out.ghost_echoes.extend(c.touches.iter().map(|&(k, _)| k));
        }
    }

    // Greedy: strongest first, each echo explained once; a candidate whose
    // echoes an accepted ambiguous line already explains is its mirror twin,
    // reported too (ambiguous).
    let mut owner: Vec<Option<usize>> = vec![None; ctx.preps.len()];
    for (c, _) in uniq.iter().zip(&ghost).filter(|(_, g)| !**g) {
        if out.accepted.len() >= p.max_surfaces as usize {
            break;
        }
        let owners: Vec<Option<usize>> = c.touches.iter().map(|&(k, _)| owner[k]).collect();
        let twin = owners.first().copied().flatten().filter(|&o| {
            out.accepted[o].surface.ambiguous
                && 5 * owners.iter().filter(|x| **x == Some(o)).count() >= 4 * owners.len()
        });
        let touches: Vec<(usize, Point)> = if twin.is_some() {
            c.touches.clone()
        } else {
            let free: Vec<usize> = c.touches.iter().filter(|(k, _)| owner[*k].is_none()).map(|&(k, _)| k).collect();
            if free.len() < c.touches.len() {
                touches_in_runs(ctx, &free, c.theta, c.rho, origin)
            } else {
                c.touches.clone()
            }
        };
        if touches.len() < p.min_support as usize {
            continue;
        }
        let (p0, p1) = segment_of(c.theta, c.rho, origin, &touches);
        if p0.dist(p1) < p.min_line_length_m {
            continue;
        }
        let ks: Vec<usize> = touches.iter().map(|&(k, _)| k).collect();
        let ambiguous = ctx.collinear(&ks);
        let idx = out.accepted.len();
        if twin.is_none() {
            for &k in &ks {
                owner[k] = Some(idx);
            }
        }
        out.accepted.push(LineOut {
            surface: Surface { kind: SurfaceKind::Line, p0, p1, support: touches.len(), ambiguous },
            touches,
        });
    }
    out
}
