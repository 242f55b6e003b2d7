//! `summary.png`: each configuration's mean scores with their 95 % intervals.

use anyhow::{Result, anyhow};
use chirpmap_experiments::Plan;
use chirpmap_experiments::stats::MeanCi;
use chirpmap_experiments::summary::ConfigSummary;
use plotters::prelude::*;
use std::path::Path;

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plotting summary failed: {e}")
}

/// Two panels (score_obstacle, score_highlight): one row per configuration,
/// a dot at the mean and a bar over the 95 % confidence interval.
pub fn plot_summary(path: &Path, plan: &Plan, summaries: &[ConfigSummary]) -> Result<()> {
    crate::plot::ensure_font();
    let n = summaries.len().max(1);
    let height = (90 + 24 * n).clamp(300, 2400) as u32;
    let root = BitMapBackend::new(path, (1200, height)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let root = root
        .titled(
            &format!("{}: mean ± 95 % CI ({} runs per configuration)", plan.def.name, plan.def.runs),
            ("sans-serif", 20),
        )
        .map_err(plot_err)?;
    let (left, right) = root.split_horizontally(700);
    let label = |k: usize| -> String {
        summaries.get(k).map_or_else(String::new, |s| {
            plan.def.params.iter().zip(&s.labels).map(|(p, l)| format!("{}={l}", p.name)).collect::<Vec<_>>().join(", ")
        })
    };
    type Panel<'a, A> = (&'a A, &'static str, fn(&ConfigSummary) -> MeanCi, bool);
    let panels: [Panel<_>; 2] = [
        (&left, "score_obstacle", |s| s.score_obstacle, true),
        (&right, "score_highlight", |s| s.score_highlight, false),
    ];
    for (area, name, get, with_labels) in panels {
        let mut chart = ChartBuilder::on(area)
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(if with_labels { 330 } else { 10 })
            .caption(name, ("sans-serif", 16))
            .build_cartesian_2d(0.0..1.05f64, (-0.5)..(n as f64 - 0.5))
            .map_err(plot_err)?;
        let fmt_label = |y: &f64| {
            let k = y.round();
            if with_labels && (y - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < n {
                label(n - 1 - k as usize)
            } else {
                String::new()
            }
        };
        chart
            .configure_mesh()
            .y_labels(n)
            .x_desc(name)
            .light_line_style(WHITE.mix(0.0))
            .y_label_formatter(&fmt_label)
            .y_label_style(("sans-serif", 11))
            .draw()
            .map_err(plot_err)?;
        chart
            .draw_series(summaries.iter().enumerate().filter_map(|(k, s)| {
                let m = get(s);
                let y = (n - 1 - k) as f64;
                m.mean.is_finite().then(|| {
                    let (lo, hi) = if m.half_width.is_finite() { (m.low(), m.high()) } else { (m.mean, m.mean) };
                    ErrorBar::new_horizontal(y, lo, m.mean, hi, BLUE.filled(), 8)
                })
            }))
            .map_err(plot_err)?;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}
