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
    /// Filters in place from zero initial state (scipy `sosfilt`), by
    /// independent segments ([`SegmentFilter`]): the same samples as
    /// [`Sos::filter_sequential_in_place`] to within the filter's forgotten
    /// memory (below 1e-30 of the input, see [`Sos::segments`]), several
    /// times faster, and the same bit for bit as the streamed high-pass
    /// (`stream::Filtered`) at any block size.
    pub fn filter_in_place(&self, x: &mut [f32]) {
        let mut f = SegmentFilter::new(self);
        let mut out = Vec::new();
        let (mut pos_in, mut pos_out) = (0usize, 0usize);
        // Outputs never run ahead of the inputs already copied into the
        // filter, so they can overwrite them.
        while pos_out < x.len() {
            let end = (pos_in + SEGMENT_FEED).min(x.len());
            f.raw_buffer().extend_from_slice(&x[pos_in..end]);
            pos_in = end;
            out.clear();
            f.pull(&mut out, pos_in == x.len());
            x[pos_out..pos_out + out.len()].copy_from_slice(&out);
            pos_out += out.len();
        }
    }

    /// The direct recursion over the whole signal, section after section
    /// (direct form II transposed, zero initial state): the definition the
    /// segmented [`Sos::filter_in_place`] is checked against.
    pub fn filter_sequential_in_place(&self, x: &mut [f32]) {
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

    /// How the signal is cut for [`SegmentFilter`]: segments of `len`
    /// samples on a fixed grid (0, len, 2·len, …), each filtered from zero
    /// state `warm` samples before its start. A stable biquad's free
    /// response decays like r^n (r: its largest pole radius), so the state
    /// the warm-up forgets weighs at most r^warm ≤ 1e-30 (times the
    /// resonance gain 1/sin θ and the cascade's n, both far below 1e10) of
    /// the input: far below f32 (and f64) resolution of the output. Ours:
    /// the zero-state, truncated-memory reading of the recursion; the bound
    /// is the free response of a stable linear recursion, which decays with
    /// its largest pole radius (Oppenheim & Schafer, *Discrete-Time Signal
    /// Processing*, 3rd ed., §3.6 and §5.1).
    /// An unstable or nearly unstable cascade gets one segment (the plain recursion).
    pub fn segments(&self) -> Segments {
        let r = self.sections.iter().map(|s| pole_radius(s.a)).fold(0.0f64, f64::max);
        let forgotten = 1e-30f64.ln();
        let warm = if r <= 0.0 { 0.0 } else { (forgotten / r.ln()).ceil() };
        if !(r < 1.0 && warm.is_finite() && warm <= MAX_WARM as f64) {
            return Segments { warm: 0, len: usize::MAX };
        }
        let warm = warm as usize;
        Segments { warm, len: (4 * warm).max(MIN_SEGMENT).next_multiple_of(4096) }
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

/// Segment grid of [`SegmentFilter`] (see [`Sos::segments`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segments {
    /// Samples filtered from zero state before each segment (the warm-up).
    pub warm: usize,
    /// Segment length (samples); `usize::MAX`: one segment, the plain recursion.
    pub len: usize,
}

/// Longest warm-up accepted (samples); longer filters run as one segment.
const MAX_WARM: usize = 1 << 22;
/// Shortest segment (samples): the warm-up costs at most a quarter of the work.
const MIN_SEGMENT: usize = 1 << 16;
/// Segments filtered together, one per lane (independent recursions the
/// processor overlaps, and the compiler vectorises).
const LANES: usize = 8;
/// Samples `filter_in_place` feeds at a time.
const SEGMENT_FEED: usize = 1 << 16;

/// Largest pole radius of `1 + a1 z⁻¹ + a2 z⁻²`.
fn pole_radius(a: [f64; 3]) -> f64 {
    let (a1, a2) = (a[1] / a[0], a[2] / a[0]);
    let disc = a1 * a1 - 4.0 * a2;
    if disc < 0.0 { a2.sqrt() } else { 0.5 * (a1.abs() + disc.sqrt()) }
}

/// The cascade run on independent segments of a stream ([`Sos::segments`]):
/// push the raw samples into [`SegmentFilter::raw_buffer`], pull the
/// filtered ones. Sample `n`'s output depends only on the samples from
/// its segment's warm-up start to `n`, so a stream can start at any
/// segment ([`SegmentFilter::starting_at`]) and give the same values, and
/// [`LANES`] segments are filtered at once.
#[derive(Debug, Clone)]
pub struct SegmentFilter {
    sections: Vec<Biquad>,
    seg: Segments,
    raw: Vec<f32>,
    /// Absolute index of `raw[0]`.
    raw0: usize,
    /// Absolute index of the next output sample (a segment start, or within
    /// the last, partial segment after the end).
    next: usize,
}

impl SegmentFilter {
    /// A filter at the start of the stream.
    pub fn new(sos: &Sos) -> Self {
        Self::starting_at(sos, 0).0
    }

    /// A filter whose first output is the segment start at or before
    /// `pos`; returns it with that start and the absolute index of the
    /// first raw sample it must be given.
    pub fn starting_at(sos: &Sos, pos: usize) -> (Self, usize, usize) {
        let seg = sos.segments();
        let start = if seg.len == usize::MAX { 0 } else { pos / seg.len * seg.len };
        let raw0 = start.saturating_sub(seg.warm);
        let f = Self { sections: sos.sections.clone(), seg, raw: Vec::new(), raw0, next: start };
        (f, start, raw0)
    }

    /// The raw samples not yet filtered (from [`SegmentFilter::starting_at`]'s
    /// raw start); append the stream's next samples to it.
    pub fn raw_buffer(&mut self) -> &mut Vec<f32> {
        &mut self.raw
    }

    /// Appends to `out` the filtered samples of every group of [`LANES`]
    /// whole segments pushed so far, or with `end` every sample pushed;
    /// returns how many.
    pub fn pull(&mut self, out: &mut Vec<f32>, end: bool) -> usize {
        let (w, s) = (self.seg.warm, self.seg.len);
        let avail = self.raw0 + self.raw.len();
        let mut emitted = 0;
        if s == usize::MAX {
            // One segment: the plain recursion needs the whole signal.
            if end && self.next < avail {
                let mut y = self.raw[self.next - self.raw0..].to_vec();
                Sos { sections: self.sections.clone() }.filter_sequential_in_place(&mut y);
                emitted = y.len();
                out.extend_from_slice(&y);
                self.next = avail;
            }
            return emitted;
        }
        while self.next < avail && (end || self.next + LANES * s <= avail) {
            let n_seg = (avail - self.next).div_ceil(s).min(LANES);
            let lens: [usize; LANES] = std::array::from_fn(|j| {
                let p = self.next + j * s;
                if j < n_seg { s.min(avail - p) } else { 0 }
            });
            let steps = w + lens[0];
            let at = out.len();
            out.resize(at + lens.iter().sum::<usize>(), 0.0);
            let regular = n_seg == LANES && self.next >= w && lens.iter().all(|&l| l == lens[0]);
            // Lane j reads the raw samples from its segment's warm-up start;
            // at the stream's edges the lanes are zero-padded copies (zeros
            // before a zero state keep it zero; samples after are dropped).
            let mut padded: Vec<Vec<f32>> = Vec::new();
            if !regular {
                padded = (0..LANES)
                    .map(|j| {
                        let p = self.next + j * s;
                        let mut v = vec![0.0f32; steps];
                        if j < n_seg {
                            let first = p.saturating_sub(w);
                            let last = (p + lens[j]).min(avail);
                            v[first + w - p..last + w - p]
                                .copy_from_slice(&self.raw[first - self.raw0..last - self.raw0]);
                        }
                        v
                    })
                    .collect();
            }
            let mut outs_buf: Vec<Vec<f32>> = if regular { Vec::new() } else { vec![vec![0.0f32; lens[0]]; LANES] };
            {
                let raw = &self.raw;
                let (raw0, next) = (self.raw0, self.next);
                let srcs: [&[f32]; LANES] = std::array::from_fn(|j| {
                    if regular {
                        let from = next + j * s - w - raw0;
                        &raw[from..from + steps]
                    } else {
                        &padded[j][..]
                    }
                });
                if regular {
                    let mut rest = &mut out[at..];
                    let outs: [&mut [f32]; LANES] = std::array::from_fn(|j| {
                        let (head, tail) = std::mem::take(&mut rest).split_at_mut(lens[j]);
                        rest = tail;
                        head
                    });
                    run_lanes(&self.sections, srcs, outs, w);
                } else {
                    let outs: [&mut [f32]; LANES] = {
                        let mut it = outs_buf.iter_mut();
                        std::array::from_fn(|_| it.next().map_or(&mut [][..], |v| &mut v[..]))
                    };
                    run_lanes(&self.sections, srcs, outs, w);
                }
            }
            if !regular {
                let mut o = at;
                for j in 0..n_seg {
                    out[o..o + lens[j]].copy_from_slice(&outs_buf[j][..lens[j]]);
                    o += lens[j];
                }
            }
            emitted += out.len() - at;
            self.next = (self.next + n_seg * s).min(avail);
            let keep_from = self.next.saturating_sub(w).max(self.raw0);
            self.raw.drain(..keep_from - self.raw0);
            self.raw0 = keep_from;
        }
        emitted
    }
}

/// Rows per block of [`run_lanes`]: the lanes are copied to a small
/// transposed buffer (in L1 cache) and filtered there.
const ROWS: usize = 256;

/// The cascade from zero state over [`LANES`] signals at once: lane `j`
/// filters `srcs[j]` (all of one length) and writes its samples after the
/// first `warm` to `outs[j]` (length `srcs[j].len() - warm`); each lane
/// gets exactly the arithmetic of [`Sos::filter_sequential_in_place`].
fn run_lanes(sections: &[Biquad], srcs: [&[f32]; LANES], mut outs: [&mut [f32]; LANES], warm: usize) {
    let steps = srcs[0].len();
    let mut blk = [[0.0f32; LANES]; ROWS];
    // Runs `f` over every block of rows, then writes the output rows.
    let mut blocks = |f: &mut dyn FnMut(&mut [[f32; LANES]])| {
        let mut t = 0;
        while t < steps {
            let n = ROWS.min(steps - t);
            for (j, src) in srcs.iter().enumerate() {
                for (row, v) in blk[..n].iter_mut().zip(&src[t..t + n]) {
                    row[j] = *v;
                }
            }
            f(&mut blk[..n]);
            if t + n > warm {
                let r0 = warm.saturating_sub(t);
                for (j, o) in outs.iter_mut().enumerate() {
                    for (d, row) in o[t + r0 - warm..t + n - warm].iter_mut().zip(&blk[r0..n]) {
                        *d = row[j];
                    }
                }
            }
            t += n;
        }
    };
    if let [s1, s2] = sections {
        let mut st = [[0.0f64; LANES]; 4];
        blocks(&mut |rows: &mut [[f32; LANES]]| two_sections(s1, s2, &mut st, rows));
        return;
    }
    let mut z = vec![[[0.0f64; LANES]; 2]; sections.len()];
    blocks(&mut |rows: &mut [[f32; LANES]]| {
        for (sec, st) in sections.iter().zip(z.iter_mut()) {
            one_section(sec, st, rows);
        }
    });
}

/// One section over rows of [`LANES`] samples, state `st` = (z1, z2) per lane.
/// The state lives in locals for the whole block (not in memory between samples).
fn one_section(s: &Biquad, st: &mut [[f64; LANES]; 2], rows: &mut [[f32; LANES]]) {
    let ([b0, b1, b2], [_, a1, a2]) = (s.b, s.a);
    let [mut z1, mut z2] = *st;
    for row in rows.iter_mut() {
        let x: [f64; LANES] = std::array::from_fn(|j| f64::from(row[j]));
        let y: [f64; LANES] = std::array::from_fn(|j| b0 * x[j] + z1[j]);
        z1 = std::array::from_fn(|j| b1 * x[j] - a1 * y[j] + z2[j]);
        z2 = std::array::from_fn(|j| b2 * x[j] - a2 * y[j]);
        *row = std::array::from_fn(|j| y[j] as f32);
    }
    *st = [z1, z2];
}

/// Two sections (the paper's order 4) in one sweep over rows of [`LANES`]
/// samples, state `st` = (z1, z2, w1, w2) per lane: the section-1 output is
/// rounded to f32 before section 2, as section after section.
fn two_sections(s1: &Biquad, s2: &Biquad, st: &mut [[f64; LANES]; 4], rows: &mut [[f32; LANES]]) {
    let ([b0, b1, b2], [_, a1, a2]) = (s1.b, s1.a);
    let ([c0, c1, c2], [_, d1, d2]) = (s2.b, s2.a);
    let [mut z1, mut z2, mut w1, mut w2] = *st;
    for row in rows.iter_mut() {
        let x: [f64; LANES] = std::array::from_fn(|j| f64::from(row[j]));
        let y: [f64; LANES] = std::array::from_fn(|j| b0 * x[j] + z1[j]);
        z1 = std::array::from_fn(|j| b1 * x[j] - a1 * y[j] + z2[j]);
        z2 = std::array::from_fn(|j| b2 * x[j] - a2 * y[j]);
        let u: [f64; LANES] = std::array::from_fn(|j| f64::from(y[j] as f32));
        let y2: [f64; LANES] = std::array::from_fn(|j| c0 * u[j] + w1[j]);
        w1 = std::array::from_fn(|j| c1 * u[j] - d1 * y2[j] + w2[j]);
        w2 = std::array::from_fn(|j| c2 * u[j] - d2 * y2[j]);
        *row = std::array::from_fn(|j| y2[j] as f32);
    }
    *st = [z1, z2, w1, w2];
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
        for i in h..n - h {
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

    fn noisy(n: usize, seed: u64, dc: f32) -> Vec<f32> {
        let mut r = seed | 1;
        (0..n)
            .map(|i| {
                r ^= r << 13;
                r ^= r >> 7;
                r ^= r << 17;
                dc + 0.5 * ((r >> 40) as f32 / 16_777_216.0 - 0.5) + 0.2 * (i as f32 * 0.003).sin()
            })
            .collect()
    }

    /// The segmented high-pass against the plain recursion (the oracle),
    /// over many segments and lane groups, with a large DC offset (the
    /// state the warm-up forgets is largest then): every sample within two
    /// f32 roundings of the input's scale (the recursion itself rounds the
    /// first section's output to f32), and nearly all bit-equal. The
    /// first segment starts from the true zero state, so it is exact.
    #[test]
    fn segmented_highpass_is_the_recursion() {
        for (fs, dc) in [(48_000.0, 0.0f32), (48_000.0, 0.9), (8_000.0, 0.5), (192_000.0, 0.3)] {
            let sos = paper_highpass(fs).unwrap();
            let seg = sos.segments();
            assert!(seg.warm > 0 && seg.len >= 4 * seg.warm && seg.len < usize::MAX, "{seg:?}");
            let n = LANES * seg.len * 2 + seg.len / 3;
            let x = noisy(n, 7, dc);
            let scale = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let (mut a, mut b) = (x.clone(), x);
            sos.filter_sequential_in_place(&mut a);
            sos.filter_in_place(&mut b);
            assert!(a[..seg.len].iter().zip(&b).all(|(p, q)| p.to_bits() == q.to_bits()), "fs {fs}: first segment");
            let mut differ = 0;
            for (i, (p, q)) in a.iter().zip(&b).enumerate() {
                assert!((p - q).abs() <= 2.0 * f32::EPSILON * scale, "fs {fs} sample {i}: {p} vs {q}");
                differ += usize::from(p.to_bits() != q.to_bits());
            }
            assert!(differ * 100 < n, "fs {fs}: {differ} of {n} samples differ");
        }
    }

    /// Started at any segment, the filter gives the samples of a run from
    /// the start, bit for bit; pushed in blocks of any size, the same too.
    #[test]
    fn segment_filter_restarts_and_blocks_are_exact() {
        let sos = paper_highpass(8_000.0).unwrap();
        let seg = sos.segments();
        let n = LANES * seg.len + 3 * seg.len + 1234;
        let x = noisy(n, 11, 0.2);
        let mut want = x.clone();
        sos.filter_in_place(&mut want);
        for (pos, block) in [(0usize, 1000usize), (seg.len + 5, 4099), (3 * seg.len, 65_536), (n - 1, 7)] {
            let (mut f, at, raw0) = SegmentFilter::starting_at(&sos, pos);
            assert!(at <= pos && pos - at < seg.len && raw0 == at.saturating_sub(seg.warm));
            let mut got = Vec::new();
            let mut i = raw0;
            while i < n {
                let e = (i + block).min(n);
                f.raw_buffer().extend_from_slice(&x[i..e]);
                i = e;
                f.pull(&mut got, i == n);
            }
            assert_eq!(got.len(), n - at);
            assert!(got.iter().zip(&want[at..]).all(|(p, q)| p.to_bits() == q.to_bits()), "from {pos}, blocks {block}");
        }
    }

    #[test]
    fn an_unstable_cascade_runs_as_one_segment() {
        let sos = Sos { sections: vec![Biquad { b: [1.0, 0.0, 0.0], a: [1.0, -1.0, 0.0] }] };
        assert_eq!(sos.segments().len, usize::MAX);
        let mut x = vec![1.0f32; 100_000];
        sos.filter_in_place(&mut x);
        // An accumulator: y[n] = n + 1.
        assert_eq!(x[99_999], 100_000.0);
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
