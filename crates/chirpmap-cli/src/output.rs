//! Safe outputs: every command writes through here, so that
//!
//! - no file chirpmap did not create is ever written over or deleted, and
//!   never one of the command's own inputs (compared by file identity, not
//!   by the path as typed), checked before any work;
//! - outputs appear together or not at all: they are written into a hidden
//!   staging folder beside their destination and moved into place (renames
//!   within one directory) only when every one of them was written;
//! - the debris of a killed run (a staging folder whose owner is gone) is
//!   removed by the next run in that place.
//!
//! Ownership is recorded in a manifest beside the outputs: each line holds a
//! file name and the identity (device, inode, size, modification time) the
//! file had when chirpmap wrote it. A file the user created or changed since
//! does not match, so it is left alone.

use anyhow::{Context, Result, bail};
use std::fs::{File, Metadata};
use std::path::{Path, PathBuf};

/// Output directories (`--out DIR`): the files the last run wrote there.
const DIR_MANIFEST: &str = ".chirpmap-outputs";
/// Single-file outputs (`synth --out X.wav`): every file chirpmap wrote in
/// that directory, kept across runs.
const FILE_MANIFEST: &str = ".chirpmap-files";
/// Prefix of staging folders; the owner's process id follows.
const STAGING_PREFIX: &str = ".chirpmap-partial-";
/// Held (locked) by the owner of a staging folder for as long as it runs.
const LOCK_FILE: &str = "lock";

/// What identifies a file's contents as the ones chirpmap wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Identity(String);

impl Identity {
    fn of(meta: &Metadata) -> Self {
        let mtime_ns =
            meta.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_nanos());
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt as _;
            Self(format!("{}:{}:{}:{mtime_ns}", meta.dev(), meta.ino(), meta.len()))
        }
        #[cfg(not(unix))]
        {
            Self(format!("{}:{mtime_ns}", meta.len()))
        }
    }
}

/// Whether two paths name the same file (same device and inode on Unix;
/// same canonical path elsewhere).
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt as _;
        if let (Ok(ma), Ok(mb)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return ma.dev() == mb.dev() && ma.ino() == mb.ino();
        }
    }
    matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// A manifest: file name → identity when written (`None`: an older
/// chirpmap's name-only line, trusted as ours).
#[derive(Debug, Default)]
struct Manifest {
    entries: Vec<(String, Option<Identity>)>,
}

impl Manifest {
    fn read(path: &Path) -> Self {
        let Ok(text) = std::fs::read_to_string(path) else {
            return Self::default();
        };
        let entries = text
            .lines()
            .filter(|l| !l.is_empty())
            .filter_map(|l| {
                let (name, id) = match l.split_once('\t') {
                    Some((n, id)) => (n, Some(Identity(id.to_string()))),
                    None => (l, None),
                };
                // Only plain names in this directory, never paths.
                (!name.contains('/') && !name.contains('\\') && name != "." && name != "..")
                    .then(|| (name.to_string(), id))
            })
            .collect();
        Self { entries }
    }

    fn get(&self, name: &str) -> Option<&Option<Identity>> {
        self.entries.iter().find(|(n, _)| n == name).map(|(_, id)| id)
    }

    /// Whether `dir/name` is a file chirpmap wrote and nobody changed since.
    fn owns(&self, dir: &Path, name: &str) -> bool {
        match (self.get(name), std::fs::symlink_metadata(dir.join(name))) {
            (Some(None), Ok(m)) => m.is_file(),
            (Some(Some(id)), Ok(m)) => m.is_file() && Identity::of(&m) == *id,
            _ => false,
        }
    }

    fn set(&mut self, name: &str, id: Identity) {
        match self.entries.iter_mut().find(|(n, _)| n == name) {
            Some(e) => e.1 = Some(id),
            None => self.entries.push((name.to_string(), Some(id))),
        }
    }

    fn text(&self) -> String {
        self.entries
            .iter()
            .map(|(n, id)| match id {
                Some(Identity(i)) => format!("{n}\t{i}\n"),
                None => format!("{n}\n"),
            })
            .collect()
    }
}

/// Removes staging folders (and older chirpmap's `NAME.partial-PID` files)
/// whose owner is no longer running.
fn clean_debris(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        if let Some(pid) = name.strip_prefix(STAGING_PREFIX) {
            if pid.parse::<u32>().is_err() {
                continue;
            }
            let abandoned = match File::open(path.join(LOCK_FILE)) {
                // The owner holds the lock while it runs; the lock dies with it.
                Ok(f) => f.try_lock().is_ok(),
                Err(_) => !process_alive(pid),
            };
            if abandoned {
                std::fs::remove_dir_all(&path).ok();
            }
        } else if let Some((_, pid)) = name.rsplit_once(".partial-")
            && pid.parse::<u32>().is_ok()
            && !process_alive(pid)
            && path.is_file()
        {
            std::fs::remove_file(&path).ok();
        }
    }
}

/// Whether a process id is running (Linux: /proc; elsewhere assume it is,
/// so nothing is removed that might be in use).
fn process_alive(pid: &str) -> bool {
    if cfg!(target_os = "linux") { Path::new("/proc").join(pid).exists() } else { true }
}

/// Where outputs go: a directory that is the run's (stale outputs of the
/// previous run there are dropped), or single files in a shared directory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Dir,
    Files,
}

/// A set of outputs being written, moved into place by [`Staged::commit`].
#[derive(Debug)]
pub struct Staged {
    dir: PathBuf,
    mode: Mode,
    staging: PathBuf,
    /// Held locked while this run is alive (see [`clean_debris`]).
    _lock: File,
    /// Declared outputs: (name in `dir`, written yet).
    outputs: Vec<(String, bool)>,
    inputs: Vec<PathBuf>,
    committed: bool,
    /// Whether `dir` did not exist before, so a failure may remove it.
    created_dir: bool,
}

impl Staged {
    /// An output directory that will hold `outputs` (names). Refuses, before
    /// any work, an `outputs` entry that would replace one of `inputs` or a
    /// file chirpmap did not write.
    pub fn dir(dir: &Path, outputs: &[&str], inputs: &[&Path]) -> Result<Self> {
        Self::new(dir, Mode::Dir, outputs, inputs)
    }

    fn new(dir: &Path, mode: Mode, outputs: &[&str], inputs: &[&Path]) -> Result<Self> {
        if dir.exists() && !dir.is_dir() {
            bail!("output {} exists and is not a directory", dir.display());
        }
        let created_dir = !dir.exists();
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create output directory {}", dir.display()))?;
        clean_debris(dir);
        let manifest = Manifest::read(&dir.join(manifest_name(mode)));
        let refuse = |e: anyhow::Error| {
            if created_dir {
                std::fs::remove_dir(dir).ok();
            }
            Err(e)
        };
        for name in outputs {
            let target = dir.join(name);
            if let Some(input) = inputs.iter().find(|i| same_file(i, &target)) {
                return refuse(anyhow::anyhow!(
                    "output {} would replace the input {}; choose another output",
                    target.display(),
                    input.display()
                ));
            }
            if std::fs::symlink_metadata(&target).is_ok() && !manifest.owns(dir, name) {
                return refuse(anyhow::anyhow!(
                    "{} exists and was not written by chirpmap (or was changed since); refusing to overwrite it: \
                     move it away or choose another output",
                    target.display()
                ));
            }
        }
        let staging = dir.join(format!("{STAGING_PREFIX}{}", std::process::id()));
        if let Err(e) = std::fs::create_dir_all(&staging) {
            return refuse(anyhow::Error::new(e).context(format!("cannot write into {}", dir.display())));
        }
        let lock = File::create(staging.join(LOCK_FILE))
            .and_then(|f| f.lock().map(|()| f))
            .with_context(|| format!("cannot create {}", staging.display()));
        let lock = match lock {
            Ok(l) => l,
            Err(e) => {
                std::fs::remove_dir_all(&staging).ok();
                return refuse(e);
            }
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            mode,
            staging,
            _lock: lock,
            outputs: outputs.iter().map(|n| (n.to_string(), false)).collect(),
            inputs: inputs.iter().map(|p| p.to_path_buf()).collect(),
            committed: false,
            created_dir,
        })
    }

    /// Path at which to write the declared output `name`; it lands in the
    /// output directory on [`Staged::commit`].
    pub fn path(&mut self, name: &str) -> Result<PathBuf> {
        match self.outputs.iter_mut().find(|(n, _)| n == name) {
            Some(o) => o.1 = true,
            None => bail!("internal: output {name} was not declared"),
        }
        Ok(self.staging.join(name))
    }

    /// Writes the declared output `name`.
    pub fn write(&mut self, name: &str, contents: impl AsRef<[u8]>) -> Result<()> {
        let p = self.path(name)?;
        std::fs::write(&p, contents).with_context(|| format!("cannot write {}", self.dir.join(name).display()))
    }

    /// Moves every written output into place, then records them in the
    /// manifest. In an output directory, files the previous run listed but
    /// this one did not write (say `spectra.csv` of an earlier `--spectra`)
    /// are removed, unless they are inputs of this run or were changed.
    pub fn commit(mut self) -> Result<PathBuf> {
        let manifest_path = self.dir.join(manifest_name(self.mode));
        let old = Manifest::read(&manifest_path);
        let written: Vec<String> = self.outputs.iter().filter(|o| o.1).map(|o| o.0.clone()).collect();
        // The new manifest is complete before anything moves: identities
        // survive a rename within the directory.
        let mut new = match self.mode {
            Mode::Files => old,
            Mode::Dir => {
                let mut kept = Manifest::default();
                for (name, id) in &old.entries {
                    let p = self.dir.join(name);
                    if !written.contains(name) && self.inputs.iter().any(|i| same_file(i, &p)) {
                        kept.entries.push((name.clone(), id.clone()));
                    }
                }
                kept
            }
        };
        for name in &written {
            let p = self.staging.join(name);
            let meta = std::fs::metadata(&p).with_context(|| format!("cannot read back {}", p.display()))?;
            new.set(name, Identity::of(&meta));
        }
        let staged_manifest = self.staging.join(manifest_name(self.mode));
        std::fs::write(&staged_manifest, new.text())
            .with_context(|| format!("cannot write {}", manifest_path.display()))?;
        let stale: Vec<String> = match self.mode {
            Mode::Files => Vec::new(),
            Mode::Dir => {
                let old = Manifest::read(&manifest_path);
                old.entries
                    .iter()
                    .map(|(n, _)| n.clone())
                    .filter(|n| !written.contains(n) && new.get(n).is_none() && old.owns(&self.dir, n))
                    .collect()
            }
        };
        for name in &written {
            let (from, to) = (self.staging.join(name), self.dir.join(name));
            std::fs::rename(&from, &to).with_context(|| format!("cannot move {} into place", to.display()))?;
        }
        std::fs::rename(&staged_manifest, &manifest_path)
            .with_context(|| format!("cannot move {} into place", manifest_path.display()))?;
        for name in stale {
            std::fs::remove_file(self.dir.join(name)).ok();
        }
        std::fs::remove_dir_all(&self.staging).ok();
        self.committed = true;
        Ok(self.dir.clone())
    }
}

/// Single output files (e.g. `synth --out X.wav --poses P.csv`), checked
/// as [`Staged::dir`] checks its outputs; in their directories, other files
/// chirpmap wrote are kept.
#[derive(Debug)]
pub struct StagedFiles {
    groups: Vec<Staged>,
    /// Each output path as given: its group and its name there.
    paths: Vec<(PathBuf, usize, String)>,
}

impl StagedFiles {
    /// Declares the output files; refuses an output that is one of `inputs`,
    /// a directory, given twice, or a file chirpmap did not write.
    pub fn new(paths: &[&Path], inputs: &[&Path]) -> Result<Self> {
        let mut dirs: Vec<(PathBuf, Vec<String>)> = Vec::new();
        let mut index = Vec::new();
        for p in paths {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .with_context(|| format!("{} is not a file path", p.display()))?;
            if p.is_dir() {
                bail!("{} is a directory; give a file path", p.display());
            }
            let parent = p.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf();
            let k = match dirs.iter().position(|(d, _)| same_dir(d, &parent)) {
                Some(k) => k,
                None => {
                    dirs.push((parent, Vec::new()));
                    dirs.len() - 1
                }
            };
            if dirs[k].1.contains(&name) {
                bail!("{} is given twice as an output", p.display());
            }
            dirs[k].1.push(name.clone());
            index.push((p.to_path_buf(), k, name));
        }
        let groups = dirs
            .iter()
            .map(|(d, names)| {
                let names: Vec<&str> = names.iter().map(String::as_str).collect();
                Staged::new(d, Mode::Files, &names, inputs)
            })
            .collect::<Result<_>>()?;
        Ok(Self { groups, paths: index })
    }

    /// Where to write the output given as `path`.
    pub fn path(&mut self, path: &Path) -> Result<PathBuf> {
        let (_, k, name) = self
            .paths
            .iter()
            .find(|(p, _, _)| p == path)
            .with_context(|| format!("internal: {} undeclared", path.display()))?;
        let (k, name) = (*k, name.clone());
        self.groups[k].path(&name)
    }

    /// Moves every output into place.
    pub fn commit(self) -> Result<()> {
        for g in self.groups {
            g.commit()?;
        }
        Ok(())
    }
}

fn manifest_name(mode: Mode) -> &'static str {
    match mode {
        Mode::Dir => DIR_MANIFEST,
        Mode::Files => FILE_MANIFEST,
    }
}

fn same_dir(a: &Path, b: &Path) -> bool {
    a == b || same_file(a, b)
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.committed {
            std::fs::remove_dir_all(&self.staging).ok();
            // Leave no empty directory behind that we created.
            if self.created_dir {
                std::fs::remove_dir(&self.dir).ok();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .expect("dir")
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn refuses_to_overwrite_a_users_file_and_an_input() {
        let t = tempfile::tempdir().expect("tmp");
        std::fs::write(t.path().join("summary.json"), "mine").expect("write");
        let err = Staged::dir(t.path(), &["summary.json"], &[]).expect_err("user's file");
        assert!(err.to_string().contains("not written by chirpmap"), "{err}");
        let input = t.path().join("summary.json");
        let err = Staged::dir(t.path(), &["summary.json"], &[&input]).expect_err("input");
        assert!(err.to_string().contains("would replace the input"), "{err}");
        assert_eq!(std::fs::read_to_string(&input).expect("read"), "mine");
        assert_eq!(names(t.path()), vec!["summary.json"]);
    }

    #[test]
    fn rerun_replaces_own_outputs_drops_stale_ones_but_keeps_inputs() {
        let t = tempfile::tempdir().expect("tmp");
        let mut s = Staged::dir(t.path(), &["a.csv", "b.csv", "c.csv"], &[]).expect("new");
        for n in ["a.csv", "b.csv", "c.csv"] {
            s.write(n, "1").expect("write");
        }
        s.commit().expect("commit");
        let input = t.path().join("b.csv");
        let mut s = Staged::dir(t.path(), &["a.csv"], &[&input]).expect("rerun");
        s.write("a.csv", "2").expect("write");
        s.commit().expect("commit");
        // c.csv was the last run's and is stale; b.csv is this run's input.
        assert_eq!(names(t.path()), vec![".chirpmap-outputs", "a.csv", "b.csv"]);
        assert_eq!(std::fs::read_to_string(t.path().join("a.csv")).expect("read"), "2");
    }

    #[test]
    fn a_changed_output_is_no_longer_ours() {
        let t = tempfile::tempdir().expect("tmp");
        let mut s = Staged::dir(t.path(), &["a.csv", "b.csv"], &[]).expect("new");
        s.write("a.csv", "1").expect("write");
        s.write("b.csv", "1").expect("write");
        s.commit().expect("commit");
        std::fs::write(t.path().join("b.csv"), "edited by the user").expect("edit");
        let mut s = Staged::dir(t.path(), &["a.csv"], &[]).expect("rerun");
        s.write("a.csv", "2").expect("write");
        s.commit().expect("commit");
        assert_eq!(std::fs::read_to_string(t.path().join("b.csv")).expect("kept"), "edited by the user");
        assert!(Staged::dir(t.path(), &["b.csv"], &[]).is_err());
    }

    #[test]
    fn failure_leaves_nothing_and_debris_of_dead_runs_is_removed() {
        let t = tempfile::tempdir().expect("tmp");
        let out = t.path().join("new");
        {
            let mut s = Staged::dir(&out, &["a.csv"], &[]).expect("new");
            s.write("a.csv", "1").expect("write");
        }
        assert!(!out.exists());
        // Debris of a killed run: a staging folder with an unlocked lock file,
        // and an older chirpmap's partial file of a process that is gone.
        let dead = t.path().join(format!("{STAGING_PREFIX}4000000000"));
        std::fs::create_dir_all(&dead).expect("mkdir");
        std::fs::write(dead.join(LOCK_FILE), "").expect("lock");
        std::fs::write(t.path().join("x.wav.partial-4000000000"), "").expect("partial");
        let s = StagedFiles::new(&[&t.path().join("x.wav")], &[]).expect("files");
        drop(s);
        assert_eq!(names(t.path()), Vec::<String>::new());
    }

    #[test]
    fn single_files_keep_each_others_records() {
        let t = tempfile::tempdir().expect("tmp");
        for name in ["a.wav", "b.wav"] {
            let p = t.path().join(name);
            let mut s = StagedFiles::new(&[&p], &[]).expect("files");
            std::fs::write(s.path(&p).expect("declared"), "x").expect("write");
            s.commit().expect("commit");
        }
        assert_eq!(names(t.path()), vec![".chirpmap-files", "a.wav", "b.wav"]);
        // Both are ours: either may be rewritten.
        assert!(StagedFiles::new(&[&t.path().join("a.wav")], &[]).is_ok());
        let same = t.path().join("a.wav");
        assert!(StagedFiles::new(&[&same, &same], &[]).is_err());
        let scene = t.path().join("s.toml");
        std::fs::write(&scene, "").expect("scene");
        let dotted = t.path().join(".").join("s.toml");
        let err = StagedFiles::new(&[&dotted], &[&scene]).expect_err("input");
        assert!(err.to_string().contains("would replace the input"), "{err}");
    }
}
