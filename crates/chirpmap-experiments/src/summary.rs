//! Per-configuration means with 95 % confidence intervals, laid out like the
//! paper's tables, plus paired differences against a baseline parameter value.

use crate::runs::RunRow;
use crate::stats::MeanCi;
use crate::sweep::Plan;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Summary of one configuration.
#[derive(Debug, Clone)]
pub struct ConfigSummary {
    /// Configuration index in the plan.
    pub config: usize,
    /// Label of each parameter's value.
    pub labels: Vec<String>,
    /// Number of runs summarised.
    pub runs: usize,
    /// Mean obstacle score with its 95 % interval (runs with a defined score).
    pub score_obstacle: MeanCi,
    /// Mean highlight score with its 95 % interval (runs with a defined score).
    pub score_highlight: MeanCi,
    /// Paired difference (this − baseline, same run index), if the sweep has a
    /// baseline and this is not it.
    pub diff_obstacle: Option<MeanCi>,
    /// Paired difference of the highlight score, like `diff_obstacle`.
    pub diff_highlight: Option<MeanCi>,
}

/// Summarises `rows` per configuration of `plan`, with paired differences against the
/// baseline value when a parameter declares one.
pub fn summarise(plan: &Plan, rows: &[RunRow]) -> Vec<ConfigSummary> {
    let mut by_config: BTreeMap<usize, BTreeMap<u64, &RunRow>> = BTreeMap::new();
    for r in rows {
        by_config.entry(r.job.config).or_default().insert(r.job.run, r);
    }
    let baseline = plan.def.params.iter().enumerate().find_map(|(k, p)| {
        let b = p.baseline.as_ref()?;
        (0..p.values.len()).find(|&v| &p.label(v) == b).map(|v| (k, v))
    });
    let empty = BTreeMap::new();
    plan.configs
        .iter()
        .map(|c| {
            let runs = by_config.get(&c.index).unwrap_or(&empty);
            let col = |f: fn(&RunRow) -> Option<f64>| -> Vec<f64> { runs.values().filter_map(|r| f(r)).collect() };
            let so: fn(&RunRow) -> Option<f64> = |r| r.metrics.score_obstacle;
            let sh: fn(&RunRow) -> Option<f64> = |r| r.metrics.score_highlight;
            let (mut diff_obstacle, mut diff_highlight) = (None, None);
            if let Some((k, v)) = baseline
                && c.choice[k] != v
            {
                let mut choice = c.choice.clone();
                choice[k] = v;
                if let Some(base) = plan.configs.iter().find(|b| b.choice == choice) {
                    let base_runs = by_config.get(&base.index).unwrap_or(&empty);
                    let paired = |f: fn(&RunRow) -> Option<f64>| -> Vec<f64> {
                        runs.iter().filter_map(|(run, r)| Some(f(r)? - f(base_runs.get(run)?)?)).collect()
                    };
                    diff_obstacle = Some(MeanCi::of(&paired(so)));
                    diff_highlight = Some(MeanCi::of(&paired(sh)));
                }
            }
            ConfigSummary {
                config: c.index,
                labels: c.labels.clone(),
                runs: runs.len(),
                score_obstacle: MeanCi::of(&col(so)),
                score_highlight: MeanCi::of(&col(sh)),
                diff_obstacle,
                diff_highlight,
            }
        })
        .collect()
}

fn has_diffs(s: &[ConfigSummary]) -> bool {
    s.iter().any(|c| c.diff_obstacle.is_some())
}

/// summary.csv: one line per configuration with means, interval bounds and, if any,
/// paired differences.
pub fn summary_csv(plan: &Plan, s: &[ConfigSummary]) -> String {
    let mut head: Vec<String> = vec!["config".into()];
    head.extend(plan.def.params.iter().map(|p| p.name.clone()));
    head.push("runs".into());
    let stats = ["score_obstacle", "score_highlight"];
    for n in stats {
        head.extend([format!("{n}_mean"), format!("{n}_ci_low"), format!("{n}_ci_high")]);
    }
    let diffs = has_diffs(s);
    if diffs {
        for n in stats {
            head.extend([format!("d_{n}_mean"), format!("d_{n}_ci_low"), format!("d_{n}_ci_high")]);
        }
    }
    let mut w = csv::WriterBuilder::new().from_writer(Vec::new());
    let _ = w.write_record(&head);
    let f = |v: f64| if v.is_finite() { format!("{v:.6}") } else { String::new() };
    let m3 = |m: &MeanCi| [f(m.mean), f(m.low()), f(m.high())];
    for c in s {
        let mut r = vec![c.config.to_string()];
        r.extend(c.labels.iter().cloned());
        r.push(c.runs.to_string());
        r.extend(m3(&c.score_obstacle));
        r.extend(m3(&c.score_highlight));
        if diffs {
            for d in [&c.diff_obstacle, &c.diff_highlight] {
                match d {
                    Some(m) => r.extend(m3(m)),
                    None => r.extend([String::new(), String::new(), String::new()]),
                }
            }
        }
        let _ = w.write_record(&r);
    }
    String::from_utf8(w.into_inner().unwrap_or_default()).unwrap_or_default()
}

/// "mean ± half-width", with an explicit sign for differences.
fn fmt_ci(m: &MeanCi, signed: bool) -> String {
    let mean = if signed { format!("{:+.3}", m.mean) } else { format!("{:.3}", m.mean) };
    if !m.mean.is_finite() {
        "–".into()
    } else if m.half_width.is_finite() {
        format!("{mean} ± {:.3}", m.half_width)
    } else {
        mean
    }
}

/// Markdown table: one row per configuration, mean ± 95 % CI half-width.
pub fn summary_md(plan: &Plan, s: &[ConfigSummary]) -> String {
    let mut out = format!("## {}\n\n", plan.def.name);
    if !plan.def.description.is_empty() {
        let _ = writeln!(out, "{}\n", plan.def.description);
    }
    let _ = writeln!(
        out,
        "{} configurations × {} runs, master seed {}. Cells: mean ± half-width of the 95 % confidence interval (Student's t).\n",
        plan.configs.len(),
        plan.def.runs,
        plan.def.seed
    );
    let diffs = has_diffs(s);
    let mut head: Vec<String> = plan.def.params.iter().map(|p| p.name.clone()).collect();
    head.extend(["runs".into(), "score_obstacle".into(), "score_highlight".into()]);
    if diffs {
        let b = plan.def.params.iter().find_map(|p| p.baseline.clone()).unwrap_or_default();
        head.extend([format!("Δ score_obstacle vs {b}"), format!("Δ score_highlight vs {b}")]);
    }
    let _ = writeln!(out, "| {} |", head.join(" | "));
    let _ = writeln!(out, "|{}", "---|".repeat(head.len()));
    for c in s {
        let mut r = c.labels.clone();
        r.extend([c.runs.to_string(), fmt_ci(&c.score_obstacle, false), fmt_ci(&c.score_highlight, false)]);
        if diffs {
            r.push(c.diff_obstacle.as_ref().map_or_else(|| "(baseline)".into(), |m| fmt_ci(m, true)));
            r.push(c.diff_highlight.as_ref().map_or_else(|| "(baseline)".into(), |m| fmt_ci(m, true)));
        }
        let _ = writeln!(out, "| {} |", r.join(" | "));
    }
    out
}
