//! The particle simulator on the paper's heaviest single-listener case
//! (issue: simulator, "Speed and memory"): default scene, 3 random obstacles,
//! 1 ms sampling, one thread.
//!
//! `cargo bench -p chirpmap-sim --bench simulate`
//!
//! - `fast`: the path tracer + spectra, peaks and echoes (`chirpmap_sim::simulate`).
//! - `fast_and_map`: the same plus Algorithm 1 on the default 0.1 m grid,
//!   highlights and both scores: everything `chirpmap simulate` computes.
//! - `stepper`: the brute-force time-stepped oracle on the same scene.
//! - `table1_1ms_paper` / `table1_1ms_evidence`: the two mappers on that
//!   run's echoes (1 505 particle echoes, 100 m × 100 m at 0.1 m), each
//!   with its highlights (issue 9: "the evidence mapper within 3× the paper
//!   mapper's time"; `chirpmap benchmark maps` times 100 such runs once each).

use chirpmap_core::scene::Sampling;
use chirpmap_core::{
    AccumulationMapper, EvidenceParams, GridSpec, Mapper, Point, Scene, map_evidence, score_highlight, score_obstacle,
};
use chirpmap_sim::{Resolved, resolve, simulate};

fn main() {
    divan::main();
}

fn scene() -> Resolved {
    let mut s = Scene::default();
    s.listeners[0].sampling = Sampling { period_ms: Some(1.0), random_ms: None };
    resolve(&s).expect("default scene resolves")
}

#[divan::bench(sample_count = 20, sample_size = 1)]
fn fast(bencher: divan::Bencher) {
    let r = scene();
    bencher.bench_local(|| simulate(&r).echoes.len());
}

#[divan::bench(sample_count = 10, sample_size = 1)]
fn fast_and_map(bencher: divan::Bencher) {
    let r = scene();
    bencher.bench_local(|| {
        let out = simulate(&r);
        let spec = GridSpec::from_bounds(r.world, r.scene.mapping.cell, u128::MAX).expect("grid");
        let mut m = AccumulationMapper::new(spec, r.scene.mapping).expect("mapper");
        m.add_echoes(&out.echoes).expect("echoes");
        let h: Vec<Point> = m.highlights().iter().map(|h| h.pos).collect();
        (score_obstacle(&r.obstacles, &h), score_highlight(&r.obstacles, &h))
    });
}

#[divan::bench(sample_count = 2, sample_size = 1)]
fn stepper(bencher: divan::Bencher) {
    let r = scene();
    bencher.bench_local(|| chirpmap_sim::oracle::simulate_stepped(&r).echoes.len());
}

#[divan::bench(sample_count = 20, sample_size = 1)]
fn table1_1ms_paper(bencher: divan::Bencher) {
    let r = scene();
    let echoes = simulate(&r).echoes;
    let spec = GridSpec::from_bounds(r.world, r.scene.mapping.cell, u128::MAX).expect("grid");
    bencher.bench_local(|| {
        let mut m = AccumulationMapper::new(spec, r.scene.mapping).expect("mapper");
        m.add_echoes(&echoes).expect("echoes");
        m.highlights().len()
    });
}

#[divan::bench(sample_count = 20, sample_size = 1)]
fn table1_1ms_evidence(bencher: divan::Bencher) {
    let r = scene();
    let echoes = simulate(&r).echoes;
    let spec = GridSpec::from_bounds(r.world, r.scene.mapping.cell, u128::MAX).expect("grid");
    bencher.bench_local(|| map_evidence(&echoes, spec, &EvidenceParams::default()).expect("map").highlights.len());
}
