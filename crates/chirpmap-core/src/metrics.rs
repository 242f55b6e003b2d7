//! Surface metrics beyond the paper's two scores (issue 9): precision,
//! recall and F1 of reported surfaces within a tolerance, symmetric Chamfer
//! distance, and per true wall the offset and angle error of its best line.
//!
//! Definitions (all distances in metres):
//! - Reported surfaces are sampled every `sample_m` along each line segment
//!   (both ends included); a point surface is one sample. True boundaries
//!   (circle circumferences, polygon edges) are sampled the same way.
//! - Precision: fraction of reported samples within `tol_m` of a true surface.
//! - Recall: fraction of *observable* true samples within `tol_m` of a
//!   reported sample. With `observed` points given (e.g. the true bounce
//!   points of [`crate::exact::exact_reflections`]), a true sample is
//!   observable when it lies within `observe_radius_m` of one of them;
//!   without, every true sample counts. Unheard parts of a wall cannot be
//!   mapped by any mapper, so they are left out rather than counted missed.
//! - F1: harmonic mean of the two (0 when both are 0).
//! - Chamfer: ½ (mean over reported samples of the distance to the truth +
//!   mean over observable true samples of the distance to the nearest
//!   reported sample); `None` when either side is empty.
//! - Walls: every polygon edge at least `min_wall_m` long and, with
//!   `observed` points given, heard: an observed point lies on the edge
//!   (within [`ON_WALL_M`]) strictly between its ends, as a true bounce
//!   point does (a wall's back face or the unlit side of a corridor is no
//!   wall any mapper could match, while a line matched to the face in front
//!   of it would be counted against it at the wall's thickness; a bounce at
//!   a corner hears neither wall). Its best line is
//!   the reported line within `max_angle_deg` whose midpoint projects onto the
//!   edge (± `tol_m`) with the smallest offset; offset = distance of that
//!   midpoint from the edge's infinite line, angle = angle between the
//!   directions (0–90°).

use crate::evidence::{Surface, SurfaceKind};
use crate::geometry::{Obstacle, Point, Shape, point_segment_distance};

/// How far (m) an observed point may lie from a polygon edge and still be
/// a bounce on it: rounding of computed bounce points, far below any
/// tolerance of the metrics.
pub const ON_WALL_M: f64 = 1e-6;

/// Parameters of [`surface_metrics`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MetricParams {
    /// Distance (m) within which a sample counts as matched.
    pub tol_m: f64,
    /// Spacing (m) of the samples along lines and true boundaries.
    pub sample_m: f64,
    /// Radius (m) around observed points within which a true sample is observable.
    pub observe_radius_m: f64,
    /// Shortest polygon edge (m) scored as a wall.
    pub min_wall_m: f64,
    /// Largest angle (°) between a wall and a line matched to it.
    pub max_angle_deg: f64,
}

impl Default for MetricParams {
    fn default() -> Self {
        Self { tol_m: 0.1, sample_m: 0.05, observe_radius_m: 0.5, min_wall_m: 0.5, max_angle_deg: 10.0 }
    }
}

/// How well the best reported line matches one true wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallMatch {
    /// Wall start (m).
    pub a: Point,
    /// Wall end (m).
    pub b: Point,
    /// `None` when no reported line matches.
    pub offset_m: Option<f64>,
    /// Angle (°, 0–90) between the wall and its best line; `None` when no line matches.
    pub angle_deg: Option<f64>,
}

/// Result of [`surface_metrics`].
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceMetrics {
    /// Fraction of reported samples within `tol_m` of a true surface.
    pub precision: f64,
    /// Fraction of observable true samples within `tol_m` of a reported sample.
    pub recall: f64,
    /// Harmonic mean of precision and recall (0 when both are 0).
    pub f1: f64,
    /// Symmetric Chamfer distance (m); `None` when either side is empty.
    pub chamfer_m: Option<f64>,
    /// Per true wall, the match of its best line.
    pub walls: Vec<WallMatch>,
}

fn sample_segment(a: Point, b: Point, step: f64, out: &mut Vec<Point>) {
    let n = ((a.dist(b) / step).ceil() as usize).clamp(1, 1_000_000);
    out.extend((0..=n).map(|k| a + (b - a) * (k as f64 / n as f64)));
}

/// Samples of the reported surfaces.
pub fn sample_surfaces(surfaces: &[Surface], step_m: f64) -> Vec<Point> {
    let mut out = Vec::new();
    for s in surfaces {
        match s.kind {
            SurfaceKind::Point => out.push(s.p0),
            SurfaceKind::Line => sample_segment(s.p0, s.p1, step_m, &mut out),
        }
    }
    out
}

/// Samples of the true boundaries.
pub fn sample_truth(truth: &[Obstacle], step_m: f64) -> Vec<Point> {
    let mut out = Vec::new();
    for o in truth {
        match &o.shape {
            Shape::Circle(c) => {
                let n = ((std::f64::consts::TAU * c.radius_m / step_m).ceil() as usize).clamp(8, 1_000_000);
                out.extend(
                    (0..n).map(|k| {
                        c.center + Point::from_angle(k as f64 * std::f64::consts::TAU / n as f64) * c.radius_m
                    }),
                );
            }
            Shape::Polygon(p) => {
                for (a, b) in p.edges() {
                    sample_segment(a, b, step_m, &mut out);
                }
            }
        }
    }
    out
}

/// Distance from `p` to the nearest true surface (∞ with no obstacles).
pub fn truth_distance(truth: &[Obstacle], p: Point) -> f64 {
    truth.iter().map(|o| o.surface_distance(p)).fold(f64::INFINITY, f64::min)
}

fn nearest(points: &[Point], p: Point) -> f64 {
    points.iter().map(|q| q.dist(p)).fold(f64::INFINITY, f64::min)
}

/// The metrics defined in the module documentation. Non-finite or
/// non-positive parameters give empty results rather than a panic.
pub fn surface_metrics(
    surfaces: &[Surface],
    truth: &[Obstacle],
    observed: Option<&[Point]>,
    params: &MetricParams,
) -> SurfaceMetrics {
    let step = if params.sample_m.is_finite() && params.sample_m > 0.0 { params.sample_m } else { 0.05 };
    let rep = sample_surfaces(surfaces, step);
    let mut tru = sample_truth(truth, step);
    if let Some(obs) = observed {
        tru.retain(|&t| nearest(obs, t) <= params.observe_radius_m);
    }
    let d_rep: Vec<f64> = rep.iter().map(|&p| truth_distance(truth, p)).collect();
    let d_tru: Vec<f64> = tru.iter().map(|&t| nearest(&rep, t)).collect();
    let frac = |d: &[f64]| {
        if d.is_empty() { 0.0 } else { d.iter().filter(|&&x| x <= params.tol_m).count() as f64 / d.len() as f64 }
    };
    let (precision, recall) = (frac(&d_rep), frac(&d_tru));
    let f1 = if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };
    let mean = |d: &[f64]| d.iter().sum::<f64>() / d.len() as f64;
    let chamfer_m = (!d_rep.is_empty() && !d_tru.is_empty()).then(|| 0.5 * (mean(&d_rep) + mean(&d_tru)));
    let lines: Vec<&Surface> = surfaces.iter().filter(|s| s.kind == SurfaceKind::Line).collect();
    let mut walls = Vec::new();
    for o in truth {
        let Shape::Polygon(poly) = &o.shape else { continue };
        for (a, b) in poly.edges() {
            let len = a.dist(b);
            if len < params.min_wall_m {
                continue;
            }
            let dir = (b - a) * (1.0 / len);
            let normal = Point::new(-dir.y, dir.x);
            let heard = |o: &Point| {
                let along = (*o - a).dot(dir);
                (*o - a).dot(normal).abs() <= ON_WALL_M && along > ON_WALL_M && along < len - ON_WALL_M
            };
            if observed.is_some_and(|obs| !obs.iter().any(heard)) {
                continue;
            }
            let best = lines
                .iter()
                .filter_map(|s| {
                    let ld = s.p1 - s.p0;
                    if ld.norm() == 0.0 {
                        return None;
                    }
                    let cosang = (ld.normalized().dot(dir)).abs().min(1.0);
                    let angle_deg = cosang.acos().to_degrees();
                    let mid = (s.p0 + s.p1) * 0.5;
                    let along = (mid - a).dot(dir);
                    let fits =
                        angle_deg <= params.max_angle_deg && along >= -params.tol_m && along <= len + params.tol_m;
                    fits.then(|| ((mid - a).dot(normal).abs(), angle_deg))
                })
                .min_by(|x, y| x.0.total_cmp(&y.0));
            walls.push(WallMatch { a, b, offset_m: best.map(|x| x.0), angle_deg: best.map(|x| x.1) });
        }
    }
    SurfaceMetrics { precision, recall, f1, chamfer_m, walls }
}

/// Distance from `p` to the nearest reported surface (∞ with none).
pub fn surface_distance(surfaces: &[Surface], p: Point) -> f64 {
    surfaces.iter().map(|s| point_segment_distance(p, s.p0, s.p1)).fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Circle, Polygon};

    fn square() -> Obstacle {
        let v = vec![Point::new(0.0, 0.0), Point::new(4.0, 0.0), Point::new(4.0, 3.0), Point::new(0.0, 3.0)];
        Obstacle { shape: Shape::Polygon(Polygon::new(v).expect("valid")), roughness: 0.0, absorption: 0.0 }
    }

    fn line(x0: f64, y0: f64, x1: f64, y1: f64) -> Surface {
        Surface {
            kind: SurfaceKind::Line,
            p0: Point::new(x0, y0),
            p1: Point::new(x1, y1),
            support: 1,
            ambiguous: false,
        }
    }

    #[test]
    fn perfect_surfaces_score_one() {
        let s =
            [line(0.0, 0.0, 4.0, 0.0), line(4.0, 0.0, 4.0, 3.0), line(4.0, 3.0, 0.0, 3.0), line(0.0, 3.0, 0.0, 0.0)];
        let m = surface_metrics(&s, &[square()], None, &MetricParams::default());
        assert_eq!((m.precision, m.recall, m.f1), (1.0, 1.0, 1.0));
        assert!(m.chamfer_m.expect("both sides") < 1e-9);
        assert_eq!(m.walls.len(), 4);
        assert!(m.walls.iter().all(|w| w.offset_m == Some(0.0) && w.angle_deg.is_some_and(|a| a < 1e-6)));
    }

    #[test]
    fn hand_computed_partial_match() {
        // One wall offset by 4 cm; a ghost 1 m away.
        let s = [line(0.0, 0.04, 4.0, 0.04), line(1.0, 1.0, 3.0, 1.0)];
        let m = surface_metrics(&s, &[square()], None, &MetricParams::default());
        // True samples at 5 cm: edges of 4, 3, 4, 3 m give 81 + 61 + 81 + 61 = 284.
        // Within 0.1 of the line y = 0.04: the 81 bottom ones, and on each side
        // edge y = 0, 0.05, 0.10 (0.04, 0.01, 0.06 away; y = 0.15 is 0.11 away).
        let expected_recall = (81.0 + 3.0 + 3.0) / 284.0;
        assert!((m.recall - expected_recall).abs() < 1e-9, "{}", m.recall);
        // Precision: the line's 81 samples of 81 + 41.
        assert!((m.precision - 81.0 / 122.0).abs() < 1e-9, "{}", m.precision);
        let bottom = m.walls[0];
        assert!((bottom.offset_m.expect("matched") - 0.04).abs() < 1e-9);
        // Observed: only the bottom wall was heard, so recall counts only it.
        let obs: Vec<Point> = (0..9).map(|k| Point::new(0.5 * k as f64, 0.0)).collect();
        let m = surface_metrics(&s, &[square()], Some(&obs), &MetricParams::default());
        // Observable: the 81 bottom samples and 11 per side edge (y ≤ 0.5); 87 recalled.
        assert!((m.recall - 87.0 / 103.0).abs() < 1e-9, "{}", m.recall);
        // Only the bottom wall was heard (its corners' bounces, (0, 0) and
        // (4, 0), do not make the side walls heard), so only it is scored.
        assert_eq!(m.walls.len(), 1);
        assert_eq!((m.walls[0].a, m.walls[0].b), (Point::new(0.0, 0.0), Point::new(4.0, 0.0)));
        assert!((m.walls[0].offset_m.expect("matched") - 0.04).abs() < 1e-9);
        let c = Obstacle {
            shape: Shape::Circle(Circle::new(Point::new(10.0, 10.0), 1.0).expect("ok")),
            roughness: 0.0,
            absorption: 0.0,
        };
        let pt = Surface {
            kind: SurfaceKind::Point,
            p0: Point::new(11.0, 10.0),
            p1: Point::new(11.0, 10.0),
            support: 1,
            ambiguous: false,
        };
        assert_eq!(surface_metrics(&[pt], &[c], None, &MetricParams::default()).precision, 1.0);
    }
}
