//! `summary.png` (or `.svg`): each configuration's mean scores with their
//! 95 % intervals and, when the sweep names a baseline, the paired
//! differences against it (paper §III.A scores; the intervals are Student-t,
//! see `chirpmap_experiments::stats`).

use crate::plot::{ensure_font, plot_err, tick_label, with_backend};
use anyhow::Result;
use chirpmap_experiments::Plan;
use chirpmap_experiments::stats::MeanCi;
use chirpmap_experiments::summary::ConfigSummary;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// Longest row label before it is shortened with "…".
const MAX_LABEL_CHARS: usize = 32;
const ROW_PX: u32 = 26;

/// Row label: the configuration's parameter values only (the parameter names
/// are in the figure's subtitle), e.g. "iii, 50 ms".
fn row_label(s: &ConfigSummary) -> String {
    let full = s.labels.join(", ");
    if full.chars().count() <= MAX_LABEL_CHARS {
        full
    } else {
        let mut short: String = full.chars().take(MAX_LABEL_CHARS - 1).collect();
        short.push('…');
        short
    }
}

/// An interval clipped to the axis `[lo, hi]`, with flags for clipped ends.
fn clip(m: &MeanCi, (lo, hi): (f64, f64)) -> Option<(f64, f64, f64, bool, bool)> {
    if !m.mean.is_finite() {
        return None;
    }
    let (a, b) = if m.half_width.is_finite() { (m.low(), m.high()) } else { (m.mean, m.mean) };
    Some((a.max(lo), m.mean.clamp(lo, hi), b.min(hi), a < lo, b > hi))
}

type Getter = fn(&ConfigSummary) -> Option<MeanCi>;

/// One panel per score (and per paired difference when the sweep has a
/// baseline): one row per configuration, a dot at the mean, a bar over the
/// 95 % confidence interval; intervals are clipped to the axis and a clipped
/// end is drawn as an arrow head. SVG when `path` ends in `.svg`.
pub fn plot_summary(path: &Path, plan: &Plan, summaries: &[ConfigSummary]) -> Result<()> {
    ensure_font();
    let has_diffs = summaries.iter().any(|s| s.diff_obstacle.is_some() || s.diff_highlight.is_some());
    let n = summaries.len().max(1);
    let label_w = summaries.iter().map(|s| row_label(s).chars().count()).max().unwrap_or(4) as u32 * 8 + 24;
    let panel_w = 330;
    let panels = if has_diffs { 4 } else { 2 };
    let width = label_w + panel_w * panels;
    let height = (120 + ROW_PX as usize * n).clamp(260, 8000) as u32;
    with_backend!(path, (width, height), |root| draw_summary(root, plan, summaries, label_w, has_diffs))
}

fn draw_summary<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    plan: &Plan,
    summaries: &[ConfigSummary],
    label_w: u32,
    has_diffs: bool,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let n = summaries.len().max(1);
    let params: Vec<&str> = plan.def.params.iter().map(|p| p.name.as_str()).collect();
    let baseline = plan.def.params.iter().find_map(|p| p.baseline.as_ref().map(|b| format!("{} = {b}", p.name)));
    let title = format!("{}: mean and 95 % CI, {} runs per configuration", plan.def.name, plan.def.runs);
    let subtitle = match &baseline {
        Some(b) => format!("rows: {}; differences are paired (same run) against {b}", params.join(", ")),
        None => format!("rows: {}", params.join(", ")),
    };
    let (w, _) = root.dim_in_pixel();
    let centre = |size| ("sans-serif", size).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Top));
    root.draw(&Text::new(title, ((w / 2) as i32, 6), centre(20))).map_err(plot_err)?;
    root.draw(&Text::new(subtitle, ((w / 2) as i32, 32), centre(14))).map_err(plot_err)?;
    let body = root.split_vertically(56).1;

    let mut panels: Vec<(&str, Getter, (f64, f64))> = vec![
        ("score_obstacle", |s| Some(s.score_obstacle), (0.0, 1.0)),
        ("score_highlight", |s| Some(s.score_highlight), (0.0, 1.0)),
    ];
    if has_diffs {
        // Symmetric about 0, wide enough for every interval (scores are in [0, 1]).
        let reach = |g: Getter| {
            let r = summaries
                .iter()
                .filter_map(g)
                .filter(|m| m.mean.is_finite())
                .map(|m| if m.half_width.is_finite() { m.low().abs().max(m.high().abs()) } else { m.mean.abs() })
                .fold(0.05f64, f64::max);
            let r = (r * 1.1).min(1.0);
            (-r, r)
        };
        let dobs: Getter = |s| s.diff_obstacle;
        let dhl: Getter = |s| s.diff_highlight;
        panels.push(("Δ score_obstacle", dobs, reach(dobs)));
        panels.push(("Δ score_highlight", dhl, reach(dhl)));
    }
    let (labels_area, plots_area) = body.split_horizontally(label_w);
    let areas = plots_area.split_evenly((1, panels.len()));
    let y_range = -0.5..(n as f64 - 0.5);
    let row_y = |k: usize| (n - 1 - k) as f64;
    let mut plot_rows: Option<std::ops::Range<i32>> = None;
    for (area, (name, get, x_range)) in areas.iter().zip(&panels) {
        let mut chart = ChartBuilder::on(area)
            .margin(10)
            .margin_right(18)
            .x_label_area_size(40)
            .y_label_area_size(4)
            .caption(*name, ("sans-serif", 16))
            .build_cartesian_2d(x_range.0..x_range.1, y_range.clone())
            .map_err(plot_err)?;
        let fmt = |v: &f64| tick_label(*v);
        chart
            .configure_mesh()
            .disable_y_mesh()
            .y_labels(0)
            .x_labels(6)
            .x_label_formatter(&fmt)
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(225, 225, 225))
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(plot_err)?;
        // Faint row guides.
        chart
            .draw_series(
                (0..n).map(|k| {
                    PathElement::new(vec![(x_range.0, row_y(k)), (x_range.1, row_y(k))], RGBColor(240, 240, 240))
                }),
            )
            .map_err(plot_err)?;
        if x_range.0 < 0.0 {
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(0.0, -0.5), (0.0, n as f64 - 0.5)],
                    BLACK.stroke_width(1),
                )))
                .map_err(plot_err)?;
        }
        let colour = RGBColor(0, 90, 181);
        for (k, s) in summaries.iter().enumerate() {
            let y = row_y(k);
            let Some(m) = get(s) else {
                if x_range.0 < 0.0 {
                    chart
                        .draw_series(std::iter::once(Text::new(
                            "baseline",
                            (0.0, y),
                            ("sans-serif", 12)
                                .into_font()
                                .color(&RGBColor(110, 110, 110))
                                .pos(Pos::new(HPos::Center, VPos::Center)),
                        )))
                        .map_err(plot_err)?;
                }
                continue;
            };
            let Some((a, mean, b, cut_lo, cut_hi)) = clip(&m, *x_range) else { continue };
            chart
                .draw_series(std::iter::once(ErrorBar::new_horizontal(y, a, mean, b, colour.filled(), 9)))
                .map_err(plot_err)?;
            for (cut, x, dir) in [(cut_lo, a, -1), (cut_hi, b, 1)] {
                if cut {
                    chart
                        .draw_series(std::iter::once(
                            EmptyElement::at((x, y))
                                + PathElement::new(vec![(-6 * dir, -5), (0, 0), (-6 * dir, 5)], colour.stroke_width(2)),
                        ))
                        .map_err(plot_err)?;
                }
            }
        }
        plot_rows.get_or_insert(chart.plotting_area().get_pixel_range().1);
    }
    // Row labels, right-aligned beside the first panel's rows.
    if let Some(py) = plot_rows {
        let (ox, oy) = labels_area.get_base_pixel();
        let h = f64::from((py.end - py.start).max(1));
        for (k, s) in summaries.iter().enumerate() {
            let frac = (row_y(k) + 0.5) / n as f64;
            let y = py.end - (frac * h).round() as i32 - oy;
            labels_area
                .draw(&Text::new(
                    row_label(s),
                    (label_w as i32 - 8, y),
                    ("sans-serif", 14).into_font().color(&BLACK).pos(Pos::new(HPos::Right, VPos::Center)),
                ))
                .map_err(plot_err)?;
        }
        let _ = ox;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ci(mean: f64, half_width: f64) -> MeanCi {
        MeanCi { n: 5, mean, half_width }
    }

    #[test]
    fn intervals_are_clipped_to_the_axis_and_flagged() {
        let close = |got: Option<(f64, f64, f64, bool, bool)>, want: (f64, f64, f64, bool, bool)| {
            let g = got.unwrap();
            assert!((g.0 - want.0).abs() < 1e-12 && (g.1 - want.1).abs() < 1e-12 && (g.2 - want.2).abs() < 1e-12);
            assert_eq!((g.3, g.4), (want.3, want.4));
        };
        close(clip(&ci(0.9, 0.3), (0.0, 1.0)), (0.6, 0.9, 1.0, false, true));
        close(clip(&ci(0.1, 0.3), (0.0, 1.0)), (0.0, 0.1, 0.4, true, false));
        close(clip(&ci(0.5, f64::NAN), (0.0, 1.0)), (0.5, 0.5, 0.5, false, false));
        assert_eq!(clip(&ci(f64::NAN, 0.1), (0.0, 1.0)), None);
    }

    #[test]
    fn labels_are_values_only_and_short() {
        let s = |labels: &[&str]| ConfigSummary {
            config: 0,
            labels: labels.iter().map(|l| l.to_string()).collect(),
            runs: 1,
            score_obstacle: ci(0.5, 0.1),
            score_highlight: ci(0.5, 0.1),
            diff_obstacle: None,
            diff_highlight: None,
        };
        assert_eq!(row_label(&s(&["iii", "50 ms"])), "iii, 50 ms");
        let long = row_label(&s(&["[{ heading_deg = 0.0, start = [-3.0, 10.0] }]", "1 ms"]));
        assert_eq!(long.chars().count(), MAX_LABEL_CHARS);
        assert!(long.ends_with('…'));
    }
}
