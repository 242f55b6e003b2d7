//! The acoustic ellipse of paper Eq. 4: every point whose distances to the
//! Source and the Listener sum to `D + Δd`.

use crate::error::{CoreError, Num, finite};
use crate::geometry::Point;

/// Largest coordinate or path difference accepted (m): far beyond any
/// acoustic scene, and small enough that cell indices never overflow.
pub const MAX_EXTENT_M: f64 = 1e9;

/// An ellipse given by its foci and path-length difference, with the derived
/// quantities the rasteriser needs precomputed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipse {
    /// First focus: the Source (m).
    pub focus_a: Point,
    /// Second focus: the Listener (m).
    pub focus_b: Point,
    /// Path-length difference Δd (m), ≥ 0.
    pub delta_d_m: f64,
    /// Centre (midpoint of the foci).
    pub center: Point,
    /// Semi-major axis a = (D + Δd)/2.
    pub semi_major_m: f64,
    /// Semi-minor axis b = sqrt(a² − (D/2)²); 0 when Δd = 0 (the segment).
    pub semi_minor_m: f64,
    /// cos of the major axis' angle from +x.
    pub cos_t: f64,
    /// sin of the major axis' angle from +x.
    pub sin_t: f64,
}

impl Ellipse {
    /// Builds the ellipse of Eq. 4. Δd = 0 collapses it to the segment between
    /// the foci; Δd < 0, non-finite inputs and coincident foci are errors.
    pub fn new(source: Point, listener: Point, delta_d_m: f64) -> Result<Self, CoreError> {
        finite("source_x", source.x)?;
        finite("source_y", source.y)?;
        finite("listener_x", listener.x)?;
        finite("listener_y", listener.y)?;
        finite("delta_d", delta_d_m)?;
        if delta_d_m < 0.0 {
            return Err(CoreError::NegativeDeltaD(delta_d_m));
        }
        if [source.x, source.y, listener.x, listener.y, delta_d_m].iter().any(|v| v.abs() > MAX_EXTENT_M) {
            return Err(CoreError::InvalidGeometry(format!(
                "coordinates and delta_d must be within ±{MAX_EXTENT_M:e} m (source {source}, listener {listener}, delta_d {})",
                Num(delta_d_m)
            )));
        }
        let d = listener - source;
        let dist_m = d.norm();
        if dist_m == 0.0 {
            return Err(CoreError::CoincidentFoci { x: source.x, y: source.y });
        }
        let semi_major_m = 0.5 * (dist_m + delta_d_m);
        // b² = a² − c² = Δd(2D + Δd)/4, written without cancellation.
        let semi_minor_m = 0.5 * (delta_d_m * (2.0 * dist_m + delta_d_m)).sqrt();
        Ok(Self {
            focus_a: source,
            focus_b: listener,
            delta_d_m,
            center: Point::new(0.5 * (source.x + listener.x), 0.5 * (source.y + listener.y)),
            semi_major_m,
            semi_minor_m,
            cos_t: d.x / dist_m,
            sin_t: d.y / dist_m,
        })
    }

    /// `|p − S| + |p − L| − (D + Δd)`: zero on the ellipse, negative inside.
    pub fn focal_excess(&self, p: Point) -> f64 {
        p.dist(self.focus_a) + p.dist(self.focus_b) - 2.0 * self.semi_major_m
    }

    /// Coefficients (A, B, C, F) of the implicit form `A x² + B x y + C y² + F`
    /// in coordinates relative to the centre; negative inside.
    pub fn conic(&self) -> (f64, f64, f64, f64) {
        let (a2, b2) = (self.semi_major_m.powi(2), self.semi_minor_m.powi(2));
        let (c, s) = (self.cos_t, self.sin_t);
        (a2 * s * s + b2 * c * c, 2.0 * (b2 - a2) * s * c, a2 * c * c + b2 * s * s, -a2 * b2)
    }

    /// Half-widths of the axis-aligned bounding box, (x, y).
    pub fn half_extents(&self) -> (f64, f64) {
        let (a, _, c, _) = self.conic();
        (c.sqrt(), a.sqrt())
    }

    /// Axis-aligned bounding box `(min, max)`.
    pub fn bbox(&self) -> (Point, Point) {
        let (hx, hy) = self.half_extents();
        (Point::new(self.center.x - hx, self.center.y - hy), Point::new(self.center.x + hx, self.center.y + hy))
    }

    /// Point on the ellipse at eccentric anomaly `u` (rad).
    pub fn point_at(&self, u: f64) -> Point {
        let (su, cu) = u.sin_cos();
        let (x, y) = (self.semi_major_m * cu, self.semi_minor_m * su);
        Point::new(self.center.x + x * self.cos_t - y * self.sin_t, self.center.y + x * self.sin_t + y * self.cos_t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn rejects_bad_input() {
        let s = Point::new(0.0, 0.0);
        assert_eq!(Ellipse::new(s, Point::new(1.0, 0.0), -0.1), Err(CoreError::NegativeDeltaD(-0.1)));
        assert!(Ellipse::new(s, s, 1.0).is_err());
        assert!(Ellipse::new(s, Point::new(1.0, f64::NAN), 1.0).is_err());
        assert!(Ellipse::new(s, Point::new(1.0, 0.0), f64::INFINITY).is_err());
        assert!(Ellipse::new(s, Point::new(1.0, 0.0), 1e155).is_err());
        assert!(Ellipse::new(s, Point::new(2e17, 0.0), 1.0).is_err());
    }

    #[test]
    fn zero_delta_d_is_the_segment() {
        let e = Ellipse::new(Point::new(0.0, 0.0), Point::new(4.0, 0.0), 0.0).unwrap();
        assert_eq!(e.semi_minor_m, 0.0);
        assert!(e.focal_excess(Point::new(2.0, 0.0)).abs() < 1e-12);
        assert!(e.focal_excess(Point::new(2.0, 0.01)) > 0.0);
    }

    #[test]
    fn hand_computed_axes() {
        // Foci 6 m apart, Δd = 4 m: a = 5, c = 3, b = 4.
        let e = Ellipse::new(Point::new(-3.0, 0.0), Point::new(3.0, 0.0), 4.0).unwrap();
        assert!((e.semi_major_m - 5.0).abs() < 1e-12 && (e.semi_minor_m - 4.0).abs() < 1e-12);
        assert!(e.focal_excess(Point::new(0.0, 4.0)).abs() < 1e-12);
        assert!(e.focal_excess(Point::new(5.0, 0.0)).abs() < 1e-12);
    }

    proptest! {
        #[test]
        fn parametric_points_satisfy_eq4_and_conic(
            sx in -30.0..30.0f64, sy in -30.0..30.0f64, lx in -30.0..30.0f64, ly in -30.0..30.0f64,
            dd in 0.0..40.0f64, u in 0.0..6.3f64,
        ) {
            prop_assume!(Point::new(sx, sy).dist(Point::new(lx, ly)) > 0.1);
            let e = Ellipse::new(Point::new(sx, sy), Point::new(lx, ly), dd).unwrap();
            let p = e.point_at(u);
            prop_assert!(e.focal_excess(p).abs() < 1e-9);
            let (a, b, c, f) = e.conic();
            let (x, y) = (p.x - e.center.x, p.y - e.center.y);
            let scale = e.semi_major_m.powi(4).max(1.0);
            prop_assert!((a * x * x + b * x * y + c * y * y + f).abs() / scale < 1e-9);
            let (lo, hi) = e.bbox();
            prop_assert!(p.x >= lo.x - 1e-9 && p.x <= hi.x + 1e-9 && p.y >= lo.y - 1e-9 && p.y <= hi.y + 1e-9);
        }
    }
}
