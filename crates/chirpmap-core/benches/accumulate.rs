//! Rasterising ellipses is the mapper's hot loop (issue: foundation, "Speed").
//!
//! `cargo bench -p chirpmap-core --bench accumulate`
//!
//! - `fast_100k`: 100 000 realistic echoes (foci 10–30 m apart, Δd 1–40 m)
//!   accumulated on the default 100 m × 100 m, 0.1 m grid; the counter reports
//!   cell updates per second.
//! - `literal_per_ellipse` vs `fast_per_ellipse`: the literal reading of
//!   Algorithm 1 (test every grid cell against the ellipse) against the
//!   rasteriser on the same ellipses, for the speed-up ratio.

use chirpmap_core::raster::{entered_cells_literal, for_each_entered_span};
use chirpmap_core::{AccumulationMapper, Echo, GridSpec, Mapper, MappingParams, Point};
use divan::counter::ItemsCount;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn main() {
    divan::main();
}

fn spec() -> GridSpec {
    GridSpec::from_bounds([-50.0, -50.0, 50.0, 50.0], 0.1, u128::MAX).expect("valid grid")
}

fn echoes(n: usize) -> Vec<Echo> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    (0..n)
        .map(|_| {
            let mid = Point::new(rng.random_range(-25.0..25.0), rng.random_range(-25.0..25.0));
            let half = rng.random_range(10.0..30.0) / 2.0;
            let dir = Point::from_angle(rng.random_range(0.0..std::f64::consts::TAU));
            let dd = rng.random_range(1.0..40.0);
            Echo::new(mid - dir * half, mid + dir * half, dd, 1.0, 0.0, 0).expect("valid echo")
        })
        .collect()
}

fn cells_of(echoes: &[Echo]) -> u64 {
    let s = spec();
    let mut n = 0u64;
    for e in echoes {
        for_each_entered_span(&e.ellipse().expect("valid"), &s, |_, lo, hi| n += (hi - lo + 1) as u64);
    }
    n
}

#[divan::bench(sample_count = 5, sample_size = 1)]
fn fast_100k(bencher: divan::Bencher) {
    let es = echoes(100_000);
    let cells = cells_of(&es);
    bencher
        .counter(ItemsCount::new(cells))
        .with_inputs(|| AccumulationMapper::new(spec(), MappingParams::default()))
        .bench_local_values(|mapper| {
            let mut m = mapper.expect("valid mapper");
            for e in &es {
                m.add_echo(e).expect("valid echo");
            }
            m.cells_updated()
        });
}

/// The bare loop (rasterise + add into a plain Vec) without the mapper, to
/// see what the mapper's bookkeeping costs.
#[divan::bench(sample_count = 5, sample_size = 1)]
fn fast_100k_bare_loop(bencher: divan::Bencher) {
    let es = echoes(100_000);
    let cells = cells_of(&es);
    let s = spec();
    bencher.counter(ItemsCount::new(cells)).with_inputs(|| vec![0.0f64; s.len()]).bench_local_values(|mut grid| {
        for e in &es {
            let w = e.weight;
            for_each_entered_span(&e.ellipse().expect("valid"), &s, |j, lo, hi| {
                for v in &mut grid[j * s.nx + lo..=j * s.nx + hi] {
                    *v += w;
                }
            });
        }
        grid
    });
}

#[divan::bench(sample_count = 20)]
fn fast_per_ellipse(bencher: divan::Bencher) {
    let es = echoes(16);
    let s = spec();
    bencher.counter(ItemsCount::new(es.len())).bench_local(|| {
        let mut n = 0usize;
        for e in &es {
            for_each_entered_span(&e.ellipse().expect("valid"), &s, |_, lo, hi| n += hi - lo + 1);
        }
        n
    });
}

#[divan::bench(sample_count = 3, sample_size = 1)]
fn literal_per_ellipse(bencher: divan::Bencher) {
    let es = echoes(16);
    let s = spec();
    bencher.counter(ItemsCount::new(es.len())).bench_local(|| {
        let mut n = 0usize;
        for e in &es {
            entered_cells_literal(&e.ellipse().expect("valid"), &s, |_, _| n += 1);
        }
        n
    });
}
