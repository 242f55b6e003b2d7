//! Property tests of the evidence mapper's closed forms against naive oracles.

use chirpmap_core::evidence::{band_cells_naive, far_tangent, for_each_band_span};
use chirpmap_core::{Ellipse, GridSpec, Point};
use proptest::prelude::*;
use std::collections::BTreeSet;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// The support-function tangent (ρ = n·c + sqrt(a²(n·u)² + b²(n·v)²)) is the
    /// maximum of n·p over a dense scan of points on the ellipse, and its
    /// tangency point lies on the ellipse.
    #[test]
    fn far_tangent_matches_brute_force_scan(
        sx in -20.0..20.0f64, sy in -20.0..20.0f64, lx in -20.0..20.0f64, ly in -20.0..20.0f64,
        dd in 0.0..15.0f64, theta in 0.0..std::f64::consts::TAU, ox in -5.0..5.0f64, oy in -5.0..5.0f64,
    ) {
        prop_assume!(Point::new(sx, sy).dist(Point::new(lx, ly)) > 0.05);
        let e = Ellipse::new(Point::new(sx, sy), Point::new(lx, ly), dd).expect("valid ellipse");
        let n = Point::from_angle(theta);
        let origin = Point::new(ox, oy);
        let (rho, touch) = far_tangent(&e, n, origin);
        const N: usize = 20_000;
        let brute = (0..N)
            .map(|k| n.dot(e.point_at(k as f64 * std::f64::consts::TAU / N as f64) - origin))
            .fold(f64::NEG_INFINITY, f64::max);
        // The scan's step in eccentric anomaly is 3.1e-4 rad, so it can fall
        // short of the maximum by at most a·(step)²/2.
        let slack = e.semi_major_m * 1e-7 + 1e-9;
        prop_assert!(rho >= brute - 1e-9, "closed form {rho} below the scan's {brute}");
        prop_assert!(rho - brute <= slack, "closed form {rho} above the scan's {brute} by more than {slack}");
        prop_assert!((n.dot(touch - origin) - rho).abs() < 1e-9);
        prop_assert!(e.focal_excess(touch).abs() < 1e-7 * (1.0 + e.semi_major_m));
    }

    /// Band rasterisation equals the per-cell test of the focal sum, except for
    /// cells whose centre lies within 1e-7 m (in focal sum) of a band edge.
    #[test]
    fn band_raster_matches_naive(
        sx in -8.0..8.0f64, sy in -8.0..8.0f64, lx in -8.0..8.0f64, ly in -8.0..8.0f64,
        dd in 0.0..8.0f64, half in prop_oneof![Just(0.0), 0.0..0.5f64, 0.0..5.0f64],
    ) {
        let (s, l) = (Point::new(sx, sy), Point::new(lx, ly));
        prop_assume!(s.dist(l) > 0.01);
        let spec = GridSpec { x_min_m: -10.013, y_min_m: -9.9871, cell_m: 0.1, nx: 200, ny: 190 };
        let (lo_dd, hi_dd) = (dd - half, dd + half);
        let mut fast = BTreeSet::new();
        let mut visits = 0usize;
        for_each_band_span(s, l, lo_dd, hi_dd, &spec, |j, lo, hi| {
            for i in lo..=hi {
                fast.insert((i, j));
                visits += 1;
            }
        }).expect("valid band");
        prop_assert_eq!(visits, fast.len(), "a cell was visited twice");
        let mut naive = BTreeSet::new();
        band_cells_naive(s, l, lo_dd, hi_dd, &spec, |i, j| { naive.insert((i, j)); });
        let d = s.dist(l);
        let near_edge = |&(i, j): &(usize, usize)| {
            let c = spec.cell_center(i, j);
            let sum = c.dist(s) + c.dist(l) - d;
            (sum - hi_dd).abs() < 1e-7 || (lo_dd > 0.0 && (sum - lo_dd).abs() < 1e-7)
        };
        let bad: Vec<_> = fast.symmetric_difference(&naive).filter(|c| !near_edge(c)).take(5).collect();
        prop_assert!(bad.is_empty(), "cells differ: {:?}", bad);
    }
}

#[test]
fn band_of_a_circle_like_ellipse_by_hand() {
    // Foci 2 mm apart, Δd = 10 m: a circle of radius ≈ 5 m. The band Δd ± 0.2
    // holds the cells whose centre is 4.9–5.1 m from the centre: an annulus of
    // area π(5.1² − 4.9²) = 6.28 m², about 628 cells of 0.01 m².
    let spec = GridSpec { x_min_m: -8.0, y_min_m: -8.0, cell_m: 0.1, nx: 160, ny: 160 };
    let mut n = 0usize;
    for_each_band_span(Point::new(-0.001, 0.0), Point::new(0.001, 0.0), 9.8, 10.2, &spec, |_, lo, hi| {
        n += hi - lo + 1;
    })
    .expect("valid");
    assert!((600..=660).contains(&n), "{n}");
    assert!(for_each_band_span(Point::new(0.0, 0.0), Point::new(0.0, 0.0), 1.0, 2.0, &spec, |_, _, _| {}).is_err());
}
