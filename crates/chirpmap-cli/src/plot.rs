//! PNG plots (plotters, bitmap backend, bundled DejaVu Sans so plots render
//! the same on machines without system fonts).

use anyhow::{Result, anyhow};
use chirpmap_core::{Grid, Highlight, Obstacle, Point, Shape};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

/// Registers the bundled font once; plotters' `ab_glyph` backend needs it.
pub fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and known good; failure would be a build bug.
        let _ = register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plotting failed: {e}")
}

/// Colour for t ∈ [0, 1] on a perceptually ordered dark-to-bright ramp
/// (an approximation of "inferno").
pub fn heat_colour(t: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 6] = [
        (0.0, [252.0, 255.0, 164.0]),
        (0.2, [249.0, 187.0, 54.0]),
        (0.4, [234.0, 108.0, 34.0]),
        (0.6, [186.0, 54.0, 85.0]),
        (0.8, [107.0, 23.0, 110.0]),
        (1.0, [20.0, 11.0, 53.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    let k = STOPS.iter().position(|s| s.0 >= t).unwrap_or(STOPS.len() - 1).max(1);
    let (t0, c0) = STOPS[k - 1];
    let (t1, c1) = STOPS[k];
    let u = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
    let mix = |a: f64, b: f64| (a + (b - a) * u).round() as u8;
    RGBColor(mix(c0[0], c1[0]), mix(c0[1], c1[1]), mix(c0[2], c1[2]))
}

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
            v.push(v[0]);
            v
        }
    }
}

/// Heat map of the accumulation with highlights, sources, listener path and
/// obstacles; axes in metres and a colour bar. Colour is √(value/max) so faint
/// single ellipses stay visible; the bar is labelled in true values.
pub fn render_map(path: &Path, plot: &MapPlot) -> Result<()> {
    ensure_font();
    let spec = plot.grid.spec;
    let (x0, x1, y0, y1) = (spec.x_min_m, spec.x_max_m(), spec.y_min_m, spec.y_max_m());
    let plot_w = 800.0;
    let height = ((plot_w * (y1 - y0) / (x1 - x0)) + 110.0).clamp(400.0, 1600.0) as u32;
    let root = BitMapBackend::new(path, (1000, height)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (left, right) = root.split_horizontally(880);
    let mut chart = ChartBuilder::on(&left)
        .caption(&plot.title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(plot_err)?;

    let max = plot.grid.max();
    let (px, py) = chart.plotting_area().get_pixel_range();
    let (pw, ph) = ((px.end - px.start).max(1) as f64, (py.end - py.start).max(1) as f64);
    let cell_range = |lo: f64, hi: f64, origin: f64, n: usize| {
        let a = ((lo - origin) / spec.cell_m).floor().max(0.0) as usize;
        let b = (((hi - origin) / spec.cell_m).ceil() as usize).clamp(a + 1, n.max(a + 1));
        (a.min(n.saturating_sub(1)), b.min(n))
    };
    if max > 0.0 {
        for sy in py.clone() {
            let ya = y1 - (f64::from(sy - py.start) + 1.0) / ph * (y1 - y0);
            let yb = y1 - f64::from(sy - py.start) / ph * (y1 - y0);
            let (j0, j1) = cell_range(ya, yb, y0, spec.ny);
            for sx in px.clone() {
                let xa = x0 + f64::from(sx - px.start) / pw * (x1 - x0);
                let xb = x0 + (f64::from(sx - px.start) + 1.0) / pw * (x1 - x0);
                let (i0, i1) = cell_range(xa, xb, x0, spec.nx);
                let mut v = 0.0f64;
                for j in j0..j1 {
                    for i in i0..i1 {
                        v = v.max(plot.grid.get(i, j));
                    }
                }
                if v > 0.0 {
                    root.draw_pixel((sx, sy), &heat_colour((v / max).sqrt())).map_err(plot_err)?;
                }
            }
        }
    }

    for (k, o) in plot.obstacles.iter().enumerate() {
        let s = chart
            .draw_series(std::iter::once(PathElement::new(outline(&o.shape), RED.stroke_width(2))))
            .map_err(plot_err)?;
        if k == 0 {
            s.label("obstacles").legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], RED.stroke_width(2)));
        }
    }
    let stride = (plot.listener_positions.len() / 4000).max(1);
    if !plot.listener_positions.is_empty() {
        chart
            .draw_series(
                plot.listener_positions.iter().step_by(stride).map(|p| Circle::new((p.x, p.y), 1, GREEN.filled())),
            )
            .map_err(plot_err)?
            .label("listener positions")
            .legend(|(x, y)| Circle::new((x + 8, y), 3, GREEN.filled()));
        if let (Some(r), Some(p)) = (plot.listener_radius_m, plot.listener_positions.first()) {
            let c = Shape::Circle(chirpmap_core::Circle { center: *p, radius_m: r.max(1e-9) });
            chart
                .draw_series(std::iter::once(PathElement::new(outline(&c), GREEN.stroke_width(2))))
                .map_err(plot_err)?;
        }
    }
    if !plot.sources.is_empty() {
        chart
            .draw_series(plot.sources.iter().map(|p| TriangleMarker::new((p.x, p.y), 9, BLUE.filled())))
            .map_err(plot_err)?
            .label("source")
            .legend(|(x, y)| TriangleMarker::new((x + 8, y), 6, BLUE.filled()));
    }
    if !plot.highlights.is_empty() {
        chart
            .draw_series(plot.highlights.iter().flat_map(|h| {
                [
                    Circle::new((h.pos.x, h.pos.y), 7, BLACK.stroke_width(3)),
                    Circle::new((h.pos.x, h.pos.y), 7, YELLOW.stroke_width(2)),
                ]
            }))
            .map_err(plot_err)?
            .label("highlights")
            .legend(|(x, y)| Circle::new((x + 8, y), 5, YELLOW.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(plot_err)?;

    // Colour bar.
    let top = if max > 0.0 { max } else { 1.0 };
    let mut bar = ChartBuilder::on(&right)
        .margin_top(44)
        .margin_bottom(52)
        .margin_right(8)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..1.0, 0.0..top)
        .map_err(plot_err)?;
    bar.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(8)
        .y_label_style(("sans-serif", 12))
        .y_desc("accumulated weight")
        .axis_desc_style(("sans-serif", 14))
        .draw()
        .map_err(plot_err)?;
    let steps = 200;
    bar.draw_series((0..steps).map(|k| {
        let (a, b) = (k as f64 / steps as f64 * top, (k + 1) as f64 / steps as f64 * top);
        Rectangle::new([(0.0, a), (1.0, b)], heat_colour((a / top).sqrt()).filled())
    }))
    .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
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

/// Log-scaled loudness so the faint reflected peaks show next to the direct one.
pub fn render_spectrum(path: &Path, plot: &SpectrumPlot) -> Result<()> {
    ensure_font();
    let root = BitMapBackend::new(path, (1000, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let top = plot.bins.iter().map(|b| b.1).fold(0.0, f64::max).max(1e-9) * 2.0;
    let floor = plot.bins.iter().map(|b| b.1).filter(|v| *v > 0.0).fold(top, f64::min) / 4.0;
    let (f0, f1) = plot.f_range_hz;
    let mut chart = ChartBuilder::on(&root)
        .caption(&plot.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(f0..f1, (floor..top).log_scale())
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("frequency (Hz)")
        .y_desc("summed loudness (log)")
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(plot_err)?;
    if let Some(f) = plot.direct_hz {
        chart
            .draw_series(std::iter::once(PathElement::new(vec![(f, floor), (f, top)], RED.mix(0.6).stroke_width(3))))
            .map_err(plot_err)?
            .label("direct peak")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], RED.stroke_width(3)));
    }
    if !plot.reflected_hz.is_empty() {
        chart
            .draw_series(
                plot.reflected_hz
                    .iter()
                    .map(|&f| PathElement::new(vec![(f, floor), (f, top)], BLUE.mix(0.5).stroke_width(2))),
            )
            .map_err(plot_err)?
            .label("reflected peaks (echoes)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLUE.stroke_width(2)));
    }
    let grey = RGBColor(30, 30, 30);
    chart
        .draw_series(
            plot.bins.iter().map(|&(f, v)| {
                Rectangle::new([(f, floor), (f + plot.bin_hz.max((f1 - f0) / 800.0), v)], grey.filled())
            }),
        )
        .map_err(plot_err)?
        .label("spectrum (10 Hz bins)")
        .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 16, y + 4)], grey.filled()));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}
