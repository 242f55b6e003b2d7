//! The error type shared by the sweep definition, runner, runs.csv and merge code.

use thiserror::Error;

/// Everything that can go wrong defining, running, resuming or merging a sweep.
#[derive(Debug, Error)]
pub enum ExperimentError {
    /// The sweep definition (or a `--shard` argument) is malformed; the message says why.
    #[error("invalid sweep: {0}")]
    InvalidSweep(String),
    /// A file exists but its content is unusable (e.g. a run outside the shard, a missing sweep.toml).
    #[error("{path}: {msg}")]
    File {
        /// The offending file.
        path: String,
        /// What is wrong with it.
        msg: String,
    },
    /// Reading or writing a file failed. The I/O error is in the message,
    /// not also a `source`, so that printing the chain says it once.
    #[error("I/O error on {path}: {err}")]
    Io {
        /// The file being read or written.
        path: String,
        /// The underlying I/O error.
        err: std::io::Error,
    },
    /// The simulation of one run failed; `config` is the configuration index, `run` the
    /// run index (random stream), `msg` the simulator's error.
    #[error("run {run} of configuration {config} failed: {msg}")]
    RunFailed {
        /// Configuration index in the plan.
        config: usize,
        /// Run index (random stream).
        run: u64,
        /// The simulator's error message.
        msg: String,
    },
    /// Shard directories cannot be merged (different sweeps or conflicting results).
    #[error("cannot merge: {0}")]
    Merge(String),
}

impl ExperimentError {
    /// An [`ExperimentError::Io`] naming `path`.
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        Self::Io { path: path.display().to_string(), err: source }
    }
    /// An [`ExperimentError::File`] naming `path`.
    pub fn file(path: &std::path::Path, msg: impl Into<String>) -> Self {
        Self::File { path: path.display().to_string(), msg: msg.into() }
    }
}
