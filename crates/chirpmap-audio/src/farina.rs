//! Sweep waveforms of any shape and their deconvolution kernels (issue 10,
//! item 4): the matched filter for a linear sweep, Farina's inverse filter
//! for an exponential one.
//!
//! Farina (2000), "Simultaneous measurement of impulse response and
//! distortion with a swept-sine technique", AES 108th Convention: an
//! exponential sweep spends a time proportional to 1/f in each band, so its
//! energy spectrum falls 3 dB per octave. Correlating with the sweep itself
//! gives an impulse response tilted toward low frequencies; weighting the
//! correlation kernel by the instantaneous frequency, `f(t)/f_max`
//! (+6 dB/octave in amplitude), whitens it. The harmonic distortion of the
//! loudspeaker then separates from the linear response in time: the n-th
//! harmonic's response appears `T·ln(n)/ln(f_hi/f_lo)` away from the linear
//! one (before it for an up-sweep, after it for a down-sweep).
//!
//! For a linear sweep the energy spectrum is flat in band, the kernel is the
//! sweep itself, and the result is the matched filter of the ranging
//! module.

use crate::detect::{ChirpTemplate, MIN_TEMPLATE_SAMPLES, taper_gain};
use crate::error::AudioError;
use chirpmap_core::LinearChirp;
use chirpmap_core::scene::SweepKind;

/// A sweep sampled at the recorder's rate, with its deconvolution kernel.
#[derive(Debug, Clone)]
pub struct SweepKernel {
    /// Shape of the sweep.
    pub kind: SweepKind,
    /// Start frequency (Hz).
    pub f_start_hz: f64,
    /// End frequency (Hz).
    pub f_end_hz: f64,
    /// Duration T (s).
    pub duration_s: f64,
    /// Sampling rate (Hz).
    pub sample_rate_hz: f64,
    /// The emitted waveform, `taper · sin(2π φ(t))` (what `synth` renders).
    pub waveform: Vec<f32>,
    /// Correlation kernel: the waveform weighted by `|f'(t)|/max|f'|`, which
    /// is 1 for a linear sweep and `f(t)/f_max` for an exponential one
    /// (Farina's inverse filter, time-reversed for correlation instead of
    /// convolution).
    pub kernel: Vec<f32>,
}

impl SweepKernel {
    /// Samples `kind` from `f_start_hz` to `f_end_hz` over `duration_s` at
    /// `sample_rate_hz` with the default 5 ms raised-cosine taper. Errors
    /// name the parameter: an invalid sweep, a sweep reaching the Nyquist
    /// frequency, or a template shorter than [`MIN_TEMPLATE_SAMPLES`].
    pub fn new(
        kind: SweepKind,
        f_start_hz: f64,
        f_end_hz: f64,
        duration_s: f64,
        sample_rate_hz: f64,
    ) -> Result<Self, AudioError> {
        let spec = chirpmap_core::scene::ChirpSpec { f_start: f_start_hz, f_end: f_end_hz, duration: duration_s, kind };
        let sweep = spec.build()?;
        // The same checks as the linear template (Nyquist, rate, memory, length).
        let lin = ChirpTemplate::new(LinearChirp::new(f_start_hz, f_end_hz, duration_s)?, sample_rate_hz)?;
        let n = lin.len();
        if n < MIN_TEMPLATE_SAMPLES {
            return Err(AudioError::InvalidParam { field: "chirp duration", reason: format!("{n} samples") });
        }
        // Whitening weight ∝ |df/dt| (energy per Hz ∝ dt/df): constant for a
        // linear sweep, ∝ f for an exponential one (Farina's +6 dB/octave).
        let dt = 1.0 / sample_rate_hz;
        let slope = |t: f64| {
            let (a, b) = ((t - 0.5 * dt).max(0.0), (t + 0.5 * dt).min(duration_s));
            match (sweep.freq_at(a), sweep.freq_at(b)) {
                (Some(fa), Some(fb)) if b > a => ((fb - fa) / (b - a)).abs(),
                _ => 0.0,
            }
        };
        let slope_max = (0..=64).map(|k| slope(duration_s * f64::from(k) / 64.0)).fold(0.0f64, f64::max);
        let mut waveform = Vec::with_capacity(n);
        let mut kernel = Vec::with_capacity(n);
        for i in 0..n {
            let t = i as f64 / sample_rate_hz;
            let ph = sweep.phase_cycles(t);
            let s = taper_gain(t, duration_s, crate::detect::DEFAULT_TAPER_S)
                * (std::f64::consts::TAU * (ph - ph.floor())).sin();
            waveform.push(s as f32);
            let w = if kind == SweepKind::Linear || slope_max <= 0.0 { 1.0 } else { slope(t) / slope_max };
            kernel.push((s * w) as f32);
        }
        Ok(Self { kind, f_start_hz, f_end_hz, duration_s, sample_rate_hz, waveform, kernel })
    }

    /// Length in samples.
    pub fn len(&self) -> usize {
        self.waveform.len()
    }

    /// Whether the kernel has no samples (never, once built).
    pub fn is_empty(&self) -> bool {
        self.waveform.is_empty()
    }

    /// A template for [`crate::detect::detect_chirps`], which correlates with
    /// `real` and reads only the duration and rate of `chirp`: the waveform
    /// of this sweep (linear or not) in a linear chirp's frame of the same
    /// band and duration. `mix` (used only by dechirping) is left empty.
    pub fn detection_template(&self) -> Result<ChirpTemplate, AudioError> {
        Ok(ChirpTemplate {
            chirp: LinearChirp::new(self.f_start_hz, self.f_end_hz, self.duration_s)?,
            sample_rate_hz: self.sample_rate_hz,
            real: self.waveform.clone(),
            mix: Vec::new(),
        })
    }

    /// Delay (s) between the linear impulse response and the 2nd harmonic's
    /// for an exponential sweep, `T·ln 2/ln(f_hi/f_lo)`; `None` for a
    /// linear sweep (its harmonics smear over the whole sweep instead).
    pub fn harmonic_lag_s(&self) -> Option<f64> {
        if self.kind != SweepKind::Exponential {
            return None;
        }
        let r = (self.f_start_hz / self.f_end_hz).ln().abs();
        (r > 0.0).then(|| self.duration_s * std::f64::consts::LN_2 / r)
    }

    /// Whether the 2nd harmonic's response comes after the linear one (a
    /// down-sweep), where an echo search would meet it.
    pub fn harmonics_follow(&self) -> bool {
        self.kind == SweepKind::Exponential && self.f_start_hz > self.f_end_hz
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Magnitude of the DFT of `x` at `f` (Hz), by direct summation (the oracle).
    fn dft_mag(x: &[f32], f: f64, fs: f64) -> f64 {
        let (mut re, mut im) = (0.0f64, 0.0f64);
        for (n, v) in x.iter().enumerate() {
            let ph = std::f64::consts::TAU * f * n as f64 / fs;
            re += f64::from(*v) * ph.cos();
            im -= f64::from(*v) * ph.sin();
        }
        re.hypot(im)
    }

    #[test]
    fn farina_kernel_whitens_an_exponential_sweep() {
        // |S(f)|·|K(f)| is the spectrum of the deconvolved impulse: flat in
        // band for Farina's kernel (within 1.5 dB between 500 Hz and 4 kHz),
        // tilted by about 3 dB/octave (≈ 9 dB over 3 octaves) for the sweep alone.
        let fs = 16_000.0;
        let k = SweepKernel::new(SweepKind::Exponential, 6000.0, 200.0, 0.5, fs).unwrap();
        let band = [500.0, 1000.0, 2000.0, 4000.0];
        let flat: Vec<f64> =
            band.iter().map(|&f| 20.0 * (dft_mag(&k.waveform, f, fs) * dft_mag(&k.kernel, f, fs)).log10()).collect();
        let tilt: Vec<f64> = band.iter().map(|&f| 20.0 * (dft_mag(&k.waveform, f, fs).powi(2)).log10()).collect();
        let spread = |v: &[f64]| v.iter().fold(f64::MIN, |m, x| m.max(*x)) - v.iter().fold(f64::MAX, |m, x| m.min(*x));
        assert!(spread(&flat) < 1.5, "Farina: {flat:?}");
        assert!(spread(&tilt) > 7.0, "matched only: {tilt:?}");
    }

    #[test]
    fn linear_kernel_is_the_waveform_and_the_harmonic_lag_follows_farina() {
        let k = SweepKernel::new(SweepKind::Linear, 10_000.0, 200.0, 0.25, 48_000.0).unwrap();
        assert_eq!(k.kernel, k.waveform);
        assert_eq!(k.harmonic_lag_s(), None);
        let e = SweepKernel::new(SweepKind::Exponential, 10_000.0, 200.0, 1.0, 48_000.0).unwrap();
        // T ln2 / ln(50) = 0.17718 s (hand computation).
        assert!((e.harmonic_lag_s().unwrap() - 0.177_184).abs() < 1e-5);
        assert!(e.harmonics_follow());
        assert!(SweepKernel::new(SweepKind::Exponential, 30_000.0, 200.0, 1.0, 48_000.0).is_err());
    }
}
