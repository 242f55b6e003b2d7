//! WAV reading and writing.
//!
//! Parsing of the RIFF container is delegated to `hound` (3.5), which reads
//! 8/16/24/32-bit integer PCM and 32-bit IEEE float, plain and
//! `WAVE_FORMAT_EXTENSIBLE` headers, and skips unknown chunks (`LIST`, `bext`,
//! AudioMoth's `guan`-style metadata). This module adds what the pipeline
//! needs on top: one error type with clear messages, a truncation check, a
//! clipping count, and conversion to `f32` in [-1, 1] per channel.

use crate::error::AudioError;
use std::io::Cursor;
use std::path::Path;

/// Sample encoding in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleFormat {
    /// Signed integer PCM with this many bits (16, 24 or 32).
    Int(u16),
    /// 32-bit IEEE float.
    Float32,
}

impl SampleFormat {
    /// Parses "16", "24", "32" (integer) or "f32"/"float".
    pub fn parse(s: &str) -> Result<Self, AudioError> {
        match s.trim() {
            "16" => Ok(Self::Int(16)),
            "24" => Ok(Self::Int(24)),
            "32" => Ok(Self::Int(32)),
            "f32" | "float" | "float32" => Ok(Self::Float32),
            other => Err(AudioError::InvalidParam {
                field: "bits",
                reason: format!("{other:?}: use 16, 24, 32 or f32"),
            }),
        }
    }
}

/// A decoded recording: one `f32` vector per channel, full scale = ±1.
#[derive(Debug, Clone)]
pub struct Recording {
    pub sample_rate_hz: u32,
    pub format: SampleFormat,
    pub channels: Vec<Vec<f32>>,
    /// Samples at (or beyond) full scale, over all channels: a sign the
    /// recorder's gain was too high.
    pub clipped_samples: usize,
}

impl Recording {
    pub fn len_samples(&self) -> usize {
        self.channels.first().map_or(0, Vec::len)
    }
    pub fn duration_s(&self) -> f64 {
        self.len_samples() as f64 / f64::from(self.sample_rate_hz)
    }
    /// The requested channel, or an error naming how many exist.
    pub fn channel(&self, index: usize) -> Result<&[f32], AudioError> {
        self.channels
            .get(index)
            .map(Vec::as_slice)
            .ok_or(AudioError::NoSuchChannel { requested: index, available: self.channels.len() })
    }
}

fn map_hound(e: hound::Error) -> AudioError {
    match e {
        hound::Error::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            AudioError::Truncated(format!("the file ends inside a header or chunk ({io})"))
        }
        hound::Error::IoError(io) => AudioError::NotWav(io.to_string()),
        hound::Error::FormatError(m) => AudioError::NotWav(m.to_string()),
        hound::Error::Unsupported => AudioError::Unsupported("this WAV encoding".into()),
        hound::Error::InvalidSampleFormat => AudioError::Unsupported("invalid sample format".into()),
        hound::Error::TooWide => AudioError::Unsupported("sample wider than 32 bits".into()),
        hound::Error::UnfinishedSample => AudioError::Truncated("the data ends inside a sample".into()),
    }
}

/// Decodes a WAV file held in memory. Never panics on any input (fuzzed in
/// `tests/wav_fuzz.rs`).
pub fn read_wav_bytes(bytes: &[u8]) -> Result<Recording, AudioError> {
    if bytes.len() < 12 || &bytes[0..4] != b"RIFF" || &bytes[8..12] != b"WAVE" {
        if bytes.len() < 12 && bytes.starts_with(b"RIFF") {
            return Err(AudioError::Truncated(format!("only {} bytes", bytes.len())));
        }
        return Err(AudioError::NotWav("the file does not start with a RIFF/WAVE header".into()));
    }
    let reader = hound::WavReader::new(Cursor::new(bytes)).map_err(map_hound)?;
    let spec = reader.spec();
    let format = match (spec.sample_format, spec.bits_per_sample) {
        (hound::SampleFormat::Int, b @ (16 | 24 | 32)) => SampleFormat::Int(b),
        (hound::SampleFormat::Float, 32) => SampleFormat::Float32,
        (f, b) => return Err(AudioError::Unsupported(format!("{b}-bit {f:?}"))),
    };
    let n_ch = usize::from(spec.channels);
    if n_ch == 0 {
        return Err(AudioError::NotWav("zero channels".into()));
    }
    if spec.sample_rate == 0 {
        return Err(AudioError::NotWav("sample rate 0".into()));
    }
    // hound reports the data chunk's declared length; a recorder that lost
    // power leaves a header that promises more than the file holds.
    let declared = reader.len() as usize;
    let frames_declared = declared / n_ch;
    // Guard the allocation against lying headers: never reserve more than
    // the bytes present could hold.
    let frames_cap = frames_declared.min(bytes.len() / n_ch / 2 + 1);
    let mut channels: Vec<Vec<f32>> = (0..n_ch).map(|_| Vec::with_capacity(frames_cap)).collect();
    let mut clipped = 0usize;
    let mut got = 0usize;
    macro_rules! pull {
        ($iter:expr, $conv:expr, $is_clip:expr) => {
            for s in $iter {
                let s = match s {
                    Ok(s) => s,
                    Err(hound::Error::IoError(io)) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
                        return Err(AudioError::Truncated(format!(
                            "the header declares {frames_declared} frames but the data ends after {} \
                             (the file was cut short)",
                            got / n_ch
                        )));
                    }
                    Err(e) => return Err(map_hound(e)),
                };
                if $is_clip(s) {
                    clipped += 1;
                }
                channels[got % n_ch].push($conv(s));
                got += 1;
            }
        };
    }
    let mut reader = reader;
    match format {
        SampleFormat::Int(bits) => {
            let full = 2f64.powi(i32::from(bits) - 1);
            let max_i = (full - 1.0) as i64;
            let scale = (1.0 / full) as f32;
            pull!(reader.samples::<i32>(), |s: i32| s as f32 * scale, |s: i32| i64::from(s).abs() >= max_i);
        }
        SampleFormat::Float32 => {
            pull!(
                reader.samples::<f32>(),
                |s: f32| if s.is_finite() { s } else { 0.0 },
                |s: f32| !s.is_finite() || s.abs() >= 1.0
            );
        }
    }
    if got < declared {
        return Err(AudioError::Truncated(format!(
            "the header declares {frames_declared} frames but the data holds {}",
            got / n_ch
        )));
    }
    // A trailing partial frame is dropped so every channel has equal length.
    let frames = got / n_ch;
    for c in &mut channels {
        c.truncate(frames);
    }
    if frames == 0 {
        return Err(AudioError::NotWav("the data chunk holds no samples".into()));
    }
    Ok(Recording { sample_rate_hz: spec.sample_rate, format, channels, clipped_samples: clipped })
}

/// Reads a WAV file from disk.
pub fn read_wav(path: &Path) -> Result<Recording, AudioError> {
    let bytes =
        std::fs::read(path).map_err(|source| AudioError::Io { path: path.display().to_string(), source })?;
    read_wav_bytes(&bytes)
}

/// Writes channels (equal length, full scale ±1; values beyond are clipped)
/// as a WAV file in the given format.
pub fn write_wav(path: &Path, sample_rate_hz: u32, format: SampleFormat, channels: &[&[f32]]) -> Result<(), AudioError> {
    let n_ch = channels.len();
    let frames = channels.first().map_or(0, |c| c.len());
    if n_ch == 0 || n_ch > usize::from(u16::MAX) || channels.iter().any(|c| c.len() != frames) {
        return Err(AudioError::InvalidParam {
            field: "channels",
            reason: "need at least one channel, all of equal length".into(),
        });
    }
    let (bits, sample_format) = match format {
        SampleFormat::Int(b) => (b, hound::SampleFormat::Int),
        SampleFormat::Float32 => (32, hound::SampleFormat::Float),
    };
    let spec = hound::WavSpec { channels: n_ch as u16, sample_rate: sample_rate_hz, bits_per_sample: bits, sample_format };
    let werr = |e: hound::Error| AudioError::Write(format!("{}: {e}", path.display()));
    let file = std::fs::File::create(path)
        .map_err(|source| AudioError::Io { path: path.display().to_string(), source })?;
    let mut w = hound::WavWriter::new(std::io::BufWriter::with_capacity(1 << 20, file), spec).map_err(werr)?;
    match format {
        SampleFormat::Int(16) => {
            let mut w16 = w.get_i16_writer((frames * n_ch) as u32);
            for i in 0..frames {
                for c in channels {
                    w16.write_sample((f64::from(c[i]).clamp(-1.0, 1.0) * 32767.0).round() as i16);
                }
            }
            w16.flush().map_err(werr)?;
        }
        SampleFormat::Int(b) => {
            let full = if b == 32 { 2_147_483_647.0 } else { f64::from((1u32 << (b - 1)) - 1) };
            for i in 0..frames {
                for c in channels {
                    w.write_sample((f64::from(c[i]).clamp(-1.0, 1.0) * full).round() as i32).map_err(werr)?;
                }
            }
        }
        SampleFormat::Float32 => {
            for i in 0..frames {
                for c in channels {
                    w.write_sample(c[i].clamp(-1.0, 1.0)).map_err(werr)?;
                }
            }
        }
    }
    w.finalize().map_err(werr)
}
