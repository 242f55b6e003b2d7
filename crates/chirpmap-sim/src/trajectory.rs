//! Listener motion: straight, or an arc at constant `spin_rate` (paper §III:
//! spin_rate 0 or π/4 rad/s, arcing away from the Source).

use chirpmap_core::Point;

/// A listener's known trajectory (the paper assumes positions are known from
/// a positioning system, §II.A).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trajectory {
    /// Position at t = 0 (m).
    pub start: Point,
    /// Heading at t = 0 (rad), counter-clockwise from +x.
    pub heading_rad: f64,
    /// Speed (m/s). Paper: 10.
    pub speed_mps: f64,
    /// Heading change rate (rad/s), positive counter-clockwise.
    pub spin_rate_rps: f64,
}

/// A segment `a`–`b` thickened by `radius_m`: a region that contains the
/// listener's disc for a time span.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capsule {
    /// Segment start (m).
    pub a: Point,
    /// Segment end (m).
    pub b: Point,
    /// Thickening radius (m).
    pub radius_m: f64,
}

impl Trajectory {
    /// Position at `t_s` after the chirp starts. Written as chord length along
    /// the mean heading, `2v·sin(ωt/2)/ω` at `h0 + ωt/2`, which is exact for
    /// arcs and stays accurate as ω → 0 (no cancellation of a huge radius).
    pub fn position(&self, t_s: f64) -> Point {
        let half = 0.5 * self.spin_rate_rps * t_s;
        let chord_m = if half.abs() < 1e-9 { self.speed_mps * t_s } else { self.speed_mps * t_s * half.sin() / half };
        self.start + Point::from_angle(self.heading_rad + half) * chord_m
    }

    /// Velocity (m/s) at `t_s`: speed along the heading `h0 + ω·t`.
    pub fn velocity(&self, t_s: f64) -> Point {
        Point::from_angle(self.heading_rad + self.spin_rate_rps * t_s) * self.speed_mps
    }

    /// Capsules covering every point within `radius_m` of the trajectory over
    /// `[0, t_end_s]`: a chord polyline with at most 0.1 rad of turn per
    /// piece, each thickened by the radius plus the arc's sagitta over the
    /// chord (and a 1 µm margin), so the cover is conservative.
    pub fn capsules(&self, t_end_s: f64, radius_m: f64) -> Vec<Capsule> {
        let turn = (self.spin_rate_rps * t_end_s).abs();
        let n = ((turn / 0.1).ceil() as usize).max(1);
        let dt = t_end_s / n as f64;
        let w = self.spin_rate_rps.abs();
        let sagitta_m = if w == 0.0 { 0.0 } else { 2.0 * self.speed_mps / w * (0.25 * w * dt).sin().powi(2) };
        (0..n)
            .map(|i| Capsule {
                a: self.position(i as f64 * dt),
                b: self.position((i + 1) as f64 * dt),
                radius_m: radius_m + sagitta_m + 1e-6,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use chirpmap_core::geometry::point_segment_distance;

    #[test]
    fn straight_and_arc_positions() {
        let s = Trajectory { start: Point::new(-3.0, 10.0), heading_rad: 0.0, speed_mps: 10.0, spin_rate_rps: 0.0 };
        let p = s.position(0.5);
        assert!((p.x - 2.0).abs() < 1e-12 && (p.y - 10.0).abs() < 1e-12);
        // Quarter circle: radius v/ω = 4 m, heading +x turning left ends at (+4, +4).
        let w = std::f64::consts::FRAC_PI_4;
        let a = Trajectory { start: Point::new(0.0, 0.0), heading_rad: 0.0, speed_mps: 4.0 * w, spin_rate_rps: w };
        let q = a.position(2.0);
        assert!((q.x - 4.0).abs() < 1e-12 && (q.y - 4.0).abs() < 1e-12, "{q:?}");
        // Speed is constant along the arc.
        let d = a.position(1.0 + 1e-6).dist(a.position(1.0)) / 1e-6;
        assert!((d - 4.0 * w).abs() < 1e-6);
    }

    #[test]
    fn capsules_cover_the_arc() {
        let a = Trajectory { start: Point::new(-3.0, 10.0), heading_rad: 0.3, speed_mps: 10.0, spin_rate_rps: 2.0 };
        let caps = a.capsules(1.5, 0.5);
        for k in 0..=1000 {
            let p = a.position(1.5 * f64::from(k) / 1000.0);
            let inside = caps.iter().any(|c| point_segment_distance(p, c.a, c.b) + 0.5 <= c.radius_m);
            assert!(inside, "{p:?}");
        }
    }
}
