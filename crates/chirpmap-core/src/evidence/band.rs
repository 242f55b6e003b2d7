//! Rasterising an echo's uncertainty band and its free interior.
//!
//! An echo with path difference Δd ± σ says the reflection point `p` has
//! `|pS| + |pL| − (D + Δd)` distributed with standard deviation σ: the
//! focal excess is the measured quantity itself, so the band is exactly the
//! region between two confocal ellipses of Eq. 4, with Δd − kσ and Δd + kσ
//! (issue 9, item 1). The free region of a measurement (item 2) is the
//! interior of its first echo's inner ellipse. Both are unions of horizontal
//! runs of cells, found row by row from the conic's roots, so the cost is
//! rows plus cells (and rows only, for the interior, with a difference array).

use crate::ellipse::Ellipse;
use crate::error::CoreError;
use crate::geometry::Point;
use crate::grid::GridSpec;

/// x-interval `[x_lo, x_hi]` (world, m) where the horizontal line at height
/// `y` crosses the filled ellipse; `None` when it misses it or the ellipse
/// has no area (Δd = 0). The row-by-row oracle's; [`RowConic::crossing`]
/// is the same arithmetic.
#[cfg(test)]
fn row_interval(e: &Ellipse, y: f64) -> Option<(f64, f64)> {
    if e.semi_minor_m <= 0.0 {
        return None;
    }
    let (qa, qb, qc, qf) = e.conic();
    let yr = y - e.center.y;
    // A X² + (B Y) X + (C Y² + F) = 0 in coordinates relative to the centre.
    let (b1, c0) = (qb * yr, qc * yr * yr + qf);
    let disc = b1 * b1 - 4.0 * qa * c0;
    if disc < 0.0 || qa <= 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    Some((e.center.x + (-b1 - sq) / (2.0 * qa), e.center.x + (-b1 + sq) / (2.0 * qa)))
}

/// `x.ceil()` without a libm call where that is exact (|x| < 2⁵², where the
/// integer conversion is exact; the default x86-64 target has no rounding
/// instruction), else (huge, infinite or NaN) `f64::ceil`. Only the sign of
/// a zero result can differ (0 for −0), which no comparison or clamp sees.
#[inline]
fn ceil(x: f64) -> f64 {
    if x.abs() < 4_503_599_627_370_496.0 {
        let t = x as i64 as f64;
        if t < x { t + 1.0 } else { t }
    } else {
        x.ceil()
    }
}

/// `x.floor()`, as [`ceil`].
#[inline]
fn floor(x: f64) -> f64 {
    if x.abs() < 4_503_599_627_370_496.0 {
        let t = x as i64 as f64;
        if t > x { t - 1.0 } else { t }
    } else {
        x.floor()
    }
}

/// Column range `[lo, hi]` of cells whose centres lie in `[x_lo, x_hi]`,
/// clipped to the grid; `None` if empty (the row-by-row oracle's).
#[cfg(test)]
fn centre_cols(spec: &GridSpec, x_lo: f64, x_hi: f64) -> Option<(usize, usize)> {
    let lo = ceil((x_lo - spec.x_min_m) / spec.cell_m - 0.5).max(0.0);
    let hi = floor((x_hi - spec.x_min_m) / spec.cell_m - 0.5).min(spec.nx as f64 - 1.0);
    (lo <= hi).then_some((lo as usize, hi as usize))
}

/// Rows `[lo, hi]` whose cell centres can meet the ellipse's bounding box.
fn rows_of(e: &Ellipse, spec: &GridSpec) -> Option<(usize, usize)> {
    let (lo, hi) = e.bbox();
    let j_lo = ceil((lo.y - spec.y_min_m) / spec.cell_m - 0.5).max(0.0);
    let j_hi = floor((hi.y - spec.y_min_m) / spec.cell_m - 0.5).min(spec.ny as f64 - 1.0);
    (j_lo <= j_hi).then_some((j_lo as usize, j_hi as usize))
}

/// Calls `span(row, col_lo, col_hi)` (inclusive) for the cells whose centre
/// `p` satisfies `D + dd_lo_m ≤ |pS| + |pL| ≤ D + dd_hi_m`: the band between
/// the confocal ellipses of `dd_lo_m` and `dd_hi_m`. `dd_lo_m ≤ 0` means no
/// inner ellipse (the filled outer ellipse). At most two spans per row, never
/// overlapping. Errors on non-finite or invalid foci and on `dd_hi_m < 0`.
pub fn for_each_band_span(
    source: Point,
    listener: Point,
    dd_lo_m: f64,
    dd_hi_m: f64,
    spec: &GridSpec,
    span: impl FnMut(usize, usize, usize),
) -> Result<(), CoreError> {
    if let Some(band) = Band::new(source, listener, dd_lo_m, dd_hi_m, spec)? {
        band.spans_in_rows(spec, 0..spec.ny, span);
    }
    Ok(())
}

/// One echo's band ([`for_each_band_span`]) with its ellipses and rows
/// computed once, so that its spans can be walked a few rows at a time
/// (a band of grid rows per thread: ring deposits, issue 14).
#[derive(Debug, Clone)]
pub(crate) struct Band {
    outer: Ellipse,
    inner: Option<Ellipse>,
    /// Rows `[lo, hi]` the band can enter.
    rows: (usize, usize),
}

impl Band {
    /// The band of `dd_lo_m..=dd_hi_m`, `None` when it enters no row of the
    /// grid or is empty; the errors of [`for_each_band_span`].
    pub(crate) fn new(
        source: Point,
        listener: Point,
        dd_lo_m: f64,
        dd_hi_m: f64,
        spec: &GridSpec,
    ) -> Result<Option<Self>, CoreError> {
        let outer = Ellipse::new(source, listener, dd_hi_m)?;
        let inner =
            if dd_lo_m > 0.0 && dd_lo_m < dd_hi_m { Some(Ellipse::new(source, listener, dd_lo_m)?) } else { None };
        if dd_lo_m >= dd_hi_m && dd_lo_m > 0.0 {
            return Ok(None);
        }
        Ok(rows_of(&outer, spec).map(|rows| Self { outer, inner, rows }))
    }

    /// Rows `[lo, hi]` the band can enter.
    pub(crate) fn rows(&self) -> (usize, usize) {
        self.rows
    }

    /// [`for_each_band_span`]'s spans in the grid rows `rows` only.
    ///
    /// Rows go in chunks: first each row's crossings of both ellipses, in
    /// cell units, in a loop without branches (the square roots and
    /// divisions of many rows in flight at once), then the spans from them.
    /// Row by row, each row's chain of a square root and four divisions ran
    /// one at a time between unpredictable branches: 9.5 % of a Table I 1 ms
    /// `simulate` with the evidence mapper, walking the rings.
    /// The arithmetic is the same, so are the spans (test
    /// `chunked_spans_are_row_by_row`).
    #[inline(always)]
    pub(crate) fn spans_in_rows(
        &self,
        spec: &GridSpec,
        rows: std::ops::Range<usize>,
        mut span: impl FnMut(usize, usize, usize),
    ) {
        const CHUNK: usize = 64;
        let (j_lo, j_hi) = (self.rows.0.max(rows.start), self.rows.1.min(rows.end.saturating_sub(1)));
        if rows.is_empty() || j_lo > j_hi {
            return;
        }
        let outer = RowConic::of(&self.outer);
        let inner = self.inner.as_ref().map(RowConic::of);
        let mut o = [Crossing::default(); CHUNK];
        let mut i = [Crossing::default(); CHUNK];
        let mut start = j_lo;
        while start <= j_hi {
            let m = (j_hi + 1 - start).min(CHUNK);
            for (r, c) in o[..m].iter_mut().enumerate() {
                *c = outer.crossing(spec, start + r);
            }
            if let Some(inner) = &inner {
                for (r, c) in i[..m].iter_mut().enumerate() {
                    *c = inner.crossing(spec, start + r);
                }
            }
            for r in 0..m {
                let j = start + r;
                let co = o[r];
                if !co.hit {
                    continue;
                }
                match inner.as_ref().map(|_| i[r]).filter(|ci| ci.hit) {
                    None => {
                        if let Some((lo, hi)) = cols_of(spec, co.lo, co.hi) {
                            span(j, lo, hi);
                        }
                    }
                    Some(ci) => {
                        // Centres strictly inside the inner ellipse are
                        // excluded; those on it belong to the band.
                        let left = cols_of(spec, co.lo, ci.lo);
                        if let Some((lo, hi)) = left {
                            span(j, lo, hi);
                        }
                        if let Some((lo, hi)) = cols_of(spec, ci.hi, co.hi) {
                            // A boundary cell shared by both halves (a
                            // degenerate inner interval) is reported once.
                            let lo_right = match left {
                                Some((_, left_hi)) if left_hi >= lo => left_hi + 1,
                                _ => lo,
                            };
                            if lo_right <= hi {
                                span(j, lo_right, hi);
                            }
                        }
                    }
                }
            }
            start += m;
        }
    }

    /// The row-by-row walk [`Band::spans_in_rows`] replaced: the oracle of
    /// test `chunked_spans_are_row_by_row`.
    #[cfg(test)]
    fn spans_in_rows_one_by_one(
        &self,
        spec: &GridSpec,
        rows: std::ops::Range<usize>,
        mut span: impl FnMut(usize, usize, usize),
    ) {
        let (j_lo, j_hi) = (self.rows.0.max(rows.start), self.rows.1.min(rows.end.saturating_sub(1)));
        if rows.is_empty() || j_lo > j_hi {
            return;
        }
        for j in j_lo..=j_hi {
            let y = spec.y_min_m + (j as f64 + 0.5) * spec.cell_m;
            let Some((xo_lo, xo_hi)) = row_interval(&self.outer, y) else { continue };
            match self.inner.as_ref().and_then(|e| row_interval(e, y)) {
                None => {
                    if let Some((lo, hi)) = centre_cols(spec, xo_lo, xo_hi) {
                        span(j, lo, hi);
                    }
                }
                Some((xi_lo, xi_hi)) => {
                    if let Some((lo, hi)) = centre_cols(spec, xo_lo, xi_lo) {
                        span(j, lo, hi);
                    }
                    if let Some((lo, hi)) = centre_cols(spec, xi_hi, xo_hi) {
                        let lo_right = match centre_cols(spec, xo_lo, xi_lo) {
                            Some((_, left_hi)) if left_hi >= lo => left_hi + 1,
                            _ => lo,
                        };
                        if lo_right <= hi {
                            span(j, lo_right, hi);
                        }
                    }
                }
            }
        }
    }
}

/// Where grid row `j`'s centre line crosses a filled ellipse, in cell units
/// (`(x − x_min) / cell − 0.5`, so the cells whose centres lie inside are
/// `ceil(lo)..=floor(hi)`); `hit` false when it misses, where the
/// row-by-row oracle's `row_interval` gives `None`.
#[derive(Debug, Clone, Copy, Default)]
struct Crossing {
    lo: f64,
    hi: f64,
    hit: bool,
}

/// An ellipse's implicit conic about its centre (as the oracle's
/// `row_interval` uses it), computed once per band instead of once per row
/// (the same values).
#[derive(Debug, Clone, Copy)]
struct RowConic {
    cx: f64,
    cy: f64,
    qa: f64,
    qb: f64,
    qc: f64,
    qf: f64,
    /// The ellipse has area and `qa > 0` (`row_interval`'s other tests; a
    /// NaN axis, which `Ellipse::new`'s finite inputs rule out, would fail
    /// here where `row_interval` let it through).
    usable: bool,
}

impl RowConic {
    fn of(e: &Ellipse) -> Self {
        let (qa, qb, qc, qf) = e.conic();
        RowConic { cx: e.center.x, cy: e.center.y, qa, qb, qc, qf, usable: e.semi_minor_m > 0.0 && qa > 0.0 }
    }
    /// The oracle's `row_interval` at row `j`'s centre line and
    /// `centre_cols`' scaling, operation for operation, without a branch.
    #[inline(always)]
    fn crossing(&self, spec: &GridSpec, j: usize) -> Crossing {
        let y = spec.y_min_m + (j as f64 + 0.5) * spec.cell_m;
        let yr = y - self.cy;
        let (b1, c0) = (self.qb * yr, self.qc * yr * yr + self.qf);
        let disc = b1 * b1 - 4.0 * self.qa * c0;
        let sq = disc.sqrt();
        let (x_lo, x_hi) = (self.cx + (-b1 - sq) / (2.0 * self.qa), self.cx + (-b1 + sq) / (2.0 * self.qa));
        Crossing {
            lo: (x_lo - spec.x_min_m) / spec.cell_m - 0.5,
            hi: (x_hi - spec.x_min_m) / spec.cell_m - 0.5,
            // A NaN passes, as in `row_interval` (which tests `disc < 0`).
            hit: self.usable & (disc >= 0.0 || disc.is_nan()),
        }
    }
}

/// The oracle's `centre_cols` from positions already in cell units.
#[inline(always)]
fn cols_of(spec: &GridSpec, u_lo: f64, u_hi: f64) -> Option<(usize, usize)> {
    let lo = ceil(u_lo).max(0.0);
    let hi = floor(u_hi).min(spec.nx as f64 - 1.0);
    (lo <= hi).then_some((lo as usize, hi as usize))
}

/// Naive oracle for [`for_each_band_span`]: tests every cell centre.
pub fn band_cells_naive(
    source: Point,
    listener: Point,
    dd_lo_m: f64,
    dd_hi_m: f64,
    spec: &GridSpec,
    mut cell: impl FnMut(usize, usize),
) {
    let d = source.dist(listener);
    for j in 0..spec.ny {
        for i in 0..spec.nx {
            let s = spec.cell_center(i, j);
            let sum = s.dist(source) + s.dist(listener);
            let inside_outer = sum <= d + dd_hi_m;
            let outside_inner = dd_lo_m <= 0.0 || sum >= d + dd_lo_m;
            if inside_outer && outside_inner {
                cell(i, j);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Walking a band a few rows at a time (as the ring deposits do, one
        /// band of rows per thread) gives exactly the spans of the whole walk,
        /// in the same order.
        #[test]
        fn spans_by_rows_are_the_whole_walk(
            sx in -8.0..8.0f64, sy in -8.0..8.0f64, lx in -8.0..8.0f64, ly in -8.0..8.0f64,
            dd in 0.0..8.0f64, half in 0.0..2.0f64, rows_per_part in 1usize..40,
        ) {
            let (s, l) = (Point::new(sx, sy), Point::new(lx, ly));
            prop_assume!(s.dist(l) > 0.01);
            let spec = GridSpec { x_min_m: -10.013, y_min_m: -9.9871, cell_m: 0.1, nx: 200, ny: 190 };
            let mut whole = Vec::new();
            for_each_band_span(s, l, dd - half, dd + half, &spec, |j, lo, hi| whole.push((j, lo, hi))).expect("band");
            let mut parts = Vec::new();
            if let Some(band) = Band::new(s, l, dd - half, dd + half, &spec).expect("band") {
                for start in (0..spec.ny).step_by(rows_per_part) {
                    let rows = start..(start + rows_per_part).min(spec.ny);
                    let mut outside = 0;
                    band.spans_in_rows(&spec, rows.clone(), |j, lo, hi| {
                        outside += usize::from(!rows.contains(&j));
                        parts.push((j, lo, hi));
                    });
                    prop_assert_eq!(outside, 0, "a span outside rows {:?}", rows);
                }
            }
            prop_assert_eq!(whole, parts);
        }

        /// The chunked walk gives the row-by-row walk's spans exactly, in
        /// the same order: bands with and without an inner ellipse, thin
        /// and degenerate ones, foci on and off the grid, row ranges that
        /// cut chunks anywhere.
        #[test]
        fn chunked_spans_are_row_by_row(
            sx in -30.0..30.0f64, sy in -30.0..30.0f64, lx in -30.0..30.0f64, ly in -30.0..30.0f64,
            dd in 0.0..40.0f64, half in prop_oneof![Just(0.0), 0.0..0.05f64, 0.0..3.0f64],
            cell in prop_oneof![Just(0.1), 0.013..0.5f64], first in 0usize..300, len in 0usize..400,
        ) {
            let (s, l) = (Point::new(sx, sy), Point::new(lx, ly));
            prop_assume!(s.dist(l) > 1e-6);
            let spec = GridSpec { x_min_m: -20.013, y_min_m: -19.9871, cell_m: cell, nx: 257, ny: 300 };
            if let Some(band) = Band::new(s, l, dd - half, dd + half, &spec).expect("band") {
                let rows = first..(first + len).min(spec.ny);
                let (mut got, mut want) = (Vec::new(), Vec::new());
                band.spans_in_rows(&spec, rows.clone(), |j, lo, hi| got.push((j, lo, hi)));
                band.spans_in_rows_one_by_one(&spec, rows, |j, lo, hi| want.push((j, lo, hi)));
                prop_assert_eq!(got, want);
            }
        }
    }
}
