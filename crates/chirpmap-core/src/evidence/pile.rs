//! Envelope points within a radius of one another: listed, and counted in a
//! time that grows with a pile's rim rather than with its square.
//!
//! The envelope of a reflector heard from many close poses is a pile of
//! crossings a few centimetres across, and the compact-reflector search
//! counts, for every point, the points within `point_radius_m` of it. Cells
//! of side r (a spatial hash) make that nine cells' lists per point, which
//! inside a pile is every point of the pile: 35 291 echoes of a walk sampled
//! every millimetre round a pillar took 4.2 s on two cores, and doubling the
//! echoes quadrupled it (EXPERIMENTS.md, session 22). A cell holding many
//! points is split into fine cells with the bounding box of their points; a
//! fine cell whose box lies wholly within r of the query is counted whole,
//! one wholly beyond r is skipped, and only the points of the fine cells the
//! circle of radius r crosses are tested one by one. The counts are those of
//! the one-by-one test (`q.dist(p) <= r`) over the nine cells exactly (the
//! spatial hash's before this, whose cells and order [`Pile::within`] keeps;
//! like it, a point within about 10⁻¹⁷·r of the line x = 0 or y = 0 can
//! miss a neighbour exactly r away, two cells over): a box is taken whole or
//! skipped only when the squared distances to its farthest and nearest
//! points clear r² by a relative 2·10⁻⁹, far beyond the few ulps by which a
//! squared distance and `hypot` can disagree (with r² outside the normal
//! range, where that margin is lost in rounding, every point is tested by
//! `hypot`). (No crate was used: the k-d trees on crates.io count within a radius
//! by visiting each point inside, which is the quadratic cost itself.)

use crate::geometry::Point;
use std::collections::HashMap;

/// A cell of side r with more points than this gets fine cells.
const HEAVY: usize = 64;

/// Fine cells per side of a cell of side r.
const FINE_PER_SIDE: f64 = 8.0;

/// How far (relative to r²) a squared distance must clear r² to be decided
/// without `hypot`.
const CLEARANCE: f64 = 1e-9;

/// Points hashed into cells of side `r`, heavy cells split into fine ones.
pub(crate) struct Pile<'a> {
    pts: &'a [Point],
    r: f64,
    cells: HashMap<(i64, i64), Cell>,
}

#[derive(Default)]
struct Cell {
    /// Points of the cell, in index order.
    idx: Vec<usize>,
    /// Bounding box of a heavy cell's points.
    lo: Point,
    hi: Point,
    /// For a heavy cell: its points by fine cell, with their bounding box.
    fine: Vec<Fine>,
}

struct Fine {
    lo: Point,
    hi: Point,
    idx: Vec<usize>,
}

impl<'a> Pile<'a> {
    /// Hashes `pts` (finite) into cells of side `r` (> 0).
    pub(crate) fn new(pts: &'a [Point], r: f64) -> Self {
        let mut cells: HashMap<(i64, i64), Cell> = HashMap::new();
        for (i, &q) in pts.iter().enumerate() {
            cells.entry(key(q, r)).or_default().idx.push(i);
        }
        let fine_side = r / FINE_PER_SIDE;
        // With r² outside the normal range (r below ~1e-154 m or above
        // ~1e154 m) the clearance is lost in rounding: every cell is then
        // tested point by point, by `hypot`.
        let heavy = if (r * r).is_normal() { HEAVY } else { usize::MAX };
        for cell in cells.values_mut().filter(|c| c.idx.len() > heavy) {
            (cell.lo, cell.hi) = (pts[cell.idx[0]], pts[cell.idx[0]]);
            let mut by_key: HashMap<(i64, i64), usize> = HashMap::new();
            for &i in &cell.idx {
                let q = pts[i];
                let slot = *by_key.entry(key(q, fine_side)).or_insert_with(|| {
                    cell.fine.push(Fine { lo: q, hi: q, idx: Vec::new() });
                    cell.fine.len() - 1
                });
                let f = &mut cell.fine[slot];
                f.lo = Point::new(f.lo.x.min(q.x), f.lo.y.min(q.y));
                f.hi = Point::new(f.hi.x.max(q.x), f.hi.y.max(q.y));
                f.idx.push(i);
                cell.lo = Point::new(cell.lo.x.min(q.x), cell.lo.y.min(q.y));
                cell.hi = Point::new(cell.hi.x.max(q.x), cell.hi.y.max(q.y));
            }
        }
        Pile { pts, r, cells }
    }

    /// The nine cells about point `i`'s, in the listing's order.
    fn around(&self, i: usize) -> impl Iterator<Item = &Cell> {
        let (kx, ky) = key(self.pts[i], self.r);
        (-1..=1).flat_map(move |dx| (-1..=1).filter_map(move |dy| self.cells.get(&(kx + dx, ky + dy))))
    }

    /// Points within `r` of point `i` (itself included): cell by cell in
    /// the nine cells' order, each cell's in index order.
    pub(crate) fn within(&self, i: usize) -> Vec<usize> {
        let p = self.pts[i];
        let mut v = Vec::new();
        for cell in self.around(i) {
            v.extend(cell.idx.iter().copied().filter(|&j| self.near(j, p)));
        }
        v
    }

    /// `pts[j].dist(p) <= r`, the same answer bit for bit: by the squared
    /// distance unless it lies within a relative 10⁻⁹ of r², far beyond
    /// the ulps by which it and `hypot`'s can differ; only then by `hypot`.
    #[inline]
    fn near(&self, j: usize, p: Point) -> bool {
        let q = self.pts[j];
        let (dx, dy) = (q.x - p.x, q.y - p.y);
        let d2 = dx * dx + dy * dy;
        let r2 = self.r * self.r;
        if !r2.is_normal() {
            return q.dist(p) <= self.r;
        }
        if d2 < r2 * (1.0 - CLEARANCE) {
            true
        } else if d2 > r2 * (1.0 + CLEARANCE) {
            false
        } else {
            q.dist(p) <= self.r
        }
    }

    /// `within(i).len()`, without testing every point of a heavy cell.
    pub(crate) fn count_within(&self, i: usize) -> usize {
        let (p, r) = (self.pts[i], self.r);
        let one_by_one = |idx: &[usize]| idx.iter().filter(|&&j| self.near(j, p)).count();
        let mut n = 0;
        for cell in self.around(i) {
            if cell.fine.is_empty() {
                n += one_by_one(&cell.idx);
                continue;
            }
            match side(p, r, cell.lo, cell.hi) {
                Side::Inside => n += cell.idx.len(),
                Side::Outside => {}
                Side::Across => {
                    for f in &cell.fine {
                        match side(p, r, f.lo, f.hi) {
                            Side::Inside => n += f.idx.len(),
                            Side::Outside => {}
                            Side::Across => n += one_by_one(&f.idx),
                        }
                    }
                }
            }
        }
        n
    }
}

/// Where a box lies against the disc of radius `r` about `p`.
enum Side {
    /// Every point of it passes [`Pile::near`] without `hypot`.
    Inside,
    /// Every point of it fails [`Pile::near`] without `hypot`.
    Outside,
    Across,
}

/// Squared distances to the box's farthest and nearest points, against r²
/// with twice [`Pile::near`]'s clearance, so that a box taken whole or
/// skipped is one whose every point [`Pile::near`] answers alike.
fn side(p: Point, r: f64, lo: Point, hi: Point) -> Side {
    let r2 = r * r;
    let (fx, fy) = ((p.x - lo.x).abs().max((p.x - hi.x).abs()), (p.y - lo.y).abs().max((p.y - hi.y).abs()));
    if fx * fx + fy * fy <= r2 * (1.0 - 2.0 * CLEARANCE) {
        return Side::Inside;
    }
    let (nx, ny) = ((lo.x - p.x).max(p.x - hi.x).max(0.0), (lo.y - p.y).max(p.y - hi.y).max(0.0));
    if nx * nx + ny * ny > r2 * (1.0 + 2.0 * CLEARANCE) { Side::Outside } else { Side::Across }
}

fn key(q: Point, side: f64) -> (i64, i64) {
    ((q.x / side).floor() as i64, (q.y / side).floor() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The naive oracle: every pair tested.
    fn naive(pts: &[Point], i: usize, r: f64) -> Vec<usize> {
        (0..pts.len()).filter(|&j| pts[j].dist(pts[i]) <= r).collect()
    }

    fn cloud(seed: u64, n: usize, centre: Point, spread: f64, rim: f64) -> Vec<Point> {
        // A ring of radius `rim` blurred by `spread` (a pillar's envelope),
        // from a small LCG so the points repeat.
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let mut u = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let a = u() * std::f64::consts::TAU;
                let d = rim + spread * (u() - 0.5);
                centre + Point::from_angle(a) * d + Point::new(spread * (u() - 0.5), spread * (u() - 0.5))
            })
            .collect()
    }

    proptest! {
        /// Counts and lists against testing every pair, on piles dense
        /// enough to have heavy cells (rings of 0–0.4 m, blurred by 0–0.3 m,
        /// 1–600 points, any radius from 1 cm to 1 m), with points repeated
        /// and points placed exactly r from another.
        #[test]
        fn counts_are_every_pair_tested(
            seed in 0u64..1_000_000,
            n in 1usize..600,
            cx in -20.0..20.0f64,
            cy in -20.0..20.0f64,
            spread in 0.0..0.3f64,
            rim in 0.0..0.4f64,
            r in 0.01..1.0f64,
        ) {
            let mut pts = cloud(seed, n, Point::new(cx, cy), spread, rim);
            pts.extend_from_within(..n.min(20));
            // Exactly r away along an axis, and r away in any direction
            // (where the squared distance and `hypot` can disagree about
            // which side of r they lie: the clearance must decide those).
            let mut on_rim: Vec<Point> = pts[..n.min(20)].iter().map(|&q| q + Point::new(r, 0.0)).collect();
            on_rim.extend(pts[..n.min(200)].iter().enumerate().map(|(k, &q)| q + Point::from_angle(0.7 * k as f64) * r));
            pts.extend(on_rim);
            let pile = Pile::new(&pts, r);
            for i in 0..pts.len() {
                let want = naive(&pts, i, r);
                prop_assert_eq!(pile.count_within(i), want.len(), "point {}", i);
                let mut got = pile.within(i);
                got.sort_unstable();
                prop_assert_eq!(got, want);
            }
        }
    }

    /// Radii whose square is subnormal or overflows: the boxes' clearance is
    /// lost in rounding there, so every point is tested by `hypot`.
    #[test]
    fn extreme_radii_are_still_every_pair_tested() {
        for r in [1e-160, 1e-200, 1e-300, 1e160] {
            let pts = cloud(3, 3000, Point::new(0.0, 0.0), 3.0 * r, 0.0);
            let pile = Pile::new(&pts, r);
            for i in (0..pts.len()).step_by(7) {
                assert_eq!(pile.count_within(i), naive(&pts, i, r).len(), "r {r}, point {i}");
            }
        }
    }

    /// A pile of 20 000 points in a 0.6 m ring (a pillar's envelope) has
    /// heavy cells, and its counts are still every pair tested (sampled).
    #[test]
    fn a_dense_pile_is_split_and_counted_exactly() {
        let pts = cloud(7, 20_000, Point::new(5.5, 3.8), 0.02, 0.3);
        let pile = Pile::new(&pts, 0.3);
        assert!(pile.cells.values().any(|c| !c.fine.is_empty()));
        for i in (0..pts.len()).step_by(97) {
            assert_eq!(pile.count_within(i), naive(&pts, i, 0.3).len(), "point {i}");
        }
    }
}
