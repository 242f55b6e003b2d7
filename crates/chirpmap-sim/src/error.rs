use chirpmap_core::CoreError;
use thiserror::Error;

/// Errors of the simulator: all come from the scene, so each names the field at fault.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SimError {
    /// The scene is inconsistent; the message names the field.
    #[error("invalid scene: {0}")]
    Scene(String),
    /// An error from the core library (chirp, geometry, mapping parameters).
    #[error(transparent)]
    Core(#[from] CoreError),
}

pub(crate) fn scene_err(msg: impl Into<String>) -> SimError {
    SimError::Scene(msg.into())
}
