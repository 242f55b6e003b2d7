//! The evidence mapper (issue 9): a second mapper beside Algorithm 1 that uses
//! what the echoes say and Algorithm 1 throws away. Design and sources in
//! `docs/evidence-mapper.md`.
//!
//! 1. **Uncertainty.** Each echo is a band of confocal ellipses Δd ± kσ
//!    ([`band`]), σ from [`Echo::sigma_m`] or [`EvidenceParams::default_sigma_m`].
//! 2. **Free space.** Within one measurement (same `t_s`, `listener_id` and positions) no
//!    reflector lies inside the first (smallest Δd) echo's ellipse: carved in
//!    log-odds, softly, as the sonar occupancy grid of Moravec and Elfes
//!    (1985) and Elfes (1989) carves a beam's "everywhere empty" region.
//! 3. **Tangency.** Walls are lines tangent to the ellipses of many
//!    consecutive poses: a Hough vote in (normal angle, offset) with the
//!    closed-form tangents of [`tangent`] (the common-tangent view of room
//!    geometry inference, Antonacci et al. 2012), refined by least squares.
//!    Compact reflectors (pillars, poles) come from the envelope of the
//!    ellipses of consecutive poses (the `envelope` module).
//! 4. **Ghosts.** A line candidate that lies mostly in carved free space, or
//!    whose tangency points lie behind a stronger line as seen from the
//!    source or listener (a corner's second-order echo draws such a virtual
//!    wall through the corner), is rejected; surfaces whose echoes come from
//!    collinear foci (a straight pass in line with the source) are flagged
//!    `ambiguous`: their mirror image across that line explains the same echoes.

pub mod band;
mod envelope;
mod lines;
mod pile;
pub mod tangent;
mod vote;

use crate::echo::Echo;
use crate::ellipse::Ellipse;
use crate::error::CoreError;
use crate::geometry::Point;
use crate::grid::{Grid, GridSpec};
use crate::mapper::{Highlight, local_maxima_above};
use serde::{Deserialize, Serialize};

use band::Band;
pub use band::{band_cells_naive, for_each_band_span};
pub use tangent::far_tangent;

/// Parameters of the evidence mapper, the `[mapping.evidence]` table of a
/// scene; every field has a default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvidenceParams {
    /// 1-σ Δd uncertainty (m) for echoes without their own `sigma_m`.
    pub default_sigma_m: f64,
    /// Half-width of an echo's band in σ (k): the band is Δd ± kσ.
    pub band_sigmas: f64,
    /// Log-odds added to a cell inside a measurement's first ellipse (< 0).
    pub free_logodds: f64,
    /// Log-odds added per echo at its reflection point once a surface
    /// explains it (> 0).
    pub hit_logodds: f64,
    /// Log-odds added along the band of an echo no surface explains (≥ 0),
    /// Gaussian in the focal excess: clutter stays faint.
    pub ring_logodds: f64,
    /// Number of normal-angle bins over the full circle of the Hough vote.
    pub angle_bins: u32,
    /// Smallest number of echoes (from runs of consecutive poses) a surface
    /// must explain.
    pub min_support: u32,
    /// A pose counts toward a surface only inside a run of at least this
    /// many consecutive poses (of one listener) tangent to it.
    pub min_run: u32,
    /// Shortest reported line segment (m); shorter tangency clusters are
    /// compact reflectors, not walls.
    pub min_line_length_m: f64,
    /// A line whose samples are more than this fraction in free space, or
    /// whose tangency points are more than this fraction hidden behind a
    /// stronger line, is a ghost.
    pub ghost_fraction: f64,
    /// Foci within this distance (m) of one straight line make a surface
    /// mirror-ambiguous.
    pub collinear_tol_m: f64,
    /// Consecutive poses are paired for the envelope once the listener has
    /// moved at least this far (m).
    pub envelope_baseline_m: f64,
    /// Cluster radius of envelope points for a compact reflector (m).
    pub point_radius_m: f64,
    /// Highlights are maxima of the map within this radius (m).
    pub peak_radius_m: f64,
    /// Cells below this log-odds are never highlights.
    pub highlight_min_logodds: f64,
    /// At most this many surfaces are reported.
    pub max_surfaces: u32,
}

impl Default for EvidenceParams {
    fn default() -> Self {
        Self {
            default_sigma_m: 0.02,
            band_sigmas: 3.0,
            free_logodds: -0.4,
            hit_logodds: 0.85,
            ring_logodds: 0.05,
            angle_bins: 360,
            min_support: 5,
            min_run: 3,
            min_line_length_m: 0.5,
            ghost_fraction: 0.5,
            collinear_tol_m: 0.05,
            envelope_baseline_m: 0.05,
            point_radius_m: 0.3,
            peak_radius_m: 0.5,
            highlight_min_logodds: 1.5,
            max_surfaces: 64,
        }
    }
}

/// Largest log-odds one deposit may add or carve (see [`EvidenceParams::validate`]).
const MAX_LOGODDS: f64 = 100.0;

impl EvidenceParams {
    /// Checks every field's range; the error names the field.
    pub fn validate(&self) -> Result<(), CoreError> {
        fn bad(field: &'static str, reason: &str) -> Result<(), CoreError> {
            Err(CoreError::InvalidParam { field, reason: reason.into() })
        }
        let pos = |v: f64| v.is_finite() && v > 0.0;
        // The same bound as an echo's own sigma_m ([`crate::echo::MAX_SIGMA_M`]).
        if !(pos(self.default_sigma_m) && self.default_sigma_m <= crate::echo::MAX_SIGMA_M) {
            return bad("evidence.default_sigma_m", "must be finite, > 0 and at most 1e6 m");
        }
        if !(self.band_sigmas.is_finite() && self.band_sigmas >= 0.5 && self.band_sigmas <= 10.0) {
            return bad("evidence.band_sigmas", "must be in [0.5, 10]");
        }
        // Log-odds of ±100 already mean probabilities within e^-100 of 0 or 1;
        // the bound keeps sums of millions of deposits finite in map.npy's f32.
        if !(self.free_logodds.is_finite() && self.free_logodds < 0.0 && self.free_logodds >= -MAX_LOGODDS) {
            return bad("evidence.free_logodds", "must be in [-100, 0)");
        }
        if !(pos(self.hit_logodds) && self.hit_logodds <= MAX_LOGODDS) {
            return bad("evidence.hit_logodds", "must be in (0, 100]");
        }
        if !(self.ring_logodds.is_finite() && (0.0..=MAX_LOGODDS).contains(&self.ring_logodds)) {
            return bad("evidence.ring_logodds", "must be in [0, 100]");
        }
        if !(8..=7200).contains(&self.angle_bins) {
            return bad("evidence.angle_bins", "must be in [8, 7200]");
        }
        if self.min_support < 2 {
            return bad("evidence.min_support", "must be >= 2");
        }
        if self.min_run < 1 {
            return bad("evidence.min_run", "must be >= 1");
        }
        if !(self.min_line_length_m.is_finite() && self.min_line_length_m >= 0.0) {
            return bad("evidence.min_line_length_m", "must be finite and >= 0");
        }
        if !(self.ghost_fraction > 0.0 && self.ghost_fraction <= 1.0) {
            return bad("evidence.ghost_fraction", "must be in (0, 1]");
        }
        for (field, v) in [
            ("evidence.collinear_tol_m", self.collinear_tol_m),
            ("evidence.envelope_baseline_m", self.envelope_baseline_m),
            ("evidence.point_radius_m", self.point_radius_m),
            ("evidence.peak_radius_m", self.peak_radius_m),
        ] {
            if !(v.is_finite() && (0.0..=1e3).contains(&v)) {
                return bad(field, "must be finite and in [0, 1000] m");
            }
        }
        if self.point_radius_m <= 0.0 {
            return bad("evidence.point_radius_m", "must be > 0");
        }
        if !self.highlight_min_logodds.is_finite() {
            return bad("evidence.highlight_min_logodds", "must be finite");
        }
        if self.max_surfaces == 0 || self.max_surfaces > 100_000 {
            return bad("evidence.max_surfaces", "must be in [1, 100000]");
        }
        Ok(())
    }
}

/// What a surface is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SurfaceKind {
    /// A straight reflector (wall): the segment `p0`–`p1` spans the observed
    /// tangency points.
    Line,
    /// A compact reflector (pillar, pole, the paper's circles): `p0` is the
    /// densest envelope point, which lies on its surface.
    Point,
}

/// One reflecting surface found by the evidence mapper.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// Whether this is a wall segment or a compact point reflector.
    pub kind: SurfaceKind,
    /// Segment start (line) or the point (point), world frame (m).
    pub p0: Point,
    /// Segment end; equal to `p0` for a point.
    pub p1: Point,
    /// Number of echoes this surface explains.
    pub support: usize,
    /// The echoes' foci are collinear, so the mirror image of this surface
    /// across their line explains the same echoes (issue 9, item 4).
    pub ambiguous: bool,
}

impl Surface {
    /// Distance (m) from `p` to the surface (segment or point).
    pub fn distance(&self, p: Point) -> f64 {
        crate::geometry::point_segment_distance(p, self.p0, self.p1)
    }
}

/// Result of [`map_evidence`].
#[derive(Debug, Clone, PartialEq)]
pub struct EvidenceMap {
    /// Final map in **log-odds of occupancy** (natural log, 0 = unknown,
    /// p = 1/(1 + e^−L)): free-space carving (< 0), plus `hit_logodds` per
    /// explained echo at its reflection point, plus faint rings of echoes no
    /// surface explains.
    pub grid: Grid,
    /// Surfaces, strongest (largest support) first.
    pub surfaces: Vec<Surface>,
    /// Local maxima of `grid` above `highlight_min_logodds` within
    /// `peak_radius_m`, in raster order: the input of the paper's scores.
    pub highlights: Vec<Highlight>,
    /// Grid cell writes (carving, rings, deposits), for benchmarks.
    pub cells_updated: u64,
}

/// One echo, prepared.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Prep {
    pub ellipse: Ellipse,
    pub sigma_m: f64,
    /// Index into the measurement list.
    pub meas: usize,
}

/// One measurement: the echoes heard by one listener at one instant.
#[derive(Debug, Clone)]
pub(crate) struct Meas {
    pub listener_id: u32,
    /// Position in this listener's time order.
    pub seq: usize,
    pub listener: Point,
    pub source: Point,
    pub echoes: Vec<usize>,
}

/// Shared inputs of the steps.
pub(crate) struct Ctx<'a> {
    pub preps: Vec<Prep>,
    pub meas: Vec<Meas>,
    pub spec: GridSpec,
    pub params: &'a EvidenceParams,
    /// Carved free-space log-odds, row-major like the grid.
    pub free: Vec<f64>,
}

impl Ctx<'_> {
    /// Free-space log-odds at `p` (0 outside the grid).
    pub fn free_at(&self, p: Point) -> f64 {
        self.spec.cell_of(p).map_or(0.0, |(i, j)| self.free[j * self.spec.nx + i])
    }
    /// How many measurements carved `p` free.
    pub fn carvings_at(&self, p: Point) -> f64 {
        (self.free_at(p) / self.params.free_logodds).round()
    }
    /// Whether `p` is free space against a surface there heard by `support`
    /// measurements: at least two measurements carved it, and more than half
    /// `support`. A measurement whose first echo was missed (its ranging
    /// reported a later one) carves through every nearer reflector, so the
    /// carvings are weighed against the echoes, as a log-odds sum would
    /// (Moravec and Elfes 1985). Counting carvings alone, 116 frames of a
    /// synthesized walk round a pillar whose pillar echo was missed carved the
    /// pillar free, and 800 echoes of it made 37 points elsewhere (session 22;
    /// lines were weighed so since session 17).
    pub fn free_against(&self, p: Point, support: usize) -> bool {
        let carvings = self.carvings_at(p);
        carvings >= 2.0 && 2.0 * carvings > support as f64
    }

    /// Positions in `ms` (measurement indices, increasing) of the
    /// measurements inside runs of at least `min_run` of one listener, each
    /// at most `max_gap` after the previous in that listener's order.
    pub fn in_runs(&self, ms: &[usize], max_gap: usize) -> Vec<usize> {
        let min_run = self.params.min_run as usize;
        let mut keep = Vec::new();
        let mut start = 0;
        for i in 1..=ms.len() {
            let breaks = i == ms.len() || {
                let (a, b) = (&self.meas[ms[i - 1]], &self.meas[ms[i]]);
                a.listener_id != b.listener_id || b.seq > a.seq + max_gap
            };
            if breaks {
                if i - start >= min_run {
                    keep.extend(start..i);
                }
                start = i;
            }
        }
        keep
    }

    /// Whether the foci of `echoes` are collinear within `collinear_tol_m`:
    /// listeners when all sources coincide, sources when all listeners do,
    /// all foci otherwise.
    pub fn collinear(&self, echoes: &[usize]) -> bool {
        !echoes.is_empty() && max_line_deviation(&self.moving_foci(echoes)) <= self.params.collinear_tol_m
    }

    /// The foci of `echoes` that move: the listeners when all sources
    /// coincide (within `collinear_tol_m`), the sources when all listeners
    /// do, all foci otherwise.
    pub fn moving_foci(&self, echoes: &[usize]) -> Vec<Point> {
        let tol = self.params.collinear_tol_m;
        let srcs: Vec<Point> = echoes.iter().map(|&k| self.preps[k].ellipse.focus_a).collect();
        let lsts: Vec<Point> = echoes.iter().map(|&k| self.preps[k].ellipse.focus_b).collect();
        if foci_spread(&srcs) <= tol {
            lsts
        } else if foci_spread(&lsts) <= tol {
            srcs
        } else {
            srcs.into_iter().chain(lsts).collect()
        }
    }

    /// The line through the foci of `echoes` (centroid, unit direction):
    /// the mirror line of an ambiguous surface. Both sources and listeners
    /// count; with all foci in one point there is none.
    pub fn foci_line(&self, echoes: &[usize]) -> Option<(Point, Point)> {
        let pts: Vec<Point> =
            echoes.iter().flat_map(|&k| [self.preps[k].ellipse.focus_a, self.preps[k].ellipse.focus_b]).collect();
        principal_axis(&pts)
    }
}

/// The mirror image of `p` across the line through `c` with unit direction `d`.
pub(crate) fn reflect_across(p: Point, (c, d): (Point, Point)) -> Point {
    let v = p - c;
    c + d * (2.0 * v.dot(d)) - v
}

/// Largest distance of a point of `ps` from the first (0 when empty).
pub(crate) fn foci_spread(ps: &[Point]) -> f64 {
    ps.first().map_or(0.0, |&p0| ps.iter().map(|p| p.dist(p0)).fold(0.0, f64::max))
}

/// Centroid and unit direction of the principal axis of `pts`.
pub(crate) fn principal_axis(pts: &[Point]) -> Option<(Point, Point)> {
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let c = pts.iter().fold(Point::new(0.0, 0.0), |a, &p| a + p) * (1.0 / n);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let d = *p - c;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    if sxx + syy <= 0.0 {
        return None;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    Some((c, Point::from_angle(angle)))
}

/// Largest distance (m) of `pts` from their principal-axis line.
pub(crate) fn max_line_deviation(pts: &[Point]) -> f64 {
    if pts.len() < 3 {
        return 0.0;
    }
    // Coincident points (no axis) lie on any line through them.
    let Some((c, dir)) = principal_axis(pts) else { return 0.0 };
    let normal = Point::new(-dir.y, dir.x);
    pts.iter().map(|p| (*p - c).dot(normal).abs()).fold(0.0, f64::max)
}

/// Adds a highlight for every surface that has none within `radius_m` (at
/// the cell of its point, or of its segment's midpoint), strongest surface
/// first. Highlights are the paper's output (its scores are computed on
/// them); when poses are sparse (Table I at 50 ms) a well-supported surface's
/// tangency points fall in different cells, no cell's log-odds reaches
/// `highlight_min_logodds`, and the map would otherwise report surfaces but
/// no highlight.
fn represent_surfaces(grid: &Grid, surfaces: &[Surface], radius_m: f64, highlights: &mut Vec<Highlight>) {
    let radius_m = radius_m.max(grid.spec.cell_m);
    for s in surfaces {
        let one = std::slice::from_ref(s);
        if highlights.iter().any(|h| crate::metrics::surface_distance(one, h.pos) <= radius_m) {
            continue;
        }
        let rep = match s.kind {
            SurfaceKind::Point => s.p0,
            SurfaceKind::Line => (s.p0 + s.p1) * 0.5,
        };
        if let Some((i, j)) = grid.spec.cell_of(rep) {
            highlights.push(Highlight { pos: grid.spec.cell_center(i, j), value: grid.data[j * grid.spec.nx + i] });
        }
    }
}

/// Maps `echoes` on the grid `spec` (issue 9): free space, surfaces (lines
/// and compact reflectors, ghosts rejected, mirror ambiguity flagged), the
/// final log-odds map and its highlights. Echoes of weight 0 are left out.
/// Errors on invalid parameters, echoes, an empty grid or a line vote
/// beyond the memory cap; never panics on input.
pub fn map_evidence(echoes: &[Echo], spec: GridSpec, params: &EvidenceParams) -> Result<EvidenceMap, CoreError> {
    params.validate()?;
    if spec.nx == 0 || spec.ny == 0 || !(spec.cell_m.is_finite() && spec.cell_m > 0.0) {
        return Err(CoreError::InvalidGrid("the evidence mapper needs a non-empty grid with cell > 0".into()));
    }
    if !(spec.x_min_m.is_finite() && spec.y_min_m.is_finite()) {
        return Err(CoreError::InvalidGrid("grid origin must be finite".into()));
    }
    // Weight 0 marks an echo kept in the file but out of the map (e.g. a
    // floor or ceiling reflection, docs/rooms.md), as it is for Algorithm 1,
    // where it adds nothing: it is neither evidence nor free space here.
    //
    // An echo repeated in one measurement (the same listener, time, foci,
    // Δd and σ: a file concatenated with itself, say) is the same ellipse
    // and the same evidence, so it is kept once: the envelope crossed every
    // copy with every copy of the next pose's, and a walk's 100 echoes
    // repeated 99 times took 34 s and gave six points beside its wall
    // (a helper's audit, session 27). Weights other than 0 do not enter
    // this mapper, so nothing is lost.
    let mut seen = std::collections::HashSet::new();
    let mut keep = |e: &Echo| {
        let at = [e.t_s, e.source.x, e.source.y, e.listener.x, e.listener.y, e.delta_d_m].map(f64::to_bits);
        let key = (e.listener_id, at, e.sigma_m.map(f64::to_bits));
        e.weight != 0.0 && seen.insert(key)
    };
    let kept: Vec<bool> = echoes.iter().map(&mut keep).collect();
    let echoes: std::borrow::Cow<'_, [Echo]> = if kept.iter().all(|k| *k) {
        echoes.into()
    } else {
        echoes.iter().zip(&kept).filter(|(_, k)| **k).map(|(e, _)| *e).collect::<Vec<_>>().into()
    };
    // The vote's offset bins follow the echoes' σ (as `prepare` reads it;
    // an invalid σ is refused there).
    let sigmas_m =
        echoes.iter().map(|e| e.sigma_m.filter(|s| s.is_finite() && *s > 0.0).unwrap_or(params.default_sigma_m));
    lines::check_vote_memory(spec, params, lines::vote_rho_bin(spec.cell_m, params, sigmas_m))?;
    let mut ctx = prepare(&echoes, spec, params)?;
    let mut cells_updated = carve_free(&mut ctx)?;

    // Walls, then compact reflectors from the echoes no wall explains.
    let lines = lines::find_lines(&ctx);
    let mut found = surfaces_from(&ctx, &lines);
    // Ambiguous lines still reported that a compact reflector of twice their
    // support explains, once their echoes are open to it: dropped, and the
    // reflectors sought again without them ([`ambiguous_lines_of_points`]).
    // (A point of twice a line's support needs twice its measurements.)
    let kept_ambiguous: Vec<bool> = lines
        .accepted
        .iter()
        .zip(&found.lines_kept)
        .map(|(l, kept)| *kept && l.surface.ambiguous && 2 * l.surface.support <= ctx.meas.len())
        .collect();
    if kept_ambiguous.iter().any(|k| *k) {
        let taken = ambiguous_lines_of_points(&ctx, &lines, &kept_ambiguous);
        if taken.iter().any(|t| *t) {
            let (dropped, kept): (Vec<_>, Vec<_>) = lines.accepted.iter().zip(&taken).partition(|(_, t)| **t);
            let without = lines::LinesResult {
                accepted: kept.into_iter().map(|(l, _)| l.clone()).collect(),
                ghost_echoes: lines.ghost_echoes.clone(),
            };
            let again = surfaces_from(&ctx, &without);
            // Kept only if the search without them does give reflectors that
            // take each dropped line's echoes: the probe's point can rest on
            // echoes the search proper skips (another ambiguous line's), and
            // a review found a pole's echoes scattered into small points, or
            // the pole moved to its mirror, when it did not.
            let mut of_line = vec![false; ctx.preps.len()];
            let confirmed = dropped.iter().all(|(l, _)| {
                of_line.fill(false);
                for &(k, _) in &l.touches {
                    of_line[k] = true;
                }
                again.surfaces.iter().any(|(s, touches)| {
                    s.kind == SurfaceKind::Point
                        && 5 * touches.iter().filter(|&&(k, _)| of_line[k]).count() >= 4 * l.touches.len()
                })
            });
            if confirmed {
                found = again;
            }
        }
    }
    let Found { surfaces, explained, ghost_echo, .. } = found;

    // Final map: carving + hits at reflection points + faint unexplained rings.
    let mut grid = Grid { spec, data: std::mem::take(&mut ctx.free) };
    for (_, touches) in &surfaces {
        for &(_, p) in touches {
            if let Some((i, j)) = spec.cell_of(p) {
                grid.data[j * spec.nx + i] += params.hit_logodds;
                cells_updated += 1;
            }
        }
    }
    if params.ring_logodds > 0.0 {
        let rings: Vec<&Prep> = ctx
            .preps
            .iter()
            .enumerate()
            .filter(|(k, _)| !explained[*k] && !ghost_echo[*k])
            .map(|(_, prep)| prep)
            .collect();
        cells_updated += deposit_rings(&mut grid, &rings, params)?;
    }

    // Maxima of the map with cells below the floor (and all cells ≤ 0) taken
    // as 0: the smallest positive f64 as the floor keeps exactly the cells > 0.
    let floor = params.highlight_min_logodds.max(f64::from_bits(1));
    let r_cells = (params.peak_radius_m / spec.cell_m + 1e-9).floor().min(1e6) as usize;
    let mut highlights = local_maxima_above(&grid, r_cells, floor, &mut Vec::new());

    let mut surfaces: Vec<Surface> = surfaces.into_iter().map(|(s, _)| s).collect();
    surfaces.sort_by_key(|s| std::cmp::Reverse(s.support));
    surfaces.truncate(params.max_surfaces as usize);
    represent_surfaces(&grid, &surfaces, params.peak_radius_m, &mut highlights);
    Ok(EvidenceMap { grid, surfaces, highlights, cells_updated })
}

/// The surfaces found from a set of lines, and what they leave.
struct Found {
    /// Lines, then compact reflectors, each with its echoes and their points.
    surfaces: Vec<(Surface, Vec<(usize, Point)>)>,
    /// Echoes some surface explains.
    explained: Vec<bool>,
    /// Echoes of ghost lines no surface explains.
    ghost_echo: Vec<bool>,
    /// Per accepted line, whether it is still a surface ([`drop_lines_of_points`]).
    lines_kept: Vec<bool>,
}

/// The lines as surfaces, then compact reflectors from the echoes no line
/// explains: the envelope's, then the vote's ([`vote`]) from the echoes left;
/// lines a reflector explains are then dropped.
fn surfaces_from(ctx: &Ctx, lines: &lines::LinesResult) -> Found {
    let mut explained = vec![false; ctx.preps.len()];
    let mut ghost_echo = vec![false; ctx.preps.len()];
    let mut surfaces: Vec<(Surface, Vec<(usize, Point)>)> = Vec::new();
    for l in &lines.accepted {
        for &(k, _) in &l.touches {
            explained[k] = true;
        }
        surfaces.push((l.surface, l.touches.clone()));
    }
    for &k in &lines.ghost_echoes {
        ghost_echo[k] = !explained[k];
    }
    let mut skip: Vec<bool> = explained.iter().zip(&ghost_echo).map(|(e, g)| *e || *g).collect();
    let max_points = (ctx.params.max_surfaces as usize).saturating_sub(surfaces.len());
    let mut models: Vec<Option<envelope::SmallCircle>> = vec![None; surfaces.len()];
    let walls = walls_of(&lines.accepted);
    let mut points = envelope::find_points(ctx, &skip, &walls, max_points);
    for p in &points {
        for &(k, _) in &p.touches {
            skip[k] = true;
        }
    }
    let voted = vote::vote_points(ctx, &skip, &walls, &points, max_points.saturating_sub(points.len()));
    points.extend(voted);
    for p in points {
        models.push(p.model);
        for &(k, _) in &p.touches {
            explained[k] = true;
        }
        surfaces.push((p.surface, p.touches));
    }
    let dropped = drop_lines_of_points(ctx, &mut surfaces, &models);
    let lines_kept = dropped[..lines.accepted.len()].iter().map(|d| !d).collect();
    Found { surfaces, explained, ghost_echo, lines_kept }
}

/// The accepted lines as the walls the point searches respect.
fn walls_of(accepted: &[lines::LineOut]) -> Vec<vote::Wall> {
    accepted
        .iter()
        .map(|l| vote::Wall {
            at: l.surface.p0,
            normal: Point::from_angle(l.theta),
            extent: lines::extended(l.surface.p0, l.surface.p1, l.theta),
            ambiguous: l.surface.ambiguous,
            support: l.surface.support,
        })
        .collect()
}

/// Whether a compact reflector (its small circle, or the point `at`
/// without one) predicts echo `k`'s Δd within the echo's band.
fn point_explains(ctx: &Ctx, model: Option<envelope::SmallCircle>, at: Point, k: usize) -> bool {
    let prep = &ctx.preps[k];
    let e = &prep.ellipse;
    let miss = match model {
        Some(model) => model.predict(e.focus_a, e.focus_b).map_or(f64::INFINITY, |(pred, _)| e.delta_d_m - pred),
        None => e.focal_excess(at),
    };
    miss.abs() <= ctx.params.band_sigmas * prep.sigma_m
}

/// Which of the `candidates` (ambiguous lines the reflectors found did not
/// explain) a compact reflector explains once their echoes are open to it:
/// the envelope is searched once more with the ambiguous lines' echoes not
/// skipped, and a line at least four fifths of whose echoes one of its
/// points explains (as in [`drop_lines_of_points`]), a point of at least
/// twice the line's support, is taken. Along a near-straight stretch of a
/// walk a pole's echoes are also those of a line on the far side (issue 9,
/// item 4); found first, such a line took the last 29 of an arc walk's 160
/// echoes off a 0.2 m pole, and the rest no longer piled up on it (the
/// pole came out as ten points, `scene_sweep` scene 246 on a grid reaching
/// the line). The support rule keeps the lines that hug Table I's 2.5–5 m
/// circles, which a small circle explains over the same stretch (taking
/// them cost `benchmark maps` F1 0.383 → 0.338 at 1 ms); candidates only,
/// since a line a reflector explains anyway is dropped without this, and
/// with all the echoes open the envelope's piles fell elsewhere (two poles
/// beside straight walks came out at their mirror points).
fn ambiguous_lines_of_points(ctx: &Ctx, lines: &lines::LinesResult, candidates: &[bool]) -> Vec<bool> {
    let mut taken = vec![false; lines.accepted.len()];
    let mut by_line = vec![false; ctx.preps.len()];
    let mut skip = vec![false; ctx.preps.len()];
    // Skipped: echoes a non-ambiguous line explains, and ghost lines' echoes
    // no accepted line explains (as for the search proper).
    for l in &lines.accepted {
        for &(k, _) in &l.touches {
            by_line[k] = true;
            skip[k] |= !l.surface.ambiguous;
        }
    }
    for &k in &lines.ghost_echoes {
        skip[k] |= !by_line[k];
    }
    let max_points = (ctx.params.max_surfaces as usize).saturating_sub(lines.accepted.len());
    let points = envelope::find_points(ctx, &skip, &walls_of(&lines.accepted), max_points);
    for ((l, t), _) in lines.accepted.iter().zip(&mut taken).zip(candidates).filter(|(_, c)| **c) {
        if l.touches.is_empty() {
            continue;
        }
        *t = points.iter().any(|p| {
            let n = l.touches.iter().filter(|&&(k, _)| point_explains(ctx, p.model, p.surface.p0, k)).count();
            5 * n >= 4 * l.touches.len() && p.surface.support >= 2 * l.surface.support
        });
    }
    taken
}

/// Removes each line at least four fifths of whose echoes a compact
/// reflector also explains (its fitted small circle's predicted Δd, or the
/// focal excess at the point without one, within the echo's band), and
/// gives the reflector those echoes. Along a straight pass a small
/// reflector's echoes are, over a stretch of the pass, also those of a line
/// on the far side (the mirror ambiguity of issue 9, item 4, with the
/// reflector's curvature below the band). Lines are sought first, so such a
/// line takes those echoes before the reflector is found from the rest; the
/// reflector is the one surface that explains them all. Seen on field B (a
/// pole) from `synth` echoes once the vote's offset bins followed σ
/// ([`lines::vote_rho_bin`]): two ambiguous lines 11 m from the pole, and
/// one beside the pole of test `pole_beside_a_straight_walk_is_one_point`.
/// A loop past circles (`benchmark maps`' loop-circles) had one such line
/// that is not ambiguous: the rule holds for any line.
fn drop_lines_of_points(
    ctx: &Ctx,
    surfaces: &mut Vec<(Surface, Vec<(usize, Point)>)>,
    models: &[Option<envelope::SmallCircle>],
) -> Vec<bool> {
    let fits = |k: usize, i: usize, at: Point| point_explains(ctx, models.get(i).copied().flatten(), at, k);
    let points: Vec<usize> = (0..surfaces.len()).filter(|&i| surfaces[i].0.kind == SurfaceKind::Point).collect();
    let mut dropped = vec![false; surfaces.len()];
    for l in 0..surfaces.len() {
        let (s, touches) = &surfaces[l];
        if s.kind != SurfaceKind::Line || touches.is_empty() {
            continue;
        }
        let owner = points.iter().find_map(|&i| {
            let taken: Vec<usize> = touches.iter().map(|&(k, _)| k).filter(|&k| fits(k, i, surfaces[i].0.p0)).collect();
            (5 * taken.len() >= 4 * touches.len()).then_some((i, taken))
        });
        let Some((i, taken)) = owner else { continue };
        dropped[l] = true;
        // The echoes it explains, one per measurement it has none of.
        let mut seen: std::collections::BTreeSet<usize> =
            surfaces[i].1.iter().map(|&(k, _)| ctx.preps[k].meas).collect();
        let point = surfaces[i].0.p0;
        for k in taken {
            if seen.insert(ctx.preps[k].meas) {
                let e = &ctx.preps[k].ellipse;
                let p = models[i].map_or(point, |m| m.specular_point(e.focus_a, e.focus_b));
                surfaces[i].1.push((k, p));
                surfaces[i].0.support += 1;
            }
        }
    }
    let mut keep = dropped.iter().map(|d| !d);
    surfaces.retain(|_| keep.next().unwrap_or(true));
    dropped
}

/// Validates echoes and groups them into measurements.
fn prepare<'a>(echoes: &[Echo], spec: GridSpec, params: &'a EvidenceParams) -> Result<Ctx<'a>, CoreError> {
    let mut preps = Vec::with_capacity(echoes.len());
    for e in echoes {
        let sigma_m = match e.sigma_m {
            Some(s) if s.is_finite() && s > 0.0 => s,
            Some(s) => {
                return Err(CoreError::InvalidParam {
                    field: "sigma",
                    reason: format!("must be finite and > 0, got {s}"),
                });
            }
            None => params.default_sigma_m,
        };
        if !e.t_s.is_finite() {
            return Err(CoreError::NotFinite { field: "t", value: e.t_s });
        }
        preps.push(Prep { ellipse: e.ellipse()?, sigma_m, meas: 0 });
    }
    // Measurements: same listener id and time, in (listener, time) order,
    // and the same listener and source positions. An echoes file without
    // `t` or `listener` columns gives every row t = 0 of listener 0, so
    // equal ids and times alone merged a whole walk, or every microphone of
    // a static array, into one measurement: one pose, no runs, and free
    // space carved from another pose's first echo (the map had no surfaces).
    // The sort is stable, so such rows keep the file's order: each change of
    // position starts the next pose.
    let mut order: Vec<usize> = (0..echoes.len()).collect();
    order.sort_by(|&a, &b| {
        echoes[a].listener_id.cmp(&echoes[b].listener_id).then(echoes[a].t_s.total_cmp(&echoes[b].t_s))
    });
    let mut meas: Vec<Meas> = Vec::new();
    for k in order {
        let e = &echoes[k];
        let same = meas.last().is_some_and(|m: &Meas| {
            let first = &echoes[m.echoes[0]];
            m.listener_id == e.listener_id && first.t_s == e.t_s && m.listener == e.listener && m.source == e.source
        });
        if !same {
            let seq = match meas.last() {
                Some(m) if m.listener_id == e.listener_id => m.seq + 1,
                _ => 0,
            };
            meas.push(Meas {
                listener_id: e.listener_id,
                seq,
                listener: e.listener,
                source: e.source,
                echoes: Vec::new(),
            });
        }
        let m = meas.len() - 1;
        meas[m].echoes.push(k);
        preps[k].meas = m;
    }
    Ok(Ctx { preps, meas, spec, params, free: crate::grid::prefaulted_zeros(spec.len()) })
}

/// Carves each measurement's first ellipse, shrunk by kσ plus a cell's
/// half-diagonal (in focal excess, ≤ 2 per metre) so that a cell is carved
/// only when all of it is inside. Row spans go into a difference array (the
/// free grid itself, summed along each row in place), so the cost is one
/// entry per row, not per cell. Returns cells carved.
///
/// Bands of grid rows go to rayon's threads, each carving every
/// measurement's rows in measurement order and then summing its rows: a
/// cell receives the same additions in the same order whatever the split,
/// so the same bits (2.9 ms of a Table I 1 ms map on one thread).
fn carve_free(ctx: &mut Ctx) -> Result<u64, CoreError> {
    use rayon::prelude::*;
    /// Grid rows per task.
    const BAND_ROWS: usize = 32;
    let spec = ctx.spec;
    let nx = spec.nx;
    let l_free = ctx.params.free_logodds;
    let mut bands: Vec<Band> = Vec::with_capacity(ctx.meas.len());
    for m in &ctx.meas {
        let Some(&first) = m
            .echoes
            .iter()
            .min_by(|&&a, &&b| ctx.preps[a].ellipse.delta_d_m.total_cmp(&ctx.preps[b].ellipse.delta_d_m))
        else {
            continue;
        };
        let p = &ctx.preps[first];
        let margin = ctx.params.band_sigmas * p.sigma_m + 2.0 * std::f64::consts::FRAC_1_SQRT_2 * spec.cell_m;
        let dd_free = p.ellipse.delta_d_m - margin;
        if dd_free <= 0.0 {
            continue;
        }
        if let Some(band) = Band::new(p.ellipse.focus_a, p.ellipse.focus_b, 0.0, dd_free, &spec)? {
            bands.push(band);
        }
    }
    if nx == 0 {
        return Ok(0);
    }
    let carved = ctx
        .free
        .par_chunks_mut(BAND_ROWS * nx)
        .enumerate()
        .map(|(t, diff)| {
            let rows = t * BAND_ROWS..t * BAND_ROWS + diff.len() / nx;
            let mut carved = 0u64;
            // (A band that misses these rows gives no spans.)
            for band in &bands {
                band.spans_in_rows(&spec, rows.clone(), |j, lo, hi| {
                    let row = (j - rows.start) * nx;
                    diff[row + lo] += l_free;
                    // The end of a span reaching the row's last cell needs no entry.
                    if hi + 1 < nx {
                        diff[row + hi + 1] -= l_free;
                    }
                    carved += (hi - lo + 1) as u64;
                });
            }
            for row in diff.chunks_exact_mut(nx) {
                let mut acc = 0.0;
                for v in row {
                    acc += *v;
                    *v = acc;
                }
            }
            carved
        })
        .sum();
    Ok(carved)
}

/// Adds the faint Gaussian ring of each unexplained echo in `rings`, in
/// order. Returns cells written.
///
/// Bands of grid rows go to rayon's threads, each adding every ring's part
/// in its rows in the rings' order: a cell receives the same additions in
/// the same order as ring after ring on one thread, so the map is
/// bit-identical whatever the thread count. On a large grid with many
/// unexplained echoes (Table I at 1 ms: 1 000 × 1 000 cells, 472 rings of
/// 1 505 echoes) this was 45 % of a `simulate`, on one core (issue 14).
fn deposit_rings(grid: &mut Grid, rings: &[&Prep], params: &EvidenceParams) -> Result<u64, CoreError> {
    use rayon::prelude::*;
    /// Grid rows per task: a band of a 1 000-column grid is 256 KB.
    const BAND_ROWS: usize = 32;
    let spec = grid.spec;
    let bands: Vec<Option<Band>> = rings
        .iter()
        .map(|prep| {
            let half = params.band_sigmas * prep.sigma_m;
            let e = &prep.ellipse;
            Band::new(e.focus_a, e.focus_b, e.delta_d_m - half, e.delta_d_m + half, &spec)
        })
        .collect::<Result<_, _>>()?;
    if spec.nx == 0 || spec.ny == 0 {
        return Ok(0);
    }
    let arch = pulp::Arch::new();
    let n = grid
        .data
        .par_chunks_mut(BAND_ROWS * spec.nx)
        .enumerate()
        .map_init(RingCells::default, |scratch, (b, cells)| {
            let rows = b * BAND_ROWS..(b * BAND_ROWS + cells.len() / spec.nx);
            let mut n = 0u64;
            for (prep, band) in rings.iter().zip(&bands) {
                let Some(band) = band else { continue };
                let (lo, hi) = band.rows();
                if hi < rows.start || lo >= rows.end {
                    continue;
                }
                scratch.gather(band, &spec, prep, rows.clone());
                scratch.weigh(arch, prep, params.ring_logodds);
                for (&k, &w) in scratch.at.iter().zip(&scratch.w) {
                    cells[k] += w;
                }
                n += scratch.at.len() as u64;
            }
            n
        })
        .sum();
    Ok(n)
}

/// One ring's cells in a band of grid rows, gathered from its spans so that
/// their weights are one long loop. Computed span by span, the weights cost
/// ~20 ns a cell on Table I at 1 ms (spans of a few cells): each short loop
/// ended in a mispredicted branch with the square roots' and the
/// polynomial's latency exposed; one loop over all of a ring's cells keeps
/// several cells in flight (issue 14).
#[derive(Debug, Default)]
struct RingCells {
    /// Index of each cell in the band's slice.
    at: Vec<usize>,
    /// Cell centre x (m).
    x: Vec<f64>,
    /// Squared y distances of the cell's row to the two foci (m²).
    dya2: Vec<f64>,
    dyb2: Vec<f64>,
    /// The cell's ring weight.
    w: Vec<f64>,
}

impl RingCells {
    /// The cells of `band` in grid rows `rows` (the first of which is the
    /// band slice's row 0), in span order.
    fn gather(&mut self, band: &Band, spec: &GridSpec, prep: &Prep, rows: std::ops::Range<usize>) {
        self.at.clear();
        self.x.clear();
        self.dya2.clear();
        self.dyb2.clear();
        let e = &prep.ellipse;
        band.spans_in_rows(spec, rows.clone(), |j, lo, hi| {
            let (dya2, dyb2) = row_focus_dy2(spec, e, j);
            let row = (j - rows.start) * spec.nx;
            let len = hi - lo + 1;
            self.at.extend(row + lo..=row + hi);
            self.x.extend((lo..=hi).map(|i| cell_centre_x(spec, i as f64)));
            self.dya2.extend(std::iter::repeat_n(dya2, len));
            self.dyb2.extend(std::iter::repeat_n(dyb2, len));
        });
    }
    /// The weights of the gathered cells.
    fn weigh(&mut self, arch: pulp::Arch, prep: &Prep, ring_logodds: f64) {
        self.w.resize(self.x.len(), 0.0);
        arch.dispatch(Weigh { cells: self, k: RingKernel::of(prep, ring_logodds) });
    }
}

/// [`RingCells::weigh`]'s loop, compiled for the widest vectors the CPU has
/// ([`pulp`]'s runtime dispatch: AVX-512 or AVX2, where the baseline x86-64
/// target has 2-lane SSE2). Each operation is IEEE-exact and none is fused
/// (Rust never contracts `a * b + c`), so the weights are the same bits on
/// every path (test `banded_rings_are_ring_after_ring` compares with the
/// baseline build's span-by-span oracle). The polynomial's dependency chain
/// bounds the loop; wider lanes share it among more cells.
struct Weigh<'a> {
    cells: &'a mut RingCells,
    k: RingKernel,
}

impl pulp::WithSimd for Weigh<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let Weigh { cells, k } = self;
        let inputs = cells.x.iter().zip(&cells.dya2).zip(&cells.dyb2);
        for (w, ((&x, &dya2), &dyb2)) in cells.w.iter_mut().zip(inputs) {
            *w = k.weight(x, dya2, dyb2);
        }
    }
}

/// Cell centre x (m) of column `i` (an integer-valued f64).
#[inline]
fn cell_centre_x(spec: &GridSpec, i: f64) -> f64 {
    spec.x_min_m + (i + 0.5) * spec.cell_m
}

/// Squared y distances (m²) from grid row `j`'s cell centres to the foci.
#[inline]
fn row_focus_dy2(spec: &GridSpec, e: &Ellipse, j: usize) -> (f64, f64) {
    let y = spec.y_min_m + (j as f64 + 0.5) * spec.cell_m;
    let (dya, dyb) = (y - e.focus_a.y, y - e.focus_b.y);
    (dya * dya, dyb * dyb)
}

/// One ring's constants: `ring_logodds · exp(−f² / 2σ²)` with `f` the cell
/// centre's focal excess. The distances to the foci are `sqrt(dx² + dy²)`,
/// not `hypot`: a libm call per distance was 14 % of a Table I 1 ms
/// `simulate` with the evidence mapper, and grid coordinates are far from
/// where `hypot`'s overflow guard matters. The results differ from
/// `Ellipse::focal_excess`'s in the last bits (test
/// `ring_weights_are_the_focal_excess_gaussian`), and so do those of
/// [`exp_nonpositive`].
struct RingKernel {
    fa_x: f64,
    fb_x: f64,
    two_a: f64,
    inv2s2: f64,
    ring_logodds: f64,
}

impl RingKernel {
    fn of(prep: &Prep, ring_logodds: f64) -> Self {
        let e = &prep.ellipse;
        RingKernel {
            fa_x: e.focus_a.x,
            fb_x: e.focus_b.x,
            two_a: 2.0 * e.semi_major_m,
            inv2s2: 1.0 / (2.0 * prep.sigma_m * prep.sigma_m),
            ring_logodds,
        }
    }
    #[inline(always)]
    fn weight(&self, x: f64, dya2: f64, dyb2: f64) -> f64 {
        let (dxa, dxb) = (x - self.fa_x, x - self.fb_x);
        let f = (dxa * dxa + dya2).sqrt() + (dxb * dxb + dyb2).sqrt() - self.two_a;
        self.ring_logodds * exp_nonpositive(-f * f * self.inv2s2)
    }
}

/// Adds the ring of `prep` to cells `lo..=hi` of grid row `j` (`row`), span
/// by span: the tests' oracle for [`deposit_rings`]' gathered cells.
#[cfg(test)]
fn add_ring_span(row: &mut [f64], spec: &GridSpec, prep: &Prep, ring_logodds: f64, j: usize, lo: usize, hi: usize) {
    let k = RingKernel::of(prep, ring_logodds);
    let (dya2, dyb2) = row_focus_dy2(spec, &prep.ellipse, j);
    for (i, cell) in row[lo..=hi].iter_mut().enumerate() {
        *cell += k.weight(cell_centre_x(spec, (lo + i) as f64), dya2, dyb2);
    }
}

/// `e^x` for `x ≤ 0`, within 3 ulp of `f64::exp` down to −700 (the worst
/// near `r = ±ln 2 / 2`, found by a review in float64 emulation); below −700
/// it returns the value at −700, 1e-304. Hand-written because libm's `exp` is a call the
/// ring loop cannot vectorise (15.5 % of a Table I 1 ms `simulate` with the
/// evidence mapper) and no maintained crate offers a portable f64 `exp` for
/// the baseline x86-64 target. Cody and Waite's reduction (1980):
/// `x = k·ln 2 + r`, `|r| ≤ ln 2 / 2`, with ln 2 split in fdlibm's two parts
/// so that `k·LN2_HI` is exact; `k` rounded by adding 1.5·2^52, which leaves it
/// in the low mantissa bits; `e^r` by its Taylor series to degree 12
/// (remainder ~2.4e-16 relative at |r| = ln 2 / 2); `2^k` built in the exponent field.
#[inline(always)]
pub(crate) fn exp_nonpositive(x: f64) -> f64 {
    const ROUND: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    // fdlibm's ln2_hi (its low 21 mantissa bits zero) and ln2_lo.
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    let x = x.max(-700.0);
    let t = x * std::f64::consts::LOG2_E + ROUND;
    let k = t - ROUND;
    // k as a two's-complement integer: t's bits minus ROUND's.
    let k_bits = t.to_bits().wrapping_sub(ROUND.to_bits());
    let r = (x - k * LN2_HI) - k * LN2_LO;
    let mut p = 1.0 / 479_001_600.0;
    for c in [
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p * r + c;
    }
    // k ∈ [−1010, 0], so k + 1023 is a normal exponent.
    p * f64::from_bits(k_bits.wrapping_add(1023) << 52)
}

/// Converts log-odds to occupancy probability.
pub fn logodds_to_probability(l: f64) -> f64 {
    1.0 / (1.0 + (-l).exp())
}

/// `ks` without its `drop` worst echoes, in order: `z` holds each echo's
/// misfit (in σ) and its index in `ks`, and is sorted here, worst first
/// (equal misfits: the earlier echo first). The trimming step of both point
/// fits ([`vote`]'s and [`envelope`]'s small circles).
pub(crate) fn without_worst(ks: &[usize], z: &mut [(f64, usize)], drop: usize) -> Vec<usize> {
    z.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut gone = vec![false; ks.len()];
    for &(_, i) in &z[..drop.min(z.len())] {
        gone[i] = true;
    }
    ks.iter().zip(&gone).filter(|(_, g)| !**g).map(|(&k, _)| k).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rings one after the other on one thread, as before issue 14's
    /// banding: the oracle of [`deposit_rings`].
    fn deposit_rings_in_turn(grid: &mut Grid, rings: &[&Prep], params: &EvidenceParams) -> Result<u64, CoreError> {
        let spec = grid.spec;
        let mut n = 0u64;
        for prep in rings {
            let e = &prep.ellipse;
            let half = params.band_sigmas * prep.sigma_m;
            for_each_band_span(e.focus_a, e.focus_b, e.delta_d_m - half, e.delta_d_m + half, &spec, |j, lo, hi| {
                let row = &mut grid.data[j * spec.nx..(j + 1) * spec.nx];
                add_ring_span(row, &spec, prep, params.ring_logodds, j, lo, hi);
                n += (hi - lo + 1) as u64;
            })?;
        }
        Ok(n)
    }

    /// The ring's `exp` against libm's (the oracle): relative error ≤ 2 ε on
    /// uniform draws from 0 down to −700 (3 ulp occurs near r = ±ln 2 / 2),
    /// the value at −700 below it, exactly 1 at 0.
    #[test]
    fn exp_nonpositive_is_libms_exp() {
        let mut r = 0x9e37_79b9_7f4a_7c15_u64;
        let mut worst = 0.0f64;
        for k in 0..200_000 {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            let u = (r >> 11) as f64 / (1u64 << 53) as f64;
            // Half the draws in the rings' range (≥ −60), half down to −700.
            let x = if k % 2 == 0 { -60.0 * u } else { -700.0 * u };
            let (got, want) = (exp_nonpositive(x), x.exp());
            worst = worst.max(((got - want) / want).abs() / f64::EPSILON);
        }
        assert!(worst <= 2.0, "worst error {worst} ulp");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert_eq!(exp_nonpositive(-0.0), 1.0);
        assert_eq!(exp_nonpositive(-800.0), exp_nonpositive(-700.0));
        assert!(exp_nonpositive(-700.0) > 0.0 && (exp_nonpositive(-700.0) / (-700.0f64).exp() - 1.0).abs() < 1e-15);
    }

    /// A ring's weights against the definition (the oracle: `focal_excess`,
    /// which measures with `hypot`, in a Gaussian) on rows crossing a ring,
    /// foci inside and outside the grid: equal to 1e-12 of the ring's peak.
    #[test]
    fn ring_weights_are_the_focal_excess_gaussian() {
        let params = EvidenceParams::default();
        let spec = GridSpec { x_min_m: -3.1, y_min_m: -2.2, cell_m: 0.05, nx: 140, ny: 90 };
        for (a, b, dd, sigma) in [((0.0, 0.0), (1.0, 0.5), 2.3, 0.02), ((-5.0, 1.0), (4.0, -3.0), 0.7, 0.1)] {
            let echo = Echo::new(Point::new(a.0, a.1), Point::new(b.0, b.1), dd, 1.0, 0.0, 0)
                .and_then(|e| e.with_sigma_m(sigma))
                .expect("echo");
            let ctx = prepare(&[echo], spec, &params).expect("prepared");
            let prep = &ctx.preps[0];
            let mut written = 0;
            for j in 0..spec.ny {
                let mut row = vec![0.0; spec.nx];
                add_ring_span(&mut row, &spec, prep, params.ring_logodds, j, 0, spec.nx - 1);
                for (i, got) in row.iter().enumerate() {
                    let f = prep.ellipse.focal_excess(spec.cell_center(i, j));
                    let want = params.ring_logodds * (-f * f / (2.0 * sigma * sigma)).exp();
                    assert!((got - want).abs() <= 1e-12 * params.ring_logodds, "cell ({i}, {j}): {got} vs {want}");
                    written += usize::from(want > 1e-3 * params.ring_logodds);
                }
            }
            assert!(written > 50, "the ring crosses the grid ({written} cells)");
        }
    }

    /// Banded ring deposits give every cell the same bits and the same count
    /// as ring after ring, on grids whose rows are not a multiple of the
    /// band, one row high, and on 1, 2 and 3 threads; rings overlap.
    #[test]
    fn banded_rings_are_ring_after_ring() {
        let params = EvidenceParams::default();
        let echoes: Vec<Echo> = (0..40)
            .map(|k| {
                let t = f64::from(k);
                let e = Echo::new(
                    Point::new(-1.0 + 0.05 * t, 0.3),
                    Point::new(2.0, -0.5 + 0.1 * t),
                    0.5 + 0.17 * t,
                    1.0,
                    0.01 * t,
                    0,
                );
                e.and_then(|e| e.with_sigma_m(0.01 + 0.002 * t)).expect("echo")
            })
            .collect();
        for (nx, ny) in [(97, 101), (120, 1), (33, 64), (1, 70)] {
            // A one-cell-wide grid is placed where the rings cross it.
            let (x_min_m, y_min_m) = (if nx == 1 { 0.5 } else { -4.03 }, if ny == 1 { 0.01 } else { -3.97 });
            let spec = GridSpec { x_min_m, y_min_m, cell_m: 0.08, nx, ny };
            let ctx = prepare(&echoes, spec, &params).expect("prepared");
            let rings: Vec<&Prep> = ctx.preps.iter().collect();
            let mut want = Grid { spec, data: (0..nx * ny).map(|k| (k % 7) as f64 * 0.25).collect() };
            let want_n = deposit_rings_in_turn(&mut want, &rings, &params).expect("oracle");
            assert!(want_n > 0, "{nx}×{ny}: no cell written");
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
                let mut got = Grid { spec, data: (0..nx * ny).map(|k| (k % 7) as f64 * 0.25).collect() };
                let got_n = pool.install(|| deposit_rings(&mut got, &rings, &params)).expect("banded");
                assert_eq!(got_n, want_n, "{nx}×{ny}, {threads} threads: cells written");
                let bits = |g: &Grid| g.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got), bits(&want), "{nx}×{ny}, {threads} threads");
            }
        }
    }

    #[test]
    fn params_default_valid_and_bad_rejected() {
        assert!(EvidenceParams::default().validate().is_ok());
        let bad = [
            EvidenceParams { default_sigma_m: 0.0, ..Default::default() },
            EvidenceParams { free_logodds: 0.1, ..Default::default() },
            EvidenceParams { angle_bins: 2, ..Default::default() },
            EvidenceParams { ghost_fraction: f64::NAN, ..Default::default() },
            EvidenceParams { point_radius_m: 0.0, ..Default::default() },
            // Deposits beyond ±100 log-odds would overflow map.npy's f32 cells.
            EvidenceParams { hit_logodds: 1e308, ..Default::default() },
            EvidenceParams { ring_logodds: 1e39, ..Default::default() },
            EvidenceParams { free_logodds: -1e308, ..Default::default() },
            // An echo's own sigma_m is refused above 1e6 m; the default too.
            EvidenceParams { default_sigma_m: 1e300, ..Default::default() },
            EvidenceParams { default_sigma_m: 1.000001e6, ..Default::default() },
        ];
        for p in bad {
            assert!(p.validate().is_err(), "{p:?}");
        }
    }

    #[test]
    fn params_parse_from_toml_with_defaults_and_reject_unknown() {
        let p: EvidenceParams = toml::from_str("default_sigma_m = 0.05").expect("valid toml");
        assert_eq!(p.default_sigma_m, 0.05);
        assert_eq!(p.angle_bins, EvidenceParams::default().angle_bins);
        assert!(toml::from_str::<EvidenceParams>("nonsense = 1").is_err());
    }

    #[test]
    fn collinearity() {
        let pts: Vec<Point> = (0..5).map(|k| Point::new(k as f64, 2.0 * k as f64 + 1.0)).collect();
        assert!(max_line_deviation(&pts) < 1e-9);
        let mut bent = pts.clone();
        bent.push(Point::new(0.0, 3.0));
        assert!(max_line_deviation(&bent) > 0.5);
    }

    /// A line vote too large for the memory cap is an error naming the
    /// field before anything is allocated (it aborted on a 30 GB allocation).
    #[test]
    fn oversized_vote_is_refused_before_allocating() {
        let spec = GridSpec::from_bounds([-1e5, -0.5, 1e5, 0.5], 0.1, u128::MAX).expect("grid");
        let params = EvidenceParams { angle_bins: 7200, ..Default::default() };
        let e = Echo::new(Point::new(0.0, 0.0), Point::new(1.0, 0.0), 0.4, 1.0, 0.0, 0).expect("echo");
        match map_evidence(&[e], spec, &params) {
            Err(CoreError::InvalidParam { field, .. }) => assert_eq!(field, "evidence.angle_bins"),
            other => panic!("expected the angle_bins error, got {:?}", other.map(|m| m.surfaces.len())),
        }
    }

    /// Echoes of weight 0 (floor and ceiling reflections, kept in the file
    /// but out of the map) change nothing, as for Algorithm 1.
    #[test]
    fn weight_zero_echoes_are_left_out() {
        let listeners = (0..40).map(|k| Point::new(-2.0 + 0.1 * f64::from(k), 3.0));
        let wall_y = -2.0;
        let mut echoes = Vec::new();
        for (k, l) in listeners.enumerate() {
            // Image source of the source (0, 0) across the wall y = -2.
            let image = Point::new(0.0, 2.0 * wall_y);
            let dd = image.dist(l) - Point::new(0.0, 0.0).dist(l);
            let t = k as f64 * 0.1;
            echoes.push(Echo::new(Point::new(0.0, 0.0), l, dd, 1.0, t, 0).expect("echo"));
            echoes.push(Echo::new(Point::new(0.0, 0.0), l, 0.5 + 0.01 * k as f64, 0.0, t, 0).expect("echo"));
        }
        let spec = GridSpec::from_bounds([-6.0, -5.0, 6.0, 6.0], 0.1, u128::MAX).expect("grid");
        let params = EvidenceParams::default();
        let with = map_evidence(&echoes, spec, &params).expect("map");
        let heard: Vec<Echo> = echoes.iter().filter(|e| e.weight > 0.0).cloned().collect();
        let without = map_evidence(&heard, spec, &params).expect("map");
        assert!(!without.surfaces.is_empty(), "the wall is found");
        assert_eq!(with.surfaces, without.surfaces);
        assert!(with.grid.data.iter().zip(&without.grid.data).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn empty_input_gives_empty_map() {
        let spec = GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 0.1, nx: 10, ny: 10 };
        let m = map_evidence(&[], spec, &EvidenceParams::default()).expect("empty is fine");
        assert!(m.surfaces.is_empty() && m.highlights.is_empty());
        let bad = GridSpec { nx: 0, ..spec };
        assert!(map_evidence(&[], bad, &EvidenceParams::default()).is_err());
    }
}
