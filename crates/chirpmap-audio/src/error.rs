use thiserror::Error;

/// Errors of the audio pipeline. Each says what was wrong with the input and,
/// where it helps, what to do about it.
#[derive(Debug, Error)]
pub enum AudioError {
    #[error("not a WAV file: {0}")]
    NotWav(String),
    #[error("truncated WAV file: {0}")]
    Truncated(String),
    #[error("unsupported WAV format: {0} (supported: 16/24/32-bit integer PCM and 32-bit float)")]
    Unsupported(String),
    #[error("cannot read {path}")]
    Io { path: String, source: std::io::Error },
    #[error("WAV write failed: {0}")]
    Write(String),
    #[error("channel {requested} does not exist; the recording has {available} channel(s) (numbered from 0)")]
    NoSuchChannel { requested: usize, available: usize },
    #[error("the recording is silent (every sample is zero)")]
    Silent,
    #[error("the chirp ({chirp_s} s) is longer than the recording ({recording_s} s); check --duration and the file")]
    ChirpLongerThanRecording { chirp_s: f64, recording_s: f64 },
    #[error(
        "no chirp found: the best matched-filter peak is only {ratio:.1}× the typical level (need {need:.1}×); \
         check --f-start/--f-end/--duration"
    )]
    NoChirp { ratio: f64, need: f64 },
    #[error(
        "no chirp found: the best normalised correlation with the chirp is {ncc:.2} (need {need:.2}); \
         check --f-start/--f-end/--duration"
    )]
    NoChirpShape { ncc: f64, need: f64 },
    #[error("speaker and microphone are at the same position ({x}, {y}); the direct distance must be > 0")]
    SpeakerAtMic { x: f64, y: f64 },
    #[error("invalid parameter {field}: {reason}")]
    InvalidParam { field: &'static str, reason: String },
    #[error(transparent)]
    Core(#[from] chirpmap_core::CoreError),
}
