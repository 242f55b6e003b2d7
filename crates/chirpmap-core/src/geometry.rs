//! Planar geometry: points, circles, polygons, rays and their intersections.
//! Frames: everything is in the world frame, metres.

use crate::error::CoreError;
use serde::{Deserialize, Serialize};

/// A point or vector in the world frame (m).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
}

impl Point {
    /// Point from its coordinates (m).
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }
    /// Euclidean distance to `o` (m).
    pub fn dist(self, o: Point) -> f64 {
        (self.x - o.x).hypot(self.y - o.y)
    }
    /// Length of the vector (m).
    pub fn norm(self) -> f64 {
        self.x.hypot(self.y)
    }
    /// Dot product.
    pub fn dot(self, o: Point) -> f64 {
        self.x * o.x + self.y * o.y
    }
    /// z component of the 2D cross product.
    pub fn cross(self, o: Point) -> f64 {
        self.x * o.y - self.y * o.x
    }
    /// True when both coordinates are finite.
    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite()
    }
    /// Unit vector at `angle_rad` from +x.
    pub fn from_angle(angle_rad: f64) -> Self {
        let (s, c) = angle_rad.sin_cos();
        Self::new(c, s)
    }
    /// Unit vector in the same direction; NaN for the zero vector.
    pub fn normalized(self) -> Self {
        let n = self.norm();
        Self::new(self.x / n, self.y / n)
    }
}

/// `(x, y)` with the numbers as a person writes them ([`crate::error::Num`]),
/// for error messages: never `Point { x: NaN, .. }` or 300-digit decimals.
impl std::fmt::Display for Point {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use crate::error::Num;
        write!(f, "({}, {})", Num(self.x), Num(self.y))
    }
}

/// Largest |coordinate| (m) a user may give for a position: a million metres
/// is already far beyond any scene of the paper (100 m worlds) and keeps every
/// squared distance far from overflow (issue 8, item 16).
pub const MAX_COORD_M: f64 = 1e6;

impl Point {
    /// Whether both coordinates are finite and within ±[`MAX_COORD_M`].
    pub fn is_sane(self) -> bool {
        self.is_finite() && self.x.abs() <= MAX_COORD_M && self.y.abs() <= MAX_COORD_M
    }
}

impl std::ops::Add for Point {
    type Output = Point;
    fn add(self, o: Point) -> Point {
        Point::new(self.x + o.x, self.y + o.y)
    }
}
impl std::ops::Sub for Point {
    type Output = Point;
    fn sub(self, o: Point) -> Point {
        Point::new(self.x - o.x, self.y - o.y)
    }
}
impl std::ops::Mul<f64> for Point {
    type Output = Point;
    fn mul(self, k: f64) -> Point {
        Point::new(self.x * k, self.y * k)
    }
}
impl std::ops::Neg for Point {
    type Output = Point;
    fn neg(self) -> Point {
        Point::new(-self.x, -self.y)
    }
}

/// A ray `origin + t·dir`, `t ≥ 0`; `dir` need not be unit length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Start of the ray (m).
    pub origin: Point,
    /// Direction; need not be unit length.
    pub dir: Point,
}

/// Where a ray meets a surface: the ray parameter, the point, and the outward
/// unit normal of the surface there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter: the hit is at `origin + t·dir`.
    pub t: f64,
    /// Hit point (m).
    pub point: Point,
    /// Outward unit normal of the surface at the hit.
    pub normal: Point,
}

/// A circle (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    /// Centre (m).
    pub center: Point,
    /// Radius (m), > 0.
    pub radius_m: f64,
}

impl Circle {
    /// Circle from centre and radius; errors unless both are finite and the
    /// radius is > 0.
    pub fn new(center: Point, radius_m: f64) -> Result<Self, CoreError> {
        if !center.is_finite() || !radius_m.is_finite() || radius_m <= 0.0 {
            return Err(CoreError::InvalidGeometry(format!(
                "circle needs a finite centre and radius > 0, got centre {center} radius {}",
                crate::error::Num(radius_m)
            )));
        }
        Ok(Self { center, radius_m })
    }
}

/// A simple polygon (vertices in order, either winding, implicitly closed).
#[derive(Debug, Clone, PartialEq)]
pub struct Polygon {
    vertices: Vec<Point>,
}

impl Polygon {
    /// Polygon from its vertices; errors with fewer than 3, any non-finite
    /// vertex, or zero area.
    pub fn new(vertices: Vec<Point>) -> Result<Self, CoreError> {
        if vertices.len() < 3 {
            return Err(CoreError::InvalidGeometry(format!(
                "polygon needs at least 3 vertices, got {}",
                vertices.len()
            )));
        }
        if let Some(p) = vertices.iter().find(|p| !p.is_finite()) {
            return Err(CoreError::InvalidGeometry(format!("polygon vertex {p} is not finite")));
        }
        let poly = Self { vertices };
        if poly.signed_area().abs() < 1e-12 {
            return Err(CoreError::InvalidGeometry("polygon has zero area".into()));
        }
        Ok(poly)
    }
    /// The vertices in the order given.
    pub fn vertices(&self) -> &[Point] {
        &self.vertices
    }
    /// Edges `(v[i], v[i+1])`, including the closing edge back to the first vertex.
    pub fn edges(&self) -> impl Iterator<Item = (Point, Point)> + '_ {
        let n = self.vertices.len();
        (0..n).map(move |i| (self.vertices[i], self.vertices[(i + 1) % n]))
    }
    /// Signed area (m², shoelace formula): positive for counter-clockwise winding.
    pub fn signed_area(&self) -> f64 {
        0.5 * self.edges().map(|(a, b)| a.cross(b)).sum::<f64>()
    }
    /// Even–odd point-in-polygon test.
    pub fn contains(&self, p: Point) -> bool {
        let mut inside = false;
        for (a, b) in self.edges() {
            if (a.y > p.y) != (b.y > p.y) {
                let x_cross = a.x + (p.y - a.y) * (b.x - a.x) / (b.y - a.y);
                if p.x < x_cross {
                    inside = !inside;
                }
            }
        }
        inside
    }
}

/// Distance from `p` to the segment `a`–`b`.
pub fn point_segment_distance(p: Point, a: Point, b: Point) -> f64 {
    let ab = b - a;
    let len2 = ab.dot(ab);
    let t = if len2 > 0.0 { ((p - a).dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
    p.dist(a + ab * t)
}

/// Shape of an obstacle.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A circular obstacle (the paper's random obstacles).
    Circle(Circle),
    /// A polygonal obstacle (walls, rooms).
    Polygon(Polygon),
}

impl Shape {
    /// Unsigned distance from `p` to the surface (boundary) of the shape:
    /// the score of §III.A measures how far a highlight is from the surface,
    /// inside or outside.
    pub fn surface_distance(&self, p: Point) -> f64 {
        match self {
            Shape::Circle(c) => (p.dist(c.center) - c.radius_m).abs(),
            Shape::Polygon(poly) => {
                poly.edges().map(|(a, b)| point_segment_distance(p, a, b)).fold(f64::INFINITY, f64::min)
            }
        }
    }

    /// True when `p` lies inside the shape (circles include their boundary;
    /// polygons use the even–odd test).
    pub fn contains(&self, p: Point) -> bool {
        match self {
            Shape::Circle(c) => p.dist(c.center) <= c.radius_m,
            Shape::Polygon(poly) => poly.contains(p),
        }
    }

    /// First intersection of `ray` with the shape's boundary at `t > t_min`,
    /// with the outward normal. Rays starting inside hit the boundary from within.
    pub fn intersect(&self, ray: &Ray, t_min: f64) -> Option<Hit> {
        match self {
            Shape::Circle(c) => {
                let oc = ray.origin - c.center;
                let a = ray.dir.dot(ray.dir);
                let b = oc.dot(ray.dir);
                let cc = oc.dot(oc) - c.radius_m * c.radius_m;
                let disc = b * b - a * cc;
                if disc < 0.0 || a == 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                // Numerically stable pair of roots.
                let q = -b - sq.copysign(b);
                let (r1, r2) = if q != 0.0 { (q / a, cc / q) } else { (0.0, 0.0) };
                let (t0, t1) = if r1 < r2 { (r1, r2) } else { (r2, r1) };
                let t = if t0 > t_min {
                    t0
                } else if t1 > t_min {
                    t1
                } else {
                    return None;
                };
                let point = ray.origin + ray.dir * t;
                Some(Hit { t, point, normal: (point - c.center).normalized() })
            }
            Shape::Polygon(poly) => {
                let ccw = poly.signed_area() > 0.0;
                let mut best: Option<Hit> = None;
                for (a, b) in poly.edges() {
                    let e = b - a;
                    let denom = ray.dir.cross(e);
                    if denom == 0.0 {
                        continue;
                    }
                    let ao = a - ray.origin;
                    let t = ao.cross(e) / denom;
                    let u = ao.cross(ray.dir) / denom;
                    if t > t_min && (0.0..=1.0).contains(&u) && best.is_none_or(|h| t < h.t) {
                        // Outward normal: right of the edge for CCW polygons.
                        let n = Point::new(e.y, -e.x).normalized();
                        let normal = if ccw { n } else { -n };
                        best = Some(Hit { t, point: ray.origin + ray.dir * t, normal });
                    }
                }
                best
            }
        }
    }

    /// Axis-aligned bounding box `(min, max)`.
    pub fn bbox(&self) -> (Point, Point) {
        match self {
            Shape::Circle(c) => (
                Point::new(c.center.x - c.radius_m, c.center.y - c.radius_m),
                Point::new(c.center.x + c.radius_m, c.center.y + c.radius_m),
            ),
            Shape::Polygon(p) => {
                let mut lo = Point::new(f64::INFINITY, f64::INFINITY);
                let mut hi = Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
                for v in p.vertices() {
                    lo = Point::new(lo.x.min(v.x), lo.y.min(v.y));
                    hi = Point::new(hi.x.max(v.x), hi.y.max(v.y));
                }
                (lo, hi)
            }
        }
    }
}

/// An obstacle: a shape plus its acoustic properties (paper §II.B).
#[derive(Debug, Clone, PartialEq)]
pub struct Obstacle {
    /// Geometry of the obstacle.
    pub shape: Shape,
    /// Fraction in [0, 1]: outgoing angle perturbed by ± roughness·90°.
    pub roughness: f64,
    /// Fraction in [0, 1] of loudness lost per bounce.
    pub absorption: f64,
}

impl Obstacle {
    /// Unsigned distance from `p` to the obstacle's surface (m); see
    /// [`Shape::surface_distance`].
    pub fn surface_distance(&self, p: Point) -> f64 {
        self.shape.surface_distance(p)
    }
}

/// Reflects direction `d` about the unit normal `n` (specular reflection).
pub fn reflect(d: Point, n: Point) -> Point {
    d - n * (2.0 * d.dot(n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn square() -> Polygon {
        Polygon::new(vec![Point::new(0.0, 0.0), Point::new(2.0, 0.0), Point::new(2.0, 2.0), Point::new(0.0, 2.0)])
            .unwrap()
    }

    #[test]
    fn circle_hit_and_normal() {
        let c = Shape::Circle(Circle::new(Point::new(5.0, 0.0), 1.0).unwrap());
        let h = c.intersect(&Ray { origin: Point::new(0.0, 0.0), dir: Point::new(1.0, 0.0) }, 1e-9).unwrap();
        assert!((h.t - 4.0).abs() < 1e-12);
        assert!((h.normal.x + 1.0).abs() < 1e-12 && h.normal.y.abs() < 1e-12);
        assert!(c.intersect(&Ray { origin: Point::new(0.0, 0.0), dir: Point::new(-1.0, 0.0) }, 1e-9).is_none());
        assert!(c.intersect(&Ray { origin: Point::new(0.0, 1.5), dir: Point::new(1.0, 0.0) }, 1e-9).is_none());
    }

    #[test]
    fn polygon_hit_normal_is_outward_for_both_windings() {
        let ccw = Shape::Polygon(square());
        let mut v = square().vertices().to_vec();
        v.reverse();
        let cw = Shape::Polygon(Polygon::new(v).unwrap());
        for s in [ccw, cw] {
            let h = s.intersect(&Ray { origin: Point::new(1.0, -3.0), dir: Point::new(0.0, 1.0) }, 1e-9).unwrap();
            assert!((h.t - 3.0).abs() < 1e-12);
            assert!((h.normal.y + 1.0).abs() < 1e-12, "{h:?}");
        }
    }

    #[test]
    fn surface_distances() {
        let s = Shape::Polygon(square());
        assert!((s.surface_distance(Point::new(1.0, 1.0)) - 1.0).abs() < 1e-12);
        assert!((s.surface_distance(Point::new(3.0, 3.0)) - 2f64.sqrt()).abs() < 1e-12);
        assert!(s.contains(Point::new(1.0, 1.0)) && !s.contains(Point::new(3.0, 1.0)));
        let c = Shape::Circle(Circle::new(Point::new(0.0, 0.0), 2.0).unwrap());
        assert!((c.surface_distance(Point::new(0.5, 0.0)) - 1.5).abs() < 1e-12);
        assert!((c.surface_distance(Point::new(0.0, 5.0)) - 3.0).abs() < 1e-12);
    }

    #[test]
    fn bad_shapes_are_errors() {
        assert!(Circle::new(Point::new(0.0, 0.0), 0.0).is_err());
        assert!(Circle::new(Point::new(f64::NAN, 0.0), 1.0).is_err());
        assert!(Polygon::new(vec![Point::new(0.0, 0.0), Point::new(1.0, 1.0)]).is_err());
        assert!(Polygon::new(vec![Point::new(0.0, 0.0), Point::new(1.0, 1.0), Point::new(2.0, 2.0)]).is_err());
    }

    proptest! {
        #[test]
        fn reflection_preserves_length_and_flips_normal_component(dx in -1.0..1.0f64, dy in -1.0..1.0f64, a in 0.0..6.3f64) {
            let d = Point::new(dx, dy);
            let n = Point::from_angle(a);
            let r = reflect(d, n);
            prop_assert!((r.norm() - d.norm()).abs() < 1e-12);
            prop_assert!((r.dot(n) + d.dot(n)).abs() < 1e-12);
        }

        #[test]
        fn circle_hits_lie_on_surface(ox in -10.0..10.0f64, oy in -10.0..10.0f64, a in 0.0..6.3f64, r in 0.5..4.0f64) {
            let c = Shape::Circle(Circle::new(Point::new(1.0, 2.0), r).unwrap());
            if let Some(h) = c.intersect(&Ray { origin: Point::new(ox, oy), dir: Point::from_angle(a) }, 1e-9) {
                prop_assert!(c.surface_distance(h.point) < 1e-9);
                prop_assert!(h.t > 0.0);
            }
        }
    }
}

/// Specular reflection point on a circle for sound from `source` heard at
/// `listener`: the point of the circle's surface where the path
/// `source → P → listener` is shortest (Fermat: angle of incidence equals
/// angle of reflection). `None` when either end is inside the circle or the
/// direct segment crosses it (the circle then shadows rather than reflects).
pub fn specular_point_on_circle(source: Point, listener: Point, circle: &Circle) -> Option<Point> {
    let (c, r) = (circle.center, circle.radius_m);
    if source.dist(c) <= r || listener.dist(c) <= r || point_segment_distance(c, source, listener) <= r {
        return None;
    }
    let path = |phi: f64| {
        let p = c + Point::from_angle(phi) * r;
        p.dist(source) + p.dist(listener)
    };
    // Coarse scan for the global minimum, then bisection on the derivative of
    // the path length (zero where incidence equals reflection).
    const N: usize = 720;
    let step = std::f64::consts::TAU / N as f64;
    // Each path length once (a comparison of two recomputed ones doubled
    // the cost); the first of equal minima, as `min_by` picks.
    let k_best = (0..N).map(|k| path(k as f64 * step)).enumerate().min_by(|a, b| a.1.total_cmp(&b.1))?.0;
    let slope = |phi: f64| {
        let u = Point::from_angle(phi);
        let p = c + u * r;
        let tangent = Point::new(-u.y, u.x);
        ((p - source).normalized() + (p - listener).normalized()).dot(tangent)
    };
    let (mut lo, mut hi) = ((k_best as f64 - 1.0) * step, (k_best as f64 + 1.0) * step);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if slope(mid) > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some(c + Point::from_angle(0.5 * (lo + hi)) * r)
}

#[cfg(test)]
mod specular_tests {
    use super::*;

    #[test]
    fn specular_point_obeys_reflection_law() {
        let circle = Circle::new(Point::new(3.0, -20.0), 4.0).unwrap();
        let (s, l) = (Point::new(0.0, 0.0), Point::new(-7.0, 10.0));
        let p = specular_point_on_circle(s, l, &circle).unwrap();
        let n = (p - circle.center).normalized();
        let to_s = (s - p).normalized();
        let to_l = (l - p).normalized();
        // Equal angles with the normal, on opposite sides of it.
        assert!((to_s.dot(n) - to_l.dot(n)).abs() < 1e-9);
        assert!(to_s.cross(n) * to_l.cross(n) < 0.0);
        // Symmetric case by hand: S and L mirror images about the line x = 3.
        let p = specular_point_on_circle(Point::new(0.0, 0.0), Point::new(6.0, 0.0), &circle).unwrap();
        assert!((p.x - 3.0).abs() < 1e-9 && (p.y + 16.0).abs() < 1e-9, "{p:?}");
        assert!(specular_point_on_circle(Point::new(0.0, -30.0), Point::new(0.0, 0.0), &circle).is_none());
    }
}
