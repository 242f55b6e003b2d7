//! All-or-nothing output directories: files are written into a hidden
//! staging folder inside the target and moved into place only when every one
//! of them was written, so a failure never leaves a half-written result.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Lists the files the last run wrote into an output directory.
const MANIFEST: &str = ".chirpmap-outputs";

#[derive(Debug)]
pub struct Staged {
    dir: PathBuf,
    staging: PathBuf,
    files: Vec<String>,
    committed: bool,
    /// Whether `dir` did not exist before, so a failure may remove it.
    created_dir: bool,
}

impl Staged {
    pub fn new(dir: &Path) -> Result<Self> {
        let created_dir = !dir.exists();
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create output directory {}", dir.display()))?;
        let staging = dir.join(format!(".chirpmap-partial-{}", std::process::id()));
        std::fs::create_dir_all(&staging).with_context(|| format!("cannot create {}", staging.display()))?;
        Ok(Self { dir: dir.to_path_buf(), staging, files: Vec::new(), committed: false, created_dir })
    }

    /// Path at which to write `name`; it lands in the output on [`Staged::commit`].
    pub fn path(&mut self, name: &str) -> PathBuf {
        if !self.files.iter().any(|f| f == name) {
            self.files.push(name.to_string());
        }
        self.staging.join(name)
    }

    pub fn write(&mut self, name: &str, contents: impl AsRef<[u8]>) -> Result<()> {
        let p = self.path(name);
        std::fs::write(&p, contents).with_context(|| format!("cannot write {}", p.display()))
    }

    /// Moves every staged file into the output directory.
    ///
    /// Files an earlier chirpmap run listed in the directory's manifest but
    /// this run did not write (say `spectra.csv` from an earlier `--spectra`)
    /// are removed, so the directory never mixes two runs; files the user put
    /// there are never touched.
    pub fn commit(mut self) -> Result<PathBuf> {
        for f in &self.files {
            let (from, to) = (self.staging.join(f), self.dir.join(f));
            std::fs::rename(&from, &to)
                .with_context(|| format!("cannot move {} to {}", from.display(), to.display()))?;
        }
        let manifest = self.dir.join(MANIFEST);
        if let Ok(old) = std::fs::read_to_string(&manifest) {
            for stale in old.lines().filter(|l| !l.is_empty() && !l.contains('/') && !self.files.iter().any(|f| f == l))
            {
                std::fs::remove_file(self.dir.join(stale)).ok();
            }
        }
        let list: String = self.files.iter().map(|f| format!("{f}\n")).collect();
        std::fs::write(&manifest, list).with_context(|| format!("cannot write {}", manifest.display()))?;
        std::fs::remove_dir_all(&self.staging).ok();
        self.committed = true;
        Ok(self.dir.clone())
    }
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
