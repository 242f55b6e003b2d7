//! Filters of the paper's field pipeline (§IV.A): a 100 Hz high-pass to
//! remove wind and handling rumble, and Savitzky–Golay smoothing of spectra
//! (which keeps peak positions while removing bin-to-bin noise).
//!
//! Both are cross-checked against scipy (`tests/scipy_reference.rs`).

use crate::error::AudioError;

/// One second-order section, direct form II transposed, coefficients
/// normalised so `a0 = 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Biquad {
    /// Numerator coefficients `b0, b1, b2`.
    pub b: [f64; 3],
    /// Denominator coefficients `a0 = 1, a1, a2`.
    pub a: [f64; 3],
}

/// A cascade of biquads (scipy's "sos" form).
#[derive(Debug, Clone, PartialEq)]
pub struct Sos {
    /// Sections applied in order.
    pub sections: Vec<Biquad>,
}

/// Butterworth high-pass of even `order` (2, 4, …) at `cutoff_hz`, by the
/// bilinear transform with pre-warping: the same design as
/// `scipy.signal.butter(order, cutoff_hz, 'highpass', fs=fs, output='sos')`.
pub fn butter_highpass(order: usize, cutoff_hz: f64, sample_rate_hz: f64) -> Result<Sos, AudioError> {
    if order == 0 || !order.is_multiple_of(2) || order > 16 {
        return Err(AudioError::InvalidParam {
            field: "order",
            reason: format!("need an even order 2..=16, got {order}"),
        });
    }
    if !(cutoff_hz > 0.0 && cutoff_hz < sample_rate_hz / 2.0) {
        return Err(AudioError::InvalidParam {
            field: "cutoff",
            reason: format!("{cutoff_hz} Hz must be in (0, {}) Hz", sample_rate_hz / 2.0),
        });
    }
    let fs2 = 2.0 * sample_rate_hz;
    let wc = fs2 * (std::f64::consts::PI * cutoff_hz / sample_rate_hz).tan();
    let mut sections = Vec::new();
    for k in 0..order / 2 {
        // Analogue low-pass prototype pole in the upper half plane.
        let theta = std::f64::consts::PI * (2 * k + order + 1) as f64 / (2 * order) as f64;
        let (pr, pi) = (theta.cos(), theta.sin());
        // High-pass transform s -> wc/s: pole wc/p = wc·conj(p) (|p| = 1).
        let (sr, si) = (wc * pr, -wc * pi);
        // Bilinear z = (fs2 + s)/(fs2 - s).
        let (nr, ni) = (fs2 + sr, si);
        let (dr, di) = (fs2 - sr, -si);
        let den = dr * dr + di * di;
        let (zr, zi) = ((nr * dr + ni * di) / den, (ni * dr - nr * di) / den);
        let a = [1.0, -2.0 * zr, zr * zr + zi * zi];
        // Zeros at z = 1 (s = 0); unit gain at Nyquist (z = -1).
        let g = (a[0] - a[1] + a[2]) / 4.0;
        sections.push(Biquad { b: [g, -2.0 * g, g], a });
    }
    Ok(Sos { sections })
}

impl Sos {
    /// Filters in place from zero initial state (scipy `sosfilt`).
    pub fn filter_in_place(&self, x: &mut [f32]) {
        for s in &self.sections {
            let [b0, b1, b2] = s.b;
            let [_, a1, a2] = s.a;
            let (mut z1, mut z2) = (0.0f64, 0.0f64);
            for v in x.iter_mut() {
                let xi = f64::from(*v);
                let y = b0 * xi + z1;
                z1 = b1 * xi - a1 * y + z2;
                z2 = b2 * xi - a2 * y;
                *v = y as f32;
            }
        }
    }

    /// Same, in f64 (used by the scipy cross-check).
    pub fn filter_f64(&self, x: &[f64]) -> Vec<f64> {
        let mut out = x.to_vec();
        for s in &self.sections {
            let (mut z1, mut z2) = (0.0f64, 0.0f64);
            for v in out.iter_mut() {
                let xi = *v;
                let y = s.b[0] * xi + z1;
                z1 = s.b[1] * xi - s.a[1] * y + z2;
                z2 = s.b[2] * xi - s.a[2] * y;
                *v = y;
            }
        }
        out
    }
}

/// The paper's 100 Hz high-pass (order 4: ours; the paper gives no order).
pub fn paper_highpass(sample_rate_hz: f64) -> Result<Sos, AudioError> {
    butter_highpass(4, 100.0, sample_rate_hz)
}

/// Solves the small dense system `m·x = r` (`m` square, `r.len()` rows) by
/// Gaussian elimination with partial pivoting (Golub & Van Loan, *Matrix
/// Computations*, §3.4). `None` when `m` is not square or is singular to
/// working precision: a pivot below 1e-12 × the largest |entry| of `m`, or a
/// non-finite solution. The one solver of the crate: Savitzky–Golay normal
/// equations here, the direct-sound fit in `ranging`.
pub(crate) fn solve_linear(mut m: Vec<Vec<f64>>, mut r: Vec<f64>) -> Option<Vec<f64>> {
    let n = r.len();
    if m.len() != n || m.iter().any(|row| row.len() != n) {
        return None;
    }
    let scale = m.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    let tiny = 1e-12 * scale;
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))?;
        if m[piv][col].is_nan() || m[piv][col].abs() <= tiny {
            return None;
        }
        m.swap(col, piv);
        r.swap(col, piv);
        let pivot_row = m[col].clone();
        for row in col + 1..n {
            let f = m[row][col] / pivot_row[col];
            for (dst, src) in m[row][col..].iter_mut().zip(&pivot_row[col..]) {
                *dst -= f * src;
            }
            r[row] -= f * r[col];
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|k| m[i][k] * x[k]).sum();
        x[i] = (r[i] - s) / m[i][i];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Savitzky–Golay smoother: the least-squares polynomial of degree
/// `polyorder` over a sliding window of `window` (odd) samples, evaluated at
/// the window centre; at the ends, the polynomial fitted to the first/last
/// `window` samples is evaluated at each edge sample (scipy's
/// `savgol_filter(..., mode='interp')`, its default).
#[derive(Debug, Clone)]
pub struct SavitzkyGolay {
    window: usize,
    /// `proj[j][i]`: weight of window sample `i` in the fitted value at position `j`.
    proj: Vec<Vec<f64>>,
}

impl SavitzkyGolay {
    /// Smoother over `window` samples (odd, ≥ 3) with a polynomial of degree
    /// `polyorder` (< `window`); the paper's spectra use scipy's `savgol_filter`.
    pub fn new(window: usize, polyorder: usize) -> Result<Self, AudioError> {
        if window.is_multiple_of(2) || window < 3 || polyorder >= window {
            return Err(AudioError::InvalidParam {
                field: "savgol",
                reason: format!("window must be odd and >= 3 and polyorder < window, got {window}, {polyorder}"),
            });
        }
        let half = (window / 2) as f64;
        let xs: Vec<f64> = (0..window).map(|i| (i as f64 - half) / half.max(1.0)).collect();
        let p = polyorder + 1;
        // Normal matrix AᵀA (A: Vandermonde of the window positions).
        let ata: Vec<Vec<f64>> =
            (0..p).map(|r| (0..p).map(|c| xs.iter().map(|x| x.powi((r + c) as i32)).sum()).collect()).collect();
        // Projection rows: for position j, weights w_i = a_jᵀ (AᵀA)⁻¹ a_i.
        let mut proj = Vec::with_capacity(window);
        for &xj in &xs {
            let aj: Vec<f64> = (0..p).map(|k| xj.powi(k as i32)).collect();
            let u = solve_linear(ata.clone(), aj)
                .ok_or(AudioError::InvalidParam { field: "savgol", reason: "singular fit".into() })?;
            proj.push(xs.iter().map(|&xi| (0..p).map(|k| u[k] * xi.powi(k as i32)).sum()).collect());
        }
        Ok(Self { window, proj })
    }

    /// Smooths `x`. Inputs shorter than the window are returned unchanged.
    pub fn smooth(&self, x: &[f64]) -> Vec<f64> {
        let (w, n) = (self.window, x.len());
        if n < w {
            return x.to_vec();
        }
        let h = w / 2;
        let mut out = vec![0.0; n];
        let centre = &self.proj[h];
        // Four outputs at a time, each summed in the order and from the start
        // `Iterator::sum` uses: the same values, with four independent add
        // chains instead of one at a time (the chain was the loop's limit).
        let start: f64 = std::iter::empty::<f64>().sum();
        let mut i = h;
        while i + 4 <= n - h {
            let xs = &x[i - h..i + h + 4];
            let mut acc = [start; 4];
            for (k, c) in centre.iter().enumerate() {
                for (j, a) in acc.iter_mut().enumerate() {
                    *a += c * xs[k + j];
                }
            }
            out[i..i + 4].copy_from_slice(&acc);
            i += 4;
        }
        for i in i..n - h {
            out[i] = centre.iter().zip(&x[i - h..i + h + 1]).map(|(c, v)| c * v).sum();
        }
        for j in 0..h {
            out[j] = self.proj[j].iter().zip(&x[..w]).map(|(c, v)| c * v).sum();
            let k = w - h + j; // positions h+1 .. w-1 of the last window
            out[n - h + j] = self.proj[k].iter().zip(&x[n - w..]).map(|(c, v)| c * v).sum();
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn solver_solves_and_refuses_singular_or_ragged_systems() {
        // Needs a row swap (zero first pivot): x = (1, 2, 3).
        let m = vec![vec![0.0, 2.0, 1.0], vec![1.0, 1.0, 1.0], vec![2.0, 0.0, 3.0]];
        let x = solve_linear(m, vec![7.0, 6.0, 11.0]).unwrap();
        for (a, b) in x.iter().zip([1.0, 2.0, 3.0]) {
            assert!((a - b).abs() < 1e-12, "{x:?}");
        }
        assert!(solve_linear(vec![vec![1.0, 2.0], vec![2.0, 4.0]], vec![1.0, 2.0]).is_none());
        assert!(solve_linear(vec![vec![1.0, 2.0]], vec![1.0, 2.0]).is_none());
        assert!(solve_linear(vec![vec![f64::NAN]], vec![1.0]).is_none());
        assert_eq!(solve_linear(vec![], vec![]), Some(vec![]));
    }

    /// Four outputs at a time give the one-at-a-time sums bit for bit
    /// (the oracle is the loop they replace), zeros and signed zeros included.
    #[test]
    fn smoothing_in_fours_is_the_plain_sum() {
        let mut next = crate::test_rng::xorshift(5);
        for case in 0..300 {
            let window = [3usize, 5, 7, 9, 11, 17][case % 6];
            let sg = SavitzkyGolay::new(window, 2).unwrap();
            let n = (next() % 60) as usize;
            let x: Vec<f64> = (0..n)
                .map(|_| match next() % 5 {
                    0 => 0.0,
                    1 => -0.0,
                    _ => (next() % 2000) as f64 / 7.0 - 100.0,
                })
                .collect();
            let got = sg.smooth(&x);
            if n < window {
                assert_eq!(got, x);
                continue;
            }
            let h = window / 2;
            for i in h..n - h {
                let want: f64 = sg.proj[h].iter().zip(&x[i - h..i + h + 1]).map(|(c, v)| c * v).sum();
                assert_eq!(got[i].to_bits(), want.to_bits(), "case {case}, output {i}");
            }
        }
    }

    proptest! {
        /// Oracle: multiply back. Diagonally dominant matrices are well conditioned,
        /// so the residual must be at rounding level.
        #[test]
        fn solver_residual_is_tiny(n in 1usize..7, seed in proptest::collection::vec(-1.0f64..1.0, 49 + 7)) {
            let m: Vec<Vec<f64>> = (0..n)
                .map(|i| (0..n).map(|j| seed[i * 7 + j] + if i == j { 2.0 * n as f64 } else { 0.0 }).collect())
                .collect();
            let r: Vec<f64> = seed[49..49 + n].to_vec();
            let x = solve_linear(m.clone(), r.clone()).unwrap();
            for i in 0..n {
                let back: f64 = (0..n).map(|j| m[i][j] * x[j]).sum();
                prop_assert!((back - r[i]).abs() < 1e-12, "row {}: {} vs {}", i, back, r[i]);
            }
        }
    }

    #[test]
    fn highpass_passes_nyquist_and_blocks_dc() {
        let sos = paper_highpass(48_000.0).unwrap();
        let dc = sos.filter_f64(&vec![1.0; 48_000]);
        assert!(dc[47_999].abs() < 1e-6, "{}", dc[47_999]);
        let ny: Vec<f64> = (0..10_000).map(|i| if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
        let y = sos.filter_f64(&ny);
        assert!((y[9_999].abs() - 1.0).abs() < 1e-4, "{}", y[9_999]);
        // 100 Hz itself is at -3 dB (Butterworth).
        let f: Vec<f64> = (0..48_000).map(|i| (std::f64::consts::TAU * 100.0 * i as f64 / 48_000.0).sin()).collect();
        let y = sos.filter_f64(&f);
        let peak = y[24_000..].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((peak - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-3, "{peak}");
    }

    #[test]
    fn savgol_reproduces_polynomials_of_its_order() {
        let sg = SavitzkyGolay::new(7, 2).unwrap();
        let x: Vec<f64> = (0..30).map(|i| 0.5 * (i as f64).powi(2) - 3.0 * i as f64 + 1.0).collect();
        for (a, b) in sg.smooth(&x).iter().zip(&x) {
            assert!((a - b).abs() < 1e-8, "{a} {b}");
        }
        // A cubic is not reproduced by a quadratic fit, so the test can fail.
        let c: Vec<f64> = (0..30).map(|i| (i as f64).powi(3)).collect();
        assert!(sg.smooth(&c).iter().zip(&c).any(|(a, b)| (a - b).abs() > 1e-3));
    }
}
