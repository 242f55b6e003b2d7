//! Constant-memory audio (issue 14, item 4): the paper's high-pass run block
//! by block, and chirp detection ([`crate::detect::detect_chirps`]) over a
//! stream, giving the same detections bit for bit while holding a few
//! blocks of samples instead of the recording.
//!
//! The correlation is computed in exactly the FFT blocks `detect_chirps`
//! uses (same inputs, same plans, so the same floating-point values). Its
//! median chunk maximum is found exactly without storing every chunk: a
//! window of values around the running median is kept, with counts of the
//! values below and above it (the selection idea of Munro & Paterson, 1980);
//! only chunks that can pass the final threshold (12 × the median or more)
//! are kept as candidates. The normalised correlations the greedy selection
//! asks for are computed afterwards from a second read of the stream.

use crate::detect::{ChirpTemplate, Detection, MIN_NCC, MIN_PEAK_RATIO};
use crate::error::AudioError;
use crate::filter::{Biquad, Sos};
use crate::spectrum::FftCache;
use chirpmap_core::Sweep;
use rustfft::num_complex::Complex32;
use std::collections::{BTreeMap, HashMap};

/// A source of samples read in blocks.
pub trait BlockSource {
    /// Appends up to `max` samples to `out` and returns how many (0 at the end).
    fn read(&mut self, out: &mut Vec<f32>, max: usize) -> Result<usize, AudioError>;
    /// Moves to a position at or before sample `pos` from which reading
    /// gives the same samples as reading through, and returns it; `None`:
    /// the source cannot move (it keeps its position).
    fn seek_before(&mut self, pos: usize) -> Result<Option<usize>, AudioError> {
        let _ = pos;
        Ok(None)
    }
}

impl BlockSource for crate::wav::WavStream {
    fn read(&mut self, out: &mut Vec<f32>, max: usize) -> Result<usize, AudioError> {
        self.read_block(out, max)
    }
    fn seek_before(&mut self, pos: usize) -> Result<Option<usize>, AudioError> {
        self.seek_frame(pos)?;
        Ok(Some(pos.min(self.frames)))
    }
}

/// The filter's state before one block: (sample index, state per section).
pub type Checkpoint = (usize, Vec<(f64, f64)>);

/// A [`BlockSource`] high-passed by a cascade of biquads whose state is
/// carried across blocks: the same arithmetic, in the same order, as
/// [`Sos::filter_in_place`] on the whole signal, so the same samples.
#[derive(Debug)]
pub struct Filtered<S> {
    inner: S,
    sections: Vec<Biquad>,
    state: Vec<(f64, f64)>,
    /// Whether any input sample (before filtering) was not zero.
    pub any_nonzero_input: bool,
    pos: usize,
    /// The state before every block read from the start (recorded on the
    /// first read through), so that a second read can start mid-stream.
    pub checkpoints: Vec<Checkpoint>,
}

impl<S: BlockSource> Filtered<S> {
    /// Filters `inner` through `sos` from zero initial state.
    pub fn new(inner: S, sos: &Sos) -> Self {
        Self {
            inner,
            sections: sos.sections.clone(),
            state: vec![(0.0, 0.0); sos.sections.len()],
            any_nonzero_input: false,
            pos: 0,
            checkpoints: Vec::new(),
        }
    }
    /// `inner` filtered from the states recorded by a previous read
    /// through the same samples (see [`Filtered::checkpoints`]).
    pub fn resume(inner: S, sos: &Sos, checkpoints: Vec<Checkpoint>) -> Self {
        Self { checkpoints, ..Self::new(inner, sos) }
    }
    /// The unfiltered source.
    pub fn inner(&self) -> &S {
        &self.inner
    }
}

impl<S: BlockSource> BlockSource for Filtered<S> {
    fn read(&mut self, out: &mut Vec<f32>, max: usize) -> Result<usize, AudioError> {
        if self.checkpoints.last().is_none_or(|c| c.0 < self.pos) {
            self.checkpoints.push((self.pos, self.state.clone()));
        }
        let start = out.len();
        let n = self.inner.read(out, max)?;
        self.pos += n;
        let block = &mut out[start..];
        if !self.any_nonzero_input {
            self.any_nonzero_input = block.iter().any(|v| *v != 0.0);
        }
        if let ([s1, s2], [st1, st2]) = (self.sections.as_slice(), self.state.as_mut_slice()) {
            // Two sections (the paper's order-4 high-pass) interleaved per
            // sample: the same operations as section after section, with the
            // two recursions overlapping in the processor.
            let ([b0, b1, b2], [_, a1, a2]) = (s1.b, s1.a);
            let ([c0, c1, c2], [_, d1, d2]) = (s2.b, s2.a);
            let ((mut z1, mut z2), (mut w1, mut w2)) = (*st1, *st2);
            for v in block.iter_mut() {
                let xi = f64::from(*v);
                let y = b0 * xi + z1;
                z1 = b1 * xi - a1 * y + z2;
                z2 = b2 * xi - a2 * y;
                let u = f64::from(y as f32);
                let y2 = c0 * u + w1;
                w1 = c1 * u - d1 * y2 + w2;
                w2 = c2 * u - d2 * y2;
                *v = y2 as f32;
            }
            (*st1, *st2) = ((z1, z2), (w1, w2));
            return Ok(n);
        }
        for (s, st) in self.sections.iter().zip(self.state.iter_mut()) {
            let [b0, b1, b2] = s.b;
            let [_, a1, a2] = s.a;
            let (mut z1, mut z2) = *st;
            for v in block.iter_mut() {
                let xi = f64::from(*v);
                let y = b0 * xi + z1;
                z1 = b1 * xi - a1 * y + z2;
                z2 = b2 * xi - a2 * y;
                *v = y as f32;
            }
            *st = (z1, z2);
        }
        Ok(n)
    }

    fn seek_before(&mut self, pos: usize) -> Result<Option<usize>, AudioError> {
        let i = self.checkpoints.partition_point(|c| c.0 <= pos);
        let Some((at, state)) = i.checked_sub(1).and_then(|i| self.checkpoints.get(i)) else { return Ok(None) };
        if *at <= self.pos {
            return Ok(None);
        }
        let Some(got) = self.inner.seek_before(*at)? else { return Ok(None) };
        if got != *at {
            return Ok(None);
        }
        self.state.clone_from(state);
        self.pos = *at;
        Ok(Some(*at))
    }
}

/// Lags per stored maximum, as in `detect_chirps`.
const CHUNK: usize = 16;

/// Exact median of a stream of values in bounded memory, when the median
/// stays within the kept window (see the module's doc).
#[derive(Debug)]
struct MedianWindow {
    vals: Vec<f32>,
    lo: f32,
    hi: f32,
    below: usize,
    n: usize,
    windowed: bool,
    cap: usize,
}

impl MedianWindow {
    fn new(cap: usize) -> Self {
        Self { vals: Vec::new(), lo: 0.0, hi: 0.0, below: 0, n: 0, windowed: false, cap }
    }
    fn push(&mut self, v: f32) -> bool {
        self.n += 1;
        if self.windowed {
            if v.total_cmp(&self.lo).is_lt() {
                self.below += 1;
                return false;
            }
            if v.total_cmp(&self.hi).is_gt() {
                return false;
            }
        }
        self.vals.push(v);
        if self.vals.len() >= self.cap {
            self.narrow();
            return true;
        }
        false
    }
    /// Keeps the values within a quarter of the window's length (in rank)
    /// either side of the running median.
    fn narrow(&mut self) {
        let len = self.vals.len();
        let t = (self.n / 2).saturating_sub(self.below).min(len - 1);
        let (r_lo, r_hi) = (t.saturating_sub(len / 4), (t + len / 4).min(len - 1));
        let lo = *self.vals.select_nth_unstable_by(r_lo, f32::total_cmp).1;
        let hi = *self.vals.select_nth_unstable_by(r_hi, f32::total_cmp).1;
        let before = self.vals.len();
        self.vals.retain(|v| v.total_cmp(&lo).is_ge());
        self.below += before - self.vals.len();
        self.vals.retain(|v| v.total_cmp(&hi).is_le());
        self.lo = lo;
        self.hi = hi;
        self.windowed = true;
    }
    /// Lower bound of every value that can still be the median.
    fn floor(&self) -> f32 {
        if self.windowed { self.lo } else { 0.0 }
    }
    /// The value at rank `n / 2`, as `select_nth_unstable` gives it, or
    /// `None` when it left the window.
    fn finish(mut self) -> Option<f32> {
        let mid = self.n / 2;
        let i = mid.checked_sub(self.below)?;
        if i >= self.vals.len() {
            return None;
        }
        Some(*self.vals.select_nth_unstable_by(i, f32::total_cmp).1)
    }
}

/// Values kept for the median, at most: 16 MB.
const MEDIAN_CAP: usize = 1 << 22;

/// The first pass over a stream: the matched filter's chunk maxima reduced
/// to what the chirp selection needs.
#[derive(Debug)]
pub struct Scan {
    /// Samples in the stream.
    pub len: usize,
    /// FFT length of the correlation (its scale is `nfft` × the correlation).
    pub nfft: usize,
    m: usize,
    rate_hz: f64,
    duration_s: f64,
    median: f32,
    /// Candidate chunks `(lag, |c|)`, strongest first (ties by lag).
    cands: Vec<(usize, f32)>,
    before: usize,
    after: usize,
    tpl_norm: f64,
}

/// Why a scan gave no [`Scan`].
#[derive(Debug)]
pub enum ScanError {
    /// What `detect_chirps` reports for the same samples.
    Audio(AudioError),
    /// The median chunk maximum drifted out of the window kept for it
    /// (a recording whose level changes greatly along it): detect in memory.
    MedianLost,
}

impl From<AudioError> for ScanError {
    fn from(e: AudioError) -> Self {
        Self::Audio(e)
    }
}

/// Samples read from the source at a time.
pub const BLOCK: usize = 1 << 16;

/// First pass of [`crate::detect::detect_chirps`] over a stream of `len`
/// high-passed samples (the same errors, in the same order, for the same samples).
pub fn scan_chirps(
    src: &mut dyn BlockSource,
    len: usize,
    tpl: &ChirpTemplate,
    max_echo_delay_s: f64,
) -> Result<Scan, ScanError> {
    scan_with_cap(src, len, tpl, max_echo_delay_s, MEDIAN_CAP)
}

fn scan_with_cap(
    src: &mut dyn BlockSource,
    len: usize,
    tpl: &ChirpTemplate,
    max_echo_delay_s: f64,
    median_cap: usize,
) -> Result<Scan, ScanError> {
    let m = tpl.len();
    if m == 0 || m > len {
        return Err(AudioError::ChirpLongerThanRecording {
            chirp_s: tpl.chirp.duration_s(),
            recording_s: len as f64 / tpl.sample_rate_hz,
        }
        .into());
    }
    let mut cache = FftCache::default();
    let nfft = (4 * m).next_power_of_two().max(1 << 14);
    let step = nfft - m + 1;
    let h = tpl.conj_spectrum(&mut cache, nfft);
    let n_lags = len - m + 1;
    let fwd = cache.plan(nfft, false);
    let inv = cache.plan(nfft, true);
    let mut buf = vec![Complex32::new(0.0, 0.0); nfft];
    let mut scratch = vec![Complex32::new(0.0, 0.0); fwd.get_inplace_scratch_len().max(inv.get_inplace_scratch_len())];
    let mut x: Vec<f32> = Vec::with_capacity(2 * nfft + BLOCK);
    let (mut x0, mut eof, mut any_nonzero) = (0usize, false, false);
    let mut med = MedianWindow::new(median_cap);
    let mut global = 0.0f32;
    let mut cands: Vec<(usize, f32)> = Vec::new();
    let (mut cur_ci, mut cur_max, mut cur_arg) = (0usize, 0.0f32, 0u32);
    let mut flush = |ci: usize, v: f32, arg: u32, cands: &mut Vec<(usize, f32)>, med: &mut MedianWindow| {
        global = global.max(v);
        if med.push(v) {
            let floor = MIN_PEAK_RATIO as f32 * med.floor();
            cands.retain(|c| c.1 >= floor);
        }
        if v >= MIN_PEAK_RATIO as f32 * med.floor() {
            cands.push((ci * CHUNK + arg as usize, v));
        }
    };
    let mut s = 0usize;
    while s < n_lags {
        let s2 = s + step;
        let need = (s2 + nfft).min(len);
        while x0 + x.len() < need && !eof {
            let got = src.read(&mut x, BLOCK)?;
            eof = got == 0;
        }
        if x0 + x.len() < need {
            return Err(
                AudioError::Truncated(format!("the stream ended after {} of {len} samples", x0 + x.len())).into()
            );
        }
        let get = |i: usize| if i >= x0 { x.get(i - x0).copied().unwrap_or(0.0) } else { 0.0 };
        for (k, b) in buf.iter_mut().enumerate() {
            let re = get(s + k);
            let im = if s2 < n_lags { get(s2 + k) } else { 0.0 };
            *b = Complex32::new(re, im);
        }
        fwd.process_with_scratch(&mut buf, &mut scratch);
        for (b, hh) in buf.iter_mut().zip(&h) {
            *b *= hh;
        }
        inv.process_with_scratch(&mut buf, &mut scratch);
        for (start, part) in [(s, 0usize), (s2, 1usize)] {
            if start >= n_lags {
                continue;
            }
            let end = (start + step).min(n_lags);
            for lag in start..end {
                let c = buf[lag - start];
                let v = if part == 0 { c.re } else { c.im }.abs();
                let ci = lag / CHUNK;
                if ci != cur_ci {
                    flush(cur_ci, cur_max, cur_arg, &mut cands, &mut med);
                    (cur_ci, cur_max, cur_arg) = (ci, 0.0, 0);
                }
                if v > cur_max {
                    cur_max = v;
                    cur_arg = (lag % CHUNK) as u32;
                }
            }
        }
        s += 2 * step;
        // Keep what the next block pair reads.
        let keep_from = s.min(x0 + x.len());
        if keep_from > x0 {
            any_nonzero = any_nonzero || x[..keep_from - x0].iter().any(|v| *v != 0.0);
            x.drain(..keep_from - x0);
            x0 = keep_from;
        }
    }
    flush(cur_ci, cur_max, cur_arg, &mut cands, &mut med);
    // The rest of the stream (samples after the last lag's template).
    loop {
        any_nonzero = any_nonzero || x.iter().any(|v| *v != 0.0);
        x0 += x.len();
        x.clear();
        if eof || src.read(&mut x, BLOCK)? == 0 {
            break;
        }
    }
    if x0 != len {
        return Err(AudioError::Truncated(format!("the stream held {x0} samples, not {len}")).into());
    }
    if !any_nonzero {
        return Err(AudioError::Silent.into());
    }
    let median = med.finish().ok_or(ScanError::MedianLost)?;
    let ratio = f64::from(global) / f64::from(median).max(1e-30);
    if ratio.is_nan() || ratio < MIN_PEAK_RATIO {
        return Err(
            AudioError::NoChirp { ratio: if ratio.is_finite() { ratio } else { 0.0 }, need: MIN_PEAK_RATIO }.into()
        );
    }
    let thr = (MIN_PEAK_RATIO as f32 * median).max(0.01 * global);
    cands.retain(|c| c.1 >= thr);
    cands.sort_by(|a, b| b.1.total_cmp(&a.1));
    let before = ((0.9 * m as f64) as usize).max(1);
    let echo = (max_echo_delay_s.max(0.0) * tpl.sample_rate_hz).ceil();
    if !echo.is_finite() || echo > len as f64 {
        return Err(AudioError::InvalidParam {
            field: "--max-delta-d",
            reason: format!("an echo delay of {max_echo_delay_s} s is longer than the recording"),
        }
        .into());
    }
    let tpl_norm = tpl.real.iter().map(|v| f64::from(*v) * f64::from(*v)).sum::<f64>().sqrt();
    Ok(Scan {
        len,
        nfft,
        m,
        rate_hz: tpl.sample_rate_hz,
        duration_s: tpl.chirp.duration_s(),
        median,
        cands,
        before,
        after: m + echo as usize,
        tpl_norm,
    })
}

/// What the greedy selection of `detect_chirps` gave with the normalised
/// correlations known so far.
#[derive(Debug)]
pub enum Selection {
    /// The detections (or the error) `detect_chirps` gives.
    Done(Result<Vec<Detection>, AudioError>),
    /// The selection with unknown correlations taken as passing; the
    /// correlations at these lags are needed to finish it.
    Tentative {
        /// Onsets the selection accepted (sorted).
        onsets: Vec<usize>,
        /// Lags whose normalised correlation is needed.
        need: Vec<(usize, f32)>,
    },
}

impl Scan {
    /// Template length (samples).
    pub fn template_len(&self) -> usize {
        self.m
    }

    /// The normalised correlation at `lag` with `|c|`, given the samples
    /// `x[lag..min(lag + m, len)]`: the same sum, in the same order, as `detect_chirps`.
    pub fn ncc(&self, window: &[f32], c: f32) -> f64 {
        let energy: f64 = window.iter().map(|v| f64::from(*v) * f64::from(*v)).sum();
        let e = energy.sqrt() * self.tpl_norm * self.nfft as f64;
        if e > 0.0 { (f64::from(c) / e).min(1.0) } else { 0.0 }
    }

    /// Runs the greedy selection of `detect_chirps` with the normalised
    /// correlations in `known`.
    pub fn select(&self, known: &HashMap<usize, f64>) -> Selection {
        let mut need = Vec::new();
        let mut accepted: BTreeMap<usize, f32> = BTreeMap::new();
        let mut out = Vec::new();
        let mut best_ncc = 0.0f64;
        for &(lag, c) in &self.cands {
            let mut near = accepted.range(lag.saturating_sub(self.after)..=lag + self.before).peekable();
            if near.peek().is_some() {
                if let Some((&a, _)) = near.find(|&(&a, &ca)| a + self.before < lag && c >= 0.5 * ca) {
                    let Some(&ncc) = known.get(&lag) else {
                        // Unknown: the rest depends on it.
                        need.push((lag, c));
                        break;
                    };
                    best_ncc = best_ncc.max(ncc);
                    if ncc >= MIN_NCC && need.is_empty() {
                        return Selection::Done(Err(AudioError::InvalidParam {
                            field: "--max-delta-d",
                            reason: format!(
                                "chirps {:.3} s apart but the echo window is T + max Δd/a = {:.3} s; \
                                 lower --max-delta-d below a·(chirp spacing − T)",
                                (lag - a) as f64 / self.rate_hz,
                                self.after as f64 / self.rate_hz
                            ),
                        }));
                    }
                    if ncc >= MIN_NCC {
                        break;
                    }
                }
                continue;
            }
            let ncc = match known.get(&lag) {
                Some(&v) => v,
                None => {
                    need.push((lag, c));
                    1.0
                }
            };
            best_ncc = best_ncc.max(ncc);
            if ncc < MIN_NCC {
                continue;
            }
            accepted.insert(lag, c);
            out.push(Detection { onset_sample: lag, strength: f64::from(c) / f64::from(self.median).max(1e-30), ncc });
        }
        if !need.is_empty() {
            return Selection::Tentative { onsets: accepted.into_keys().collect(), need };
        }
        if out.is_empty() {
            return Selection::Done(Err(AudioError::NoChirpShape { ncc: best_ncc, need: MIN_NCC }));
        }
        out.sort_by_key(|d| d.onset_sample);
        Selection::Done(Ok(out))
    }

    /// Chirp duration (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }
}

/// A second read of a stream, serving windows `[start, end)` of it (sorted
/// by `start`) in order, while holding one window and one block.
pub fn for_windows(
    src: &mut dyn BlockSource,
    len: usize,
    windows: &[(usize, usize)],
    mut serve: impl FnMut(usize, &[f32]),
) -> Result<(), AudioError> {
    let mut x: Vec<f32> = Vec::new();
    let mut x0 = 0usize;
    for (i, &(start, end)) in windows.iter().enumerate() {
        let end = end.min(len);
        let start = start.min(end);
        if start < x0 {
            return Err(AudioError::InvalidParam { field: "windows", reason: "not sorted by start".into() });
        }
        if start >= x0 + x.len() + BLOCK
            && let Some(at) = src.seek_before(start)?
            && at > x0 + x.len()
        {
            // Jump over samples no window needs.
            x.clear();
            x0 = at;
        }
        let d = (start - x0).min(x.len());
        x.drain(..d);
        x0 += d;
        while x0 + x.len() < end {
            if src.read(&mut x, BLOCK)? == 0 {
                return Err(AudioError::Truncated(format!("the stream ended before sample {end} of {len}")));
            }
            let d = (start - x0).min(x.len());
            x.drain(..d);
            x0 += d;
        }
        serve(i, &x[start - x0..end - x0]);
    }
    Ok(())
}

/// Finishes the detection of a [`Scan`] and visits every chirp's window
/// in a second read of the stream (a third only when a chirp's normalised
/// correlation changes which chirps are accepted). `open` reopens the
/// stream from its start; each chirp's window is `before` samples before
/// its onset to `after` samples after it (clipped to the stream).
/// `start(onsets)` makes the per-read state, `visit(state, k, window,
/// onset within window)` is called for chirp `k` in order of onset. The
/// detections are `detect_chirps`' and the state is from a read whose
/// onsets are theirs.
pub fn visit_chirps<S: BlockSource, T>(
    scan: &Scan,
    mut open: impl FnMut() -> Result<S, AudioError>,
    before: usize,
    after: usize,
    mut start: impl FnMut(&[usize]) -> T,
    mut visit: impl FnMut(&mut T, usize, &[f32], usize),
) -> Result<(Vec<Detection>, T), AudioError> {
    let m = scan.m;
    let mut known: HashMap<usize, f64> = HashMap::new();
    let mut picked: Option<(Vec<usize>, T)> = None;
    loop {
        let (onsets, need, done) = match scan.select(&known) {
            Selection::Done(Err(e)) => return Err(e),
            Selection::Done(Ok(d)) => {
                let onsets: Vec<usize> = d.iter().map(|d| d.onset_sample).collect();
                if let Some((p, state)) = picked.take()
                    && p == onsets
                {
                    return Ok((d, state));
                }
                (onsets, Vec::new(), Some(d))
            }
            Selection::Tentative { onsets, need } => (onsets, need, None),
        };
        // (start, end, what): what < need.len() → a correlation, else chirp what − need.len().
        let mut windows: Vec<(usize, usize, usize)> =
            need.iter().enumerate().map(|(i, &(lag, _))| (lag, lag + m, i)).collect();
        windows.extend(onsets.iter().enumerate().map(|(k, &o)| (o.saturating_sub(before), o + after, need.len() + k)));
        windows.sort_by_key(|w| w.0);
        let ranges: Vec<(usize, usize)> = windows.iter().map(|w| (w.0, w.1)).collect();
        let mut state = start(&onsets);
        let mut src = open()?;
        for_windows(&mut src, scan.len, &ranges, |i, x| {
            let (w0, _, what) = windows[i];
            if what < need.len() {
                known.insert(need[what].0, scan.ncc(x, need[what].1));
            } else {
                let k = what - need.len();
                visit(&mut state, k, x, onsets[k] - w0);
            }
        })?;
        if let Some(d) = done {
            return Ok((d, state));
        }
        picked = Some((onsets, state));
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::detect::detect_chirps;
    use proptest::prelude::*;

    struct Mem(Vec<f32>, usize);
    impl BlockSource for Mem {
        fn read(&mut self, out: &mut Vec<f32>, max: usize) -> Result<usize, AudioError> {
            let n = max.min(self.0.len() - self.1);
            out.extend_from_slice(&self.0[self.1..self.1 + n]);
            self.1 += n;
            Ok(n)
        }
    }

    fn xorshift(r: &mut u64) -> f32 {
        *r ^= *r << 13;
        *r ^= *r >> 7;
        *r ^= *r << 17;
        (*r >> 40) as f32 / 16_777_216.0
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// The windowed median against sorting everything (the oracle),
        /// with windows narrowed many times; a drifting level may lose it,
        /// never give a wrong value.
        #[test]
        fn median_window_is_exact_or_says_so(n in 1usize..3000, cap in 8usize..200, drift in 0.0f32..3.0, seed in any::<u64>()) {
            let mut r = seed | 1;
            let v: Vec<f32> = (0..n).map(|i| xorshift(&mut r) * (1.0 + drift * i as f32 / n as f32)).collect();
            let mut w = MedianWindow::new(cap);
            for &x in &v {
                w.push(x);
            }
            let mut sorted = v.clone();
            sorted.sort_by(f32::total_cmp);
            if let Some(m) = w.finish() {
                prop_assert_eq!(m.to_bits(), sorted[n / 2].to_bits());
            } else {
                prop_assert!(drift > 0.0, "a stationary stream lost its median");
            }
        }

        /// The streamed detection gives `detect_chirps`' detections (onsets,
        /// strengths, correlations) or its error, with the median window
        /// narrowed and the samples served in blocks of any size.
        #[test]
        fn streamed_detection_is_detect_chirps(
            n_chirps in 0usize..6,
            gap in 300usize..3000,
            noise in 0.0f32..0.5,
            cap in 16usize..5000,
            seed in any::<u64>(),
        ) {
            let fs = 8000.0;
            let tpl = ChirpTemplate::new(chirpmap_core::LinearChirp::new(3000.0, 200.0, 0.1).unwrap(), fs).unwrap();
            let m = tpl.len();
            let mut r = seed | 1;
            let len = 500 + n_chirps * (m + gap) + 700;
            let mut x: Vec<f32> = (0..len).map(|_| noise * (xorshift(&mut r) - 0.5)).collect();
            for k in 0..n_chirps {
                let at = 500 + k * (m + gap) + (xorshift(&mut r) * 50.0) as usize;
                for (i, t) in tpl.real.iter().enumerate() {
                    x[at + i] += t;
                    if at + i + 120 < len {
                        x[at + i + 120] += 0.3 * t;
                    }
                }
            }
            let mut cache = FftCache::default();
            let max_delay = 0.02;
            let want = detect_chirps(&x, &tpl, &mut cache, max_delay);
            let mut src = Mem(x.clone(), 0);
            let got = match scan_with_cap(&mut src, len, &tpl, max_delay, cap) {
                Err(ScanError::MedianLost) => return Ok(()),
                Err(ScanError::Audio(e)) => Err(e),
                Ok(scan) => {
                    let mut known = HashMap::new();
                    loop {
                        match scan.select(&known) {
                            Selection::Done(d) => break d,
                            Selection::Tentative { need, .. } => {
                                for (lag, c) in need {
                                    known.insert(lag, scan.ncc(&x[lag..(lag + m).min(len)], c));
                                }
                            }
                        }
                    }
                }
            };
            match (want, got) {
                (Ok(a), Ok(b)) => {
                    prop_assert_eq!(a.len(), b.len());
                    for (p, q) in a.iter().zip(&b) {
                        prop_assert_eq!(p.onset_sample, q.onset_sample);
                        prop_assert_eq!(p.strength.to_bits(), q.strength.to_bits());
                        prop_assert_eq!(p.ncc.to_bits(), q.ncc.to_bits());
                    }
                }
                (Err(a), Err(b)) => prop_assert_eq!(a.to_string(), b.to_string()),
                (a, b) => prop_assert!(false, "detect_chirps {:?}, streamed {:?}", a, b),
            }
        }
    }
}
