//! WAV reading and writing.
//!
//! Reading is our own RIFF walker, not `hound`: hound 3.5.1 (checked in its
//! `read.rs`) skips an unknown chunk by its declared length without the RIFF
//! pad byte that follows an odd-sized chunk, so it misreads files with an
//! odd-length `LIST`/metadata chunk, and it reports a truncated file as a
//! generic I/O error ("Failed to read enough bytes") rather than as
//! truncation. Decoding straight from the byte slice is also several times
//! faster than hound's per-sample iterator, which matters for hour-long
//! recordings. Writing uses `hound` (correct and well kept).
//!
//! Supported: PCM (format tag 1) 16/24/32-bit integer, IEEE float (tag 3)
//! 32-bit, and `WAVE_FORMAT_EXTENSIBLE` (tag 0xFFFE) with either subformat;
//! any number of channels; unknown chunks (`LIST`, `bext`, `guan`, `fact`, …)
//! are skipped, pad bytes included.

use crate::error::AudioError;
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
            other => {
                Err(AudioError::InvalidParam { field: "bits", reason: format!("{other:?}: use 16, 24, 32 or f32") })
            }
        }
    }
}

/// A decoded recording: one `f32` vector per channel, full scale = ±1.
#[derive(Debug, Clone)]
pub struct Recording {
    /// Sampling rate (Hz).
    pub sample_rate_hz: u32,
    /// Sample format (as read from the file, or to write).
    pub format: SampleFormat,
    /// Samples per channel, scaled to full scale ±1.
    pub channels: Vec<Vec<f32>>,
    /// Samples at (or beyond) full scale, over all channels: a sign the
    /// recorder's gain was too high.
    pub clipped_samples: usize,
}

impl Recording {
    /// Samples per channel.
    pub fn len_samples(&self) -> usize {
        self.channels.first().map_or(0, Vec::len)
    }
    /// Duration (s): samples per channel over the sampling rate.
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

/// Highest sample rate accepted from a WAV header (Hz): above every audio
/// and bat recorder (AudioMoth: 384 kHz). A header claiming 4294967295 Hz
/// made `range` ask for 38 GB (issue 8, item 8).
pub const MAX_SAMPLE_RATE_HZ: u32 = 1_000_000;
/// Most channels accepted from a WAV header (microphone arrays have tens).
pub const MAX_CHANNELS: u16 = 256;

fn le_u16(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}
fn le_u32(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

fn sample_format(tag: u16, bits: u16) -> Result<SampleFormat, AudioError> {
    match (tag, bits) {
        (1, b @ (16 | 24 | 32)) => Ok(SampleFormat::Int(b)),
        (3, 32) => Ok(SampleFormat::Float32),
        (1, b) => Err(AudioError::Unsupported(format!("{b}-bit integer PCM"))),
        (3, b) => Err(AudioError::Unsupported(format!("{b}-bit float"))),
        (t, _) => Err(AudioError::Unsupported(format!("format tag {t:#06x} (compressed or unknown)"))),
    }
}

/// The fmt chunk's format, channel count and sample rate checked against
/// what we read (both the whole-file reader and [`WavStream`]).
fn check_fmt(tag: u16, n_ch: u16, rate: u32, bits: u16) -> Result<(SampleFormat, usize), AudioError> {
    let format = sample_format(tag, bits)?;
    let n_ch = usize::from(n_ch);
    if n_ch == 0 {
        return Err(AudioError::NotWav("zero channels".into()));
    }
    if rate == 0 {
        return Err(AudioError::NotWav("sample rate 0".into()));
    }
    if rate > MAX_SAMPLE_RATE_HZ {
        return Err(AudioError::Unsupported(format!(
            "sample rate {rate} Hz in the header; at most {MAX_SAMPLE_RATE_HZ} Hz is accepted"
        )));
    }
    if n_ch > usize::from(MAX_CHANNELS) {
        return Err(AudioError::Unsupported(format!(
            "{n_ch} channels in the header; at most {MAX_CHANNELS} are accepted"
        )));
    }
    Ok((format, n_ch))
}

/// Decodes a WAV file held in memory. Never panics on any input (fuzzed in
/// `tests/wav.rs`).
pub fn read_wav_bytes(bytes: &[u8]) -> Result<Recording, AudioError> {
    if bytes.len() < 12 {
        if bytes.len() >= 4 && bytes.starts_with(b"RIFF") {
            return Err(AudioError::Truncated(format!("only {} bytes", bytes.len())));
        }
        return Err(AudioError::NotWav("the file does not start with a RIFF/WAVE header".into()));
    }
    if &bytes[0..4] != b"RIFF" || &bytes[8..12] != b"WAVE" {
        let what = if &bytes[0..4] == b"RF64" { "RF64 (64-bit RIFF)" } else { "the file" };
        return Err(AudioError::NotWav(format!("{what} does not start with a RIFF/WAVE header")));
    }
    let mut pos = 12usize;
    let mut fmt: Option<(u16, u16, u32, u16)> = None; // (tag, channels, rate, bits)
    let data = loop {
        let (Some(id), Some(len)) = (bytes.get(pos..pos + 4), le_u32(bytes, pos + 4)) else {
            return Err(match fmt {
                None => AudioError::Truncated("the file ends before a fmt chunk".into()),
                Some(_) => AudioError::Truncated("the file ends before the data chunk".into()),
            });
        };
        let body = pos + 8;
        let len = len as usize;
        match id {
            b"fmt " => {
                let f = bytes
                    .get(body..body + len.min(40))
                    .filter(|f| f.len() >= 16)
                    .ok_or_else(|| AudioError::Truncated("the fmt chunk is cut short".into()))?;
                let mut tag = le_u16(f, 0).unwrap_or(0);
                let channels = le_u16(f, 2).unwrap_or(0);
                let rate = le_u32(f, 4).unwrap_or(0);
                let bits = le_u16(f, 14).unwrap_or(0);
                if tag == 0xFFFE {
                    // Extensible: the subformat GUID starts with the real tag.
                    tag =
                        le_u16(f, 24).ok_or_else(|| AudioError::Truncated("extensible fmt chunk cut short".into()))?;
                }
                fmt = Some((tag, channels, rate, bits));
            }
            b"data" => {
                let Some(f) = fmt else {
                    return Err(AudioError::NotWav("the data chunk comes before any fmt chunk".into()));
                };
                // An unsupported encoding is the more useful message, even if also cut short.
                sample_format(f.0, f.3)?;
                let avail = bytes.len().saturating_sub(body);
                // Recorders that stream write 0 or 0xFFFFFFFF before they know the length.
                let declared = if len == 0 || len == u32::MAX as usize { avail } else { len };
                if declared > avail {
                    return Err(AudioError::Truncated(format!(
                        "the data chunk declares {declared} bytes but the file holds {avail} (the file was cut short)"
                    )));
                }
                break (f, &bytes[body..body + declared]);
            }
            _ => {}
        }
        // Chunks are padded to even length.
        pos = body.saturating_add(len).saturating_add(len & 1);
    };
    let ((tag, n_ch, rate, bits), data) = data;
    let (format, n_ch) = check_fmt(tag, n_ch, rate, bits)?;
    let width = usize::from(bits / 8);
    let frame_bytes = width * n_ch;
    let frames = data.len() / frame_bytes;
    if frames == 0 {
        return Err(AudioError::NotWav("the data chunk holds no complete sample frame".into()));
    }
    // Decoded samples are f32 (4 bytes) whatever the file's width.
    crate::error::check_memory(
        || format!("decoding {frames} frames × {n_ch} channel(s)"),
        (frames as u128) * (n_ch as u128) * 4,
        "split the recording into shorter files",
    )?;
    let mut channels: Vec<Vec<f32>> = (0..n_ch).map(|_| Vec::with_capacity(frames)).collect();
    let mut outs: Vec<(usize, &mut Vec<f32>)> = channels.iter_mut().enumerate().collect();
    let Decoded { clipped, float_peak, non_finite } =
        decode_frames(format, &data[..frames * frame_bytes], n_ch, &mut outs);
    if let Some((at, what)) = non_finite {
        return Err(AudioError::NonFinite { frame: at / n_ch, channel: at % n_ch, what });
    }
    if f64::from(float_peak) > crate::error::MAX_FLOAT_SAMPLE {
        return Err(AudioError::BadScale { peak: float_peak });
    }
    Ok(Recording { sample_rate_hz: rate, format, channels, clipped_samples: clipped })
}

/// Reads a WAV file from disk.
/// Reads no more than the decoded-size cap allows (a 32-bit file decodes to
/// its own size; headers add little), so a huge file is refused before it
/// is read and an endless stream (`/dev/zero`, a FIFO) stops at the cap.
pub fn read_wav(path: &Path) -> Result<Recording, AudioError> {
    use std::io::Read;
    let io = |source| AudioError::Io { path: path.display().to_string(), source };
    let file = std::fs::File::open(path).map_err(io)?;
    let cap = u64::try_from(crate::error::MEMORY_CAP_BYTES).unwrap_or(u64::MAX).saturating_add(1 << 20);
    let too_large = |bytes: u64| {
        crate::error::check_memory(
            || "reading the WAV file".to_string(),
            u128::from(bytes),
            "split the recording into shorter files",
        )
    };
    let meta = file.metadata().map_err(io)?;
    if meta.is_file() && meta.len() > cap {
        too_large(meta.len())?;
    }
    let mut bytes = Vec::new();
    file.take(cap + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > cap {
        too_large(bytes.len() as u64)?;
    }
    read_wav_bytes(&bytes)
}

/// Writes channels (equal length, full scale ±1; values beyond are clipped)
/// as a WAV file in the given format (one [`WavSink`] write).
pub fn write_wav(
    path: &Path,
    sample_rate_hz: u32,
    format: SampleFormat,
    channels: &[&[f32]],
) -> Result<(), AudioError> {
    let frames = channels.first().map_or(0, |c| c.len());
    if channels.iter().any(|c| c.len() != frames) {
        return Err(AudioError::InvalidParam {
            field: "channels",
            reason: "need at least one channel, all of equal length".into(),
        });
    }
    let mut sink = WavSink::create(path, sample_rate_hz, format, channels.len(), frames as u64)?;
    sink.write(channels)?;
    sink.finalize()
}

/// Rounds half away from zero, as `f64::round` does, without a call into
/// the C library and without a branch (the per-sample `round` call was
/// 2.5 % of `synth`'s time, a branchy version 20 %): adding ½ − 2⁻⁵⁴ with
/// x's sign and truncating is exact (LLVM lowers `round` the same way where
/// the CPU can truncate), and `as i64` truncates exactly below 2⁶³. NaN
/// gives 0 and out-of-range values saturate, which the callers' clamps turn
/// into the same samples as `round`'s.
#[inline]
pub(crate) fn round_half_away(x: f64) -> f64 {
    (x + 0.499_999_999_999_999_94f64.copysign(x)) as i64 as f64
}

/// A sample scaled to 16 bits as [`write_wav`] always did,
/// `(v · 32768).round().clamp(−32768, 32767) as i16`, bit for bit: below
/// 2³¹ the truncation is exact, beyond it saturates to a value the clamp
/// maps where the old clamp did, and NaN gives 0 as before.
#[inline]
fn to_i16(v: f32) -> i16 {
    let x = f64::from(v) * 32_768.0;
    ((x + 0.499_999_999_999_999_94f64.copysign(x)) as i32).clamp(-32_768, 32_767) as i16
}

/// A WAV file written block by block (issue 14: `synth` streams): the
/// header is written by `hound` on [`WavSink::create`] and completed by
/// [`WavSink::finalize`]; the bytes are those [`write_wav`] writes for the
/// same samples, whatever the blocks.
pub struct WavSink {
    writer: hound::WavWriter<std::io::BufWriter<std::fs::File>>,
    format: SampleFormat,
    n_channels: usize,
    frames_left: u64,
    path: String,
    /// 16-bit samples of the block being written (reused).
    ints: Vec<i16>,
}

impl std::fmt::Debug for WavSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WavSink").field("path", &self.path).field("frames_left", &self.frames_left).finish()
    }
}

impl WavSink {
    /// Creates `path` for `frames` frames of `n_channels` channels. Refuses
    /// up front a recording whose data would not fit a RIFF file (4 GiB).
    pub fn create(
        path: &Path,
        sample_rate_hz: u32,
        format: SampleFormat,
        n_channels: usize,
        frames: u64,
    ) -> Result<Self, AudioError> {
        if n_channels == 0 || n_channels > usize::from(u16::MAX) {
            return Err(AudioError::InvalidParam {
                field: "channels",
                reason: "need at least one channel, all of equal length".into(),
            });
        }
        let (bits, sample_format) = match format {
            SampleFormat::Int(b) => (b, hound::SampleFormat::Int),
            SampleFormat::Float32 => (32, hound::SampleFormat::Float),
        };
        let data_bytes = u128::from(frames) * n_channels as u128 * u128::from(bits / 8);
        // hound's header is at most 68 bytes (WAVE_FORMAT_EXTENSIBLE).
        if data_bytes + 68 > u128::from(u32::MAX) {
            return Err(AudioError::InvalidParam {
                field: "channels",
                reason: format!(
                    "{frames} frames × {n_channels} channel(s) × {} bytes exceed the 4 GiB a WAV file can hold; \
                     use fewer listeners, fewer or shorter chirps, or 16-bit samples",
                    bits / 8
                ),
            });
        }
        let spec = hound::WavSpec {
            channels: n_channels as u16,
            sample_rate: sample_rate_hz,
            bits_per_sample: bits,
            sample_format,
        };
        let p = path.display().to_string();
        let file = std::fs::File::create(path).map_err(|source| AudioError::Io { path: p.clone(), source })?;
        let writer = hound::WavWriter::new(std::io::BufWriter::with_capacity(1 << 20, file), spec)
            .map_err(|e| AudioError::Write(format!("{p}: {e}")))?;
        Ok(Self { writer, format, n_channels, frames_left: frames, path: p, ints: Vec::new() })
    }

    /// Appends frames: one slice per channel, all of equal length.
    pub fn write(&mut self, channels: &[&[f32]]) -> Result<(), AudioError> {
        let frames = channels.first().map_or(0, |c| c.len());
        if channels.len() != self.n_channels || channels.iter().any(|c| c.len() != frames) {
            return Err(AudioError::InvalidParam {
                field: "channels",
                reason: "need at least one channel, all of equal length".into(),
            });
        }
        if frames as u64 > self.frames_left {
            return Err(AudioError::Write(format!("{}: more frames than declared", self.path)));
        }
        self.frames_left -= frames as u64;
        let path = &self.path;
        let werr = |e: hound::Error| AudioError::Write(format!("{path}: {e}"));
        let w = &mut self.writer;
        match self.format {
            SampleFormat::Int(16) => {
                // Bounded blocks: hound's 16-bit writer buffers what it is
                // asked for. The samples are converted in a loop of their
                // own first (it vectorises), then handed over.
                let ints = &mut self.ints;
                for start in (0..frames).step_by(1 << 16) {
                    let end = (start + (1 << 16)).min(frames);
                    ints.clear();
                    if let [c] = channels {
                        ints.extend(c[start..end].iter().map(|v| to_i16(*v)));
                    } else {
                        ints.extend((start..end).flat_map(|i| channels.iter().map(move |c| to_i16(c[i]))));
                    }
                    let mut w16 = w.get_i16_writer(ints.len() as u32);
                    for v in ints.iter() {
                        w16.write_sample(*v);
                    }
                    w16.flush().map_err(werr)?;
                }
            }
            SampleFormat::Int(b) => {
                let full = 2f64.powi(i32::from(b) - 1);
                for i in 0..frames {
                    for c in channels {
                        w.write_sample(round_half_away(f64::from(c[i]) * full).clamp(-full, full - 1.0) as i32)
                            .map_err(werr)?;
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
        Ok(())
    }

    /// Completes the header; every declared frame must have been written.
    pub fn finalize(self) -> Result<(), AudioError> {
        if self.frames_left != 0 {
            return Err(AudioError::Write(format!("{}: {} frames were never written", self.path, self.frames_left)));
        }
        let path = self.path;
        self.writer.finalize().map_err(|e| AudioError::Write(format!("{path}: {e}")))
    }
}

/// A WAV file read block by block, one channel at a time (issue 14, item 4):
/// the header is parsed once, with [`read_wav_bytes`]'s checks and messages,
/// and the samples are decoded as they are read, so that an hour or ten of
/// audio never has to be held in memory.
#[derive(Debug)]
pub struct WavStream {
    reader: std::io::BufReader<std::fs::File>,
    /// Sampling rate (Hz).
    pub sample_rate_hz: u32,
    /// Sample format of the file.
    pub format: SampleFormat,
    /// Channels in the file.
    pub n_channels: usize,
    /// Frames (samples per channel) in the data chunk.
    pub frames: usize,
    channel: usize,
    frames_read: usize,
    clipped: usize,
    float_peak: f32,
    raw: Vec<u8>,
    /// Byte offset of the first sample in the file.
    data_start: u64,
}

impl WavStream {
    /// Opens `path` and parses its header; `channel` is the one decoded.
    pub fn open(path: &Path, channel: usize) -> Result<Self, AudioError> {
        use std::io::{Read, Seek, SeekFrom};
        let io = |source| AudioError::Io { path: path.display().to_string(), source };
        let file = std::fs::File::open(path).map_err(io)?;
        let meta = file.metadata().map_err(io)?;
        // A pipe (`<(cat rec.wav)`, /dev/stdin) cannot be read a second time
        // or sought in: say so, rather than fail later with "Illegal seek".
        if !meta.is_file() {
            return Err(io(std::io::Error::other(
                "not a regular file: the recording is read in blocks and parts of it again, which needs a file \
                 (a pipe or /dev/stdin cannot be sought in); save it to a file first",
            )));
        }
        let file_len = meta.len();
        let mut reader = std::io::BufReader::with_capacity(1 << 20, file);
        // Reads up to `n` bytes at the current position (fewer at the end of the file).
        let take = |r: &mut std::io::BufReader<std::fs::File>, n: usize| -> Result<Vec<u8>, AudioError> {
            let mut v = Vec::with_capacity(n);
            r.by_ref().take(n as u64).read_to_end(&mut v).map_err(io)?;
            Ok(v)
        };
        let head = take(&mut reader, 12)?;
        if head.len() < 12 {
            if head.len() >= 4 && head.starts_with(b"RIFF") {
                return Err(AudioError::Truncated(format!("only {} bytes", head.len())));
            }
            return Err(AudioError::NotWav("the file does not start with a RIFF/WAVE header".into()));
        }
        if &head[0..4] != b"RIFF" || &head[8..12] != b"WAVE" {
            let what = if &head[0..4] == b"RF64" { "RF64 (64-bit RIFF)" } else { "the file" };
            return Err(AudioError::NotWav(format!("{what} does not start with a RIFF/WAVE header")));
        }
        let mut pos = 12u64;
        let mut fmt: Option<(u16, u16, u32, u16)> = None;
        let (data_start, data_len) = loop {
            reader.seek(SeekFrom::Start(pos)).map_err(io)?;
            let ch = take(&mut reader, 8)?;
            let (Some(id), Some(len)) = (ch.get(0..4), le_u32(&ch, 4)) else {
                return Err(match fmt {
                    None => AudioError::Truncated("the file ends before a fmt chunk".into()),
                    Some(_) => AudioError::Truncated("the file ends before the data chunk".into()),
                });
            };
            let body = pos + 8;
            let len = u64::from(len);
            match id {
                b"fmt " => {
                    let f = take(&mut reader, len.min(40) as usize)?;
                    if f.len() < 16 || (f.len() as u64) < len.min(40) {
                        return Err(AudioError::Truncated("the fmt chunk is cut short".into()));
                    }
                    let mut tag = le_u16(&f, 0).unwrap_or(0);
                    let channels = le_u16(&f, 2).unwrap_or(0);
                    let rate = le_u32(&f, 4).unwrap_or(0);
                    let bits = le_u16(&f, 14).unwrap_or(0);
                    if tag == 0xFFFE {
                        tag = le_u16(&f, 24)
                            .ok_or_else(|| AudioError::Truncated("extensible fmt chunk cut short".into()))?;
                    }
                    fmt = Some((tag, channels, rate, bits));
                }
                b"data" => {
                    let Some(f) = fmt else {
                        return Err(AudioError::NotWav("the data chunk comes before any fmt chunk".into()));
                    };
                    sample_format(f.0, f.3)?;
                    let avail = file_len.saturating_sub(body);
                    let declared = if len == 0 || len == u64::from(u32::MAX) { avail } else { len };
                    if declared > avail {
                        return Err(AudioError::Truncated(format!(
                            "the data chunk declares {declared} bytes but the file holds {avail} (the file was cut short)"
                        )));
                    }
                    break (body, declared);
                }
                _ => {}
            }
            pos = body.saturating_add(len).saturating_add(len & 1);
        };
        let Some((tag, n_ch, rate, bits)) = fmt else {
            return Err(AudioError::NotWav("the data chunk comes before any fmt chunk".into()));
        };
        let (format, n_ch) = check_fmt(tag, n_ch, rate, bits)?;
        let frame_bytes = usize::from(bits / 8) * n_ch;
        let frames = usize::try_from(data_len / frame_bytes as u64).unwrap_or(usize::MAX);
        if frames == 0 {
            return Err(AudioError::NotWav("the data chunk holds no complete sample frame".into()));
        }
        if channel >= n_ch {
            return Err(AudioError::NoSuchChannel { requested: channel, available: n_ch });
        }
        Ok(Self {
            reader,
            sample_rate_hz: rate,
            format,
            n_channels: n_ch,
            frames,
            channel,
            frames_read: 0,
            clipped: 0,
            float_peak: 0.0,
            raw: Vec::new(),
            data_start,
        })
    }

    /// Continues reading at frame `frame` (at most [`WavStream::frames`]).
    pub fn seek_frame(&mut self, frame: usize) -> Result<(), AudioError> {
        use std::io::{Seek, SeekFrom};
        let frame = frame.min(self.frames);
        let width = match self.format {
            SampleFormat::Int(b) => u64::from(b / 8),
            SampleFormat::Float32 => 4,
        };
        let at = self.data_start + frame as u64 * width * self.n_channels as u64;
        self.reader
            .seek(SeekFrom::Start(at))
            .map_err(|e| AudioError::Truncated(format!("cannot seek to frame {frame} ({e})")))?;
        self.frames_read = frame;
        Ok(())
    }

    /// Samples at (or beyond) full scale so far, over all channels (as
    /// [`Recording::clipped_samples`] once the whole file is read).
    pub fn clipped_samples(&self) -> usize {
        self.clipped
    }

    /// Appends up to `max_frames` samples of the channel to `out` (full
    /// scale ±1, decoded exactly as [`read_wav_bytes`] does) and returns how
    /// many; 0 at the end of the data. At the end, a float file whose peak
    /// shows it is not scaled to ±1 is refused as [`read_wav_bytes`] refuses it.
    pub fn read_block(&mut self, out: &mut Vec<f32>, max_frames: usize) -> Result<usize, AudioError> {
        use std::io::Read;
        let n = max_frames.min(self.frames - self.frames_read);
        if n == 0 {
            if f64::from(self.float_peak) > crate::error::MAX_FLOAT_SAMPLE {
                return Err(AudioError::BadScale { peak: self.float_peak });
            }
            return Ok(0);
        }
        let width = match self.format {
            SampleFormat::Int(b) => usize::from(b / 8),
            SampleFormat::Float32 => 4,
        };
        let frame_bytes = width * self.n_channels;
        self.raw.resize(n * frame_bytes, 0);
        self.reader
            .read_exact(&mut self.raw)
            .map_err(|e| AudioError::Truncated(format!("the data chunk ends early while reading ({e})")))?;
        self.frames_read += n;
        out.reserve(n);
        // The same decoding as read_wav_bytes.
        let first = self.frames_read - n;
        let Decoded { clipped, float_peak, non_finite } =
            decode_frames(self.format, &self.raw, self.n_channels, &mut [(self.channel, out)]);
        if let Some((at, what)) = non_finite {
            let channel = at % self.n_channels;
            return Err(AudioError::NonFinite { frame: first + at / self.n_channels, channel, what });
        }
        self.clipped += clipped;
        self.float_peak = self.float_peak.max(float_peak);
        Ok(n)
    }
}

/// What [`decode_frames`] found besides the samples.
struct Decoded {
    /// Samples at full scale, over every channel.
    clipped: usize,
    /// Largest |value| of the float samples (0 for integer formats), which
    /// tells a float file not scaled to ±1.
    float_peak: f32,
    /// The first non-finite float sample: its index in the block (frame ×
    /// channels + channel) and `NaN`, `inf` or `-inf`. The caller refuses
    /// the file, so the values decoded for it do not matter.
    non_finite: Option<(usize, &'static str)>,
}

/// Decodes whole frames of `n_ch` samples in `format`: for each `(c, out)`
/// of `outs`, appends channel `c`'s samples to `out` (full scale ±1). One
/// loop per encoding (the match is outside the loops), and values and counts
/// in loops of their own: together, the count's update through a reference
/// kept the loop scalar (8 % of `range`'s CPU on a 16-bit file); apart, each
/// vectorises.
fn decode_frames(format: SampleFormat, raw: &[u8], n_ch: usize, outs: &mut [(usize, &mut Vec<f32>)]) -> Decoded {
    fn each<const W: usize>(
        raw: &[u8],
        n_ch: usize,
        outs: &mut [(usize, &mut Vec<f32>)],
        value: impl Fn([u8; W]) -> f32,
        clipped: impl Fn([u8; W]) -> bool,
    ) -> usize {
        for (c, out) in outs.iter_mut() {
            // Written once, not zero-filled first (an exact-size extend);
            // mono on its own, where a constant stride lets the loop vectorise.
            if n_ch == 1 {
                out.extend(raw.chunks_exact(W).map(|s| value(sample_bytes(s))));
            } else {
                let at = *c * W..(*c + 1) * W;
                out.extend(raw.chunks_exact(W * n_ch).map(|frame| value(sample_bytes(&frame[at.clone()]))));
            }
        }
        raw.chunks_exact(W).filter(|s| clipped(sample_bytes(s))).count()
    }
    let int24 = |s: [u8; 3]| i32::from_le_bytes([0, s[0], s[1], s[2]]) >> 8;
    let ints = |clipped| Decoded { clipped, float_peak: 0.0, non_finite: None };
    match format {
        SampleFormat::Int(16) => ints(each::<2>(
            raw,
            n_ch,
            outs,
            |s| f32::from(i16::from_le_bytes(s)) / 32_768.0,
            |s| matches!(i16::from_le_bytes(s), i16::MAX | i16::MIN),
        )),
        SampleFormat::Int(24) => ints(each::<3>(
            raw,
            n_ch,
            outs,
            |s| int24(s) as f32 / 8_388_608.0,
            |s| matches!(int24(s), 8_388_607 | -8_388_608),
        )),
        SampleFormat::Int(_) => ints(each::<4>(
            raw,
            n_ch,
            outs,
            |s| (f64::from(i32::from_le_bytes(s)) / 2_147_483_648.0) as f32,
            |s| matches!(i32::from_le_bytes(s), i32::MAX | i32::MIN),
        )),
        SampleFormat::Float32 => {
            let float = |s: &[u8]| f32::from_le_bytes(sample_bytes(s));
            // |NaN| is NaN, which `max` skips: count it as infinite, so one
            // pass finds the peak and whether any sample is not finite.
            let peak = raw
                .chunks_exact(4)
                .map(|s| float(s).abs())
                .fold(0.0f32, |p, a| p.max(if a.is_nan() { f32::INFINITY } else { a }));
            if peak == f32::INFINITY {
                let found = raw.chunks_exact(4).map(float).enumerate().find(|(_, f)| !f.is_finite());
                if let Some((at, f)) = found {
                    let what = if f.is_nan() {
                        "NaN"
                    } else if f > 0.0 {
                        "inf"
                    } else {
                        "-inf"
                    };
                    return Decoded { clipped: 0, float_peak: peak, non_finite: Some((at, what)) };
                }
            }
            let clipped = each::<4>(raw, n_ch, outs, f32::from_le_bytes, |s| f32::from_le_bytes(s).abs() >= 1.0);
            Decoded { clipped, float_peak: peak, non_finite: None }
        }
    }
}

/// One sample's bytes (`s.len() == W`, as `chunks_exact(W)` gives them).
#[inline]
fn sample_bytes<const W: usize>(s: &[u8]) -> [u8; W] {
    let mut b = [0u8; W];
    b.copy_from_slice(s);
    b
}
