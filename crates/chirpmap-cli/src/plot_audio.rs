//! Audio figures (paper Fig. 8): a spectrogram of one chirp with a dB colour
//! bar, and the amplitude spectrum of one frame with the direct and reflected
//! peaks. SVG when the path ends in `.svg`, PNG otherwise.

use crate::plot::{
    COLOUR_CACHE, ColourMap, colour_bar, colour_slot, ensure_font, legend_and_present, line_chart, plot_err,
    tick_label, with_backend,
};
use anyhow::Result;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// Dynamic range shown by the spectrogram (dB below its maximum).
const RANGE_DB: f64 = 60.0;

/// Spectrogram: `frames[i][k]` magnitude at time `t0_s + i·hop_s`, bin k of
/// width `bin_hz`; shown in dB relative to the largest magnitude over the top
/// 60 dB (inferno), up to `f_max_hz`, with a colour bar in dB.
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
    let sg = Spectrogram { title, frames, t0_s, hop_s, bin_hz, f_max_hz };
    with_backend!(path, (1000, 600), |root| draw_spectrogram(root, &sg))
}

struct Spectrogram<'a> {
    title: &'a str,
    frames: &'a [Vec<f64>],
    t0_s: f64,
    hop_s: f64,
    bin_hz: f64,
    f_max_hz: f64,
}

/// RGB raster (`w` × `h`, top row = `f_max`) of the spectrogram in dB.
/// Pixel rows are drawn on rayon's threads, and each task evaluates the
/// colour map once per distinct value it meets (a direct-mapped cache: a
/// frequency bin spans several pixel rows, and a `log10` plus a spline per
/// pixel made the figure a tenth of `range`'s wall time; issue 14).
fn spectrogram_raster(sg: &Spectrogram, (w, h): (u32, u32)) -> Vec<u8> {
    use rayon::prelude::*;
    let mut buf = vec![255u8; (w as usize) * (h as usize) * 3];
    let max = sg.frames.iter().flat_map(|f| f.iter()).filter(|v| v.is_finite()).fold(0.0f64, |m, v| m.max(*v));
    if max <= 0.0 || sg.bin_hz <= 0.0 || w == 0 {
        return buf;
    }
    // The frame of each pixel column and the bin of each pixel row.
    let frame_of: Vec<Option<&Vec<f64>>> = (0..w)
        .map(|sx| sg.frames.get(((f64::from(sx) + 0.5) / f64::from(w) * sg.frames.len() as f64) as usize))
        .collect();
    let colour = |v: f64| {
        let db = 20.0 * (v / max).max(1e-12).log10();
        ColourMap::Inferno.eval((db + RANGE_DB) / RANGE_DB)
    };
    let init = || vec![None::<(u64, RGBColor)>; COLOUR_CACHE];
    buf.par_chunks_mut(w as usize * 3).enumerate().for_each_init(init, |cache, (sy, row)| {
        let f = (1.0 - (sy as f64 + 0.5) / f64::from(h)) * sg.f_max_hz;
        let bin = (f / sg.bin_hz) as usize;
        for (px, fr) in row.chunks_exact_mut(3).zip(&frame_of) {
            let Some(&v) = fr.and_then(|fr| fr.get(bin)) else { continue };
            let bits = v.to_bits();
            let slot = &mut cache[colour_slot(bits)];
            let c = match *slot {
                Some((b, c)) if b == bits => c,
                _ => {
                    let c = colour(v);
                    *slot = Some((bits, c));
                    c
                }
            };
            px.copy_from_slice(&[c.0, c.1, c.2]);
        }
    });
    buf
}

fn draw_spectrogram<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, sg: &Spectrogram) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let (left, right) = root.split_horizontally(880);
    let t1 = sg.t0_s + sg.hop_s * sg.frames.len().max(1) as f64;
    let f_max = if sg.f_max_hz > 0.0 { sg.f_max_hz } else { 1.0 };
    let mut chart = ChartBuilder::on(&left)
        .caption(sg.title, ("sans-serif", 20))
        .margin(12)
        .margin_right(20)
        .x_label_area_size(44)
        .y_label_area_size(70)
        .build_cartesian_2d(sg.t0_s..t1, 0.0..f_max)
        .map_err(plot_err)?;
    let fmt = |v: &f64| tick_label(*v);
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("time in recording (s)")
        .y_desc("frequency (Hz)")
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(plot_err)?;
    let (px, py) = chart.plotting_area().get_pixel_range();
    let (pw, ph) = ((px.end - px.start).max(1) as u32, (py.end - py.start).max(1) as u32);
    let raster = spectrogram_raster(sg, (pw, ph));
    if let Some(img) = BitMapElement::<_>::with_owned_buffer((px.start, py.start), (pw, ph), raster) {
        root.draw(&img).map_err(plot_err)?;
    }
    // The bar spans the plotting area's height: same top and bottom margins.
    let (_, h) = root.dim_in_pixel();
    let top = u32::try_from(py.start).unwrap_or(0);
    let bottom = h.saturating_sub(u32::try_from(py.end).unwrap_or(h));
    colour_bar(
        &right,
        (-RANGE_DB, 0.0),
        "level (dB re max)",
        |db| ColourMap::Inferno.eval((db + RANGE_DB) / RANGE_DB),
        (top, bottom),
    )?;
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
    with_backend!(path, (1000, 520), |root| draw_spectrum(root, title, freqs_hz, amplitude, direct_hz, reflected_hz))
}

fn draw_spectrum<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    freqs_hz: &[f64],
    amplitude: &[f64],
    direct_hz: Option<f64>,
    reflected_hz: Option<f64>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let f0 = freqs_hz.first().copied().unwrap_or(0.0);
    let f1 = freqs_hz.last().copied().unwrap_or(1.0);
    let (f0, f1) = if f1 > f0 { (f0, f1) } else { (f0, f0 + 1.0) };
    let top = amplitude.iter().filter(|v| v.is_finite()).fold(0.0f64, |m, v| m.max(*v)).max(1e-30) * 1.1;
    let mut chart = line_chart(&root, title, (f0..f1, 0.0..top), 80, ("frequency (Hz)", "amplitude (smoothed)"))?;
    chart
        .draw_series(LineSeries::new(freqs_hz.iter().copied().zip(amplitude.iter().copied()), BLACK.stroke_width(2)))
        .map_err(plot_err)?
        .label("spectrum")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
    for (f, colour, label) in [(direct_hz, BLUE, "direct"), (reflected_hz, RED, "reflected")] {
        if let Some(f) = f {
            chart
                .draw_series(std::iter::once(plotters::element::DashedPathElement::new(
                    vec![(f, 0.0), (f, top)],
                    6,
                    4,
                    colour.stroke_width(2),
                )))
                .map_err(plot_err)?
                .label(format!("{label} {f:.0} Hz"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
        }
    }
    legend_and_present(&mut chart, &root)
}

/// Echogram (issue 10, item 5): the impulse response's envelope in dB
/// against the path difference, the echoes found in most chirps as red
/// dashed lines, the predicted floor/ceiling echoes as blue dotted ones.
pub fn render_echogram(
    path: &Path,
    title: &str,
    curve: &[(f64, f64)],
    echoes: &[(f64, String)],
    predicted: &[(&'static str, f64)],
) -> Result<()> {
    ensure_font();
    with_backend!(path, (1100, 520), |root| draw_echogram(root, title, curve, echoes, predicted))
}

/// Lowest level shown by the echogram (dB re the direct sound).
const ECHOGRAM_FLOOR_DB: f64 = -60.0;

fn draw_echogram<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    curve: &[(f64, f64)],
    echoes: &[(f64, String)],
    predicted: &[(&'static str, f64)],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let finite = || curve.iter().filter(|(d, l)| d.is_finite() && l.is_finite());
    let x0 = finite().map(|p| p.0).fold(f64::INFINITY, f64::min);
    let x1 = finite().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
    let (x0, x1) = if x0.is_finite() && x1 > x0 { (x0, x1) } else { (0.0, 1.0) };
    let mut chart = line_chart(
        &root,
        title,
        (x0..x1, ECHOGRAM_FLOOR_DB..5.0),
        70,
        ("path difference to the direct sound (m)", "envelope (dB re direct)"),
    )?;
    chart
        .draw_series(LineSeries::new(finite().map(|&(d, l)| (d, l.max(ECHOGRAM_FLOOR_DB))), BLACK.stroke_width(1)))
        .map_err(plot_err)?
        .label("median envelope")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
    for (k, (d, label)) in echoes.iter().enumerate() {
        let line = std::iter::once(plotters::element::DashedPathElement::new(
            vec![(*d, ECHOGRAM_FLOOR_DB), (*d, 5.0)],
            5,
            4,
            RED.mix(0.8).stroke_width(1),
        ));
        let s = chart.draw_series(line).map_err(plot_err)?;
        if k == 0 {
            s.label("echo (in most chirps)")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], RED.stroke_width(2)));
        }
        if !label.is_empty() {
            chart
                .draw_series(std::iter::once(Text::new(label.clone(), (*d, 2.0), ("sans-serif", 13).into_font())))
                .map_err(plot_err)?;
        }
    }
    for (k, (label, d)) in predicted.iter().enumerate() {
        let line = std::iter::once(plotters::element::DashedPathElement::new(
            vec![(*d, ECHOGRAM_FLOOR_DB), (*d, 5.0)],
            2,
            3,
            BLUE.stroke_width(2),
        ));
        let s = chart.draw_series(line).map_err(plot_err)?;
        if k == 0 {
            s.label("predicted floor/ceiling")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLUE.stroke_width(2)));
        }
        let text =
            Text::new(format!("{label} (predicted)"), (*d, ECHOGRAM_FLOOR_DB + 4.0), ("sans-serif", 13).into_font());
        chart.draw_series(std::iter::once(text)).map_err(plot_err)?;
    }
    legend_and_present(&mut chart, &root)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spectrogram_raster_is_in_db_with_high_frequencies_on_top() {
        // Two frames, 4 bins of 100 Hz: frame 0 loud at bin 0, frame 1 at bin 3 (−20 dB).
        let frames = vec![vec![1.0, 0.0, 0.0, 0.0], vec![0.0, 0.0, 0.0, 0.1]];
        let sg = Spectrogram { title: "", frames: &frames, t0_s: 0.0, hop_s: 0.1, bin_hz: 100.0, f_max_hz: 400.0 };
        let r = spectrogram_raster(&sg, (2, 4));
        let px = |x: usize, y: usize| RGBColor(r[(y * 2 + x) * 3], r[(y * 2 + x) * 3 + 1], r[(y * 2 + x) * 3 + 2]);
        assert_eq!(px(0, 3), ColourMap::Inferno.eval(1.0)); // bottom row = bin 0, 0 dB
        assert_eq!(px(1, 0), ColourMap::Inferno.eval(40.0 / 60.0)); // top row = bin 3, −20 dB
        assert_eq!(px(0, 0), ColourMap::Inferno.eval(0.0)); // silence floors at −60 dB
    }

    #[test]
    fn audio_figures_render_as_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        let frames: Vec<Vec<f64>> =
            (0..50).map(|i| (0..200).map(|k| if k == i + 20 { 1.0 } else { 1e-3 }).collect()).collect();
        let freqs: Vec<f64> = (0..100).map(|k| 100.0 * f64::from(k)).collect();
        let amp: Vec<f64> = freqs.iter().map(|f| (-((f - 3000.0) / 300.0).powi(2)).exp()).collect();
        for ext in ["png", "svg"] {
            render_spectrogram(&dir.path().join(format!("g.{ext}")), "g", &frames, 1.0, 0.01, 50.0, 10_000.0).unwrap();
            render_spectrum(&dir.path().join(format!("s.{ext}")), "s", &freqs, &amp, Some(3000.0), Some(4200.0))
                .unwrap();
            let curve: Vec<(f64, f64)> =
                (0..500).map(|i| (f64::from(i) * 0.01, -40.0 + 30.0 * f64::from(i % 97 == 0))).collect();
            render_echogram(
                &dir.path().join(format!("e.{ext}")),
                "e",
                &curve,
                &[(0.97, String::new()), (1.94, "ceiling".into())],
                &[("ceiling", 1.9)],
            )
            .unwrap();
        }
        let svg = std::fs::read_to_string(dir.path().join("g.svg")).unwrap();
        assert!(svg.contains("<image") && svg.contains("dB"));
    }
}
