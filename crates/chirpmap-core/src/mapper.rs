//! Mappers turn echoes into a map; highlight extraction turns a map into
//! likely obstacle surface points (paper §II.C, Algorithm 1).

use crate::echo::Echo;
use crate::error::CoreError;
use crate::geometry::Point;
use crate::grid::{Grid, GridSpec};
use crate::raster::for_each_entered_span;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

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
}

impl Default for MappingParams {
    fn default() -> Self {
        Self { cell: 0.1, keep_top: 0.1, min_of_max: 0.01, peak_radius: 5.0 }
    }
}

impl MappingParams {
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
        Ok(())
    }

    /// Window radius in cells, ⌊peak_radius / w⌋ as in Algorithm 1.
    pub fn peak_radius_cells(&self) -> usize {
        (self.peak_radius / self.cell + 1e-9).floor() as usize
    }
}

/// A likely obstacle location: the centre of a locally maximal cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Highlight {
    pub pos: Point,
    pub value: f64,
}

/// What every mapper offers: take echoes one at a time, expose a map, and
/// extract highlights from it. The probabilistic mapper plugs in here.
pub trait Mapper {
    /// Adds one echo's evidence.
    fn add_echo(&mut self, echo: &Echo) -> Result<(), CoreError>;
    /// The current map.
    fn grid(&self) -> &Grid;
    /// Highlights of the current map.
    fn highlights(&self) -> Vec<Highlight>;
}

/// Side of the square tiles the accumulator is stored in (cells).
const TILE: usize = 8;

/// Algorithm 1: each ellipse adds its weight once to every cell it enters.
///
/// The accumulator is stored in 8 × 8-cell tiles rather than rows: an
/// ellipse's steep arcs climb row after row, and with rows 8 KB apart every
/// step was a new cache line on a new page; inside a tile the next row is the
/// next cache line. [`Mapper::grid`] returns the row-major view, rebuilt on
/// demand after new echoes.
#[derive(Debug, Clone)]
pub struct AccumulationMapper {
    spec: GridSpec,
    /// Tiles in row-major tile order, each 8 rows of 8 cells.
    tiles: Vec<f64>,
    tiles_x: usize,
    row_major: std::sync::OnceLock<Grid>,
    params: MappingParams,
    cells_updated: u64,
}

impl AccumulationMapper {
    pub fn new(spec: GridSpec, params: MappingParams) -> Result<Self, CoreError> {
        params.validate()?;
        let tiles_x = spec.nx.div_ceil(TILE);
        let tiles_y = spec.ny.div_ceil(TILE);
        Ok(Self {
            spec,
            tiles: vec![0.0; tiles_x * tiles_y * TILE * TILE],
            tiles_x,
            row_major: std::sync::OnceLock::new(),
            params,
            cells_updated: 0,
        })
    }

    /// Total cell updates so far (for benchmarks and progress reporting).
    pub fn cells_updated(&self) -> u64 {
        self.cells_updated
    }

    fn accumulate(&mut self, echo: &Echo) -> Result<(), CoreError> {
        let e = echo.ellipse()?;
        self.row_major.take();
        let (tiles, tiles_x, w) = (&mut self.tiles, self.tiles_x, echo.weight);
        let mut n = 0u64;
        for_each_entered_span(&e, &self.spec, |j, lo, hi| {
            let row_base = (j / TILE) * tiles_x * TILE * TILE + (j % TILE) * TILE;
            let mut i = lo;
            while i <= hi {
                let tile_end = (i / TILE * TILE + TILE - 1).min(hi);
                let base = row_base + (i / TILE) * TILE * TILE;
                for v in &mut tiles[base + i % TILE..=base + tile_end % TILE] {
                    *v += w;
                }
                i = tile_end + 1;
            }
            n += (hi - lo + 1) as u64;
        });
        self.cells_updated += n;
        Ok(())
    }

    fn untile(&self) -> Grid {
        let mut g = Grid::zeros(self.spec);
        let nx = self.spec.nx;
        for (j, row) in g.data.chunks_mut(nx).enumerate() {
            let row_base = (j / TILE) * self.tiles_x * TILE * TILE + (j % TILE) * TILE;
            for (i, v) in row.iter_mut().enumerate() {
                *v = self.tiles[row_base + (i / TILE) * TILE * TILE + i % TILE];
            }
        }
        g
    }
}

impl Mapper for AccumulationMapper {
    fn add_echo(&mut self, echo: &Echo) -> Result<(), CoreError> {
        self.accumulate(echo)
    }
    fn grid(&self) -> &Grid {
        self.row_major.get_or_init(|| self.untile())
    }
    fn highlights(&self) -> Vec<Highlight> {
        let mut g = self.grid().clone();
        threshold(&mut g.data, self.params.keep_top, self.params.min_of_max);
        local_maxima(&g, self.params.peak_radius_cells())
    }
}

/// Algorithm 1's thresholding: zero cells below the (1 − keep_top) quantile of
/// the non-zero cells and cells below `min_of_max · max`. The quantile is the
/// value at rank ⌊(1 − keep_top)·n⌋ (0-based, ascending) of the n non-zero cells.
pub fn threshold(data: &mut [f64], keep_top: f64, min_of_max: f64) {
    let mut nonzero: Vec<f64> = data.iter().copied().filter(|v| *v != 0.0).collect();
    if nonzero.is_empty() {
        return;
    }
    let n = nonzero.len();
    let rank = (((1.0 - keep_top) * n as f64).floor() as usize).min(n - 1);
    let (_, q, _) = nonzero.select_nth_unstable_by(rank, f64::total_cmp);
    let quantile = *q;
    let max = data.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let floor = quantile.max(min_of_max * max);
    for v in data.iter_mut() {
        if *v < floor {
            *v = 0.0;
        }
    }
}

/// Sliding-window maximum of `src` with half-width `r` (window 2r+1, clipped at
/// the ends), written to `dst`. Monotonic deque: O(n) for any r.
fn sliding_max(src: impl Iterator<Item = f64> + Clone, n: usize, r: usize, mut dst: impl FnMut(usize, f64)) {
    let vals: Vec<f64> = src.collect();
    let mut dq: VecDeque<usize> = VecDeque::new();
    let mut next = 0;
    for i in 0..n {
        let hi = (i + r).min(n - 1);
        while next <= hi {
            while dq.back().is_some_and(|&b| vals[b] <= vals[next]) {
                dq.pop_back();
            }
            dq.push_back(next);
            next += 1;
        }
        while dq.front().is_some_and(|&f| f + r < i) {
            dq.pop_front();
        }
        if let Some(&f) = dq.front() {
            dst(i, vals[f]);
        }
    }
}

/// Cells with a non-zero value equal to the maximum of the (2r+1)² square
/// window around them, in raster order.
pub fn local_maxima(g: &Grid, r: usize) -> Vec<Highlight> {
    let GridSpec { nx, ny, .. } = g.spec;
    let mut row_max = vec![0.0; nx * ny];
    for j in 0..ny {
        let row = &g.data[j * nx..(j + 1) * nx];
        sliding_max(row.iter().copied(), nx, r, |i, v| row_max[j * nx + i] = v);
    }
    let mut win_max = vec![0.0; nx * ny];
    for i in 0..nx {
        sliding_max((0..ny).map(|j| row_max[j * nx + i]), ny, r, |j, v| win_max[j * nx + i] = v);
    }
    let mut out = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let v = g.data[j * nx + i];
            if v > 0.0 && v == win_max[j * nx + i] {
                out.push(Highlight { pos: g.spec.cell_center(i, j), value: v });
            }
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

    #[test]
    fn sliding_max_matches_naive() {
        let vals: Vec<f64> = (0..97).map(|i| ((i * 37) % 23) as f64).collect();
        for r in [0, 1, 5, 50, 200] {
            let mut got = vec![0.0; vals.len()];
            sliding_max(vals.iter().copied(), vals.len(), r, |i, v| got[i] = v);
            for (i, g) in got.iter().enumerate() {
                let lo = i.saturating_sub(r);
                let hi = (i + r).min(vals.len() - 1);
                let want = vals[lo..=hi].iter().copied().fold(f64::MIN, f64::max);
                assert_eq!(*g, want, "r={r} i={i}");
            }
        }
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

    #[test]
    fn tiled_accumulator_matches_row_major_reference() {
        // Odd grid sizes exercise partial edge tiles.
        let spec = GridSpec { x_min_m: -3.05, y_min_m: -2.0, cell_m: 0.1, nx: 203, ny: 117 };
        let mut m = AccumulationMapper::new(spec, MappingParams::default()).unwrap();
        let mut reference = Grid::zeros(spec);
        for (k, (sx, lx, dd)) in [(-2.0, 15.0, 3.0), (0.0, 4.0, 0.0), (-5.0, 30.0, 12.0)].into_iter().enumerate() {
            let e = Echo::new(Point::new(sx, 3.0), Point::new(lx, 5.5), dd, 1.0 + k as f64, 0.0, 0).unwrap();
            m.add_echo(&e).unwrap();
            let _ = m.grid(); // the cached view must be invalidated by the next echo
            for_each_entered_span(&e.ellipse().unwrap(), &spec, |j, lo, hi| {
                for i in lo..=hi {
                    reference.data[j * spec.nx + i] += e.weight;
                }
            });
        }
        assert_eq!(m.grid(), &reference);
        assert!(reference.data.iter().filter(|v| **v > 0.0).count() > 500);
    }
}
