//! Per-chirp impulse responses (issue 10, item 1): the recording around one
//! chirp correlated with the sweep's deconvolution kernel
//! ([`crate::farina::SweepKernel`]), as an analytic (complex) signal whose
//! magnitude is the envelope and whose phase follows each arrival's carrier.
//! Every reflection of the chirp is one peak of it, not only the first.

use crate::farina::SweepKernel;
use crate::spectrum::FftCache;
use rustfft::num_complex::{Complex32, Complex64};

/// Extracts the impulse response of one chirp at a time, with the kernel's
/// spectrum cached.
#[derive(Debug)]
pub struct IrExtractor {
    cache: FftCache,
    kernel_len: usize,
    pre: usize,
    post: usize,
    nfft: usize,
    kernel_conj: Vec<Complex32>,
    /// Σ waveform·kernel: the response's peak for the sweep alone.
    norm: f64,
}

impl IrExtractor {
    /// Responses from `pre` samples before a chirp's onset to `post` samples
    /// after it.
    pub fn new(kernel: &SweepKernel, pre: usize, post: usize) -> Self {
        let m = kernel.len();
        let nfft = (m + pre + post).next_power_of_two();
        let mut cache = FftCache::default();
        let mut h = vec![Complex32::new(0.0, 0.0); nfft];
        for (d, s) in h.iter_mut().zip(&kernel.kernel) {
            d.re = *s;
        }
        cache.forward(&mut h);
        let kernel_conj = h.iter().map(|c| c.conj()).collect();
        let norm = kernel.waveform.iter().zip(&kernel.kernel).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum::<f64>();
        Self { cache, kernel_len: m, pre, post, nfft, kernel_conj, norm: if norm > 0.0 { norm } else { 1.0 } }
    }

    /// Samples before the onset held at the start of each response.
    pub fn pre(&self) -> usize {
        self.pre
    }

    /// The analytic impulse response around `onset` (index `pre` = lag 0,
    /// the detected onset); samples outside `x` count as zero. Scaled by the
    /// kernel's energy so that the template itself gives a peak near 1.
    pub fn extract(&mut self, x: &[f32], onset: usize) -> Vec<Complex64> {
        let n = self.nfft;
        let start = onset as isize - self.pre as isize;
        let take = self.kernel_len + self.pre + self.post;
        // Real-input forward FFT (half the work of a complex one), then the
        // analytic spectrum: positive frequencies doubled, negative ones zero.
        let plan = self.cache.plan_real(n);
        let mut input = plan.make_input_vec();
        for (k, b) in input.iter_mut().take(take).enumerate() {
            let i = start + k as isize;
            if i >= 0 {
                *b = x.get(i as usize).copied().unwrap_or(0.0);
            }
        }
        let mut half = plan.make_output_vec();
        if plan.process(&mut input, &mut half).is_err() {
            return vec![Complex64::new(0.0, 0.0); self.pre + self.post];
        }
        let mut buf = vec![Complex32::new(0.0, 0.0); n];
        for (k, (b, (v, h))) in buf.iter_mut().zip(half.iter().zip(&self.kernel_conj)).enumerate() {
            *b = if k == 0 || k == n / 2 { v * h } else { v * h * 2.0 };
        }
        self.cache.inverse(&mut buf);
        let scale = 1.0 / (n as f64 * self.norm);
        buf[..self.pre + self.post].iter().map(|c| Complex64::new(f64::from(c.re), f64::from(c.im)) * scale).collect()
    }
}

/// The analytic signal of `x` (negative frequencies removed by FFT): for an
/// impulse response given directly (`range --input rir`).
pub fn analytic(x: &[f32]) -> Vec<Complex64> {
    let n = (2 * x.len()).next_power_of_two().max(2);
    let mut cache = FftCache::default();
    let mut buf: Vec<Complex32> = (0..n).map(|i| Complex32::new(x.get(i).copied().unwrap_or(0.0), 0.0)).collect();
    cache.forward(&mut buf);
    for (k, b) in buf.iter_mut().enumerate() {
        if k > 0 && k < n / 2 {
            *b *= 2.0;
        } else if k > n / 2 {
            *b = Complex32::new(0.0, 0.0);
        }
    }
    cache.inverse(&mut buf);
    let s = 1.0 / n as f64;
    buf[..x.len()].iter().map(|c| Complex64::new(f64::from(c.re), f64::from(c.im)) * s).collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use chirpmap_core::scene::SweepKind;

    #[test]
    fn impulse_response_peaks_at_the_onset_and_at_the_echo() {
        // One sweep at sample 300 plus a copy 0.4× at +200 samples: peaks at
        // lag 0 and 200 (index pre and pre + 200), ratio 0.4.
        let k = SweepKernel::new(SweepKind::Linear, 8000.0, 500.0, 0.05, 24_000.0).unwrap();
        let mut x = vec![0.0f32; 4000];
        for (i, s) in k.waveform.iter().enumerate() {
            x[300 + i] += s;
            x[500 + i] += 0.4 * s;
        }
        let mut ex = IrExtractor::new(&k, 50, 400);
        let ir = ex.extract(&x, 300);
        let env: Vec<f64> = ir.iter().map(|c| c.norm()).collect();
        let arg = |lo: usize, hi: usize| (lo..hi).max_by(|&a, &b| env[a].total_cmp(&env[b])).unwrap();
        assert_eq!(arg(0, 150), 50);
        assert_eq!(arg(150, 450), 250);
        assert!((env[250] / env[50] - 0.4).abs() < 0.02, "{}", env[250] / env[50]);
        assert!((env[50] - 1.0).abs() < 0.1, "peak {}", env[50]);
    }

    #[test]
    fn analytic_signal_of_a_tone_has_constant_magnitude() {
        let x: Vec<f32> = (0..1000).map(|i| (0.3 * i as f64).cos() as f32).collect();
        let a = analytic(&x);
        // Away from the ends (the tone is not periodic in the FFT frame).
        for c in &a[200..800] {
            assert!((c.norm() - 1.0).abs() < 0.02, "{}", c.norm());
        }
    }
}
