use chirpmap_core::error::Num;
use thiserror::Error;

/// Largest |sample| of a float WAV accepted (full scale is ±1). Files a
/// little over full scale are common; 10⁶ × full scale is a wrongly scaled
/// file, and at ×10³⁰ the matched filter's sums overflow `f32` (issue 8,
/// item 16).
pub const MAX_FLOAT_SAMPLE: f64 = 1e6;

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
    #[error(
        "the chirp ({} s) is longer than the recording ({} s); check --duration and the file",
        Num(*chirp_s),
        Num(*recording_s)
    )]
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
    #[error("speaker and microphone are at the same position ({}, {}); the direct distance must be > 0", Num(*x), Num(*y))]
    SpeakerAtMic { x: f64, y: f64 },
    #[error(
        "float samples reach {} but full scale is ±1: the file's samples are scaled wrongly (more than {} times \
         full scale); rescale the recording to ±1",
        Num(f64::from(*peak)),
        Num(MAX_FLOAT_SAMPLE)
    )]
    BadScale { peak: f32 },
    #[error("invalid parameter {field}: {reason}")]
    InvalidParam { field: &'static str, reason: String },
    #[error(
        "{what} would need about {} of memory, more than the cap of {}; {hint}",
        human_bytes(*bytes),
        human_bytes(*cap)
    )]
    TooLarge { what: String, bytes: u128, cap: u128, hint: &'static str },
    #[error(transparent)]
    Core(#[from] chirpmap_core::CoreError),
}

/// Cap on the memory (bytes) one audio step may plan to allocate: 4 GiB,
/// checked against an estimate *before* allocating, so a hostile header or
/// a typo gives an error naming the estimate instead of an abort at the
/// allocator (issue 8, items 8–9). An hour at 48 kHz is 0.7 GB per channel.
pub const MEMORY_CAP_BYTES: u128 = 4 << 30;

/// Refuses `bytes` beyond [`MEMORY_CAP_BYTES`], naming `what` was estimated.
pub fn check_memory(what: impl FnOnce() -> String, bytes: u128, hint: &'static str) -> Result<(), AudioError> {
    if bytes > MEMORY_CAP_BYTES {
        return Err(AudioError::TooLarge { what: what(), bytes, cap: MEMORY_CAP_BYTES, hint });
    }
    Ok(())
}

/// `1.2 GB`-style byte counts for messages (decimal units).
pub fn human_bytes(bytes: u128) -> String {
    let b = bytes as f64;
    for (unit, scale) in [("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)] {
        if b >= scale {
            return format!("{:.1} {unit} ({bytes} bytes)", b / scale);
        }
    }
    format!("{bytes} bytes")
}
