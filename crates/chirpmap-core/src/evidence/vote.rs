//! Compact reflectors the envelope misses: a vote over positions by the
//! bands of the echoes left, then a trimmed least-squares fit.
//!
//! The envelope ([`super::envelope`]) places a reflector where the ellipses
//! of consecutive poses cross. When the poses are sparse and Δd scatters by
//! a few σ from pose to pose (the particle echoes of a rough circle at
//! Table I's 50 ms sampling: its particles return from across the face),
//! those crossings fall metres apart and never pile up, although every pose
//! heard the reflector and its bands still overlap there. This step counts,
//! on a grid of cells as wide as the echoes' median band half-width kσ (at
//! least the map's cell and a quarter of the cluster radius), the
//! measurements whose band (Δd ± kσ, plus √2 cells) covers each cell: the
//! vote of the generalised Hough transform
//! (Ballard 1981) on the bands Algorithm 1 draws as lines. A local maximum
//! heard by `min_support` measurements, outside carved free space, seeds a
//! point reflector fitted by Gauss–Newton to the echo of each measurement
//! whose band holds the seed ([`trimmed_fit`]: a rough face's stray returns
//! are trimmed, and the echoes must come from runs of poses). The fit must
//! keep half the echoes through its seed, and is refused in free space,
//! behind or on a found wall, or next to a reflector already found.
//! docs/evidence-mapper.md §3 gives the measurements behind each rule.

use super::band::Band;
use super::envelope::PointOut;
use super::lines::crosses;
use super::{Ctx, Surface, SurfaceKind};
use crate::geometry::{Point, point_segment_distance};
use crate::grid::GridSpec;

/// Largest vote grid (cells): beyond it the vote's cells are coarsened, so
/// memory stays bounded whatever the map's bounds and cell.
const MAX_VOTE_CELLS: usize = 1 << 22;

/// Measurements apart (in one listener's order) that still continue a run
/// in [`in_runs`].
const MAX_POSE_GAP: usize = 2;

/// Rounds of fitting and trimming before a seed is given up.
const MAX_TRIM_ROUNDS: usize = 24;

/// Gauss–Newton iterations of a point fit.
const FIT_ITERATIONS: usize = 50;

/// Seeds examined at most: each costs a pass over the echoes left, and on a
/// fine grid of precise echoes amid clutter the vote has tens of thousands
/// of local maxima (56 711 on a 20 000-pose walk with two false echoes per
/// pose at σ = 2 mm and 1 cm cells, 15 s for this step before the cap).
const MAX_SEEDS: usize = 1024;

/// Point reflectors from the echoes neither skipped (explained or ghosts)
/// nor explained by the compact reflectors already `found` (their fitted
/// circles), at most `max_points`, strongest vote first. `walls` are the
/// lines found.
pub(crate) fn vote_points(
    ctx: &Ctx,
    skip: &[bool],
    walls: &[Wall],
    found: &[PointOut],
    max_points: usize,
) -> Vec<PointOut> {
    let p = ctx.params;
    if max_points == 0 {
        return Vec::new();
    }
    let (trusted, reach) = trusted_reach(walls);
    // In measurement order: one vote per measurement and one echo per
    // measurement below rely on it.
    let mut left: Vec<usize> = (0..ctx.preps.len())
        .filter(|&k| !skip[k] && !explained_by(ctx, k, found) && !image_echo(ctx, k, &trusted, &reach))
        .collect();
    left.sort_by_key(|&k| (ctx.preps[k].meas, k));
    if distinct_meas(ctx, &left) < p.min_support as usize {
        return Vec::new();
    }
    let extents: Vec<(Point, Point)> = walls.iter().map(|w| w.extent).collect();
    let mut not_left = vec![true; ctx.preps.len()];
    for &k in &left {
        not_left[k] = false;
    }
    let Some(vote) = Vote::count(ctx, &left) else { return Vec::new() };
    let mut used = vec![false; ctx.preps.len()];
    // Hashes of the echo sets tried: neighbouring seeds of one ridge of the
    // vote often hold the same echoes, and a set that failed once fails
    // again.
    let mut tried: std::collections::HashSet<u64> = std::collections::HashSet::new();
    // Reflectors so far; a seed or fit within two cluster radii of one is
    // that reflector's leftover echoes (a pillar is no point at σ = 1 cm).
    let mut reflectors: Vec<Point> = found.iter().map(|f| f.surface.p0).collect();
    let near_reflector =
        |q: Point, reflectors: &[Point]| reflectors.iter().any(|r| r.dist(q) <= 2.0 * p.point_radius_m);
    let mut out = Vec::new();
    let seeds: Vec<Point> = vote.seeds(ctx).into_iter().take(MAX_SEEDS).collect();
    for batch in seeds.chunks(SEED_BATCH) {
        let mut plan =
            plan_batch(ctx, batch, &left, &used, &reflectors, &tried, vote.slack_m, &near_reflector).into_iter();
        // The plan holds while no reflector has been accepted in this batch.
        let accepted_before = out.len();
        for &seed in batch {
            let planned = plan.next().filter(|_| out.len() == accepted_before);
            if out.len() >= max_points {
                break;
            }
            if near_reflector(seed, &reflectors) {
                continue;
            }
            let (through, fitted) = match planned {
                Some(Planned { through: Some(through), fitted }) => (through, fitted),
                _ => (nearest_per_meas(ctx, &left, &used, seed, vote.slack_m), None),
            };
            if through.len() < p.min_support as usize || !tried.insert(hash_of(&through)) {
                continue;
            }
            // Consensus, as in RANSAC (Fischler and Bolles 1981): at least half
            // the echoes through the seed must fit the point. A reflector that
            // is no point at the echoes' σ (a 0.3 m pillar at σ = 1 cm), or the
            // higher-order echoes of a pillar and a wall, leaves a few echoes
            // that fit a point somewhere near by chance; six such points
            // appeared on a dense room walk with a pillar and clutter (test
            // `pillar_in_clutter_gets_no_stray_points_from_the_vote`). The fit
            // gives up once fewer remain (its echoes only ever shrink).
            let fitted = fitted.unwrap_or_else(|| trimmed_fit(ctx, seed, through.len().div_ceil(2), through));
            let Some((at, ks)) = fitted else { continue };
            // On a found wall that is not ambiguous (within the cluster radius
            // of it, continued to its corners with the other such walls), the
            // echoes are the wall's own that its runs missed: no new reflector.
            // (An ambiguous line of a straight pass may be a large circle's
            // stand-in; a point beside it can place the circle better.)
            let on_wall = on_wall(&reach, at, p.point_radius_m);
            if ctx.spec.cell_of(at).is_none()
                || ctx.free_against(at, ks.len())
                || on_wall
                || near_reflector(at, &reflectors)
                || hidden(ctx, &ks, at, &extents)
            {
                continue;
            }
            let ks = extend_runs(ctx, ks, nearest_per_meas(ctx, &left, &used, at, 0.0));
            // A pillar is no point at a centimetre's σ: the point fits the
            // echoes of one side of it, and the rest would seed points
            // metres away (a 0.3 m pillar circled at σ = 0.5–2 cm gave 25–28
            // points, session 22). As the envelope's reflectors do, the
            // point grows into the small circle that fits its echoes, which
            // then takes every echo left that the circle explains.
            let mut touches: Vec<(usize, Point)> = ks.iter().map(|&k| (k, at)).collect();
            let mut meas_seen: std::collections::BTreeSet<usize> = ks.iter().map(|&k| ctx.preps[k].meas).collect();
            let model = super::envelope::explain_more(ctx, &not_left, &used, at, &mut touches, &mut meas_seen)
                .unwrap_or(super::envelope::SmallCircle { c: at, rho_m: 0.0 });
            // Every echo at its reflection point on the circle, as the ones
            // it grew by (the point's own echoes were placed at the point).
            for (k, q) in &mut touches {
                let e = &ctx.preps[*k].ellipse;
                *q = model.specular_point(e.focus_a, e.focus_b);
            }
            for &(k, _) in &touches {
                used[k] = true;
            }
            let ks: Vec<usize> = touches.iter().map(|&(k, _)| k).collect();
            reflectors.push(at);
            let at = model.point_toward(at);
            out.push(PointOut {
                surface: Surface {
                    kind: SurfaceKind::Point,
                    p0: at,
                    p1: at,
                    support: meas_seen.len(),
                    ambiguous: super::envelope::point_ambiguous(ctx, &ks, at),
                },
                touches,
                model: Some(model),
            });
        }
    }
    out
}

/// The walls that are not mirror-ambiguous, and each continued to its
/// corners with the others ([`Wall::reach_to_corners`]).
pub(crate) fn trusted_reach(walls: &[Wall]) -> (Vec<Wall>, Vec<(Point, Point)>) {
    let trusted: Vec<Wall> = walls.iter().filter(|w| !w.ambiguous).copied().collect();
    let reach = trusted.iter().map(|w| w.reach_to_corners(&trusted)).collect();
    (trusted, reach)
}

/// Whether `at` lies within `radius_m` of a trusted wall's reach: a compact
/// reflector found there is made of that wall's own echoes its runs missed.
pub(crate) fn on_wall(reach: &[(Point, Point)], at: Point, radius_m: f64) -> bool {
    reach.iter().any(|&(q0, q1)| point_segment_distance(at, q0, q1) <= radius_m)
}

/// Seeds worked out together by [`plan_batch`].
const SEED_BATCH: usize = 16;

/// A point reflector and the echoes it explains, as [`trimmed_fit`] gives it.
type Fitted = Option<(Point, Vec<usize>)>;

/// A seed's echoes and fit, worked out ahead of the sequential pass.
struct Planned {
    /// The echoes through the seed (`None`: next to a reflector).
    through: Option<Vec<usize>>,
    /// The trimmed fit, where the pass will need it (`None`: not fitted).
    fitted: Option<Fitted>,
}

/// The echoes through each seed of `batch` and, for each seed the
/// sequential pass of [`vote_points`] will fit, its [`trimmed_fit`], on
/// rayon's threads (the fits were 10–13 ms of this step on Table I at
/// 1 ms, and all but a few are refused). Both are pure functions of the seed
/// and of the state before the batch (`used`, `reflectors`, `tried`), so they
/// are what the pass would compute for as long as it accepts no reflector;
/// after it accepts one it works the batch's other seeds out itself. The
/// same reflectors whatever the thread count.
#[allow(clippy::too_many_arguments)]
fn plan_batch(
    ctx: &Ctx,
    batch: &[Point],
    left: &[usize],
    used: &[bool],
    reflectors: &[Point],
    tried: &std::collections::HashSet<u64>,
    slack_m: f64,
    near_reflector: &(impl Fn(Point, &[Point]) -> bool + Sync),
) -> Vec<Planned> {
    use rayon::prelude::*;
    let min = ctx.params.min_support as usize;
    let throughs: Vec<Option<Vec<usize>>> = batch
        .par_iter()
        .map(|&seed| (!near_reflector(seed, reflectors)).then(|| nearest_per_meas(ctx, left, used, seed, slack_m)))
        .collect();
    // Which seeds the pass fits: as it decides, with the hashes of this
    // batch's earlier sets added to those tried before.
    let mut seen: std::collections::HashSet<u64> = std::collections::HashSet::new();
    let fit_it: Vec<bool> = throughs
        .iter()
        .map(|t| {
            t.as_ref().is_some_and(|t| {
                let h = hash_of(t);
                t.len() >= min && !tried.contains(&h) && seen.insert(h)
            })
        })
        .collect();
    let fits: Vec<Option<Fitted>> = batch
        .par_iter()
        .zip(&throughs)
        .zip(&fit_it)
        .map(|((&seed, through), &fit_it)| {
            let through = through.as_ref().filter(|_| fit_it)?;
            Some(trimmed_fit(ctx, seed, through.len().div_ceil(2), through.clone()))
        })
        .collect();
    throughs.into_iter().zip(fits).map(|(through, fitted)| Planned { through, fitted }).collect()
}

/// A hash of an echo set (the `tried` sets hold hashes, not the sets).
fn hash_of(ks: &[usize]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    ks.hash(&mut h);
    h.finish()
}

/// Whether a compact reflector already found predicts echo `k`'s Δd within
/// its band (the fitted circle of [`super::envelope`]).
fn explained_by(ctx: &Ctx, k: usize, found: &[PointOut]) -> bool {
    let prep = &ctx.preps[k];
    let e = &prep.ellipse;
    found.iter().filter_map(|f| f.model).any(|m| {
        m.predict(e.focus_a, e.focus_b)
            .is_some_and(|(pred, _)| (e.delta_d_m - pred).abs() <= ctx.params.band_sigmas * prep.sigma_m)
    })
}

/// `ks` (one echo per measurement, in measurement order) with each echo of
/// `more` (likewise) whose measurement is not in `ks` and continues one of
/// its runs (same listener, within [`MAX_POSE_GAP`] of a measurement of
/// `ks` or of one added before it), in measurement order.
fn extend_runs(ctx: &Ctx, ks: Vec<usize>, more: Vec<usize>) -> Vec<usize> {
    let key = |k: usize| {
        let m = &ctx.meas[ctx.preps[k].meas];
        (m.listener_id, m.seq)
    };
    let mut have: std::collections::BTreeSet<(u32, usize)> = ks.iter().map(|&k| key(k)).collect();
    let mut all = ks;
    // Forward and backward, so that a run grows at both ends.
    for pass in 0..2 {
        let order: Vec<usize> = if pass == 0 { more.clone() } else { more.iter().rev().copied().collect() };
        for k in order {
            let (l, seq) = key(k);
            if have.contains(&(l, seq)) {
                continue;
            }
            let lo = seq.saturating_sub(MAX_POSE_GAP);
            if have.range((l, lo)..=(l, seq + MAX_POSE_GAP)).next().is_some() {
                have.insert((l, seq));
                all.push(k);
            }
        }
    }
    all.sort_by_key(|&k| ctx.preps[k].meas);
    all
}

/// A found wall, as the vote sees it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Wall {
    /// A point of its line.
    pub at: Point,
    /// The line's unit normal.
    pub normal: Point,
    /// The stretch over which it hides what lies behind it.
    pub extent: (Point, Point),
    /// Mirror-ambiguous: its images are not trusted.
    pub ambiguous: bool,
    /// Echoes it explains.
    pub support: usize,
}

impl Wall {
    fn mirror(&self, p: Point) -> Point {
        p - self.normal * (2.0 * (p - self.at).dot(self.normal))
    }

    /// The extent continued along the line to the nearest crossing with
    /// another of `walls`' lines beyond each end (a room's corner), where
    /// there is one: walls are seen over a stretch, but they go on to the
    /// next wall.
    fn reach_to_corners(&self, walls: &[Wall]) -> (Point, Point) {
        let (q0, q1) = self.extent;
        let len = q0.dist(q1);
        // (A NaN length fails the comparison too.)
        if len.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return self.extent;
        }
        let d = (q1 - q0) * (1.0 / len);
        let (mut lo, mut hi) = (None::<f64>, None::<f64>);
        for v in walls {
            let den = d.dot(v.normal);
            // Parallel (or the wall itself): no corner.
            if den.abs() < 1e-6 {
                continue;
            }
            let t = (v.at - q0).dot(v.normal) / den;
            if t > len {
                hi = Some(hi.map_or(t, |h| h.min(t)));
            } else if t < 0.0 {
                lo = Some(lo.map_or(t, |l| l.max(t)));
            }
        }
        (q0 + d * lo.unwrap_or(0.0), q0 + d * hi.unwrap_or(len))
    }
}

/// Where the segment `a`–`b` crosses the line of `w`, if it does.
fn crossing(a: Point, b: Point, w: &Wall) -> Option<Point> {
    let (fa, fb) = ((a - w.at).dot(w.normal), (b - w.at).dot(w.normal));
    if fa * fb > 0.0 || fa == fb {
        return None;
    }
    Some(a + (b - a) * (fa / (fa - fb)))
}

/// Whether echo `k`'s Δd is, within its band, that of a second-order image
/// of its source in two of the `trusted` walls (not ambiguous; `reach[i]` is
/// wall `i` continued to its corners), with both bounces on the walls' reach
/// (the image-source model of room acoustics, Allen and Berkley 1979, with
/// its visibility test): a corner's or two parallel walls' second
/// reflection. Such an echo is no evidence of a reflector of its own; the
/// room with a pillar of `chirpmap benchmark maps` otherwise gathered its
/// corners' second reflections into points outside the room. First-order
/// images are left out: a short line fitted beside a circle (the loop past
/// circles) explained that circle's leftover echoes by its image and so hid
/// a compact reflector.
fn image_echo(ctx: &Ctx, k: usize, trusted: &[Wall], reach: &[(Point, Point)]) -> bool {
    let prep = &ctx.preps[k];
    let e = &prep.ellipse;
    let (s, l) = (e.focus_a, e.focus_b);
    let direct = s.dist(l);
    let tol = ctx.params.band_sigmas * prep.sigma_m;
    let margin = ctx.params.point_radius_m;
    let on = |q: Point, i: usize| point_segment_distance(q, reach[i].0, reach[i].1) <= margin;
    trusted.iter().enumerate().any(|(a, wa)| {
        let first = wa.mirror(s);
        trusted.iter().enumerate().any(|(b, wb)| {
            if a == b {
                return false;
            }
            let image = wb.mirror(first);
            if (image.dist(l) - direct - e.delta_d_m).abs() > tol {
                return false;
            }
            // Listener → bounce on b → bounce on a → source.
            let Some(on_b) = crossing(l, image, wb) else { return false };
            let Some(on_a) = crossing(on_b, first, wa) else { return false };
            on(on_b, b) && on(on_a, a)
        })
    })
}

/// Whether more than `ghost_fraction` of the echoes `ks` would have to
/// cross one of the `walls` (found lines) on their way from the source to
/// `at` or from `at` to the listener: a reflector behind a wall is the
/// image of a higher-order reflection, as for lines ([`super::lines`]'s
/// occlusion test).
pub(crate) fn hidden(ctx: &Ctx, ks: &[usize], at: Point, walls: &[(Point, Point)]) -> bool {
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
        // At least a quarter of the cluster radius: the vote only seeds the
        // fit, and finer cells multiply its work by the square (1 cm cells
        // with σ = 2 mm: a 28 m map's vote took seconds).
        let mut cell = tau.max(s.cell_m).max(0.25 * p.point_radius_m);
        if (w / cell) * (h / cell) > MAX_VOTE_CELLS as f64 {
            cell = (w * h / MAX_VOTE_CELLS as f64).sqrt();
        }
        let nx = ((w / cell).ceil() as usize).max(1);
        let ny = ((h / cell).ceil() as usize).max(1);
        let spec = GridSpec { x_min_m: s.x_min_m, y_min_m: s.y_min_m, cell_m: cell, nx, ny };
        // A cell centre within half a diagonal of the band: the focal excess
        // changes by at most 2 per metre.
        let slack_m = std::f64::consts::SQRT_2 * cell;
        let mut counts = crate::grid::prefaulted(nx * ny, 0u32);
        // The last measurement (+1) that voted for each cell: one vote per
        // measurement, however many of its echoes cover the cell.
        let mut stamp = crate::grid::prefaulted(nx * ny, 0u32);
        let bands: Vec<Option<(u32, Band)>> = left
            .iter()
            .map(|&k| {
                let prep = &ctx.preps[k];
                let e = &prep.ellipse;
                let half = p.band_sigmas * prep.sigma_m + slack_m;
                let mark = prep.meas as u32 + 1;
                Ok(Band::new(e.focus_a, e.focus_b, e.delta_d_m - half, e.delta_d_m + half, &spec)?.map(|b| (mark, b)))
            })
            .collect::<Result<_, crate::error::CoreError>>()
            .ok()?;
        // Bands of grid rows on rayon's threads, each walking every echo in
        // order over its rows: a cell's count and stamp see the echoes in
        // the same order whatever the split, so the same counts (the serial
        // count was 4.1 ms of a Table I 1 ms map, 2.4 ms so).
        use rayon::prelude::*;
        const BAND_ROWS: usize = 32;
        let tasks = counts.par_chunks_mut(BAND_ROWS * nx).zip(stamp.par_chunks_mut(BAND_ROWS * nx)).enumerate();
        tasks.for_each(|(t, (counts, stamp))| {
            let rows = t * BAND_ROWS..t * BAND_ROWS + counts.len() / nx;
            // (A band that misses these rows gives no spans.)
            for (mark, band) in bands.iter().flatten() {
                band.spans_in_rows(&spec, rows.clone(), |j, lo, hi| {
                    // Branch-free (the stamp test mispredicts along a
                    // band's edge): the same counts.
                    let row = (j - rows.start) * nx + lo..=(j - rows.start) * nx + hi;
                    for (s, c) in stamp[row.clone()].iter_mut().zip(&mut counts[row]) {
                        *c += u32::from(*s != *mark);
                        *s = *mark;
                    }
                });
            }
        });
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
                if is_max && !ctx.free_against(self.spec.cell_center(i, j), v as usize) {
                    seeds.push((v, j * nx + i));
                }
            }
        }
        seeds.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        seeds.into_iter().map(|(_, c)| self.spec.cell_center(c % nx, c / nx)).collect()
    }
}

/// Of each measurement, the echo of `left` (in measurement order) not
/// `used` whose band (plus `slack_m`) holds `at`, nearest to it in σ; in
/// measurement order.
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
        match best.last_mut() {
            Some(b) if b.0 == prep.meas => {
                if z < b.1 {
                    *b = (prep.meas, z, k);
                }
            }
            _ => best.push((prep.meas, z, k)),
        }
    }
    best.into_iter().map(|b| b.2).collect()
}

/// A point reflector fitted to `ks` (one echo per measurement, in
/// measurement order) from `start`. While any echo lies more than kσ off
/// the fit, the worst eighth of them (at least one, only those off, never
/// below `min_support` echoes) are dropped and the point refitted, for at
/// most [`MAX_TRIM_ROUNDS`] rounds. Once all fit, the echoes outside runs
/// ([`in_runs`]) are dropped and the point refitted, unless fewer than
/// `min_support`, or fewer than a third of them, are in runs (echoes that
/// agree by chance are scattered along the walk). `None` when the fit
/// fails, any of these refuses it, or fewer than `min_keep` echoes remain.
///
/// The echoes only ever shrink, and the echoes in runs of a subset are in
/// runs of the whole set, so a set with fewer than `max(min_support,
/// min_keep)` echoes in runs is refused before any fit, and a fit stops as
/// soon as fewer than `min_keep` are left: the same results as fitting to
/// the end and refusing afterwards (on Table I at 1 ms every one of 168
/// completed fits was then refused by the consensus, and they took two
/// thirds of this step's time).
fn trimmed_fit(ctx: &Ctx, start: Point, min_keep: usize, mut ks: Vec<usize>) -> Fitted {
    let p = ctx.params;
    let min = p.min_support as usize;
    if in_runs(ctx, &ks).len() < min.max(min_keep) {
        return None;
    }
    for _ in 0..MAX_TRIM_ROUNDS {
        if ks.len() < min_keep {
            return None;
        }
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
        ks = super::without_worst(&ks, &mut z, (ks.len() / 8).max(1).min(outliers).min(ks.len() - min));
    }
    None
}

/// The echoes of `ks` (one per measurement, in measurement order) whose
/// measurements lie in runs of at least `min_run` measurements of one
/// listener, each within [`MAX_POSE_GAP`] of the previous in that
/// listener's order: a reflector is heard from neighbouring poses, as a
/// wall is ([`super::lines`]), and a stray echo far along the walk pins a
/// fit anywhere (seen on the loop past circles: four echoes of consecutive
/// poses and one 50 poses later fitted a point 20 m from every circle). One
/// measurement may miss the echo (sparse poses of a rough reflector: Table I
/// at 50 ms). A pose that heard nothing is no measurement, so it does not
/// count as a gap.
fn in_runs(ctx: &Ctx, ks: &[usize]) -> Vec<usize> {
    let ms: Vec<usize> = ks.iter().map(|&k| ctx.preps[k].meas).collect();
    ctx.in_runs(&ms, MAX_POSE_GAP).into_iter().map(|i| ks[i]).collect()
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
            // Minus the focal excess ([`excess`], from the norms at hand).
            let r = -(na + nb - 2.0 * e.semi_major_m);
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
