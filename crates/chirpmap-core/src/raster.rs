//! Which grid cells does an ellipse *enter*? (paper Algorithm 1, inner loop).
//!
//! A cell is entered when the ellipse curve (not its interior) passes through
//! it. [`for_each_entered_span`] answers this row by row in time proportional
//! to the number of rows plus the number of cells entered: in the band between
//! two horizontal grid lines the curve is at most two arcs, and each arc's
//! x-extent is fixed by where it crosses the two lines and, if it lies in the
//! band, the ellipse's leftmost or rightmost point. Cells of one row are
//! reported as disjoint column spans, so every entered cell is visited exactly
//! once. [`entered_cells_literal`] is the literal reading (test every cell of
//! the grid) kept as a test oracle and benchmark baseline.

use crate::ellipse::Ellipse;
use crate::geometry::Point;
use crate::grid::GridSpec;

/// Calls `span(row, col_lo, col_hi)` (inclusive, clipped to the grid) for
/// every run of cells the ellipse enters. Spans never overlap.
pub fn for_each_entered_span(e: &Ellipse, spec: &GridSpec, mut span: impl FnMut(usize, usize, usize)) {
    let (qa, qb, qc, _) = e.conic();
    let inv_w = 1.0 / spec.cell_m;
    // Everything below is in cell units relative to the ellipse centre, so a
    // cell index is floor(centre + offset) with no division in the loop.
    let (hx, hy) = (qc.sqrt() * inv_w, qa.sqrt() * inv_w);
    let cx = (e.center.x - spec.x_min_m) * inv_w;
    let cy = (e.center.y - spec.y_min_m) * inv_w;
    let (nx, ny) = (spec.nx as i64, spec.ny as i64);
    if cx + hx < 0.0 || cy + hy < 0.0 || cx - hx >= nx as f64 || cy - hy >= ny as f64 {
        return;
    }
    let j_first = floor_i64(cy - hy).max(0);
    let j_last = floor_i64(cy + hy).min(ny - 1);
    // y of the rightmost point (hx, y_r); the leftmost is (−hx, −y_r).
    // From ∂Q/∂y = B x + 2 C y = 0.
    let y_right = if qc > 0.0 { -qb * hx / (2.0 * qc) } else { 0.0 };
    // Where the curve crosses the horizontal line at height y: the roots of
    // A x² + B y x + C y² + F, whose discriminant simplifies to 4a²b²(A − y²):
    // x = k_mid·y ± k_half·sqrt(A − y²).
    let (k_mid, k_half) = if qa > 0.0 { (-qb / (2.0 * qa), e.semi_major_m * e.semi_minor_m / qa) } else { (0.0, 0.0) };
    let qa_c = qa * inv_w * inv_w;
    // Left and right crossing of the line at relative height y (clamped to
    // the ellipse's x-extent; a line that misses it collapses to the point
    // below/above the centre, which only the top and bottom bands would see).
    let crossing = |y: f64| -> (f64, f64) {
        let half = k_half * (qa_c - y * y).max(0.0).sqrt();
        let mid = k_mid * y;
        ((mid - half).max(-hx), (mid + half).min(hx))
    };
    let last_col = nx - 1;
    let mut emit = |row: usize, x_lo: f64, x_hi: f64| {
        let (lo, hi) = (floor_i64(cx + x_lo).max(0), floor_i64(cx + x_hi).min(last_col));
        if lo <= hi {
            span(row, lo as usize, hi as usize);
        }
    };
    // Rows (unclipped) holding the bottom, top, leftmost and rightmost points.
    let (j_bottom, j_top) = (floor_i64(cy - hy), floor_i64(cy + hy));
    let (j_left, j_right) = (floor_i64(cy - y_right), floor_i64(cy + y_right));
    if j_bottom == j_top {
        emit(j_top as usize, -hx, hx);
        return;
    }
    let mut below = crossing(j_first as f64 - cy);
    for j in j_first..=j_last {
        let row = j as usize;
        let left_x = if j == j_left { -hx } else { f64::INFINITY };
        let right_x = if j == j_right { hx } else { f64::NEG_INFINITY };
        if j == j_bottom {
            // Only the upper line crosses: one arc over the bottom point.
            let (tl, tr) = crossing(j as f64 + 1.0 - cy);
            emit(row, tl.min(left_x), tr.max(right_x));
            below = (tl, tr);
            continue;
        }
        if j == j_top {
            let (bl, br) = below;
            emit(row, bl.min(left_x), br.max(right_x));
            continue;
        }
        let above = crossing(j as f64 + 1.0 - cy);
        let ((bl, br), (tl, tr)) = (below, above);
        let (l_lo, l_hi) = (bl.min(tl).min(left_x), bl.max(tl));
        let (r_lo, r_hi) = (br.min(tr), br.max(tr).max(right_x));
        if floor_i64(cx + r_lo) <= floor_i64(cx + l_hi) {
            // The two arcs share a cell: one span, never a cell twice.
            emit(row, l_lo, r_hi.max(l_hi));
        } else {
            emit(row, l_lo, l_hi);
            emit(row, r_lo, r_hi);
        }
        below = above;
    }
}

/// Literal Algorithm 1: test every cell of the grid. A closed cell is entered
/// iff the focal excess `|p−S|+|p−L|−(D+Δd)` is ≥ 0 at some corner (part of the
/// cell is on or outside the curve) and the cell meets the filled ellipse
/// (minimum of the convex conic over the box ≤ 0). Calls `cell(i, j)`.
pub fn entered_cells_literal(e: &Ellipse, spec: &GridSpec, mut cell: impl FnMut(usize, usize)) {
    let (qa, qb, qc, qf) = e.conic();
    let q = |x: f64, y: f64| qa * x * x + qb * x * y + qc * y * y + qf;
    // Minimum of the conic on the segment (x0,y0)→(x1,y1): a convex quadratic in t.
    let seg_min = |x0: f64, y0: f64, x1: f64, y1: f64| -> f64 {
        let (dx, dy) = (x1 - x0, y1 - y0);
        let a2 = qa * dx * dx + qb * dx * dy + qc * dy * dy;
        let a1 = 2.0 * qa * x0 * dx + qb * (x0 * dy + y0 * dx) + 2.0 * qc * y0 * dy;
        let t = if a2 > 0.0 { (-a1 / (2.0 * a2)).clamp(0.0, 1.0) } else { 0.0 };
        q(x0 + t * dx, y0 + t * dy).min(q(x0, y0)).min(q(x1, y1))
    };
    let w = spec.cell_m;
    for j in 0..spec.ny {
        for i in 0..spec.nx {
            let x0 = spec.x_min_m + i as f64 * w;
            let y0 = spec.y_min_m + j as f64 * w;
            let corners = [(x0, y0), (x0 + w, y0), (x0 + w, y0 + w), (x0, y0 + w)];
            if !corners.iter().any(|&(x, y)| e.focal_excess(Point::new(x, y)) >= 0.0) {
                continue;
            }
            if e.semi_minor_m == 0.0 {
                // Δd = 0: the "ellipse" is the segment between the foci, and
                // its conic degenerates to a double line; clip the segment.
                if segment_meets_box(e.focus_a, e.focus_b, x0, y0, x0 + w, y0 + w) {
                    cell(i, j);
                }
                continue;
            }
            let (lx, ly) = (x0 - e.center.x, y0 - e.center.y);
            let centre_inside = lx <= 0.0 && 0.0 <= lx + w && ly <= 0.0 && 0.0 <= ly + w;
            let meets = centre_inside
                || seg_min(lx, ly, lx + w, ly) <= 0.0
                || seg_min(lx + w, ly, lx + w, ly + w) <= 0.0
                || seg_min(lx + w, ly + w, lx, ly + w) <= 0.0
                || seg_min(lx, ly + w, lx, ly) <= 0.0;
            if meets {
                cell(i, j);
            }
        }
    }
}

/// `floor` as an integer without a libm call: on baseline x86-64 (no SSE4.1)
/// `f64::floor` is a function call, and it sits in the per-row hot path.
#[inline]
fn floor_i64(v: f64) -> i64 {
    let t = v as i64;
    t - i64::from((t as f64) > v)
}

/// Liang–Barsky: does the segment a→b meet the closed box?
fn segment_meets_box(a: Point, b: Point, x0: f64, y0: f64, x1: f64, y1: f64) -> bool {
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a.x - x0), (dx, x1 - a.x), (-dy, a.y - y0), (dy, y1 - a.y)] {
        if p == 0.0 {
            if q < 0.0 {
                return false;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    t0 <= t1
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::BTreeSet;

    fn fast_cells(e: &Ellipse, spec: &GridSpec) -> (BTreeSet<(usize, usize)>, usize) {
        let mut set = BTreeSet::new();
        let mut visits = 0;
        for_each_entered_span(e, spec, |j, lo, hi| {
            for i in lo..=hi {
                visits += 1;
                set.insert((i, j));
            }
        });
        (set, visits)
    }

    fn literal_cells(e: &Ellipse, spec: &GridSpec) -> BTreeSet<(usize, usize)> {
        let mut set = BTreeSet::new();
        entered_cells_literal(e, spec, |i, j| {
            set.insert((i, j));
        });
        set
    }

    fn spec() -> GridSpec {
        // Offsets that are not multiples of the cell keep exact ties unlikely.
        GridSpec { x_min_m: -20.013, y_min_m: -20.0071, cell_m: 0.1, nx: 400, ny: 400 }
    }

    #[test]
    fn circle_like_ellipse_marks_a_ring() {
        let e = Ellipse::new(Point::new(-0.001, 0.0), Point::new(0.001, 0.0), 10.0).unwrap();
        let (cells, visits) = fast_cells(&e, &spec());
        assert_eq!(cells.len(), visits, "a cell was visited twice");
        assert_eq!(cells, literal_cells(&e, &spec()));
        // A circle of radius 5 m crosses ~ 4·(2r/w) cells.
        assert!((380..=420).contains(&cells.len()), "{}", cells.len());
    }

    #[test]
    fn degenerate_segment_and_clipping() {
        let s = spec();
        for (a, b, dd) in [
            (Point::new(-3.0, -2.0), Point::new(4.0, 5.5), 0.0),
            (Point::new(-3.0, 0.05), Point::new(4.0, 0.05), 0.0),
            (Point::new(0.0, -3.0), Point::new(0.0, 6.0), 0.0),
            (Point::new(-15.0, -15.0), Point::new(15.0, 18.0), 9.0),
            (Point::new(30.0, 30.0), Point::new(35.0, 30.0), 1.0),
            (Point::new(0.0, 0.0), Point::new(0.02, 0.01), 0.03),
        ] {
            let e = Ellipse::new(a, b, dd).unwrap();
            let (cells, visits) = fast_cells(&e, &s);
            assert_eq!(cells.len(), visits, "{a:?} {b:?} {dd}");
            assert_eq!(cells, literal_cells(&e, &s), "{a:?} {b:?} {dd}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        #[test]
        fn fast_rasteriser_equals_literal_algorithm_1(
            sx in -12.0..12.0f64, sy in -12.0..12.0f64, lx in -12.0..12.0f64, ly in -12.0..12.0f64,
            dd in prop_oneof![Just(0.0), 0.0..0.3f64, 0.0..30.0f64],
        ) {
            prop_assume!(Point::new(sx, sy).dist(Point::new(lx, ly)) > 1e-3);
            let s = spec();
            let e = Ellipse::new(Point::new(sx, sy), Point::new(lx, ly), dd).unwrap();
            let (cells, visits) = fast_cells(&e, &s);
            prop_assert_eq!(cells.len(), visits, "a cell was counted twice");
            let lit = literal_cells(&e, &s);
            let missing: Vec<_> = lit.difference(&cells).take(5).collect();
            let extra: Vec<_> = cells.difference(&lit).take(5).collect();
            prop_assert!(missing.is_empty() && extra.is_empty(), "missing {:?} extra {:?}", missing, extra);
        }

        #[test]
        fn every_curve_point_lies_in_an_entered_cell(
            sx in -12.0..12.0f64, sy in -12.0..12.0f64, lx in -12.0..12.0f64, ly in -12.0..12.0f64,
            dd in 0.0..20.0f64,
        ) {
            prop_assume!(Point::new(sx, sy).dist(Point::new(lx, ly)) > 1e-3);
            let s = spec();
            let e = Ellipse::new(Point::new(sx, sy), Point::new(lx, ly), dd).unwrap();
            let (cells, _) = fast_cells(&e, &s);
            for k in 0..2000 {
                let p = e.point_at(k as f64 * std::f64::consts::TAU / 2000.0);
                if let Some(c) = s.cell_of(p) {
                    prop_assert!(cells.contains(&c), "curve point {:?} in cell {:?} not marked", p, c);
                }
            }
        }
    }
}
