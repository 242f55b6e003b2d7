//! Random scenes for the evidence mapper: a regression sweep for changes to
//! its heuristics, which `chirpmap benchmark maps` cannot judge alone (its
//! walls lie on the vote's angle bins, its σ is 2 cm or a particle bin).
//!
//! `cargo run --release -p chirpmap-core --example scene_sweep -- [SCENES] [FIRST_SEED]`
//! (defaults 300 and 0) prints one line per scene: its parameters, how many
//! of its compact reflectors and walls were found, the stray surfaces, and
//! every surface; then the totals. Run it at two commits and `diff` the
//! outputs: every changed line is a scene to look at. Session 17's two
//! reverted changes (EXPERIMENTS.md) were each caught by such a sweep.
//!
//! Scenes, exact echoes (`chirpmap_core::exact`) with optional Gaussian noise
//! and false echoes, σ from 1 mm to 10 cm: compact reflectors (0.05–0.5 m)
//! in the open on straight, loop or arc walks; 2–5 m circles; rooms of
//! 5–10 m × 4–8 m, rotated or not, with 0–2 pillars and, in half of them,
//! second-order echoes; a straight pass past one pole, sometimes through the
//! source (the mirror-ambiguous case). A reflector counts as found when a
//! point lies within 0.15 m of its surface (any surface for circles over
//! 1 m), a wall when a line has both ends within 0.1 m of it; a surface is
//! stray when it lies more than 0.35 m off every true surface (ambiguous
//! ones counted apart: their mirror twin is reported by design).

use chirpmap_core::exact::{ExactOptions, ExactScene, Pose, exact_echoes};
use chirpmap_core::geometry::point_segment_distance;
use chirpmap_core::metrics::truth_distance;
use chirpmap_core::{
    Circle, Echo, EvidenceParams, GridSpec, Obstacle, Point, Polygon, Shape, Surface, SurfaceKind, map_evidence,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};

fn circle(c: Point, r: f64) -> Obstacle {
    Obstacle { shape: Shape::Circle(Circle::new(c, r).expect("circle")), roughness: 0.0, absorption: 0.0 }
}

fn polygon(v: Vec<Point>) -> Obstacle {
    Obstacle { shape: Shape::Polygon(Polygon::new(v).expect("polygon")), roughness: 0.0, absorption: 0.0 }
}

/// A standard normal draw (Box–Muller).
fn gauss(r: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = r.random_range(1e-12..1.0);
    let u2: f64 = r.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
}

fn segment(a: Point, b: Point, n: usize) -> Vec<Point> {
    (0..n).map(|i| a + (b - a) * (i as f64 / (n - 1).max(1) as f64)).collect()
}

/// An ellipse (or, with `sweep` < 1, an arc of it) of `n` poses.
fn ellipse(c: Point, rx: f64, ry: f64, sweep: f64, phase: f64, n: usize) -> Vec<Point> {
    (0..n)
        .map(|k| {
            let u = phase + sweep * TAU * k as f64 / n as f64;
            Point::new(c.x + rx * u.cos(), c.y + ry * u.sin())
        })
        .collect()
}

struct Scene {
    desc: String,
    truth: Vec<Obstacle>,
    /// Compact reflectors: centre and radius.
    compact: Vec<(Point, f64)>,
    echoes: Vec<Echo>,
    spec: GridSpec,
}

/// Adds a circle of radius `rad` at `c` unless it comes within 0.5 m of one
/// already placed.
fn place(truth: &mut Vec<Obstacle>, compact: &mut Vec<(Point, f64)>, c: Point, rad: f64) {
    if compact.iter().all(|&(q, rq)| q.dist(c) > rq + rad + 0.5) {
        compact.push((c, rad));
        truth.push(circle(c, rad));
    }
}

fn scene(seed: u64) -> Scene {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let p = Point::new;
    let kind = r.random_range(0..4u32);
    let sigma_m = [0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1][r.random_range(0..7)];
    let noisy = r.random_range(0..2) == 0;
    let clutter = [0usize, 0, 1, 2][r.random_range(0..4)];
    let cell_m = [0.05, 0.1, 0.1, 0.2][r.random_range(0..4)];
    let n_poses = [40usize, 80, 160, 400, 1000][r.random_range(0..5)];
    let (mut truth, mut compact) = (Vec::new(), Vec::new());
    let mut second_order = false;
    let (source, listeners, walk) = match kind {
        0 | 3 => {
            let source = p(r.random_range(-1.0..1.0), r.random_range(-1.0..1.0));
            for _ in 0..if kind == 3 { 1 } else { r.random_range(1..4) } {
                let rad = r.random_range(0.05f64.ln()..0.5f64.ln()).exp();
                let (d, b) = (r.random_range(2.0..8.0), r.random_range(0.0..TAU));
                place(&mut truth, &mut compact, p(d * b.cos(), d * b.sin()), rad);
            }
            match if kind == 3 { 0 } else { r.random_range(0..3) } {
                0 => {
                    let h: f64 = r.random_range(0.0..PI);
                    let (dir, normal) = (p(h.cos(), h.sin()), p(-h.sin(), h.cos()));
                    let off = if kind == 3 && r.random_range(0..2) == 0 { 0.0 } else { r.random_range(-1.5..1.5) };
                    let len = r.random_range(3.0..16.0);
                    let a = source + normal * off - dir * (len / 2.0);
                    (
                        source,
                        segment(a, a + dir * len, n_poses),
                        format!("straight {len:.1} m, {off:.2} m off the source"),
                    )
                }
                1 => {
                    let (rx, ry) = (r.random_range(1.0..5.0), r.random_range(1.0..5.0));
                    (source, ellipse(p(0.0, 0.0), rx, ry, 1.0, 0.0, n_poses), format!("loop {rx:.1} × {ry:.1} m"))
                }
                _ => {
                    let (rad, sweep, phase) =
                        (r.random_range(1.0..4.0), r.random_range(0.1..0.5), r.random_range(0.0..TAU));
                    (source, ellipse(p(0.0, 0.0), rad, rad, sweep, phase, n_poses), format!("arc of {rad:.1} m"))
                }
            }
        }
        1 => {
            for _ in 0..r.random_range(1..4) {
                let rad = r.random_range(2.0..5.0);
                let (d, b) = (rad + r.random_range(3.0..12.0), r.random_range(0.0..TAU));
                place(&mut truth, &mut compact, p(d * b.cos(), d * b.sin()), rad);
            }
            let (rx, ry) = (r.random_range(1.0..3.0), r.random_range(1.0..3.0));
            (p(0.0, 0.0), ellipse(p(0.5, -0.3), rx, ry, 1.0, 0.0, n_poses), format!("loop {rx:.1} × {ry:.1} m"))
        }
        _ => {
            let (w, h) = (r.random_range(5.0..10.0), r.random_range(4.0..8.0));
            let rot: f64 = if r.random_range(0..2) == 0 { 0.0 } else { r.random_range(0.0..90.0f64).to_radians() };
            let at = |x: f64, y: f64| p(x * rot.cos() - y * rot.sin(), x * rot.sin() + y * rot.cos());
            truth.push(polygon(vec![at(0.0, 0.0), at(w, 0.0), at(w, h), at(0.0, h)]));
            for _ in 0..r.random_range(0..3) {
                let rad = r.random_range(0.05f64.ln()..0.5f64.ln()).exp();
                place(&mut truth, &mut compact, at(r.random_range(1.0..w - 1.0), r.random_range(1.0..h - 1.0)), rad);
            }
            second_order = r.random_range(0..2) == 0;
            let source = at(r.random_range(0.5..w - 0.5), r.random_range(0.5..h - 0.5));
            let (rx, ry) = (r.random_range(0.8..w / 2.0 - 0.4), r.random_range(0.8..h / 2.0 - 0.4));
            let loop_ = ellipse(p(w / 2.0, h / 2.0), rx, ry, 1.0, 0.0, n_poses);
            let walk = format!("room {w:.1} × {h:.1} m turned {:.1}°, loop {rx:.1} × {ry:.1} m", rot.to_degrees());
            (source, loop_.into_iter().map(|q| at(q.x, q.y)).collect::<Vec<_>>(), walk)
        }
    };
    // No pose on a reflector or the source.
    let listeners: Vec<Point> = listeners
        .into_iter()
        .filter(|&q| q.dist(source) > 0.05 && truth.iter().all(|o| o.surface_distance(q) > 0.1))
        .collect();
    let poses: Vec<Pose> =
        listeners.iter().enumerate().map(|(k, &listener)| Pose { t_s: 0.01 * k as f64, listener }).collect();
    let opts = ExactOptions { second_order, ..ExactOptions::default() };
    let mut echoes = exact_echoes(source, &poses, &ExactScene::from_obstacles(&truth), &opts).expect("echoes");
    if noisy {
        for e in &mut echoes {
            e.delta_d_m = (e.delta_d_m + sigma_m * gauss(&mut r)).max(0.0);
        }
    }
    let mut pts: Vec<Point> = compact.iter().flat_map(|&(c, rad)| [c + p(rad, rad), c - p(rad, rad)]).collect();
    pts.push(source);
    pts.extend(&listeners);
    for o in &truth {
        if let Shape::Polygon(poly) = &o.shape {
            pts.extend(poly.vertices());
        }
    }
    let lo = pts.iter().fold(p(f64::INFINITY, f64::INFINITY), |a, q| p(a.x.min(q.x), a.y.min(q.y)));
    let hi = pts.iter().fold(p(f64::NEG_INFINITY, f64::NEG_INFINITY), |a, q| p(a.x.max(q.x), a.y.max(q.y)));
    for q in &poses {
        for _ in 0..clutter {
            let dd = r.random_range(0.3..12.0);
            echoes.push(Echo::new(source, q.listener, dd, 1.0, q.t_s, 0).expect("false echo"));
        }
    }
    let echoes = echoes.into_iter().map(|e| e.with_sigma_m(sigma_m).expect("sigma")).collect();
    let spec =
        GridSpec::from_bounds([lo.x - 2.0, lo.y - 2.0, hi.x + 2.0, hi.y + 2.0], cell_m, u128::MAX).expect("grid");
    let reflectors: Vec<String> =
        compact.iter().map(|(c, rad)| format!("({:.2}, {:.2}) r {rad:.2}", c.x, c.y)).collect();
    let desc = format!(
        "{walk}; source ({:.2}, {:.2}); {} poses; reflectors [{}]; σ {sigma_m} m{}; {clutter} false echoes per pose; \
         {}cell {cell_m} m",
        source.x,
        source.y,
        poses.len(),
        reflectors.join(", "),
        if noisy { " with noise" } else { "" },
        if second_order { "second order; " } else { "" },
    );
    Scene { desc, truth, compact, echoes, spec }
}

/// Largest distance (m) of a surface's ends and middle from the truth.
fn off_truth(truth: &[Obstacle], s: &Surface) -> f64 {
    [s.p0, s.p1, (s.p0 + s.p1) * 0.5].into_iter().map(|q| truth_distance(truth, q)).fold(0.0, f64::max)
}

fn main() {
    let arg = |i: usize, default: u64| std::env::args().nth(i).map_or(default, |a| a.parse().expect("a number"));
    let (n, first) = (arg(1, 300), arg(2, 0));
    let (mut refl, mut walls, mut stray, mut stray_amb) = ((0, 0), (0, 0), 0, 0);
    let started = std::time::Instant::now();
    for seed in first..first + n {
        let sc = scene(seed);
        let map = map_evidence(&sc.echoes, sc.spec, &EvidenceParams::default()).expect("evidence map");
        let found_refl = sc
            .compact
            .iter()
            .filter(|&&(c, rad)| {
                map.surfaces.iter().any(|s| {
                    (s.kind == SurfaceKind::Point || rad > 1.0)
                        && [s.p0, s.p1, (s.p0 + s.p1) * 0.5].iter().all(|q| (q.dist(c) - rad).abs() <= 0.15)
                })
            })
            .count();
        let edges: Vec<(Point, Point)> = sc
            .truth
            .iter()
            .filter_map(|o| if let Shape::Polygon(poly) = &o.shape { Some(poly.edges()) } else { None })
            .flatten()
            .filter(|(a, b)| a.dist(*b) >= 0.5)
            .collect();
        let found_walls = edges
            .iter()
            .filter(|&&(a, b)| {
                map.surfaces.iter().any(|s| {
                    s.kind == SurfaceKind::Line
                        && point_segment_distance(s.p0, a, b) <= 0.1
                        && point_segment_distance(s.p1, a, b) <= 0.1
                })
            })
            .count();
        let off: Vec<&Surface> = map.surfaces.iter().filter(|s| off_truth(&sc.truth, s) > 0.35).collect();
        let (amb, plain) = (off.iter().filter(|s| s.ambiguous).count(), off.iter().filter(|s| !s.ambiguous).count());
        refl = (refl.0 + found_refl, refl.1 + sc.compact.len());
        walls = (walls.0 + found_walls, walls.1 + edges.len());
        stray += plain;
        stray_amb += amb;
        let surfaces: Vec<String> = map
            .surfaces
            .iter()
            .map(|s| match s.kind {
                SurfaceKind::Point => format!("point ({:.3}, {:.3}) {}", s.p0.x, s.p0.y, s.support),
                SurfaceKind::Line => {
                    format!("line ({:.3}, {:.3})–({:.3}, {:.3}) {}", s.p0.x, s.p0.y, s.p1.x, s.p1.y, s.support)
                }
            } + if s.ambiguous { " amb" } else { "" })
            .collect();
        println!(
            "scene {seed}: {} | reflectors {found_refl}/{}, walls {found_walls}/{}, stray {plain} (+{amb} ambiguous) | {}",
            sc.desc,
            sc.compact.len(),
            edges.len(),
            surfaces.join("; ")
        );
    }
    println!(
        "total: {n} scenes, reflectors {}/{}, walls {}/{}, stray {stray} (+{stray_amb} ambiguous)",
        refl.0, refl.1, walls.0, walls.1
    );
    eprintln!("{n} scenes in {:.1} s", started.elapsed().as_secs_f64());
}
