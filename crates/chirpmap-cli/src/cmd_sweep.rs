//! `chirpmap sweep` and `chirpmap merge`: the paper's tables, in parallel,
//! resumable, shardable.

use crate::plot_summary::plot_summary;
use anyhow::{Context, Result, anyhow, bail};
use chirpmap_experiments::driver::{merge, run_sweep};
use chirpmap_experiments::presets::{PRESETS, preset};
use chirpmap_experiments::{Plan, Shard, SweepDef};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The most worker threads `--threads` takes: each holds a run's working
/// memory, so a mistyped count (a million) used to start threads for a
/// minute and then fail.
const MAX_THREADS: u64 = 1024;

#[derive(Debug, Args)]
pub struct SweepArgs {
    /// A preset (`table1`, `table2`) or a sweep TOML file.
    pub sweep: String,
    /// Output directory (runs.csv, summary.csv, summary.md, summary.png). Rerunning resumes.
    #[arg(long)]
    pub out: PathBuf,
    /// Override the number of runs per configuration.
    #[arg(long)]
    pub runs: Option<u64>,
    /// Worker threads (default: all cores), 1 to 1024. Results do not depend on it.
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_THREADS))]
    pub threads: Option<usize>,
    /// Run only shard I of N (0-based), e.g. `--shard 2/8`; join shards with `chirpmap merge`.
    #[arg(long, value_parser = parse_shard)]
    pub shard: Option<Shard>,
}

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// Shard output directories of one sweep.
    #[arg(required = true)]
    pub dirs: Vec<PathBuf>,
    /// Output directory for the joined runs.csv and summaries.
    #[arg(long)]
    pub out: PathBuf,
}

fn parse_shard(s: &str) -> Result<Shard, String> {
    Shard::parse(s).map_err(|e| e.to_string())
}

/// Resolves a preset name or a sweep file.
pub fn load_sweep(arg: &str) -> Result<SweepDef> {
    let (start, path_len) = chirpmap::default_listener_path();
    if let Some(def) = preset(arg, start, path_len) {
        return Ok(def);
    }
    let path = Path::new(arg);
    if !path.exists() {
        bail!("unknown preset {arg:?} and no such sweep file (presets: {})", PRESETS.join(", "));
    }
    let text = crate::files::read_text_input(path, "sweep file", crate::files::MAX_TOML_BYTES)?;
    SweepDef::from_toml_str(&text).map_err(|e| anyhow!("{}: {e}", path.display()))
}

fn plan(def: &SweepDef) -> Result<Plan, chirpmap_experiments::ExperimentError> {
    def.plan(chirpmap_experiments::pipeline::validate_scene)
}

/// Draws summary.png (into a hidden file moved into place, so a failure
/// keeps the previous figure whole).
fn finish(dir: &Path, plan: &Plan, summaries: &[chirpmap_experiments::summary::ConfigSummary]) -> Result<()> {
    let png = dir.join("summary.png");
    // A new file's name (never a user's file of the same name), drawn over.
    let (staged, _) = chirpmap_experiments::runs::new_sibling(&png)?;
    let drawn = plot_summary(&staged, plan, summaries)
        .and_then(|()| std::fs::rename(&staged, &png).map_err(anyhow::Error::from))
        .with_context(|| format!("cannot write {}", png.display()));
    if drawn.is_err() {
        std::fs::remove_file(&staged).ok();
    }
    drawn
}

fn print_summary(dir: &Path) {
    let md = std::fs::read_to_string(dir.join("summary.md")).unwrap_or_default();
    say!("{md}");
}

pub fn run_sweep_cmd(args: &SweepArgs, no_progress: bool) -> Result<()> {
    let mut def = load_sweep(&args.sweep)?;
    if let Some(r) = args.runs {
        def.runs = r;
    }
    let plan = plan(&def).map_err(|e| anyhow!("{}: {e}", args.sweep))?;
    let shard = args.shard.unwrap_or(Shard::ALL);
    let threads = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let total = plan.shard_jobs(shard).len();
    let bar = ProgressBar::new(total as u64);
    if no_progress {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} runs  {per_sec}  ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let started = Instant::now();
    let outcome =
        run_sweep(&plan, &args.out, shard, threads, chirpmap_experiments::pipeline::run_metrics, |done, _| {
            bar.set_position(done as u64);
        })?;
    bar.finish_and_clear();
    let secs = started.elapsed().as_secs_f64();
    finish(&args.out, &plan, &outcome.summaries)?;
    eprintln!(
        "{}: {} runs done ({} resumed, {} run now) in {secs:.1} s on {threads} threads ({:.1} runs/s); wrote {}",
        plan.def.name,
        outcome.rows.len(),
        outcome.resumed,
        outcome.executed,
        outcome.executed as f64 / secs.max(1e-9),
        args.out.display()
    );
    print_summary(&args.out);
    Ok(())
}

pub fn run_merge_cmd(args: &MergeArgs) -> Result<()> {
    let inputs: Vec<&Path> = args.dirs.iter().map(PathBuf::as_path).collect();
    let (outcome, report) = merge(&inputs, &args.out, plan)?;
    if !report.duplicated.is_empty() {
        eprintln!(
            "warning: {} runs appear in more than one input (identical results, kept once), e.g. configuration {}, run {}",
            report.duplicated.len(),
            report.duplicated[0].config,
            report.duplicated[0].run
        );
    }
    if !report.missing.is_empty() {
        eprintln!(
            "warning: {} runs are missing (first: configuration {}, run {}); the summary covers the rest",
            report.missing.len(),
            report.missing[0].config,
            report.missing[0].run
        );
    }
    let (_, def) = chirpmap_experiments::driver::read_sweep_def(inputs[0])?;
    let plan = plan(&def)?;
    finish(&args.out, &plan, &outcome.summaries)?;
    eprintln!("merged {} runs from {} directories into {}", outcome.rows.len(), inputs.len(), args.out.display());
    print_summary(&args.out);
    Ok(())
}
