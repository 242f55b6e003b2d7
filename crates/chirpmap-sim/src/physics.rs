//! The particle model's physics (paper §II.B), shared by the path tracer and
//! the stepper so both simulate exactly the same model.

use crate::rng::bounce_uniform;
use crate::trajectory::Capsule;
use chirpmap_core::geometry::{Hit, reflect};
use chirpmap_core::{Obstacle, Point, Polygon, Shape};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Rays start this far past a bounce so a particle does not re-hit the surface
/// it just left (a convex obstacle cannot be hit again anyway).
///
/// Hits count only where a ray *enters* an obstacle (see [`nearest_hit`]):
/// particles are always outside obstacles (the source is outside every one,
/// obstacles do not overlap, bounces leave the surface), so a ray crossing a
/// surface from within is a rounding artefact of a bounce point that landed a
/// hair inside. Near-tangent outgoing directions (rough bounces) can turn such
/// a hair into a "hit" farther than `T_MIN_M` away, so the distance alone is
/// not enough.
pub const T_MIN_M: f64 = 1e-9;

/// Unit directions `j·2π/per_tick`, `j = 0..per_tick`.
pub fn direction_table(per_tick: u32) -> Vec<Point> {
    (0..per_tick).map(|j| Point::from_angle(f64::from(j) * (TAU / f64::from(per_tick)))).collect()
}

/// Direction of a particle: table direction `j` rotated by the tick's offset,
/// given as `(cos, sin)`. This is the paper's "evenly distributed in a circle
/// … a random angular offset is applied" (§II.B), without a `sin_cos` per particle.
#[inline]
pub fn emission_dir(table_dir: Point, offset_cos_sin: (f64, f64)) -> Point {
    let (c, s) = offset_cos_sin;
    Point::new(c * table_dir.x - s * table_dir.y, s * table_dir.x + c * table_dir.y)
}

/// Outgoing direction after a bounce on a surface with outward unit `normal`.
///
/// Roughness (docs/parameters.md, "ours"): the specular direction is rotated by a
/// uniform angle in ±roughness·90°; a rotation that would point into the
/// surface is folded back about the surface tangent, so the particle always
/// leaves the obstacle. `u01` is the particle's bounce random number.
pub fn bounce_dir(dir: Point, normal: Point, roughness: f64, u01: f64) -> Point {
    let specular = reflect(dir, normal);
    if roughness == 0.0 {
        return specular;
    }
    let (s, c) = ((2.0 * u01 - 1.0) * roughness * FRAC_PI_2).sin_cos();
    let out = Point::new(c * specular.x - s * specular.y, s * specular.x + c * specular.y);
    // Folding the angle β from the normal to π − β is a mirror about the tangent.
    let into = out.dot(normal);
    if into < 0.0 { out - normal * (2.0 * into) } else { out }
}

/// Distance along `dir` (unit) from `pos` to the world's edge. A particle that
/// crosses it has left (§II.B) and never returns (the world is convex).
#[inline]
pub fn world_exit_m(pos: Point, dir: Point, world: &[f64; 4]) -> f64 {
    let tx = if dir.x > 0.0 {
        (world[2] - pos.x) / dir.x
    } else if dir.x < 0.0 {
        (world[0] - pos.x) / dir.x
    } else {
        f64::INFINITY
    };
    let ty = if dir.y > 0.0 {
        (world[3] - pos.y) / dir.y
    } else if dir.y < 0.0 {
        (world[1] - pos.y) / dir.y
    } else {
        f64::INFINITY
    };
    tx.min(ty).max(0.0)
}

/// Where the ray (`dir` unit) enters a circle beyond `t_min`, with the outward
/// normal: the near root of [`Shape::intersect`](chirpmap_core::Shape::intersect)
/// only. A ray starting inside (or on) the circle is leaving it and has no
/// entry, whatever the rounding of its origin; a ray pointing away exits early.
#[inline]
pub fn circle_hit(center: Point, radius_m: f64, pos: Point, dir: Point, t_min: f64) -> Option<Hit> {
    let oc = pos - center;
    let b = oc.dot(dir);
    let cc = oc.dot(oc) - radius_m * radius_m;
    // The entry root t0 = −b − √(b² − cc) is positive only if b < 0 and cc > 0.
    if cc <= 0.0 || b >= 0.0 {
        return None;
    }
    let disc = b * b - cc;
    if disc < 0.0 {
        return None;
    }
    // Numerically stable near root (t0·t1 = cc, t1 = √disc − b > 0).
    let t = cc / (disc.sqrt() - b);
    if t <= t_min {
        return None;
    }
    let point = pos + dir * t;
    Some(Hit { t, point, normal: (point - center) * (1.0 / radius_m) })
}

/// Where the ray (`dir` unit) first enters a polygon beyond `t_min`: the
/// nearest crossing of an edge from outside (`dir · outward normal < 0`),
/// computed as [`Shape::intersect`](chirpmap_core::Shape::intersect) does but
/// skipping edges the ray crosses from within.
pub fn polygon_hit(poly: &Polygon, pos: Point, dir: Point, t_min: f64) -> Option<Hit> {
    let ccw = poly.signed_area() > 0.0;
    let mut best: Option<Hit> = None;
    for (a, b) in poly.edges() {
        let e = b - a;
        // dir · n_out = ±dir × e / |e| (n_out is right of the edge when CCW).
        let denom = dir.cross(e);
        if (ccw && denom >= 0.0) || (!ccw && denom <= 0.0) {
            continue;
        }
        let ao = a - pos;
        let t = ao.cross(e) / denom;
        let u = ao.cross(dir) / denom;
        if t > t_min && (0.0..=1.0).contains(&u) && best.is_none_or(|h| t < h.t) {
            let n = Point::new(e.y, -e.x).normalized();
            let normal = if ccw { n } else { -n };
            best = Some(Hit { t, point: pos + dir * t, normal });
        }
    }
    best
}

/// Nearest obstacle surface the ray enters beyond `t_min`, with the
/// obstacle's index. Only entries count (see [`T_MIN_M`]).
#[inline]
pub fn nearest_hit(obstacles: &[Obstacle], pos: Point, dir: Point, t_min: f64) -> Option<(Hit, usize)> {
    let mut best: Option<(Hit, usize)> = None;
    for (i, o) in obstacles.iter().enumerate() {
        let h = match &o.shape {
            Shape::Circle(c) => circle_hit(c.center, c.radius_m, pos, dir, t_min),
            Shape::Polygon(p) => polygon_hit(p, pos, dir, t_min),
        };
        if let Some(h) = h
            && best.is_none_or(|(b, _)| h.t < b.t)
        {
            best = Some((h, i));
        }
    }
    best
}

/// Applies a bounce off `obstacle` to a particle: new direction and loudness.
#[inline]
pub fn apply_bounce(
    obstacle: &Obstacle,
    dir: Point,
    normal: Point,
    loudness: f64,
    bounce_key: u64,
    particle: u64,
    bounce: u32,
) -> (Point, f64) {
    let u = if obstacle.roughness == 0.0 { 0.5 } else { bounce_uniform(bounce_key, particle, bounce) };
    (bounce_dir(dir, normal, obstacle.roughness, u), loudness * (1.0 - obstacle.absorption))
}

/// Interval of the line parameter `s` (points `p + u·s`, `u` unit) within
/// `c.radius_m` of the capsule's axis, or `None`. The set is convex, so the
/// hull of its parts (two end discs and the middle slab) is exact.
pub fn capsule_interval(p: Point, u: Point, c: &Capsule) -> Option<(f64, f64)> {
    let r = c.radius_m;
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for q in [c.a, c.b] {
        let w = p - q;
        let b = w.dot(u);
        let disc = b * b - (w.dot(w) - r * r);
        if disc >= 0.0 {
            let sq = disc.sqrt();
            lo = lo.min(-b - sq);
            hi = hi.max(-b + sq);
        }
    }
    let axis = c.b - c.a;
    let len = axis.norm();
    if len > 0.0 {
        let e = axis * (1.0 / len);
        // Along the axis: 0 ≤ (p − a)·e + s·(u·e) ≤ len.
        let slab = |x0: f64, rate: f64, a: f64, b: f64| -> Option<(f64, f64)> {
            if rate.abs() < 1e-300 {
                return (a..=b).contains(&x0).then_some((f64::NEG_INFINITY, f64::INFINITY));
            }
            let (s1, s2) = ((a - x0) / rate, (b - x0) / rate);
            Some((s1.min(s2), s1.max(s2)))
        };
        let w = p - c.a;
        if let (Some(i1), Some(i2)) = (slab(w.dot(e), u.dot(e), 0.0, len), slab(e.cross(w), e.cross(u), -r, r)) {
            let (a, b) = (i1.0.max(i2.0), i1.1.min(i2.1));
            if a <= b {
                lo = lo.min(a);
                hi = hi.max(b);
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// Angular window (centre, half-width) in which rays from `from` can reach any
/// of `points`' convex hull; `None` when `from` is inside it (all directions).
pub fn points_window(from: Point, points: &[Point]) -> Option<(f64, f64)> {
    let first = points.first()?;
    let a0 = (*first - from).y.atan2((*first - from).x);
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for p in points {
        let d = *p - from;
        if d.norm() < 1e-12 {
            return None;
        }
        let rel = (d.y.atan2(d.x) - a0 + PI).rem_euclid(TAU) - PI;
        lo = lo.min(rel);
        hi = hi.max(rel);
    }
    if hi - lo >= PI - 1e-6 {
        return None;
    }
    Some((a0 + 0.5 * (lo + hi), 0.5 * (hi - lo)))
}

/// Angular window of a disc seen from `from`; `None` when `from` is inside.
pub fn disc_window(from: Point, center: Point, radius_m: f64) -> Option<(f64, f64)> {
    let d = center - from;
    let dist = d.norm();
    if dist <= radius_m * (1.0 + 1e-9) + 1e-9 {
        return None;
    }
    Some((d.y.atan2(d.x), (radius_m / dist).asin()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use chirpmap_core::geometry::Ray;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn bounce_leaves_the_surface_within_the_roughness_cone(
            din in 0.0..TAU, nin in 0.0..TAU, rough in 0.0..1.0f64, u in 0.0..1.0f64,
        ) {
            let n = Point::from_angle(nin);
            let mut d = Point::from_angle(din);
            if d.dot(n) > 0.0 { d = -d; }
            let out = bounce_dir(d, n, rough, u);
            prop_assert!((out.norm() - 1.0).abs() < 1e-12);
            prop_assert!(out.dot(n) >= -1e-12);
            let spec = reflect(d, n);
            let ang = spec.cross(out).atan2(spec.dot(out)).abs();
            prop_assert!(ang <= rough * FRAC_PI_2 + 1e-9, "{ang}");
        }

        #[test]
        fn capsule_interval_matches_sampling(px in -20.0..20.0f64, py in -20.0..20.0f64, a in 0.0..TAU) {
            let c = Capsule { a: Point::new(-3.0, 1.0), b: Point::new(4.0, 2.0), radius_m: 0.7 };
            let (p, u) = (Point::new(px, py), Point::from_angle(a));
            let iv = capsule_interval(p, u, &c);
            for k in 0..4000 {
                let s = -60.0 + 0.03 * f64::from(k);
                let x = p + u * s;
                let inside = chirpmap_core::geometry::point_segment_distance(x, c.a, c.b) <= c.radius_m;
                if inside {
                    let (lo, hi) = iv.expect("interval");
                    prop_assert!(lo - 1e-9 <= s && s <= hi + 1e-9);
                }
            }
        }
    }

    proptest! {
        /// Outside the circle: the core's hit, if it enters. Inside: none.
        #[test]
        fn circle_hit_is_cores_entry(ox in -10.0..10.0f64, oy in -10.0..10.0f64, a in 0.0..TAU, r in 0.5..4.0f64) {
            let c = chirpmap_core::Circle::new(Point::new(1.0, 2.0), r).unwrap();
            let (o, d) = (Point::new(ox, oy), Point::from_angle(a));
            let want = Shape::Circle(c).intersect(&Ray { origin: o, dir: d }, T_MIN_M).filter(|w| w.normal.dot(d) < 0.0);
            let have = circle_hit(c.center, r, o, d, T_MIN_M);
            prop_assert_eq!(want.is_some(), have.is_some());
            if let (Some(w), Some(h)) = (want, have) {
                prop_assert!((w.t - h.t).abs() < 1e-9 && w.normal.dist(h.normal) < 1e-9);
            }
        }

        /// Polygons: the core's nearest hit when it enters; never a hit from within.
        #[test]
        fn polygon_hit_is_cores_entry(ox in -6.0..6.0f64, oy in -6.0..6.0f64, a in 0.0..TAU, rev in any::<bool>()) {
            // A concave U, so rays can leave it and enter it again.
            let mut v = vec![
                Point::new(-3.0, -3.0), Point::new(3.0, -3.0), Point::new(3.0, 3.0), Point::new(1.0, 3.0),
                Point::new(1.0, -1.0), Point::new(-1.0, -1.0), Point::new(-1.0, 3.0), Point::new(-3.0, 3.0),
            ];
            if rev { v.reverse(); }
            let poly = Polygon::new(v).unwrap();
            let (o, d) = (Point::new(ox, oy), Point::from_angle(a));
            let have = polygon_hit(&poly, o, d, T_MIN_M);
            if let Some(h) = have {
                prop_assert!(h.normal.dot(d) < 0.0);
            }
            if !poly.contains(o) {
                let want = Shape::Polygon(poly).intersect(&Ray { origin: o, dir: d }, T_MIN_M);
                prop_assert_eq!(want.is_some(), have.is_some());
                if let (Some(w), Some(h)) = (want, have) {
                    prop_assert!((w.t - h.t).abs() < 1e-9 && w.normal.dist(h.normal) < 1e-12);
                }
            }
        }
    }

    /// A rough bounce that leaves a circle almost tangentially from a point
    /// rounded a hair inside it must not "hit" the circle again on the way out
    /// (the seed-829 mismatch between the tracer and the stepper).
    #[test]
    fn grazing_exit_from_just_inside_is_not_a_hit() {
        let (center, r) = (Point::new(0.0, 0.0), 5.0);
        let n = Point::from_angle(0.7);
        let pos = center + n * (r - 1e-14);
        // 1e-6 rad off the tangent, outwards: leaves the surface ~1e-8 m later.
        let d = Point::from_angle(0.7 + FRAC_PI_2 - 1e-6);
        let core = Shape::Circle(chirpmap_core::Circle::new(center, r).unwrap());
        let exit = core.intersect(&Ray { origin: pos, dir: d }, T_MIN_M).unwrap();
        assert!(exit.t > T_MIN_M && exit.normal.dot(d) > 0.0, "{exit:?}");
        assert!(circle_hit(center, r, pos, d, T_MIN_M).is_none());
        // A square's edge, origin a hair inside, leaving nearly along the edge.
        let sq =
            Polygon::new(vec![Point::new(0.0, 0.0), Point::new(2.0, 0.0), Point::new(2.0, 2.0), Point::new(0.0, 2.0)])
                .unwrap();
        let (pos, d) = (Point::new(1.0, 1e-14), Point::from_angle(-1e-6));
        assert!(Shape::Polygon(sq.clone()).intersect(&Ray { origin: pos, dir: d }, T_MIN_M).is_some());
        assert!(polygon_hit(&sq, pos, d, T_MIN_M).is_none());
    }

    #[test]
    fn windows() {
        let (c, h) = disc_window(Point::new(0.0, 0.0), Point::new(0.0, -20.0), 10.0).unwrap();
        assert!((c + FRAC_PI_2).abs() < 1e-12 && (h - 0.5f64.asin()).abs() < 1e-12);
        assert!(disc_window(Point::new(0.0, 0.0), Point::new(1.0, 0.0), 2.0).is_none());
        let wall = [Point::new(-30.0, -20.0), Point::new(30.0, -20.0), Point::new(30.0, -21.0)];
        let (c, h) = points_window(Point::new(0.0, 0.0), &wall).unwrap();
        assert!((c + FRAC_PI_2).abs() < 0.05 && (h - 0.983).abs() < 0.01);
        let around = [Point::new(-1.0, -1.0), Point::new(1.0, -1.0), Point::new(0.0, 1.0)];
        assert!(points_window(Point::new(0.0, 0.0), &around).is_none());
    }
}
