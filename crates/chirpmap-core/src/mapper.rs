//! Mappers turn echoes into a map; highlight extraction turns a map into
//! likely obstacle surface points (paper §II.C, Algorithm 1).

use crate::echo::Echo;
use crate::ellipse::Ellipse;
use crate::error::CoreError;
use crate::evidence::EvidenceParams;
use crate::geometry::Point;
use crate::grid::{Grid, GridSpec};
#[cfg(test)]
use crate::raster::for_each_entered_span;
use crate::raster::{entered_rows, for_each_entered_block_in_rows};
use serde::{Deserialize, Serialize};

/// The four numbers of Algorithm 1's post-processing, paper values by default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MappingParams {
    /// Grid cell side (m). Paper: 0.1.
    pub cell: f64,
    /// Fraction of non-zero cells kept by the percentile threshold. Paper: 0.1
    /// (the bottom 90 % are zeroed).
    pub keep_top: f64,
    /// Cells below this fraction of the maximum are zeroed. Paper: 0.01.
    pub min_of_max: f64,
    /// A highlight is the maximum within this radius (m). Paper: 5 (50 cells).
    pub peak_radius: f64,
    /// 0 (default): Algorithm 1 as the paper states it, each ellipse adds its
    /// weight once to every cell it enters. N > 0: the authors' implementation
    /// as §II.C describes it, N points evenly spaced in eccentric anomaly
    /// "placed into the bins", so a cell gets one weight per point in it (and
    /// thin parts of a long ellipse may skip cells). For comparison runs.
    pub ellipse_points: u32,
    /// Which mapper turns echoes into a map: `paper` (Algorithm 1, default, so
    /// the paper's tables stay reproducible) or `evidence` (issue 9).
    pub mapper: MapperKind,
    /// The evidence mapper's parameters, the `[mapping.evidence]` table.
    pub evidence: EvidenceParams,
}

/// The mapper selected by `[mapping] mapper = "..."`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MapperKind {
    /// Algorithm 1 of the paper ([`AccumulationMapper`]).
    #[default]
    Paper,
    /// The evidence mapper ([`crate::evidence::map_evidence`]).
    Evidence,
}

impl Default for MappingParams {
    fn default() -> Self {
        Self {
            cell: 0.1,
            keep_top: 0.1,
            min_of_max: 0.01,
            peak_radius: 5.0,
            ellipse_points: 0,
            mapper: MapperKind::Paper,
            evidence: EvidenceParams::default(),
        }
    }
}

/// Largest `ellipse_points`: every echo costs this many point placements, so
/// 4294967295 ran for hours (issue 8, item 10); the authors' reading needs a
/// few thousand (EXPERIMENTS.md compares 1000 and 3600).
pub const MAX_ELLIPSE_POINTS: u32 = 100_000;

impl MappingParams {
    /// Checks every parameter's range; the error names the first bad field.
    pub fn validate(&self) -> Result<(), CoreError> {
        let bad = |field: &'static str, reason: &str| Err(CoreError::InvalidParam { field, reason: reason.into() });
        if !(self.cell.is_finite() && self.cell > 0.0) {
            return bad("cell", "must be finite and > 0");
        }
        if !(self.keep_top > 0.0 && self.keep_top <= 1.0) {
            return bad("keep_top", "must be in (0, 1]");
        }
        if !(0.0..=1.0).contains(&self.min_of_max) {
            return bad("min_of_max", "must be in [0, 1]");
        }
        if !(self.peak_radius.is_finite() && self.peak_radius >= 0.0) {
            return bad("peak_radius", "must be finite and >= 0");
        }
        if self.ellipse_points > MAX_ELLIPSE_POINTS {
            return Err(CoreError::InvalidParam {
                field: "ellipse_points",
                reason: format!("must be at most {MAX_ELLIPSE_POINTS}, got {}", self.ellipse_points),
            });
        }
        self.evidence.validate()
    }

    /// Window radius in cells, ⌊peak_radius / w⌋ as in Algorithm 1.
    pub fn peak_radius_cells(&self) -> usize {
        // `as` saturates, and local_maxima clamps to the grid size.
        (self.peak_radius / self.cell + 1e-9).floor() as usize
    }
}

/// A likely obstacle location: the centre of a locally maximal cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Highlight {
    /// Centre of the locally maximal cell (m).
    pub pos: Point,
    /// Accumulated value of that cell.
    pub value: f64,
}

/// What every mapper offers: take echoes one at a time, expose a map, and
/// extract highlights from it. The probabilistic mapper plugs in here.
pub trait Mapper {
    /// Adds one echo's evidence.
    fn add_echo(&mut self, echo: &Echo) -> Result<(), CoreError>;
    /// Adds the echoes in order, stopping at the first that fails (the ones
    /// before it stay added), exactly as [`Mapper::add_echo`] one by one
    /// would; a mapper may do it faster in batches.
    fn add_echoes(&mut self, echoes: &[Echo]) -> Result<(), CoreError> {
        echoes.iter().try_for_each(|e| self.add_echo(e))
    }
    /// The current map.
    fn grid(&self) -> &Grid;
    /// Highlights of the current map.
    fn highlights(&self) -> Vec<Highlight>;
}

/// Algorithm 1: each ellipse adds its weight once to every cell it enters.
///
/// (An 8 × 8-tiled layout was tried for cache locality of steep arcs and
/// measured no faster than rows; see BENCHMARKS.md. What does pay is
/// [`Mapper::add_echoes`]'s banding, see [`band_shift`].)
#[derive(Debug, Clone)]
pub struct AccumulationMapper {
    grid: Grid,
    params: MappingParams,
    cells_updated: u64,
    /// Upper bound on any cell's value: the sum of every added weight times
    /// the most times one echo can add it to a cell. While it is finite no
    /// cell can overflow to infinity (issue 8, item 7).
    max_cell_bound: f64,
}

/// Bytes of grid per band of rows: a band's cells stay in the core's L2
/// cache (≥ 512 KiB on the machines measured) while its echoes are added.
const BAND_BYTES: usize = 512 << 10;

/// Echoes checked before they are added in one banded pass: bounds the
/// memory of their ellipses (~100 bytes each) whatever the number of
/// echoes (100 in tests, so that batches split).
const MAX_BATCH_ECHOES: usize = if cfg!(test) { 100 } else { 1 << 16 };

/// Cache blocking of Algorithm 1's accumulation (issue 14): the grid is cut
/// into horizontal bands of `2^shift` rows ([`BAND_BYTES`] each), and each
/// band walks every echo of a batch in order, rasterising only the rows it
/// holds ([`for_each_entered_block_in_rows`]) and adding them while the band
/// sits in L2. An ellipse's rows are 8 KB apart on the default grid, so
/// adding an echo's spans as they are rasterised touches a new cache line of
/// an L3-resident grid per span; banding ran the 10 000 benchmark echoes 3×
/// faster (BENCHMARKS.md). Bands run on rayon's threads; every cell lies in
/// one band and receives its additions in echo order, so the sums are
/// bit-identical to adding echo after echo, whatever the thread count.
///
/// (Until session 19 the spans were first dealt into per-band record lists,
/// up to 8 MB of fresh memory per batch, then replayed band by band; the
/// band walking its echoes needs no record and writes each span once.)
///
/// `None` when banding cannot pay (one band covers the grid).
fn band_shift(spec: &GridSpec) -> Option<u32> {
    let nx = spec.nx.max(1);
    let rows = (BAND_BYTES / 8 / nx).max(1);
    let shift = usize::BITS - 1 - rows.leading_zeros();
    let n_bands = spec.ny.div_ceil(1 << shift);
    (n_bands >= 2).then_some(shift)
}

/// Spans up to this long are added with one fixed-width, branch-free write.
const SHORT_SPAN: usize = 4;

/// `masks[len]`: `w` in the first `len` of [`SHORT_SPAN`] lanes, 0 after.
fn span_masks(w: f64) -> [[f64; SHORT_SPAN]; SHORT_SPAN + 1] {
    let mut masks = [[0.0f64; SHORT_SPAN]; SHORT_SPAN + 1];
    for (len, m) in masks.iter_mut().enumerate() {
        m[..len].fill(w);
    }
    masks
}

/// Adds `w` to cells `start..start + len` of `data`. A span of at most
/// [`SHORT_SPAN`] cells is one fixed-width write of `masks[len]`: `w` to its
/// cells and `+0.0` to the cells after it, which changes no value (cells are
/// never −0 or NaN), so no branch depends on the span's length; longer spans
/// (and spans at the very end of `data`) go cell by cell.
#[inline(always)]
fn add_span(data: &mut [f64], start: usize, len: usize, w: f64, masks: &[[f64; SHORT_SPAN]; SHORT_SPAN + 1]) {
    match data.get_mut(start..start + SHORT_SPAN) {
        Some(cells) if len <= SHORT_SPAN => {
            for (c, m) in cells.iter_mut().zip(&masks[len]) {
                *c += m;
            }
        }
        _ => {
            for c in &mut data[start..start + len] {
                *c += w;
            }
        }
    }
}

impl AccumulationMapper {
    /// Mapper on the grid `spec`; errors when `params` fail
    /// [`MappingParams::validate`].
    pub fn new(spec: GridSpec, params: MappingParams) -> Result<Self, CoreError> {
        params.validate()?;
        Ok(Self { grid: Grid::zeros_prefaulted(spec), params, cells_updated: 0, max_cell_bound: 0.0 })
    }

    /// Total cell updates so far (for benchmarks and progress reporting).
    pub fn cells_updated(&self) -> u64 {
        self.cells_updated
    }

    /// The accumulated grid, without copying it.
    pub fn into_grid(self) -> Grid {
        self.grid
    }

    fn accumulate(&mut self, echo: &Echo) -> Result<(), CoreError> {
        let e = self.check(echo)?;
        let spec = self.grid.spec;
        let (data, w) = (&mut self.grid.data, echo.weight);
        let mut n = 0u64;
        if self.params.ellipse_points > 0 {
            let step = std::f64::consts::TAU / f64::from(self.params.ellipse_points);
            for k in 0..self.params.ellipse_points {
                if let Some((i, j)) = spec.cell_of(e.point_at(f64::from(k) * step)) {
                    data[j * spec.nx + i] += w;
                    n += 1;
                }
            }
        } else {
            n = add_ellipse(&e, &spec, data, w);
        }
        self.cells_updated += n;
        Ok(())
    }

    /// Validates `echo` (its ellipse, its weight, and that no cell can
    /// overflow) and counts its weight in the bound; changes no cell.
    fn check(&mut self, echo: &Echo) -> Result<Ellipse, CoreError> {
        let e = echo.ellipse()?;
        // `Echo`'s fields are public, so check the weight here too, and refuse
        // an echo that could make a cell infinite (the plot's colour bar over
        // 0..inf hung `map`): checked before any cell changes.
        if !(echo.weight.is_finite() && echo.weight >= 0.0) {
            return Err(CoreError::InvalidParam {
                field: "weight",
                reason: format!("must be finite and >= 0, got {}", crate::error::Num(echo.weight)),
            });
        }
        let per_cell = f64::from(self.params.ellipse_points.max(1));
        let bound = self.max_cell_bound + echo.weight * per_cell;
        if !bound.is_finite() {
            return Err(CoreError::InvalidParam {
                field: "weight",
                reason: format!(
                    "the echoes' weights add up beyond the largest number ({}); a cell of the map would be \
                     infinite. Scale the weights down",
                    crate::error::Num(f64::MAX)
                ),
            });
        }
        self.max_cell_bound = bound;
        Ok(e)
    }

    /// [`Mapper::add_echoes`] by bands of `2^shift` rows ([`band_shift`]):
    /// the same cells get the same additions in the same order as
    /// echo-by-echo accumulation. Echoes are checked in order (the map gets
    /// every echo before the first bad one, like [`Mapper::add_echo`]) and
    /// added in batches of at most [`MAX_BATCH_ECHOES`].
    fn add_banded(&mut self, echoes: &[Echo], shift: u32) -> Result<(), CoreError> {
        let mut batch: Vec<(Ellipse, f64)> = Vec::with_capacity(echoes.len().min(MAX_BATCH_ECHOES));
        for echo in echoes {
            let e = match self.check(echo) {
                Ok(e) => e,
                Err(err) => {
                    self.add_batch(&batch, shift);
                    return Err(err);
                }
            };
            if batch.len() == MAX_BATCH_ECHOES {
                self.add_batch(&batch, shift);
                batch.clear();
            }
            batch.push((e, echo.weight));
        }
        self.add_batch(&batch, shift);
        Ok(())
    }

    /// Adds `batch` band by band, the bands on rayon's threads.
    fn add_batch(&mut self, batch: &[(Ellipse, f64)], shift: u32) {
        use rayon::prelude::*;
        if batch.is_empty() {
            return;
        }
        let spec = self.grid.spec;
        let rows: Vec<Option<(usize, usize)>> = batch.iter().map(|(e, _)| entered_rows(e, &spec)).collect();
        let arch = pulp::Arch::new();
        self.cells_updated += self
            .grid
            .data
            .par_chunks_mut(spec.nx << shift)
            .enumerate()
            .map(|(b, cells)| {
                let first_row = b << shift;
                let band = first_row..first_row + cells.len() / spec.nx;
                arch.dispatch(AddBand { cells, band, batch, rows: &rows, spec: &spec })
            })
            .sum::<u64>();
    }
}

/// One band's cells walking a batch of ellipses in order
/// ([`for_each_entered_block_in_rows`]), compiled for the widest vectors the
/// CPU has ([`pulp`]'s runtime dispatch): the rasteriser's branch-free row
/// passes. No operation is fused, so the spans are the same either way.
struct AddBand<'a> {
    /// The band's cells, from its first row's first cell.
    cells: &'a mut [f64],
    /// The band's grid rows.
    band: std::ops::Range<usize>,
    batch: &'a [(Ellipse, f64)],
    /// Each ellipse's [`entered_rows`].
    rows: &'a [Option<(usize, usize)>],
    spec: &'a GridSpec,
}

impl pulp::WithSimd for AddBand<'_> {
    type Output = u64;
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> u64 {
        let Self { cells, band, batch, rows, spec } = self;
        let mut n = 0u64;
        for ((e, w), rows) in batch.iter().zip(rows) {
            if rows.is_some_and(|(first, last)| first < band.end && last >= band.start) {
                n += add_ellipse_in_rows(e, spec, band.clone(), cells, *w);
            }
        }
        n
    }
}

impl Mapper for AccumulationMapper {
    fn add_echo(&mut self, echo: &Echo) -> Result<(), CoreError> {
        self.accumulate(echo)
    }
    fn add_echoes(&mut self, echoes: &[Echo]) -> Result<(), CoreError> {
        match band_shift(&self.grid.spec).filter(|_| self.params.ellipse_points == 0) {
            Some(shift) => self.add_banded(echoes, shift),
            None => echoes.iter().try_for_each(|e| self.accumulate(e)),
        }
    }
    fn grid(&self) -> &Grid {
        &self.grid
    }
    fn highlights(&self) -> Vec<Highlight> {
        let (g, r, mut scratch) = (&self.grid, self.params.peak_radius_cells(), Vec::new());
        let (keep_top, min_of_max) = (self.params.keep_top, self.params.min_of_max);
        // `local_maxima_above(g, r, threshold_floor(..))`, with the survivors
        // gathered while the floor is found; None only when every cell is 0.
        let found = quantile_floor(&g.data, keep_top, min_of_max, &mut scratch, Some((g.spec.nx, survivor_limit(g))));
        found.map_or_else(Vec::new, |(floor, cells)| maxima_of(g, r, floor, cells, &mut scratch))
    }
}

/// Adds `w` once to every cell `e` enters (Algorithm 1's inner loop, one
/// echo at a time) and returns how many cells that is. Short spans are
/// written branch-free with `+0.0` in the lanes after them (see the mapper's
/// `add_span`), so `data` must hold no −0.0 (it would become +0.0).
pub fn add_ellipse(e: &Ellipse, spec: &GridSpec, data: &mut [f64], w: f64) -> u64 {
    add_ellipse_in_rows(e, spec, 0..spec.ny, data, w)
}

/// [`add_ellipse`] in the grid rows `rows` only, `cells` holding those rows
/// (from row `rows.start`): one band's part of an echo ([`band_shift`]).
#[inline(always)]
fn add_ellipse_in_rows(e: &Ellipse, spec: &GridSpec, rows: std::ops::Range<usize>, cells: &mut [f64], w: f64) -> u64 {
    let masks = span_masks(w);
    let nx = spec.nx;
    let mut n = 0u64;
    let first_row = rows.start;
    for_each_entered_block_in_rows(e, spec, rows, |b| {
        let mut base = (b.j0 - first_row) * nx;
        for r in 0..b.len {
            for (lo, hi) in [(b.lo1[r], b.hi1[r]), (b.lo2[r], b.hi2[r])] {
                if lo <= hi {
                    let len = (hi - lo + 1) as usize;
                    add_span(cells, base + lo as usize, len, w, &masks);
                    n += len as u64;
                }
            }
            base += nx;
        }
    });
    n
}

/// Algorithm 1's thresholding: zero cells below the (1 − keep_top) quantile of
/// the non-zero cells and cells below `min_of_max · max`. The quantile is the
/// value at rank ⌊(1 − keep_top)·n⌋ (0-based, ascending) of the n non-zero cells.
pub fn threshold(data: &mut [f64], keep_top: f64, min_of_max: f64) {
    if let Some(floor) = threshold_floor(data, keep_top, min_of_max, &mut Vec::new()) {
        for v in data.iter_mut() {
            if *v < floor {
                *v = 0.0;
            }
        }
    }
}

/// The value below which [`threshold`] zeroes a cell, without changing the
/// data (`None` when no cell is non-zero: nothing changes). `scratch`
/// receives the candidates of the quantile's bucket (kept for its capacity).
pub fn threshold_floor(data: &[f64], keep_top: f64, min_of_max: f64, scratch: &mut Vec<f64>) -> Option<f64> {
    quantile_floor(data, keep_top, min_of_max, scratch, None).map(|(floor, _)| floor)
}

/// [`threshold_floor`], and with `cells = Some((nx, limit))` the
/// [`survivors`] of that floor (gathered in the same pass) when at most
/// `limit` cells can be among them.
///
/// The quantile is found by a radix select (issue 14): one parallel pass
/// counts the non-zero cells by the top [`QUANTILE_BUCKET_BITS`] bits of
/// their [`f64::total_cmp`] key (sign, exponent and the first mantissa
/// bits), which names the bucket holding the wanted rank; a second pass
/// gathers only that bucket's values (and the cells of it and the buckets
/// above, which hold every survivor) and selects within them. The counts are
/// exact and order-free, so the value is the one a full sort would pick,
/// whatever the thread count, without copying every non-zero cell.
fn quantile_floor(
    data: &[f64],
    keep_top: f64,
    min_of_max: f64,
    scratch: &mut Vec<f64>,
    cells: Option<(usize, usize)>,
) -> Option<(f64, Option<Survivors>)> {
    use rayon::prelude::*;
    let buckets = 1usize << QUANTILE_BUCKET_BITS;
    let bucket_of = |v: f64| (total_order_key(v) >> (64 - QUANTILE_BUCKET_BITS)) as usize;
    // Pass 1, a few contiguous parts per thread: each counts into its own u32
    // counters (a part has fewer than 2³² cells), summed after; f64::max
    // ignores NaN, so the maximum does not depend on the order either.
    let part_len = data.len().div_ceil(2 * rayon::current_num_threads().max(1)).clamp(SCAN_CHUNK, u32::MAX as usize);
    let parts: Vec<(Vec<u32>, f64)> = data
        .par_chunks(part_len)
        .map(|c| {
            let mut counts = vec![0u32; buckets];
            for &v in c.iter().filter(|v| **v != 0.0) {
                counts[bucket_of(v)] += 1;
            }
            (counts, c.iter().copied().fold(f64::NEG_INFINITY, f64::max))
        })
        .collect();
    let mut counts = vec![0u64; buckets];
    let mut max = f64::NEG_INFINITY;
    for (c, m) in &parts {
        counts.iter_mut().zip(c).for_each(|(x, y)| *x += u64::from(*y));
        max = max.max(*m);
    }
    let n = usize::try_from(counts.iter().sum::<u64>()).ok()?;
    if n == 0 {
        return None;
    }
    let rank = (((1.0 - keep_top) * n as f64).floor() as usize).min(n - 1);
    // The bucket holding `rank`, and how many non-zero cells lie below it.
    let mut below = 0usize;
    let mut bucket = 0;
    for (b, &c) in counts.iter().enumerate() {
        let c = c as usize;
        if below + c > rank {
            bucket = b;
            break;
        }
        below += c;
    }
    // Every survivor (at or above the quantile, positive) is in `bucket` or
    // above it: gathered when those are few enough.
    let gather = cells.filter(|&(_, limit)| n - below <= limit).map(|(nx, _)| nx);
    // Pass 2: that bucket's values (zero is never in it: its count has none).
    let parts: Vec<(Vec<f64>, Survivors)> = data
        .par_chunks(SCAN_CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let (mut values, mut kept) = (Vec::new(), Vec::new());
            for (k, &v) in chunk.iter().enumerate().filter(|(_, v)| **v != 0.0) {
                let b = bucket_of(v);
                if b == bucket {
                    values.push(v);
                }
                if let Some(nx) = gather.filter(|_| b >= bucket && v > 0.0) {
                    let at = c * SCAN_CHUNK + k;
                    kept.push((at % nx, at / nx, v));
                }
            }
            (values, kept)
        })
        .collect();
    scratch.clear();
    parts.iter().for_each(|(values, _)| scratch.extend_from_slice(values));
    let (_, q, _) = scratch.select_nth_unstable_by(rank - below, f64::total_cmp);
    let floor = q.max(min_of_max * max);
    // The gathered cells hold every survivor only when the floor is at or
    // above the quantile (not when the quantile is NaN: then the floor is
    // `min_of_max · max`, and the survivors are found by a scan).
    let survivors = gather.filter(|_| floor >= *q).map(|_| {
        let mut kept: Survivors = parts.into_iter().flat_map(|(_, kept)| kept).collect();
        kept.retain(|&(_, _, v)| v >= floor);
        kept
    });
    Some((floor, survivors))
}

/// Bits of the [`f64::total_cmp`] key that name a bucket of
/// [`threshold_floor`]'s radix select (2¹⁶ counters per part, a few parts per thread).
const QUANTILE_BUCKET_BITS: u32 = 16;

/// A `u64` whose unsigned order is [`f64::total_cmp`]'s order (negative
/// values' bits flipped, positive values' sign bit set).
fn total_order_key(v: f64) -> u64 {
    let bits = v.to_bits();
    if bits >> 63 == 1 { !bits } else { bits | (1 << 63) }
}

/// Cells per parallel task of the whole-grid scans (256 KiB of f64).
const SCAN_CHUNK: usize = 1 << 15;

/// Running maximum over windows of `2r+1` elements (van Herk / Gil–Werman):
/// three max operations per element whatever `r` is. `src` is padded with `r`
/// zeros on both sides (values are non-negative), `out[i]` is the maximum of
/// `src[i-r ..= i+r]` clipped to the slice.
fn window_max_1d(src: &[f64], r: usize, out: &mut [f64], pad: &mut Vec<f64>, g: &mut Vec<f64>, h: &mut Vec<f64>) {
    let n = src.len();
    let k = 2 * r + 1;
    let m = n + 2 * r;
    pad.clear();
    pad.resize(r, 0.0);
    pad.extend_from_slice(src);
    pad.resize(m, 0.0);
    g.clear();
    g.extend_from_slice(pad);
    h.clear();
    h.extend_from_slice(pad);
    for block in g.chunks_mut(k) {
        for p in 1..block.len() {
            block[p] = block[p].max(block[p - 1]);
        }
    }
    for block in h.chunks_mut(k) {
        for p in (0..block.len() - 1).rev() {
            block[p] = block[p].max(block[p + 1]);
        }
    }
    for ((o, a), b) in out.iter_mut().zip(&h[..n]).zip(&g[2 * r..2 * r + n]) {
        // Padded window [i, i + 2r] spans at most two blocks.
        *o = a.max(*b);
    }
}

/// Columns per strip of [`local_maxima_above`]'s vertical pass: its two van
/// Herk buffers hold `(ny + 2r) · STRIP` values, small enough for the cache.
const STRIP: usize = 64;

/// Highlights: non-zero cells equal to the maximum of the (2r+1)² square
/// window around them (Algorithm 1's "local maxima within ⌊5/w⌋ bins"), in
/// raster order. A plateau of equal maxima yields one highlight per window:
/// a tied cell is dropped when an earlier (raster order) highlight of the
/// same value lies within its window.
pub fn local_maxima(g: &Grid, r: usize) -> Vec<Highlight> {
    local_maxima_above(g, r, f64::NEG_INFINITY, &mut Vec::new())
}

/// [`local_maxima`] of the grid with every cell below `floor` taken as 0 (the
/// map [`threshold`] with that floor would leave), without copying the grid:
/// Algorithm 1's highlights are `local_maxima_above(grid, r, threshold_floor(..))`.
/// `scratch` is kept for reuse.
///
/// A cell is a candidate when no cell of its window is larger. When few
/// cells survive the floor (Algorithm 1 keeps the top 10 % of the non-zero
/// ones), they are bucketed by `(i, j) / (r + 1)`: two cells of one bucket are
/// always within each other's window, so only a bucket's largest cells need
/// to look at the 8 neighbouring buckets ([`sparse_candidates`]). Otherwise
/// the van Herk / Gil–Werman window maximum runs over the whole grid
/// ([`dense_candidates`]).
pub fn local_maxima_above(g: &Grid, r: usize, floor: f64, scratch: &mut Vec<f64>) -> Vec<Highlight> {
    maxima_of(g, r, floor, None, scratch)
}

/// [`local_maxima_above`] given the [`survivors`] when they are known.
fn maxima_of(g: &Grid, r: usize, floor: f64, known: Option<Survivors>, scratch: &mut Vec<f64>) -> Vec<Highlight> {
    let GridSpec { nx, ny, .. } = g.spec;
    if nx == 0 || ny == 0 {
        return Vec::new();
    }
    let r = r.min(nx.max(ny));
    // Both sources give survivors only when they are at most `survivor_limit`.
    let candidates = match known.or_else(|| survivors(g, floor, survivor_limit(g))) {
        Some(cells) => sparse_candidates(g, r, cells),
        None => dense_candidates(g, r, floor, scratch),
    };
    thin_plateaus(g, r, candidates)
}

/// Survivors beyond which [`dense_candidates`] is faster than [`sparse_candidates`].
fn survivor_limit(g: &Grid) -> usize {
    g.data.len() / 8
}

/// Cells `(i, j, value)` at or above a floor, in raster order.
type Survivors = Vec<(usize, usize, f64)>;

/// Cells `(i, j, value)` by bucket `(i, j) / (r + 1)`.
type CellBuckets = std::collections::HashMap<(usize, usize), Vec<(usize, usize, f64)>>;

/// The cells `(i, j, value)` at or above `floor` and positive, in raster
/// order, or `None` when they are more than `limit` (1/8 of the grid:
/// then [`dense_candidates`] is faster). Scanned in parallel chunks.
fn survivors(g: &Grid, floor: f64, limit: usize) -> Option<Survivors> {
    use rayon::prelude::*;
    let nx = g.spec.nx;
    let keep = |v: f64| v >= floor && v > 0.0;
    let count: usize = g.data.par_chunks(SCAN_CHUNK).map(|c| c.iter().filter(|&&v| keep(v)).count()).sum();
    if count > limit {
        return None;
    }
    let chunks: Vec<Vec<(usize, usize, f64)>> = g
        .data
        .par_chunks(SCAN_CHUNK)
        .enumerate()
        .map(|(c, cells)| {
            let base = c * SCAN_CHUNK;
            let kept = cells.iter().enumerate().filter(|&(_, &v)| keep(v));
            kept.map(|(k, &v)| ((base + k) % nx, (base + k) / nx, v)).collect()
        })
        .collect();
    Some(chunks.concat())
}

/// The `cells` (from [`survivors`]) with no larger one within `r`
/// (Chebyshev), in raster order, by buckets of `r + 1` cells: a cell below
/// the largest of its own bucket has a larger one within `r`; the others
/// (the buckets' largest, a few hundred in the default `simulate`) are
/// checked against the cells of the eight buckets around theirs.
fn sparse_candidates(g: &Grid, r: usize, cells: Vec<(usize, usize, f64)>) -> Vec<(usize, usize, f64)> {
    debug_assert!(cells.iter().all(|&(i, j, _)| i < g.spec.nx && j < g.spec.ny));
    let bucket = r + 1;
    let (cols, rows) = (g.spec.nx / bucket + 1, g.spec.ny / bucket + 1);
    let cells = if cols.saturating_mul(rows) <= 8 * cells.len() + 4096 {
        match sparse_candidates_dense(r, cells, cols, rows, MAX_TIED_CANDIDATES) {
            Ok(found) => return found,
            Err(cells) => cells,
        }
    } else {
        cells
    };
    sparse_candidates_sorted(r, cells, cols)
}

/// Largest cells one bucket may tie for [`sparse_candidates_dense`]: each
/// cell around a bucket is checked against every one of its candidates, so
/// a plateau of thousands of tied cells beside larger ones took 0.8 s there
/// (a review's stripes of 1 and 2 on the default grid; the sorted search
/// stops at the first larger cell within reach: 48 ms).
const MAX_TIED_CANDIDATES: usize = 16;

/// [`sparse_candidates`] with the buckets as dense arrays (`cols × rows`
/// entries, a few per cell at most): two passes over the cells, no sort and
/// no hashing. A hash map of sorted lists took 1.6 ms of the default
/// `simulate`'s 23 631 survivors, on one thread (issue 14). Gives the cells
/// back when a bucket ties for its largest value in more than `max_ties`
/// cells ([`MAX_TIED_CANDIDATES`]).
fn sparse_candidates_dense(
    r: usize,
    mut cells: Vec<(usize, usize, f64)>,
    cols: usize,
    rows: usize,
    max_ties: usize,
) -> Result<Survivors, Survivors> {
    let bucket = r + 1;
    // Each cell's bucket, computed once (two integer divisions a cell).
    let keys: Vec<usize> = cells.iter().map(|&(i, j, _)| (j / bucket) * cols + i / bucket).collect();
    let mut largest = vec![f64::NEG_INFINITY; cols * rows];
    for (&(_, _, v), &k) in cells.iter().zip(&keys) {
        let m = &mut largest[k];
        *m = if v > *m { v } else { *m };
    }
    // Candidates: each bucket's largest cells (ties all kept), by bucket.
    // (Survivors are positive, never NaN, so `<=` is "not below".)
    let mut candidates: Vec<(usize, usize)> =
        (0..cells.len()).filter(|&c| largest[keys[c]] <= cells[c].2).map(|c| (keys[c], c)).collect();
    candidates.sort_unstable();
    if candidates.chunk_by(|a, b| a.0 == b.0).any(|tied| tied.len() > max_ties) {
        return Err(cells);
    }
    let mut first = vec![usize::MAX; cols * rows];
    for (n, &(k, _)) in candidates.iter().enumerate().rev() {
        first[k] = n;
    }
    // The buckets around bucket `b` (itself included) that hold cells.
    let around = |b: usize, f: &mut dyn FnMut(usize)| {
        let (bi, bj) = (b % cols, b / cols);
        for qj in bj.saturating_sub(1)..=(bj + 1).min(rows - 1) {
            for qi in bi.saturating_sub(1)..=(bi + 1).min(cols - 1) {
                let k = qj * cols + qi;
                if first[k] != usize::MAX {
                    f(k);
                }
            }
        }
    };
    // The smallest candidate value around each bucket: a cell not above it
    // dominates no candidate (most cells, ruled out by one comparison).
    let lowest_around: Vec<f64> = (0..cols * rows)
        .map(|b| {
            let mut lowest = f64::INFINITY;
            around(b, &mut |k| lowest = if largest[k] < lowest { largest[k] } else { lowest });
            lowest
        })
        .collect();
    let mut dominated = vec![false; cells.len()];
    for (&(i, j, v), &b) in cells.iter().zip(&keys) {
        if v <= lowest_around[b] {
            continue;
        }
        around(b, &mut |k| {
            if v > largest[k] {
                for &(_, c) in candidates[first[k]..].iter().take_while(|(ck, _)| *ck == k) {
                    let (ci, cj, _) = cells[c];
                    dominated[c] |= ci.abs_diff(i) <= r && cj.abs_diff(j) <= r;
                }
            }
        });
    }
    let mut c = 0;
    cells.retain(|&(_, _, v)| {
        let keep = largest[keys[c]] <= v && !dominated[c];
        c += 1;
        keep
    });
    Ok(cells)
}

/// [`sparse_candidates`] when dense bucket arrays would be large (a window
/// of a few cells on a big grid): one sorted copy of the cells (by bucket,
/// then largest first) and each bucket's range in it, by binary search.
fn sparse_candidates_sorted(r: usize, mut cells: Vec<(usize, usize, f64)>, cols: usize) -> Vec<(usize, usize, f64)> {
    let bucket = r + 1;
    // Every cell's bucket column is below `cols`; a neighbour column equal
    // to it is off the grid (not the next row's first bucket).
    let key = |bi: usize, bj: usize| bj * cols + bi;
    let mut sorted: Vec<(usize, f64, usize, usize)> =
        cells.iter().map(|&(i, j, v)| (key(i / bucket, j / bucket), v, i, j)).collect();
    // Largest first within a bucket, so a scan stops at the first cell not larger.
    sorted.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)));
    let mut ranges: Vec<(usize, std::ops::Range<usize>)> = Vec::new();
    for (k, c) in sorted.iter().enumerate() {
        match ranges.last_mut() {
            Some((last, range)) if *last == c.0 => range.end = k + 1,
            _ => ranges.push((c.0, k..k + 1)),
        }
    }
    let list = |bi: usize, bj: usize| {
        let found = (bi < cols).then(|| ranges.binary_search_by_key(&key(bi, bj), |(k, _)| *k).ok()).flatten();
        found.map_or(&[][..], |x| &sorted[ranges[x].1.clone()])
    };
    cells.retain(|&(i, j, v)| {
        let (bi, bj) = (i / bucket, j / bucket);
        if list(bi, bj)[0].1 > v {
            return false; // a larger cell of the same bucket is within the window
        }
        let dominated = (bj.saturating_sub(1)..=bj + 1).any(|qj| {
            (bi.saturating_sub(1)..=bi + 1).any(|qi| {
                list(qi, qj)
                    .iter()
                    .take_while(|c| c.1 > v)
                    .any(|&(_, _, ci, cj)| ci.abs_diff(i) <= r && cj.abs_diff(j) <= r)
            })
        });
        !dominated
    });
    cells
}

/// [`sparse_candidates`] by window maxima over the whole grid: a horizontal
/// van Herk pass into `scratch` (one grid-sized buffer), then a vertical
/// one in strips of [`STRIP`] columns that keeps only the candidates.
fn dense_candidates(g: &Grid, r: usize, floor: f64, scratch: &mut Vec<f64>) -> Vec<(usize, usize, f64)> {
    let GridSpec { nx, ny, .. } = g.spec;
    let value = |v: f64| if v < floor { 0.0 } else { v };
    // Horizontal pass: the maximum of each row's window around each cell.
    let row_max = scratch;
    row_max.clear();
    row_max.resize(nx * ny, 0.0);
    let (mut row, mut pad, mut gbuf, mut hbuf) = (Vec::with_capacity(nx), Vec::new(), Vec::new(), Vec::new());
    // Strips holding a cell at or above the floor: only they can hold a highlight.
    let mut strip_live = vec![false; nx.div_ceil(STRIP)];
    for j in 0..ny {
        let src = &g.data[j * nx..(j + 1) * nx];
        if src.iter().all(|&v| value(v) <= 0.0) {
            continue; // window maxima of an all-zero row: 0, as initialised
        }
        row.clear();
        row.extend(src.iter().map(|&v| value(v)));
        for (k, c) in row.chunks(STRIP).enumerate() {
            strip_live[k] |= c.iter().any(|v| *v > 0.0);
        }
        window_max_1d(&row, r, &mut row_max[j * nx..(j + 1) * nx], &mut pad, &mut gbuf, &mut hbuf);
    }
    // Vertical pass, strip by strip (van Herk along columns): candidates are
    // positive cells equal to their window's maximum.
    let k = 2 * r + 1;
    let m = ny + 2 * r;
    let mut candidates: Vec<(usize, usize, f64)> = Vec::new();
    let (mut gs, mut hs) = (Vec::new(), Vec::new());
    for (strip, _) in strip_live.iter().enumerate().filter(|(_, live)| **live) {
        let c0 = strip * STRIP;
        let w = STRIP.min(nx - c0);
        // Padded row p of the strip: grid row p − r, zeros outside.
        let src = |p: usize| (p >= r && p < r + ny).then(|| &row_max[(p - r) * nx + c0..(p - r) * nx + c0 + w]);
        gs.clear();
        gs.resize(m * w, 0.0);
        hs.clear();
        hs.resize(m * w, 0.0);
        for p in 0..m {
            let (prev, cur) = gs.split_at_mut(p * w);
            let cur = &mut cur[..w];
            match (p % k == 0, src(p)) {
                (true, Some(s)) => cur.copy_from_slice(s),
                (true, None) => {}
                (false, s) => {
                    let prev = &prev[(p - 1) * w..];
                    for (i, c) in cur.iter_mut().enumerate() {
                        *c = prev[i].max(s.map_or(0.0, |s| s[i]));
                    }
                }
            }
        }
        for p in (0..m).rev() {
            let (cur, next) = hs.split_at_mut((p + 1) * w);
            let cur = &mut cur[p * w..];
            match (p % k == k - 1 || p == m - 1, src(p)) {
                (true, Some(s)) => cur.copy_from_slice(s),
                (true, None) => {}
                (false, s) => {
                    for (i, c) in cur.iter_mut().enumerate() {
                        *c = next[i].max(s.map_or(0.0, |s| s[i]));
                    }
                }
            }
        }
        for j in 0..ny {
            let (hr, gr) = (&hs[j * w..(j + 1) * w], &gs[(j + 2 * r) * w..(j + 2 * r + 1) * w]);
            for i in 0..w {
                let v = value(g.data[j * nx + c0 + i]);
                if v > 0.0 && v == hr[i].max(gr[i]) {
                    candidates.push((c0 + i, j, v));
                }
            }
        }
    }
    candidates.sort_unstable_by_key(|&(i, j, _)| (j, i));
    candidates
}

/// One highlight per plateau window: candidates in raster order, a tied
/// cell dropped when an earlier kept one of the same value lies within `r`.
fn thin_plateaus(g: &Grid, r: usize, candidates: Vec<(usize, usize, f64)>) -> Vec<Highlight> {
    let bucket = r + 1;
    // Kept highlights `(i, j, value)`, bucketed by (i, j) / (r + 1).
    let mut kept = CellBuckets::default();
    let mut out = Vec::new();
    for (i, j, v) in candidates {
        let (bi, bj) = (i / bucket, j / bucket);
        let tied = (bj.saturating_sub(1)..=bj + 1).any(|qj| {
            (bi.saturating_sub(1)..=bi + 1).any(|qi| {
                kept.get(&(qi, qj)).is_some_and(|cells| {
                    cells.iter().any(|&(ci, cj, cv)| cv == v && ci.abs_diff(i) <= r && cj.abs_diff(j) <= r)
                })
            })
        });
        if !tied {
            kept.entry((bi, bj)).or_default().push((i, j, v));
            out.push(Highlight { pos: g.spec.cell_center(i, j), value: v });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(n: usize) -> GridSpec {
        GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 0.1, nx: n, ny: n }
    }

    #[test]
    fn threshold_keeps_top_decile_and_respects_max_fraction() {
        // Non-zero values 1..=100: rank 90 (0-based) is 91, so 91..=100 survive.
        let mut d: Vec<f64> = (1..=100).map(f64::from).chain(std::iter::repeat_n(0.0, 50)).collect();
        threshold(&mut d, 0.1, 0.01);
        let kept: Vec<f64> = d.iter().copied().filter(|v| *v > 0.0).collect();
        assert_eq!(kept, (91..=100).map(f64::from).collect::<Vec<_>>());
        // The max fraction wins when it is stricter.
        let mut d = vec![1.0, 2.0, 3.0, 1000.0];
        threshold(&mut d, 1.0, 0.01);
        assert_eq!(d, vec![0.0, 0.0, 0.0, 1000.0]);
    }

    /// The radix select's floor against a full sort of the non-zero cells
    /// (the definition), on values spread over many binades, ties, NaN and
    /// negative values.
    #[test]
    fn threshold_floor_is_the_sorted_non_zero_cells_rank() {
        let naive = |d: &[f64], keep_top: f64, min_of_max: f64| {
            let mut nz: Vec<f64> = d.iter().copied().filter(|v| *v != 0.0).collect();
            if nz.is_empty() {
                return None;
            }
            nz.sort_by(f64::total_cmp);
            let rank = (((1.0 - keep_top) * nz.len() as f64).floor() as usize).min(nz.len() - 1);
            let max = d.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            Some(nz[rank].max(min_of_max * max))
        };
        let mut x = 12345u64;
        let mut next = || {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            x >> 11
        };
        for case in 0..40 {
            let n = [0, 1, 2, 7, 1000, 100_000][case % 6];
            let d: Vec<f64> = (0..n)
                .map(|_| match next() % 10 {
                    0..=3 => 0.0,
                    4 => -0.0,
                    5 => (next() % 4) as f64, // ties
                    6 if case % 5 == 0 => f64::NAN,
                    7 if case % 3 == 0 => -((next() % 1000) as f64) * 1e-3,
                    _ => f64::from_bits(0x3e00_0000_0000_0000 + (next() % (1 << 58))), // 2⁻³¹ … 2³³
                })
                .collect();
            for keep_top in [0.0, 0.1, 0.5, 0.999, 1.0] {
                let got = threshold_floor(&d, keep_top, 0.01, &mut Vec::new());
                let want = naive(&d, keep_top, 0.01);
                assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "case {case}, n {n}, keep_top {keep_top}");
            }
        }
    }

    /// `highlights`' fused path (survivors gathered with the floor) against
    /// `local_maxima_above(threshold_floor(..))`, on grids of several scan
    /// chunks, with ties, and with the quantile's rank on a NaN cell.
    #[test]
    fn fused_highlights_match_the_two_step_definition() {
        let mut x = 99u64;
        let mut next = || {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            x >> 33
        };
        let cells = |h: Vec<Highlight>| h.iter().map(|h| (h.pos.x.to_bits(), h.pos.y.to_bits())).collect::<Vec<_>>();
        for (n, keep_top) in [(300usize, 0.1), (257, 0.3), (181, 0.05)] {
            let mut g = Grid::zeros(spec(n));
            for v in &mut g.data {
                *v = match next() % 10 {
                    0..=6 => 0.0,
                    7 => (next() % 5) as f64,
                    _ => (next() % 100_000) as f64 * 1e-3,
                };
            }
            let floor = threshold_floor(&g.data, keep_top, 0.01, &mut Vec::new()).unwrap_or(f64::INFINITY);
            let want = cells(local_maxima_above(&g, 7, floor, &mut Vec::new()));
            let (_, known) = quantile_floor(&g.data, keep_top, 0.01, &mut Vec::new(), Some((n, survivor_limit(&g))))
                .expect("non-zero cells");
            assert!(known.is_some(), "few enough survivors to gather");
            assert_eq!(cells(maxima_of(&g, 7, floor, known, &mut Vec::new())), want, "n {n}");
        }
        // 1, 2, 3, 4 and a NaN: rank ⌊0.9·5⌋ = 4 is the NaN (largest in total order).
        let mut g = Grid::zeros(spec(10));
        for (k, v) in [1.0, 2.0, 3.0, 4.0, f64::NAN].into_iter().enumerate() {
            g.data[k * 21] = v;
        }
        let floor = threshold_floor(&g.data, 0.1, 0.01, &mut Vec::new()).expect("non-zero cells");
        let want = cells(local_maxima_above(&g, 1, floor, &mut Vec::new()));
        assert_eq!(want.len(), 4);
        let (_, known) = quantile_floor(&g.data, 0.1, 0.01, &mut Vec::new(), Some((10, usize::MAX))).expect("cells");
        assert_eq!(cells(maxima_of(&g, 1, floor, known, &mut Vec::new())), want);
    }

    #[test]
    fn local_maxima_respect_window() {
        let mut g = Grid::zeros(spec(200));
        g.data[10 * 200 + 10] = 5.0; // (10,10)
        g.data[10 * 200 + 40] = 7.0; // 30 cells away: suppresses (10,10) at r = 50
        g.data[150 * 200 + 150] = 1.0; // far away: its own peak
        let h = local_maxima(&g, 50);
        let cells: Vec<_> = h.iter().map(|h| g.spec.cell_of(h.pos).unwrap()).collect();
        assert_eq!(cells, vec![(40, 10), (150, 150)]);
        let h = local_maxima(&g, 20);
        assert_eq!(h.len(), 3);
    }

    /// Reference: a cell is a maximum iff no cell in its window is larger,
    /// and plateau ties go to the earliest kept cell in raster order.
    fn naive_maxima(g: &Grid, r: usize) -> Vec<(usize, usize)> {
        let GridSpec { nx, ny, .. } = g.spec;
        let mut kept: Vec<(usize, usize, f64)> = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let v = g.get(i, j);
                let mut is_max = v > 0.0;
                for jj in j.saturating_sub(r)..=(j + r).min(ny - 1) {
                    for ii in i.saturating_sub(r)..=(i + r).min(nx - 1) {
                        is_max &= g.get(ii, jj) <= v;
                    }
                }
                let tied = kept.iter().any(|&(ki, kj, kv)| kv == v && ki.abs_diff(i) <= r && kj.abs_diff(j) <= r);
                if is_max && !tied {
                    kept.push((i, j, v));
                }
            }
        }
        kept.into_iter().map(|(i, j, _)| (i, j)).collect()
    }

    /// A plateau tied in far more cells than [`MAX_TIED_CANDIDATES`] beside
    /// larger cells: the dense search gives the cells back (its check of
    /// every cell against every tied candidate took 0.8 s on a review's
    /// stripes), and the sorted search finds the naive maxima.
    #[test]
    fn a_wide_plateau_goes_to_the_sorted_search() {
        let (nx, ny, r) = (120, 12, 5);
        let mut g = Grid::zeros(GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 0.1, nx, ny });
        // Stripes of 1 and 2, six cells wide (one bucket): every 1-bucket ties in 72 cells.
        for j in 0..ny {
            for i in 0..nx {
                g.data[j * nx + i] = if (i / (r + 1)) % 2 == 0 { 1.0 } else { 2.0 };
            }
        }
        let (cols, rows) = (nx / (r + 1) + 1, ny / (r + 1) + 1);
        let cells = survivors(&g, 0.5, usize::MAX).expect("survivors");
        assert!(sparse_candidates_dense(r, cells.clone(), cols, rows, MAX_TIED_CANDIDATES).is_err());
        let found = thin_plateaus(&g, r, sparse_candidates(&g, r, cells));
        let at: Vec<(usize, usize)> = found.iter().map(|h| g.spec.cell_of(h.pos).expect("on the grid")).collect();
        assert_eq!(at, naive_maxima(&g, r));
    }

    proptest::proptest! {
        #[test]
        fn local_maxima_match_naive(
            nx in 1usize..40, ny in 1usize..40, r in 0usize..12, seed in 0u64..1000, levels in 1u64..6,
        ) {
            let mut g = Grid::zeros(GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 0.1, nx, ny });
            let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            for v in &mut g.data {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                *v = ((x >> 33) % (levels + 1)) as f64; // few levels: many ties and zeros
            }
            let got: Vec<_> = local_maxima(&g, r).iter().map(|h| g.spec.cell_of(h.pos).unwrap()).collect();
            proptest::prop_assert_eq!(got, naive_maxima(&g, r));
        }
    }

    proptest::proptest! {
        /// Thresholding on the fly equals thresholding a copy, on grids wide
        /// enough for several strips of the vertical pass.
        #[test]
        fn local_maxima_above_match_naive_on_a_thresholded_copy(
            nx in 1usize..150, ny in 1usize..30, r in 0usize..9, seed in 0u64..1000, levels in 1u64..8,
            keep_top in 0.05..1.0f64,
        ) {
            let mut g = Grid::zeros(GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 0.1, nx, ny });
            let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            for v in &mut g.data {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                *v = ((x >> 33) % (levels + 1)) as f64;
            }
            let mut copy = g.clone();
            threshold(&mut copy.data, keep_top, 0.01);
            let want = naive_maxima(&copy, r);
            let floor = threshold_floor(&g.data, keep_top, 0.01, &mut Vec::new()).unwrap_or(f64::INFINITY);
            let cells = |h: Vec<Highlight>| h.iter().map(|h| g.spec.cell_of(h.pos).unwrap()).collect::<Vec<_>>();
            proptest::prop_assert_eq!(cells(local_maxima_above(&g, r, floor, &mut Vec::new())), want.clone());
            // Both candidate searches, whichever the survivors' count picks.
            let sparse = thin_plateaus(&g, r, sparse_candidates(&g, r, survivors(&g, floor, usize::MAX).unwrap()));
            let dense = thin_plateaus(&g, r, dense_candidates(&g, r, floor, &mut Vec::new()));
            proptest::prop_assert_eq!(cells(sparse), want.clone());
            proptest::prop_assert_eq!(cells(dense), want.clone());
            // Both bucket layouts of the sparse search, whichever the grid's size picks.
            let survivors = || survivors(&g, floor, usize::MAX).unwrap();
            let (cols, rows) = (nx / (r + 1) + 1, ny / (r + 1) + 1);
            let by_arrays = sparse_candidates_dense(r, survivors(), cols, rows, usize::MAX);
            let by_arrays = thin_plateaus(&g, r, by_arrays.unwrap_or_else(|_| unreachable!("no cap on ties")));
            let by_sorting = thin_plateaus(&g, r, sparse_candidates_sorted(r, survivors(), cols));
            proptest::prop_assert_eq!(cells(by_arrays), want.clone());
            proptest::prop_assert_eq!(cells(by_sorting), want.clone());
            // The survivors gathered with the floor (`highlights`' path), and
            // with too low a limit to gather them.
            for limit in [usize::MAX, 3] {
                let (fused_floor, known) = quantile_floor(&g.data, keep_top, 0.01, &mut Vec::new(), Some((nx, limit))).unzip();
                proptest::prop_assert_eq!(fused_floor.unwrap_or(f64::INFINITY).to_bits(), floor.to_bits());
                let fused = maxima_of(&g, r, floor, known.flatten(), &mut Vec::new());
                proptest::prop_assert_eq!(cells(fused), want.clone());
            }
        }
    }

    #[test]
    fn plateau_gives_one_highlight_per_window() {
        let mut g = Grid::zeros(spec(100));
        for j in 40..43 {
            for i in 10..14 {
                g.data[j * 100 + i] = 3.0;
            }
        }
        let h = local_maxima(&g, 50);
        assert_eq!(h.len(), 1);
        assert_eq!(g.spec.cell_of(h[0].pos), Some((10, 40)));
        // A huge radius is clamped, not an overflow.
        assert_eq!(local_maxima(&g, usize::MAX).len(), 1);
    }

    #[test]
    fn accumulation_adds_weight_once_per_entered_cell() {
        let mut m = AccumulationMapper::new(spec(200), MappingParams::default()).unwrap();
        let e = Echo::new(Point::new(5.0, 10.0), Point::new(15.0, 10.0), 4.0, 2.5, 0.0, 0).unwrap();
        m.add_echo(&e).unwrap();
        m.add_echo(&e).unwrap();
        let vals: Vec<f64> = m.grid().data.iter().copied().filter(|v| *v != 0.0).collect();
        assert!(vals.iter().all(|v| *v == 5.0));
        assert_eq!(vals.len() as u64 * 2, m.cells_updated());
    }

    /// Echoes like the accumulate benchmark's, with uneven weights (so the
    /// order of additions shows in the sums), from a fixed LCG.
    fn random_echoes(n: usize, seed: u64) -> Vec<Echo> {
        let mut x = seed;
        let mut uniform = |lo: f64, hi: f64| {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            lo + (hi - lo) * ((x >> 11) as f64 / (1u64 << 53) as f64)
        };
        (0..n)
            .map(|_| {
                let mid = Point::new(uniform(-25.0, 25.0), uniform(-25.0, 25.0));
                let half = uniform(0.5, 30.0) / 2.0;
                let dir = Point::from_angle(uniform(0.0, std::f64::consts::TAU));
                let (dd, w) = (uniform(0.0, 40.0), uniform(0.0, 3.0));
                Echo::new(mid - dir * half, mid + dir * half, dd, w, 0.0, 0).unwrap()
            })
            .collect()
    }

    /// The accumulation before issue 14: the previous rasteriser and one
    /// plain addition per entered cell, echo after echo.
    fn reference_grid(spec: GridSpec, echoes: &[Echo]) -> (Vec<f64>, u64) {
        let mut data = vec![0.0; spec.len()];
        let mut n = 0;
        for e in echoes {
            crate::raster::for_each_entered_span_reference(&e.ellipse().unwrap(), &spec, |j, lo, hi| {
                for v in &mut data[j * spec.nx + lo..=j * spec.nx + hi] {
                    *v += e.weight;
                }
                n += (hi - lo + 1) as u64;
            });
        }
        (data, n)
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn banded_and_per_echo_accumulation_are_bit_identical_to_the_reference() {
        let specs = [
            GridSpec { x_min_m: -50.0, y_min_m: -50.0, cell_m: 0.1, nx: 1000, ny: 1000 },
            GridSpec { x_min_m: -30.0, y_min_m: -41.0, cell_m: 0.07, nx: 97, ny: 1300 },
            GridSpec { x_min_m: -40.0, y_min_m: -20.0, cell_m: 0.05, nx: 1700, ny: 500 },
        ];
        for (k, spec) in specs.into_iter().enumerate() {
            let echoes = random_echoes(600, 17 + k as u64);
            let (want, cells) = reference_grid(spec, &echoes);
            let mut banded = AccumulationMapper::new(spec, MappingParams::default()).unwrap();
            // Two calls: state between batches must not matter.
            banded.add_echoes(&echoes[..250]).unwrap();
            banded.add_echoes(&echoes[250..]).unwrap();
            let mut single = AccumulationMapper::new(spec, MappingParams::default()).unwrap();
            for e in &echoes {
                single.add_echo(e).unwrap();
            }
            assert!(band_shift(&spec).is_some(), "grid {k} is not banded");
            assert_eq!(bits(&banded.grid().data), bits(&want), "banded, grid {k}");
            assert_eq!(bits(&single.grid().data), bits(&want), "per echo, grid {k}");
            assert_eq!((banded.cells_updated(), single.cells_updated()), (cells, cells));
        }
    }

    #[test]
    fn banded_accumulation_is_bit_identical_whatever_the_thread_count() {
        let spec = GridSpec { x_min_m: -50.0, y_min_m: -50.0, cell_m: 0.1, nx: 1000, ny: 1000 };
        let echoes = random_echoes(500, 99);
        let (want, cells) = reference_grid(spec, &echoes);
        for threads in [1, 2, 3, 8] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let m = pool.install(|| {
                let mut m = AccumulationMapper::new(spec, MappingParams::default()).unwrap();
                m.add_echoes(&echoes).unwrap();
                m
            });
            assert_eq!(bits(&m.grid().data), bits(&want), "{threads} threads");
            assert_eq!(m.cells_updated(), cells, "{threads} threads");
        }
    }

    #[test]
    fn add_echoes_stops_at_the_first_bad_echo_like_add_echo() {
        let spec = GridSpec { x_min_m: -50.0, y_min_m: -50.0, cell_m: 0.1, nx: 1000, ny: 1000 };
        let mut echoes = random_echoes(40, 5);
        echoes[23].weight = f64::NAN;
        let mut banded = AccumulationMapper::new(spec, MappingParams::default()).unwrap();
        let err = banded.add_echoes(&echoes).unwrap_err();
        let mut single = AccumulationMapper::new(spec, MappingParams::default()).unwrap();
        let err_single = echoes.iter().try_for_each(|e| single.add_echo(e)).unwrap_err();
        assert_eq!(err, err_single);
        let (want, cells) = reference_grid(spec, &echoes[..23]);
        assert_eq!(bits(&banded.grid().data), bits(&want));
        assert_eq!(banded.cells_updated(), cells);
        assert_eq!(bits(&single.grid().data), bits(&want));
    }

    #[test]
    fn point_sampled_ellipses_count_points_per_cell() {
        let spec = GridSpec { x_min_m: -10.0, y_min_m: -10.0, cell_m: 0.1, nx: 200, ny: 200 };
        let params = MappingParams { ellipse_points: 4000, ..MappingParams::default() };
        let mut m = AccumulationMapper::new(spec, params).unwrap();
        // Circle-like ellipse of radius 5 m: perimeter 31.4 m ≈ 314 cells' worth of arc, so
        // 4000 points put ~10 points (weight 10) in each cell they cross.
        let e = Echo::new(Point::new(-0.001, 0.0), Point::new(0.001, 0.0), 10.0, 1.0, 0.0, 0).unwrap();
        m.add_echo(&e).unwrap();
        let total: f64 = m.grid().data.iter().sum();
        assert_eq!(total, 4000.0);
        assert!(m.grid().max() > 5.0);
        // Every point lands in a cell the exact rasteriser marks.
        let mut exact = vec![false; spec.len()];
        for_each_entered_span(&e.ellipse().unwrap(), &spec, |j, lo, hi| {
            for i in lo..=hi {
                exact[j * spec.nx + i] = true;
            }
        });
        assert!(m.grid().data.iter().zip(&exact).all(|(v, x)| *v == 0.0 || *x));
    }
}
