//! Compact reflectors the envelope misses: a vote over positions by the
//! bands of the echoes left, then a trimmed least-squares fit.
//!
//! The envelope ([`super::envelope`]) places a reflector where the ellipses
//! of consecutive poses cross. When the poses are sparse and Δd scatters by
//! a few σ from pose to pose (the particle echoes of a rough circle at
//! Table I's 50 ms sampling: its particles return from across the face),
//! those crossings fall metres apart and never pile up, although every pose
//! heard the reflector and its bands still overlap there. This step counts,
//! on a grid of band-wide cells, the measurements whose band (Δd ± kσ, plus
//! the cell's size) covers each cell, the vote of the generalised Hough
//! transform (Ballard 1981) on the bands Algorithm 1 draws as lines; a
//! local maximum heard by `min_support` measurements, outside carved free
//! space, seeds a point reflector fitted to the echoes through it by
//! Gauss–Newton. An echo more than kσ off the fit is dropped, worst first,
//! while `min_support` measurements remain (a rough face's stray
//! returns); a seed left with fewer is no reflector.

use super::envelope::PointOut;
use super::lines::crosses;
use super::{Ctx, Surface, SurfaceKind, for_each_band_span};
use crate::geometry::Point;
use crate::grid::GridSpec;

/// Largest vote grid (cells): beyond it the vote's cells are coarsened, so
/// memory stays bounded whatever the map's bounds and cell.
const MAX_VOTE_CELLS: usize = 1 << 22;

/// Poses apart that still continue a run in [`in_runs`].
const MAX_POSE_GAP: usize = 2;

/// Rounds of fitting and trimming before a seed is given up.
const MAX_TRIM_ROUNDS: usize = 24;

/// Gauss–Newton iterations of a point fit.
const FIT_ITERATIONS: usize = 50;

/// Point reflectors from the echoes neither skipped (explained or ghosts)
/// nor used, at most `max_points`, strongest vote first.
pub(crate) fn vote_points(ctx: &Ctx, skip: &[bool], walls: &[Wall], max_points: usize) -> Vec<PointOut> {
    let p = ctx.params;
    let left: Vec<usize> = (0..ctx.preps.len()).filter(|&k| !skip[k] && !image_echo(ctx, k, walls)).collect();
    let trusted: Vec<Wall> = walls.iter().filter(|w| !w.ambiguous).copied().collect();
    let walls: Vec<(Point, Point)> = walls.iter().map(|w| w.extent).collect();
    let walls = &walls[..];
    if max_points == 0 || distinct_meas(ctx, &left) < p.min_support as usize {
        return Vec::new();
    }
    let Some(vote) = Vote::count(ctx, &left) else { return Vec::new() };
    let mut used = vec![false; ctx.preps.len()];
    let mut tried: std::collections::HashSet<Vec<usize>> = std::collections::HashSet::new();
    let mut out = Vec::new();
    for seed in vote.seeds(ctx) {
        if out.len() >= max_points {
            break;
        }
        let through = nearest_per_meas(ctx, &left, &used, seed, vote.slack_m);
        // Neighbouring seeds of one ridge of the vote often hold the same
        // echoes; a set that failed once fails again.
        if through.len() < p.min_support as usize || !tried.insert(through.clone()) {
            continue;
        }
        let Some((at, ks)) = trimmed_fit(ctx, seed, through) else { continue };
        // On the line of a found wall that is not ambiguous (within the
        // cluster radius), the echoes are the wall's own that its runs
        // missed, often where it goes on beyond the stretch its runs saw:
        // no new reflector. (An ambiguous line of a straight pass may be a
        // large circle's stand-in; a point beside it can place the circle
        // better.)
        let on_wall = trusted.iter().any(|w| (at - w.at).dot(w.normal).abs() <= p.point_radius_m);
        if ctx.spec.cell_of(at).is_none() || ctx.is_free(at) || on_wall || hidden(ctx, &ks, at, walls) {
            continue;
        }
        // Echoes of the measurements not yet in the fit that it explains.
        let mut ks = ks;
        let mut seen: std::collections::BTreeSet<usize> = ks.iter().map(|&k| ctx.preps[k].meas).collect();
        for k in nearest_per_meas(ctx, &left, &used, at, 0.0) {
            if seen.insert(ctx.preps[k].meas) {
                ks.push(k);
            }
        }
        for &k in &ks {
            used[k] = true;
        }
        out.push(PointOut {
            surface: Surface {
                kind: SurfaceKind::Point,
                p0: at,
                p1: at,
                support: seen.len(),
                ambiguous: super::envelope::point_ambiguous(ctx, &ks, at),
            },
            touches: ks.iter().map(|&k| (k, at)).collect(),
            model: Some(super::envelope::SmallCircle { c: at, rho_m: 0.0 }),
        });
    }
    out
}

/// A found wall, as the vote sees it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Wall {
    /// A point of its line and the line's unit normal.
    pub at: Point,
    pub normal: Point,
    /// The stretch over which it hides what lies behind it.
    pub extent: (Point, Point),
    /// Mirror-ambiguous: its images are not trusted.
    pub ambiguous: bool,
}

impl Wall {
    fn mirror(&self, p: Point) -> Point {
        p - self.normal * (2.0 * (p - self.at).dot(self.normal))
    }
}

/// Whether echo `k`'s Δd is, within its band, that of a second-order image
/// of its source in two of the walls that are not ambiguous (the
/// image-source model of room acoustics, Allen and Berkley 1979): a
/// corner's or two parallel walls' second reflection. Such an echo is no
/// evidence of a reflector of its own; the room with a pillar of `chirpmap
/// benchmark maps` otherwise gathered its corners' second reflections into
/// points outside the room. First-order images are left out: a short line
/// fitted beside a circle (the loop past circles) explained that circle's
/// leftover echoes by its image and so hid a compact reflector.
fn image_echo(ctx: &Ctx, k: usize, walls: &[Wall]) -> bool {
    let prep = &ctx.preps[k];
    let e = &prep.ellipse;
    let (s, l) = (e.focus_a, e.focus_b);
    let direct = s.dist(l);
    let tol = ctx.params.band_sigmas * prep.sigma_m;
    let fits = |image: Point| (image.dist(l) - direct - e.delta_d_m).abs() <= tol;
    let trusted: Vec<&Wall> = walls.iter().filter(|w| !w.ambiguous).collect();
    trusted.iter().enumerate().any(|(a, wa)| {
        let first = wa.mirror(s);
        trusted.iter().enumerate().any(|(b, wb)| a != b && fits(wb.mirror(first)))
    })
}

/// Whether more than `ghost_fraction` of the echoes `ks` would have to
/// cross one of the `walls` (found lines) on their way from the source to
/// `at` or from `at` to the listener: a reflector behind a wall is the
/// image of a higher-order reflection, as for lines ([`super::lines`]'s
/// occlusion test).
fn hidden(ctx: &Ctx, ks: &[usize], at: Point, walls: &[(Point, Point)]) -> bool {
    let n = ks
        .iter()
        .filter(|&&k| {
            let e = &ctx.preps[k].ellipse;
            walls.iter().any(|&(q0, q1)| crosses(e.focus_a, at, q0, q1) || crosses(e.focus_b, at, q0, q1))
        })
        .count();
    n as f64 > ctx.params.ghost_fraction * ks.len() as f64
}

fn distinct_meas(ctx: &Ctx, ks: &[usize]) -> usize {
    let mut ms: Vec<usize> = ks.iter().map(|&k| ctx.preps[k].meas).collect();
    ms.sort_unstable();
    ms.dedup();
    ms.len()
}

/// The count of measurements whose bands cover each cell of a grid of
/// band-wide cells over the map's bounds.
struct Vote {
    spec: GridSpec,
    counts: Vec<u32>,
    /// Focal-excess slack (m) that makes a band cover every cell it touches.
    slack_m: f64,
}

impl Vote {
    fn count(ctx: &Ctx, left: &[usize]) -> Option<Self> {
        let p = ctx.params;
        let mut taus: Vec<f64> = left.iter().map(|&k| p.band_sigmas * ctx.preps[k].sigma_m).collect();
        taus.sort_by(f64::total_cmp);
        let tau = taus[taus.len() / 2];
        let s = &ctx.spec;
        let (w, h) = (s.x_max_m() - s.x_min_m, s.y_max_m() - s.y_min_m);
        let mut cell = tau.max(s.cell_m);
        if (w / cell) * (h / cell) > MAX_VOTE_CELLS as f64 {
            cell = (w * h / MAX_VOTE_CELLS as f64).sqrt();
        }
        let nx = ((w / cell).ceil() as usize).max(1);
        let ny = ((h / cell).ceil() as usize).max(1);
        let spec = GridSpec { x_min_m: s.x_min_m, y_min_m: s.y_min_m, cell_m: cell, nx, ny };
        // A cell centre within half a diagonal of the band: the focal excess
        // changes by at most 2 per metre.
        let slack_m = std::f64::consts::SQRT_2 * cell;
        let mut counts = vec![0u32; nx * ny];
        // The last measurement (+1) that voted for each cell: one vote per
        // measurement, however many of its echoes cover the cell.
        let mut stamp = vec![0u32; nx * ny];
        for &k in left {
            let prep = &ctx.preps[k];
            let e = &prep.ellipse;
            let half = p.band_sigmas * prep.sigma_m + slack_m;
            let mark = prep.meas as u32 + 1;
            let spans =
                for_each_band_span(e.focus_a, e.focus_b, e.delta_d_m - half, e.delta_d_m + half, &spec, |j, lo, hi| {
                    for c in j * nx + lo..=j * nx + hi {
                        if stamp[c] != mark {
                            stamp[c] = mark;
                            counts[c] += 1;
                        }
                    }
                });
            spans.ok()?;
        }
        Some(Vote { spec, counts, slack_m })
    }

    /// Cells with at least `min_support` votes, maximal among their eight
    /// neighbours (equal neighbours earlier in raster order win), outside
    /// carved free space: their centres, most votes first.
    fn seeds(&self, ctx: &Ctx) -> Vec<Point> {
        let (nx, ny) = (self.spec.nx, self.spec.ny);
        let min = ctx.params.min_support;
        let mut seeds: Vec<(u32, usize)> = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let v = self.counts[j * nx + i];
                if v < min {
                    continue;
                }
                let is_max = (j.saturating_sub(1)..=(j + 1).min(ny - 1)).all(|jj| {
                    (i.saturating_sub(1)..=(i + 1).min(nx - 1)).all(|ii| {
                        let w = self.counts[jj * nx + ii];
                        (jj, ii) == (j, i) || w < v || (w == v && (jj, ii) > (j, i))
                    })
                });
                if is_max && !ctx.is_free(self.spec.cell_center(i, j)) {
                    seeds.push((v, j * nx + i));
                }
            }
        }
        seeds.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        seeds.into_iter().map(|(_, c)| self.spec.cell_center(c % nx, c / nx)).collect()
    }
}

/// Of each measurement, the echo of `left` not `used` whose band (plus
/// `slack_m`) holds `at`, nearest to it in σ; in measurement order.
fn nearest_per_meas(ctx: &Ctx, left: &[usize], used: &[bool], at: Point, slack_m: f64) -> Vec<usize> {
    let band = ctx.params.band_sigmas;
    let mut best: Vec<(usize, f64, usize)> = Vec::new();
    for &k in left {
        if used[k] {
            continue;
        }
        let prep = &ctx.preps[k];
        let miss = excess(&prep.ellipse, at).abs();
        if miss > band * prep.sigma_m + slack_m {
            continue;
        }
        let z = miss / prep.sigma_m;
        match best.iter_mut().find(|b| b.0 == prep.meas) {
            Some(b) if z < b.1 => *b = (prep.meas, z, k),
            Some(_) => {}
            None => best.push((prep.meas, z, k)),
        }
    }
    best.sort_by_key(|b| b.0);
    best.into_iter().map(|b| b.2).collect()
}

/// A point reflector fitted to `ks` from `start`, dropping the worst echo
/// while any lies more than kσ off and `min_support` remain. `None` when
/// the fit fails or too few echoes remain.
fn trimmed_fit(ctx: &Ctx, start: Point, mut ks: Vec<usize>) -> Option<(Point, Vec<usize>)> {
    let p = ctx.params;
    let min = p.min_support as usize;
    for _ in 0..MAX_TRIM_ROUNDS {
        let at = fit_point(ctx, &ks, start)?;
        let mut z: Vec<(f64, usize)> = ks
            .iter()
            .enumerate()
            .map(|(i, &k)| (excess(&ctx.preps[k].ellipse, at).abs() / ctx.preps[k].sigma_m, i))
            .collect();
        let outliers = z.iter().filter(|(z, _)| *z > p.band_sigmas).count();
        if outliers == 0 {
            let runs = in_runs(ctx, &ks);
            if runs.len() == ks.len() {
                return Some((at, ks));
            }
            // Refit to the echoes of runs of poses alone, unless most of
            // the fit's echoes are not in runs: a reflector is heard pose
            // after pose, while echoes that agree by chance (clutter) are
            // scattered along the walk and only a few fall in runs.
            if runs.len() < min || 3 * runs.len() < ks.len() {
                return None;
            }
            ks = runs;
            continue;
        }
        if ks.len() <= min {
            return None;
        }
        // The worst eighth of the echoes (at least one, only outliers, and
        // never below `min_support`) go: a few rounds for a few hundred
        // echoes through a seed, where one at a time cost a fit per echo.
        let drop = (ks.len() / 8).max(1).min(outliers).min(ks.len() - min);
        z.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut gone = vec![false; ks.len()];
        for &(_, i) in &z[..drop] {
            gone[i] = true;
        }
        ks = ks.iter().zip(&gone).filter(|(_, g)| !**g).map(|(&k, _)| k).collect();
    }
    None
}

/// The echoes of `ks` (one per measurement, in measurement order) whose
/// measurements lie in runs of at least `min_run` poses of one listener,
/// each within [`MAX_POSE_GAP`] poses of the previous: a reflector is
/// heard from neighbouring poses, as a wall is ([`super::lines`]), and a
/// stray echo far along the walk pins a fit anywhere (seen on the loop past
/// circles: four echoes of consecutive poses and one 50 poses later fitted
/// a point 20 m from every circle). One pose may miss the echo (sparse
/// poses of a rough reflector: Table I at 50 ms).
fn in_runs(ctx: &Ctx, ks: &[usize]) -> Vec<usize> {
    let min_run = ctx.params.min_run as usize;
    let mut keep = Vec::new();
    let mut start = 0;
    for i in 1..=ks.len() {
        let breaks = i == ks.len() || {
            let (a, b) = (&ctx.meas[ctx.preps[ks[i - 1]].meas], &ctx.meas[ctx.preps[ks[i]].meas]);
            a.listener_id != b.listener_id || b.seq > a.seq + MAX_POSE_GAP
        };
        if breaks {
            if i - start >= min_run {
                keep.extend_from_slice(&ks[start..i]);
            }
            start = i;
        }
    }
    keep
}

/// Weighted least-squares position of a point reflector for the echoes
/// `ks` (residual: minus the focal excess, weight 1/σ²), by Gauss–Newton
/// from `start`. `None` on a singular system or no convergence.
fn fit_point(ctx: &Ctx, ks: &[usize], start: Point) -> Option<Point> {
    let mut at = start;
    for _ in 0..FIT_ITERATIONS {
        let (mut a11, mut a12, mut a22, mut g1, mut g2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &k in ks {
            let prep = &ctx.preps[k];
            let e = &prep.ellipse;
            let (da, db) = (at - e.focus_a, at - e.focus_b);
            let (na, nb) = (da.dot(da).sqrt(), db.dot(db).sqrt());
            if !(na > 1e-9 && nb > 1e-9) {
                return None;
            }
            let j = da * (1.0 / na) + db * (1.0 / nb);
            let w = 1.0 / (prep.sigma_m * prep.sigma_m);
            let r = -excess(e, at);
            a11 += w * j.x * j.x;
            a12 += w * j.x * j.y;
            a22 += w * j.y * j.y;
            g1 += w * j.x * r;
            g2 += w * j.y * r;
        }
        let det = a11 * a22 - a12 * a12;
        // (NaN fails the comparison too.)
        if det.abs().partial_cmp(&(1e-12 * (a11 * a22).abs())) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let step = Point::new((a22 * g1 - a12 * g2) / det, (a11 * g2 - a12 * g1) / det);
        at = at + step;
        if !(at.x.is_finite() && at.y.is_finite()) {
            return None;
        }
        if step.norm() < 1e-5 {
            return Some(at);
        }
    }
    None
}

/// [`crate::ellipse::Ellipse::focal_excess`] with distances by `sqrt` of the
/// squared norm rather than `hypot` (a libm call per distance, 11 % of a
/// Table I 1 ms map in this step): within a few ulps, and coordinates of a
/// map are far from where `hypot`'s overflow guard matters.
#[inline]
fn excess(e: &crate::ellipse::Ellipse, p: Point) -> f64 {
    let (a, b) = (p - e.focus_a, p - e.focus_b);
    a.dot(a).sqrt() + b.dot(b).sqrt() - 2.0 * e.semi_major_m
}
