//! The evidence mapper against Algorithm 1 on the same echoes (issue 9:
//! "the evidence mapper within 3× the paper mapper's time").
//!
//! `cargo bench -p chirpmap-core --bench evidence`
//!
//! Both sides do the whole job: Algorithm 1 accumulates every echo and
//! extracts its highlights (threshold + local maxima); the evidence mapper
//! runs `map_evidence` (free space, tangent-line vote, envelope points, final
//! map, highlights). Scenes: the 8 m × 6 m room with a pillar and corner
//! echoes (160 poses, ~1760 echoes, 14 m × 12 m grid at 0.1 m), the loop
//! past three circles (160 poses, 480 echoes, 55 m × 50 m grid at 0.1 m) and
//! the L-shaped corridor of `chirpmap benchmark maps` (471 echoes), all from
//! `chirpmap_core::exact`; and a pillar circled by 12 566 poses 1 mm apart
//! (echoes with 1 cm of noise), whose envelope is one dense pile.

use chirpmap_core::exact::{ExactOptions, ExactScene, Pose, exact_echoes};
use chirpmap_core::{
    AccumulationMapper, Circle, Echo, EvidenceParams, GridSpec, Mapper, MappingParams, Obstacle, Point, Polygon, Shape,
    map_evidence,
};

fn main() {
    divan::main();
}

fn obstacle(shape: Shape) -> Obstacle {
    Obstacle { shape, roughness: 0.0, absorption: 0.0 }
}

fn loop_poses(centre: Point, rx: f64, ry: f64, n: usize) -> Vec<Pose> {
    (0..n)
        .map(|k| {
            let u = k as f64 * std::f64::consts::TAU / n as f64;
            Pose { t_s: k as f64, listener: Point::new(centre.x + rx * u.cos(), centre.y + ry * u.sin()) }
        })
        .collect()
}

fn room() -> (Vec<Echo>, GridSpec) {
    let v = vec![Point::new(0.0, 0.0), Point::new(8.0, 0.0), Point::new(8.0, 6.0), Point::new(0.0, 6.0)];
    let truth = [
        obstacle(Shape::Polygon(Polygon::new(v).expect("room"))),
        obstacle(Shape::Circle(Circle::new(Point::new(5.5, 3.8), 0.3).expect("pillar"))),
    ];
    let opts = ExactOptions { second_order: true, ..ExactOptions::default() };
    let poses = loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, 160);
    let echoes =
        exact_echoes(Point::new(2.0, 2.5), &poses, &ExactScene::from_obstacles(&truth), &opts).expect("echoes");
    (echoes, GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid"))
}

fn circles() -> (Vec<Echo>, GridSpec) {
    let c = |x: f64, y: f64, r: f64| obstacle(Shape::Circle(Circle::new(Point::new(x, y), r).expect("circle")));
    let truth = [c(-10.0, -20.0, 3.0), c(6.0, -26.0, 4.0), c(14.0, -14.0, 2.5)];
    let poses = loop_poses(Point::new(2.0, -12.0), 7.0, 4.0, 160);
    let echoes =
        exact_echoes(Point::new(0.0, 0.0), &poses, &ExactScene::from_obstacles(&truth), &ExactOptions::default())
            .expect("echoes");
    (echoes, GridSpec::from_bounds([-25.0, -40.0, 30.0, 10.0], 0.1, u128::MAX).expect("grid"))
}

/// The L-shaped corridor of `chirpmap benchmark maps`: 2 m wide, source at
/// (1, 1), poses every 0.1 m along (2, 1.2) → (12.9, 1.2) → (12.9, 11)
/// (the second leg is out of the source's sight), 471 echoes, 20 m × 18 m
/// grid at 0.1 m.
fn corridor() -> (Vec<Echo>, GridSpec) {
    let v = [(0.0, 0.0), (14.0, 0.0), (14.0, 12.0), (12.0, 12.0), (12.0, 2.0), (0.0, 2.0)];
    let outer = Polygon::new(v.iter().map(|&(x, y)| Point::new(x, y)).collect()).expect("corridor");
    let legs = [(Point::new(2.0, 1.2), Point::new(12.9, 1.2)), (Point::new(12.9, 1.2), Point::new(12.9, 11.0))];
    let mut at = Vec::new();
    for (a, b) in legs {
        let n = (a.dist(b) / 0.1).round() as usize;
        at.extend((0..n).map(|i| a + (b - a) * (i as f64 / n as f64)));
    }
    let poses: Vec<Pose> = at.into_iter().enumerate().map(|(i, listener)| Pose { t_s: i as f64, listener }).collect();
    let scene = ExactScene::from_obstacles(&[obstacle(Shape::Polygon(outer))]);
    let echoes = exact_echoes(Point::new(1.0, 1.0), &poses, &scene, &ExactOptions::default()).expect("echoes");
    (echoes, GridSpec::from_bounds([-3.0, -3.0, 17.0, 15.0], 0.1, u128::MAX).expect("grid"))
}

/// A 0.3 m pillar circled at 2 m by `n` poses (the walk of the evidence
/// tests' `pillar_circled`), Δd with noise of σ = 1 cm (a sum of three
/// uniforms, at most ±3 cm), `sigma_m` = 1 cm; 14 m × 12 m grid at 0.1 m.
fn dense_pillar(n: usize) -> (Vec<Echo>, GridSpec) {
    let pillar = obstacle(Shape::Circle(Circle::new(Point::new(5.5, 3.8), 0.3).expect("pillar")));
    let poses: Vec<Pose> = (0..n)
        .map(|k| {
            let u = k as f64 * std::f64::consts::TAU / n as f64 - std::f64::consts::FRAC_PI_2;
            Pose { t_s: 0.01 * k as f64, listener: Point::new(4.0 + 2.0 * u.cos(), 3.2 + 2.0 * u.sin()) }
        })
        .collect();
    let scene = ExactScene::from_obstacles(std::slice::from_ref(&pillar));
    let mut echoes = exact_echoes(Point::new(2.0, 2.5), &poses, &scene, &ExactOptions::default()).expect("echoes");
    echoes.retain(|e| e.delta_d_m > 0.3);
    let mut x = 7u64;
    let mut uniform = || {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    for e in &mut echoes {
        e.delta_d_m += 0.02 * (uniform() + uniform() + uniform() - 1.5);
    }
    let echoes = echoes.into_iter().map(|e| e.with_sigma_m(0.01).expect("sigma")).collect();
    (echoes, GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid"))
}

fn paper(echoes: &[Echo], spec: GridSpec) -> usize {
    let mut m = AccumulationMapper::new(spec, MappingParams::default()).expect("mapper");
    for e in echoes {
        m.add_echo(e).expect("echo");
    }
    m.highlights().len()
}

fn evidence(echoes: &[Echo], spec: GridSpec) -> usize {
    map_evidence(echoes, spec, &EvidenceParams::default()).expect("map").surfaces.len()
}

#[divan::bench(sample_count = 10)]
fn room_paper(bencher: divan::Bencher) {
    let (echoes, spec) = room();
    bencher.bench_local(|| paper(&echoes, spec));
}

#[divan::bench(sample_count = 10)]
fn room_evidence(bencher: divan::Bencher) {
    let (echoes, spec) = room();
    bencher.bench_local(|| evidence(&echoes, spec));
}

#[divan::bench(sample_count = 10)]
fn circles_paper(bencher: divan::Bencher) {
    let (echoes, spec) = circles();
    bencher.bench_local(|| paper(&echoes, spec));
}

#[divan::bench(sample_count = 10)]
fn circles_evidence(bencher: divan::Bencher) {
    let (echoes, spec) = circles();
    bencher.bench_local(|| evidence(&echoes, spec));
}

#[divan::bench(sample_count = 10)]
fn corridor_paper(bencher: divan::Bencher) {
    let (echoes, spec) = corridor();
    bencher.bench_local(|| paper(&echoes, spec));
}

#[divan::bench(sample_count = 10)]
fn corridor_evidence(bencher: divan::Bencher) {
    let (echoes, spec) = corridor();
    bencher.bench_local(|| evidence(&echoes, spec));
}

#[divan::bench(sample_count = 5)]
fn dense_pillar_paper(bencher: divan::Bencher) {
    let (echoes, spec) = dense_pillar(12_566);
    bencher.bench_local(|| paper(&echoes, spec));
}

#[divan::bench(sample_count = 5)]
fn dense_pillar_evidence(bencher: divan::Bencher) {
    let (echoes, spec) = dense_pillar(12_566);
    bencher.bench_local(|| evidence(&echoes, spec));
}
