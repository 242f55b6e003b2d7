//! The synthesizer in constant memory (issue 14): any length of recording,
//! sample for sample what [`super::synthesize`] returns.
//!
//! [`super::synthesize`] needs two statistics of the whole recording before
//! its first sample is final: the power of each noiseless channel (it sets
//! the noise level) and the peak of the noisy channels (it sets the output
//! gain). Here each noiseless channel is rendered once, chunk by chunk, into
//! a scratch file of `f32` samples (4 bytes × samples × listeners) while
//! its power is summed in the same order; the noise is then added in place
//! while the peak is taken, and a last read scales the samples and hands
//! them on. Rendering (the sines) is the costly part and is done once; the
//! scratch file is read twice and written twice.

use super::{Renderer, SynthConfig, accumulate_power, noise_rng, noise_sigma};
use crate::error::AudioError;
use chirpmap_core::Scene;
use rand_distr::{Distribution, StandardNormal};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Frames per chunk (a multiple of [`super::POSE_BLOCK`]): 256 KiB of
/// `f32` per listener.
pub const CHUNK_FRAMES: usize = 1 << 16;

/// A rendering checked and ready to stream (see [`synthesize_streamed`]).
#[derive(Debug)]
pub struct SynthStream<'a> {
    renderer: Renderer<'a>,
    scene: &'a Scene,
    cfg: &'a SynthConfig,
}

impl<'a> SynthStream<'a> {
    /// Checks `scene` and `cfg` as [`super::synthesize`] does (but for its
    /// memory cap: nothing here grows with the recording).
    pub fn new(scene: &'a Scene, cfg: &'a SynthConfig) -> Result<Self, AudioError> {
        scene.validate()?;
        cfg.validate()?;
        Ok(Self { renderer: Renderer::new(scene, cfg)?, scene, cfg })
    }

    /// Samples per channel.
    pub fn frames(&self) -> usize {
        self.renderer.len_samples()
    }

    /// Channels (one per listener).
    pub fn n_channels(&self) -> usize {
        self.scene.listeners.len()
    }

    /// Sampling rate (Hz).
    pub fn sample_rate_hz(&self) -> u32 {
        self.cfg.sample_rate_hz
    }

    /// Renders, handing the final samples to `emit` (see [`synthesize_streamed`]).
    pub fn run(&self, scratch: &Path, emit: impl FnMut(&[&[f32]]) -> Result<(), AudioError>) -> Result<(), AudioError> {
        run(&self.renderer, self.scene, self.cfg, scratch, emit)
    }
}

/// The scratch file, removed when dropped (on success and on every error).
struct Scratch {
    file: File,
    path: PathBuf,
}

impl Drop for Scratch {
    fn drop(&mut self) {
        std::fs::remove_file(&self.path).ok();
    }
}

impl Scratch {
    fn io(&self, source: std::io::Error) -> AudioError {
        AudioError::Io { path: self.path.display().to_string(), source }
    }

    fn seek(&mut self, sample: usize) -> Result<(), AudioError> {
        self.file.seek(SeekFrom::Start(sample as u64 * 4)).map(|_| ()).map_err(|e| self.io(e))
    }

    fn write(&mut self, at: usize, y: &[f32], bytes: &mut Vec<u8>) -> Result<(), AudioError> {
        bytes.resize(y.len() * 4, 0);
        for (b, v) in bytes.chunks_exact_mut(4).zip(y) {
            b.copy_from_slice(&v.to_le_bytes());
        }
        self.seek(at)?;
        self.file.write_all(bytes).map_err(|e| self.io(e))
    }

    fn read(&mut self, at: usize, y: &mut [f32], bytes: &mut Vec<u8>) -> Result<(), AudioError> {
        bytes.resize(y.len() * 4, 0);
        self.seek(at)?;
        self.file.read_exact(bytes).map_err(|e| self.io(e))?;
        for (v, b) in y.iter_mut().zip(bytes.chunks_exact(4)) {
            *v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        Ok(())
    }
}

/// Renders what [`super::synthesize`] renders, for any length, in memory
/// that does not grow with the recording: `emit` receives consecutive runs
/// of frames (one slice per listener, at most [`CHUNK_FRAMES`] each), the
/// final samples, equal bit for bit to [`super::synthesize`]'s channels.
/// `scratch` is a new file the function creates (it refuses an existing
/// one) and removes before it returns: 4 bytes × samples × listeners.
/// The poses are [`super::listener_poses`].
pub fn synthesize_streamed(
    scene: &Scene,
    cfg: &SynthConfig,
    scratch: &Path,
    emit: impl FnMut(&[&[f32]]) -> Result<(), AudioError>,
) -> Result<(), AudioError> {
    SynthStream::new(scene, cfg)?.run(scratch, emit)
}

fn run(
    r: &Renderer<'_>,
    scene: &Scene,
    cfg: &SynthConfig,
    scratch: &Path,
    mut emit: impl FnMut(&[&[f32]]) -> Result<(), AudioError>,
) -> Result<(), AudioError> {
    let (n, n_l) = (r.len_samples(), scene.listeners.len());
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .open(scratch)
        .map_err(|source| AudioError::Io { path: scratch.display().to_string(), source })?;
    let mut s = Scratch { file, path: scratch.to_path_buf() };
    let chunks = n.div_ceil(CHUNK_FRAMES);
    let span = |c: usize| (c * CHUNK_FRAMES, ((c + 1) * CHUNK_FRAMES).min(n));
    let mut bytes = Vec::with_capacity(CHUNK_FRAMES * 4);
    let mut y = vec![0.0f32; CHUNK_FRAMES];
    // Pass 1: the noiseless channels, their power and their peak.
    let mut sigma = Vec::with_capacity(n_l);
    let mut peak = 0.0f32;
    for li in 0..n_l {
        let mut acc = (0.0, 0);
        for c in 0..chunks {
            let (a, b) = span(c);
            let y = &mut y[..b - a];
            y.fill(0.0);
            r.render(li, a, y);
            accumulate_power(y, &mut acc);
            s.write(li * n + a, y, &mut bytes)?;
        }
        sigma.push(noise_sigma(cfg, acc.0, acc.1));
    }
    // Pass 2: the noise, added in place, and the peak of every channel.
    for (li, sg) in sigma.iter().enumerate() {
        let mut rng = sg.map(|_| noise_rng(cfg, li));
        for c in 0..chunks {
            let (a, b) = span(c);
            let y = &mut y[..b - a];
            s.read(li * n + a, y, &mut bytes)?;
            if let (Some(sigma), Some(rng)) = (sg, rng.as_mut()) {
                for v in y.iter_mut() {
                    let g: f32 = StandardNormal.sample(rng);
                    *v += sigma * g;
                }
                s.write(li * n + a, y, &mut bytes)?;
            }
            peak = y.iter().fold(peak, |m, v| m.max(v.abs()));
        }
    }
    // Pass 3: scaled to the peak, frame runs of every channel in order.
    let gain = (peak > 0.0).then(|| cfg.peak as f32 / peak);
    let mut bufs = vec![vec![0.0f32; CHUNK_FRAMES]; n_l];
    for c in 0..chunks {
        let (a, b) = span(c);
        for (li, buf) in bufs.iter_mut().enumerate() {
            let buf = &mut buf[..b - a];
            s.read(li * n + a, buf, &mut bytes)?;
            if let Some(g) = gain {
                for v in buf.iter_mut() {
                    *v *= g;
                }
            }
        }
        let slices: Vec<&[f32]> = bufs.iter().map(|b| &b[..span(c).1 - span(c).0]).collect();
        emit(&slices)?;
    }
    Ok(())
}
