//! Figures: PNG (plotters' bitmap backend) or SVG (vector; chosen by a path
//! ending in `.svg`), with the bundled DejaVu Sans so text renders the same on
//! machines without system fonts.
//!
//! Conventions for every figure (issue 13): exact perceptual colour maps
//! ([`ColourMap`], from the `colorous` crate's ports of matplotlib's
//! viridis/inferno/cividis, van der Walt & Smith 2015; Nuñez et al. 2018),
//! tick labels as people write them ([`tick_label`]: "50", not "50.0") and, on
//! maps, metres at a 1:1 aspect ratio for any grid shape.

use anyhow::{Result, anyhow};
use chirpmap_core::{Grid, Highlight, Obstacle, Point, Shape};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{FontStyle, register_font};
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

/// Registers the bundled font once; plotters' `ab_glyph` text needs it.
pub fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and known good; failure would be a build bug.
        let _ = register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

pub(crate) fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plotting failed: {e}")
}

/// The axes every line figure draws (spectra, echogram): caption, margins,
/// a light grid, readable tick labels and axis titles `(x, y)`.
pub(crate) fn line_chart<'a, DB: DrawingBackend>(
    root: &'a DrawingArea<DB, Shift>,
    title: &str,
    (x, y): (std::ops::Range<f64>, std::ops::Range<f64>),
    y_label_area: u32,
    (x_desc, y_desc): (&str, &str),
) -> Result<
    ChartContext<'a, DB, Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>>,
>
where
    DB::ErrorType: 'static,
{
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .margin_right(40)
        .x_label_area_size(44)
        .y_label_area_size(y_label_area)
        .build_cartesian_2d(x, y)
        .map_err(plot_err)?;
    let fmt = |v: &f64| tick_label(*v);
    chart
        .configure_mesh()
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(215, 215, 215))
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(plot_err)?;
    Ok(chart)
}

/// The legend box in the upper right (every figure with labelled series).
pub(crate) fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(plot_err)?;
    Ok(())
}

/// The legend box, then the figure written out.
pub(crate) fn legend_and_present<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    root: &DrawingArea<DB, Shift>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    draw_legend(chart)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// Whether `path` asks for vector output (`.svg`, any case); everything else
/// is written as a bitmap in the format its extension names (PNG normally).
pub fn is_svg(path: &Path) -> bool {
    has_extension(path, "svg")
}

fn has_extension(path: &Path, ext: &str) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case(ext))
}

/// Whether `path` names a PNG file (`.png`, any case).
pub fn is_png(path: &Path) -> bool {
    has_extension(path, "png")
}

/// Writes `rgb` (8-bit RGB rows, top first) as a PNG of `(w, h)` pixels.
/// Errors do not name `path`: the commands write figures into staging
/// folders and name the output's final place themselves.
///
/// Why not plotters' own save: it goes through `image`'s encoder with the
/// adaptive filter, which tries all five PNG filters on every row. A fixed
/// Paeth filter with the same fast deflate (fdeflate) encoded the default
/// map figure (1012 × 916) in 2.1–2.3 ms against 3.0–4.6 ms, at 246 KB
/// against 243 KB (BENCHMARKS.md, session 21; issue 14's ≤ 50 ms `simulate`).
pub fn write_png(path: &Path, rgb: &[u8], (w, h): (u32, u32)) -> Result<()> {
    let file = std::fs::File::create(path)?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::FilterType::Paeth);
    enc.set_adaptive_filter(png::AdaptiveFilterType::NonAdaptive);
    let written = enc.write_header().and_then(|mut png| {
        png.write_image_data(rgb)?;
        png.finish()
    });
    Ok(written?)
}

/// Runs `$draw(root)` on an SVG or a bitmap drawing area of `$size` pixels
/// at `$path`, by [`is_svg`]; `$draw` must be generic over the backend. A
/// PNG is drawn into memory and written by [`write_png`]; other bitmap
/// formats are saved by plotters.
macro_rules! with_backend {
    ($path:expr, $size:expr, $draw:expr) => {{
        let path: &std::path::Path = $path;
        let (w, h): (u32, u32) = $size;
        if $crate::plot::is_svg(path) {
            $draw(plotters::prelude::SVGBackend::new(path, (w, h)).into_drawing_area())
        } else if $crate::plot::is_png(path) {
            let mut rgb = vec![0u8; w as usize * h as usize * 3];
            $draw(plotters::prelude::BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area())
                .and_then(|()| $crate::plot::write_png(path, &rgb, (w, h)))
        } else {
            $draw(plotters::prelude::BitMapBackend::new(path, (w, h)).into_drawing_area())
        }
    }};
}
#[allow(unused_imports)] // used by plot_audio and plot_summary
pub(crate) use with_backend;

/// Tick label as a person writes it: no trailing zeros ("50", "0.25",
/// "-1.5"), no "-0" (|v| < 1e-12 is 0), at most 6 decimals; scientific only
/// for tiny or huge magnitudes ("1e-7", "2.5e9").
pub fn tick_label(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    // Tick arithmetic leaves residues like -2.8e-17 where 0 is meant.
    if a < 1e-12 {
        return "0".to_string();
    }
    if !(1e-4..1e9).contains(&a) {
        let s = format!("{v:.3e}");
        let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
        let m = m.trim_end_matches('0').trim_end_matches('.');
        return format!("{m}e{e}");
    }
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".to_string() } else { s.to_string() }
}

/// Label of a power of ten on a log axis, "10⁻³" (empty for other values, so
/// only decades are labelled).
pub fn decade_label(v: f64) -> String {
    if !(v.is_finite() && v > 0.0) {
        return String::new();
    }
    let e = v.log10().round();
    if (v / 10f64.powf(e) - 1.0).abs() > 1e-6 {
        return String::new();
    }
    const SUP: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
    let digits: String =
        (e.abs() as i64).to_string().chars().map(|c| SUP[c.to_digit(10).unwrap_or(0) as usize]).collect();
    format!("10{}{digits}", if e < 0.0 { "⁻" } else { "" })
}

/// A perceptually uniform colour map (exact: `colorous` samples matplotlib's
/// 256-entry tables for viridis and inferno; cividis is Nuñez et al.'s fit).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum ColourMap {
    /// Dark blue-purple → green → yellow; the default for maps.
    #[default]
    Viridis,
    /// Black → red → yellow; the default for spectrograms.
    Inferno,
    /// Blue → yellow, readable with colour-vision deficiency.
    #[allow(dead_code)] // offered to the commands (issue 13); no command picks it yet
    Cividis,
}

impl ColourMap {
    /// Colour at `t` ∈ [0, 1] (clamped; NaN gives the low end).
    pub fn eval(self, t: f64) -> RGBColor {
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        let g = match self {
            Self::Viridis => colorous::VIRIDIS,
            Self::Inferno => colorous::INFERNO,
            Self::Cividis => colorous::CIVIDIS,
        };
        let c = g.eval_continuous(t);
        RGBColor(c.r, c.g, c.b)
    }
}

/// How grid values map to colour.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum ColourScale {
    /// `√(value / max)` over [0, max] (negative values show as 0): single
    /// faint ellipses stay visible next to dense spots; for Algorithm 1's
    /// accumulated weights.
    #[default]
    SqrtOfMax,
    /// Linear over [min, max] of the finite values, any sign; for maps with
    /// negative values such as log-odds of occupancy.
    Linear,
}

/// Whether any value of `c` is negative, and its finite minimum and maximum
/// (±∞ when none is finite). Eight independent lanes of branch-free selects,
/// so the loop vectorises; a fold of `f64::min`/`max` over one accumulator
/// did not and took ~4 ms of the default run's figure (issue 14). Minimum
/// and maximum do not depend on the order the values are met in, but for
/// the sign of a zero result (−0 or +0), which gives the same colours and
/// tick labels.
fn finite_extent(c: &[f64]) -> (bool, f64, f64) {
    const LANES: usize = 8;
    let (mut negative, mut lo, mut hi) = ([false; LANES], [f64::INFINITY; LANES], [f64::NEG_INFINITY; LANES]);
    let mut lanes = c.chunks_exact(LANES);
    for x in &mut lanes {
        for k in 0..LANES {
            let v = x[k];
            negative[k] |= v < 0.0;
            let finite = v.is_finite();
            lo[k] = if finite && v < lo[k] { v } else { lo[k] };
            hi[k] = if finite && v > hi[k] { v } else { hi[k] };
        }
    }
    let tail = lanes.remainder().iter().copied();
    let tail_lo = tail.clone().filter(|v| v.is_finite()).fold(f64::INFINITY, f64::min);
    let tail_hi = tail.clone().filter(|v| v.is_finite()).fold(f64::NEG_INFINITY, f64::max);
    (
        negative.iter().any(|n| *n) || tail.clone().any(|v| v < 0.0),
        lo.iter().copied().fold(tail_lo, f64::min),
        hi.iter().copied().fold(tail_hi, f64::max),
    )
}

impl ColourScale {
    /// The value range the colour bar spans for `data`.
    fn range(self, data: &[f64]) -> (f64, f64) {
        let finite = data.iter().copied().filter(|v| v.is_finite());
        let max = finite.clone().fold(f64::NEG_INFINITY, f64::max);
        let (lo, hi) = match self {
            Self::SqrtOfMax => (0.0, max.max(0.0)),
            Self::Linear => (finite.fold(f64::INFINITY, f64::min), max),
        };
        if lo.is_finite() && hi > lo {
            (lo, hi)
        } else {
            let lo = if lo.is_finite() { lo } else { 0.0 };
            (lo, lo + 1.0)
        }
    }

    /// The scale of [`ColourScale::with_range`] alone.
    #[cfg(test)] // the figures use `with_range`, which computes it in the same pass
    pub fn for_values(data: &[f64]) -> Self {
        if data.iter().any(|v| *v < 0.0) { Self::Linear } else { Self::SqrtOfMax }
    }

    /// The scale for a map, [`ColourScale::Linear`] when any value is
    /// negative (a signed quantity such as log-odds), else
    /// [`ColourScale::SqrtOfMax`], and its [`ColourScale::range`]: one pass
    /// over `data` in parallel chunks (each pass over an 8 MB grid costs a
    /// figure more than its colours do; issue 14).
    pub fn with_range(data: &[f64]) -> (Self, (f64, f64)) {
        use rayon::prelude::*;
        let (negative, min, max) = data
            .par_chunks(1 << 15)
            .map(finite_extent)
            .reduce(|| (false, f64::INFINITY, f64::NEG_INFINITY), |a, b| (a.0 | b.0, a.1.min(b.1), a.2.max(b.2)));
        let scale = if negative { Self::Linear } else { Self::SqrtOfMax };
        // The finite minimum and maximum are the same whatever the chunks' order.
        (scale, scale.range(&[min, max]))
    }

    /// Position in [0, 1] on the colour map of `v` within `range`.
    fn position(self, v: f64, (lo, hi): (f64, f64)) -> f64 {
        let u = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
        match self {
            Self::SqrtOfMax => u.sqrt(),
            Self::Linear => u,
        }
    }
}

// Overlay colours chosen to stand out on every part of viridis (which has no
// red, white or light cyan) and to stay apart from each other.
const HIGHLIGHT: RGBColor = RGBColor(230, 30, 40);
const OBSTACLE: RGBColor = WHITE;
const LISTENER: RGBColor = RGBColor(120, 230, 255);
const SURFACE: RGBColor = RGBColor(255, 140, 0);

/// A surface an evidence mapper reports: a wall segment from `.0` to `.1`
/// (a point when both are equal), in metres, and whether it is ambiguous
/// (e.g. one of a mirror pair a straight pass cannot tell apart).
pub type Surface = ((f64, f64), (f64, f64), bool);

/// Everything drawn on a map figure (paper Fig. 4).
#[derive(Debug)]
pub struct MapPlot<'a> {
    pub title: String,
    pub grid: &'a Grid,
    pub highlights: &'a [Highlight],
    pub sources: &'a [Point],
    /// Listener positions at measurement times (drawn as a path of dots).
    pub listener_positions: &'a [Point],
    /// Listener detection radius, drawn around the first position.
    pub listener_radius_m: Option<f64>,
    pub obstacles: &'a [Obstacle],
}

/// Optional extras of a map figure ([`render_map_with`]); `Default` draws none.
#[derive(Debug, Clone, Copy, Default)]
pub struct MapStyle<'a> {
    /// Wall segments and points reported by an evidence mapper: solid orange
    /// lines (dashed when ambiguous), points as crosses.
    pub surfaces: &'a [Surface],
    /// Colour map of the grid values (the scale follows the values: see
    /// [`ColourScale::with_range`]).
    pub colour_map: ColourMap,
    /// Label of the colour bar (default "accumulated weight").
    pub value_label: Option<&'a str>,
}

fn outline(shape: &Shape) -> Vec<(f64, f64)> {
    match shape {
        Shape::Circle(c) => (0..=120)
            .map(|k| {
                let p = c.center + Point::from_angle(k as f64 * std::f64::consts::TAU / 120.0) * c.radius_m;
                (p.x, p.y)
            })
            .collect(),
        Shape::Polygon(p) => {
            let mut v: Vec<(f64, f64)> = p.vertices().iter().map(|v| (v.x, v.y)).collect();
            if let Some(&first) = v.first() {
                v.push(first);
            }
            v
        }
    }
}

/// The part of segment `a`–`b` inside the box `x` × `y` (Liang & Barsky
/// 1984), or `None` when it misses the box.
fn clip_segment(a: (f64, f64), b: (f64, f64), x: (f64, f64), y: (f64, f64)) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a.0 - x.0), (dx, x.1 - a.0), (-dy, a.1 - y.0), (dy, y.1 - a.1)] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
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
    (t0 <= t1).then_some(((a.0 + t0 * dx, a.1 + t0 * dy), (a.0 + t1 * dx, a.1 + t1 * dy)))
}

/// `path` cut to the box: the runs of it that lie inside, so nothing outside
/// the axes is drawn (plotters would pin outside points to the border).
fn clip_path(path: &[(f64, f64)], x: (f64, f64), y: (f64, f64)) -> Vec<Vec<(f64, f64)>> {
    let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut current: Vec<(f64, f64)> = Vec::new();
    for w in path.windows(2) {
        match clip_segment(w[0], w[1], x, y) {
            Some((p, q)) => {
                if current.last() != Some(&p) {
                    if current.len() > 1 {
                        runs.push(std::mem::take(&mut current));
                    }
                    current.clear();
                    current.push(p);
                }
                current.push(q);
            }
            None => {
                if current.len() > 1 {
                    runs.push(std::mem::take(&mut current));
                }
                current.clear();
            }
        }
    }
    if current.len() > 1 {
        runs.push(current);
    }
    runs
}

fn inside(p: (f64, f64), x: (f64, f64), y: (f64, f64)) -> bool {
    (x.0..=x.1).contains(&p.0) && (y.0..=y.1).contains(&p.1)
}

/// Pixel layout of a map figure: the plotting area has `plot_px` pixels and
/// shows `x_range` × `y_range` metres at the same metres per pixel in x and y.
#[derive(Debug, Clone, PartialEq)]
struct MapLayout {
    size_px: (u32, u32),
    plot_px: (u32, u32),
    x_range: (f64, f64),
    y_range: (f64, f64),
}

const TITLE_H: u32 = 40;
const MARGIN: u32 = 14;
const X_LABELS: u32 = 48;
const Y_LABELS: u32 = 64;
const BAR_W: u32 = 120;

/// Chooses the figure size for a `width_m` × `height_m` map: ~800 px on the
/// long side, at least 240 px on the short side (up to 2400 px on the long
/// one), and an exact 1:1 scale (the ranges are widened symmetrically to fill
/// whole pixels).
fn map_layout(x: (f64, f64), y: (f64, f64)) -> MapLayout {
    let (wx, wy) = ((x.1 - x.0).max(1e-9), (y.1 - y.0).max(1e-9));
    let mut s = (800.0 / wx).min(800.0 / wy);
    if wx.min(wy) * s < 240.0 {
        s = (240.0 / wx.min(wy)).min(2400.0 / wx.max(wy));
    }
    let pw = (wx * s).round().max(1.0) as u32;
    let ph = (wy * s).round().max(1.0) as u32;
    let m_per_px = (wx / f64::from(pw)).max(wy / f64::from(ph));
    let half = |lo: f64, hi: f64, n: u32| {
        let c = 0.5 * (lo + hi);
        let h = 0.5 * m_per_px * f64::from(n);
        (c - h, c + h)
    };
    MapLayout {
        size_px: (2 * MARGIN + Y_LABELS + pw + BAR_W, TITLE_H + 2 * MARGIN + ph + X_LABELS),
        plot_px: (pw, ph),
        x_range: half(x.0, x.1, pw),
        y_range: half(y.0, y.1, ph),
    }
}

/// RGB raster (`w` × `h`, top row first) of `grid` over the world window
/// `x_range` × `y_range`: each pixel shows the largest value among the cells
/// it covers (so thin ellipses never vanish when a pixel spans several
/// cells), coloured by `cmap` on `scale`; outside the grid stays white.
#[cfg(test)]
fn grid_raster(
    grid: &Grid,
    (w, h): (u32, u32),
    x_range: (f64, f64),
    y_range: (f64, f64),
    cmap: ColourMap,
    scale: ColourScale,
) -> Vec<u8> {
    grid_raster_in(grid, (w, h), x_range, y_range, cmap, scale, scale.range(&grid.data))
}

/// Slots of the rasters' colour caches ([`grid_raster_in`], the spectrogram's).
pub(crate) const COLOUR_CACHE: usize = 1 << 10;

/// The colour-cache slot of a value's bits (a multiplicative hash keeping
/// as many top bits as the cache has slots).
pub(crate) fn colour_slot(bits: u64) -> usize {
    ((bits ^ (bits >> 29)).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - COLOUR_CACHE.trailing_zeros())) as usize
}

/// [`grid_raster`] with the value range already known. A pixel's colour is
/// computed once per distinct value a task meets (most pixels of a map are
/// 0, and a spline evaluation per pixel was 12 % of `simulate`).
fn grid_raster_in(
    grid: &Grid,
    (w, h): (u32, u32),
    x_range: (f64, f64),
    y_range: (f64, f64),
    cmap: ColourMap,
    scale: ColourScale,
    range: (f64, f64),
) -> Vec<u8> {
    use rayon::prelude::*;
    let spec = grid.spec;
    let mut buf = vec![255u8; (w as usize) * (h as usize) * 3];
    if grid.data.len() != spec.len() || spec.is_empty() || w == 0 {
        return buf;
    }
    let cells = |lo: f64, hi: f64, origin: f64, n: usize| -> Option<(usize, usize)> {
        let a = ((lo - origin) / spec.cell_m).floor();
        let b = ((hi - origin) / spec.cell_m).ceil();
        if b <= 0.0 || a >= n as f64 {
            return None;
        }
        let a = a.max(0.0) as usize;
        Some((a, (b as usize).clamp(a + 1, n)))
    };
    let (mx, my) = ((x_range.1 - x_range.0) / f64::from(w), (y_range.1 - y_range.0) / f64::from(h));
    let cols: Vec<Option<(usize, usize)>> = (0..w)
        .map(|sx| {
            let xa = x_range.0 + f64::from(sx) * mx;
            cells(xa, xa + mx, spec.x_min_m, spec.nx)
        })
        .collect();
    // Pixel rows are independent: drawn on rayon's threads (issue 14).
    // Each task's colours by value: a direct-mapped cache (a map holds a few
    // thousand distinct values and most pixels repeat one; the spline is
    // evaluated once per value a task meets, not per pixel).
    let init = || (Vec::new(), vec![None::<(u64, RGBColor)>; COLOUR_CACHE]);
    buf.par_chunks_mut(w as usize * 3).enumerate().for_each_init(init, |(row_max, cache), (sy, out)| {
        let yb = y_range.1 - sy as f64 * my;
        let Some((j0, j1)) = cells(yb - my, yb, spec.y_min_m, spec.ny) else { return };
        // The pixel row's cell rows, reduced to one row of column maxima
        // first (f64::max ignores NaN, so the order of the cells does not matter).
        let row_of = |j: usize| &grid.data[j * spec.nx..(j + 1) * spec.nx];
        let maxima: &[f64] = if j1 - j0 == 1 {
            row_of(j0)
        } else {
            row_max.clear();
            row_max.extend_from_slice(row_of(j0));
            for j in j0 + 1..j1 {
                row_max.iter_mut().zip(row_of(j)).for_each(|(m, x)| *m = m.max(*x));
            }
            row_max
        };
        for (sx, c) in cols.iter().enumerate() {
            let Some((i0, i1)) = *c else { continue };
            let v = maxima[i0..i1].iter().fold(f64::NEG_INFINITY, |m, x| m.max(*x));
            let bits = v.to_bits();
            let slot = &mut cache[colour_slot(bits)];
            let col = match *slot {
                Some((b, c)) if b == bits => c,
                _ => {
                    let c = cmap.eval(scale.position(v, range));
                    *slot = Some((bits, c));
                    c
                }
            };
            out[sx * 3..sx * 3 + 3].copy_from_slice(&[col.0, col.1, col.2]);
        }
    });
    buf
}

/// Draws a vertical colour bar in `area`: `cmap(f(v))` for v from 0 to
/// `top`, labelled in true values with `desc` beside it.
pub(crate) fn colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    (lo, hi): (f64, f64),
    desc: &str,
    colour: impl Fn(f64) -> RGBColor,
    (margin_top, margin_bottom): (u32, u32),
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let label_w = 46;
    let mut bar = ChartBuilder::on(area)
        .margin_top(margin_top)
        .margin_bottom(margin_bottom)
        .margin_left(10)
        .margin_right(label_w + 28)
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(plot_err)?;
    let steps = 256;
    bar.draw_series((0..steps).map(|k| {
        let a = lo + (hi - lo) * k as f64 / steps as f64;
        let b = lo + (hi - lo) * (k + 1) as f64 / steps as f64;
        Rectangle::new([(0.0, a), (1.0, b)], colour(0.5 * (a + b)).filled())
    }))
    .map_err(plot_err)?;
    bar.draw_series(std::iter::once(Rectangle::new([(0.0, lo), (1.0, hi)], BLACK.stroke_width(1))))
        .map_err(plot_err)?;
    // Ticks and labels on the right, as people write them.
    // Pixel ranges are absolute; `area` draws relative to its own corner.
    let (ox, oy) = area.get_base_pixel();
    let (px, py) = bar.plotting_area().get_pixel_range();
    let (px, py) = (px.start - ox..px.end - ox, py.start - oy..py.end - oy);
    let n = 6;
    let ticks = nice_ticks(lo, hi, n);
    for v in ticks {
        let y = py.end - 1 - ((v - lo) / (hi - lo) * f64::from(py.end - 1 - py.start)).round() as i32;
        area.draw(&PathElement::new(vec![(px.end, y), (px.end + 5, y)], BLACK.stroke_width(1))).map_err(plot_err)?;
        area.draw(&Text::new(
            tick_label(v),
            (px.end + 8, y),
            ("sans-serif", 13).into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center)),
        ))
        .map_err(plot_err)?;
    }
    let (w, h) = area.dim_in_pixel();
    area.draw(&Text::new(
        desc.to_string(),
        ((px.end + label_w + 22).min(w as i32 - 4), (h / 2) as i32),
        ("sans-serif", 14)
            .into_font()
            .transform(FontTransform::Rotate270)
            .color(&BLACK)
            .pos(Pos::new(HPos::Center, VPos::Bottom)),
    ))
    .map_err(plot_err)?;
    Ok(())
}

/// Round tick values (steps of 1, 2 or 5 × 10ᵏ) inside `[lo, hi]`, about `n` of them.
pub fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo || n == 0 {
        return Vec::new();
    }
    let raw = (hi - lo) / n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Heat map of the grid with highlights, sources, listener path, obstacles
/// and evidence-mapper surfaces; axes in metres at 1:1 and a colour bar.
/// Colour is √(value/max) so faint single ellipses stay visible (linear over
/// [min, max] for maps with negative values, such as log-odds); the bar is
/// labelled in true values. [`MapStyle`] holds the extras (surfaces, colour
/// map, colour-bar label). Writes SVG when `path` ends in `.svg`, PNG otherwise.
pub fn render_map_with(path: &Path, plot: &MapPlot, style: &MapStyle) -> Result<()> {
    ensure_font();
    let spec = plot.grid.spec;
    let layout = map_layout((spec.x_min_m, spec.x_max_m()), (spec.y_min_m, spec.y_max_m()));
    with_backend!(path, layout.size_px, |root| draw_map(root, plot, style, &layout))
}

fn draw_map<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    plot: &MapPlot,
    style: &MapStyle,
    layout: &MapLayout,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let (title, body) = root.split_vertically(TITLE_H);
    title
        .draw(&Text::new(
            plot.title.clone(),
            ((layout.size_px.0 / 2) as i32, (TITLE_H / 2) as i32),
            ("sans-serif", 20).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Center)),
        ))
        .map_err(plot_err)?;
    let (left, right) = body.split_horizontally(layout.size_px.0 - BAR_W);
    let (x0, x1) = layout.x_range;
    let (y0, y1) = layout.y_range;
    let mut chart = ChartBuilder::on(&left)
        .margin(MARGIN)
        .x_label_area_size(X_LABELS)
        .y_label_area_size(Y_LABELS)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(plot_err)?;
    let fmt = |v: &f64| tick_label(*v);
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(plot_err)?;

    let (px, py) = chart.plotting_area().get_pixel_range();
    let (pw, ph) = ((px.end - px.start).max(1) as u32, (py.end - py.start).max(1) as u32);
    let (scale, range) = ColourScale::with_range(&plot.grid.data);
    let raster = grid_raster_in(plot.grid, (pw, ph), layout.x_range, layout.y_range, style.colour_map, scale, range);
    if let Some(img) = BitMapElement::<_>::with_owned_buffer((px.start, py.start), (pw, ph), raster) {
        root.draw(&img).map_err(plot_err)?;
    }

    let (xr, yr) = (layout.x_range, layout.y_range);
    for (k, o) in plot.obstacles.iter().enumerate() {
        let runs = clip_path(&outline(&o.shape), xr, yr);
        chart.draw_series(runs.iter().map(|r| PathElement::new(r.clone(), BLACK.stroke_width(4)))).map_err(plot_err)?;
        let s = chart
            .draw_series(runs.into_iter().map(|r| PathElement::new(r, OBSTACLE.stroke_width(2))))
            .map_err(plot_err)?;
        if k == 0 {
            s.label("obstacles").legend(|(x, y)| {
                Rectangle::new([(x, y - 5), (x + 16, y + 5)], ShapeStyle::from(&BLACK).stroke_width(2))
            });
        }
    }
    let stride = (plot.listener_positions.len() / 4000).max(1);
    if !plot.listener_positions.is_empty() {
        chart
            .draw_series(
                plot.listener_positions
                    .iter()
                    .step_by(stride)
                    .filter(|p| inside((p.x, p.y), xr, yr))
                    .map(|p| Circle::new((p.x, p.y), 1, LISTENER.filled())),
            )
            .map_err(plot_err)?
            .label("listener positions")
            .legend(|(x, y)| Circle::new((x + 8, y), 3, LISTENER.mix(1.0).filled().stroke_width(1)));
        if let (Some(r), Some(p)) = (plot.listener_radius_m, plot.listener_positions.first()) {
            let c = Shape::Circle(chirpmap_core::Circle { center: *p, radius_m: r.max(1e-9) });
            chart
                .draw_series(
                    clip_path(&outline(&c), xr, yr).into_iter().map(|r| PathElement::new(r, LISTENER.stroke_width(2))),
                )
                .map_err(plot_err)?;
        }
    }
    draw_surfaces(&mut chart, style.surfaces, xr, yr)?;
    if !plot.sources.is_empty() {
        chart
            .draw_series(plot.sources.iter().filter(|p| inside((p.x, p.y), xr, yr)).flat_map(|p| {
                [
                    TriangleMarker::new((p.x, p.y), 11, BLACK.filled()),
                    TriangleMarker::new((p.x, p.y), 7, WHITE.filled()),
                ]
            }))
            .map_err(plot_err)?
            .label("source")
            .legend(|(x, y)| TriangleMarker::new((x + 8, y), 6, BLACK.filled()));
    }
    if !plot.highlights.is_empty() {
        chart
            .draw_series(plot.highlights.iter().filter(|h| inside((h.pos.x, h.pos.y), xr, yr)).flat_map(|h| {
                [
                    Circle::new((h.pos.x, h.pos.y), 8, WHITE.stroke_width(5)),
                    Circle::new((h.pos.x, h.pos.y), 8, HIGHLIGHT.stroke_width(3)),
                ]
            }))
            .map_err(plot_err)?
            .label("highlights")
            .legend(|(x, y)| Circle::new((x + 8, y), 5, HIGHLIGHT.stroke_width(3)));
    }
    draw_legend(&mut chart)?;

    let cmap = style.colour_map;
    colour_bar(
        &right,
        range,
        style.value_label.unwrap_or("accumulated weight"),
        |v| cmap.eval(scale.position(v, range)),
        (MARGIN, MARGIN + X_LABELS),
    )?;
    root.present().map_err(plot_err)?;
    Ok(())
}

fn draw_surfaces<DB: DrawingBackend>(
    chart: &mut ChartContext<
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    surfaces: &[Surface],
    xr: (f64, f64),
    yr: (f64, f64),
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let mut labelled = false;
    for &(a, b, ambiguous) in surfaces {
        let is_point = (a.0 - b.0).abs() < 1e-12 && (a.1 - b.1).abs() < 1e-12;
        let (a, b) = if is_point {
            if !inside(a, xr, yr) {
                continue;
            }
            (a, b)
        } else {
            match clip_segment(a, b, xr, yr) {
                Some(ab) => ab,
                None => continue,
            }
        };
        let mut elements: Vec<DynElement<DB, (f64, f64)>> = Vec::new();
        if is_point {
            elements.push(Cross::new(a, 7, BLACK.stroke_width(5)).into_dyn());
            elements.push(Cross::new(a, 7, SURFACE.stroke_width(3)).into_dyn());
        } else if ambiguous {
            elements
                .push(plotters::element::DashedPathElement::new(vec![a, b], 8, 6, BLACK.stroke_width(5)).into_dyn());
            elements
                .push(plotters::element::DashedPathElement::new(vec![a, b], 8, 6, SURFACE.stroke_width(3)).into_dyn());
        } else {
            elements.push(PathElement::new(vec![a, b], BLACK.stroke_width(5)).into_dyn());
            elements.push(PathElement::new(vec![a, b], SURFACE.stroke_width(3)).into_dyn());
        }
        let s = chart.draw_series(elements).map_err(plot_err)?;
        if !labelled {
            labelled = true;
            s.label("surfaces (dashed: ambiguous)")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], SURFACE.stroke_width(3)));
        }
    }
    Ok(())
}

/// One listener spectrum (paper §II.B: loudness summed per frequency bin) with
/// its direct and reflected peaks marked.
#[derive(Debug)]
pub struct SpectrumPlot<'a> {
    pub title: String,
    /// `(bin lower edge Hz, loudness)` of occupied bins.
    pub bins: &'a [(f64, f64)],
    pub bin_hz: f64,
    /// Frequency axis range (Hz).
    pub f_range_hz: (f64, f64),
    pub direct_hz: Option<f64>,
    pub reflected_hz: &'a [f64],
}

/// Log-scaled loudness so the faint reflected peaks show next to the direct
/// one. Bars are at least 3 px wide; peaks are marked by triangles above
/// their bars (red: direct, blue: reflected), so markers never hide bars.
/// The log axis spans whole decades, each labelled. SVG for `.svg` paths.
pub fn render_spectrum(path: &Path, plot: &SpectrumPlot) -> Result<()> {
    ensure_font();
    with_backend!(path, (1000, 520), |root| draw_spectrum(root, plot))
}

fn draw_spectrum<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, plot: &SpectrumPlot) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let vmax = plot.bins.iter().map(|b| b.1).filter(|v| v.is_finite()).fold(0.0, f64::max).max(1e-12);
    let vmin = plot.bins.iter().map(|b| b.1).filter(|v| v.is_finite() && *v > 0.0).fold(vmax, f64::min);
    // Whole decades, with room above the tallest bar for its marker.
    let top = 10f64.powf((vmax * 3.0).log10().ceil());
    let floor = 10f64.powf(vmin.log10().floor()).min(top / 10.0);
    // Widen by a hair so rounding in plotters' decade walk keeps both end decades.
    let (floor, top) = (floor * (1.0 - 1e-9), top * (1.0 + 1e-9));
    let (f0, f1) = plot.f_range_hz;
    let (f0, f1) = if f1 > f0 { (f0, f1) } else { (f0, f0 + 1.0) };
    let mut chart = ChartBuilder::on(&root)
        .caption(&plot.title, ("sans-serif", 20))
        .margin(12)
        .margin_right(40)
        .x_label_area_size(44)
        .y_label_area_size(70)
        .build_cartesian_2d(f0..f1, (floor..top).log_scale())
        .map_err(plot_err)?;
    let decades = (top / floor).log10().round().max(1.0) as usize;
    let fmt_x = |v: &f64| tick_label(*v);
    let fmt_y = |v: &f64| decade_label(*v);
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("frequency (Hz)")
        .y_desc("summed loudness (log scale)")
        .x_label_formatter(&fmt_x)
        .y_label_formatter(&fmt_y)
        .y_labels(decades + 1)
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(plot_err)?;
    let (px, _) = chart.plotting_area().get_pixel_range();
    let hz_per_px = (f1 - f0) / f64::from((px.end - px.start).max(1));
    let width = plot.bin_hz.max(3.0 * hz_per_px);
    let grey = RGBColor(40, 40, 40);
    chart
        .draw_series(plot.bins.iter().filter(|b| b.1 > 0.0).map(|&(f, v)| {
            let c = f + 0.5 * plot.bin_hz;
            Rectangle::new([(c - 0.5 * width, floor), (c + 0.5 * width, v)], grey.filled())
        }))
        .map_err(plot_err)?
        .label(format!("spectrum ({} Hz bins)", tick_label(plot.bin_hz)))
        .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 16, y + 4)], grey.filled()));
    // Marker height: just above the tallest bar within ±2 bins of the peak.
    let height_at = |f: f64| {
        plot.bins
            .iter()
            .filter(|b| (b.0 + 0.5 * plot.bin_hz - f).abs() <= 2.0 * plot.bin_hz.max(hz_per_px))
            .map(|b| b.1)
            .fold(floor, f64::max)
            * 1.6
    };
    if let Some(f) = plot.direct_hz {
        chart
            .draw_series(std::iter::once(TriangleMarker::new((f, height_at(f)), 8, RED.filled())))
            .map_err(plot_err)?
            .label("direct peak")
            .legend(|(x, y)| TriangleMarker::new((x + 8, y), 6, RED.filled()));
    }
    if !plot.reflected_hz.is_empty() {
        chart
            .draw_series(plot.reflected_hz.iter().map(|&f| TriangleMarker::new((f, height_at(f)), 7, BLUE.filled())))
            .map_err(plot_err)?
            .label("reflected peaks (echoes)")
            .legend(|(x, y)| TriangleMarker::new((x + 8, y), 6, BLUE.filled()));
    }
    legend_and_present(&mut chart, &root)
}

#[cfg(test)]
mod tests {
    use super::*;
    use chirpmap_core::GridSpec;

    fn draw_sample<DB: DrawingBackend>(root: DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE).map_err(plot_err)?;
        root.draw(&Rectangle::new([(3, 2), (20, 9)], RGBColor(200, 30, 40).filled())).map_err(plot_err)?;
        root.draw(&Circle::new((30, 12), 5, BLUE.filled())).map_err(plot_err)?;
        root.present().map_err(plot_err)
    }

    /// A figure drawn through `with_backend!` to a `.PNG` path (any case)
    /// is written by `write_png` and decodes (png's decoder, not the
    /// encoder's code) to the pixels plotters drew in memory.
    #[test]
    fn png_figures_decode_to_the_drawn_pixels() {
        let (w, h) = (41u32, 23u32);
        let mut drawn = vec![0u8; (w * h * 3) as usize];
        draw_sample(BitMapBackend::with_buffer(&mut drawn, (w, h)).into_drawing_area()).unwrap();
        assert!(drawn.iter().any(|&b| b != 255), "the test must draw something");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("figure.PNG");
        with_backend!(&path, (w, h), draw_sample).unwrap();
        let mut reader = png::Decoder::new(std::fs::File::open(&path).unwrap()).read_info().unwrap();
        let mut decoded = vec![0u8; reader.output_buffer_size()];
        let info = reader.next_frame(&mut decoded).unwrap();
        assert_eq!((info.width, info.height, info.color_type), (w, h, png::ColorType::Rgb));
        assert_eq!(decoded, drawn);
    }

    #[test]
    fn a_png_that_cannot_be_written_is_an_io_error() {
        let dir = tempfile::tempdir().unwrap();
        let e = write_png(&dir.path().join("missing").join("map.png"), &[0; 12], (2, 2)).unwrap_err();
        assert_eq!(e.downcast_ref::<std::io::Error>().map(std::io::Error::kind), Some(std::io::ErrorKind::NotFound));
    }

    #[test]
    fn tick_labels_read_as_written() {
        assert_eq!(tick_label(50.0), "50");
        assert_eq!(tick_label(-50.0), "-50");
        assert_eq!(tick_label(0.25), "0.25");
        assert_eq!(tick_label(0.1 + 0.2), "0.3");
        assert_eq!(tick_label(-0.0), "0");
        assert_eq!(tick_label(-2.7755575615628914e-17), "0");
        assert_eq!(tick_label(-1e-7), "-1e-7");
        assert_eq!(tick_label(2.5e9), "2.5e9");
        assert_eq!(decade_label(1e-3), "10⁻³");
        assert_eq!(decade_label(100.0), "10²");
        assert_eq!(decade_label(1.0), "10⁰");
        assert_eq!(decade_label(20.0), "");
    }

    #[test]
    fn nice_ticks_are_round_and_inside() {
        assert_eq!(nice_ticks(0.0, 10.0, 5), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        assert_eq!(nice_ticks(-60.0, 0.0, 6), vec![-60.0, -50.0, -40.0, -30.0, -20.0, -10.0, 0.0]);
        let t = nice_ticks(0.0, 37.3, 6);
        assert!(t.iter().all(|v| (0.0..=37.3).contains(v)) && t.len() >= 4, "{t:?}");
        assert!(nice_ticks(1.0, 1.0, 5).is_empty());
    }

    #[test]
    fn colour_maps_are_the_published_tables() {
        // matplotlib's _viridis_data / _inferno_data end points (×255, rounded).
        assert_eq!(ColourMap::Viridis.eval(0.0), RGBColor(68, 1, 84));
        assert_eq!(ColourMap::Viridis.eval(1.0), RGBColor(253, 231, 37));
        assert_eq!(ColourMap::Inferno.eval(0.0), RGBColor(0, 0, 4));
        assert_eq!(ColourMap::Inferno.eval(2.0), ColourMap::Inferno.eval(1.0));
        assert_eq!(ColourMap::Viridis.eval(f64::NAN), ColourMap::Viridis.eval(0.0));
    }

    #[test]
    fn map_layout_is_one_to_one_for_any_shape() {
        for (wx, wy) in [(100.0, 100.0), (100.0, 7.0), (3.0, 90.0), (1000.0, 1.0), (0.5, 0.5)] {
            let l = map_layout((-wx / 2.0, wx / 2.0), (2.0, 2.0 + wy));
            let mx = (l.x_range.1 - l.x_range.0) / f64::from(l.plot_px.0);
            let my = (l.y_range.1 - l.y_range.0) / f64::from(l.plot_px.1);
            assert!((mx - my).abs() <= 1e-9 * mx, "{wx}×{wy}: {mx} vs {my} m/px");
            // The whole grid is shown.
            assert!(l.x_range.0 <= -wx / 2.0 + 1e-9 && l.x_range.1 >= wx / 2.0 - 1e-9);
            assert!(l.y_range.0 <= 2.0 + 1e-9 && l.y_range.1 >= 2.0 + wy - 1e-9);
            assert!(l.plot_px.0.max(l.plot_px.1) <= 2400);
        }
    }

    #[test]
    fn paths_are_cut_at_the_box() {
        let (x, y) = ((0.0, 10.0), (0.0, 10.0));
        assert_eq!(clip_segment((-5.0, 5.0), (15.0, 5.0), x, y), Some(((0.0, 5.0), (10.0, 5.0))));
        assert_eq!(clip_segment((-5.0, -5.0), (-1.0, 20.0), x, y), None);
        assert_eq!(clip_segment((1.0, 1.0), (2.0, 2.0), x, y), Some(((1.0, 1.0), (2.0, 2.0))));
        // In, out, in again: two runs; a path wholly outside: none.
        let runs = clip_path(&[(1.0, 5.0), (20.0, 5.0), (20.0, 6.0), (1.0, 6.0)], x, y);
        assert_eq!(runs, vec![vec![(1.0, 5.0), (10.0, 5.0)], vec![(10.0, 6.0), (1.0, 6.0)]]);
        assert!(clip_path(&[(20.0, 20.0), (30.0, 30.0)], x, y).is_empty());
    }

    fn test_grid() -> Grid {
        let spec = GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 1.0, nx: 40, ny: 10 };
        let mut g = Grid::zeros(spec);
        g.data[3 * 40 + 5] = 4.0; // cell (5, 3)
        g.data[9 * 40 + 39] = 1.0; // top-right cell
        g
    }

    #[test]
    fn raster_puts_rows_of_y_max_on_top_and_keeps_single_cells() {
        let g = test_grid();
        // 4 px per cell.
        let r = grid_raster(&g, (160, 40), (0.0, 40.0), (0.0, 10.0), ColourMap::Viridis, ColourScale::SqrtOfMax);
        let px = |x: usize, y: usize| [r[(y * 160 + x) * 3], r[(y * 160 + x) * 3 + 1], r[(y * 160 + x) * 3 + 2]];
        let top = ColourMap::Viridis.eval(1.0);
        // Cell (5, 3): x in [5, 6) → px 20..24; y in [3, 4) → rows from the top 24..28.
        assert_eq!(px(21, 25), [top.0, top.1, top.2]);
        let half = ColourMap::Viridis.eval(0.5); // √(1/4)
        assert_eq!(px(158, 1), [half.0, half.1, half.2]);
        let zero = ColourMap::Viridis.eval(0.0);
        assert_eq!(px(80, 20), [zero.0, zero.1, zero.2]);
        // Downsampled 10×: the single hot cell still shows (max, not mean).
        let small = grid_raster(&g, (4, 1), (0.0, 40.0), (0.0, 10.0), ColourMap::Viridis, ColourScale::SqrtOfMax);
        assert_eq!(&small[..3], &[top.0, top.1, top.2]);
    }

    #[test]
    fn linear_scale_spans_negative_values() {
        // Log-odds: -2 (free) … 0 (unknown) … 2 (occupied).
        let spec = GridSpec { x_min_m: 0.0, y_min_m: 0.0, cell_m: 1.0, nx: 3, ny: 1 };
        let g = Grid { spec, data: vec![-2.0, 0.0, 2.0] };
        assert_eq!(ColourScale::Linear.range(&g.data), (-2.0, 2.0));
        assert_eq!(ColourScale::SqrtOfMax.range(&g.data), (0.0, 2.0));
        let r = grid_raster(&g, (3, 1), (0.0, 3.0), (0.0, 1.0), ColourMap::Viridis, ColourScale::Linear);
        let at = |k: usize| RGBColor(r[3 * k], r[3 * k + 1], r[3 * k + 2]);
        assert_eq!(at(0), ColourMap::Viridis.eval(0.0));
        assert_eq!(at(1), ColourMap::Viridis.eval(0.5));
        assert_eq!(at(2), ColourMap::Viridis.eval(1.0));
        // A constant or empty map still has a usable range.
        assert_eq!(ColourScale::Linear.range(&[3.0, 3.0]), (3.0, 4.0));
        // One pass gives what the two give, on the grid above and edge cases.
        for data in [&g.data[..], &[], &[0.0, 0.0], &[f64::NAN, 2.0, f64::INFINITY], &[-1.0, f64::NEG_INFINITY, 5.0]] {
            let scale = ColourScale::for_values(data);
            assert_eq!(ColourScale::with_range(data), (scale, scale.range(data)), "{data:?}");
        }
        assert_eq!(ColourScale::SqrtOfMax.range(&[]), (0.0, 1.0));
        assert_eq!(ColourScale::Linear.range(&[f64::NAN]), (0.0, 1.0));
        assert_eq!(ColourScale::for_values(&g.data), ColourScale::Linear);
        assert_eq!(ColourScale::for_values(&[0.0, 3.0]), ColourScale::SqrtOfMax);
    }

    proptest::proptest! {
        /// The eight-lane pass gives what the two plain passes give, for any
        /// length (lanes and tail) and any mix of NaN, ±∞, ±0 and negatives.
        #[test]
        fn one_lane_pass_is_the_two_plain_passes(data in proptest::collection::vec(proptest::prop_oneof![
            -5.0f64..5.0,
            proptest::strategy::Just(f64::NAN),
            proptest::strategy::Just(f64::INFINITY),
            proptest::strategy::Just(f64::NEG_INFINITY),
            proptest::strategy::Just(-0.0),
            proptest::strategy::Just(0.0),
        ], 0..40)) {
            let scale = ColourScale::for_values(&data);
            proptest::prop_assert_eq!(ColourScale::with_range(&data), (scale, scale.range(&data)));
        }
    }

    #[test]
    fn map_renders_png_and_svg_with_surfaces() {
        let dir = tempfile::tempdir().unwrap();
        let g = test_grid();
        let hl = [Highlight { pos: Point::new(5.5, 3.5), value: 4.0 }];
        let surfaces: [Surface; 3] =
            [((1.0, 1.0), (10.0, 1.0), false), ((1.0, 8.0), (10.0, 8.0), true), ((20.0, 5.0), (20.0, 5.0), false)];
        let plot = MapPlot {
            title: "test".into(),
            grid: &g,
            highlights: &hl,
            sources: &[Point::new(0.0, 0.0)],
            listener_positions: &[Point::new(30.0, 5.0), Point::new(31.0, 5.0)],
            listener_radius_m: Some(0.5),
            obstacles: &[],
        };
        let style = MapStyle { surfaces: &surfaces, ..MapStyle::default() };
        for name in ["m.png", "m.svg"] {
            render_map_with(&dir.path().join(name), &plot, &style).unwrap();
        }
        let svg = std::fs::read_to_string(dir.path().join("m.svg")).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("<image") && svg.contains("<text"), "{}", &svg[..200]);
        // One embedded image for the heat map, not a rectangle per pixel.
        assert!(svg.len() < 400_000, "{} bytes", svg.len());
        let png = std::fs::read(dir.path().join("m.png")).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }

    #[test]
    fn spectrum_renders() {
        let dir = tempfile::tempdir().unwrap();
        let bins = [(1000.0, 5.0), (1010.0, 0.01), (3000.0, 0.2)];
        let plot = SpectrumPlot {
            title: "s".into(),
            bins: &bins,
            bin_hz: 10.0,
            f_range_hz: (200.0, 10_000.0),
            direct_hz: Some(1005.0),
            reflected_hz: &[3005.0],
        };
        render_spectrum(&dir.path().join("s.png"), &plot).unwrap();
        render_spectrum(&dir.path().join("s.svg"), &plot).unwrap();
        assert!(std::fs::read_to_string(dir.path().join("s.svg")).unwrap().contains("10⁻"));
    }
}
