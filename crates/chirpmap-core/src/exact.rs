//! Exact echo generators: the truth the mappers are tested against, never the
//! mapper itself (issue 9).
//!
//! For a source, listener poses and reflectors (line-segment walls and
//! circles), each visible specular reflection gives its exact path-length
//! difference Δd = reflected path − |SL|:
//! - walls by the image-source method (Allen and Berkley 1979): the source's
//!   mirror image across the wall's line, the reflection point where the
//!   segment image–listener crosses the line, required to lie on the wall
//!   segment, with both legs unblocked;
//! - circles by the specular point ([`specular_point_on_circle`]);
//! - optionally second-order wall–wall reflections (images of images: the
//!   corner echoes of a room), each bounce point on its segment, every leg
//!   unblocked.
//!
//! Poses whose direct path is blocked give no echoes: Δd is measured
//! against the direct sound, and without it there is no measurement (and
//! the mapper's free-space rule, which needs it, would not hold).
//!
//! Arrivals of equal length (within `merge_tol_m`) are one echo, as a
//! receiver hears them (the two bounce orders in a right-angled corner give
//! the same path).

use crate::echo::Echo;
use crate::error::CoreError;
use crate::geometry::{Circle, Obstacle, Point, Shape, point_segment_distance, specular_point_on_circle};

/// A straight, two-sided reflecting wall from `a` to `b` (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallSegment {
    /// Wall start (m).
    pub a: Point,
    /// Wall end (m).
    pub b: Point,
}

/// Reflectors of an exact scene.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ExactScene {
    /// Straight walls (polygon edges).
    pub walls: Vec<WallSegment>,
    /// Circular reflectors.
    pub circles: Vec<Circle>,
}

impl ExactScene {
    /// Walls from the edges of every polygon, circles as they are.
    pub fn from_obstacles(obstacles: &[Obstacle]) -> Self {
        let mut s = Self::default();
        for o in obstacles {
            match &o.shape {
                Shape::Circle(c) => s.circles.push(*c),
                Shape::Polygon(p) => s.walls.extend(p.edges().map(|(a, b)| WallSegment { a, b })),
            }
        }
        s
    }
}

/// One listener pose: where and when it heard.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Time of the pose (s) from the start of the chirp.
    pub t_s: f64,
    /// Listener position at that time (m).
    pub listener: Point,
}

/// Options of [`exact_echoes`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExactOptions {
    /// Also produce second-order wall–wall reflections.
    pub second_order: bool,
    /// Arrivals whose paths differ by less than this (m) are one echo.
    pub merge_tol_m: f64,
    /// Listener id written into the echoes.
    pub listener_id: u32,
}

impl Default for ExactOptions {
    fn default() -> Self {
        Self { second_order: false, merge_tol_m: 1e-6, listener_id: 0 }
    }
}

/// An exact reflection: Δd, its order, and where it bounced.
#[derive(Debug, Clone, PartialEq)]
pub struct ExactReflection {
    /// Index of the [`Pose`] that heard this reflection.
    pub pose_index: usize,
    /// Path-length difference Δd (m): reflected path minus direct path.
    pub delta_d_m: f64,
    /// 1 (wall or circle) or 2 (wall–wall).
    pub order: u8,
    /// Bounce points, in path order.
    pub bounces: Vec<Point>,
}

const EPS: f64 = 1e-9;

fn mirror(p: Point, w: &WallSegment) -> Point {
    let d = w.b - w.a;
    let t = (p - w.a).dot(d) / d.dot(d);
    let foot = w.a + d * t;
    foot * 2.0 - p
}

/// Signed side of `p` relative to the wall's line.
fn side(p: Point, w: &WallSegment) -> f64 {
    (w.b - w.a).cross(p - w.a)
}

/// Where segment `p`–`q` crosses the wall's line, if inside both segments
/// (strictly inside `p`–`q`).
fn hit(p: Point, q: Point, w: &WallSegment) -> Option<Point> {
    let r = q - p;
    let s = w.b - w.a;
    let denom = r.cross(s);
    if denom.abs() < 1e-15 {
        return None;
    }
    let t = (w.a - p).cross(s) / denom;
    let u = (w.a - p).cross(r) / denom;
    (t > EPS && t < 1.0 - EPS && (-EPS..=1.0 + EPS).contains(&u)).then(|| p + r * t)
}

/// Whether the leg `p`–`q` is blocked by a wall (other than those in
/// `except`) or a circle.
fn blocked(p: Point, q: Point, scene: &ExactScene, except: &[usize]) -> bool {
    let len = p.dist(q);
    if len < EPS {
        return false;
    }
    for (i, w) in scene.walls.iter().enumerate() {
        if except.contains(&i) {
            continue;
        }
        let r = q - p;
        let s = w.b - w.a;
        let denom = r.cross(s);
        if denom.abs() < 1e-15 {
            continue;
        }
        let t = (w.a - p).cross(s) / denom;
        let u = (w.a - p).cross(r) / denom;
        let tol = 1e-7 / len;
        if t > tol && t < 1.0 - tol && (0.0..=1.0).contains(&u) {
            return true;
        }
    }
    scene.circles.iter().any(|c| point_segment_distance(c.center, p, q) < c.radius_m - 1e-7)
}

fn validate_point(field: &'static str, p: Point) -> Result<(), CoreError> {
    if p.is_finite() { Ok(()) } else { Err(CoreError::InvalidGeometry(format!("{field} must be finite, got {p:?}"))) }
}

/// All visible reflections for every pose, sorted by pose then Δd.
pub fn exact_reflections(
    source: Point,
    poses: &[Pose],
    scene: &ExactScene,
    opts: &ExactOptions,
) -> Result<Vec<ExactReflection>, CoreError> {
    validate_point("source", source)?;
    if !(opts.merge_tol_m.is_finite() && opts.merge_tol_m >= 0.0) {
        return Err(CoreError::InvalidParam { field: "merge_tol_m", reason: "must be finite and >= 0".into() });
    }
    for w in &scene.walls {
        validate_point("wall end", w.a)?;
        validate_point("wall end", w.b)?;
        if w.a.dist(w.b) < EPS {
            return Err(CoreError::InvalidGeometry("a wall segment has zero length".into()));
        }
    }
    let mut out = Vec::new();
    for (pi, pose) in poses.iter().enumerate() {
        let l = pose.listener;
        validate_point("listener", l)?;
        if !pose.t_s.is_finite() {
            return Err(CoreError::NotFinite { field: "t", value: pose.t_s });
        }
        let direct = source.dist(l);
        // Δd is measured against the direct sound: where a reflector blocks
        // it there is no reference, and no measurement.
        if blocked(source, l, scene, &[]) {
            continue;
        }
        let mut found: Vec<ExactReflection> = Vec::new();
        for (i, w) in scene.walls.iter().enumerate() {
            let (ss, sl) = (side(source, w), side(l, w));
            if ss * sl <= 0.0 {
                continue;
            }
            let img = mirror(source, w);
            let Some(p) = hit(l, img, w) else { continue };
            if blocked(source, p, scene, &[i]) || blocked(p, l, scene, &[i]) {
                continue;
            }
            found.push(ExactReflection { pose_index: pi, delta_d_m: img.dist(l) - direct, order: 1, bounces: vec![p] });
        }
        for c in &scene.circles {
            if let Some(p) = specular_point_on_circle(source, l, c) {
                if blocked(source, p, scene, &[]) || blocked(p, l, scene, &[]) {
                    continue;
                }
                found.push(ExactReflection {
                    pose_index: pi,
                    delta_d_m: p.dist(source) + p.dist(l) - direct,
                    order: 1,
                    bounces: vec![p],
                });
            }
        }
        if opts.second_order {
            for (i, w1) in scene.walls.iter().enumerate() {
                if side(source, w1) == 0.0 {
                    continue;
                }
                let img1 = mirror(source, w1);
                for (j, w2) in scene.walls.iter().enumerate() {
                    if i == j {
                        continue;
                    }
                    // The listener must see w2 from the side img1 is on.
                    if side(img1, w2) * side(l, w2) <= 0.0 {
                        continue;
                    }
                    let img2 = mirror(img1, w2);
                    let Some(p2) = hit(l, img2, w2) else { continue };
                    let Some(p1) = hit(p2, img1, w1) else { continue };
                    // Real bounces: the source and p2 on the same side of w1.
                    if side(source, w1) * side(p2, w1) <= 0.0 {
                        continue;
                    }
                    if blocked(source, p1, scene, &[i])
                        || blocked(p1, p2, scene, &[i, j])
                        || blocked(p2, l, scene, &[j])
                    {
                        continue;
                    }
                    found.push(ExactReflection {
                        pose_index: pi,
                        delta_d_m: img2.dist(l) - direct,
                        order: 2,
                        bounces: vec![p1, p2],
                    });
                }
            }
        }
        found.sort_by(|a, b| a.delta_d_m.total_cmp(&b.delta_d_m));
        let mut merged: Vec<ExactReflection> = Vec::new();
        for r in found {
            // Strictly less, as documented: a tolerance of 0 merges nothing.
            if merged.last().is_some_and(|m| r.delta_d_m - m.delta_d_m < opts.merge_tol_m) {
                continue;
            }
            merged.push(r);
        }
        out.extend(merged);
    }
    Ok(out)
}

/// [`exact_reflections`] as echoes (weight 1, no σ), ready for a mapper.
pub fn exact_echoes(
    source: Point,
    poses: &[Pose],
    scene: &ExactScene,
    opts: &ExactOptions,
) -> Result<Vec<Echo>, CoreError> {
    exact_reflections(source, poses, scene, opts)?
        .iter()
        .map(|r| {
            let pose = &poses[r.pose_index];
            Echo::new(source, pose.listener, r.delta_d_m, 1.0, pose.t_s, opts.listener_id)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall(ax: f64, ay: f64, bx: f64, by: f64) -> WallSegment {
        WallSegment { a: Point::new(ax, ay), b: Point::new(bx, by) }
    }

    #[test]
    fn single_wall_by_hand() {
        // Source (0,0), listener (4,0), wall y = 3: image (0,6), path |(0,6)-(4,0)| = sqrt(52).
        let scene = ExactScene { walls: vec![wall(-10.0, 3.0, 10.0, 3.0)], circles: vec![] };
        let poses = [Pose { t_s: 0.0, listener: Point::new(4.0, 0.0) }];
        let r = exact_reflections(Point::new(0.0, 0.0), &poses, &scene, &ExactOptions::default()).expect("valid");
        assert_eq!(r.len(), 1);
        assert!((r[0].delta_d_m - (52f64.sqrt() - 4.0)).abs() < 1e-12);
        assert!((r[0].bounces[0].x - 2.0).abs() < 1e-12 && (r[0].bounces[0].y - 3.0).abs() < 1e-12);
        // A short wall that misses the reflection point reflects nothing.
        let short = ExactScene { walls: vec![wall(5.0, 3.0, 10.0, 3.0)], circles: vec![] };
        assert!(
            exact_reflections(Point::new(0.0, 0.0), &poses, &short, &ExactOptions::default()).expect("ok").is_empty()
        );
        // A blocking wall between hides it.
        let blocked =
            ExactScene { walls: vec![wall(-10.0, 3.0, 10.0, 3.0), wall(-10.0, 1.0, 10.0, 1.0)], circles: vec![] };
        let r = exact_reflections(Point::new(0.0, 0.0), &poses, &blocked, &ExactOptions::default()).expect("ok");
        assert_eq!(r.len(), 1, "only the near wall: {r:?}");
        assert!((r[0].delta_d_m - (20f64.sqrt() - 4.0)).abs() < 1e-12);
        // A circle on the direct path: no reference, no echoes at all.
        let c = Circle::new(Point::new(2.0, 0.0), 0.5).expect("valid");
        let shadowed = ExactScene { walls: vec![wall(-10.0, 3.0, 10.0, 3.0)], circles: vec![c] };
        assert!(
            exact_reflections(Point::new(0.0, 0.0), &poses, &shadowed, &ExactOptions::default())
                .expect("ok")
                .is_empty()
        );
    }

    #[test]
    fn corner_second_order_is_the_point_image() {
        // Corner at the origin, walls along +x and +y; source (1,2), listener (3,1).
        let scene = ExactScene { walls: vec![wall(0.0, 0.0, 10.0, 0.0), wall(0.0, 0.0, 0.0, 10.0)], circles: vec![] };
        let (s, l) = (Point::new(1.0, 2.0), Point::new(3.0, 1.0));
        let poses = [Pose { t_s: 0.0, listener: l }];
        let opts = ExactOptions { second_order: true, ..ExactOptions::default() };
        let r = exact_reflections(s, &poses, &scene, &opts).expect("valid");
        let second: Vec<_> = r.iter().filter(|r| r.order == 2).collect();
        assert_eq!(second.len(), 1, "{r:?}");
        let expected = Point::new(-1.0, -2.0).dist(l) - s.dist(l);
        assert!((second[0].delta_d_m - expected).abs() < 1e-12);
        assert_eq!(r.iter().filter(|r| r.order == 1).count(), 2);
    }

    #[test]
    fn circle_reflection_matches_specular_point() {
        let c = Circle::new(Point::new(0.0, 5.0), 1.0).expect("valid");
        let scene = ExactScene { walls: vec![], circles: vec![c] };
        let poses = [Pose { t_s: 0.0, listener: Point::new(2.0, 0.0) }];
        let r = exact_reflections(Point::new(-2.0, 0.0), &poses, &scene, &ExactOptions::default()).expect("ok");
        assert_eq!(r.len(), 1);
        // Symmetric: bounce at (0, 4), path 2·sqrt(4 + 16).
        assert!((r[0].delta_d_m - (2.0 * 20f64.sqrt() - 4.0)).abs() < 1e-9);
    }

    #[test]
    fn bad_input_is_an_error() {
        let scene = ExactScene { walls: vec![wall(0.0, 0.0, 0.0, 0.0)], circles: vec![] };
        let poses = [Pose { t_s: 0.0, listener: Point::new(2.0, 0.0) }];
        assert!(exact_reflections(Point::new(0.0, 1.0), &poses, &scene, &ExactOptions::default()).is_err());
        let ok = ExactScene::default();
        assert!(exact_reflections(Point::new(f64::NAN, 1.0), &poses, &ok, &ExactOptions::default()).is_err());
    }
}
