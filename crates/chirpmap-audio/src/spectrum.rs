//! FFT helpers (rustfft; realfft for real input), windows, STFT and sub-bin
//! peak interpolation.

use realfft::{RealFftPlanner, RealToComplex};
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::collections::HashMap;
use std::sync::Arc;

/// Caches FFT plans by size and direction; one per thread of work.
pub struct FftCache {
    planner: FftPlanner<f32>,
    plans: HashMap<(usize, bool), Arc<dyn Fft<f32>>>,
    /// Real-to-complex plans (realfft packs a real frame of n samples into an
    /// n/2-point complex FFT: about half the work of a complex FFT of n).
    real_planner: RealFftPlanner<f32>,
    real_plans: HashMap<usize, Arc<dyn RealToComplex<f32>>>,
    windows: HashMap<usize, Arc<Vec<f32>>>,
    /// [`magnitude_bins`]' input, output and scratch buffers, reused from
    /// frame to frame (the gap method runs two per frame, 24 frames a chirp).
    real_in: Vec<f32>,
    real_out: Vec<Complex32>,
    real_scratch: Vec<Complex32>,
    /// Scratch of the complex plans, reused: `Fft::process` allocates and
    /// zeroes a fresh one per call (512 KB per matched-filter chirp at
    /// 48 kHz), and the transform's values do not depend on its contents.
    scratch: Vec<Complex32>,
}

impl std::fmt::Debug for FftCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FftCache").field("plans", &self.plans.len()).finish()
    }
}

impl Default for FftCache {
    fn default() -> Self {
        Self {
            planner: FftPlanner::new(),
            plans: HashMap::new(),
            real_planner: RealFftPlanner::new(),
            real_plans: HashMap::new(),
            windows: HashMap::new(),
            real_in: Vec::new(),
            real_out: Vec::new(),
            real_scratch: Vec::new(),
            scratch: Vec::new(),
        }
    }
}

impl FftCache {
    /// Complex FFT plan of size `n` (inverse if `inverse`), created once and cached.
    pub fn plan(&mut self, n: usize, inverse: bool) -> Arc<dyn Fft<f32>> {
        let planner = &mut self.planner;
        self.plans
            .entry((n, inverse))
            .or_insert_with(|| if inverse { planner.plan_fft_inverse(n) } else { planner.plan_fft_forward(n) })
            .clone()
    }
    /// Forward real-to-complex plan of size `n` (output bins 0..=n/2).
    pub fn plan_real(&mut self, n: usize) -> Arc<dyn RealToComplex<f32>> {
        let planner = &mut self.real_planner;
        self.real_plans.entry(n).or_insert_with(|| planner.plan_fft_forward(n)).clone()
    }
    /// Hann window of `n` samples, computed once.
    pub fn hann(&mut self, n: usize) -> Arc<Vec<f32>> {
        self.windows.entry(n).or_insert_with(|| Arc::new(hann(n))).clone()
    }
    /// In-place forward FFT of `buf` (unnormalised).
    pub fn forward(&mut self, buf: &mut [Complex32]) {
        self.process(buf, false);
    }
    /// In-place inverse FFT of `buf` (unnormalised: scale by 1/n yourself).
    pub fn inverse(&mut self, buf: &mut [Complex32]) {
        self.process(buf, true);
    }
    /// Bins 0..=n/2 of the forward FFT of `samples` zero-padded (or cut) to
    /// `n` values, by a real-input FFT in the cache's reused buffers. `None`
    /// only if realfft rejects the buffers, which are sized from its plan.
    pub fn forward_real(&mut self, samples: impl IntoIterator<Item = f32>, n: usize) -> Option<&[Complex32]> {
        let plan = self.plan_real(n);
        let (input, out, scratch) = (&mut self.real_in, &mut self.real_out, &mut self.real_scratch);
        // Every value is written again each time: the FFT uses its input as
        // scratch.
        input.clear();
        input.extend(samples.into_iter().take(n));
        input.resize(n, 0.0);
        out.resize(n / 2 + 1, Complex32::new(0.0, 0.0));
        scratch.resize(plan.get_scratch_len(), Complex32::new(0.0, 0.0));
        plan.process_with_scratch(input, out, scratch).ok()?;
        Some(out)
    }
    fn process(&mut self, buf: &mut [Complex32], inverse: bool) {
        let plan = self.plan(buf.len(), inverse);
        let need = plan.get_inplace_scratch_len();
        if self.scratch.len() < need {
            self.scratch.resize(need, Complex32::new(0.0, 0.0));
        }
        plan.process_with_scratch(buf, &mut self.scratch[..need]);
    }
}

/// Periodic-free (symmetric) Hann window of `n` samples.
pub fn hann(n: usize) -> Vec<f32> {
    if n <= 1 {
        return vec![1.0; n];
    }
    (0..n).map(|i| (0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / (n - 1) as f64).cos()) as f32).collect()
}

/// Vertex offset in (-0.5, 0.5) bins of the parabola through three samples
/// around a local maximum at the middle one.
pub fn parabolic_offset(left: f64, mid: f64, right: f64) -> f64 {
    let den = left - 2.0 * mid + right;
    if den.abs() < 1e-300 || !den.is_finite() { 0.0 } else { (0.5 * (left - right) / den).clamp(-0.5, 0.5) }
}

/// Sub-bin position of the maximum of `v` in `[lo, hi)` (clamped to the
/// slice): the arg-max refined by a parabola through the log magnitudes
/// (exact for a Gaussian peak, close for a Hann main lobe).
/// Returns `(position, value)`.
pub fn peak_in(v: &[f64], lo: usize, hi: usize) -> Option<(f64, f64)> {
    let hi = hi.min(v.len());
    if lo >= hi {
        return None;
    }
    let (i, &m) = v[lo..hi].iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    let i = i + lo;
    if m.is_nan() || m <= 0.0 {
        return None;
    }
    if i == 0 || i + 1 >= v.len() {
        return Some((i as f64, m));
    }
    let l = |x: f64| x.max(m * 1e-12).ln();
    Some((i as f64 + parabolic_offset(l(v[i - 1]), l(m), l(v[i + 1])), m))
}

/// Magnitude spectrum (bins 0..=n/2) of a real frame, Hann-windowed and
/// zero-padded to `nfft`, by a real-input FFT (equal to the complex FFT's
/// first half within f32 rounding; see the test against the complex path).
pub fn magnitude_spectrum(cache: &mut FftCache, frame: &[f32], nfft: usize) -> Vec<f64> {
    magnitude_bins(cache, frame, nfft, 0..usize::MAX)
}

/// The bins `bins` of [`magnitude_spectrum`] (clamped to its bins 0..=n/2),
/// the same values, for callers that read no others: the FFT is the same,
/// the magnitudes are taken only where needed.
pub fn magnitude_bins(cache: &mut FftCache, frame: &[f32], nfft: usize, bins: std::ops::Range<usize>) -> Vec<f64> {
    let w = cache.hann(frame.len());
    let n = nfft.max(frame.len());
    if n == 0 {
        return Vec::new();
    }
    let (lo, hi) = (bins.start.min(n / 2 + 1), bins.end.min(n / 2 + 1));
    let Some(out) = cache.forward_real(frame.iter().zip(w.iter()).map(|(x, wi)| x * wi), n) else {
        return vec![0.0; hi.saturating_sub(lo)];
    };
    out.get(lo..hi).unwrap_or_default().iter().map(abs_f64).collect()
}

/// `|c|` in f64 from the f32 parts: exact squares, a rounded sum and a
/// rounded square root, where
/// `Complex32::norm` (hypotf) is a libm call per bin (8 % of a gap run's
/// time); the spectra's and the matched filter's envelope.
#[inline]
pub(crate) fn abs_f64(c: &Complex32) -> f64 {
    (f64::from(c.re) * f64::from(c.re) + f64::from(c.im) * f64::from(c.im)).sqrt()
}

/// STFT magnitude (frames × bins) with a Hann window of `frame_len`, hop
/// `hop`, `nfft`-point FFTs. Used for spectrogram plots.
pub fn stft_magnitude(cache: &mut FftCache, x: &[f32], frame_len: usize, hop: usize, nfft: usize) -> Vec<Vec<f64>> {
    let mut out = Vec::new();
    if frame_len == 0 || hop == 0 || x.len() < frame_len {
        return out;
    }
    let mut s = 0;
    while s + frame_len <= x.len() {
        out.push(magnitude_spectrum(cache, &x[s..s + frame_len], nfft));
        s += hop;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The complex-FFT path the real FFT replaced: the oracle.
    fn magnitude_spectrum_complex(cache: &mut FftCache, frame: &[f32], nfft: usize) -> Vec<f64> {
        let w = cache.hann(frame.len());
        let mut buf = vec![Complex32::new(0.0, 0.0); nfft.max(frame.len())];
        for (i, (x, wi)) in frame.iter().zip(w.iter()).enumerate() {
            buf[i].re = x * wi;
        }
        let n = buf.len();
        cache.forward(&mut buf);
        buf[..=n / 2].iter().map(|c| f64::from(c.norm())).collect()
    }

    #[test]
    fn real_fft_matches_the_complex_path() {
        let mut c = FftCache::default();
        // Even and odd sizes, zero padding, a chirp plus a tone.
        for (len, nfft) in [(256usize, 256usize), (300, 1024), (1001, 1001), (4800, 8192), (1, 1), (5, 8)] {
            let x: Vec<f32> = (0..len)
                .map(|i| {
                    let t = i as f64 / 48_000.0;
                    ((std::f64::consts::TAU * (2000.0 * t + 3.0e5 * t * t)).sin() + 0.3 * (7.0 * i as f64).cos()) as f32
                })
                .collect();
            let a = magnitude_spectrum(&mut c, &x, nfft);
            let b = magnitude_spectrum_complex(&mut c, &x, nfft);
            assert_eq!(a.len(), b.len());
            let peak = b.iter().fold(0.0f64, |m, v| m.max(*v)).max(1e-30);
            for (k, (p, q)) in a.iter().zip(&b).enumerate() {
                // f32 FFTs: rounding grows like log2(n)·ε·Σ|x|; 1e-5 of the peak is far above it.
                assert!((p - q).abs() <= 1e-5 * peak, "len {len} nfft {nfft} bin {k}: {p} vs {q}");
            }
        }
    }

    #[test]
    fn peak_interpolation_finds_off_bin_tone() {
        let fs = 48_000.0;
        let f0 = 1234.5;
        let x: Vec<f32> = (0..4096).map(|i| (std::f64::consts::TAU * f0 * i as f64 / fs).sin() as f32).collect();
        let mut c = FftCache::default();
        let nfft = 16384;
        let m = magnitude_spectrum(&mut c, &x, nfft);
        let (pos, _) = peak_in(&m, 1, m.len()).unwrap();
        let f = pos * fs / nfft as f64;
        assert!((f - f0).abs() < 0.2, "{f}");
        // Without interpolation the arg-max alone is off by up to half a bin (1.46 Hz).
        assert_eq!(parabolic_offset(1.0, 2.0, 1.0), 0.0);
        assert!(parabolic_offset(1.0, 2.0, 1.5) > 0.0);
    }
}
