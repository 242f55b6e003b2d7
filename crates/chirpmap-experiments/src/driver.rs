//! The whole sweep lifecycle on an output directory: initialise or resume,
//! run what is missing, stream rows, write summaries; and merging shards.

use crate::error::ExperimentError;
use crate::runner::execute;
use crate::runs::{RUNS_FILE, RunMetrics, RunRow, RunsFile, SHARD_FILE, SWEEP_FILE, read_rows, write_sorted};
use crate::summary::{ConfigSummary, summarise, summary_csv, summary_md};
use crate::sweep::{Job, Plan, Shard, SweepDef};
use chirpmap_core::Scene;
use std::collections::BTreeMap;
use std::path::Path;

/// What a sweep (or merge) left in its directory.
#[derive(Debug)]
pub struct Outcome {
    pub rows: Vec<RunRow>,
    /// Runs of this shard already present before this invocation.
    pub resumed: usize,
    /// Runs executed now.
    pub executed: usize,
    pub summaries: Vec<ConfigSummary>,
}

/// Writes summary.csv and summary.md (atomically) for `rows`.
pub fn write_summaries(dir: &Path, plan: &Plan, rows: &[RunRow]) -> Result<Vec<ConfigSummary>, ExperimentError> {
    let s = summarise(plan, rows);
    for (name, text) in [("summary.csv", summary_csv(plan, &s)), ("summary.md", summary_md(plan, &s))] {
        let p = dir.join(name);
        let tmp = dir.join(format!(".{name}.tmp"));
        std::fs::write(&tmp, text).map_err(|e| ExperimentError::io(&tmp, e))?;
        std::fs::rename(&tmp, &p).map_err(|e| ExperimentError::io(&p, e))?;
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
        return Err(ExperimentError::file(&file.path, format!("holds run {stray:?}, which is not in shard {shard:?}")));
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
    let rows = file.finish(plan)?;
    let summaries = write_summaries(dir, plan, &rows)?;
    Ok(Outcome { rows, resumed, executed, summaries })
}

/// Reads a sweep directory's definition.
pub fn read_sweep_def(dir: &Path) -> Result<(String, SweepDef), ExperimentError> {
    let p = dir.join(SWEEP_FILE);
    let text = std::fs::read_to_string(&p).map_err(|e| ExperimentError::io(&p, e))?;
    let def = SweepDef::from_toml_str(&text).map_err(|e| ExperimentError::file(&p, e.to_string()))?;
    Ok((text, def))
}

/// Problems found while merging.
#[derive(Debug, Default)]
pub struct MergeReport {
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
                        "run {:?} appears twice with different results (second in {})",
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
    report.missing = plan.jobs().into_iter().filter(|j| !rows.contains_key(j)).collect();
    std::fs::create_dir_all(out).map_err(|e| ExperimentError::io(out, e))?;
    let sweep_path = out.join(SWEEP_FILE);
    std::fs::write(&sweep_path, &text0).map_err(|e| ExperimentError::io(&sweep_path, e))?;
    let shard_path = out.join(SHARD_FILE);
    std::fs::write(&shard_path, "0/1\n").map_err(|e| ExperimentError::io(&shard_path, e))?;
    let rows: Vec<RunRow> = rows.into_values().collect();
    write_sorted(&out.join(RUNS_FILE), &plan, &rows)?;
    let summaries = write_summaries(out, &plan, &rows)?;
    Ok((Outcome { rows, resumed: 0, executed: 0, summaries }, report))
}
