//! `runs.csv`: one row per finished run, streamed as runs finish so an
//! interrupted sweep loses nothing, and read back to resume or merge.

use crate::error::ExperimentError;
use crate::sweep::{Job, Plan, Shard};
use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::path::{Path, PathBuf};

/// What one run measures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunMetrics {
    /// Score of the obstacle map against the scene's true obstacles; `None` when undefined
    /// (see the core crate's scoring).
    pub score_obstacle: Option<f64>,
    /// Score of the highlight map against the true obstacles; `None` when undefined.
    pub score_highlight: Option<f64>,
    /// Number of highlights in the map.
    pub n_highlights: usize,
    /// Number of echoes the listeners detected.
    pub n_echoes: usize,
}

/// One row of runs.csv.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRow {
    /// Which configuration and run this row belongs to.
    pub job: Job,
    /// Label of each parameter's value, in the sweep's parameter order.
    pub labels: Vec<String>,
    /// Seed recorded for the run (the master seed; the run index selects the stream).
    pub seed: u64,
    /// What the run measured.
    pub metrics: RunMetrics,
    /// Wall-clock time of the run, in seconds.
    pub elapsed_s: f64,
}

/// Column names of runs.csv for `plan`: `config`, one column per parameter, then the
/// run, seed, metric and timing columns.
pub fn header(plan: &Plan) -> Vec<String> {
    let mut h = vec!["config".to_string()];
    h.extend(plan.def.params.iter().map(|p| p.name.clone()));
    h.extend(
        ["run", "seed", "score_obstacle", "score_highlight", "n_highlights", "n_echoes", "elapsed_s"].map(String::from),
    );
    h
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, |x| x.to_string())
}

fn row_record(row: &RunRow) -> Vec<String> {
    let mut r = vec![row.job.config.to_string()];
    r.extend(row.labels.iter().cloned());
    r.extend([
        row.job.run.to_string(),
        row.seed.to_string(),
        opt(row.metrics.score_obstacle),
        opt(row.metrics.score_highlight),
        row.metrics.n_highlights.to_string(),
        row.metrics.n_echoes.to_string(),
        row.elapsed_s.to_string(),
    ]);
    r
}

fn csv_line(fields: &[String]) -> Vec<u8> {
    let mut w = csv::WriterBuilder::new().from_writer(Vec::new());
    // Writing to a Vec cannot fail.
    let _ = w.write_record(fields);
    w.into_inner().unwrap_or_default()
}

/// Reads rows of a runs.csv written for `plan`; errors name file and line.
pub fn read_rows(path: &Path, plan: &Plan) -> Result<Vec<RunRow>, ExperimentError> {
    let text = std::fs::read(path).map_err(|e| ExperimentError::io(path, e))?;
    // A crash can leave a partial last line: ignore anything after the last newline.
    let end = text.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    let mut rdr = csv::ReaderBuilder::new().from_reader(&text[..end]);
    let want = header(plan);
    let have: Vec<String> = rdr
        .headers()
        .map_err(|e| ExperimentError::file(path, format!("cannot read header: {e}")))?
        .iter()
        .map(String::from)
        .collect();
    if have != want {
        return Err(ExperimentError::file(
            path,
            format!(
                "header {:?} does not match this sweep's {:?}",
                chirpmap_core::error::excerpt(&have.join(","), 0),
                want.join(",")
            ),
        ));
    }
    let np = plan.def.params.len();
    let mut rows = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(|e| ExperimentError::file(path, format!("malformed row: {e}")))?;
        let line = rec.position().map_or(0, |p| p.line());
        let bad = |what: &str| ExperimentError::file(path, format!("line {line}: bad {what}"));
        let f = |i: usize| rec.get(i).unwrap_or("");
        let config: usize = f(0).parse().map_err(|_| bad("config"))?;
        let labels: Vec<String> = (1..=np).map(|i| f(i).to_string()).collect();
        let c = plan.configs.get(config).ok_or_else(|| bad("config index"))?;
        if c.labels != labels {
            return Err(bad("parameter labels for this configuration"));
        }
        let run: u64 = f(np + 1).parse().map_err(|_| bad("run"))?;
        if run >= plan.def.runs {
            return Err(bad("run index"));
        }
        let seed: u64 = f(np + 2).parse().map_err(|_| bad("seed"))?;
        let optf = |i: usize, w: &str| -> Result<Option<f64>, ExperimentError> {
            let s = f(i);
            if s.is_empty() { Ok(None) } else { s.parse().map(Some).map_err(|_| bad(w)) }
        };
        rows.push(RunRow {
            job: Job { config, run },
            labels,
            seed,
            metrics: RunMetrics {
                score_obstacle: optf(np + 3, "score_obstacle")?,
                score_highlight: optf(np + 4, "score_highlight")?,
                n_highlights: f(np + 5).parse().map_err(|_| bad("n_highlights"))?,
                n_echoes: f(np + 6).parse().map_err(|_| bad("n_echoes"))?,
            },
            elapsed_s: f(np + 7).parse().map_err(|_| bad("elapsed_s"))?,
        });
    }
    Ok(rows)
}

/// Writes rows sorted by (configuration, run) to `path` atomically.
pub fn write_sorted(path: &Path, plan: &Plan, rows: &[RunRow]) -> Result<(), ExperimentError> {
    let mut sorted: Vec<&RunRow> = rows.iter().collect();
    sorted.sort_by_key(|r| r.job);
    let mut buf = csv_line(&header(plan));
    for r in sorted {
        buf.extend(csv_line(&row_record(r)));
    }
    let tmp = path.with_extension("csv.tmp");
    std::fs::write(&tmp, buf).map_err(|e| ExperimentError::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| ExperimentError::io(path, e))
}

/// An output directory's runs.csv opened for appending, with the rows it
/// already holds.
#[derive(Debug)]
pub struct RunsFile {
    /// Location of the runs.csv file.
    pub path: PathBuf,
    file: std::fs::File,
    /// Rows already in the file, keyed by job (the runs a resume skips).
    pub done: BTreeMap<Job, RunRow>,
}

/// Name of the sweep definition copied into an output directory.
pub const SWEEP_FILE: &str = "sweep.toml";
/// Name of the file recording which shard (`I/N`) a directory holds.
pub const SHARD_FILE: &str = "shard.txt";
/// Name of the per-run results file.
pub const RUNS_FILE: &str = "runs.csv";

impl RunsFile {
    /// Opens `dir` for `plan`: a fresh directory is initialised; one holding
    /// this same sweep and shard resumes; anything else is an error.
    pub fn open(dir: &Path, plan: &Plan, shard: Shard) -> Result<Self, ExperimentError> {
        std::fs::create_dir_all(dir).map_err(|e| ExperimentError::io(dir, e))?;
        let sweep_path = dir.join(SWEEP_FILE);
        let shard_path = dir.join(SHARD_FILE);
        let path = dir.join(RUNS_FILE);
        let sweep_text = plan.def.to_toml_string();
        let shard_text = format!("{}/{}\n", shard.index, shard.count);
        match std::fs::read_to_string(&sweep_path) {
            Ok(existing) if existing != sweep_text => {
                return Err(ExperimentError::file(
                    &sweep_path,
                    "this directory holds runs of a different sweep (definition, runs or seed differ); \
                     use another --out directory",
                ));
            }
            Ok(_) => {}
            Err(_) if path.exists() => {
                return Err(ExperimentError::file(&path, format!("runs.csv without {SWEEP_FILE}: not ours to extend")));
            }
            Err(_) => std::fs::write(&sweep_path, &sweep_text).map_err(|e| ExperimentError::io(&sweep_path, e))?,
        }
        match std::fs::read_to_string(&shard_path) {
            Ok(existing) if existing != shard_text => {
                return Err(ExperimentError::file(
                    &shard_path,
                    format!("this directory holds shard {}, not {}", existing.trim(), shard_text.trim()),
                ));
            }
            Ok(_) => {}
            Err(_) => std::fs::write(&shard_path, &shard_text).map_err(|e| ExperimentError::io(&shard_path, e))?,
        }
        let mut done = BTreeMap::new();
        if path.exists() {
            let rows = read_rows(&path, plan)?;
            for r in rows {
                if done.insert(r.job, r.clone()).is_some() {
                    return Err(ExperimentError::file(&path, format!("duplicate row for {:?}", r.job)));
                }
            }
            // Drop a partial last line left by a crash before appending.
            let bytes = std::fs::read(&path).map_err(|e| ExperimentError::io(&path, e))?;
            let keep = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
            if keep < bytes.len() {
                let f =
                    std::fs::OpenOptions::new().write(true).open(&path).map_err(|e| ExperimentError::io(&path, e))?;
                f.set_len(keep as u64).map_err(|e| ExperimentError::io(&path, e))?;
            }
        }
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| ExperimentError::io(&path, e))?;
        if file.seek(std::io::SeekFrom::End(0)).map_err(|e| ExperimentError::io(&path, e))? == 0 {
            file.write_all(&csv_line(&header(plan))).map_err(|e| ExperimentError::io(&path, e))?;
        }
        Ok(Self { path, file, done })
    }

    /// Appends one finished run as a whole line and flushes it.
    pub fn append(&mut self, row: RunRow) -> Result<(), ExperimentError> {
        if self.done.contains_key(&row.job) {
            return Ok(());
        }
        let line = csv_line(&row_record(&row));
        self.file.write_all(&line).map_err(|e| ExperimentError::io(&self.path, e))?;
        self.file.flush().map_err(|e| ExperimentError::io(&self.path, e))?;
        self.done.insert(row.job, row);
        Ok(())
    }

    /// Rewrites runs.csv sorted, so finished outputs compare row for row.
    pub fn finish(self, plan: &Plan) -> Result<Vec<RunRow>, ExperimentError> {
        let rows: Vec<RunRow> = self.done.into_values().collect();
        drop(self.file);
        write_sorted(&self.path, plan, &rows)?;
        Ok(rows)
    }
}
