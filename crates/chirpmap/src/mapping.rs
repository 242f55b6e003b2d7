//! Echoes → map → highlights → scores (paper Algorithm 1 and §III.A).

use crate::error::{Error, Result};
use chirpmap_core::error::Num;
use chirpmap_core::grid::DEFAULT_MEMORY_CAP_BYTES;
use chirpmap_core::metrics::{MetricParams, SurfaceMetrics, surface_metrics};
use chirpmap_core::{
    AccumulationMapper, Echo, Grid, GridSpec, Highlight, Mapper, MapperKind, MappingParams, Obstacle, Point, Surface,
    SurfaceKind, map_evidence, score_highlight, score_obstacle,
};
use serde::Serialize;
use std::collections::HashSet;

/// What to map and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapOptions {
    /// Algorithm 1's parameters (cell, thresholds, window), paper values by default.
    pub params: MappingParams,
    /// Grid bounds `[x_min, y_min, x_max, y_max]` (m); `None` covers every ellipse.
    pub bounds: Option<[f64; 4]>,
    /// Cap on the mapper's working memory (bytes); bigger grids are refused
    /// before allocating.
    pub memory_cap_bytes: u128,
}

impl Default for MapOptions {
    fn default() -> Self {
        Self { params: MappingParams::default(), bounds: None, memory_cap_bytes: DEFAULT_MEMORY_CAP_BYTES }
    }
}

/// A finished map.
#[derive(Debug, Clone)]
pub struct MapResult {
    /// The map (rows = y, row 0 at `spec.y_min_m`): accumulated ellipse
    /// weights for the paper's mapper, log-odds of occupancy for the
    /// evidence mapper.
    pub grid: Grid,
    /// Likely obstacle locations: local maxima of the map (Algorithm 1's
    /// highlights with the paper's mapper).
    pub highlights: Vec<Highlight>,
    /// Reflecting surfaces (walls as segments, compact reflectors as
    /// points), strongest first; empty with the paper's mapper, which only
    /// finds highlights.
    pub surfaces: Vec<Surface>,
    /// Cell updates made while mapping (the benchmarks' work measure).
    pub cells_updated: u64,
    /// The parameters the map was made with.
    pub params: MappingParams,
}

impl MapResult {
    /// Placement of the grid in the world.
    pub fn spec(&self) -> GridSpec {
        self.grid.spec
    }

    /// Highlight positions only (what the scores take).
    pub fn highlight_points(&self) -> Vec<Point> {
        self.highlights.iter().map(|h| h.pos).collect()
    }
}

/// The paper's two scores (§III.A); `None` when the scene has no obstacles.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Scores {
    /// How well each obstacle is described by a highlight (false negatives).
    pub score_obstacle: Option<f64>,
    /// How well each highlight describes an obstacle (false positives).
    pub score_highlight: Option<f64>,
}

/// Scores `highlights` against the true `obstacles` (paper §III.A).
pub fn score(obstacles: &[Obstacle], highlights: &[Point]) -> Scores {
    Scores {
        score_obstacle: score_obstacle(obstacles, highlights),
        score_highlight: score_highlight(obstacles, highlights),
    }
}

/// How well a map describes the true obstacles: the paper's two scores
/// (§III.A) and the surface metrics of `chirpmap_core::metrics` (precision,
/// recall and F1 within 0.1 m, Chamfer distance, per wall the offset and
/// angle of its best line).
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// The paper's scores of the highlights.
    pub scores: Scores,
    /// Surface metrics: of the surfaces (evidence mapper), or of the
    /// highlights taken as point surfaces (paper mapper), so both mappers
    /// are measured alike.
    pub surfaces: SurfaceMetrics,
}

/// Evaluates `map`, made from `echoes`, against the true `obstacles`. The
/// surface metrics count only what the measurements could hear: true
/// surface within `MetricParams::observe_radius_m` of a first-order
/// reflection point of some measurement ([`observed_points`]), and walls
/// with such a point on them. Without echoes (or when the obstacles' exact
/// reflections cannot be computed) every true surface counts.
pub fn evaluate(obstacles: &[Obstacle], map: &MapResult, echoes: &[Echo]) -> Evaluation {
    let points;
    let surfaces: &[Surface] = if map.surfaces.is_empty() {
        points = map
            .highlights
            .iter()
            .map(|h| Surface { kind: SurfaceKind::Point, p0: h.pos, p1: h.pos, support: 1, ambiguous: false })
            .collect::<Vec<_>>();
        &points
    } else {
        &map.surfaces
    };
    let params = MetricParams::default();
    Evaluation {
        scores: score(obstacles, &map.highlight_points()),
        surfaces: surface_metrics(surfaces, obstacles, observed_points(obstacles, echoes).as_deref(), &params),
    }
}

/// Where the true `obstacles` reflect the measurements of `echoes`: their
/// first-order specular points, the exact model's visible ones
/// ([`chirpmap_core::exact`], which leaves out measurements whose direct
/// sound an obstacle blocks), every reflector's even when two give the same
/// path. The measurements are thinned to one per pair of half-observation-
/// radius squares (source's, listener's) and to at most
/// [`MAX_OBSERVED_MEASUREMENTS`], evenly spaced in a fixed order; the points
/// to one per quarter-tolerance square (a long walk has a point per pose and
/// wall). A reflection point moves by about as much as the listener or the
/// source does (half as much off a wall), well inside the observation
/// radius, while the exact model's circle search costs ~0.1 ms a pose (the
/// 706 poses of a Table I 1 ms run took 80 ms). `None` with no echoes, when
/// the exact model refuses the geometry or finds no reflection at all: then
/// every true surface counts.
pub fn observed_points(obstacles: &[Obstacle], echoes: &[Echo]) -> Option<Vec<Point>> {
    use chirpmap_core::exact::{ExactOptions, ExactScene, Pose, exact_reflections};
    let metric = MetricParams::default();
    let pose_m = 0.5 * metric.observe_radius_m;
    let thin_m = 0.25 * metric.tol_m;
    let square = |p: Point, side_m: f64| ((p.x / side_m).floor() as i64, (p.y / side_m).floor() as i64);
    // The fixed order of points: x, then y.
    let xy = |p: &Point, q: &Point| p.x.total_cmp(&q.x).then(p.y.total_cmp(&q.y));
    // Measurements: one (source, listener) pair per pair of squares, the
    // first in (squares, coordinates) order.
    type Pair = ((i64, i64, i64, i64), (Point, Point));
    let mut meas: Vec<Pair> = echoes
        .iter()
        .map(|e| {
            let (s, l) = (square(e.source, pose_m), square(e.listener, pose_m));
            ((s.0, s.1, l.0, l.1), (e.source, e.listener))
        })
        .collect();
    meas.sort_by(|a, b| a.0.cmp(&b.0).then(xy(&a.1.0, &b.1.0)).then(xy(&a.1.1, &b.1.1)));
    meas.dedup_by_key(|m| m.0);
    let step = meas.len().div_ceil(MAX_OBSERVED_MEASUREMENTS).max(1);
    let mut kept: Vec<(Point, Point)> = meas.into_iter().step_by(step).map(|m| m.1).collect();
    if kept.is_empty() {
        return None;
    }
    // One call of the exact model per source.
    kept.sort_by(|a, b| xy(&a.0, &b.0));
    let scene = ExactScene::from_obstacles(obstacles);
    // No merging of equal paths (the default merges arrivals within 1 µm,
    // as one echo): a corridor walked along its centre line hears both
    // walls at once, and both were heard.
    let opts = ExactOptions { merge_tol_m: 0.0, ..ExactOptions::default() };
    let mut points: Vec<((i64, i64), Point)> = Vec::new();
    for group in kept.chunk_by(|a, b| a.0.x.to_bits() == b.0.x.to_bits() && a.0.y.to_bits() == b.0.y.to_bits()) {
        let poses: Vec<Pose> = group.iter().map(|&(_, listener)| Pose { t_s: 0.0, listener }).collect();
        let refl = exact_reflections(group[0].0, &poses, &scene, &opts).ok()?;
        for p in refl.iter().filter(|r| r.order == 1).flat_map(|r| r.bounces.iter().copied()) {
            points.push((square(p, thin_m), p));
        }
    }
    points.sort_by(|a, b| a.0.cmp(&b.0).then(xy(&a.1, &b.1)));
    points.dedup_by_key(|c| c.0);
    (!points.is_empty()).then(|| points.into_iter().map(|(_, p)| p).collect())
}

/// Measurements [`observed_points`] asks the exact model about at most
/// (each costs up to ~0.1 ms per circle): a moving source gets no thinning
/// from the listener's squares alone (60 000 echoes of distinct sources took
/// 7 s before the cap).
pub const MAX_OBSERVED_MEASUREMENTS: usize = 4096;

/// Bounds covering every ellipse and every `extra` box `(lo, hi)`, snapped
/// outward to whole cells plus one; `None` when nothing finite is covered.
pub fn covering_bounds(echoes: &[Echo], extra: &[(Point, Point)], cell_m: f64) -> Option<[f64; 4]> {
    extent(echoes, extra).map(|b| snapped(b, cell_m))
}

/// `b` snapped outward to whole cells plus one.
fn snapped(b: [f64; 4], cell_m: f64) -> [f64; 4] {
    let snap_lo = |v: f64| (v / cell_m).floor() * cell_m - cell_m;
    let snap_hi = |v: f64| (v / cell_m).ceil() * cell_m + cell_m;
    [snap_lo(b[0]), snap_lo(b[1]), snap_hi(b[2]), snap_hi(b[3])]
}

/// The box `[x_min, y_min, x_max, y_max]` of every ellipse and `extra` box;
/// `None` when nothing finite is covered.
fn extent(echoes: &[Echo], extra: &[(Point, Point)]) -> Option<[f64; 4]> {
    let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    let mut grow = |lo: Point, hi: Point| {
        b = [b[0].min(lo.x), b[1].min(lo.y), b[2].max(hi.x), b[3].max(hi.y)];
    };
    for e in echoes {
        if let Ok(el) = e.ellipse() {
            let (lo, hi) = el.bbox();
            grow(lo, hi);
        }
    }
    for &(lo, hi) in extra {
        grow(lo, hi);
    }
    b.iter().all(|v| v.is_finite()).then_some(b)
}

/// Maps `echoes` with Algorithm 1. `extra` boxes (e.g. the obstacles to be
/// drawn) widen the default bounds.
pub fn map_echoes(echoes: &[Echo], extra: &[(Point, Point)], opts: &MapOptions) -> Result<MapResult> {
    let params = opts.params;
    params.validate()?;
    if echoes.is_empty() {
        return Err(Error::Invalid("no echoes to map".into()));
    }
    // What the map covers: --bounds, or the echoes' ellipses (then snapped to cells).
    let (covered, bounds) = match opts.bounds {
        Some(b) => (b, b),
        None => {
            let e =
                extent(echoes, extra).ok_or_else(|| Error::Invalid("cannot derive bounds from the echoes".into()))?;
            (e, snapped(e, params.cell))
        }
    };
    // Bounds checked first (an inverted box is its own error).
    let spec = GridSpec::from_bounds(bounds, params.cell, opts.memory_cap_bytes)?;
    // A cell larger than half of what is covered makes a map of a few cells
    // that shows nothing (`--cell 1e300` gave 4 × 4 cells at ±2e300 m);
    // `simulate` refuses such cells for its world too.
    let side_m = (covered[2] - covered[0]).min(covered[3] - covered[1]);
    if side_m.is_nan() || side_m / 2.0 < 1e-6 {
        // Only degenerate ellipses (a listener within a hair of the source)
        // or bounds of zero width cover so little: no cell would do.
        return Err(Error::Invalid(format!(
            "the map covers only {} m across (each echo's source and listener all but coincide, or the bounds \
             have no width): give bounds",
            Num(side_m)
        )));
    }
    // With a relative tolerance: 6.1 − 5.9 is 0.19999999999999973, and a
    // cell of 0.1 m was refused as more than half of it.
    if params.cell > side_m / 2.0 * (1.0 + 1e-9) {
        return Err(Error::Invalid(format!(
            "cell {} m leaves fewer than 2 cells across the {} m the map covers: use a cell of at most {} m \
             (paper: 0.1)",
            Num(params.cell),
            Num(side_m),
            Num(side_m / 2.0)
        )));
    }
    map_on_grid(echoes, spec, params)
}

/// Maps `echoes` on a given grid (the simulator maps on its world) with
/// the mapper `params.mapper` selects.
pub fn map_on_grid(echoes: &[Echo], spec: GridSpec, params: MappingParams) -> Result<MapResult> {
    params.validate()?;
    match params.mapper {
        MapperKind::Paper => {
            let mut mapper = AccumulationMapper::new(spec, params)?;
            mapper.add_echoes(echoes)?;
            let highlights = mapper.highlights();
            let cells_updated = mapper.cells_updated();
            Ok(MapResult { grid: mapper.into_grid(), highlights, surfaces: Vec::new(), cells_updated, params })
        }
        MapperKind::Evidence => {
            let m = map_evidence(echoes, spec, &params.evidence)?;
            Ok(MapResult {
                grid: m.grid,
                highlights: m.highlights,
                surfaces: m.surfaces,
                cells_updated: m.cells_updated,
                params,
            })
        }
    }
}

/// Distinct sources (in first-seen order) and the listener positions where
/// they change, for drawing the echoes' foci. Linear in the echoes.
pub fn foci(echoes: &[Echo]) -> (Vec<Point>, Vec<Point>) {
    let mut seen: HashSet<(u64, u64)> = HashSet::new();
    let mut sources: Vec<Point> = Vec::new();
    let mut listeners: Vec<Point> = Vec::new();
    for e in echoes {
        if seen.insert((e.source.x.to_bits(), e.source.y.to_bits())) {
            sources.push(e.source);
        }
        if listeners.last() != Some(&e.listener) {
            listeners.push(e.listener);
        }
    }
    (sources, listeners)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn echo(sx: f64, lx: f64, dd: f64) -> Echo {
        Echo::new(Point::new(sx, 0.0), Point::new(lx, 0.0), dd, 1.0, 0.0, 0).expect("valid echo")
    }

    #[test]
    fn foci_keeps_first_seen_order_and_dedups() {
        let es = [echo(0.0, 1.0, 1.0), echo(5.0, 1.0, 1.0), echo(0.0, 2.0, 1.0), echo(0.0, 2.0, 2.0)];
        let (s, l) = foci(&es);
        assert_eq!(s, vec![Point::new(0.0, 0.0), Point::new(5.0, 0.0)]);
        assert_eq!(l, vec![Point::new(1.0, 0.0), Point::new(2.0, 0.0)]);
    }

    #[test]
    fn covering_bounds_contains_the_ellipse() {
        // Foci (0,0), (2,0), Δd = 2: major axis 4, so x ∈ [-1, 3], y ∈ [-√3, √3].
        let b = covering_bounds(&[echo(0.0, 2.0, 2.0)], &[], 0.1).expect("finite");
        assert!(b[0] <= -1.0 && b[2] >= 3.0 && b[1] <= -(3f64).sqrt() && b[3] >= 3f64.sqrt());
    }

    /// A cell of half the bounds' side is allowed though the side, a
    /// difference of decimals, rounds below twice the cell (6.1 − 5.9 =
    /// 0.19999999999999973); echoes whose ellipses cover nothing get a
    /// message that does not ask for a cell of "at most 0 m" (both from a
    /// helper's audit, session 27).
    #[test]
    fn cells_of_half_the_side_pass_and_degenerate_ellipses_are_named() {
        let echoes = [echo(0.0, 2.0, 2.0)];
        let at = |bounds| MapOptions { bounds: Some(bounds), ..MapOptions::default() };
        assert!(map_echoes(&echoes, &[], &at([-3.0, 5.9, 11.0, 6.1])).is_ok());
        let err = map_echoes(&echoes, &[], &at([-3.0, 5.9, 11.0, 6.09])).expect_err("0.19 m across");
        assert!(err.to_string().contains("leaves fewer than 2 cells"), "{err}");
        let hair = [Echo::new(Point::new(0.0, 0.0), Point::new(5e-324, 0.0), 0.0, 1.0, 0.0, 0).expect("valid echo")];
        let err = map_echoes(&hair, &[], &MapOptions::default()).expect_err("nothing covered");
        assert!(err.to_string().contains("covers only 0 m across"), "{err}");
    }

    #[test]
    fn empty_echoes_is_an_error() {
        assert!(map_echoes(&[], &[], &MapOptions::default()).is_err());
    }
}
