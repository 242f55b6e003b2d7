//! The whole sweep lifecycle on an output directory: initialise or resume,
//! run what is missing, stream rows, write summaries; and merging shards.

use crate::error::ExperimentError;
use crate::runner::execute;
use crate::runs::{
    CUT_SHORT, RUNS_FILE, RunMetrics, RunRow, RunsFile, SHARD_FILE, SWEEP_FILE, SweepLock, foreign_sweep_file,
    read_rows, shard_file_is_cut, sweep_file_is_cut, write_atomic, write_sorted,
};
use crate::summary::{ConfigSummary, summarise, summary_csv, summary_md};
use crate::sweep::{Job, Plan, Shard, SweepDef};
use chirpmap_core::Scene;
use std::collections::BTreeMap;
use std::path::Path;

/// What a sweep (or merge) left in its directory.
#[derive(Debug)]
pub struct Outcome {
    /// All rows now in the directory (earlier and new runs).
    pub rows: Vec<RunRow>,
    /// Runs of this shard already present before this invocation.
    pub resumed: usize,
    /// Runs executed now.
    pub executed: usize,
    /// Per-configuration summaries of `rows`.
    pub summaries: Vec<ConfigSummary>,
}

/// Writes summary.csv and summary.md (atomically) for `rows`.
pub fn write_summaries(dir: &Path, plan: &Plan, rows: &[RunRow]) -> Result<Vec<ConfigSummary>, ExperimentError> {
    let s = summarise(plan, rows);
    for (name, text) in [("summary.csv", summary_csv(plan, &s)), ("summary.md", summary_md(plan, &s))] {
        write_atomic(&dir.join(name), text.as_bytes())?;
    }
    Ok(s)
}

/// Runs shard `shard` of `plan` into `dir`, resuming whatever is there.
/// `progress(done, total)` is called after every finished run.
pub fn run_sweep(
    plan: &Plan,
    dir: &Path,
    shard: Shard,
    threads: usize,
    run_one: impl Fn(&Scene, u64) -> Result<RunMetrics, String> + Sync,
    mut progress: impl FnMut(usize, usize),
) -> Result<Outcome, ExperimentError> {
    let mut file = RunsFile::open(dir, plan, shard)?;
    let jobs = plan.shard_jobs(shard);
    let resumed = file.done.len();
    if let Some(stray) = file.done.keys().find(|j| !jobs.contains(j)) {
        return Err(ExperimentError::file(&file.path, format!("holds run ({stray}), which is not in shard {shard}")));
    }
    let todo: Vec<Job> = jobs.iter().copied().filter(|j| !file.done.contains_key(j)).collect();
    let total = jobs.len();
    progress(resumed, total);
    let mut executed = 0;
    execute(plan, &todo, threads, run_one, |row| {
        file.append(row)?;
        executed += 1;
        progress(resumed + executed, total);
        Ok(())
    })?;
    let (rows, _still_ours) = file.finish(plan)?;
    let summaries = write_summaries(dir, plan, &rows)?;
    Ok(Outcome { rows, resumed, executed, summaries })
}

/// Reads a sweep directory's definition.
pub fn read_sweep_def(dir: &Path) -> Result<(String, SweepDef), ExperimentError> {
    let p = dir.join(SWEEP_FILE);
    let text = std::fs::read_to_string(&p).map_err(|e| ExperimentError::io(&p, e))?;
    if text.trim().is_empty() {
        return Err(ExperimentError::file(&p, format!("{CUT_SHORT}, not a sweep definition")));
    }
    let def = SweepDef::from_toml_str(&text).map_err(|e| ExperimentError::file(&p, e.to_string()))?;
    Ok((text, def))
}

/// `shard.txt` of a merged output: the whole sweep.
const MERGED_SHARD: &str = "0/1\n";

/// Whether two existing paths are the same directory: same canonical path,
/// or (on Unix) the same device and inode, so `./s0`, `s0/` and a symlink to
/// it are all recognised.
fn same_dir(a: &Path, b: &Path) -> bool {
    let (Ok(ca), Ok(cb)) = (std::fs::canonicalize(a), std::fs::canonicalize(b)) else { return false };
    if ca == cb {
        return true;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(ma), Ok(mb)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return ma.dev() == mb.dev() && ma.ino() == mb.ino();
        }
    }
    false
}

/// Refuses a merge `--out` that is one of the inputs, or that holds anything
/// but nothing at all or an earlier merge of this same sweep (issue 8, item
/// 4: `merge s0 s1 --out other` overwrote another sweep, `--out s0`
/// rewrote a shard's shard.txt). `run_sweep` refuses the same way.
fn check_merge_out(inputs: &[&Path], out: &Path, sweep_text: &str) -> Result<(), ExperimentError> {
    if !out.exists() {
        return Ok(());
    }
    if !out.is_dir() {
        return Err(ExperimentError::file(out, "exists and is not a directory; merge writes a directory"));
    }
    if let Some(input) = inputs.iter().find(|d| same_dir(d, out)) {
        return Err(ExperimentError::Merge(format!(
            "--out {} is the input shard directory {}; merge into a new directory",
            out.display(),
            input.display()
        )));
    }
    let refuse = |why: &str| {
        Err(ExperimentError::Merge(format!("--out {} {why}; merge into a new or empty directory", out.display())))
    };
    let read = std::fs::read_to_string(out.join(SWEEP_FILE));
    // Why a whole sweep.toml other than this sweep's is no sweep definition (parsed once).
    let foreign = read.as_ref().ok().filter(|t| *t != sweep_text).and_then(|t| foreign_sweep_file(t));
    match read {
        Ok(text) if text != sweep_text && sweep_file_is_cut(&text, sweep_text) => {
            refuse(&format!("holds a {SWEEP_FILE} that {CUT_SHORT}"))
        }
        Ok(_) if foreign.is_some() => Err(ExperimentError::file(&out.join(SWEEP_FILE), foreign.unwrap_or_default())),
        Ok(text) if text != sweep_text => refuse("holds another sweep (its sweep.toml differs)"),
        Ok(_) => match std::fs::read_to_string(out.join(SHARD_FILE)) {
            Ok(shard) if shard == MERGED_SHARD => Ok(()),
            Ok(shard) if shard_file_is_cut(&shard) => refuse(&format!("holds a {SHARD_FILE} that {CUT_SHORT}")),
            Ok(shard) => refuse(&format!("holds shard {} of this sweep, not a merged output", shard.trim())),
            Err(_) => refuse("holds a sweep.toml without shard.txt, not a merged output"),
        },
        Err(_) => {
            let mut entries = std::fs::read_dir(out).map_err(|e| ExperimentError::io(out, e))?;
            if entries.next().is_some() { refuse("is not empty and holds no sweep") } else { Ok(()) }
        }
    }
}

/// Problems found while merging.
#[derive(Debug, Default)]
pub struct MergeReport {
    /// Jobs of the plan found in no input.
    pub missing: Vec<Job>,
    /// Jobs present in more than one input (identical results are kept once).
    pub duplicated: Vec<Job>,
}

/// Joins shard directories into `out`. Refuses inputs from different sweeps
/// or seeds, and duplicates whose results differ; reports missing runs.
pub fn merge(
    inputs: &[&Path],
    out: &Path,
    plan_of: impl Fn(&SweepDef) -> Result<Plan, ExperimentError>,
) -> Result<(Outcome, MergeReport), ExperimentError> {
    let first = inputs.first().ok_or_else(|| ExperimentError::Merge("no input directories".into()))?;
    let (text0, def0) = read_sweep_def(first)?;
    check_merge_out(inputs, out, &text0)?;
    for d in &inputs[1..] {
        let (text, def) = read_sweep_def(d)?;
        if text != text0 {
            let why = if def.seed != def0.seed { "a different seed" } else { "a different sweep definition" };
            return Err(ExperimentError::Merge(format!("{} and {} hold {why}", first.display(), d.display())));
        }
    }
    let plan = plan_of(&def0)?;
    let mut report = MergeReport::default();
    let mut rows: BTreeMap<Job, RunRow> = BTreeMap::new();
    for d in inputs {
        let p = d.join(RUNS_FILE);
        if !p.exists() {
            return Err(ExperimentError::file(&p, "missing (not a sweep output directory?)"));
        }
        for r in read_rows(&p, &plan)? {
            match rows.get(&r.job) {
                Some(prev) if prev.metrics != r.metrics => {
                    return Err(ExperimentError::Merge(format!(
                        "run ({}) appears twice with different results (second in {})",
                        r.job,
                        d.display()
                    )));
                }
                Some(_) => report.duplicated.push(r.job),
                None => {
                    rows.insert(r.job, r);
                }
            }
        }
    }
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::io(out, e))?;
    // Held to the end: a sweep still running in `out`, or another merge,
    // must not write there meanwhile (two sweeps may not either).
    let _lock = SweepLock::take(out)?;
    // Checked again now that `out` exists and is locked (a symlink or a race
    // could make it an input).
    check_merge_out(inputs, out, &text0)?;
    // An earlier merge or a whole sweep of this same sweep in `out` keeps
    // its runs (with their times) and gains the inputs' others: they were
    // replaced by the inputs' alone, losing any run no input held.
    let kept = out.join(RUNS_FILE);
    if kept.exists() {
        for r in read_rows(&kept, &plan)? {
            match rows.get(&r.job) {
                Some(input) if input.metrics != r.metrics => {
                    return Err(ExperimentError::file(
                        &kept,
                        format!("holds run ({}) with results other than the inputs'", r.job),
                    ));
                }
                _ => {
                    rows.insert(r.job, r);
                }
            }
        }
    }
    report.missing = plan.jobs().into_iter().filter(|j| !rows.contains_key(j)).collect();
    write_atomic(&out.join(SWEEP_FILE), text0.as_bytes())?;
    write_atomic(&out.join(SHARD_FILE), MERGED_SHARD.as_bytes())?;
    let rows: Vec<RunRow> = rows.into_values().collect();
    write_sorted(&out.join(RUNS_FILE), &plan, &rows)?;
    let summaries = write_summaries(out, &plan, &rows)?;
    Ok((Outcome { rows, resumed: 0, executed: 0, summaries }, report))
}
