//! `runs.csv`: one row per finished run, streamed as runs finish so an
//! interrupted sweep loses nothing, and read back to resume or merge.

use crate::error::ExperimentError;
use crate::sweep::{Job, Plan, Shard, SweepDef};
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
    /// Surface F1 of the map's surfaces (its highlights as points for the
    /// paper mapper) against the true obstacles (`chirpmap_core::metrics`);
    /// `None` in rows written before the column existed.
    pub surface_f1: Option<f64>,
    /// Symmetric Chamfer distance (m) between the map's surfaces and the
    /// obstacles; `None` when the map has no surface (or in older rows).
    pub chamfer_m: Option<f64>,
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

/// Metric columns after `run,seed`, in order.
const METRIC_COLUMNS: [&str; 7] =
    ["score_obstacle", "score_highlight", "surface_f1", "chamfer_m", "n_highlights", "n_echoes", "elapsed_s"];
/// Columns added since the first runs.csv format; files without them are
/// still read (their values are derived or `None`) and upgraded on resume.
const NEWER_METRIC_COLUMNS: [&str; 2] = ["surface_f1", "chamfer_m"];

/// Names every column a sweep writes (parameters may not reuse them).
pub const RESERVED_COLUMNS: [&str; 10] = [
    "config",
    "run",
    "seed",
    "score_obstacle",
    "score_highlight",
    "surface_f1",
    "chamfer_m",
    "n_highlights",
    "n_echoes",
    "elapsed_s",
];

/// Column names of runs.csv for `plan`: `config`, one column per parameter
/// (its label; labelled numeric parameters also get `<name>_value`, e.g.
/// `spin_rate,spin_rate_value` = `pi/4,0.785…`), then the run, seed, metric
/// and timing columns.
pub fn header(plan: &Plan) -> Vec<String> {
    let mut h = vec!["config".to_string()];
    for p in &plan.def.params {
        h.push(p.name.clone());
        if p.has_value_column() {
            h.push(p.value_column());
        }
    }
    h.extend(["run", "seed"].map(String::from));
    h.extend(METRIC_COLUMNS.map(String::from));
    h
}

/// The header of runs.csv files written before value and surface columns.
fn legacy_header(plan: &Plan) -> Vec<String> {
    let mut h = vec!["config".to_string()];
    h.extend(plan.def.params.iter().map(|p| p.name.clone()));
    h.extend(["run", "seed"].map(String::from));
    h.extend(METRIC_COLUMNS.iter().filter(|c| !NEWER_METRIC_COLUMNS.contains(c)).map(|c| c.to_string()));
    h
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, |x| x.to_string())
}

/// The numeric value of each labelled numeric parameter in configuration `config`.
fn value_fields(plan: &Plan, config: usize) -> Vec<String> {
    let Some(c) = plan.configs.get(config) else { return Vec::new() };
    plan.def
        .params
        .iter()
        .zip(&c.choice)
        .filter(|(p, _)| p.has_value_column())
        .map(|(p, &k)| p.numeric_value(k).map_or_else(String::new, |v| v.to_string()))
        .collect()
}

fn row_record(plan: &Plan, row: &RunRow) -> Vec<String> {
    let mut r = vec![row.job.config.to_string()];
    let mut values = value_fields(plan, row.job.config).into_iter();
    for (p, label) in plan.def.params.iter().zip(&row.labels) {
        r.push(label.clone());
        if p.has_value_column() {
            r.push(values.next().unwrap_or_default());
        }
    }
    r.extend([
        row.job.run.to_string(),
        row.seed.to_string(),
        opt(row.metrics.score_obstacle),
        opt(row.metrics.score_highlight),
        opt(row.metrics.surface_f1),
        opt(row.metrics.chamfer_m),
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

/// Reads rows of a runs.csv written for `plan` (or by an older chirpmap,
/// without the value and surface columns); errors name file and line.
pub fn read_rows(path: &Path, plan: &Plan) -> Result<Vec<RunRow>, ExperimentError> {
    Ok(read_rows_with_format(path, plan)?.0)
}

/// [`read_rows`], also telling whether the file has the current header.
fn read_rows_with_format(path: &Path, plan: &Plan) -> Result<(Vec<RunRow>, bool), ExperimentError> {
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
    let current = have == want;
    if !current && have != legacy_header(plan) {
        return Err(ExperimentError::file(
            path,
            format!(
                "header {:?} does not match this sweep's {:?}",
                chirpmap_core::error::excerpt(&have.join(","), 0),
                want.join(",")
            ),
        ));
    }
    let col = |name: &str| have.iter().position(|h| h == name);
    let np = plan.def.params.len();
    // Parameter label columns: in the current format a value column may follow each.
    let mut label_cols = Vec::with_capacity(np);
    let mut value_cols = Vec::new();
    let mut i = 1;
    for p in &plan.def.params {
        label_cols.push(i);
        i += 1;
        if current && p.has_value_column() {
            value_cols.push(i);
            i += 1;
        }
    }
    let mut rows = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(|e| ExperimentError::file(path, format!("malformed row: {e}")))?;
        let line = rec.position().map_or(0, |p| p.line());
        let bad = |what: &str| ExperimentError::file(path, format!("line {line}: bad {what}"));
        let f = |i: usize| rec.get(i).unwrap_or("");
        let named = |name: &str| col(name).map_or("", f);
        let config: usize = f(0).parse().map_err(|_| bad("config"))?;
        let labels: Vec<String> = label_cols.iter().map(|&i| f(i).to_string()).collect();
        let c = plan.configs.get(config).ok_or_else(|| bad("config index"))?;
        if c.labels != labels {
            return Err(bad("parameter labels for this configuration"));
        }
        let values: Vec<String> = value_cols.iter().map(|&i| f(i).to_string()).collect();
        if current && values != value_fields(plan, config) {
            return Err(bad("parameter values for this configuration"));
        }
        let run: u64 = named("run").parse().map_err(|_| bad("run"))?;
        if run >= plan.def.runs {
            return Err(bad("run index"));
        }
        let seed: u64 = named("seed").parse().map_err(|_| bad("seed"))?;
        // Each value in the range the metric can take (a hand-edited NaN or 7.5
        // would otherwise flow into the summary's means).
        let optf = |w: &str, ok: fn(f64) -> bool| -> Result<Option<f64>, ExperimentError> {
            let s = named(w);
            if s.is_empty() {
                return Ok(None);
            }
            let v: f64 = s.parse().map_err(|_| bad(w))?;
            if ok(v) { Ok(Some(v)) } else { Err(bad(w)) }
        };
        let unit = |v: f64| (0.0..=1.0).contains(&v);
        let length = |v: f64| v.is_finite() && v >= 0.0;
        let elapsed_s: f64 = named("elapsed_s").parse().map_err(|_| bad("elapsed_s"))?;
        if !length(elapsed_s) {
            return Err(bad("elapsed_s"));
        }
        rows.push(RunRow {
            job: Job { config, run },
            labels,
            seed,
            metrics: RunMetrics {
                score_obstacle: optf("score_obstacle", unit)?,
                score_highlight: optf("score_highlight", unit)?,
                surface_f1: optf("surface_f1", unit)?,
                chamfer_m: optf("chamfer_m", length)?,
                n_highlights: named("n_highlights").parse().map_err(|_| bad("n_highlights"))?,
                n_echoes: named("n_echoes").parse().map_err(|_| bad("n_echoes"))?,
            },
            elapsed_s,
        });
    }
    Ok((rows, current))
}

/// Writes rows sorted by (configuration, run) to `path` atomically.
pub fn write_sorted(path: &Path, plan: &Plan, rows: &[RunRow]) -> Result<(), ExperimentError> {
    let mut sorted: Vec<&RunRow> = rows.iter().collect();
    sorted.sort_by_key(|r| r.job);
    let mut buf = csv_line(&header(plan));
    for r in sorted {
        buf.extend(csv_line(&row_record(plan, r)));
    }
    write_atomic(path, &buf)
}

/// An output directory's runs.csv opened for appending, with the rows it
/// already holds.
#[derive(Debug)]
pub struct RunsFile {
    /// Location of the runs.csv file.
    pub path: PathBuf,
    /// The sweep's plan (column layout of the value columns).
    plan: Plan,
    file: std::fs::File,
    /// Rows already in the file, keyed by job (the runs a resume skips).
    pub done: BTreeMap<Job, RunRow>,
    /// Held for as long as this sweep writes into the directory.
    lock: SweepLock,
}

/// A sweep's exclusive hold on its directory, released when dropped: the
/// directory itself is locked (`flock` on its descriptor, so nothing is
/// written into a directory that is then refused); where the file system
/// cannot lock a directory (NFS), a [`SWEEP_LOCK_FILE`] in it.
#[derive(Debug)]
pub struct SweepLock {
    _file: std::fs::File,
}

impl SweepLock {
    /// Takes the lock without waiting; a directory another sweep holds is an error.
    pub fn take(dir: &Path) -> Result<Self, ExperimentError> {
        let busy = |at: &Path| {
            ExperimentError::file(
                at,
                "is locked: another chirpmap sweep is writing into this directory; wait for it to finish \
                 (then rerun to resume) or use another --out",
            )
        };
        if let Ok(file) = std::fs::File::open(dir) {
            match file.try_lock() {
                Ok(()) => return Ok(Self { _file: file }),
                Err(std::fs::TryLockError::WouldBlock) => return Err(busy(dir)),
                Err(std::fs::TryLockError::Error(_)) => {}
            }
        }
        let path = dir.join(SWEEP_LOCK_FILE);
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| ExperimentError::io(&path, e))?;
        match file.try_lock() {
            Ok(()) => Ok(Self { _file: file }),
            Err(std::fs::TryLockError::WouldBlock) => Err(busy(&path)),
            Err(std::fs::TryLockError::Error(e)) => Err(ExperimentError::io(&path, e)),
        }
    }
}

/// Locked by the sweep writing into a directory where the directory itself
/// cannot be locked ([`SweepLock`]): a second sweep started into it (two
/// terminals, a Slurm task resubmitted while the first still runs) is
/// refused, where it used to run every job again beside the first and leave
/// runs.csv with each row twice.
pub const SWEEP_LOCK_FILE: &str = ".chirpmap-sweep-lock";

/// Name of the sweep definition copied into an output directory.
pub const SWEEP_FILE: &str = "sweep.toml";
/// Name of the file recording which shard (`I/N`) a directory holds.
pub const SHARD_FILE: &str = "shard.txt";
/// Name of the per-run results file.
pub const RUNS_FILE: &str = "runs.csv";

/// How an empty or cut-short sweep.toml or shard.txt is described: chirpmap
/// wrote them in place before they were written atomically, and a full disk
/// left them empty, which later runs reported as another sweep or shard.
pub(crate) const CUT_SHORT: &str = "is empty or cut short (a write was interrupted, e.g. by a full disk)";

/// Whether a sweep.toml read back that differs from `expected` looks cut
/// short (empty, a prefix of `expected`, or without its final newline),
/// rather than another sweep's or a file chirpmap did not write.
pub(crate) fn sweep_file_is_cut(text: &str, expected: &str) -> bool {
    expected.starts_with(text) || text.trim().is_empty() || !text.ends_with('\n')
}

/// Why a whole sweep.toml (not [`sweep_file_is_cut`]) is no sweep
/// definition: a file of the user's, or one damaged; `None` for a sweep
/// definition. Such a file is not chirpmap's to delete or overwrite: a
/// user's own sweep.toml in `--out` was reported as cut short, with the
/// advice to delete it.
pub(crate) fn foreign_sweep_file(text: &str) -> Option<String> {
    SweepDef::from_toml_str(text).err().map(|e| {
        let e = e.to_string();
        let first = e.lines().find(|l| !l.trim().is_empty()).unwrap_or("").trim().to_string();
        format!("is no sweep definition chirpmap wrote ({first}): not ours to overwrite; use another --out directory")
    })
}

/// Writes `path` whole or not at all (a new hidden file beside it, then a
/// rename): a full disk must not leave an empty sweep.toml or shard.txt,
/// which every later run took for another sweep's.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ExperimentError> {
    let (tmp, mut file) = new_sibling(path)?;
    if let Err(e) = file.write_all(bytes) {
        drop(file);
        let _ = std::fs::remove_file(&tmp);
        return Err(ExperimentError::io(&tmp, e));
    }
    drop(file);
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        ExperimentError::io(path, e)
    })
}

/// A new, empty hidden file in `path`'s directory, for writing `path` by a
/// rename: created with `create_new` under a name no file there has, so
/// that no file of the user's is written over. Fixed names
/// (`runs.csv.tmp`, `.sweep.toml.tmp`) were: a user's file of that name
/// was overwritten and then renamed onto runs.csv or sweep.toml.
pub fn new_sibling(path: &Path) -> Result<(PathBuf, std::fs::File), ExperimentError> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let mut serial = 0u32;
    loop {
        let tmp = path.with_file_name(format!(".chirpmap-tmp-{}-{serial}-{name}", std::process::id()));
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(file) => return Ok((tmp, file)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && serial < 1000 => serial += 1,
            Err(e) => return Err(ExperimentError::io(&tmp, e)),
        }
    }
}

/// Whether a shard.txt read back is not the `I/N` line chirpmap writes.
pub(crate) fn shard_file_is_cut(text: &str) -> bool {
    let parsed = text.strip_suffix('\n').and_then(|l| l.split_once('/'));
    !parsed.is_some_and(|(i, n)| i.parse::<usize>().is_ok() && n.parse::<usize>().is_ok())
}

impl RunsFile {
    /// Opens `dir` for `plan`: a fresh directory is initialised; one holding
    /// this same sweep and shard resumes; anything else is an error.
    pub fn open(dir: &Path, plan: &Plan, shard: Shard) -> Result<Self, ExperimentError> {
        if dir.exists() && !dir.is_dir() {
            return Err(ExperimentError::file(dir, "is a file; --out must be a directory (new or a sweep's own)"));
        }
        std::fs::create_dir_all(dir).map_err(|e| ExperimentError::io(dir, e))?;
        // Before anything is read or written: two sweeps started together
        // into a new directory must not both take it for theirs.
        let lock = SweepLock::take(dir)?;
        let sweep_path = dir.join(SWEEP_FILE);
        let shard_path = dir.join(SHARD_FILE);
        let path = dir.join(RUNS_FILE);
        let sweep_text = plan.def.to_toml_string();
        let shard_text = format!("{}/{}\n", shard.index, shard.count);
        let read = std::fs::read_to_string(&sweep_path);
        // Why a whole sweep.toml other than this sweep's is no sweep definition (parsed once).
        let foreign = read.as_ref().ok().filter(|t| **t != sweep_text).and_then(|t| foreign_sweep_file(t));
        match read {
            Ok(existing) if existing != sweep_text && sweep_file_is_cut(&existing, &sweep_text) => {
                let what = if path.exists() {
                    format!(
                        "{RUNS_FILE} here cannot be resumed without it: copy {SWEEP_FILE} from another directory \
                         of the same sweep (a shard) or use another --out directory"
                    )
                } else {
                    format!("no run is recorded here: delete it (and {SHARD_FILE}) and rerun")
                };
                return Err(ExperimentError::file(
                    &sweep_path,
                    format!("{CUT_SHORT}, not a whole sweep definition; {what}"),
                ));
            }
            Ok(_) if foreign.is_some() => {
                return Err(ExperimentError::file(&sweep_path, foreign.unwrap_or_default()));
            }
            Ok(existing) if existing != sweep_text => {
                return Err(ExperimentError::file(
                    &sweep_path,
                    "this directory holds runs of a different sweep (definition, runs or seed differ); \
                     use another --out directory",
                ));
            }
            Ok(_) => {}
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(ExperimentError::io(&sweep_path, e)),
            Err(_) if path.exists() => {
                return Err(ExperimentError::file(&path, format!("runs.csv without {SWEEP_FILE}: not ours to extend")));
            }
            Err(_) => {
                // A new sweep directory: nothing it writes may be there already
                // (a user's summary.md would be overwritten at the end).
                for name in [SHARD_FILE, "summary.csv", "summary.md", "summary.png"] {
                    let p = dir.join(name);
                    if p.exists() {
                        return Err(ExperimentError::file(
                            &p,
                            format!(
                                "exists but this directory holds no {SWEEP_FILE}: not ours to overwrite; use another --out directory"
                            ),
                        ));
                    }
                }
                write_atomic(&sweep_path, sweep_text.as_bytes())?;
            }
        }
        match std::fs::read_to_string(&shard_path) {
            Ok(existing) if shard_file_is_cut(&existing) => {
                return Err(ExperimentError::file(
                    &shard_path,
                    format!(
                        "{CUT_SHORT}, not a shard `I/N`; if this directory holds shard {} of this sweep, \
                         write that line into it and rerun, else use another --out directory",
                        shard_text.trim()
                    ),
                ));
            }
            Ok(existing) if existing != shard_text => {
                return Err(ExperimentError::file(
                    &shard_path,
                    format!("this directory holds shard {}, not {}", existing.trim(), shard_text.trim()),
                ));
            }
            Ok(_) => {}
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(ExperimentError::io(&shard_path, e)),
            Err(_) => write_atomic(&shard_path, shard_text.as_bytes())?,
        }
        let mut done: BTreeMap<Job, RunRow> = BTreeMap::new();
        if path.exists() {
            let (rows, current) = read_rows_with_format(&path, plan)?;
            if !current {
                // An older format: rewrite it (atomically, it is this sweep's own
                // file) in the current one before appending rows to it.
                write_sorted(&path, plan, &rows)?;
            }
            let mut twice = false;
            for r in rows {
                // The same run twice with the same results (two sweeps that
                // once ran into one directory at the same time) is kept
                // once, as `merge` keeps it; different results are refused.
                match done.get(&r.job) {
                    Some(prev) if prev.metrics != r.metrics => {
                        return Err(ExperimentError::file(
                            &path,
                            format!("run ({}) appears twice with different results", r.job),
                        ));
                    }
                    Some(_) => twice = true,
                    None => {
                        done.insert(r.job, r);
                    }
                }
            }
            if twice {
                let once: Vec<RunRow> = done.values().cloned().collect();
                write_sorted(&path, plan, &once)?;
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
        Ok(Self { path, plan: plan.clone(), file, done, lock })
    }

    /// Appends one finished run as a whole line and flushes it.
    pub fn append(&mut self, row: RunRow) -> Result<(), ExperimentError> {
        if self.done.contains_key(&row.job) {
            return Ok(());
        }
        let line = csv_line(&row_record(&self.plan, &row));
        self.file.write_all(&line).map_err(|e| ExperimentError::io(&self.path, e))?;
        self.file.flush().map_err(|e| ExperimentError::io(&self.path, e))?;
        self.done.insert(row.job, row);
        Ok(())
    }

    /// Rewrites runs.csv sorted, so finished outputs compare row for row.
    /// Also returns the directory's lock, for the caller to hold while it
    /// writes the summaries.
    pub fn finish(self, plan: &Plan) -> Result<(Vec<RunRow>, SweepLock), ExperimentError> {
        let rows: Vec<RunRow> = self.done.into_values().collect();
        drop(self.file);
        write_sorted(&self.path, plan, &rows)?;
        Ok((rows, self.lock))
    }
}
