//! The audio pipeline's error type and its memory guard.

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
    /// The bytes are not a RIFF/WAVE file; the message says which check failed.
    #[error("not a WAV file: {0}")]
    NotWav(String),
    /// The file ends before a chunk its header announces.
    #[error("truncated WAV file: {0}")]
    Truncated(String),
    /// A sample format other than 16/24/32-bit integer PCM or 32-bit float.
    #[error("unsupported WAV format: {0} (supported: 16/24/32-bit integer PCM and 32-bit float)")]
    Unsupported(String),
    /// Reading the file failed.
    #[error("cannot read {path}")]
    Io {
        /// The file being read.
        path: String,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// Writing a WAV file failed; the message names the file and the encoder's error.
    #[error("WAV write failed: {0}")]
    Write(String),
    /// The requested channel is not in the recording.
    #[error("channel {requested} does not exist; the recording has {available} channel(s) (numbered from 0)")]
    NoSuchChannel {
        /// Channel index asked for (0-based).
        requested: usize,
        /// Number of channels in the recording.
        available: usize,
    },
    /// Every sample is zero, so nothing can be detected.
    #[error("the recording is silent (every sample is zero)")]
    Silent,
    /// The chirp is longer than the recording, so it cannot be in it.
    #[error(
        "the chirp ({} s) is longer than the recording ({} s); check --duration and the file",
        Num(*chirp_s),
        Num(*recording_s)
    )]
    ChirpLongerThanRecording {
        /// Chirp duration (s).
        chirp_s: f64,
        /// Recording duration (s).
        recording_s: f64,
    },
    /// No matched-filter peak stands out enough from the noise.
    #[error(
        "no chirp found: the best matched-filter peak is only {ratio:.1}× the typical level (need {need:.1}×); \
         check --f-start/--f-end/--duration"
    )]
    NoChirp {
        /// Best matched-filter peak over the recording's typical level.
        ratio: f64,
        /// Ratio required for a detection.
        need: f64,
    },
    /// A peak was found but its waveform does not look like the chirp.
    #[error(
        "no chirp found: the best normalised correlation with the chirp is {ncc:.2} (need {need:.2}); \
         check --f-start/--f-end/--duration"
    )]
    NoChirpShape {
        /// Best normalised correlation with the template, in [0, 1].
        ncc: f64,
        /// Correlation required for a detection.
        need: f64,
    },
    /// Speaker and microphone coincide, so the direct path has no length.
    #[error("speaker and microphone are at the same position ({}, {}); the direct distance must be > 0", Num(*x), Num(*y))]
    SpeakerAtMic {
        /// Shared x coordinate (m).
        x: f64,
        /// Shared y coordinate (m).
        y: f64,
    },
    /// Float samples far beyond full scale (more than [`MAX_FLOAT_SAMPLE`]).
    #[error(
        "float samples reach {} but full scale is ±1: the file's samples are scaled wrongly (more than {} times \
         full scale); rescale the recording to ±1",
        Num(f64::from(*peak)),
        Num(MAX_FLOAT_SAMPLE)
    )]
    BadScale {
        /// Largest |sample| found.
        peak: f32,
    },
    /// A float sample that is NaN or infinite: no recorder writes one, so
    /// the file is damaged (or was written from invalid values). Refused
    /// rather than read as silence or as clipping, which would hide it.
    #[error(
        "float sample {frame} of channel {channel} is {what}: the file is damaged or was written from invalid \
         values (a WAV holds finite samples)"
    )]
    NonFinite {
        /// Frame (sample index per channel, from 0) of the first such sample.
        frame: usize,
        /// Its channel (from 0).
        channel: usize,
        /// `NaN`, `inf` or `-inf`.
        what: &'static str,
    },
    /// A parameter is out of range; `field` names it, `reason` says why.
    #[error("invalid parameter {field}: {reason}")]
    InvalidParam {
        /// Name of the parameter (as on the command line or in the struct).
        field: &'static str,
        /// What is wrong and what is allowed.
        reason: String,
    },
    /// A planned allocation exceeds [`MEMORY_CAP_BYTES`].
    #[error(
        "{what} would need about {} of memory, more than the cap of {}; {hint}",
        human_bytes(*bytes),
        human_bytes(*cap)
    )]
    TooLarge {
        /// What would be allocated.
        what: String,
        /// Estimated size (bytes).
        bytes: u128,
        /// The cap, [`MEMORY_CAP_BYTES`].
        cap: u128,
        /// How to bring the size down.
        hint: &'static str,
    },
    /// An error from `chirpmap-core` (e.g. an invalid chirp), passed through.
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
