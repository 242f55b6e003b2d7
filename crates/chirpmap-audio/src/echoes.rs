//! Every reflection of one impulse response (issue 10, items 1 and 3), by
//! matching pursuit with the loudspeaker–microphone system response.
//!
//! A real loudspeaker does not emit an impulse: its response rings for a
//! few milliseconds (the dEchorate room's MixCube for about 2 ms, at Δd
//! 0.27–0.40 m) and every reflection is a delayed, scaled copy of that
//! same response. Picking envelope peaks therefore reports the ringing as
//! echoes and picks whichever lobe of each echo's cluster happens to be the
//! highest. Instead, the system response (an "atom") is
//!
//! - the direct sound itself: the impulse response from a little before
//!   its peak to `ringing` samples after it (nothing that arrives within
//!   that window can be told from the ringing, so no echo is reported
//!   there), or
//! - a calibration: the same window of a recording of the direct sound
//!   alone (speaker close to the microphone, or in free field), which
//!   models the ringing without the room, so echoes inside the window are
//!   reported when they stand out of it.
//!
//! Matching pursuit (Mallat & Zhang 1993; in radio astronomy Högbom's CLEAN,
//! 1974) then explains the response as a sum of delayed, scaled and
//! phase-rotated copies of the atom: correlate the residual with the atom,
//! take the best lag (refined to a fraction of a sample by a parabola),
//! fit the complex gain by least squares with the atom shifted by that
//! fraction, subtract, repeat. The complex gain absorbs the phase change of
//! a reflection off an absorbing panel.

/// Complex samples of impulse responses (re-exported for the facade).
pub use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::cell::RefCell;
use std::sync::Arc;

/// The system response used as the atom of matching pursuit.
#[derive(Debug, Clone, PartialEq)]
pub struct SystemResponse {
    /// Complex (analytic) samples of the response.
    pub samples: Vec<Complex64>,
    /// Index of the direct peak within `samples`.
    pub peak_index: usize,
}

impl SystemResponse {
    /// The window `ir[peak − pre .. peak + ringing]` around the largest
    /// |ir| in `search` (the direct sound): the system response estimated
    /// from the direct sound itself. `None` if the window leaves `ir` or
    /// the response is silent there.
    pub fn from_direct(ir: &[Complex64], search: std::ops::Range<usize>, pre: usize, ringing: usize) -> Option<Self> {
        let peak = argmax_norm(ir, search.start, search.end.min(ir.len()))?;
        let lo = peak.checked_sub(pre)?;
        let samples = ir.get(lo..peak + ringing)?.to_vec();
        (samples.iter().any(|c| c.norm() > 0.0)).then_some(Self { samples, peak_index: pre })
    }

    /// The average of several responses (complex mean, each aligned on its
    /// own peak and normalised to unit peak): a calibration recording's
    /// chirps averaged, so that noise falls by √n. `None` if empty or the
    /// lengths differ.
    pub fn average(responses: &[SystemResponse]) -> Option<Self> {
        let first = responses.first()?;
        let n = first.samples.len();
        let mut acc = vec![Complex64::new(0.0, 0.0); n];
        for r in responses {
            if r.samples.len() != n || r.peak_index != first.peak_index {
                return None;
            }
            let p = r.samples[r.peak_index];
            if p.norm() == 0.0 {
                return None;
            }
            // Normalise gain and carrier phase at the peak.
            let g = p.conj() / (p.norm() * p.norm());
            for (a, s) in acc.iter_mut().zip(&r.samples) {
                *a += s * g;
            }
        }
        let k = 1.0 / responses.len() as f64;
        Some(Self { samples: acc.into_iter().map(|c| c * k).collect(), peak_index: first.peak_index })
    }

    /// Energy Σ|s|².
    fn energy(&self) -> f64 {
        self.samples.iter().map(|c| c.norm_sqr()).sum()
    }
}

/// Limits of the pursuit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PursuitParams {
    /// Where the direct peak is searched (indices of the impulse response).
    pub direct_lo: usize,
    /// End (exclusive) of the direct search.
    pub direct_hi: usize,
    /// Smallest echo delay after the direct peak (samples).
    pub min_lag: f64,
    /// Largest echo delay after the direct peak (samples).
    pub max_lag: f64,
    /// Most echoes picked.
    pub max_echoes: usize,
    /// Weakest echo picked, relative to the direct sound (dB, negative).
    pub threshold_db: f64,
    /// Whether the atom was cut from this very response (the direct sound is
    /// then subtracted exactly, and nothing within the atom is searched).
    pub self_estimated: bool,
    /// Samples after the peak kept in the atom that matches echoes.
    pub echo_atom_after_peak: usize,
}

/// One arrival explained by the atom.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arrival {
    /// Delay after the direct arrival (samples, fractional).
    pub lag_samples: f64,
    /// Amplitude relative to the direct arrival.
    pub amplitude: f64,
    /// Phase relative to the direct arrival (rad).
    pub phase_rad: f64,
}

/// The direct arrival's position and the echoes of one impulse response.
#[derive(Debug, Clone, PartialEq)]
pub struct Pursuit {
    /// Position of the direct peak in the response (samples, fractional).
    pub direct_index: f64,
    /// Complex gain of the direct arrival against the atom.
    pub direct_gain: Complex64,
    /// Echoes, in the order they were picked (strongest first).
    pub arrivals: Vec<Arrival>,
}

fn argmax_norm(v: &[Complex64], lo: usize, hi: usize) -> Option<usize> {
    (lo..hi.min(v.len()))
        .filter(|&i| v[i].norm().is_finite())
        .max_by(|&a, &b| v[a].norm_sqr().total_cmp(&v[b].norm_sqr()))
}

/// Vertex offset of the parabola through three samples (−0.5..0.5).
fn vertex(l: f64, c: f64, r: f64) -> f64 {
    let den = l - 2.0 * c + r;
    if den.abs() < 1e-300 || !den.is_finite() { 0.0 } else { (0.5 * (l - r) / den).clamp(-0.5, 0.5) }
}

thread_local! {
    /// FFT plans reused across chirps (planning a size costs more than
    /// running it once).
    static PLANNER: RefCell<FftPlanner<f64>> = RefCell::new(FftPlanner::new());
}

fn plan(n: usize, inverse: bool) -> Arc<dyn Fft<f64>> {
    PLANNER.with(|p| {
        let mut p = p.borrow_mut();
        if inverse { p.plan_fft_inverse(n) } else { p.plan_fft_forward(n) }
    })
}

/// The atom delayed by `frac` ∈ [0, 1) samples (phase ramp in the frequency
/// domain; the atom is zero-padded so the circular shift does not wrap).
struct Shifter {
    spectrum: Vec<Complex64>,
    n: usize,
    len: usize,
    inverse: Arc<dyn Fft<f64>>,
}

impl Shifter {
    fn new(atom: &[Complex64]) -> Self {
        let len = atom.len() + 4;
        let n = (2 * len).next_power_of_two();
        let mut buf: Vec<Complex64> = (0..n).map(|i| atom.get(i).copied().unwrap_or_default()).collect();
        plan(n, false).process(&mut buf);
        Self { spectrum: buf, n, len, inverse: plan(n, true) }
    }
    fn shifted(&mut self, frac: f64) -> Vec<Complex64> {
        let n = self.n;
        let mut buf: Vec<Complex64> = self
            .spectrum
            .iter()
            .enumerate()
            .map(|(k, s)| {
                let f = if k <= n / 2 { k as f64 } else { k as f64 - n as f64 } / n as f64;
                s * Complex64::from_polar(1.0 / n as f64, -std::f64::consts::TAU * f * frac)
            })
            .collect();
        self.inverse.process(&mut buf);
        buf.truncate(self.len);
        buf
    }
}

/// Correlation `c[k] = Σ_j conj(atom[j])·res[k+j] / E` for every start k
/// with the whole atom inside `res`.
fn correlate_all(res: &[Complex64], atom: &[Complex64], energy: f64) -> Vec<Complex64> {
    let la = atom.len();
    if res.len() < la {
        return Vec::new();
    }
    let n = (res.len() + la).next_power_of_two();
    let fwd = plan(n, false);
    let mut r: Vec<Complex64> = (0..n).map(|i| res.get(i).copied().unwrap_or_default()).collect();
    let mut a: Vec<Complex64> = (0..n).map(|i| atom.get(i).copied().unwrap_or_default()).collect();
    fwd.process(&mut r);
    fwd.process(&mut a);
    for (x, y) in r.iter_mut().zip(&a) {
        *x *= y.conj();
    }
    plan(n, true).process(&mut r);
    let s = 1.0 / (n as f64 * energy);
    r.truncate(res.len() - la + 1);
    r.iter_mut().for_each(|c| *c *= s);
    r
}

fn correlate_at(res: &[Complex64], atom: &[Complex64], energy: f64, k: usize) -> Complex64 {
    let mut acc = Complex64::new(0.0, 0.0);
    for (a, r) in atom.iter().zip(&res[k..]) {
        acc += a.conj() * r;
    }
    acc / energy
}

/// One atom's matching state over a residual: the atom, its fractional
/// shifter and its correlation with the residual at every start.
struct Stage {
    atom: Vec<Complex64>,
    energy: f64,
    shifter: Shifter,
    /// The whole system response (the atom is its head), subtracted with
    /// the gain fitted on the atom so that each echo's own ringing goes too.
    whole: Option<Shifter>,
    corr: Vec<Complex64>,
}

impl Stage {
    fn new(atom: &[Complex64], whole: Option<&[Complex64]>, res: &[Complex64]) -> Option<Self> {
        let energy: f64 = atom.iter().map(|c| c.norm_sqr()).sum();
        if atom.is_empty() || res.len() < atom.len() + 2 || !(energy > 0.0 && energy.is_finite()) {
            return None;
        }
        let corr = correlate_all(res, atom, energy);
        let whole = whole.filter(|w| w.len() > atom.len()).map(Shifter::new);
        Some(Self { atom: atom.to_vec(), energy, shifter: Shifter::new(atom), whole, corr })
    }

    /// Recomputes the correlation at the starts whose window overlaps `res[lo..hi]`.
    fn update(&mut self, res: &[Complex64], lo: usize, hi: usize) {
        let (la, n) = (self.atom.len(), self.corr.len());
        for (k, c) in self.corr.iter_mut().enumerate().take(hi.min(n)).skip(lo.saturating_sub(la)) {
            *c = correlate_at(res, &self.atom, self.energy, k);
        }
    }

    /// Fits the atom starting at `s0` (fractional) by least squares,
    /// subtracts it from `res` and returns its complex gain.
    fn subtract(&mut self, res: &mut [Complex64], s0: f64) -> Option<Complex64> {
        if s0.is_nan() || s0 < 0.0 {
            return None;
        }
        let ist = s0.floor() as usize;
        let tt = self.shifter.shifted(s0 - ist as f64);
        let seg = res.get(ist..ist + tt.len())?;
        let (mut num, mut den) = (Complex64::new(0.0, 0.0), 0.0);
        for (t, r) in tt.iter().zip(seg) {
            num += t.conj() * r;
            den += t.norm_sqr();
        }
        if den <= 0.0 {
            return None;
        }
        let g = num / den;
        self.apply(res, s0, -g);
        Some(g)
    }

    /// Puts back an arrival [`Stage::subtract`] removed (start `s0`, gain `g`).
    fn restore(&mut self, res: &mut [Complex64], s0: f64, g: Complex64) {
        self.apply(res, s0, g);
    }

    /// `res += g · (whole response, or atom) starting at s0`, then the
    /// correlation is brought up to date where it changed.
    fn apply(&mut self, res: &mut [Complex64], s0: f64, g: Complex64) {
        let ist = s0.floor() as usize;
        let frac = s0 - ist as f64;
        let tt = match self.whole.as_mut() {
            Some(w) => w.shifted(frac),
            None => self.shifter.shifted(frac),
        };
        let end = (ist + tt.len()).min(res.len());
        if ist >= end {
            return;
        }
        for (r, t) in res[ist..end].iter_mut().zip(&tt) {
            *r += g * t;
        }
        self.update(res, ist, end);
    }

    /// Re-fits the arrival picked at `s0` with gain `g` against the current
    /// residual (every other arrival removed): put back, located again
    /// within its main lobe, fitted and removed. Returns the new start and
    /// gain (the old ones if no peak is left there).
    fn refit(&mut self, res: &mut [Complex64], s0: f64, g: Complex64) -> Option<(f64, Complex64)> {
        self.restore(res, s0, g);
        let k0 = s0.round() as usize;
        let s1 = match self.best_peak(k0.saturating_sub(MERGE_SAMPLES + 1), k0 + MERGE_SAMPLES + 2) {
            Some(k) => refine(&self.corr, k),
            None => s0,
        };
        Some((s1, self.subtract(res, s1)?))
    }

    /// The strongest start in `lo..hi`.
    fn best(&self, lo: usize, hi: usize) -> Option<usize> {
        (lo..hi.min(self.corr.len())).max_by(|&a, &b| self.corr[a].norm_sqr().total_cmp(&self.corr[b].norm_sqr()))
    }

    /// The strongest local maximum of |corr| strictly inside `lo..hi` (a
    /// value at the window's edge is the slope of an arrival outside it).
    fn best_peak(&self, lo: usize, hi: usize) -> Option<usize> {
        let c = |k: usize| self.corr[k].norm_sqr();
        (lo + 1..hi.min(self.corr.len()).saturating_sub(1))
            .filter(|&k| c(k) >= c(k - 1) && c(k) >= c(k + 1))
            .max_by(|&a, &b| c(a).total_cmp(&c(b)))
    }
}

/// Two arrivals closer than this (samples) are one: no atom of a sweep
/// resolves them (10 kHz of bandwidth at 48 kHz is a 4.8-sample main lobe).
const MERGE_SAMPLES: usize = 2;

/// Explains `ir` as the direct arrival plus echoes (see the module docs).
/// The direct arrival is removed with the whole atom (its ringing
/// included); echoes are located and their gains fitted with the atom's
/// first `peak_index + p.echo_atom_after_peak` samples, the part that
/// locates an arrival best when arrivals overlap, and then removed with the
/// whole atom, their own ringing included. `None` when the direct sound is not
/// found, the response is shorter than the atom, or the atom is silent.
pub fn pursue(ir: &[Complex64], atom: &SystemResponse, p: &PursuitParams) -> Option<Pursuit> {
    let pk = atom.peak_index;
    let mut res = ir.to_vec();
    // The direct arrival.
    let direct_peak = argmax_norm(ir, p.direct_lo, p.direct_hi.min(ir.len()))?;
    let (direct_start, g0) = if p.self_estimated {
        // The atom is this very window: remove it exactly.
        let s = direct_peak.checked_sub(pk)?;
        if s + atom.samples.len() > res.len() || atom.energy() <= 0.0 {
            return None;
        }
        for (r, a) in res[s..].iter_mut().zip(&atom.samples) {
            *r -= a;
        }
        (s as f64, Complex64::new(1.0, 0.0))
    } else {
        let mut stage = Stage::new(&atom.samples, None, &res)?;
        let k = stage.best(direct_peak.saturating_sub(pk + 8), (direct_peak + 8).saturating_sub(pk))?;
        let s0 = refine(&stage.corr, k);
        let g = stage.subtract(&mut res, s0)?;
        (s0, g)
    };
    let g0n = g0.norm();
    if !(g0n > 0.0 && g0n.is_finite()) {
        return None;
    }
    let echo_len = (pk + p.echo_atom_after_peak.max(1)).min(atom.samples.len());
    let mut stage = Stage::new(&atom.samples[..echo_len], Some(&atom.samples), &res)?;
    let thr = 10f64.powf(p.threshold_db / 20.0);
    // Echo starts: the echo's peak lies `lag` after the direct's, so its
    // atom starts `lag` after the direct atom's start.
    let lo = (direct_start + p.min_lag).ceil().max(0.0) as usize;
    let hi = ((direct_start + p.max_lag).floor().max(0.0) as usize + 1).min(stage.corr.len());
    // Picked arrivals: (start in `res`, complex gain against the atom).
    let mut picked: Vec<(f64, Complex64)> = Vec::new();
    // Each pass either adds an arrival or re-fits one; re-fits are bounded.
    let mut refits_left = 2 * p.max_echoes;
    while picked.len() < p.max_echoes && lo + 2 < hi {
        let Some(k) = stage.best_peak(lo, hi) else { break };
        if stage.corr[k].norm() < thr * g0n {
            break;
        }
        let s0 = refine(&stage.corr, k);
        // A peak within the main lobe of an arrival already picked is that
        // arrival's fit error (the tail of a neighbour found later had
        // biased it), not a second arrival: re-fit it instead (cyclic
        // matching pursuit, Christensen & Jensen 2007).
        if let Some(j) = picked.iter().position(|(s, _)| (s - s0).abs() < MERGE_SAMPLES as f64) {
            if refits_left == 0 {
                break;
            }
            refits_left -= 1;
            let Some(fit) = stage.refit(&mut res, picked[j].0, picked[j].1) else { break };
            picked[j] = fit;
            continue;
        }
        let Some(g) = stage.subtract(&mut res, s0) else { break };
        if (g / g0).norm() < 0.5 * thr {
            // The fit explains far less than the correlation promised: the
            // residual there is not atom-shaped; stop rather than loop.
            break;
        }
        picked.push((s0, g));
    }
    // One cyclic pass: each arrival re-fitted with all the others removed,
    // so that a later neighbour's ringing no longer biases it.
    for arrival in &mut picked {
        if let Some(fit) = stage.refit(&mut res, arrival.0, arrival.1) {
            *arrival = fit;
        }
    }
    let arrivals = picked
        .iter()
        .map(|&(s0, g)| {
            let rel = g / g0;
            Arrival { lag_samples: s0 - direct_start, amplitude: rel.norm(), phase_rad: rel.arg() }
        })
        .collect();
    Some(Pursuit { direct_index: direct_start + pk as f64, direct_gain: g0, arrivals })
}

/// Sub-sample position of the correlation peak at `k`: the vertex of the
/// parabola through the log magnitudes (exact for a Gaussian envelope, as
/// in [`crate::spectrum::peak_in`]).
fn refine(corr: &[Complex64], k: usize) -> f64 {
    if k == 0 || k + 1 >= corr.len() {
        return k as f64;
    }
    let m = corr[k].norm();
    let l = |c: Complex64| c.norm().max(m * 1e-12).max(1e-300).ln();
    k as f64 + vertex(l(corr[k - 1]), l(corr[k]), l(corr[k + 1]))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A ringing atom: a Gaussian-windowed carrier plus a decaying tail.
    fn atom_at(t: f64) -> Complex64 {
        let main = (-(t / 2.0).powi(2)).exp();
        let tail = if t > 3.0 { 0.3 * (-(t - 3.0) / 15.0).exp() } else { 0.0 };
        Complex64::from_polar(main + tail, 0.9 * t)
    }

    /// Σ gᵢ·atom(n − qᵢ) sampled exactly (the oracle: continuous atom, exact delays).
    fn render(arrivals: &[(f64, Complex64)], n: usize) -> Vec<Complex64> {
        (0..n)
            .map(|i| {
                arrivals
                    .iter()
                    .map(|&(q, g)| if i as f64 >= q - 10.0 { g * atom_at(i as f64 - q) } else { Complex64::default() })
                    .sum()
            })
            .collect()
    }

    #[test]
    fn pursuit_finds_fractional_delays_under_the_ringing() {
        let truth = [
            (40.0, Complex64::new(1.0, 0.0)),
            (123.37, Complex64::from_polar(0.3, 2.0)),
            (171.8, Complex64::from_polar(0.2, -1.0)),
            (260.55, Complex64::from_polar(0.1, 0.4)),
        ];
        let ir = render(&truth, 600);
        let atom = SystemResponse::from_direct(&ir, 0..80, 10, 70).unwrap();
        let p = PursuitParams {
            direct_lo: 0,
            direct_hi: 80,
            min_lag: 70.0,
            max_lag: 400.0,
            max_echoes: 10,
            threshold_db: -30.0,
            self_estimated: true,
            echo_atom_after_peak: 70,
        };
        let out = pursue(&ir, &atom, &p).unwrap();
        let mut got: Vec<Arrival> = out.arrivals.clone();
        got.sort_by(|a, b| a.lag_samples.total_cmp(&b.lag_samples));
        assert_eq!(got.len(), 3, "{got:?}");
        for (a, (q, g)) in got.iter().zip(&truth[1..]) {
            assert!((a.lag_samples - (q - 40.0)).abs() < 0.05, "{a:?} vs {q}");
            assert!((a.amplitude - g.norm()).abs() < 0.02 * g.norm() + 0.005, "{a:?} vs {g}");
        }
    }

    #[test]
    fn average_of_aligned_copies_is_the_copy() {
        let a = SystemResponse { samples: vec![Complex64::new(0.0, 1.0), Complex64::new(0.0, 2.0)], peak_index: 1 };
        let b = SystemResponse { samples: vec![Complex64::new(1.0, 0.0), Complex64::new(2.0, 0.0)], peak_index: 1 };
        let m = SystemResponse::average(&[a, b]).unwrap();
        assert!((m.samples[1] - Complex64::new(1.0, 0.0)).norm() < 1e-12);
        assert!((m.samples[0] - Complex64::new(0.5, 0.0)).norm() < 1e-12);
    }
}
