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

/// Rows per [`RowBlock`]: the crossings of `BLOCK + 1` grid lines are
/// computed in one branch-free pass (which the compiler vectorises), then the
/// rows' spans.
pub const BLOCK: usize = 64;

/// `0, 1, …, BLOCK` as f64, so line heights are `(m0 + k) - cy` with no
/// integer-to-float conversion in the vectorised loop.
const STEPS: [f64; BLOCK + 1] = {
    let mut s = [0.0; BLOCK + 1];
    let mut k = 0;
    while k <= BLOCK {
        s[k] = k as f64;
        k += 1;
    }
    s
};

/// Column grids wider than this fall back to [`for_each_entered_span_reference`]:
/// the float floor below is exact only below 2⁵¹ (no grid that wide fits in memory).
const MAX_FAST_COLS: f64 = (1u64 << 50) as f64;

/// `a > b ? a : b` written so that it maps to one `maxpd` (same value as
/// `f64::max` for the non-NaN inputs here; ±0 both floor to 0).
#[inline(always)]
fn max_f(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}

#[inline(always)]
fn min_f(a: f64, b: f64) -> f64 {
    if a < b { a } else { b }
}

/// `floor(v)` clamped to `[-1, hi]`, as an exact integer-valued f64, with
/// float operations only (round to nearest by adding 1.5·2⁵², then step
/// down when that rounded up), so a loop of them vectorises on baseline
/// x86-64, which has no packed `floor` or f64→i64 conversion. Clamping
/// first keeps |v| < 2⁵¹, where the trick is exact; and since −1 and `hi`
/// are integers, `floor(clamp(v)) = clamp(floor(v))`.
#[inline(always)]
fn floor_clamped(v: f64, hi: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    let v = min_f(max_f(v, -1.0), hi);
    let r = (v + MAGIC) - MAGIC;
    r - if r > v { 1.0 } else { 0.0 }
}

/// `x` as an integer, for integer-valued `|x| < 2⁵¹`: adding 1.5·2⁵² puts
/// `2⁵¹ + x` in the mantissa bits. Unlike `as`, which must saturate and map
/// NaN to 0, this is three integer operations without branches.
#[inline(always)]
fn to_int(x: f64) -> i64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    ((x + MAGIC).to_bits() & ((1 << 52) - 1)) as i64 - (1 << 51)
}

/// Consecutive rows of an ellipse's entered cells, as arrays (one entry per
/// row) so that producer and consumer loops vectorise. Row `j0 + k` enters
/// columns `lo1[k]..=hi1[k]` and `lo2[k]..=hi2[k]`; either span may be empty
/// (`lo > hi`); they are disjoint (`lo2 > hi1`) and within `0..nx` when
/// non-empty. Entries from `len` on are stale.
#[derive(Debug, Clone)]
pub struct RowBlock {
    /// First row of the block.
    pub j0: usize,
    /// Number of rows in the block (at most [`BLOCK`]).
    pub len: usize,
    /// First span's first column, per row.
    pub lo1: [i64; BLOCK],
    /// First span's last column, per row.
    pub hi1: [i64; BLOCK],
    /// Second span's first column, per row.
    pub lo2: [i64; BLOCK],
    /// Second span's last column, per row.
    pub hi2: [i64; BLOCK],
}

impl RowBlock {
    fn new() -> Self {
        Self { j0: 0, len: 0, lo1: [0; BLOCK], hi1: [0; BLOCK], lo2: [0; BLOCK], hi2: [0; BLOCK] }
    }

    /// The block's rows as `(row, [lo1, hi1, lo2, hi2])`.
    pub fn rows(&self) -> impl Iterator<Item = (usize, [i64; 4])> + '_ {
        (0..self.len).map(|k| (self.j0 + k, [self.lo1[k], self.hi1[k], self.lo2[k], self.hi2[k]]))
    }
}

/// Calls `block` with consecutive runs of the grid rows the ellipse enters,
/// bottom to top ([`RowBlock`]); every entered row comes exactly once. The
/// cells are exactly those of [`for_each_entered_span_reference`] (the same
/// floating-point operations per crossing; compared cell for cell in the
/// tests), so maps stay bit-identical.
///
/// Issue 14's rewrite of the inner loop: per block of up to [`BLOCK`] rows the
/// grid lines' crossings are computed in one branch-free pass, both arcs of a
/// row come from the crossings of its two lines by min/max of integer-valued
/// floats (floor is monotone, so `floor(min(a, b)) = min(floor a, floor b)`),
/// and the two arcs of a row are two spans whatever their overlap (the second
/// starts after the first). The few rows that differ (the bottom and top rows
/// hold one arc; the leftmost and rightmost points widen their rows) are
/// patched in between, so every loop over rows is branch-free and vectorises.
#[inline(always)]
pub fn for_each_entered_block(e: &Ellipse, spec: &GridSpec, block: impl FnMut(&RowBlock)) {
    for_each_entered_block_in_rows(e, spec, 0..spec.ny, block);
}

/// [`for_each_entered_block`] restricted to the grid rows `rows`: the same
/// spans for those rows, so a map can be built band of rows by band of rows
/// (each band's cells in cache) without recording spans. A row's crossings
/// depend only on its index (`(m0 + k) − cy` with exact integer sums,
/// whatever row a block starts at), so the cells are bit for bit those of
/// the whole ellipse's walk (test `rows_in_bands_are_the_whole_walk`).
#[inline(always)]
pub fn for_each_entered_block_in_rows(
    e: &Ellipse,
    spec: &GridSpec,
    rows: std::ops::Range<usize>,
    mut block: impl FnMut(&RowBlock),
) {
    if rows.is_empty() {
        return;
    }
    if spec.nx as f64 <= MAX_FAST_COLS {
        blocks(e, spec, (rows.start as i64, rows.end as i64 - 1), block);
        return;
    }
    // Wider than any grid in memory: the reference, one row per block (its
    // spans of a row are consecutive, at most two, the second after the first).
    let mut b = RowBlock::new();
    for_each_entered_span_reference(e, spec, |j, lo, hi| {
        if !rows.contains(&j) {
            return;
        }
        let (lo, hi) = (lo as i64, hi as i64);
        if b.len == 1 && b.j0 == j {
            (b.lo2[0], b.hi2[0]) = (lo, hi);
            return;
        }
        if b.len == 1 {
            block(&b);
        }
        (b.j0, b.len) = (j, 1);
        (b.lo1[0], b.hi1[0], b.lo2[0], b.hi2[0]) = (lo, hi, 1, 0);
    });
    if b.len == 1 {
        block(&b);
    }
}

/// Calls `row(j, lo1, hi1, lo2, hi2)` for every grid row `j` the ellipse
/// enters, bottom to top ([`for_each_entered_block`] one row at a time).
pub fn for_each_entered_row(e: &Ellipse, spec: &GridSpec, mut row: impl FnMut(usize, i64, i64, i64, i64)) {
    for_each_entered_block(e, spec, |b| {
        for (j, r) in b.rows() {
            row(j, r[0], r[1], r[2], r[3]);
        }
    });
}

/// The grid rows `[first, last]` [`for_each_entered_block`] walks for `e`
/// (each one holds at least one entered cell), or `None` when the ellipse
/// misses the grid: a cheap test of whether a band of rows needs the walk.
pub fn entered_rows(e: &Ellipse, spec: &GridSpec) -> Option<(usize, usize)> {
    if spec.nx as f64 > MAX_FAST_COLS {
        let (mut first, mut last) = (None, 0);
        for_each_entered_span_reference(e, spec, |j, _, _| {
            first.get_or_insert(j);
            last = j;
        });
        return first.map(|f| (f, last));
    }
    let f = CellFrame::of(e, spec)?;
    let (first, last) = (floor_i64(f.cy - f.hy).max(0), floor_i64(f.cy + f.hy).min(spec.ny as i64 - 1));
    (first <= last).then_some((first as usize, last as usize))
}

/// An ellipse in cell units: its conic (Ellipse::conic), its half-extents
/// and its centre relative to the grid's corner, computed as the reference
/// rasteriser computes them.
struct CellFrame {
    qa: f64,
    qb: f64,
    qc: f64,
    hx: f64,
    hy: f64,
    cx: f64,
    cy: f64,
}

impl CellFrame {
    /// `None` when the ellipse's box misses the grid.
    #[inline(always)]
    fn of(e: &Ellipse, spec: &GridSpec) -> Option<Self> {
        let (qa, qb, qc, _) = e.conic();
        let inv_w = 1.0 / spec.cell_m;
        let (hx, hy) = (qc.sqrt() * inv_w, qa.sqrt() * inv_w);
        let cx = (e.center.x - spec.x_min_m) * inv_w;
        let cy = (e.center.y - spec.y_min_m) * inv_w;
        let misses = cx + hx < 0.0 || cy + hy < 0.0 || cx - hx >= spec.nx as f64 || cy - hy >= spec.ny as f64;
        (!misses).then_some(Self { qa, qb, qc, hx, hy, cx, cy })
    }
}

/// [`for_each_entered_block`] for grids of at most [`MAX_FAST_COLS`] columns,
/// in the rows `first..=last` of `rows` only.
#[inline(always)]
fn blocks(e: &Ellipse, spec: &GridSpec, rows: (i64, i64), mut block: impl FnMut(&RowBlock)) {
    let nx_f = spec.nx as f64;
    // The same quantities, computed the same way, as the reference.
    let Some(CellFrame { qa, qb, qc, hx, hy, cx, cy }) = CellFrame::of(e, spec) else { return };
    let inv_w = 1.0 / spec.cell_m;
    let ny = spec.ny as i64;
    let j_first = floor_i64(cy - hy).max(0).max(rows.0);
    let j_last = floor_i64(cy + hy).min(ny - 1).min(rows.1);
    let y_right = if qc > 0.0 { -qb * hx / (2.0 * qc) } else { 0.0 };
    let (k_mid, k_half) = if qa > 0.0 { (-qb / (2.0 * qa), e.semi_major_m * e.semi_minor_m / qa) } else { (0.0, 0.0) };
    let qa_c = qa * inv_w * inv_w;
    let last_col_f = nx_f - 1.0;
    // Columns of the leftmost and rightmost points.
    let (x_left, x_right) = (floor_clamped(cx + -hx, nx_f), floor_clamped(cx + hx, nx_f));
    let (j_bottom, j_top) = (floor_i64(cy - hy), floor_i64(cy + hy));
    let (j_left, j_right) = (floor_i64(cy - y_right), floor_i64(cy + y_right));
    // Crossing columns of the grid lines below and above each row of a block
    // (line m is the bottom edge of row m), then the rows' arcs as floats.
    let mut fl = [0.0f64; BLOCK + 1];
    let mut fr = [0.0f64; BLOCK + 1];
    let (mut lo1, mut hi1, mut lo2, mut hi2) = ([0.0f64; BLOCK], [0.0f64; BLOCK], [0.0f64; BLOCK], [0.0f64; BLOCK]);
    let mut out = RowBlock::new();
    let mut m0 = j_first;
    while m0 <= j_last {
        let n = ((j_last - m0 + 1) as usize).min(BLOCK);
        let m0_f = m0 as f64;
        for ((l, r), s) in fl[..=n].iter_mut().zip(&mut fr[..=n]).zip(&STEPS[..=n]) {
            // (m0 + k) - cy: the integer sum is exact, as in the reference.
            let y = (m0_f + s) - cy;
            // Where the curve crosses the line: x = k_mid·y ± k_half·sqrt(A − y²),
            // clamped to the ellipse's x-extent (see the reference).
            let half = k_half * max_f(qa_c - y * y, 0.0).sqrt();
            let mid = k_mid * y;
            *l = floor_clamped(cx + max_f(mid - half, -hx), nx_f);
            *r = floor_clamped(cx + min_f(mid + half, hx), nx_f);
        }
        // Two arcs per row: each spans its crossings with the row's two lines.
        for k in 0..n {
            (lo1[k], hi1[k]) = (min_f(fl[k], fl[k + 1]), max_f(fl[k], fl[k + 1]));
            (lo2[k], hi2[k]) = (min_f(fr[k], fr[k + 1]), max_f(fr[k], fr[k + 1]));
        }
        // Rows with one arc: over the bottom (top) point, between the
        // crossings of the line above (below); both in a flat ellipse's row.
        let in_block = |j: i64| (m0..m0 + n as i64).contains(&j).then(|| (j - m0) as usize);
        let single = |j: i64| j == j_bottom || j == j_top;
        if let Some(k) = in_block(j_bottom) {
            (lo1[k], hi1[k]) = if j_bottom == j_top { (x_left, x_right) } else { (fl[k + 1], fr[k + 1]) };
            (lo2[k], hi2[k]) = (nx_f + 1.0, -1.0);
        }
        if let Some(k) = in_block(j_top).filter(|_| j_top != j_bottom) {
            (lo1[k], hi1[k]) = (fl[k], fr[k]);
            (lo2[k], hi2[k]) = (nx_f + 1.0, -1.0);
        }
        // The leftmost and rightmost points widen the rows they lie in.
        if let Some(k) = in_block(j_left) {
            lo1[k] = x_left;
        }
        if let Some(k) = in_block(j_right) {
            if single(j_right) {
                hi1[k] = x_right;
            } else {
                hi2[k] = x_right;
            }
        }
        // The second arc starts after the first: two spans whatever their
        // overlap, never a cell twice. Clipped to the grid, as integers.
        for k in 0..n {
            out.lo1[k] = to_int(max_f(lo1[k], 0.0));
            out.hi1[k] = to_int(min_f(hi1[k], last_col_f));
            out.lo2[k] = to_int(max_f(max_f(lo2[k], hi1[k] + 1.0), 0.0));
            out.hi2[k] = to_int(min_f(hi2[k], last_col_f));
        }
        (out.j0, out.len) = (m0 as usize, n);
        block(&out);
        m0 += n as i64;
    }
}

/// Calls `span(row, col_lo, col_hi)` (inclusive, clipped to the grid) for
/// every run of cells the ellipse enters, row by row ([`for_each_entered_row`]).
/// Spans never overlap.
pub fn for_each_entered_span(e: &Ellipse, spec: &GridSpec, mut span: impl FnMut(usize, usize, usize)) {
    for_each_entered_row(e, spec, |j, lo1, hi1, lo2, hi2| {
        if lo1 <= hi1 {
            span(j, lo1 as usize, hi1 as usize);
        }
        if lo2 <= hi2 {
            span(j, lo2 as usize, hi2 as usize);
        }
    });
}

/// The foundation issue's row-by-row rasteriser: one crossing per grid line,
/// branches per row. Kept as the cell-for-cell oracle of
/// [`for_each_entered_row`] (issue 14 requires the maps to stay identical) and
/// as the benchmark baseline. Calls `span(row, col_lo, col_hi)` (inclusive,
/// clipped to the grid) for every run of cells the ellipse enters; spans never
/// overlap.
pub fn for_each_entered_span_reference(e: &Ellipse, spec: &GridSpec, mut span: impl FnMut(usize, usize, usize)) {
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

    /// Cells of the previous rasteriser, in the order it reports them.
    fn reference_cells(e: &Ellipse, spec: &GridSpec) -> Vec<(usize, usize)> {
        let mut v = Vec::new();
        for_each_entered_span_reference(e, spec, |j, lo, hi| v.extend((lo..=hi).map(|i| (i, j))));
        v
    }

    /// Cells of [`for_each_entered_row`] in report order, checking its
    /// contract on the way: rows ascending and reported once, spans inside
    /// the grid and the second after the first.
    fn row_cells(e: &Ellipse, spec: &GridSpec) -> Vec<(usize, usize)> {
        let mut v = Vec::new();
        let mut last_row = None;
        for_each_entered_row(e, spec, |j, lo1, hi1, lo2, hi2| {
            assert!(last_row.is_none_or(|r| r < j) && j < spec.ny, "row {j} after {last_row:?}");
            last_row = Some(j);
            for (lo, hi) in [(lo1, hi1), (lo2, hi2)] {
                if lo <= hi {
                    assert!(lo >= 0 && (hi as usize) < spec.nx, "span {lo}..={hi} outside the grid");
                    v.extend((lo as usize..=hi as usize).map(|i| (i, j)));
                }
            }
            assert!(lo1 > hi1 || lo2 > hi2 || lo2 > hi1, "spans {lo1}..={hi1} and {lo2}..={hi2} overlap");
        });
        v
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

    /// Ellipses of every kind against a grid: inside, crossing each border,
    /// bigger than the grid, thin, tiny, far away, on exact cell lines.
    fn same_cells_as_reference(e: &Ellipse, s: &GridSpec) {
        let new = row_cells(e, s);
        assert_eq!(new, reference_cells(e, s), "{e:?} on {s:?}");
    }

    #[test]
    fn row_rasteriser_equals_reference_on_edge_cases() {
        let specs = [
            spec(),
            GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 0.1, nx: 1000, ny: 1000 },
            GridSpec { x_min_m: -1.0, y_min_m: -1.0, cell_m: 0.5, nx: 1, ny: 1 },
            GridSpec { x_min_m: -3.0, y_min_m: 0.0, cell_m: 0.25, nx: 7, ny: 300 },
            GridSpec { x_min_m: 0.0, y_min_m: -3.0, cell_m: 0.25, nx: 300, ny: 7 },
        ];
        let p = Point::new;
        let cases = [
            (p(-3.0, -2.0), p(4.0, 5.5), 0.0),
            (p(-3.0, 0.0), p(4.0, 0.0), 0.0),
            (p(0.0, -3.0), p(0.0, 6.0), 0.0),
            (p(0.0, 0.0), p(10.0, 0.0), 2.0),
            (p(0.0, 0.0), p(0.0, 10.0), 2.0),
            (p(-15.0, -15.0), p(15.0, 18.0), 9.0),
            (p(-40.0, 3.0), p(40.0, 3.1), 60.0),
            (p(30.0, 30.0), p(35.0, 30.0), 1.0),
            (p(0.0, 0.0), p(0.02, 0.01), 0.03),
            (p(1e8, -1e8), p(-1e8, 1e8), 5.0),
            (p(-5e8, 2.0), p(5e8, 2.0), 1e-3),
            (p(0.05, 0.05), p(0.05, 0.15), 1e-12),
            (p(-20.0, 20.0), p(20.0, 20.0), 0.5),
        ];
        for s in &specs {
            for &(a, b, dd) in &cases {
                same_cells_as_reference(&Ellipse::new(a, b, dd).unwrap(), s);
            }
        }
    }

    #[test]
    fn row_rasteriser_equals_reference_on_benchmark_like_echoes() {
        // The accumulate benchmark's distribution (foci 10–30 m apart around
        // midpoints in ±25 m, Δd 1–40 m) on the 1000 × 1000 grid, from a
        // fixed LCG so the test is reproducible without a dev-dependency.
        let s = GridSpec { x_min_m: -50.0, y_min_m: -50.0, cell_m: 0.1, nx: 1000, ny: 1000 };
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = |lo: f64, hi: f64| {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            lo + (hi - lo) * ((x >> 11) as f64 / (1u64 << 53) as f64)
        };
        for _ in 0..2000 {
            let mid = Point::new(uniform(-25.0, 25.0), uniform(-25.0, 25.0));
            let half = uniform(10.0, 30.0) / 2.0;
            let dir = Point::from_angle(uniform(0.0, std::f64::consts::TAU));
            let dd = uniform(1.0, 40.0);
            same_cells_as_reference(&Ellipse::new(mid - dir * half, mid + dir * half, dd).unwrap(), &s);
        }
    }

    /// Blocks of [`for_each_entered_block_in_rows`] over bands of `band`
    /// rows, flattened to `(row, [lo1, hi1, lo2, hi2])`.
    fn banded_rows(e: &Ellipse, s: &GridSpec, band: usize) -> Vec<(usize, [i64; 4])> {
        let mut v = Vec::new();
        let mut start = 0;
        while start < s.ny {
            let rows = start..(start + band).min(s.ny);
            for_each_entered_block_in_rows(e, s, rows.clone(), |b| {
                assert!(rows.contains(&b.j0) && rows.contains(&(b.j0 + b.len - 1)), "block outside its rows");
                v.extend(b.rows());
            });
            start += band;
        }
        v
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        /// Walking an ellipse band of rows by band of rows gives every row
        /// the whole walk gives, with the same spans, and nothing else; and
        /// [`entered_rows`] names the first and last of them.
        #[test]
        fn rows_in_bands_are_the_whole_walk(
            sx in -25.0..25.0f64, sy in -25.0..25.0f64, lx in -25.0..25.0f64, ly in -25.0..25.0f64,
            dd in prop_oneof![Just(0.0), 0.0..0.3f64, 0.0..40.0f64],
            band in prop_oneof![Just(1usize), 1..10usize, Just(64usize), 60..70usize, Just(400usize)],
        ) {
            prop_assume!(Point::new(sx, sy).dist(Point::new(lx, ly)) > 1e-3);
            let s = spec();
            let e = Ellipse::new(Point::new(sx, sy), Point::new(lx, ly), dd).unwrap();
            let mut whole = Vec::new();
            for_each_entered_block(&e, &s, |b| whole.extend(b.rows()));
            prop_assert_eq!(&banded_rows(&e, &s, band), &whole);
            let ends = whole.first().zip(whole.last()).map(|(a, b)| (a.0, b.0));
            prop_assert_eq!(entered_rows(&e, &s), ends);
        }

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
        fn row_rasteriser_equals_reference_cell_for_cell(
            sx in -60.0..60.0f64, sy in -60.0..60.0f64, lx in -60.0..60.0f64, ly in -60.0..60.0f64,
            dd in prop_oneof![Just(0.0), 0.0..0.3f64, 0.0..80.0f64],
            x0 in -30.0..30.0f64, y0 in -30.0..30.0f64, cell in prop_oneof![Just(0.1), 0.01..2.0f64],
            nx in 1usize..300, ny in 1usize..300,
        ) {
            prop_assume!(Point::new(sx, sy).dist(Point::new(lx, ly)) > 1e-6);
            let s = GridSpec { x_min_m: x0, y_min_m: y0, cell_m: cell, nx, ny };
            let e = Ellipse::new(Point::new(sx, sy), Point::new(lx, ly), dd).unwrap();
            prop_assert_eq!(row_cells(&e, &s), reference_cells(&e, &s));
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
