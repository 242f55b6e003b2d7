use thiserror::Error;

/// Errors of the core library. Each names the field or quantity at fault so
/// the CLI can point the user at the offending line.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CoreError {
    #[error("{field} must be finite, got {value}")]
    NotFinite { field: &'static str, value: f64 },
    #[error("delta_d must be >= 0 m, got {0}")]
    NegativeDeltaD(f64),
    #[error("source and listener coincide at ({x}, {y}); the ellipse is undefined")]
    CoincidentFoci { x: f64, y: f64 },
    #[error("invalid chirp: {0}")]
    InvalidChirp(String),
    #[error("invalid geometry: {0}")]
    InvalidGeometry(String),
    #[error("invalid grid: {0}")]
    InvalidGrid(String),
    #[error(
        "grid of {nx} x {ny} cells needs {bytes} bytes to map, more than the cap of {cap} bytes; \
         pass smaller --bounds or a larger --cell"
    )]
    GridTooLarge { nx: usize, ny: usize, bytes: u128, cap: u128 },
    #[error("invalid mapping parameter {field}: {reason}")]
    InvalidParam { field: &'static str, reason: String },
    #[error("invalid scene: {0}")]
    InvalidScene(String),
}

/// Returns `value` if finite, otherwise a [`CoreError::NotFinite`] naming `field`.
pub fn finite(field: &'static str, value: f64) -> Result<f64, CoreError> {
    if value.is_finite() { Ok(value) } else { Err(CoreError::NotFinite { field, value }) }
}
