//! One error type for the whole pipeline; each layer's error is kept as the
//! source so its message reaches the user unchanged.

use chirpmap_audio::AudioError;
use chirpmap_core::CoreError;
use chirpmap_sim::SimError;

/// Why a pipeline step refused its input.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Geometry, grid or mapping parameters.
    #[error(transparent)]
    Core(#[from] CoreError),
    /// Scene resolution or simulation.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// Recording, chirp template, ranging or synthesis.
    #[error(transparent)]
    Audio(#[from] AudioError),
    /// An input the pipeline cannot use, with the reason.
    #[error("{0}")]
    Invalid(String),
    /// A parameter out of its range; `field` is the parameter's name as the
    /// Rust and Python APIs spell it (the CLI's flag with `-` for `_`).
    #[error("{field}: {reason}")]
    Field {
        /// The parameter.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
}

/// Result of a pipeline step.
pub type Result<T, E = Error> = std::result::Result<T, E>;
