use thiserror::Error;

#[derive(Debug, Error)]
pub enum ExperimentError {
    #[error("invalid sweep: {0}")]
    InvalidSweep(String),
    #[error("{path}: {msg}")]
    File { path: String, msg: String },
    #[error("I/O error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("run {run} of configuration {config} failed: {msg}")]
    RunFailed { config: usize, run: u64, msg: String },
    #[error("cannot merge: {0}")]
    Merge(String),
}

impl ExperimentError {
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        Self::Io { path: path.display().to_string(), source }
    }
    pub fn file(path: &std::path::Path, msg: impl Into<String>) -> Self {
        Self::File { path: path.display().to_string(), msg: msg.into() }
    }
}
