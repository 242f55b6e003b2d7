//! Tangent lines of an acoustic ellipse in closed form (issue 9, item 3).
//!
//! For a unit normal `n`, the lines with normal `n` tangent to the ellipse of
//! centre `c`, semi-axes `a`, `b` along unit axes `u`, `v` are
//! `n·p = n·c ± h(n)` with the support function
//! `h(n) = sqrt(a²(n·u)² + b²(n·v)²)`, touching at
//! `c ± (a²(n·u) u + b²(n·v) v) / h(n)`.
//!
//! Which sign is physical: the ellipse's interior is free (a reflector inside
//! it would have been heard earlier), so a reflecting line lies outside it
//! with the foci on the other side. Taking `+` with `n` over the full circle
//! lists every tangent line once, oriented so that `n` points from the free
//! side (the foci) into the reflector. The `−` tangent of `n` is the `+`
//! tangent of `−n`, so nothing is lost, and a wall and the opposite face of
//! a thin wall stay apart.

use crate::ellipse::Ellipse;
use crate::geometry::Point;

/// Offset `ρ = n·(c − origin) + h(n)` of the far tangent line with unit
/// normal `n` (the line is `n·(p − origin) = ρ`), and its tangency point.
pub fn far_tangent(e: &Ellipse, n: Point, origin: Point) -> (f64, Point) {
    let u = Point::new(e.cos_t, e.sin_t);
    let v = Point::new(-e.sin_t, e.cos_t);
    let (nu, nv) = (n.dot(u), n.dot(v));
    let (a2, b2) = (e.semi_major_m * e.semi_major_m, e.semi_minor_m * e.semi_minor_m);
    let h = (a2 * nu * nu + b2 * nv * nv).sqrt();
    let rho = n.dot(e.center - origin) + h;
    let touch = if h > 0.0 { e.center + (u * (a2 * nu) + v * (b2 * nv)) * (1.0 / h) } else { e.center };
    (rho, touch)
}

/// Offset only (the Hough vote's inner loop), with the axis projections
/// precomputed by the caller: `nu = n·u`, `nv = n·v`, `nc = n·(c − origin)`.
#[inline]
pub(crate) fn far_offset(a2: f64, b2: f64, nu: f64, nv: f64, nc: f64) -> f64 {
    nc + (a2 * nu * nu + b2 * nv * nv).sqrt()
}
