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

/// What a scan does with the windows of likely chirps as it passes them
/// (see [`scan_visiting`]).
pub struct Visitor<'a, R> {
    /// Samples of each window before the onset.
    pub before: usize,
    /// Samples of each window from the onset (at least the template's length).
    pub after: usize,
    /// Called with a window (clipped to the stream) and the onset's index in it,
    /// from any thread, in any order.
    pub visit: &'a (dyn Fn(&[f32], usize) -> R + Sync),
}

impl<R> std::fmt::Debug for Visitor<'_, R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Visitor").field("before", &self.before).field("after", &self.after).finish_non_exhaustive()
    }
}

/// One `T` per thread of rayon's current pool (and one for any other
/// thread): the caches of a [`Visitor`] called from several threads.
#[derive(Debug)]
pub struct PerThread<T> {
    slots: Vec<std::sync::Mutex<T>>,
}

impl<T: Default> Default for PerThread<T> {
    fn default() -> Self {
        Self { slots: (0..=rayon::current_num_threads()).map(|_| std::sync::Mutex::default()).collect() }
    }
}

impl<T> PerThread<T> {
    /// `f` with this thread's `T`.
    pub fn with<U>(&self, f: impl FnOnce(&mut T) -> U) -> U {
        let last = self.slots.len() - 1;
        let i = rayon::current_thread_index().map_or(last, |i| i.min(last));
        let mut t = self.slots[i].lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        f(&mut t)
    }
}

/// What a scan computed for the likely chirps it passed: the inputs the
/// chirp selection and the caller would otherwise read a second time.
#[derive(Debug)]
pub struct Visits<R> {
    /// Normalised correlation ([`Scan::ncc`]) at each visited onset.
    pub ncc: HashMap<usize, f64>,
    /// What the visitor returned, by onset.
    pub results: HashMap<usize, R>,
}

impl<R> Default for Visits<R> {
    fn default() -> Self {
        Self { ncc: HashMap::new(), results: HashMap::new() }
    }
}

impl<R> Visits<R> {
    /// Records what [`visit_all`] returned.
    fn extend(&mut self, got: Vec<(usize, f64, R)>) {
        for (onset, ncc, r) in got {
            self.ncc.insert(onset, ncc);
            self.results.insert(onset, r);
        }
    }
}

/// First pass of [`crate::detect::detect_chirps`] over a stream of `len`
/// high-passed samples (the same errors, in the same order, for the same samples).
pub fn scan_chirps<S: BlockSource + Send + ?Sized>(
    src: &mut S,
    len: usize,
    tpl: &ChirpTemplate,
    max_echo_delay_s: f64,
) -> Result<Scan, ScanError> {
    scan_with_cap::<S, ()>(src, len, tpl, max_echo_delay_s, MEDIAN_CAP, None).map(|(s, _)| s)
}

/// [`scan_chirps`] that also visits, on the way, the window of every matched-filter
/// peak that is likely a chirp (the strongest within the chirp selection's own
/// spans, well above the level of its FFT block), and computes its normalised
/// correlation, while those samples are still at hand: with a visitor that
/// ranges a chirp, one read of the stream serves both the detection and the
/// ranging (speculative: the selection, exact and unchanged, decides later
/// which visits count; a chirp it accepts without a visit is read again).
///
/// Reading and high-passing the next FFT block (and the visits) run
/// alongside the current block's correlation (`rayon::join`: in parallel
/// when rayon has two threads). Every value is computed by the same code
/// from the same samples whatever the thread count, so the results are the
/// same bit for bit.
pub fn scan_visiting<S: BlockSource + Send + ?Sized, R: Send>(
    src: &mut S,
    len: usize,
    tpl: &ChirpTemplate,
    max_echo_delay_s: f64,
    visitor: Visitor<'_, R>,
) -> Result<(Scan, Visits<R>), ScanError> {
    scan_with_cap(src, len, tpl, max_echo_delay_s, MEDIAN_CAP, Some(visitor))
}

/// Per-chunk maxima of one FFT block pair: `(chunk, max |c|, lag % CHUNK
/// of the first lag reaching it)`, partial chunks at the ends included.
type Segments = Vec<(usize, f32, u32)>;

/// Samples kept from a stream: consecutive blocks as read (never copied
/// into one buffer), the first starting at sample `x0`.
#[derive(Debug, Default)]
struct Kept {
    blocks: std::collections::VecDeque<Vec<f32>>,
    x0: usize,
    end: usize,
    /// Emptied blocks, for the next reads (no fresh pages per block).
    spare: Vec<Vec<f32>>,
}

impl Kept {
    fn push(&mut self, b: Vec<f32>) {
        self.end += b.len();
        if b.is_empty() {
            self.spare.push(b);
        } else {
            self.blocks.push_back(b);
        }
    }
    fn fresh(&mut self) -> Vec<f32> {
        self.spare.pop().unwrap_or_default()
    }
    /// Drops the blocks that end at or before `pos`; `any_nonzero` learns
    /// whether any of their samples was not zero.
    fn drop_before(&mut self, pos: usize, any_nonzero: &mut bool) {
        while let Some(b) = self.blocks.front() {
            if self.x0 + b.len() > pos {
                break;
            }
            *any_nonzero = *any_nonzero || b.iter().any(|v| *v != 0.0);
            self.x0 += b.len();
            if let Some(mut b) = self.blocks.pop_front() {
                b.clear();
                self.spare.push(b);
            }
        }
    }
    /// The kept samples of `[from, to)`, in order, as slices.
    fn pieces(&self, from: usize, to: usize) -> impl Iterator<Item = &[f32]> {
        let mut at = self.x0;
        self.blocks.iter().filter_map(move |b| {
            let (b0, b1) = (at, at + b.len());
            at = b1;
            let (lo, hi) = (from.max(b0), to.min(b1));
            (lo < hi).then(|| &b[lo - b0..hi - b0])
        })
    }
    /// Samples `[from, to)` (all kept) as one slice: borrowed when one block
    /// holds them, else copied into `scratch`.
    fn window<'s>(&'s self, from: usize, to: usize, scratch: &'s mut Vec<f32>) -> &'s [f32] {
        let mut it = self.pieces(from, to);
        match (it.next(), it.next()) {
            (Some(p), None) => p,
            (first, second) => {
                scratch.clear();
                scratch.extend(first.into_iter().chain(second).chain(it).flatten());
                scratch
            }
        }
    }
}

/// Fills `buf` with the kept samples from `re_from` on as real parts and,
/// with `im_from`, those from `im_from` on as imaginary parts, zeros past what
/// is kept: the two real blocks of one complex FFT, written in one pass (a
/// second pass writing the imaginary parts alone re-read and re-wrote the
/// 2 MB buffer for every block pair).
fn fill_pair(kept: &Kept, re_from: usize, im_from: Option<usize>, buf: &mut [Complex32]) {
    let n = buf.len();
    let mut re = kept.pieces(re_from, re_from + n);
    let mut im = im_from.into_iter().flat_map(|f| kept.pieces(f, f + n));
    // Pieces are never empty: an empty slice means "take the next one".
    let (mut a, mut b): (&[f32], &[f32]) = (&[], &[]);
    let mut k = 0;
    while k < n {
        if a.is_empty() {
            a = re.next().unwrap_or_default();
        }
        if b.is_empty() {
            b = im.next().unwrap_or_default();
        }
        let m = match (a.len(), b.len()) {
            (0, 0) => break,
            (0, m) | (m, 0) => m,
            (la, lb) => la.min(lb),
        };
        let dst = &mut buf[k..k + m];
        if b.is_empty() {
            dst.iter_mut().zip(&a[..m]).for_each(|(d, x)| *d = Complex32::new(*x, 0.0));
        } else if a.is_empty() {
            dst.iter_mut().zip(&b[..m]).for_each(|(d, y)| *d = Complex32::new(0.0, *y));
        } else {
            dst.iter_mut().zip(&a[..m]).zip(&b[..m]).for_each(|((d, x), y)| *d = Complex32::new(*x, *y));
        }
        a = &a[m.min(a.len())..];
        b = &b[m.min(b.len())..];
        k += m;
    }
    buf[k..].fill(Complex32::new(0.0, 0.0));
}

/// Correlates the block pair starting at lag `s` (samples from `kept`) and
/// writes its chunk maxima to `segs`, in lag order: the same values,
/// compared in the same order, as `detect_chirps`. With `level`, also
/// returns the median of the chunk maxima.
#[allow(clippy::too_many_arguments)]
fn correlate_pair(
    kept: &Kept,
    s: usize,
    step: usize,
    n_lags: usize,
    h: &[Complex32],
    plans: (&dyn rustfft::Fft<f32>, &dyn rustfft::Fft<f32>),
    buf: &mut [Complex32],
    scratch: &mut [Complex32],
    segs: &mut Segments,
    level: bool,
) -> Option<f32> {
    let (fwd, inv) = plans;
    let s2 = s + step;
    // Samples past the stream's end are zeros.
    fill_pair(kept, s, (s2 < n_lags).then_some(s2), buf);
    fwd.process_with_scratch(buf, scratch);
    for (b, hh) in buf.iter_mut().zip(h) {
        *b *= hh;
    }
    inv.process_with_scratch(buf, scratch);
    segs.clear();
    for (start, part) in [(s, 0usize), (s2, 1usize)] {
        if start >= n_lags {
            continue;
        }
        let end = (start + step).min(n_lags);
        let mut lag = start;
        while lag < end {
            let stop = ((lag / CHUNK + 1) * CHUNK).min(end);
            let (mut mx, mut arg) = (0.0f32, 0u32);
            for (j, c) in buf[lag - start..stop - start].iter().enumerate() {
                let v = if part == 0 { c.re } else { c.im }.abs();
                if v > mx {
                    mx = v;
                    arg = ((lag + j) % CHUNK) as u32;
                }
            }
            segs.push((lag / CHUNK, mx, arg));
            lag = stop;
        }
    }
    (level && !segs.is_empty()).then(|| {
        let mut vals: Vec<f32> = segs.iter().map(|g| g.1).collect();
        let mid = vals.len() / 2;
        *vals.select_nth_unstable_by(mid, f32::total_cmp).1
    })
}

/// Matched-filter peaks that are the strongest within the chirp selection's
/// spans (nothing as strong up to `after` lags before, nothing stronger up to
/// `before` lags after): the likely chirps a scan visits.
#[derive(Debug, Default)]
struct Peaks {
    before: usize,
    after: usize,
    /// Earlier values, non-increasing from front to back (a sliding maximum).
    recent: std::collections::VecDeque<(usize, f32)>,
    /// Peaks not yet passed by `before` lags.
    pending: std::collections::VecDeque<(usize, f32)>,
}

impl Peaks {
    fn push(&mut self, lag: usize, v: f32) {
        while self.recent.front().is_some_and(|r| r.0 + self.after < lag) {
            self.recent.pop_front();
        }
        let dominated = self.recent.front().is_some_and(|r| r.1 >= v);
        while self.recent.back().is_some_and(|r| r.1 < v) {
            self.recent.pop_back();
        }
        self.recent.push_back((lag, v));
        let before = self.before;
        self.pending.retain(|p| !(p.0 + before >= lag && p.1 < v));
        if !dominated {
            self.pending.push_back((lag, v));
        }
    }
    /// Moves to `out` the peaks whose spans end before lag `upto` (every
    /// later value is at or after `upto`).
    fn settled(&mut self, upto: usize, out: &mut Vec<(usize, f32)>) {
        while let Some(&p) = self.pending.front() {
            if p.0 + self.before >= upto {
                break;
            }
            out.push(p);
            self.pending.pop_front();
        }
    }
}

/// The running state of a scan's chunk maxima, fed in lag order.
#[derive(Debug)]
struct Chunks {
    med: MedianWindow,
    global: f32,
    cands: Vec<(usize, f32)>,
    cur: (usize, f32, u32),
    peaks: Option<Peaks>,
}

impl Chunks {
    /// One chunk's maximum is final.
    fn close(&mut self, visit_floor: f32) {
        let (ci, v, arg) = self.cur;
        let lag = ci * CHUNK + arg as usize;
        self.global = self.global.max(v);
        if self.med.push(v) {
            let floor = MIN_PEAK_RATIO as f32 * self.med.floor();
            self.cands.retain(|c| c.1 >= floor);
        }
        // The final threshold is at least 12 × the median and 1 % of the largest
        // maximum, which only grows: a chunk below either bound now never passes.
        if v >= MIN_PEAK_RATIO as f32 * self.med.floor() && v >= 0.01 * self.global {
            self.cands.push((lag, v));
        }
        if let Some(p) = self.peaks.as_mut()
            && v >= visit_floor
            && v >= 0.01 * self.global
            && v > 0.0
        {
            p.push(lag, v);
        }
    }
    fn feed(&mut self, segs: &Segments, visit_floor: f32) {
        for &(ci, v, arg) in segs {
            if ci != self.cur.0 {
                self.close(visit_floor);
                self.cur = (ci, 0.0, 0);
            }
            if v > self.cur.1 {
                self.cur.1 = v;
                self.cur.2 = arg;
            }
        }
    }
}

/// Visits the windows of `due` (all within `kept`) in parallel, adding
/// their correlations and results to `visits`.
#[allow(clippy::too_many_arguments)]
fn visit_all<R: Send>(
    kept: &Kept,
    due: &[(usize, f32)],
    len: usize,
    m: usize,
    (w_before, w_after): (usize, usize),
    ncc_of: &(dyn Fn(&[f32], f32) -> f64 + Sync),
    visit: &(dyn Fn(&[f32], usize) -> R + Sync),
) -> Vec<(usize, f64, R)> {
    use rayon::prelude::*;
    due.par_iter()
        .with_max_len(1)
        .map_init(Vec::new, |scratch, &(onset, c)| {
            let (w0, w1) = (onset.saturating_sub(w_before), (onset + w_after).min(len));
            // Only whole windows (a window not kept whole is left to a second read).
            if w0 < kept.x0 || w1 > kept.end {
                return None;
            }
            let w = kept.window(w0, w1, scratch);
            let ncc = ncc_of(&w[onset - w0..(onset + m - w0).min(w.len())], c);
            Some((onset, ncc, visit(w, onset - w0)))
        })
        .flatten()
        .collect()
}

#[allow(clippy::too_many_lines)]
fn scan_with_cap<S: BlockSource + Send + ?Sized, R: Send>(
    src: &mut S,
    len: usize,
    tpl: &ChirpTemplate,
    max_echo_delay_s: f64,
    median_cap: usize,
    visitor: Option<Visitor<'_, R>>,
) -> Result<(Scan, Visits<R>), ScanError> {
    let m = tpl.len();
    if m == 0 || m > len {
        return Err(AudioError::ChirpLongerThanRecording {
            chirp_s: tpl.chirp.duration_s(),
            recording_s: len as f64 / tpl.sample_rate_hz,
        }
        .into());
    }
    let nfft = (4 * m).next_power_of_two().max(1 << 14);
    let step = nfft - m + 1;
    let n_lags = len - m + 1;
    let need_of = |s: usize| (s + step + nfft).min(len);
    // Before the scan can start: the template's spectrum (with the forward
    // plan), the inverse plan and the first block pair's samples, three
    // independent jobs (~9, ~5 and ~7 ms for a 1 s chirp at 48 kHz; run one
    // after the other they were 5 % of a 10-min `range`). A plan depends only
    // on its size and direction, so the separate planners give the same FFTs.
    let mut kept = Kept::default();
    let mut first = kept.fresh();
    let ((h, fwd), (inv, eof)) = rayon::join(
        || {
            let mut cache = FftCache::default();
            let h = tpl.conj_spectrum(&mut cache, nfft);
            (h, cache.plan(nfft, false))
        },
        || {
            rayon::join(
                || FftCache::default().plan(nfft, true),
                || -> Result<bool, AudioError> {
                    let mut eof = false;
                    while first.len() < need_of(0) && !eof {
                        eof = src.read(&mut first, BLOCK)? == 0;
                    }
                    Ok(eof)
                },
            )
        },
    );
    let mut eof = eof?;
    kept.push(first);
    let mut buf = vec![Complex32::new(0.0, 0.0); nfft];
    let mut scratch = vec![Complex32::new(0.0, 0.0); fwd.get_inplace_scratch_len().max(inv.get_inplace_scratch_len())];
    let tpl_norm = tpl.real.iter().map(|v| f64::from(*v) * f64::from(*v)).sum::<f64>().sqrt();
    let ncc_of = |window: &[f32], c: f32| ncc_value(window, c, tpl_norm, nfft);
    // The selection's spans (the same as `detect_chirps`'), for the peaks visited.
    let sel_before = ((0.9 * m as f64) as usize).max(1);
    let echo = (max_echo_delay_s.max(0.0) * tpl.sample_rate_hz).ceil();
    let sel_after = m + if echo.is_finite() { echo.min(len as f64) as usize } else { len };
    let mut st = Chunks {
        med: MedianWindow::new(median_cap),
        global: 0.0,
        cands: Vec::new(),
        cur: (0, 0.0, 0),
        peaks: visitor.as_ref().map(|_| Peaks { before: sel_before, after: sel_after, ..Peaks::default() }),
    };
    let spans = visitor.as_ref().map_or((0, 0), |v| (v.before, v.after.max(m)));
    // The windows of the peaks `due` visited (nothing without a visitor).
    let visit_due = |kept: &Kept, due: &[(usize, f32)]| match visitor.as_ref() {
        Some(v) => visit_all(kept, due, len, m, spans, &ncc_of, v.visit),
        None => Vec::new(),
    };
    let mut visits = Visits::default();
    // Peaks whose windows are still to visit, in onset order.
    let mut due: Vec<(usize, f32)> = Vec::new();
    let mut any_nonzero = false;
    // Chunk maxima of the pair before (fed while this pair is correlated) and of this pair.
    let (mut prev, mut segs): (Option<(Segments, f32)>, Segments) = (None, Vec::new());
    let mut s = 0usize;
    while s < n_lags {
        if kept.end < need_of(s) {
            return Err(AudioError::Truncated(format!("the stream ended after {} of {len} samples", kept.end)).into());
        }
        // While this pair is correlated: the next pair's samples are read and
        // high-passed, the pair before's maxima are fed to the selection's
        // state, and the windows due are visited.
        let target = if s + 2 * step < n_lags { need_of(s + 2 * step) } else { len };
        let now: Vec<(usize, f32)> = {
            let k = due.partition_point(|&(o, _)| (o + spans.1).min(len) <= kept.end);
            due.drain(..k).collect()
        };
        let mut next = kept.fresh();
        let kept_ref = &kept;
        let visiting = visitor.is_some();
        let (level, (read, got)) = rayon::join(
            || {
                correlate_pair(
                    kept_ref,
                    s,
                    step,
                    n_lags,
                    &h,
                    (&*fwd, &*inv),
                    &mut buf,
                    &mut scratch,
                    &mut segs,
                    visiting,
                )
            },
            || {
                rayon::join(
                    || -> Result<bool, AudioError> {
                        let mut eof = eof;
                        while kept_ref.end + next.len() < target && !eof {
                            eof = src.read(&mut next, BLOCK)? == 0;
                        }
                        if let Some((segs, floor)) = prev.take() {
                            st.feed(&segs, floor);
                            if let Some(p) = st.peaks.as_mut() {
                                p.settled(st.cur.0 * CHUNK, &mut due);
                            }
                        }
                        Ok(eof)
                    },
                    || visit_due(kept_ref, &now),
                )
            },
        );
        eof = read?;
        kept.push(next);
        visits.extend(got);
        let floor = level.map_or(f32::INFINITY, |l| MIN_PEAK_RATIO as f32 * l);
        prev = Some((std::mem::take(&mut segs), floor));
        s += 2 * step;
        // Keep what the next block pair reads and the windows still to visit
        // (a later peak's window starts at most `w_before` before the chunk still open).
        let mut keep_from = s;
        if let Some(p) = st.peaks.as_ref() {
            let first = due.first().or(p.pending.front()).map_or(st.cur.0 * CHUNK, |p| p.0.min(st.cur.0 * CHUNK));
            keep_from = keep_from.min(first.saturating_sub(spans.0));
        }
        kept.drop_before(keep_from, &mut any_nonzero);
    }
    if let Some((segs, floor)) = prev.take() {
        st.feed(&segs, floor);
    }
    st.close(0.0);
    if let Some(p) = st.peaks.as_mut() {
        p.settled(usize::MAX, &mut due);
    }
    let Chunks { med, global, mut cands, .. } = st;
    // The last peaks (every window ends within the samples read) while the median is found.
    let (median, got) = rayon::join(|| med.finish(), || visit_due(&kept, &due));
    visits.extend(got);
    // The rest of the stream (samples after the last lag's template).
    kept.drop_before(usize::MAX, &mut any_nonzero);
    let mut x0 = kept.x0;
    let mut x = Vec::new();
    while !eof {
        x.clear();
        eof = src.read(&mut x, BLOCK)? == 0;
        any_nonzero = any_nonzero || x.iter().any(|v| *v != 0.0);
        x0 += x.len();
    }
    if x0 != len {
        return Err(AudioError::Truncated(format!("the stream held {x0} samples, not {len}")).into());
    }
    if !any_nonzero {
        return Err(AudioError::Silent.into());
    }
    let median = median.ok_or(ScanError::MedianLost)?;
    let ratio = f64::from(global) / f64::from(median).max(1e-30);
    if ratio.is_nan() || ratio < MIN_PEAK_RATIO {
        return Err(
            AudioError::NoChirp { ratio: if ratio.is_finite() { ratio } else { 0.0 }, need: MIN_PEAK_RATIO }.into()
        );
    }
    let thr = (MIN_PEAK_RATIO as f32 * median).max(0.01 * global);
    cands.retain(|c| c.1 >= thr);
    cands.sort_by(|a, b| b.1.total_cmp(&a.1));
    if !echo.is_finite() || echo > len as f64 {
        return Err(AudioError::InvalidParam {
            field: "--max-delta-d",
            reason: format!("an echo delay of {max_echo_delay_s} s is longer than the recording"),
        }
        .into());
    }
    Ok((
        Scan {
            len,
            nfft,
            m,
            rate_hz: tpl.sample_rate_hz,
            duration_s: tpl.chirp.duration_s(),
            median,
            cands,
            before: sel_before,
            // `echo` is finite and at most `len` here, so this is `m + echo`.
            after: sel_after,
            tpl_norm,
        },
        visits,
    ))
}

/// The normalised correlation of `detect_chirps` (the same sum, in the same order).
fn ncc_value(window: &[f32], c: f32, tpl_norm: f64, nfft: usize) -> f64 {
    let energy: f64 = window.iter().map(|v| f64::from(*v) * f64::from(*v)).sum();
    let e = energy.sqrt() * tpl_norm * nfft as f64;
    if e > 0.0 { (f64::from(c) / e).min(1.0) } else { 0.0 }
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
        ncc_value(window, c, self.tpl_norm, self.nfft)
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

/// Finishes the detection of a [`Scan`]: the greedy selection of
/// `detect_chirps` with the normalised correlations in `known` (from
/// [`Visits::ncc`], or empty), reading from `open()`'s stream the windows of
/// those it still needs (and adding them to `known`). The detections (or the
/// error) `detect_chirps` gives.
pub fn select_reading<S: BlockSource>(
    scan: &Scan,
    known: &mut HashMap<usize, f64>,
    mut open: impl FnMut() -> Result<S, AudioError>,
) -> Result<Vec<Detection>, AudioError> {
    loop {
        match scan.select(known) {
            Selection::Done(d) => return d,
            Selection::Tentative { mut need, .. } => {
                need.sort_by_key(|n| n.0);
                let ranges: Vec<(usize, usize)> = need.iter().map(|&(lag, _)| (lag, lag + scan.m)).collect();
                let mut src = open()?;
                for_windows(&mut src, scan.len, &ranges, |i, x| {
                    known.insert(need[i].0, scan.ncc(x, need[i].1));
                })?;
            }
        }
    }
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
            let (x, tpl) = chirps_in_noise(n_chirps, gap, noise, seed);
            let (m, len) = (tpl.len(), x.len());
            let mut cache = FftCache::default();
            let max_delay = 0.02;
            let want = detect_chirps(&x, &tpl, &mut cache, max_delay);
            let mut src = Mem(x.clone(), 0);
            let got = match scan_with_cap::<_, ()>(&mut src, len, &tpl, max_delay, cap, None) {
                Err(ScanError::MedianLost) => return Ok(()),
                Err(ScanError::Audio(e)) => Err(e),
                Ok((scan, _)) => {
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

    /// A test signal: chirps of 0.1 s at 8 kHz with an echo, in noise.
    fn chirps_in_noise(n_chirps: usize, gap: usize, noise: f32, seed: u64) -> (Vec<f32>, ChirpTemplate) {
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
        (x, tpl)
    }

    /// What the test visitor returns: the window's length, the onset in it and its samples' bits.
    fn fingerprint(w: &[f32], r: usize) -> (usize, usize, u64) {
        (w.len(), r, w.iter().fold(0u64, |h, v| h.rotate_left(5) ^ u64::from(v.to_bits())))
    }

    type Visited = (Vec<(usize, f64, (usize, usize, u64))>, Vec<Detection>);

    /// The scan with a visitor, in a pool of `threads`, blocks of `block` samples.
    fn visited(
        x: &[f32],
        tpl: &ChirpTemplate,
        (before, after): (usize, usize),
        threads: usize,
        block: usize,
    ) -> Visited {
        struct Blocks<'a>(&'a [f32], usize, usize);
        impl BlockSource for Blocks<'_> {
            fn read(&mut self, out: &mut Vec<f32>, max: usize) -> Result<usize, AudioError> {
                let n = max.min(self.2).min(self.0.len() - self.1);
                out.extend_from_slice(&self.0[self.1..self.1 + n]);
                self.1 += n;
                Ok(n)
            }
        }
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut src = Blocks(x, 0, block);
            let visit = |w: &[f32], r: usize| fingerprint(w, r);
            let (scan, v) =
                scan_with_cap(&mut src, x.len(), tpl, 0.02, MEDIAN_CAP, Some(Visitor { before, after, visit: &visit }))
                    .unwrap();
            let mut known = v.ncc.clone();
            let dets = select_reading(&scan, &mut known, || Ok(Blocks(x, 0, block))).unwrap();
            let mut got: Vec<_> = v.results.into_iter().map(|(o, r)| (o, v.ncc[&o], r)).collect();
            got.sort_by_key(|g| g.0);
            (got, dets)
        })
    }

    /// The visits of one read are what a second read of each window gives,
    /// every detected chirp is visited, the detections are `detect_chirps'`,
    /// and one thread or four give the same values bit for bit.
    #[test]
    fn visits_are_the_windows_and_do_not_depend_on_threads() {
        for (n_chirps, gap, noise, seed) in [(40usize, 900usize, 0.05f32, 7u64), (25, 2500, 0.3, 11), (3, 400, 0.0, 5)]
        {
            let (x, tpl) = chirps_in_noise(n_chirps, gap, noise, seed);
            let m = tpl.len();
            let spans = (40, m + 200);
            let (got, dets) = visited(&x, &tpl, spans, 1, 1000);
            let want = detect_chirps(&x, &tpl, &mut FftCache::default(), 0.02).unwrap();
            assert_eq!(dets.len(), n_chirps);
            assert_eq!(dets, want);
            for d in &dets {
                assert!(got.iter().any(|g| g.0 == d.onset_sample), "chirp at {} not visited", d.onset_sample);
            }
            let norm = tpl.real.iter().map(|v| f64::from(*v) * f64::from(*v)).sum::<f64>().sqrt();
            for &(onset, ncc, r) in &got {
                let (w0, w1) = (onset.saturating_sub(spans.0), (onset + spans.1).min(x.len()));
                assert_eq!(r, fingerprint(&x[w0..w1], onset - w0));
                if let Some(d) = dets.iter().find(|d| d.onset_sample == onset) {
                    assert_eq!(ncc.to_bits(), d.ncc.to_bits());
                }
                let c = x[onset..(onset + m).min(x.len())].iter().map(|v| f64::from(*v).powi(2)).sum::<f64>();
                assert!(ncc > 0.0 && c > 0.0 && norm > 0.0);
            }
            for (threads, block) in [(4, 1000), (2, 65_536), (1, 37)] {
                let (g2, d2) = visited(&x, &tpl, spans, threads, block);
                assert_eq!(d2, dets);
                assert_eq!(g2.len(), got.len());
                for (a, b) in got.iter().zip(&g2) {
                    assert_eq!((a.0, a.1.to_bits(), a.2), (b.0, b.1.to_bits(), b.2));
                }
            }
        }
    }
}
