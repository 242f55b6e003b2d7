//! The 2D accumulation grid (paper §II.C: square cells, 0.1 m by default).

use crate::error::CoreError;
use crate::geometry::Point;

/// Default cap on the mapper's peak working memory (2 GiB); beyond this the
/// user gets an error instead of an out-of-memory crash.
pub const DEFAULT_MEMORY_CAP_BYTES: u128 = 2 << 30;

/// Grid-sized f64 buffers budgeted for mapping: an upper bound. Since issue 14
/// the paper mapper holds the accumulator and one scratch buffer of highlight
/// extraction (the non-zero values, then the horizontal window maxima) plus
/// fixed-size span buffers, and the commands a copy for each map file they
/// write; the bound stays at the foundation issue's 6 so that the grids
/// accepted do not change.
pub const WORKING_COPIES: u128 = 6;

/// Placement of a grid in the world frame. Cell `(i, j)` covers
/// `[x_min + i·cell, x_min + (i+1)·cell) × [y_min + j·cell, y_min + (j+1)·cell)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridSpec {
    /// Left edge of the grid (m).
    pub x_min_m: f64,
    /// Bottom edge of the grid (m).
    pub y_min_m: f64,
    /// Side of a square cell (m).
    pub cell_m: f64,
    /// Number of cells along x.
    pub nx: usize,
    /// Number of cells along y.
    pub ny: usize,
}

impl GridSpec {
    /// Grid covering `[x_min, x_max] × [y_min, y_max]` with square cells of
    /// `cell_m`, refusing grids whose mapping would need more than `cap_bytes`
    /// ([`WORKING_COPIES`] f64 buffers of the grid's size).
    pub fn from_bounds(bounds: [f64; 4], cell_m: f64, cap_bytes: u128) -> Result<Self, CoreError> {
        let [x_min, y_min, x_max, y_max] = bounds;
        if !cell_m.is_finite() || cell_m <= 0.0 {
            return Err(CoreError::InvalidGrid(format!("cell size must be finite and > 0, got {cell_m}")));
        }
        if bounds.iter().any(|v| !v.is_finite()) || x_max <= x_min || y_max <= y_min {
            return Err(CoreError::InvalidGrid(format!(
                "bounds must be finite with xmin < xmax and ymin < ymax, got {x_min},{y_min},{x_max},{y_max}"
            )));
        }
        let nx_f = ((x_max - x_min) / cell_m).ceil().max(1.0);
        let ny_f = ((y_max - y_min) / cell_m).ceil().max(1.0);
        let bytes = (nx_f * ny_f * 8.0 * WORKING_COPIES as f64) as u128;
        if nx_f * ny_f * 8.0 * WORKING_COPIES as f64 > cap_bytes as f64 {
            return Err(CoreError::GridTooLarge { nx: nx_f as usize, ny: ny_f as usize, bytes, cap: cap_bytes });
        }
        Ok(Self { x_min_m: x_min, y_min_m: y_min, cell_m, nx: nx_f as usize, ny: ny_f as usize })
    }

    /// Number of cells, `nx·ny`.
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }
    /// True when the grid has no cells.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Right edge of the grid (m).
    pub fn x_max_m(&self) -> f64 {
        self.x_min_m + self.nx as f64 * self.cell_m
    }
    /// Top edge of the grid (m).
    pub fn y_max_m(&self) -> f64 {
        self.y_min_m + self.ny as f64 * self.cell_m
    }
    /// Centre of cell `(i, j)`.
    pub fn cell_center(&self, i: usize, j: usize) -> Point {
        Point::new(self.x_min_m + (i as f64 + 0.5) * self.cell_m, self.y_min_m + (j as f64 + 0.5) * self.cell_m)
    }
    /// Cell containing `p`, if any.
    pub fn cell_of(&self, p: Point) -> Option<(usize, usize)> {
        let i = ((p.x - self.x_min_m) / self.cell_m).floor();
        let j = ((p.y - self.y_min_m) / self.cell_m).floor();
        (i >= 0.0 && j >= 0.0 && (i as usize) < self.nx && (j as usize) < self.ny).then_some((i as usize, j as usize))
    }
}

/// `len` zeros whose memory pages have all been written once (a store of 0.0
/// every 4 KiB, on rayon's threads), for buffers that are then accumulated
/// into with `+=`.
///
/// Why: a large `vec![0.0; n]` is fresh, untouched memory. The first `+=` on
/// each page *reads* it, so the kernel maps its shared zero page read-only;
/// the write that follows then faults again, copies that page and flushes the
/// page's TLB entry on every core running the process (an inter-processor
/// interrupt, slow in a VM). Writing first makes it one fault per page and
/// no flush. Measured on the default `simulate` run: page faults 10 000 →
/// 8 000 and 8–9 % less wall time (BENCHMARKS.md, issue 14). The values are
/// the same zeros.
pub fn prefaulted_zeros(len: usize) -> Vec<f64> {
    prefaulted(len, 0.0)
}

/// [`prefaulted_zeros`] of any plain type: `len` copies of `zero` (a value
/// whose bytes are all 0, so that the allocation is fresh zeroed memory),
/// each 4 KiB page written once. For the evidence mapper's f32 and u32
/// accumulators, whose copy-on-write faults were 2 % of a Table I 1 ms
/// `simulate` with it, in the kernel's TLB-flush interrupts.
pub fn prefaulted<T: Copy + Send + Sync>(len: usize, zero: T) -> Vec<T> {
    use rayon::prelude::*;
    // The smallest page size; chunks are a multiple of it.
    let page = (4096 / std::mem::size_of::<T>().max(1)).max(1);
    let mut data = vec![zero; len];
    data.par_chunks_mut(page << 7).for_each(|chunk| chunk.iter_mut().step_by(page).for_each(|v| *v = zero));
    // The stores are 4 KiB apart from the first cell, which need not start a
    // page: the last page can hold cells after the last store.
    if let Some(v) = data.last_mut() {
        *v = zero;
    }
    data
}

/// Row-major grid of values (`j·nx + i`).
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Placement of the grid.
    pub spec: GridSpec,
    /// Cell values, row-major: index `j·nx + i`.
    pub data: Vec<f64>,
}

impl Grid {
    /// Grid of `spec` with every cell 0.
    pub fn zeros(spec: GridSpec) -> Self {
        Self { spec, data: vec![0.0; spec.len()] }
    }
    /// [`Grid::zeros`] with every page of its memory already written: for a
    /// grid about to be accumulated into (see [`prefaulted_zeros`]).
    pub fn zeros_prefaulted(spec: GridSpec) -> Self {
        Self { spec, data: prefaulted_zeros(spec.len()) }
    }
    /// Value of cell `(i, j)`; panics when out of range.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.data[j * self.spec.nx + i]
    }
    /// Largest cell value, or 0 when every cell is ≤ 0 or the grid is empty.
    pub fn max(&self) -> f64 {
        self.data.iter().copied().fold(0.0, f64::max)
    }
}
