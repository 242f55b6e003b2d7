//! Walls as common tangents: Hough vote in (normal angle θ, offset ρ) with the
//! closed-form far tangents of each ellipse, least-squares refinement, ghost
//! rejection and a greedy one-surface-per-echo assignment.

use super::tangent::{far_offset, far_tangent};
use super::{Ctx, EvidenceParams, Surface, SurfaceKind};
use crate::error::CoreError;
use crate::geometry::Point;
use crate::grid::{DEFAULT_MEMORY_CAP_BYTES, GridSpec};
use std::f64::consts::TAU;

/// An accepted wall: the surface and, per explained echo, its tangency point.
#[derive(Debug, Clone)]
pub(crate) struct LineOut {
    pub surface: Surface,
    pub touches: Vec<(usize, Point)>,
    /// Normal angle (rad) and offset from the grid centre (m).
    pub theta: f64,
    pub rho: f64,
}

#[derive(Debug, Clone, Default)]
pub(crate) struct LinesResult {
    pub accepted: Vec<LineOut>,
    /// Echoes of rejected ghost lines (higher-order reflections): they are
    /// neither rings nor envelope evidence.
    pub ghost_echoes: Vec<usize>,
}

/// What became of a Hough peak: not refined (its own line bends or is not
/// heard), or refined (`None` when too few echoes remained).
enum Screened {
    NotRefined(Cand),
    Refined(Option<Cand>),
}

/// A refined line candidate.
#[derive(Debug, Clone)]
struct Cand {
    theta: f64,
    rho: f64,
    /// Echoes tangent to the line, one per measurement, inside runs of
    /// consecutive poses, with their tangency points.
    touches: Vec<(usize, Point)>,
    p0: Point,
    p1: Point,
    /// Root-mean-square tangency residual of the touches, in σ.
    rms_sigmas: f64,
}

impl Cand {
    fn normal(&self) -> Point {
        Point::from_angle(self.theta)
    }
    fn support(&self) -> usize {
        self.touches.len()
    }
    fn length(&self) -> f64 {
        self.p0.dist(self.p1)
    }
}

fn origin_of(ctx: &Ctx) -> Point {
    let s = &ctx.spec;
    Point::new(0.5 * (s.x_min_m + s.x_max_m()), 0.5 * (s.y_min_m + s.y_max_m()))
}

fn tau(ctx: &Ctx, k: usize) -> f64 {
    ctx.params.band_sigmas * ctx.preps[k].sigma_m
}

/// Far tangent offset for the unit normal `n` (no trigonometry).
fn rho_n(ctx: &Ctx, k: usize, n: Point, origin: Point) -> f64 {
    let e = &ctx.preps[k].ellipse;
    let nu = n.x * e.cos_t + n.y * e.sin_t;
    let nv = -n.x * e.sin_t + n.y * e.cos_t;
    far_offset(e.semi_major_m * e.semi_major_m, e.semi_minor_m * e.semi_minor_m, nu, nv, n.dot(e.center - origin))
}

/// Per-echo constants of the far tangent offset, structure of arrays: the
/// same arithmetic as [`rho_n`] (bit for bit) in loops the compiler can
/// vectorise.
pub(crate) struct Tangents {
    cos_t: Vec<f64>,
    sin_t: Vec<f64>,
    a2: Vec<f64>,
    b2: Vec<f64>,
    cx: Vec<f64>,
    cy: Vec<f64>,
    /// Band half-width kσ (m).
    tau: Vec<f64>,
    /// σ (m).
    sigma: Vec<f64>,
    /// Least-squares weight 1/σ².
    w: Vec<f64>,
    /// Bound (m/rad) on |dρ/dθ|: |c − origin| + a (the offset's derivative
    /// is the tangency point's component along the line, |touch − origin|).
    lip: Vec<f64>,
}

impl Tangents {
    fn new(ctx: &Ctx, origin: Point) -> Self {
        let n = ctx.preps.len();
        let mut t = Tangents {
            cos_t: Vec::with_capacity(n),
            sin_t: Vec::with_capacity(n),
            a2: Vec::with_capacity(n),
            b2: Vec::with_capacity(n),
            cx: Vec::with_capacity(n),
            cy: Vec::with_capacity(n),
            tau: Vec::with_capacity(n),
            sigma: Vec::with_capacity(n),
            w: Vec::with_capacity(n),
            lip: Vec::with_capacity(n),
        };
        for (k, p) in ctx.preps.iter().enumerate() {
            let e = &p.ellipse;
            let c = e.center - origin;
            t.cos_t.push(e.cos_t);
            t.sin_t.push(e.sin_t);
            t.a2.push(e.semi_major_m * e.semi_major_m);
            t.b2.push(e.semi_minor_m * e.semi_minor_m);
            t.cx.push(c.x);
            t.cy.push(c.y);
            t.tau.push(tau(ctx, k));
            t.sigma.push(p.sigma_m);
            t.w.push(1.0 / (p.sigma_m * p.sigma_m));
            t.lip.push(c.x.hypot(c.y) + e.semi_major_m);
        }
        t
    }
    /// Far tangent offset of echo `k` for the unit normal `n` (as [`rho_n`]).
    #[inline]
    fn offset(&self, k: usize, n: Point) -> f64 {
        let (c, s) = (self.cos_t[k], self.sin_t[k]);
        let nu = n.x * c + n.y * s;
        let nv = -n.x * s + n.y * c;
        far_offset(self.a2[k], self.b2[k], nu, nv, n.x * self.cx[k] + n.y * self.cy[k])
    }
    fn len(&self) -> usize {
        self.a2.len()
    }
    /// The entries of `set`, in its order (same values, so the same offsets).
    fn subset(&self, set: &[usize]) -> Tangents {
        let pick = |v: &[f64]| set.iter().map(|&k| v[k]).collect::<Vec<f64>>();
        Tangents {
            cos_t: pick(&self.cos_t),
            sin_t: pick(&self.sin_t),
            a2: pick(&self.a2),
            b2: pick(&self.b2),
            cx: pick(&self.cx),
            cy: pick(&self.cy),
            tau: pick(&self.tau),
            sigma: pick(&self.sigma),
            w: pick(&self.w),
            lip: pick(&self.lip),
        }
    }
    /// Far tangent offset of echo `k` and its derivative in the normal
    /// angle, `n⊥·c + (b² − a²)(n·u)(n·v)/h`.
    #[inline]
    fn offset_slope(&self, k: usize, n: Point) -> (f64, f64) {
        let (c, s) = (self.cos_t[k], self.sin_t[k]);
        let nu = n.x * c + n.y * s;
        let nv = -n.x * s + n.y * c;
        let (a2, b2) = (self.a2[k], self.b2[k]);
        let h = (a2 * nu * nu + b2 * nv * nv).sqrt();
        let rho = n.x * self.cx[k] + n.y * self.cy[k] + h;
        let dc = -n.y * self.cx[k] + n.x * self.cy[k];
        let slope = if h > 0.0 { dc + (b2 - a2) * nu * nv / h } else { dc };
        (rho, slope)
    }
    /// Far tangent offsets of every echo for the unit normal `n`.
    #[inline(always)]
    fn offsets(&self, n: Point, out: &mut [f64]) {
        let it = self.cos_t.iter().zip(&self.sin_t).zip(self.a2.iter().zip(&self.b2)).zip(self.cx.iter().zip(&self.cy));
        for (o, (((&c, &s), (&a2, &b2)), (&cx, &cy))) in out.iter_mut().zip(it) {
            let nu = n.x * c + n.y * s;
            let nv = -n.x * s + n.y * c;
            *o = far_offset(a2, b2, nu, nv, n.x * cx + n.y * cy);
        }
    }
}

/// `x.ceil()` for finite `x` without a libm call (the default x86-64 target
/// has no rounding instruction); exact, saturating beyond ±2⁶³.
#[inline]
fn ceil_fast(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t < x { t + 1.0 } else { t }
}

/// `x.floor()` for finite `x`, as [`ceil_fast`].
#[inline]
fn floor_fast(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    let (_, m, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    *m
}

/// Densest offset among the sorted tangent offsets `vals`: the window of
/// `width` (2τ, τ = kσ with σ the set's median) holding the most offsets,
/// and its mean. Returns `(count, mean)`.
///
/// The window never shrinks (Kadane-style): at each offset it either grows
/// by one, when the offset is within `width` of the window's first, or
/// slides by one. Its size is then the most offsets any window ending there
/// holds, and the window recorded at its last growth is the first window of
/// the final size, as a search of every window would find; with one step
/// per offset instead of a loop, the branch is a conditional move.
fn densest(vals: &[f64], width: f64) -> (usize, f64) {
    let (mut best_lo, mut lo) = (0usize, 0usize);
    for hi in 0..vals.len() {
        let slides = vals[hi] - vals[lo] > width;
        best_lo = if slides { best_lo } else { lo };
        lo += usize::from(slides);
    }
    let best = vals.len() - lo;
    let mean = vals[best_lo..best_lo + best].iter().sum::<f64>() / best.max(1) as f64;
    (best, mean)
}

/// [`Tangents::offsets`] compiled for the widest vectors the CPU has
/// ([`pulp`]'s runtime dispatch; the same bits, as in [`VoteRow`]).
struct Offsets<'a> {
    tan: &'a Tangents,
    n: Point,
    out: &'a mut [f64],
}

impl pulp::WithSimd for Offsets<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        self.tan.offsets(self.n, self.out);
    }
}

/// The scan's score at one angle: Σ exp(−(r_k − centre)² / 2σ_k²) over the
/// offsets `raw` (set order) within `cut` of `centre`. It is most of a
/// line's refinement (about 1.3 M terms for the L-corridor's 201 peaks), so
/// it is summed in [`KERNEL_LANES`] fixed lanes with the rings' polynomial
/// `exp`, which the compiler vectorises; the lanes make the sum the same
/// bits at every vector width ([`pulp`]'s runtime dispatch).
struct KernelSum<'a> {
    raw: &'a [f64],
    /// −1 / 2σ_k², in set order.
    neg_half_prec: &'a [f64],
    centre: f64,
    cut: f64,
}

/// Partial sums of [`KernelSum`], added in a fixed order at the end.
const KERNEL_LANES: usize = 8;

impl pulp::WithSimd for KernelSum<'_> {
    type Output = f64;
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> f64 {
        let Self { raw, neg_half_prec, centre, cut } = self;
        let term = |r: f64, c: f64| {
            let d = r - centre;
            let e = super::exp_nonpositive(d * d * c);
            if d.abs() <= cut { e } else { 0.0 }
        };
        let mut acc = [0.0f64; KERNEL_LANES];
        let whole = raw.len() / KERNEL_LANES * KERNEL_LANES;
        for (r, c) in raw[..whole].chunks_exact(KERNEL_LANES).zip(neg_half_prec[..whole].chunks_exact(KERNEL_LANES)) {
            for l in 0..KERNEL_LANES {
                acc[l] += term(r[l], c[l]);
            }
        }
        for (l, (&r, &c)) in raw[whole..].iter().zip(&neg_half_prec[whole..]).enumerate() {
            acc[l] += term(r, c);
        }
        ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
    }
}

/// Cells per block of the peak search's skip test.
const PEAK_BLOCK: usize = 32;

/// Kernel terms farther than this many σ from the centre are left out of
/// the scan's score: each is below e^−36 ≈ 2·10⁻¹⁶ of a term at the centre.
const KERNEL_CUT_SIGMAS: f64 = 8.5;

/// The tangent offsets of a candidate's echoes at one scan angle, sorted,
/// with `order[i]` the position in the set of the `i`-th smallest. The
/// order is kept from one angle to the next, which barely changes it for a
/// few hundred echoes, so an insertion sort is nearly linear. It is not for
/// a long wall's tens of thousands of echoes within a few bands of one
/// another, where a step of the angle reorders most of them: an insertion
/// sort's moves grow with their square (240 000 echoes of a 10-minute walk
/// in a room spent 8 s here), so past a budget of moves the sort finishes
/// with a stable merge sort, which orders equal offsets as the insertion
/// sort would (both keep the previous order among equals).
#[derive(Default)]
struct SortedOffsets {
    order: Vec<usize>,
    vals: Vec<f64>,
    /// Offsets in set order (scratch).
    raw: Vec<f64>,
    /// (offset, position) pairs for the merge sort (scratch).
    pairs: Vec<(f64, usize)>,
    /// The CPU's vector level, detected once for every scan angle.
    arch: pulp::Arch,
}

/// Moves per offset the insertion sort may spend before the merge sort
/// takes over.
const INSERTION_MOVES_PER_OFFSET: usize = 16;

impl SortedOffsets {
    fn reset(&mut self, len: usize) {
        self.order.clear();
        self.order.extend(0..len);
    }
    /// Sorts the offsets at `n` of the echoes of `local` (a
    /// [`Tangents::subset`], so computed in one straight loop).
    fn at(&mut self, local: &Tangents, n: Point) {
        self.raw.resize(local.len(), 0.0);
        self.arch.dispatch(Offsets { tan: local, n, out: &mut self.raw });
        self.vals.clear();
        self.vals.extend(self.order.iter().map(|&i| self.raw[i]));
        self.finish_sort(INSERTION_MOVES_PER_OFFSET * self.vals.len());
    }
    /// Sorts `vals` (by `total_cmp`, equal values in their present order),
    /// permuting `order` alike: by insertion within `budget` moves, else
    /// by a merge sort.
    fn finish_sort(&mut self, budget: usize) {
        if !insertion_sort_within(&mut self.vals, &mut self.order, budget) {
            // The prefix is sorted stably and the rest is untouched, so a
            // stable sort of the whole gives what the insertion sort would.
            self.pairs.clear();
            self.pairs.extend(self.vals.iter().copied().zip(self.order.iter().copied()));
            self.pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
            for ((v, o), &(pv, po)) in self.vals.iter_mut().zip(self.order.iter_mut()).zip(&self.pairs) {
                (*v, *o) = (pv, po);
            }
        }
    }
}

/// Insertion-sorts `vals` (by `total_cmp`, stable), permuting `order`
/// alike, unless that takes more than `budget` moves: then it stops with
/// a stably sorted prefix and the rest as it was, and returns false.
fn insertion_sort_within(vals: &mut [f64], order: &mut [usize], budget: usize) -> bool {
    let mut moves = 0usize;
    for i in 1..vals.len() {
        let (v, o) = (vals[i], order[i]);
        let mut j = i;
        while j > 0 && vals[j - 1].total_cmp(&v) == std::cmp::Ordering::Greater {
            vals[j] = vals[j - 1];
            order[j] = order[j - 1];
            j -= 1;
        }
        vals[j] = v;
        order[j] = o;
        moves += i - j;
        if moves > budget {
            return false;
        }
    }
    true
}

/// The angle in `[lo, hi]` minimising the weighted variance of the tangent
/// offsets of `set` (weighted least squares for the line), by Gauss–Newton
/// from `start`: with offsets linear in the angle about θ, r_k + r'_k·Δ, the
/// variance is least at Δ = −Cov(r, r′)/Var(r′); its fixed point is where
/// the variance's derivative 2·Cov(r, r′) vanishes.
fn min_spread(tan: &Tangents, set: &[usize], lo: f64, hi: f64, start: f64) -> f64 {
    let mut theta = start.clamp(lo, hi);
    for _ in 0..8 {
        let n = Point::from_angle(theta);
        let (mut sw, mut sr, mut sd, mut srd, mut sdd) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &k in set {
            let (r, d) = tan.offset_slope(k, n);
            let w = tan.w[k];
            sw += w;
            sr += w * r;
            sd += w * d;
            srd += w * r * d;
            sdd += w * d * d;
        }
        let (mr, md) = (sr / sw, sd / sw);
        let var_d = sdd / sw - md * md;
        if var_d.is_nan() || var_d <= 0.0 {
            break;
        }
        let step = -(srd / sw - mr * md) / var_d;
        let next = (theta + step).clamp(lo, hi);
        let moved = (next - theta).abs();
        theta = next;
        if moved <= 1e-12 {
            break;
        }
    }
    theta
}

/// Echoes whose far tangent at `theta` lies within their band of `rho`
/// (plus `extra`), in index order; `buf` is scratch for the offsets.
fn gather(tan: &Tangents, theta: f64, rho: f64, extra: f64, buf: &mut Vec<f64>) -> Vec<usize> {
    buf.resize(tan.len(), 0.0);
    tan.offsets(Point::from_angle(theta), buf);
    buf.iter()
        .zip(&tan.tau)
        .enumerate()
        .filter(|(_, (r, t))| (**r - rho).abs() <= **t + extra)
        .map(|(k, _)| k)
        .collect()
}

/// Gathers near one line: every echo that [`gather`] can return for an
/// angle within `d_theta` of `theta` and an offset within `d_rho` of `rho`
/// (with `extra` ≤ `max_extra`), since an offset moves by at most
/// `lip`·|Δθ|. Later gathers inside that box test only these echoes and
/// return exactly what a full gather would.
struct NearSet {
    theta: f64,
    rho: f64,
    d_theta: f64,
    d_rho: f64,
    max_extra: f64,
    ks: Vec<usize>,
}

impl NearSet {
    fn new(tan: &Tangents, theta: f64, rho: f64, d_theta: f64, d_rho: f64, max_extra: f64, buf: &mut Vec<f64>) -> Self {
        buf.resize(tan.len(), 0.0);
        tan.offsets(Point::from_angle(theta), buf);
        // 1e-9 m of slack for rounding in the offsets.
        let ks = (0..tan.len())
            .filter(|&k| (buf[k] - rho).abs() <= tan.tau[k] + max_extra + tan.lip[k] * d_theta + d_rho + 1e-9)
            .collect();
        NearSet { theta, rho, d_theta, d_rho, max_extra, ks }
    }
    fn gather(&self, tan: &Tangents, theta: f64, rho: f64, extra: f64, buf: &mut Vec<f64>) -> Vec<usize> {
        let inside = (theta - self.theta).abs() <= self.d_theta && (rho - self.rho).abs() <= self.d_rho;
        if !inside || extra > self.max_extra {
            return gather(tan, theta, rho, extra, buf);
        }
        let n = Point::from_angle(theta);
        self.ks.iter().copied().filter(|&k| (tan.offset(k, n) - rho).abs() <= tan.tau[k] + extra).collect()
    }
}

/// Keeps, per measurement, the echo closest to the line, and only
/// measurements inside runs of ≥ `min_run` consecutive poses of one listener
/// (tangency by neighbouring poses, issue 9 item 3). Returns touches and the
/// segment spanned by them.
fn touches_in_runs(ctx: &Ctx, set: &[usize], theta: f64, rho: f64, origin: Point) -> Vec<(usize, Point)> {
    let n = Point::from_angle(theta);
    // (measurement, residual, echo, touch) in set order; stably sorted by
    // measurement, so the first smallest residual of each wins, as a map
    // keeping the first strictly smaller one would.
    let mut cand: Vec<(usize, f64, usize, Point)> = set
        .iter()
        .map(|&k| {
            let (r, p) = far_tangent(&ctx.preps[k].ellipse, n, origin);
            (ctx.preps[k].meas, (r - rho).abs() / ctx.preps[k].sigma_m, k, p)
        })
        .collect();
    cand.sort_by_key(|c| c.0);
    let mut best: Vec<(usize, usize, Point)> = Vec::new();
    let mut best_res = f64::NAN;
    for &(m, res, k, p) in &cand {
        match best.last_mut() {
            Some(b) if b.0 == m => {
                if res < best_res {
                    *b = (m, k, p);
                    best_res = res;
                }
            }
            _ => {
                best.push((m, k, p));
                best_res = res;
            }
        }
    }
    // Runs over (listener, seq); measurements are sorted by (listener, t), so
    // consecutive measurement indices of one listener are consecutive poses.
    let ms: Vec<usize> = best.iter().map(|b| b.0).collect();
    let keep = ctx.in_runs(&ms, 1);
    keep.iter().map(|&i| (best[i].1, best[i].2)).collect()
}

fn segment_of(theta: f64, rho: f64, origin: Point, touches: &[(usize, Point)]) -> (Point, Point) {
    let n = Point::from_angle(theta);
    let d = Point::new(-n.y, n.x);
    let foot = origin + n * rho;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &(_, p) in touches {
        let t = d.dot(p - origin);
        lo = lo.min(t);
        hi = hi.max(t);
    }
    if lo > hi {
        return (foot, foot);
    }
    (foot + d * lo, foot + d * hi)
}

/// Weighted variance of the tangent offsets of `set` at `theta`, and their mean.
fn spread(tan: &Tangents, set: &[usize], theta: f64) -> (f64, f64) {
    let (mut sw, mut swr, mut swr2) = (0.0, 0.0, 0.0);
    let n = Point::from_angle(theta);
    for &k in set {
        let r = tan.offset(k, n);
        let w = tan.w[k];
        sw += w;
        swr += w * r;
        swr2 += w * r * r;
    }
    let mean = swr / sw;
    ((swr2 / sw - mean * mean).max(0.0), mean)
}

/// Refines a Hough peak: first the angle within the bin where the most
/// tangent offsets fall in one band (a scan, since away from the true angle
/// a long wall's offsets fan out by length × angle error), then weighted
/// least squares (Gauss–Newton on the offsets' variance, [`min_spread`],
/// offset = their mean), re-gathering the echoes within their band each
/// round (from a [`NearSet`], which returns what a full gather would).
fn refine(ctx: &Ctx, tan: &Tangents, theta0: f64, rho0: f64, origin: Point, bin: f64, rho_bin: f64) -> Option<Cand> {
    let mut buf = Vec::new();
    let mut sorted = SortedOffsets::default();
    let mut best_order = Vec::new();
    // The scan's resolution: 4 bins in 40 steps, searched coarse to fine (21
    // angles a fifth of a bin apart, then the 2 between them about the best
    // one): 23 scores instead of 41. (A coarser first pass, 9 angles, found
    // other peaks on the Table I 1 ms scenes of `benchmark maps`, whose many
    // crossing ellipses make the score ragged.)
    const STEPS: usize = 40;
    const COARSE: usize = 20;
    let (mut theta, mut rho) = (theta0, rho0);
    let step = 4.0 * bin / STEPS as f64;
    // Scan ±2 bins for the angle where the tangent offsets agree best
    // (Gaussian kernel score about the densest offset); recentre while the
    // best angle sits on the scan's edge (short walls vote over a plateau
    // several bins wide, so the peak bin can be off).
    for _ in 0..3 {
        let set0 = gather(tan, theta, rho, 2.0 * rho_bin, &mut buf);
        if set0.len() < 2 {
            return None;
        }
        let mut sig: Vec<f64> = set0.iter().map(|&k| tan.sigma[k]).collect();
        let width = 2.0 * ctx.params.band_sigmas * median(&mut sig);
        let cut = KERNEL_CUT_SIGMAS * sig.iter().copied().fold(0.0, f64::max);
        let lo = theta - 2.0 * bin;
        sorted.reset(set0.len());
        let local = tan.subset(&set0);
        let neg_half_prec: Vec<f64> = local.sigma.iter().map(|s| -0.5 / (s * s)).collect();
        let score_at = |s: usize, sorted: &mut SortedOffsets| -> (f64, f64) {
            let th = lo + step * s as f64;
            sorted.at(&local, Point::from_angle(th));
            let vals = &sorted.vals;
            let (_, centre) = densest(vals, width);
            let score =
                sorted.arch.dispatch(KernelSum { raw: &sorted.raw, neg_half_prec: &neg_half_prec, centre, cut });
            (score, centre)
        };
        let stride = STEPS / COARSE;
        let mut best = (f64::NEG_INFINITY, 0usize, rho);
        for c in 0..=COARSE {
            let (score, centre) = score_at(c * stride, &mut sorted);
            if score > best.0 {
                best = (score, c * stride, centre);
                best_order.clone_from(&sorted.order);
            }
        }
        let (f_lo, f_hi) = (best.1.saturating_sub(stride), (best.1 + stride).min(STEPS));
        for s in f_lo..=f_hi {
            if s % stride == 0 {
                continue;
            }
            sorted.order.clone_from(&best_order);
            let (score, centre) = score_at(s, &mut sorted);
            if score > best.0 {
                best = (score, s, centre);
            }
        }
        theta = lo + step * best.1 as f64;
        rho = best.2;
        if best.1 != 0 && best.1 != STEPS {
            break;
        }
    }
    let mut span = 2.0 * step;
    let near = NearSet::new(tan, theta, rho, 4.0 * step, 2.0 * rho_bin, 0.0, &mut buf);
    for _ in 0..4 {
        let set = near.gather(tan, theta, rho, 0.0, &mut buf);
        if set.len() < 2 {
            return None;
        }
        theta = min_spread(tan, &set, theta - span, theta + span, theta);
        rho = spread(tan, &set, theta).1;
        span *= 0.5;
    }
    let set = near.gather(tan, theta, rho, 0.0, &mut buf);
    let theta = theta.rem_euclid(TAU);
    let touches = touches_in_runs(ctx, &set, theta, rho, origin);
    let (p0, p1) = segment_of(theta, rho, origin, &touches);
    let ks: Vec<usize> = touches.iter().map(|&(k, _)| k).collect();
    let rms_sigmas = if ks.is_empty() {
        f64::INFINITY
    } else {
        let n = Point::from_angle(theta);
        let sum: f64 = ks.iter().map(|&k| ((rho_n(ctx, k, n, origin) - rho) / ctx.preps[k].sigma_m).powi(2)).sum();
        (sum / ks.len() as f64).sqrt()
    };
    Some(Cand { theta, rho, touches, p0, p1, rms_sigmas })
}

/// Whether the tangent offsets bend along the line: the sagitta of a
/// parabola fitted to residual vs position exceeds half a band (kσ/2). A
/// large circle seen over a small arc passes for a line in the vote, but its
/// residuals curve by the arc's sagitta.
fn curved(ctx: &Ctx, c: &Cand, origin: Point) -> bool {
    let n = c.normal();
    let d = Point::new(-n.y, n.x);
    let pts: Vec<(f64, f64)> =
        c.touches.iter().map(|&(k, p)| (d.dot(p - origin), rho_n(ctx, k, n, origin) - c.rho)).collect();
    if pts.len() < 4 {
        return false;
    }
    let m = pts.iter().map(|p| p.0).sum::<f64>() / pts.len() as f64;
    let half = pts.iter().map(|p| (p.0 - m).abs()).fold(0.0, f64::max);
    if half <= 0.0 {
        return false;
    }
    // Least squares r = a + b x + q x² with x = (t − m)/half in [−1, 1].
    let mut s = [[0.0f64; 3]; 3];
    let mut y = [0.0f64; 3];
    for &(t, r) in &pts {
        let x = (t - m) / half;
        let basis = [1.0, x, x * x];
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += basis[i] * basis[j];
            }
            y[i] += basis[i] * r;
        }
    }
    let Some(sol) = solve3(s, y) else { return false };
    let mut sig: Vec<f64> = c.touches.iter().map(|&(k, _)| ctx.preps[k].sigma_m).collect();
    let sigma_m = median(&mut sig);
    // Standard error of the fitted q for residuals of σ: σ·√((SᵀS)⁻¹)₂₂, the
    // (2, 2) cofactor over the determinant. With few echoes (a short pass,
    // Table I at 50 ms) it reaches kσ/2 itself, and noise alone would call a
    // straight run curved: the bend must also be significant.
    let inv22 = (s[0][0] * s[1][1] - s[0][1] * s[1][0]) / det3(s);
    let se_m = if inv22.is_finite() && inv22 > 0.0 { sigma_m * inv22.sqrt() } else { 0.0 };
    sol[2].abs() > (0.5 * ctx.params.band_sigmas * sigma_m).max(SAGITTA_SIGNIFICANCE * se_m)
}

/// A peak whose own, unrefined line is heard from fewer than this fraction
/// of the poses that should hear it is not refined: half the fraction the
/// refined line must reach, 1 − `ghost_fraction` (so 0.25 by default).
/// Refinement moves the line by a few angle bins (±2 per scan, recentred at
/// most 3 times) and rarely doubles the fraction: in the room with corner
/// echoes the accepted lines start at 0.30–0.99, and 78 of the 97 rejected
/// as unheard below 0.30 (test `peak_census_of_the_room`; BENCHMARKS.md,
/// "Session 8").
fn unheard_at_peak(ghost_fraction: f64) -> f64 {
    0.5 * (1.0 - ghost_fraction)
}

/// How many standard errors a sagitta must reach to count as a bend: 2 took
/// Table I at 50 ms from score_obstacle 0.520 to 0.586 and changed no other
/// case of `chirpmap benchmark maps`; 3 cost the loop past circles and the
/// L-corridor (docs/evidence-mapper.md, Known limits).
const SAGITTA_SIGNIFICANCE: f64 = 2.0;

/// Determinant of a 3 × 3 matrix (cofactor expansion along the first row).
pub(crate) fn det3(m: [[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// Solves a 3 × 3 linear system by Cramer's rule; `None` when singular
/// (three unknowns do not warrant a linear-algebra crate).
pub(crate) fn solve3(a: [[f64; 3]; 3], y: [f64; 3]) -> Option<[f64; 3]> {
    let d = det3(a);
    if d.abs() < 1e-12 {
        return None;
    }
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][c] = y[r];
        }
        *o = det3(m) / d;
    }
    Some(out)
}

/// Of the measurements that would hear a wall on this segment (their
/// image-source reflection point lies on it, both foci on the free side),
/// the fraction that did hear an echo at the predicted Δd within kσ. A real
/// wall is heard from wherever it can be; a line that only a short run of
/// poses happens to be tangent to is not (negative evidence, as in
/// occupancy mapping).
fn heard_ratio(ctx: &Ctx, c: &Cand, origin: Point) -> f64 {
    let n = c.normal();
    let d = Point::new(-n.y, n.x);
    let (t0, t1) = (d.dot(c.p0 - origin), d.dot(c.p1 - origin));
    let (t_lo, t_hi) = (t0.min(t1), t0.max(t1));
    let (mut predicted, mut heard) = (0usize, 0usize);
    for m in &ctx.meas {
        let (s, l) = (m.source, m.listener);
        let (hs, hl) = (c.rho - n.dot(s - origin), c.rho - n.dot(l - origin));
        if hs <= 0.0 || hl <= 0.0 {
            continue;
        }
        let image = s + n * (2.0 * hs);
        // Reflection point: where L → image crosses the line.
        let q = l + (image - l) * (hl / (hl + hs));
        let tq = d.dot(q - origin);
        if tq < t_lo || tq > t_hi {
            continue;
        }
        predicted += 1;
        let dd = image.dist(l) - s.dist(l);
        if m.echoes.iter().any(|&k| (ctx.preps[k].ellipse.delta_d_m - dd).abs() <= tau(ctx, k)) {
            heard += 1;
        }
    }
    if predicted == 0 { 0.0 } else { heard as f64 / predicted as f64 }
}

/// Whether segments `a`–`b` and `c`–`d` cross, `a`–`b` excluding a small
/// neighbourhood of `b` (the tangency point itself).
pub(crate) fn crosses(a: Point, b: Point, c: Point, d: Point) -> bool {
    let r = b - a;
    let s = d - c;
    let denom = r.cross(s);
    if denom.abs() < 1e-12 {
        return false;
    }
    let t = (c - a).cross(s) / denom;
    let u = (c - a).cross(r) / denom;
    let eps = 1e-3 / r.norm().max(1e-9);
    (0.0..=1.0 - eps).contains(&t) && (0.0..=1.0).contains(&u)
}

/// The segment `p0`–`p1` (normal angle `theta`) extended at both ends by its
/// length up to 1 m plus a quarter of it, since the ends of a wall are
/// rarely observed: the extent over which it hides what lies behind it.
pub(crate) fn extended(p0: Point, p1: Point, theta: f64) -> (Point, Point) {
    let len = p0.dist(p1);
    let n = Point::from_angle(theta);
    let dir = if len > 0.0 { (p1 - p0) * (1.0 / len) } else { Point::new(-n.y, n.x) };
    let grow = len.min(1.0) + 0.25 * len;
    (p0 - dir * grow, p1 + dir * grow)
}

/// Fraction of `c`'s tangency points hidden from the source or the listener
/// behind one of `occluders` (each [`extended`]).
fn occluded_fraction(ctx: &Ctx, c: &Cand, occluders: &[&Cand]) -> f64 {
    if c.touches.is_empty() || occluders.is_empty() {
        return 0.0;
    }
    let ext: Vec<(Point, Point)> = occluders.iter().map(|o| extended(o.p0, o.p1, o.theta)).collect();
    let hidden = c
        .touches
        .iter()
        .filter(|&&(k, p)| {
            let e = &ctx.preps[k].ellipse;
            ext.iter().any(|&(q0, q1)| crosses(e.focus_a, p, q0, q1) || crosses(e.focus_b, p, q0, q1))
        })
        .count();
    hidden as f64 / c.touches.len() as f64
}

/// Fraction of the segment's samples (every half cell) carved free by more
/// measurements than half the line's support (and at least two): negative
/// evidence weighed against the positive, as log-odds occupancy mapping
/// does (Moravec and Elfes 1985), rather than any two carvings. A
/// measurement whose first echo was missed, or was a false echo longer
/// than the true ones, carves free space across real walls; with one or two
/// false echoes per pose, a few such measurements marked every wall of a
/// room free, and the room lost all four (`examples/scene_sweep.rs`: walls
/// found 55 % of the time with false echoes against 89 % without; test
/// `room_walls_survive_measurements_of_false_echoes_only`).
fn free_fraction(ctx: &Ctx, c: &Cand) -> f64 {
    let len = c.length();
    let n = ((len / (0.5 * ctx.spec.cell_m)).ceil() as usize).clamp(1, 100_000);
    let support = c.support();
    let free = (0..=n).filter(|&s| ctx.free_against(c.p0 + (c.p1 - c.p0) * (s as f64 / n as f64), support)).count();
    free as f64 / (n + 1) as f64
}

/// Which candidates are ghosts: mostly in free space, or (in up to six
/// rounds, until nothing changes) mostly hidden behind stronger non-ghost
/// lines that do not explain the same echoes. Each candidate's possible
/// occluders are found once, and its hidden fraction is recomputed only when
/// its set of non-ghost occluders changed since the last round, on rayon's
/// threads: the same verdicts as recomputing everything every round, one
/// candidate after another (issue 9: that took 5 ms of the Table I 1 ms
/// evidence map, on one core).
fn ghost_lines(ctx: &Ctx, uniq: &[Cand]) -> Vec<bool> {
    use rayon::prelude::*;
    let p = ctx.params;
    let in_free: Vec<bool> = uniq.par_iter().map(|c| free_fraction(ctx, c) > p.ghost_fraction).collect();
    let echo_sets: Vec<Vec<usize>> = uniq
        .iter()
        .map(|c| {
            let mut ks: Vec<usize> = c.touches.iter().map(|&(k, _)| k).collect();
            ks.sort_unstable();
            ks
        })
        .collect();
    let may_hide: Vec<Vec<usize>> = (0..uniq.len())
        .into_par_iter()
        .map(|i| {
            let c = &uniq[i];
            if in_free[i] {
                return Vec::new();
            }
            (0..uniq.len())
                .filter(|&j| j != i && 2 * uniq[j].support() >= c.support() && !explains_same(c, &echo_sets[j]))
                .collect()
        })
        .collect();
    let mut ghost = in_free.clone();
    // Each candidate's last occluder set and its verdict for that set.
    let mut last: Vec<Option<(Vec<usize>, bool)>> = vec![None; uniq.len()];
    for _ in 0..6 {
        let round: Vec<(bool, Option<Vec<usize>>)> = (0..uniq.len())
            .into_par_iter()
            .map(|i| {
                if in_free[i] {
                    return (true, None);
                }
                let occ: Vec<usize> = may_hide[i].iter().copied().filter(|&j| !ghost[j]).collect();
                if let Some((prev, verdict)) = &last[i]
                    && *prev == occ
                {
                    return (*verdict, None);
                }
                let occluders: Vec<&Cand> = occ.iter().map(|&j| &uniq[j]).collect();
                (occluded_fraction(ctx, &uniq[i], &occluders) > p.ghost_fraction, Some(occ))
            })
            .collect();
        let mut next = Vec::with_capacity(uniq.len());
        for (i, (verdict, occ)) in round.into_iter().enumerate() {
            if let Some(occ) = occ {
                last[i] = Some((occ, verdict));
            }
            next.push(verdict);
        }
        if next == ghost {
            break;
        }
        ghost = next;
    }
    ghost
}

/// Whether the candidate whose echoes are `o_echoes` (sorted) explains at least half of
/// `c`'s echoes: another fit of the same echoes (its mirror twin, say) cannot hide them.
fn explains_same(c: &Cand, o_echoes: &[usize]) -> bool {
    let shared = c.touches.iter().filter(|(k, _)| o_echoes.binary_search(k).is_ok()).count();
    2 * shared >= c.support()
}

fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(TAU);
    d.min(TAU - d)
}

/// The mirror twin of the accepted line `a`: the other wall that gives the
/// same echoes. With one fixed focus F (all sources, or all listeners, in
/// one place) and the moving foci on a straight line, the path of an echo
/// off a wall is |F′ − L| with F′ the image of F; reflecting F′ across the
/// moving foci's line gives an image F″ with the same distances, whose wall
/// is the perpendicular bisector of F and F″. With no fixed focus (a
/// co-moving source and listener on one line), the twin is the wall
/// reflected across the foci's line. Returns `(theta, rho)`.
fn mirror_twin(ctx: &Ctx, a: &LineOut, origin: Point) -> Option<(f64, f64)> {
    let ks: Vec<usize> = a.touches.iter().map(|&(k, _)| k).collect();
    let tol = ctx.params.collinear_tol_m;
    let srcs: Vec<Point> = ks.iter().map(|&k| ctx.preps[k].ellipse.focus_a).collect();
    let lsts: Vec<Point> = ks.iter().map(|&k| ctx.preps[k].ellipse.focus_b).collect();
    let fixed = |ps: &[Point]| ps.iter().all(|p| p.dist(ps[0]) <= tol);
    let reflect = super::reflect_across;
    let n = Point::from_angle(a.theta);
    let (f, moving) = if !srcs.is_empty() && fixed(&srcs) {
        (srcs[0], lsts)
    } else if !lsts.is_empty() && fixed(&lsts) {
        (lsts[0], srcs)
    } else {
        let axis = ctx.foci_line(&ks)?;
        let q = reflect(origin + n * a.rho, axis);
        let n2 = reflect(origin + n, axis) - reflect(origin, axis);
        return Some((n2.y.atan2(n2.x).rem_euclid(TAU), n2.dot(q - origin)));
    };
    let axis = super::principal_axis(&moving)?;
    let image = f + n * (2.0 * (a.rho - n.dot(f - origin)));
    let image2 = reflect(image, axis);
    let d = image2 - f;
    if d.norm() == 0.0 {
        return None;
    }
    let n2 = d.normalized();
    Some((n2.y.atan2(n2.x).rem_euclid(TAU), n2.dot((f + image2) * 0.5 - origin)))
}

/// The vote's geometry: offsets from `origin` (the grid centre) in bins of
/// `rho_bin` over [−`r_max`, `r_max`], normal angles in `k_bins` bins of `bin`.
struct Geom {
    origin: Point,
    /// The grid's reach: half its diagonal plus a cell.
    r_max: f64,
    rho_bin: f64,
    /// Offset bins past ±`r_max` on each side, for echoes whose tangent
    /// lines reach beyond the grid ([`Geom::new`]); bin `b`'s offset is
    /// (`b` − `ext`)·`rho_bin` − `r_max`.
    ext: usize,
    n_rho: usize,
    k_bins: usize,
    bin: f64,
}

/// Most offset bins a vote row may have.
const MAX_RHO_BINS: usize = 1 << 20;

/// Most offset bins the vote is extended by on each side, in multiples of
/// the grid's own ([`Geom::new`]): lines up to five grid reaches from its
/// centre, enough for a room cropped to a corner of it.
const MAX_EXTENSION: usize = 2;

impl Geom {
    /// The grid's vote geometry, its offsets extended to every echo's tangent
    /// lines. With bounds cropped to part of the echoes (`map --bounds`), a
    /// wall outside the grid's reach was never voted: its echoes were left
    /// unexplained, and the compact-reflector stages made points of them
    /// inside the grid, while the wall's mirror twin was reported alone
    /// (test `cropping_the_grid_keeps_walls_beyond_it`). Extending by whole
    /// bins leaves every bin's offset the same bits, so a grid that covers
    /// its echoes (the default bounds) votes exactly as before. The extension
    /// is at most [`MAX_EXTENSION`] times the grid's own offsets on each side
    /// (a 0.5 m grid cropped from echoes 10⁶ m away otherwise voted over
    /// 1.5 GB), and within the memory cap and [`MAX_RHO_BINS`].
    fn new(ctx: &Ctx) -> Self {
        let rho_bin = vote_rho_bin(ctx.spec.cell_m, ctx.params, ctx.preps.iter().map(|p| p.sigma_m));
        let origin = origin_of(ctx);
        let mut g = Self::of(&ctx.spec, ctx.params.angle_bins, rho_bin, origin);
        // A far tangent offset is at most the farthest point of the band's
        // outer ellipse from the origin: within |c − o| + a and within the
        // farthest corner of the ellipse's bounding box.
        let reach = ctx
            .preps
            .iter()
            .map(|p| {
                let e = &p.ellipse;
                let a = e.semi_major_m + 0.5 * ctx.params.band_sigmas * p.sigma_m;
                let half_d = 0.5 * e.focus_a.dist(e.focus_b);
                let b = (a * a - half_d * half_d).max(0.0).sqrt();
                let hx = (a * e.cos_t).hypot(b * e.sin_t);
                let hy = (a * e.sin_t).hypot(b * e.cos_t);
                let d = e.center - origin;
                (d.norm() + a).min((d.x.abs() + hx).hypot(d.y.abs() + hy))
            })
            .fold(0.0, f64::max);
        if reach > g.r_max {
            let cap_bins = ((DEFAULT_MEMORY_CAP_BYTES / 4) / g.k_bins as u128).min(MAX_RHO_BINS as u128) as usize;
            let room = (cap_bins.saturating_sub(g.n_rho) / 2).min(MAX_EXTENSION * g.n_rho);
            g.ext = (((reach - g.r_max) / g.rho_bin).ceil() as usize).min(room);
            g.n_rho += 2 * g.ext;
        }
        g
    }
    /// Bins of `rho_bin`, widened where the grid's reach would need more
    /// than [`MAX_RHO_BINS`] of them: a row capped at that many covered only
    /// the offsets nearest −r_max, so on a grid 200 km wide the walls
    /// through its middle were never voted for ([`check_vote_memory`]
    /// refuses bins widened to more than twice `rho_bin`).
    fn of(spec: &GridSpec, angle_bins: u32, rho_bin: f64, origin: Point) -> Self {
        let r_max = 0.5 * (spec.x_max_m() - spec.x_min_m).hypot(spec.y_max_m() - spec.y_min_m) + spec.cell_m;
        // Two bins short of the cap, so the rounding of the count below stays within it.
        let rho_bin = rho_bin.max(2.0 * r_max / (MAX_RHO_BINS - 2) as f64);
        let k_bins = angle_bins as usize;
        Geom {
            origin,
            r_max,
            rho_bin,
            ext: 0,
            n_rho: ((2.0 * r_max / rho_bin).ceil() as usize + 1).min(MAX_RHO_BINS),
            k_bins,
            bin: TAU / k_bins as f64,
        }
    }
    /// The offset of bin `b`.
    fn offset_of(&self, b: usize) -> f64 {
        (b as f64 - self.ext as f64) * self.rho_bin - self.r_max
    }
    /// The line of Hough cell (`t`, `b`): normal angle and offset.
    fn line_of(&self, t: usize, b: usize) -> (f64, f64) {
        (t as f64 * self.bin, self.offset_of(b))
    }
}

/// Offset bins of the line vote (m): the grid's cell, or the echoes' median
/// band half-width kσ when that is narrower, but no finer than a sixteenth
/// of a cell (the vote's memory and time stay within 16× the cell's).
/// Bins wider than the band quantise a wall's offset by more than its
/// echoes allow: its peak splits over two bins, the vote's best cells sit
/// a few angle bins off, and the peak's own line, tested before refinement,
/// misses the band, so the wall is dropped. Seen on a long walk in a room
/// with σ = 1 cm and 10 cm cells (scripts/bench/long-walk.sh's echoes):
/// one to three of the four walls were found, depending on the bounds.
pub(crate) fn vote_rho_bin(cell_m: f64, params: &EvidenceParams, sigmas_m: impl Iterator<Item = f64>) -> f64 {
    let mut taus: Vec<f64> = sigmas_m.map(|s| params.band_sigmas * s).collect();
    if taus.is_empty() {
        return cell_m;
    }
    median(&mut taus).clamp(cell_m / 16.0, cell_m)
}

/// Refuses a grid and angle resolution whose line vote (an f32 accumulator of
/// `angle_bins` × offset bins of `rho_bin`) would need more than the
/// mapper's memory cap, before anything is allocated: an error naming the
/// field, not an abort; and a grid whose reach needs offset bins widened
/// past twice `rho_bin` ([`Geom::of`]).
pub(crate) fn check_vote_memory(spec: GridSpec, params: &EvidenceParams, rho_bin: f64) -> Result<(), CoreError> {
    let g = Geom::of(&spec, params.angle_bins, rho_bin, Point::new(0.0, 0.0));
    let bytes = (g.k_bins as u128) * (g.n_rho as u128) * 4;
    if bytes > DEFAULT_MEMORY_CAP_BYTES {
        return Err(CoreError::InvalidParam {
            field: "evidence.angle_bins",
            reason: format!(
                "the line vote over this grid ({} angle bins x {} offset bins) needs {bytes} bytes, more than the \
                 cap of {DEFAULT_MEMORY_CAP_BYTES} bytes; use fewer angle bins, smaller bounds or a larger cell",
                g.k_bins, g.n_rho
            ),
        });
    }
    // Offset bins widened to more than twice what the echoes' σ asks for
    // quantise a wall's offset past its band, and walls are lost (a wall
    // of σ = 2 cm was found on a grid 80 km wide, bins 1.2× wider, and lost
    // at 200 km, 3×): refused rather than lost silently.
    if g.rho_bin > 2.0 * rho_bin {
        return Err(CoreError::InvalidGrid(format!(
            "the line vote would need {} offset bins of {} m across this grid, more than the {MAX_RHO_BINS} it can \
             vote; use smaller bounds or a larger cell",
            crate::error::Num((2.0 * g.r_max / rho_bin).ceil() + 1.0),
            crate::error::Num(rho_bin)
        )));
    }
    Ok(())
}

/// One angle's row of the Hough vote ([`hough_peaks`]), compiled for the
/// widest vectors the CPU has ([`pulp`]'s runtime dispatch: AVX-512 or AVX2,
/// where the baseline x86-64 target has 2-lane SSE2). No operation is fused,
/// so the votes are the same bits either way.
struct VoteRow<'a> {
    tan: &'a Tangents,
    n: Point,
    rho_buf: &'a mut [f64],
    row: &'a mut [f32],
    half: &'a [f64],
    inv_half: &'a [f64],
    centres: &'a [f64],
    r_max: f64,
    /// [`Geom::ext`] as a float.
    ext: f64,
    inv_bin: f64,
    window: usize,
}

impl pulp::WithSimd for VoteRow<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let VoteRow { tan, n, rho_buf, row, half, inv_half, centres, r_max, ext, inv_bin, window } = self;
        let n_rho = row.len();
        tan.offsets(n, rho_buf);
        for ((&rho, &half), &inv_half) in rho_buf.iter().zip(half).zip(inv_half) {
            // By a multiplication rather than a division: rounding can move
            // `lo` or `hi` by one only when a bin centre lies within an ulp
            // of the band's edge, where its weight is 0 or ~1e-16 (and the
            // window keeps a spare cell past the band either way).
            let lo = (ceil_fast((rho - half + r_max) * inv_bin) + ext).max(0.0);
            let hi = (floor_fast((rho + half + r_max) * inv_bin) + ext).min(n_rho as f64 - 1.0);
            if lo > hi {
                continue;
            }
            let first = lo as usize;
            // A fixed-length window (cells past `hi` get a weight of exactly
            // 0 or, by rounding, far below one f32 ulp of any peak) avoids a
            // data-dependent loop length.
            let end = (first + window).min(n_rho);
            for (v, &x) in row[first..end].iter_mut().zip(&centres[first..]) {
                let d = (x - rho).abs();
                *v += (1.0 - d * inv_half).max(0.0) as f32;
            }
        }
    }
}

/// The Hough vote and its peaks, strongest first (ties in cell order), at
/// most 4 × `max_surfaces`: (votes, angle bin, offset bin).
fn hough_peaks(ctx: &Ctx, tan: &Tangents, g: &Geom) -> Vec<(f32, usize, usize)> {
    let p = ctx.params;
    let Geom { r_max, rho_bin, n_rho, k_bins, bin, ext, .. } = *g;
    let ext = ext as f64;
    let trig: Vec<(f64, f64)> = (0..k_bins).map(|t| (t as f64 * bin).sin_cos()).map(|(s, c)| (c, s)).collect();
    // Triangular votes (1 at the tangent offset, 0 at the band's edge plus a
    // bin) so that the angle where the offsets agree best is a strict peak
    // rather than one end of a plateau of equal counts.
    let mut acc = crate::grid::prefaulted(k_bins * n_rho, 0f32);
    let half: Vec<f64> = (0..tan.len()).map(|k| tau(ctx, k) + rho_bin).collect();
    let inv_half: Vec<f64> = half.iter().map(|h| 1.0 / h).collect();
    // At most the row: a huge σ (a band wider than the grid) must not size
    // the bin centres' table or the vote's loop beyond it (its cells past
    // the row are never written either way).
    let window = half.iter().map(|h| (2.0 * h / rho_bin) as usize + 2).max().unwrap_or(1).min(n_rho);
    let inv_bin = 1.0 / rho_bin;
    // Offset of each bin's centre (the same expression as in the loop it
    // replaces, so the same value), padded by a window for the last spans.
    let centres: Vec<f64> = (0..n_rho + window).map(|i| (i as f64 - ext) * rho_bin - r_max).collect();
    // Angle by angle (each echo's votes reach a cell in echo order either
    // way): one accumulator row stays in cache, and the offsets of all
    // echoes at one angle are a straight, vectorisable loop. Rows are
    // independent, so they are voted on rayon's threads (the same sums
    // whatever the thread count).
    use rayon::prelude::*;
    let rows = acc.par_chunks_mut(n_rho).zip(trig.par_iter());
    let arch = pulp::Arch::new();
    let (half, inv_half, centres) = (&half[..], &inv_half[..], &centres[..]);
    rows.for_each_init(
        || vec![0.0; tan.len()],
        |rho_buf, (row, &(nx, ny))| {
            let n = Point::new(nx, ny);
            arch.dispatch(VoteRow { tan, n, rho_buf, row, half, inv_half, centres, r_max, ext, inv_bin, window });
        },
    );
    // Peaks: votes ≥ min_support and maximal among the 8 neighbours
    // (θ wraps); equal neighbours earlier in scan order win.
    // Row by row on rayon's threads: a cell's verdict reads only the
    // finished vote, and the sort below is a total order, so the list is
    // the same whatever the thread count.
    let min_votes = p.min_support as f32;
    let acc = &acc[..];
    let row_peaks = |t: usize| -> Vec<(f32, usize, usize)> {
        let mut peaks = Vec::new();
        // Most cells are far below the threshold: a block none of whose
        // cells reaches it (a branch-free maximum) is skipped at once.
        let blocks = acc[t * n_rho..(t + 1) * n_rho].chunks(PEAK_BLOCK).enumerate();
        for (blk, block) in blocks.filter(|(_, c)| c.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v)) >= min_votes) {
            for (i, &v) in block.iter().enumerate() {
                let b = blk * PEAK_BLOCK + i;
                if v < min_votes {
                    continue;
                }
                let mut is_max = true;
                'nb: for dt in [k_bins - 1, 0, 1] {
                    let tt = (t + dt) % k_bins;
                    for bb in b.saturating_sub(1)..=(b + 1).min(n_rho - 1) {
                        if (tt, bb) == (t, b) {
                            continue;
                        }
                        let w = acc[tt * n_rho + bb];
                        let earlier = tt < t || (tt == t && bb < b);
                        if w > v || (w == v && earlier) {
                            is_max = false;
                            break 'nb;
                        }
                    }
                }
                if is_max {
                    peaks.push((v, t, b));
                }
            }
        }
        peaks
    };
    let mut peaks: Vec<(f32, usize, usize)> = (0..k_bins).into_par_iter().flat_map_iter(row_peaks).collect();
    peaks.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    peaks.truncate((4 * p.max_surfaces as usize).min(MAX_PEAKS));
    peaks
}

/// Most Hough peaks refined, whatever `max_surfaces` (whose limit is
/// 100 000): each refined candidate keeps its echoes, and the screening's
/// nearness test and the duplicate test compare candidates pairwise, so 4 ×
/// 100 000 peaks of 10 000 random echoes (with nothing screened) took
/// 2.5 min and 8.4 GB, far past the memory cap. The default `max_surfaces`
/// (64) refines 256.
const MAX_PEAKS: usize = 1024;

/// The peaks, strongest first, screened and refined: `(refined, screened)`.
/// A peak next to a line already refined or screened (within 2 bins in
/// angle, and that line's midpoint within 2 offset bins plus a band of the
/// peak's line) is the same line's skirt: refining it again finds that line.
/// A peak whose echoes, at the peak itself, already bend along the line (the
/// tangents of a pillar or of a circle's arc) is not refined: the curvature
/// test rejects it afterwards anyway, and a tilt of the line (the peak's
/// angle is off by up to half a bin) adds only a linear term to the
/// residuals, not a sagitta. Nor is a peak whose own line is heard from too
/// few of the poses that should hear it ([`unheard_at_peak`]). Screened
/// peaks still stand for their neighbours.
fn screen_and_refine(ctx: &Ctx, tan: &Tangents, g: &Geom, peaks: &[(f32, usize, usize)]) -> (Vec<Cand>, Vec<Cand>) {
    use rayon::prelude::*;
    let p = ctx.params;
    let Geom { origin, rho_bin, bin, .. } = *g;
    let unheard = unheard_at_peak(p.ghost_fraction);
    let mut refined: Vec<Cand> = Vec::new();
    let mut screened: Vec<Cand> = Vec::new();
    let is_near = |theta: f64, rho: f64, done: &[Cand]| {
        let n = Point::from_angle(theta);
        done.iter().any(|c| {
            let mid = (c.p0 + c.p1) * 0.5;
            angle_diff(theta, c.theta) <= 2.0 * bin
                && (n.dot(mid - origin) - rho).abs() <= 2.0 * rho_bin + p.band_sigmas * p.default_sigma_m
        })
    };
    // Screening and refining a peak are pure functions of the peak, so a
    // batch of peaks is worked out on rayon's threads ahead of the
    // sequential pass that decides, peak by peak and in order, which results
    // to use: the same candidates as one peak at a time. A peak already near
    // a line before its batch stays near (the lists only grow), so it is not
    // worked out; one that becomes near within its batch is wasted work.
    const BATCH: usize = 16;
    for batch in peaks.chunks(BATCH) {
        let work: Vec<Option<Screened>> = batch
            .par_iter()
            .map_init(Vec::new, |buf, &(_, t, b)| {
                let (theta, rho) = g.line_of(t, b);
                if is_near(theta, rho, &refined) || is_near(theta, rho, &screened) {
                    return None;
                }
                let set = gather(tan, theta, rho, 0.0, buf);
                let touches = touches_in_runs(ctx, &set, theta, rho, origin);
                let (p0, p1) = segment_of(theta, rho, origin, &touches);
                let quick = Cand { theta, rho, touches, p0, p1, rms_sigmas: f64::INFINITY };
                Some(if curved(ctx, &quick, origin) || heard_ratio(ctx, &quick, origin) < unheard {
                    Screened::NotRefined(quick)
                } else {
                    Screened::Refined(refine(ctx, tan, theta, rho, origin, bin, rho_bin))
                })
            })
            .collect();
        for (&(_, t, b), w) in batch.iter().zip(work) {
            let (theta, rho) = g.line_of(t, b);
            let Some(w) = w else { continue };
            if is_near(theta, rho, &refined) || is_near(theta, rho, &screened) {
                continue;
            }
            match w {
                Screened::NotRefined(quick) => screened.push(quick),
                Screened::Refined(Some(c)) => refined.push(c),
                Screened::Refined(None) => {}
            }
        }
    }
    (refined, screened)
}

/// The Hough vote, candidate refinement, ghost rejection and assignment.
pub(crate) fn find_lines(ctx: &Ctx) -> LinesResult {
    let p = ctx.params;
    if ctx.preps.is_empty() {
        return LinesResult::default();
    }
    let g = Geom::new(ctx);
    let Geom { origin, rho_bin, bin, .. } = g;
    let tan = Tangents::new(ctx, origin);
    let peaks = hough_peaks(ctx, &tan, &g);
    let (refined, _) = screen_and_refine(ctx, &tan, &g, &peaks);
    let mut cands: Vec<Cand> = refined
        .into_iter()
        .filter(|c| c.support() >= p.min_support as usize && c.length() >= p.min_line_length_m)
        .filter(|c| !curved(ctx, c, origin) && heard_ratio(ctx, c, origin) >= 1.0 - p.ghost_fraction)
        .collect();
    cands.sort_by(|a, b| {
        b.support().cmp(&a.support()).then(a.rms_sigmas.total_cmp(&b.rms_sigmas)).then(a.theta.total_cmp(&b.theta))
    });
    let mut uniq: Vec<Cand> = Vec::new();
    for c in cands {
        let dup = uniq.iter().any(|u| {
            angle_diff(u.theta, c.theta) < 3.0 * bin && {
                let shared = c.touches.iter().filter(|(k, _)| u.touches.iter().any(|(j, _)| j == k)).count();
                2 * shared >= c.support()
            }
        });
        if !dup {
            uniq.push(c);
        }
    }

    // Ghosts: mostly in free space, or mostly behind a stronger line.
    let ghost = ghost_lines(ctx, &uniq);
    let mut out = LinesResult::default();
    for (c, g) in uniq.iter().zip(&ghost) {
        if *g {
            out.ghost_echoes.extend(c.touches.iter().map(|&(k, _)| k));
        }
    }

    // Greedy: strongest first, each echo explained once; a candidate whose
    // echoes an accepted ambiguous line already explains is its mirror twin,
    // reported too (ambiguous).
    let mut owner: Vec<Option<usize>> = vec![None; ctx.preps.len()];
    let twin_tol = p.band_sigmas * p.default_sigma_m;
    // One mirror twin per ambiguous line: the best-fitting candidate near it.
    let mut has_twin: Vec<bool> = Vec::new();
    for (c, _) in uniq.iter().zip(&ghost).filter(|(_, g)| !**g) {
        if out.accepted.len() >= p.max_surfaces as usize {
            break;
        }
        let owners: Vec<Option<usize>> = c.touches.iter().map(|&(k, _)| owner[k]).collect();
        let twin = owners.first().copied().flatten().filter(|&o| {
            let a = &out.accepted[o];
            !has_twin[o]
                && a.surface.ambiguous
                && 5 * owners.iter().filter(|x| **x == Some(o)).count() >= 4 * owners.len()
                && mirror_twin(ctx, a, origin).is_some_and(|(th, rho)| {
                    angle_diff(th, c.theta) <= 2.0 * bin && (rho - c.rho).abs() <= 2.0 * twin_tol + rho_bin
                })
        });
        let touches: Vec<(usize, Point)> = if twin.is_some() {
            c.touches.clone()
        } else {
            let free: Vec<usize> = c.touches.iter().filter(|(k, _)| owner[*k].is_none()).map(|&(k, _)| k).collect();
            if free.len() < c.touches.len() {
                touches_in_runs(ctx, &free, c.theta, c.rho, origin)
            } else {
                c.touches.clone()
            }
        };
        if touches.len() < p.min_support as usize {
            continue;
        }
        let (p0, p1) = segment_of(c.theta, c.rho, origin, &touches);
        if p0.dist(p1) < p.min_line_length_m {
            continue;
        }
        let ks: Vec<usize> = touches.iter().map(|&(k, _)| k).collect();
        let ambiguous = ctx.collinear(&ks);
        let idx = out.accepted.len();
        match twin {
            None => {
                for &k in &ks {
                    owner[k] = Some(idx);
                }
            }
            Some(o) => has_twin[o] = true,
        }
        has_twin.push(twin.is_some());
        out.accepted.push(LineOut {
            surface: Surface { kind: SurfaceKind::Line, p0, p1, support: touches.len(), ambiguous },
            touches,
            theta: c.theta,
            rho: c.rho,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evidence::{EvidenceParams, carve_free, prepare};
    use crate::exact::{ExactOptions, ExactScene, Pose, exact_echoes};
    use crate::{Circle, Echo, GridSpec, Obstacle, Polygon, Shape};

    /// The 8 m × 6 m room with a pillar, first- and second-order echoes
    /// along a loop of 160 poses (the `evidence` bench's room).
    fn room_echoes() -> (Vec<Echo>, GridSpec) {
        let ob = |shape| Obstacle { shape, roughness: 0.0, absorption: 0.0 };
        let v = vec![Point::new(0.0, 0.0), Point::new(8.0, 0.0), Point::new(8.0, 6.0), Point::new(0.0, 6.0)];
        let truth = [
            ob(Shape::Polygon(Polygon::new(v).expect("room"))),
            ob(Shape::Circle(Circle::new(Point::new(5.5, 3.8), 0.3).expect("pillar"))),
        ];
        let poses: Vec<Pose> = (0..160)
            .map(|k| {
                let u = f64::from(k) * TAU / 160.0;
                Pose { t_s: f64::from(k), listener: Point::new(4.0 + 2.6 * u.cos(), 3.0 + 1.8 * u.sin()) }
            })
            .collect();
        let opts = ExactOptions { second_order: true, ..ExactOptions::default() };
        let echoes =
            exact_echoes(Point::new(2.0, 2.5), &poses, &ExactScene::from_obstacles(&truth), &opts).expect("echoes");
        (echoes, GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid"))
    }

    fn same(a: &[Cand], b: &[Cand]) -> bool {
        a.len() == b.len()
            && a.iter().zip(b).all(|(x, y)| {
                x.theta.to_bits() == y.theta.to_bits()
                    && x.rho.to_bits() == y.rho.to_bits()
                    && x.touches.iter().map(|t| t.0).eq(y.touches.iter().map(|t| t.0))
            })
    }

    /// Runs `f` on the room's context, vote geometry, tangents and peaks.
    fn with_room<R>(f: impl FnOnce(&Ctx, &Geom, &Tangents, &[(f32, usize, usize)]) -> R) -> R {
        let (echoes, spec) = room_echoes();
        let params = EvidenceParams::default();
        let mut ctx = prepare(&echoes, spec, &params).expect("ctx");
        carve_free(&mut ctx).expect("carve");
        let g = Geom::new(&ctx);
        let tan = Tangents::new(&ctx, g.origin);
        let peaks = hough_peaks(&ctx, &tan, &g);
        f(&ctx, &g, &tan, &peaks)
    }

    /// The one peak at a time loop `screen_and_refine` replaced, with or
    /// without the unheard-at-peak screen: the refined candidates with the
    /// heard fraction of their unrefined line, the screened ones, and how
    /// many peaks were skipped as near a line already found.
    fn sequential(
        ctx: &Ctx,
        g: &Geom,
        tan: &Tangents,
        peaks: &[(f32, usize, usize)],
        screen: bool,
    ) -> (Vec<(f64, Cand)>, Vec<Cand>, usize) {
        let (p, origin) = (ctx.params, g.origin);
        let (mut refined, mut screened, mut near_n, mut buf) = (Vec::<(f64, Cand)>::new(), Vec::new(), 0, Vec::new());
        for &(_, t, b) in peaks {
            let (theta, rho) = g.line_of(t, b);
            let n = Point::from_angle(theta);
            let near = refined.iter().map(|r| &r.1).chain(&screened).any(|c: &Cand| {
                let mid = (c.p0 + c.p1) * 0.5;
                angle_diff(theta, c.theta) <= 2.0 * g.bin
                    && (n.dot(mid - origin) - rho).abs() <= 2.0 * g.rho_bin + p.band_sigmas * p.default_sigma_m
            });
            if near {
                near_n += 1;
                continue;
            }
            let set = gather(tan, theta, rho, 0.0, &mut buf);
            let touches = touches_in_runs(ctx, &set, theta, rho, origin);
            let (p0, p1) = segment_of(theta, rho, origin, &touches);
            let quick = Cand { theta, rho, touches, p0, p1, rms_sigmas: f64::INFINITY };
            let heard = heard_ratio(ctx, &quick, origin);
            if curved(ctx, &quick, origin) || (screen && heard < unheard_at_peak(p.ghost_fraction)) {
                screened.push(quick);
                continue;
            }
            if let Some(c) = refine(ctx, tan, theta, rho, origin, g.bin, g.rho_bin) {
                refined.push((heard, c));
            }
        }
        (refined, screened, near_n)
    }

    /// At most [`MAX_PEAKS`] peaks are refined however many surfaces are
    /// allowed: the room's echoes with every local maximum of two votes a
    /// peak give more than that.
    #[test]
    fn peaks_are_capped_whatever_max_surfaces() {
        let (echoes, spec) = room_echoes();
        let params = EvidenceParams { max_surfaces: 100_000, min_support: 2, ..EvidenceParams::default() };
        let mut ctx = prepare(&echoes, spec, &params).expect("ctx");
        carve_free(&mut ctx).expect("carve");
        let g = Geom::new(&ctx);
        let tan = Tangents::new(&ctx, g.origin);
        assert_eq!(hough_peaks(&ctx, &tan, &g).len(), MAX_PEAKS);
        let few = EvidenceParams { max_surfaces: 10, ..params };
        let ctx = Ctx { params: &few, ..ctx };
        assert_eq!(hough_peaks(&ctx, &tan, &g).len(), 40);
    }

    /// The batched screening takes exactly the candidates of the one peak at
    /// a time loop, whatever the pool's size.
    #[test]
    fn batched_screening_is_the_sequential_loop() {
        with_room(|ctx, g, tan, peaks| {
            assert!(peaks.len() > 100, "{} peaks", peaks.len());
            let (refined, screened, _) = sequential(ctx, g, tan, peaks, true);
            let refined: Vec<Cand> = refined.into_iter().map(|r| r.1).collect();
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                let (r, sc) = pool.install(|| screen_and_refine(ctx, tan, g, peaks));
                assert!(same(&r, &refined) && same(&sc, &screened), "{threads} threads");
            }
            assert!(!refined.is_empty() && !screened.is_empty());
        });
    }

    /// The ghost verdicts against the loop `ghost_lines` replaced: every
    /// candidate's occluders and hidden fraction recomputed every round, one
    /// candidate after another, with a linear search for shared echoes. On
    /// the room's refined and screened candidates, whatever the pool's size.
    #[test]
    fn ghost_verdicts_are_the_round_by_round_loop() {
        with_room(|ctx, g, tan, peaks| {
            let p = ctx.params;
            let (refined, screened) = screen_and_refine(ctx, tan, g, peaks);
            let cands: Vec<Cand> = refined.into_iter().chain(screened).collect();
            let shares = |c: &Cand, o: &Cand| {
                let shared = c.touches.iter().filter(|(k, _)| o.touches.iter().any(|(j, _)| j == k)).count();
                2 * shared >= c.support()
            };
            let in_free: Vec<bool> = cands.iter().map(|c| free_fraction(ctx, c) > p.ghost_fraction).collect();
            let mut want = in_free.clone();
            let mut rounds_changed = 0;
            for _ in 0..6 {
                let next: Vec<bool> = (0..cands.len())
                    .map(|i| {
                        let c = &cands[i];
                        in_free[i] || {
                            let occ: Vec<&Cand> = (0..cands.len())
                                .filter(|&j| {
                                    j != i && !want[j] && 2 * cands[j].support() >= c.support() && !shares(c, &cands[j])
                                })
                                .map(|j| &cands[j])
                                .collect();
                            occluded_fraction(ctx, c, &occ) > p.ghost_fraction
                        }
                    })
                    .collect();
                if next == want {
                    break;
                }
                want = next;
                rounds_changed += 1;
            }
            let hidden = want.iter().zip(&in_free).filter(|(g, f)| **g && !**f).count();
            assert!(hidden > 0 && want.iter().any(|g| !g), "{hidden} hidden of {}", cands.len());
            assert!(rounds_changed >= 2, "{rounds_changed} rounds changed a verdict");
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                assert_eq!(pool.install(|| ghost_lines(ctx, &cands)), want, "{threads} threads");
            }
        });
    }

    /// Every peak refined (no unheard-at-peak screen), and what became of
    /// it, against the heard fraction of its unrefined line: no line the
    /// mapper accepts starts below the screen's threshold (with a margin), so
    /// screening by it loses none. Prints the census BENCHMARKS.md quotes
    /// (`-- --nocapture`).
    #[test]
    fn peak_census_of_the_room() {
        with_room(|ctx, g, tan, peaks| {
            let p = ctx.params;
            let (refined, screened, near_n) = sequential(ctx, g, tan, peaks, false);
            // Outcomes in the order `find_lines` tests them.
            let (mut kept, mut short, mut bent, mut unheard) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for (h, c) in &refined {
                if c.support() < p.min_support as usize || c.length() < p.min_line_length_m {
                    short.push(*h);
                } else if curved(ctx, c, g.origin) {
                    bent.push(*h);
                } else if heard_ratio(ctx, c, g.origin) < 1.0 - p.ghost_fraction {
                    unheard.push(*h);
                } else {
                    kept.push(*h);
                }
            }
            let range =
                |v: &[f64]| v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
            let below = |v: &[f64], x: f64| v.iter().filter(|&&h| h < x).count();
            let screen = unheard_at_peak(p.ghost_fraction);
            println!(
                "room: {} peaks, {near_n} near a line already found, {} screened as curved, {} refined: {} kept \
                 (heard at the peak {:.2?}), {} unheard ({} below 0.30, {} below the screen's {screen}), {} curved, \
                 {} short",
                peaks.len(),
                screened.len(),
                refined.len(),
                kept.len(),
                range(&kept),
                unheard.len(),
                below(&unheard, 0.30),
                below(&unheard, screen),
                bent.len(),
                short.len()
            );
            let (with_screen, _) = screen_and_refine(ctx, tan, g, peaks);
            println!("room: {} peaks refined with the screen", with_screen.len());
            assert!(with_screen.len() < refined.len());
            assert!(kept.len() >= 4, "{} lines", kept.len());
            assert!(range(&kept).0 >= 1.1 * screen, "{:?}", range(&kept));
            // The screen spares a good share of the unheard peaks' work
            // (48 of 102 since the vote's offset bins follow σ; 59 of 97
            // with bins of a cell).
            assert!(below(&unheard, screen) > unheard.len() / 3);
        });
    }

    proptest::proptest! {
        /// The scan's kernel score: the same bits on the CPU's widest
        /// vectors as on plain scalar code (so a seed gives the same map on
        /// every machine), and within 1e-12 of the sum with libm's `exp`
        /// over the offsets within the cut (the oracle).
        #[test]
        fn kernel_sum_is_the_same_bits_at_every_width(
            raw_sigma in proptest::collection::vec((-3.0f64..3.0, 0.001f64..0.3), 0..80),
            centre in -2.0f64..2.0,
            cut_sigmas in 1.0f64..9.0,
        ) {
            let (raw, sigma): (Vec<f64>, Vec<f64>) = raw_sigma.into_iter().unzip();
            let neg_half_prec: Vec<f64> = sigma.iter().map(|s| -0.5 / (s * s)).collect();
            let cut = cut_sigmas * sigma.iter().copied().fold(0.0, f64::max);
            let sum = || KernelSum { raw: &raw, neg_half_prec: &neg_half_prec, centre, cut };
            let wide = pulp::Arch::new().dispatch(sum());
            let scalar = pulp::WithSimd::with_simd(sum(), pulp::Scalar::new());
            proptest::prop_assert_eq!(wide.to_bits(), scalar.to_bits());
            let oracle: f64 = raw
                .iter()
                .zip(&sigma)
                .filter(|(r, _)| (**r - centre).abs() <= cut)
                .map(|(r, s)| (-0.5 * ((r - centre) / s).powi(2)).exp())
                .sum();
            proptest::prop_assert!((wide - oracle).abs() <= 1e-12 * oracle.max(1.0), "{wide} vs {oracle}");
        }

        /// The one-step window finds what a search of every window finds:
        /// the most offsets within `width` of one another and the mean of
        /// the first such window (oracle: each start's count by scan, ties
        /// to the earliest; values on a coarse lattice, so ties and windows
        /// exactly `width` wide are common).
        #[test]
        fn densest_is_the_first_fullest_window(
            mut keys in proptest::collection::vec(0u8..40, 0..60),
            width_steps in 0u8..12,
        ) {
            keys.sort_unstable();
            let vals: Vec<f64> = keys.iter().map(|&k| f64::from(k) * 0.125 - 1.0).collect();
            let width = f64::from(width_steps) * 0.125;
            let (mut best, mut best_lo) = (0usize, 0usize);
            for lo in 0..vals.len() {
                let count = vals[lo..].iter().take_while(|&&v| v - vals[lo] <= width).count();
                if count > best {
                    (best, best_lo) = (count, lo);
                }
            }
            let mean = vals[best_lo..best_lo + best].iter().sum::<f64>() / best.max(1) as f64;
            let (got, got_mean) = densest(&vals, width);
            proptest::prop_assert_eq!(got, best);
            proptest::prop_assert_eq!(got_mean.to_bits(), mean.to_bits());
        }

        /// Sorting with a move budget and the merge sort's finish gives a
        /// stable sort by `total_cmp` (the oracle: the standard library's),
        /// ties included (few distinct values, so many), whatever the
        /// budget; with and without −0 and NaN among the values (`+0` and
        /// `−0`, or NaNs of either sign, are distinct keys there).
        #[test]
        fn budgeted_sort_is_the_stable_total_order(
            keys in proptest::collection::vec(0u8..6, 0..80),
            odd in 0u8..3,
            budget in 0usize..400,
        ) {
            let odd_value = |k: u8| match (odd, k) {
                (1, 0) => -0.0,
                (2, 0) => f64::NAN,
                (2, 1) => -f64::NAN,
                _ => f64::from(k) * 0.25 - 0.5,
            };
            let raw: Vec<f64> = keys.iter().map(|&k| odd_value(k)).collect();
            let mut want: Vec<(f64, usize)> = raw.iter().copied().zip(0..).collect();
            want.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut got = SortedOffsets { vals: raw.clone(), order: (0..raw.len()).collect(), ..SortedOffsets::default() };
            got.finish_sort(budget);
            let got_v: Vec<u64> = got.vals.iter().map(|v| v.to_bits()).collect();
            let want_v: Vec<u64> = want.iter().map(|w| w.0.to_bits()).collect();
            let want_o: Vec<usize> = want.iter().map(|w| w.1).collect();
            proptest::prop_assert_eq!(got_v, want_v);
            proptest::prop_assert_eq!(&got.order, &want_o);
        }
    }
}
