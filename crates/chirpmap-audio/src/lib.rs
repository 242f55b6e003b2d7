//! Audio pipeline of chirpmap (issue 5; paper §IV field experiment): WAV
//! I/O, the paper's filters, FFT/STFT, chirp detection by matched filter,
//! three ranging methods (the paper's frequency gap, matched filtering,
//! dechirping), frame-wise echo extraction for moving listeners, and an
//! image-source waveform synthesizer. No printing.

#![warn(missing_docs)]

pub mod detect;
pub mod doppler;
pub mod echoes;
pub mod error;
pub mod farina;
pub mod filter;
pub mod frames;
pub mod ranging;
pub mod rir;
pub mod spectrum;
pub mod stats;
pub mod stream;
pub mod synth;
pub mod wav;

pub use detect::{ChirpTemplate, Detection, detect_chirps};
pub use error::AudioError;
pub use ranging::{Estimate, Method, RangeLimits, Ranger, wall_distance_m};
pub use synth::{SynthConfig, synthesize};
pub use wav::{Recording, SampleFormat, read_wav, read_wav_bytes, write_wav};

#[cfg(test)]
pub(crate) mod test_rng {
    /// Marsaglia's xorshift64 (2003), seeded with a non-zero `r`: the unit
    /// tests' deterministic random cases.
    pub(crate) fn xorshift(mut r: u64) -> impl FnMut() -> u64 {
        move || {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            r
        }
    }
}
