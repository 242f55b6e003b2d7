//! Safe outputs: every command writes through here, so that
//!
//! - no file chirpmap did not create is ever written over or deleted, and
//!   never one of the command's own inputs (compared by file identity, not
//!   by the path as typed), checked before any work;
//! - outputs appear together or not at all: they are written into a hidden
//!   staging folder beside their destination and moved into place (renames
//!   within one directory) only when every one of them was written;
//! - the debris of a killed run (a staging folder whose owner is gone) is
//!   removed by the next run in that place; nothing else is ever removed;
//! - runs writing into one place at the same time (`make -j`, two terminals,
//!   a resubmitted job) see each other's changes whole: reading and changing
//!   what a directory holds (debris, manifest, the outputs' names) is done
//!   under an exclusive lock on the directory ([`DirLock`]), taken only for
//!   those moments, never for the work itself.
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
/// The manifests a commit writes in its staging folder before moving them
/// into place: named with [`STAGING_PREFIX`], which no output may have, so
/// no staged output shares their names (an output named `manifest` was
/// written over with the manifest).
const STAGED_MANIFEST: &str = ".chirpmap-partial-manifest";
const STAGED_MANIFEST_DURING_COMMIT: &str = ".chirpmap-partial-manifest-during-commit";
/// Locked while a run looks at or changes what an output directory holds.
const DIR_LOCK: &str = ".chirpmap-lock";

/// An exclusive lock on an output directory (see the module's doc); released
/// when dropped. The directory itself is locked (`flock` on its descriptor,
/// so nothing is added to it); where a file system cannot lock a directory
/// (NFS emulates `flock` with POSIX locks, which need a file open for
/// writing), a [`DIR_LOCK`] file in it is locked instead.
#[derive(Debug)]
struct DirLock {
    _file: File,
}

impl DirLock {
    fn take(dir: &Path) -> Result<Self> {
        if let Ok(file) = File::open(dir)
            && file.lock().is_ok()
        {
            return Ok(Self { _file: file });
        }
        let path = dir.join(DIR_LOCK);
        // Read-only when another user's lock file is there (a shared /tmp):
        // `flock` needs no write access.
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .or_else(|_| File::open(&path))
            .with_context(|| format!("cannot open the lock {}", path.display()))?;
        file.lock().with_context(|| format!("cannot lock {}", path.display()))?;
        Ok(Self { _file: file })
    }
}

/// This process's staging folders not yet committed or dropped, each with
/// its output directory when this run created it: what [`abandon_all`]
/// removes when the process is interrupted. A commit holds the lock while it
/// moves files, so an interruption waits for it rather than cutting it.
static LIVE: std::sync::Mutex<Vec<Live>> = std::sync::Mutex::new(Vec::new());

/// A staging folder, and the output directory with the outermost directory
/// created on the way to it, when this run created them.
type Live = (PathBuf, Option<(PathBuf, PathBuf)>);

fn live() -> std::sync::MutexGuard<'static, Vec<Live>> {
    LIVE.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Removes every staging folder of this process (and an output directory it
/// created, if nothing else is in it), for an interrupted run (Ctrl-C,
/// SIGTERM) that is about to exit without unwinding. Returns with the
/// registry locked, so no commit can start before the process exits.
pub fn abandon_all() -> impl Sized {
    let mut live = live();
    for (staging, created) in live.drain(..) {
        remove_staging(&staging);
        if let Some((dir, top)) = created {
            remove_created(&dir, &top);
        }
    }
    live
}

/// Removes the output directory a run created if it is empty (another run
/// may have written there since), then the empty directories it created on
/// the way, up to `top`. A [`DIR_LOCK`] file (file systems that cannot lock a
/// directory) is never unlinked: a run waiting on it would then hold a lock
/// on a file another run no longer sees; the directory stays with it.
fn remove_created(dir: &Path, top: &Path) {
    for d in dir.ancestors() {
        // `remove_dir` removes only empty directories.
        if std::fs::remove_dir(d).is_err() || d == top {
            break;
        }
    }
}

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

/// One line of a manifest.
#[derive(Debug, Clone)]
struct Entry {
    /// File name in the directory.
    name: String,
    /// Identity when written (`None`: an older chirpmap's name-only line,
    /// trusted as ours).
    id: Option<Identity>,
    /// The command that wrote it (`None`: an older chirpmap's line).
    by: Option<String>,
}

/// A manifest: what chirpmap wrote in a directory, line by line
/// `name<TAB>identity<TAB>command`.
#[derive(Debug, Default, Clone)]
struct Manifest {
    entries: Vec<Entry>,
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
                let mut parts = l.splitn(3, '\t');
                let name = parts.next()?;
                let id = parts.next().map(|id| Identity(id.to_string()));
                let by = parts.next().map(str::to_string);
                // Only plain names in this directory, never paths.
                (!name.contains('/') && !name.contains('\\') && name != "." && name != "..").then(|| Entry {
                    name: name.to_string(),
                    id,
                    by,
                })
            })
            .collect();
        Self { entries }
    }

    fn get(&self, name: &str) -> Option<&Entry> {
        self.entries.iter().find(|e| e.name == name)
    }

    /// Whether `dir/name` is a file chirpmap wrote and nobody changed since.
    /// A name may be listed with several identities: the manifest written
    /// before a commit's renames lists both the old and the new file.
    fn owns(&self, dir: &Path, name: &str) -> bool {
        let Ok(m) = std::fs::symlink_metadata(dir.join(name)) else { return false };
        m.is_file()
            && self
                .entries
                .iter()
                .filter(|e| e.name == name)
                .any(|e| e.id.as_ref().is_none_or(|id| *id == Identity::of(&m)))
    }

    /// Lists `name` with `id`, written by `by`, only.
    fn set(&mut self, name: &str, id: Identity, by: &str) {
        self.entries.retain(|e| e.name != name);
        self.entries.push(Entry { name: name.to_string(), id: Some(id), by: Some(by.to_string()) });
    }

    fn text(&self) -> String {
        self.entries
            .iter()
            .map(|e| match (&e.id, &e.by) {
                (Some(Identity(i)), Some(by)) => format!("{}\t{i}\t{by}\n", e.name),
                (Some(Identity(i)), None) => format!("{}\t{i}\n", e.name),
                (None, _) => format!("{}\n", e.name),
            })
            .collect()
    }
}

/// Removes the staging folders of runs that are gone: a folder named
/// [`STAGING_PREFIX`]`PID` whose lock file nobody holds. Called with the
/// directory locked ([`DirLock`]); a run creates its staging folder and
/// locks its lock file under that same lock, so a folder is never seen
/// between the two. Nothing else is removed: a folder of that name without a
/// lock file, or a user's `NAME.partial-123` (older chirpmaps staged files
/// under such names, and removed any whose process id was not running, which
/// could be a user's file or a run on another host), is left alone.
fn clean_debris(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(id) = name.strip_prefix(STAGING_PREFIX) else { continue };
        // `PID-N` (`PID` of older chirpmaps).
        let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
        if !id.split_once('-').map_or(digits(id), |(a, b)| digits(a) && digits(b)) {
            continue;
        }
        let path = entry.path();
        let abandoned = File::open(path.join(LOCK_FILE)).is_ok_and(|f| f.try_lock().is_ok());
        if abandoned {
            remove_staging(&path);
        }
    }
}

/// Moves the staged file `from` to `to`, as `rename` does. Where `to` is a
/// regular file, on Linux, the two are exchanged instead (`renameat2` with
/// `RENAME_EXCHANGE`, as atomic as a rename), which leaves the replaced file
/// at `from`, in the staging folder, removed with it.
///
/// Why: a rename onto an existing file makes ext4 write the new file's
/// data out before it returns (its `auto_da_alloc` guard for programs that
/// do not `fsync`): 3 ms for the default run's 4 MB map.npy, 5 ms of a
/// `simulate` run into its own folder again, a tenth of the run (issue 14).
/// An exchange is not a replacement, so nothing is written out (chirpmap
/// does not `fsync`: after a power cut soon after a run, its outputs may be
/// empty, as any program's that does not). Where the file system cannot
/// exchange (NFS, kernels before 3.15), a plain rename.
///
/// What the exchange moved out must be a regular file: a directory put in
/// `to`'s place after it was looked at is exchanged back and refused, as a
/// rename onto it fails (a review made the gap wide enough to hit).
fn move_into_place(from: &Path, to: &Path) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    if std::fs::symlink_metadata(to).is_ok_and(|m| m.file_type().is_file()) {
        use rustix::fs::{CWD, RenameFlags, renameat_with};
        if renameat_with(CWD, from, CWD, to, RenameFlags::EXCHANGE).is_ok() {
            if std::fs::symlink_metadata(from).is_ok_and(|m| m.file_type().is_file()) {
                return Ok(());
            }
            renameat_with(CWD, from, CWD, to, RenameFlags::EXCHANGE)?;
            return Err(std::io::Error::other(format!(
                "{} changed while chirpmap moved its output into place (it is no longer a file); nothing was replaced",
                to.display()
            )));
        }
    }
    std::fs::rename(from, to)
}

/// Removes a staging folder: its outputs first, its lock file last, so a
/// removal cut short (a kill, a file appearing meanwhile) leaves a folder
/// that still reads as debris, never one without its lock.
/// Only files are removed: chirpmap puts nothing else there, and a
/// directory found there is someone's (left, with the folder around it).
fn remove_staging(staging: &Path) {
    if let Ok(entries) = std::fs::read_dir(staging) {
        for e in entries.flatten() {
            let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
            if e.file_name() != LOCK_FILE && !is_dir {
                std::fs::remove_file(e.path()).ok();
            }
        }
    }
    std::fs::remove_file(staging.join(LOCK_FILE)).ok();
    std::fs::remove_dir(staging).ok();
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
    /// The command writing (`simulate`, …), recorded in the manifest.
    command: &'static str,
    /// When `dir` did not exist before: the outermost directory this run
    /// created on the way to it (`a` of a new `a/b/c`, `dir` itself when only
    /// it was new), so a failure may remove them when empty.
    created_top: Option<PathBuf>,
}

impl Staged {
    /// An output directory that will hold `outputs` (names). Refuses, before
    /// any work, an `outputs` entry that would replace one of `inputs` or a
    /// file chirpmap did not write.
    pub fn dir(dir: &Path, command: &'static str, outputs: &[&str], inputs: &[&Path]) -> Result<Self> {
        Self::new(dir, Mode::Dir, command, outputs, inputs)
    }

    fn new(dir: &Path, mode: Mode, command: &'static str, outputs: &[&str], inputs: &[&Path]) -> Result<Self> {
        if dir.exists() && !dir.is_dir() {
            bail!("output {} exists and is not a directory", dir.display());
        }
        if std::fs::symlink_metadata(dir).is_ok_and(|m| m.is_symlink()) && !dir.exists() {
            bail!(
                "output {} is a symbolic link to nothing (dangling); remove it or choose another output",
                dir.display()
            );
        }
        let created_top =
            dir.ancestors().take_while(|a| !a.as_os_str().is_empty() && !a.exists()).last().map(Path::to_path_buf);
        // Unique within the process too (two output groups, or two commands of
        // one process, in one directory spelled two ways), and registered
        // before anything is created, so an interruption from now on removes
        // what this run made.
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let serial = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let staging = dir.join(format!("{STAGING_PREFIX}{}-{serial}", std::process::id()));
        live().push((staging.clone(), created_top.clone().map(|top| (dir.to_path_buf(), top))));
        let refuse = |e: anyhow::Error| {
            live().retain(|(s, _)| *s != staging);
            remove_staging(&staging);
            if let Some(top) = &created_top {
                remove_created(dir, top);
            }
            Err(e)
        };
        if let Err(e) = std::fs::create_dir_all(dir) {
            return refuse(anyhow::Error::new(e).context(format!("cannot create output directory {}", dir.display())));
        }
        let guard = match DirLock::take(dir) {
            Ok(g) => g,
            Err(e) => return refuse(e),
        };
        clean_debris(dir);
        let manifest = Manifest::read(&dir.join(manifest_name(mode)));
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
        // A new folder (`create_dir`, not `_all`): the name is this run's alone.
        // Its lock is taken without waiting: nothing may block while the
        // directory is locked.
        let lock = std::fs::create_dir(&staging)
            .with_context(|| format!("cannot write into {}", dir.display()))
            .and_then(|()| {
                let f = File::create(staging.join(LOCK_FILE))
                    .with_context(|| format!("cannot create {}", staging.display()))?;
                f.try_lock().map_err(|e| anyhow::anyhow!("cannot lock {}: {e}", staging.join(LOCK_FILE).display()))?;
                Ok(f)
            });
        let lock = match lock {
            Ok(l) => l,
            Err(e) => {
                drop(guard);
                return refuse(e);
            }
        };
        drop(guard);
        Ok(Self {
            dir: dir.to_path_buf(),
            mode,
            staging,
            _lock: lock,
            outputs: outputs.iter().map(|n| (n.to_string(), false)).collect(),
            inputs: inputs.iter().map(|p| p.to_path_buf()).collect(),
            committed: false,
            command,
            created_top,
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

    /// Where the output `name` lands, as errors name it (not the staging
    /// path [`Staged::path`] gives, which is gone by the time a user reads
    /// the message).
    pub fn shown(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Writes the declared output `name`.
    pub fn write(&mut self, name: &str, contents: impl AsRef<[u8]>) -> Result<()> {
        let p = self.path(name)?;
        std::fs::write(&p, contents).with_context(|| format!("cannot write {}", self.shown(name).display()))
    }

    /// Writes the declared output `name` through `write`, which gets the
    /// open file: for outputs too large to build in memory first. I/O
    /// errors name the file; `write`'s own errors pass through.
    pub fn write_with(&mut self, name: &str, write: impl FnOnce(&mut File) -> Result<()>) -> Result<()> {
        let p = self.path(name)?;
        let cannot = || format!("cannot write {}", self.shown(name).display());
        let mut f = File::create(&p).with_context(cannot)?;
        write(&mut f).map_err(|e| if e.is::<std::io::Error>() { e.context(cannot()) } else { e })
    }

    /// Moves every written output into place and records them in the
    /// manifest, with the directory locked. In an output directory, files the
    /// previous run listed but this one did not write (say `spectra.csv` of an
    /// earlier `--spectra`) are removed, unless they are inputs of this run or
    /// were changed. Before the first rename, the manifest lists both the
    /// files in place and this run's, so a run killed during the renames
    /// leaves outputs the next run may replace (not a directory it refuses).
    pub fn commit(mut self) -> Result<PathBuf> {
        let _guard = DirLock::take(&self.dir)?;
        // Held to the end, so an interruption waits for the commit; the entry
        // leaves the registry only once the outputs are in place.
        let mut live = live();
        let manifest_path = self.dir.join(manifest_name(self.mode));
        let old = Manifest::read(&manifest_path);
        let written: Vec<String> = self.outputs.iter().filter(|o| o.1).map(|o| o.0.clone()).collect();
        // A file that appeared while this run worked (a user's, or another
        // program's) is refused as it would have been at the start.
        for name in &written {
            let target = self.dir.join(name);
            if std::fs::symlink_metadata(&target).is_ok() && !old.owns(&self.dir, name) {
                bail!(
                    "{} appeared while this run worked and was not written by chirpmap; refusing to overwrite it: \
                     move it away or choose another output",
                    target.display()
                );
            }
        }
        // In an output directory, a file of the last run that this one does not
        // write is kept (and stays listed) when it is one of this run's inputs,
        // or another command's (`map` into a `simulate` folder keeps its
        // scene.toml, the only record of the random obstacles), or written by
        // an older chirpmap that did not record the command. The rest of the
        // same command's files are stale and removed below.
        let mut new = match self.mode {
            Mode::Files => old.clone(),
            Mode::Dir => {
                let mut kept = Manifest::default();
                for e in &old.entries {
                    let p = self.dir.join(&e.name);
                    let input = self.inputs.iter().any(|i| same_file(i, &p));
                    let others = e.by.as_deref() != Some(self.command) && old.owns(&self.dir, &e.name);
                    if !written.contains(&e.name) && (input || others) {
                        kept.entries.push(e.clone());
                    }
                }
                kept
            }
        };
        // Identities survive a rename within the directory.
        let mut both = old.clone();
        for name in &written {
            let p = self.staging.join(name);
            let meta = std::fs::metadata(&p).with_context(|| format!("cannot read back {}", p.display()))?;
            let id = Identity::of(&meta);
            both.entries.push(Entry { name: name.clone(), id: Some(id.clone()), by: Some(self.command.into()) });
            new.set(name, id, self.command);
        }
        let put_manifest = |m: &Manifest, staged_name: &str| -> Result<()> {
            let staged = self.staging.join(staged_name);
            std::fs::write(&staged, m.text()).with_context(|| format!("cannot write {}", manifest_path.display()))?;
            move_into_place(&staged, &manifest_path).with_context(|| {
                format!("cannot update {} (in a shared directory, is it another user's?)", manifest_path.display())
            })
        };
        put_manifest(&both, STAGED_MANIFEST_DURING_COMMIT)?;
        let stale: Vec<String> = match self.mode {
            Mode::Files => Vec::new(),
            Mode::Dir => old
                .entries
                .iter()
                .map(|e| e.name.clone())
                .filter(|n| !written.contains(n) && new.get(n).is_none() && old.owns(&self.dir, n))
                .collect(),
        };
        for name in &written {
            let (from, to) = (self.staging.join(name), self.dir.join(name));
            move_into_place(&from, &to).with_context(|| format!("cannot move {} into place", to.display()))?;
            #[cfg(test)]
            if STOP_AFTER_FIRST_RENAME.with(std::cell::Cell::get) {
                bail!("stopped after moving {name} into place (test)");
            }
        }
        put_manifest(&new, STAGED_MANIFEST)?;
        for name in stale {
            let p = self.dir.join(&name);
            if std::fs::remove_file(&p).is_ok() {
                eprintln!(
                    "note: removed {} (the previous `{}` run's output, not written by this one)",
                    p.display(),
                    self.command
                );
            }
        }
        remove_staging(&self.staging);
        self.committed = true;
        live.retain(|(s, _)| *s != self.staging);
        drop(live);
        Ok(self.dir.clone())
    }
}

#[cfg(test)]
thread_local! {
    /// Makes [`Staged::commit`] stop after its first rename, as a kill there
    /// would (test only; per thread, so parallel tests are not affected).
    static STOP_AFTER_FIRST_RENAME: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
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
            // `file_name` of `new/` is `new`: a WAV named like the folder meant.
            if p.as_os_str().to_string_lossy().ends_with(std::path::MAIN_SEPARATOR) {
                bail!("{} ends with a path separator, so it names a directory; give a file path", p.display());
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
            // chirpmap's own bookkeeping there: `--poses DIR/.chirpmap-files`
            // wrote the poses and then the manifest over them.
            if [DIR_MANIFEST, FILE_MANIFEST, DIR_LOCK].contains(&name.as_str()) || name.starts_with(STAGING_PREFIX) {
                bail!(
                    "{}: chirpmap keeps this name for its own records of what it wrote there; give the output another name",
                    p.display()
                );
            }
            dirs[k].1.push(name.clone());
            index.push((p.to_path_buf(), k, name));
        }
        let groups = dirs
            .iter()
            .map(|(d, names)| {
                let names: Vec<&str> = names.iter().map(String::as_str).collect();
                Staged::new(d, Mode::Files, "synth", &names, inputs)
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
            live().retain(|(s, _)| *s != self.staging);
            remove_staging(&self.staging);
            // Leave no empty directory behind that we created.
            // (Its lock file too, unless another run has written there since.)
            if let Some(top) = &self.created_top {
                remove_created(&self.dir, top);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file moved onto a file replaces it (on Linux by an exchange that
    /// leaves the old one at the source, in the staging folder); onto
    /// nothing it is a rename; onto a directory it fails and leaves the
    /// directory whole (an exchange would have swapped it into the staging
    /// folder, which is removed).
    #[test]
    fn moving_into_place_replaces_files_only() {
        let t = tempfile::tempdir().expect("tmp");
        let (from, to) = (t.path().join("new"), t.path().join("out"));
        std::fs::write(&from, "new").expect("write");
        std::fs::write(&to, "old").expect("write");
        move_into_place(&from, &to).expect("replace");
        assert_eq!(std::fs::read_to_string(&to).expect("read"), "new");
        if cfg!(target_os = "linux") {
            // Exchanged (tmpfs, ext4, xfs, btrfs), or renamed where it cannot be.
            let left = std::fs::read_to_string(&from).ok();
            assert!(left.is_none() || left.as_deref() == Some("old"), "{left:?}");
        }
        std::fs::write(&from, "again").expect("write");
        let fresh = t.path().join("fresh");
        move_into_place(&from, &fresh).expect("rename");
        assert_eq!(std::fs::read_to_string(&fresh).expect("read"), "again");
        assert!(!from.exists());
        std::fs::write(&from, "file").expect("write");
        let dir = t.path().join("dir");
        std::fs::create_dir(&dir).expect("dir");
        std::fs::write(dir.join("keep"), "mine").expect("write");
        assert!(move_into_place(&from, &dir).is_err());
        assert_eq!(std::fs::read_to_string(dir.join("keep")).expect("kept"), "mine");
        assert_eq!(std::fs::read_to_string(&from).expect("still there"), "file");
    }

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
        let err = Staged::dir(t.path(), "test", &["summary.json"], &[]).expect_err("user's file");
        assert!(err.to_string().contains("not written by chirpmap"), "{err}");
        let input = t.path().join("summary.json");
        let err = Staged::dir(t.path(), "test", &["summary.json"], &[&input]).expect_err("input");
        assert!(err.to_string().contains("would replace the input"), "{err}");
        assert_eq!(std::fs::read_to_string(&input).expect("read"), "mine");
        assert_eq!(names(t.path()), vec!["summary.json"]);
    }

    /// Single-file outputs named as chirpmap's own records (its manifests,
    /// lock, staging folders) are refused before anything is written: the
    /// manifest was written over such an output after it.
    #[test]
    fn outputs_named_as_chirpmaps_own_records_are_refused() {
        let t = tempfile::tempdir().expect("tmp");
        let wav = t.path().join("rec.wav");
        for name in [FILE_MANIFEST, DIR_MANIFEST, DIR_LOCK, &format!("{STAGING_PREFIX}7")] {
            let p = t.path().join(name);
            let err = StagedFiles::new(&[&wav, &p], &[]).expect_err("reserved");
            assert!(err.to_string().contains("keeps this name for its own records"), "{err}");
        }
        assert!(names(t.path()).is_empty(), "nothing written");
    }

    #[test]
    fn rerun_replaces_own_outputs_drops_stale_ones_but_keeps_inputs() {
        let t = tempfile::tempdir().expect("tmp");
        let mut s = Staged::dir(t.path(), "test", &["a.csv", "b.csv", "c.csv"], &[]).expect("new");
        for n in ["a.csv", "b.csv", "c.csv"] {
            s.write(n, "1").expect("write");
        }
        s.commit().expect("commit");
        let input = t.path().join("b.csv");
        let mut s = Staged::dir(t.path(), "test", &["a.csv"], &[&input]).expect("rerun");
        s.write("a.csv", "2").expect("write");
        s.commit().expect("commit");
        // c.csv was the last run's and is stale; b.csv is this run's input.
        assert_eq!(names(t.path()), vec![".chirpmap-outputs", "a.csv", "b.csv"]);
        assert_eq!(std::fs::read_to_string(t.path().join("a.csv")).expect("read"), "2");
    }

    #[test]
    fn another_commands_outputs_are_kept_and_stay_replaceable() {
        let t = tempfile::tempdir().expect("tmp");
        let run = |command: &'static str, names: &[&str]| {
            let mut s = Staged::dir(t.path(), command, names, &[]).expect("new");
            for n in names {
                s.write(n, command).expect("write");
            }
            s.commit().expect("commit");
        };
        run("simulate", &["map.png", "scene.toml"]);
        // `map` into a simulate folder: scene.toml is not its output, and stays.
        run("map", &["map.png", "surfaces.csv"]);
        assert_eq!(names(t.path()), vec![".chirpmap-outputs", "map.png", "scene.toml", "surfaces.csv"]);
        assert_eq!(std::fs::read_to_string(t.path().join("scene.toml")).expect("kept"), "simulate");
        // Still chirpmap's: the next simulate replaces it; surfaces.csv is map's and stays.
        run("simulate", &["map.png", "scene.toml"]);
        assert_eq!(names(t.path()), vec![".chirpmap-outputs", "map.png", "scene.toml", "surfaces.csv"]);
        // The same command without one of its outputs drops it as stale.
        run("map", &["map.png"]);
        assert_eq!(names(t.path()), vec![".chirpmap-outputs", "map.png", "scene.toml"]);
    }

    #[test]
    fn a_changed_output_is_no_longer_ours() {
        let t = tempfile::tempdir().expect("tmp");
        let mut s = Staged::dir(t.path(), "test", &["a.csv", "b.csv"], &[]).expect("new");
        s.write("a.csv", "1").expect("write");
        s.write("b.csv", "1").expect("write");
        s.commit().expect("commit");
        std::fs::write(t.path().join("b.csv"), "edited by the user").expect("edit");
        let mut s = Staged::dir(t.path(), "test", &["a.csv"], &[]).expect("rerun");
        s.write("a.csv", "2").expect("write");
        s.commit().expect("commit");
        assert_eq!(std::fs::read_to_string(t.path().join("b.csv")).expect("kept"), "edited by the user");
        assert!(Staged::dir(t.path(), "test", &["b.csv"], &[]).is_err());
    }

    #[test]
    fn failure_leaves_nothing_and_debris_of_dead_runs_is_removed() {
        let t = tempfile::tempdir().expect("tmp");
        let out = t.path().join("new");
        {
            let mut s = Staged::dir(&out, "test", &["a.csv"], &[]).expect("new");
            s.write("a.csv", "1").expect("write");
        }
        assert!(!out.exists());
        // Every directory created on the way goes too, and nothing above.
        {
            let deep = t.path().join("n1/n2/n3");
            let mut s = Staged::dir(&deep, "test", &["a.csv"], &[]).expect("new");
            s.write("a.csv", "1").expect("write");
        }
        assert!(!t.path().join("n1").exists() && t.path().exists());
        // Debris of a killed run: a staging folder with an unlocked lock file.
        let dead = t.path().join(format!("{STAGING_PREFIX}4000000000"));
        std::fs::create_dir_all(&dead).expect("mkdir");
        std::fs::write(dead.join(LOCK_FILE), "").expect("lock");
        // Not debris: a user's file named like an older chirpmap's partial
        // file, and a folder named like a staging folder without a lock.
        std::fs::write(t.path().join("thesis.tex.partial-4000000000"), "draft").expect("partial");
        let users = t.path().join(format!("{STAGING_PREFIX}17"));
        std::fs::create_dir_all(&users).expect("mkdir");
        std::fs::write(users.join("notes.txt"), "mine").expect("notes");
        let s = StagedFiles::new(&[&t.path().join("x.wav")], &[]).expect("files");
        drop(s);
        assert_eq!(names(t.path()), vec![format!("{STAGING_PREFIX}17"), "thesis.tex.partial-4000000000".into()]);
        assert_eq!(std::fs::read_to_string(users.join("notes.txt")).expect("kept"), "mine");
    }

    #[test]
    fn a_live_runs_staging_folder_is_never_removed() {
        let t = tempfile::tempdir().expect("tmp");
        let mut first = Staged::dir(t.path(), "test", &["a.csv"], &[]).expect("first");
        first.write("a.csv", "1").expect("write");
        // Another run starting meanwhile cleans debris: not the first's folder.
        let (tx, rx) = std::sync::mpsc::channel();
        let dir = t.path().to_path_buf();
        std::thread::spawn(move || {
            clean_debris(&dir);
            tx.send(()).ok();
        });
        rx.recv().expect("cleaned");
        assert_eq!(first.commit().expect("commit"), t.path());
        assert_eq!(std::fs::read_to_string(t.path().join("a.csv")).expect("read"), "1");
    }

    #[test]
    fn a_commit_killed_between_renames_leaves_outputs_the_next_run_may_replace() {
        let t = tempfile::tempdir().expect("tmp");
        let mut s = Staged::dir(t.path(), "test", &["a.csv", "b.csv"], &[]).expect("new");
        s.write("a.csv", "old").expect("write");
        s.write("b.csv", "old").expect("write");
        s.commit().expect("commit");
        // A commit stopped after its first rename (as a kill would stop it).
        let mut s = Staged::dir(t.path(), "test", &["a.csv", "b.csv"], &[]).expect("new");
        s.write("a.csv", "new").expect("write");
        s.write("b.csv", "new").expect("write");
        STOP_AFTER_FIRST_RENAME.with(|c| c.set(true));
        let stopped = s.commit();
        STOP_AFTER_FIRST_RENAME.with(|c| c.set(false));
        assert!(stopped.is_err());
        assert_eq!(std::fs::read_to_string(t.path().join("a.csv")).expect("a"), "new");
        assert_eq!(std::fs::read_to_string(t.path().join("b.csv")).expect("b"), "old");
        let mut s = Staged::dir(t.path(), "test", &["a.csv", "b.csv"], &[]).expect("the next run is not refused");
        s.write("a.csv", "2").expect("write");
        s.write("b.csv", "2").expect("write");
        s.commit().expect("commit");
        let text = std::fs::read_to_string(t.path().join(DIR_MANIFEST)).expect("manifest");
        assert_eq!(text.lines().count(), 2, "one identity per file once committed: {text}");
    }

    /// Outputs named as the staging folder's own files were once clobbered:
    /// `manifest` was written over with the manifest (through the old file,
    /// which the exchange had left under that name, so a user's hard link to
    /// it changed too), `manifest-during-commit` became the old manifest.
    /// Reruns now keep each output's content and leave the user's link alone.
    #[test]
    fn outputs_named_like_the_staging_folders_files_are_written_whole() {
        let t = tempfile::tempdir().expect("tmp");
        let outs: Vec<PathBuf> =
            ["manifest", "manifest-during-commit", "lock"].iter().map(|n| t.path().join(n)).collect();
        let refs: Vec<&Path> = outs.iter().map(PathBuf::as_path).collect();
        for round in ["first", "second", "third"] {
            let mut s = StagedFiles::new(&refs, &[]).expect("files");
            for p in &outs {
                std::fs::write(s.path(p).expect("declared"), format!("{round} {}", p.display())).expect("write");
            }
            s.commit().expect("commit");
            for p in &outs {
                assert_eq!(std::fs::read_to_string(p).expect("read"), format!("{round} {}", p.display()));
            }
            if round == "first" {
                std::fs::hard_link(&outs[0], t.path().join("keep")).expect("link");
            }
        }
        let kept = std::fs::read_to_string(t.path().join("keep")).expect("kept");
        assert_eq!(kept, format!("first {}", outs[0].display()));
    }

    /// A staging folder's removal deletes files only: a directory found there
    /// is not chirpmap's (an exchange raced by a directory put in an output's
    /// place would leave one there), so it stays, with its contents.
    #[test]
    fn removing_a_staging_folder_leaves_directories_alone() {
        let t = tempfile::tempdir().expect("tmp");
        let staging = t.path().join(format!("{STAGING_PREFIX}1-0"));
        std::fs::create_dir_all(staging.join("echoes.csv")).expect("dir");
        std::fs::write(staging.join("echoes.csv").join("data"), "precious").expect("write");
        std::fs::write(staging.join("map.npy"), "staged").expect("write");
        std::fs::write(staging.join(LOCK_FILE), "").expect("lock");
        remove_staging(&staging);
        assert_eq!(std::fs::read_to_string(staging.join("echoes.csv").join("data")).expect("kept"), "precious");
        assert!(!staging.join("map.npy").exists());
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
