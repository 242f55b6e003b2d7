//! Audio figures (paper Fig. 8): a spectrogram of one chirp and the
//! amplitude spectrum of one frame with the direct and reflected peaks.

use crate::plot::{ensure_font, heat_colour};
use anyhow::{Result, anyhow};
use plotters::prelude::*;
use std::path::Path;

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plotting failed: {e}")
}

/// Spectrogram: `frames[i][k]` magnitude at time `t0_s + i·hop_s`, bin k of
/// width `bin_hz`; shown in dB over the top 60 dB, up to `f_max_hz`.
pub fn render_spectrogram(
    path: &Path,
    title: &str,
    frames: &[Vec<f64>],
    t0_s: f64,
    hop_s: f64,
    bin_hz: f64,
    f_max_hz: f64,
) -> Result<()> {
    ensure_font();
    let root = BitMapBackend::new(path, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let t1 = t0_s + hop_s * frames.len().max(1) as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(t0_s..t1, 0.0..f_max_hz)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("time in recording (s)")
        .y_desc("frequency (Hz)")
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(plot_err)?;
    let max = frames.iter().flat_map(|f| f.iter()).fold(0.0f64, |m, v| m.max(*v)).max(1e-30);
    let (px, py) = chart.plotting_area().get_pixel_range();
    let (pw, ph) = ((px.end - px.start).max(1) as f64, (py.end - py.start).max(1) as f64);
    for sx in px.clone() {
        let i = ((f64::from(sx - px.start) / pw) * frames.len() as f64) as usize;
        let Some(fr) = frames.get(i) else { continue };
        for sy in py.clone() {
            let f = (1.0 - f64::from(sy - py.start) / ph) * f_max_hz;
            let k = (f / bin_hz) as usize;
            let Some(v) = fr.get(k) else { continue };
            let db = 20.0 * (v / max).max(1e-12).log10();
            let u = ((db + 60.0) / 60.0).clamp(0.0, 1.0);
            root.draw_pixel((sx, sy), &heat_colour(u)).map_err(plot_err)?;
        }
    }
    root.present().map_err(plot_err)?;
    Ok(())
}

/// Amplitude vs frequency with vertical markers at the direct and
/// reflected peaks.
pub fn render_spectrum(
    path: &Path,
    title: &str,
    freqs_hz: &[f64],
    amplitude: &[f64],
    direct_hz: Option<f64>,
    reflected_hz: Option<f64>,
) -> Result<()> {
    ensure_font();
    let root = BitMapBackend::new(path, (900, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (f0, f1) = (freqs_hz.first().copied().unwrap_or(0.0), freqs_hz.last().copied().unwrap_or(1.0).max(1e-9));
    let top = amplitude.iter().fold(0.0f64, |m, v| m.max(*v)).max(1e-30) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(f0..f1, 0.0..top)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("frequency (Hz)")
        .y_desc("amplitude (smoothed)")
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(plot_err)?;
    chart
        .draw_series(LineSeries::new(freqs_hz.iter().copied().zip(amplitude.iter().copied()), BLACK.stroke_width(2)))
        .map_err(plot_err)?;
    for (f, colour, label) in [(direct_hz, BLUE, "direct"), (reflected_hz, RED, "reflected")] {
        if let Some(f) = f {
            chart
                .draw_series(std::iter::once(PathElement::new(vec![(f, 0.0), (f, top)], colour.stroke_width(2))))
                .map_err(plot_err)?
                .label(format!("{label} {f:.0} Hz"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}
