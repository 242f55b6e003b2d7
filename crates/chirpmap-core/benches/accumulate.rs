//! Rasterising ellipses is the mapper's hot loop (issue: foundation, "Speed";
//! issue 14: "the mapper near the machine's limit").
//!
//! `cargo bench -p chirpmap-core --bench accumulate`
//!
//! - `fast_100k`: 100 000 realistic echoes (foci 10–30 m apart, Δd 1–40 m)
//!   accumulated by the mapper on the default 100 m × 100 m, 0.1 m grid; the
//!   counter reports cell updates per second.
//! - `reference_100k`: the same echoes with the previous rasteriser
//!   (`for_each_entered_span_reference`) and a plain add per cell: the
//!   speed-up of issue 14 measured in the same run.
//! - `raster_only_100k`, `raster_only_reference_100k`: the rasterisers alone
//!   (cells counted, nothing written): the arithmetic's share.
//! - Peers, the machine's limits measured in the same run (issue 14, item 1):
//!   `peer_random_increments` adds 1 at as many pseudo-random cells of a grid
//!   of the same size (8 MB of f64) as `fast_100k` updates;
//!   `peer_span_replay` replays the exact span sequence of the first 10 000
//!   echoes (recorded beforehand), additions only.
//! - `CHIRPMAP_INTERLEAVED=5 cargo bench -p chirpmap-core --bench accumulate`
//!   runs the mapper, the rasteriser alone, the previous loop and the two
//!   peers in 5 interleaved rounds instead and prints each one's rate and
//!   its ratio to the random increments: on the shared machine only ratios
//!   measured this way are stable.
//! - `literal_per_ellipse` vs `fast_per_ellipse`: the literal reading of
//!   Algorithm 1 (test every grid cell against the ellipse) against the
//!   rasteriser on the same ellipses, for the speed-up ratio.

use chirpmap_core::mapper::add_ellipse;
use chirpmap_core::raster::{entered_cells_literal, for_each_entered_span, for_each_entered_span_reference};
use chirpmap_core::{AccumulationMapper, Echo, GridSpec, Mapper, MappingParams, Point};
use divan::counter::ItemsCount;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn main() {
    if let Some(rounds) = std::env::var("CHIRPMAP_INTERLEAVED").ok().and_then(|v| v.parse().ok()) {
        interleaved(rounds);
        return;
    }
    divan::main();
}

/// This thread's CPU time (s) from Linux's /proc/thread-self/schedstat
/// (first field: ns on the CPU), so that time slices lost to other processes
/// on the shared machine do not count; `None` elsewhere.
fn thread_cpu_s() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(text.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
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

/// Interleaved rounds of the mapper's loop and its peers, so that every
/// ratio compares passes made under the same load; each pass is timed by the
/// thread's CPU time where Linux gives it (time slices lost to other
/// processes on the shared machine do not count), else by the wall clock.
fn interleaved(rounds: usize) {
    let s = spec();
    let echoes = echoes(100_000);
    let es: Vec<_> = echoes.iter().map(|e| e.ellipse().expect("valid")).collect();
    let cells = cells_of(&echoes);
    let len = s.len() as u64;
    let mut spans: Vec<(u32, u32)> = Vec::new();
    for e in &es[..10_000] {
        for_each_entered_span(e, &s, |j, lo, hi| spans.push(((j * s.nx + lo) as u32, (hi - lo + 1) as u32)));
    }
    let replay_cells: u64 = spans.iter().map(|&(_, n)| u64::from(n)).sum();
    // One grid for the plain passes, its pages faulted in before timing
    // (values keep growing, which changes no timing).
    let mut g = vec![0.0f64; s.len()];
    for v in &mut g {
        *v = std::hint::black_box(0.0);
    }
    let mut mapper = AccumulationMapper::new(s, MappingParams::default()).expect("valid mapper");
    // The mapper spreads its work over rayon's threads; here over one, this
    // thread, so that its CPU time is the whole pass's (the peers are serial).
    let one_thread =
        rayon::ThreadPoolBuilder::new().num_threads(1).use_current_thread().build().expect("a thread pool");
    type Pass<'a> = Box<dyn FnMut(&mut Vec<f64>) -> u64 + 'a>;
    let mut passes: Vec<(&str, Pass)> = vec![
        (
            "mapper add_echoes (banded)",
            Box::new(|_| {
                one_thread.install(|| mapper.add_echoes(&echoes)).expect("valid echoes");
                cells
            }),
        ),
        ("add_ellipse per echo", Box::new(|g| es.iter().map(|e| add_ellipse(e, &s, g, 1.0)).sum())),
        (
            "raster only",
            Box::new(|_| {
                let mut n = 0usize;
                for e in &es {
                    for_each_entered_span(e, &s, |_, lo, hi| n += hi - lo + 1);
                }
                n as u64
            }),
        ),
        (
            "previous mapper loop",
            Box::new(|g| {
                // The previous rasteriser, a plain add per cell, and the
                // load of the same column 6 rows ahead that it made.
                let mut touch = 0.0f64;
                for e in &es {
                    for_each_entered_span_reference(e, &s, |j, lo, hi| {
                        if let Some(v) = g.get((j + 6) * s.nx + lo) {
                            touch += *v;
                        }
                        for v in &mut g[j * s.nx + lo..=j * s.nx + hi] {
                            *v += 1.0;
                        }
                    });
                }
                std::hint::black_box(touch);
                cells
            }),
        ),
        (
            "previous, without the touch",
            Box::new(|g| {
                for e in &es {
                    for_each_entered_span_reference(e, &s, |j, lo, hi| {
                        for v in &mut g[j * s.nx + lo..=j * s.nx + hi] {
                            *v += 1.0;
                        }
                    });
                }
                cells
            }),
        ),
        (
            "peer: random increments",
            Box::new(|g| {
                let mut x = 0x9e37_79b9_7f4a_7c15u64;
                for _ in 0..cells {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    g[((u128::from(x) * u128::from(len)) >> 64) as usize] += 1.0;
                }
                cells
            }),
        ),
        (
            "peer: span replay",
            Box::new(|g| {
                for &(start, n) in &spans {
                    for v in &mut g[start as usize..(start + n) as usize] {
                        *v += 1.0;
                    }
                }
                replay_cells
            }),
        ),
    ];
    let mut t: Vec<Vec<f64>> = vec![Vec::new(); passes.len()];
    let mut n: Vec<u64> = vec![0; passes.len()];
    for _ in 0..rounds {
        for (k, (_, pass)) in passes.iter_mut().enumerate() {
            let (started, cpu) = (std::time::Instant::now(), thread_cpu_s());
            n[k] = std::hint::black_box(pass(&mut g));
            let wall = started.elapsed().as_secs_f64();
            t[k].push(match (cpu, thread_cpu_s()) {
                (Some(a), Some(b)) => b - a,
                _ => wall,
            });
        }
    }
    let rates: Vec<f64> = t.iter_mut().zip(&n).map(|(v, &c)| c as f64 / median(v) / 1e6).collect();
    let peer = rates[passes.iter().position(|(name, _)| name.starts_with("peer: random")).expect("peer")];
    let clock = if thread_cpu_s().is_some() { "thread CPU time" } else { "wall time" };
    println!("{rounds} interleaved rounds, medians of {clock}; {cells} cell updates per pass");
    for ((name, _), r) in passes.iter().zip(&rates) {
        println!("{name:30} {r:8.1} M cell updates/s  ({:.2} of random increments)", r / peer);
    }
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
            m.add_echoes(&es).expect("valid echoes");
            m.cells_updated()
        });
}

/// The bare loop (rasterise + [`add_ellipse`] into a plain Vec) without the
/// mapper's checks, to see what the mapper's bookkeeping costs.
#[divan::bench(sample_count = 5, sample_size = 1)]
fn fast_100k_bare_loop(bencher: divan::Bencher) {
    let es: Vec<_> = echoes(100_000).iter().map(|e| e.ellipse().expect("valid")).collect();
    let cells = cells_of(&echoes(100_000));
    let s = spec();
    bencher.counter(ItemsCount::new(cells)).with_inputs(|| vec![0.0f64; s.len()]).bench_local_values(|mut grid| {
        let mut n = 0;
        for e in &es {
            n += add_ellipse(e, &s, &mut grid, 1.0);
        }
        (grid, n)
    });
}

/// The previous rasteriser with a plain add per cell (what the mapper did
/// before issue 14, minus the prefetch touch).
#[divan::bench(sample_count = 5, sample_size = 1)]
fn reference_100k(bencher: divan::Bencher) {
    let es: Vec<_> = echoes(100_000).iter().map(|e| e.ellipse().expect("valid")).collect();
    let cells = cells_of(&echoes(100_000));
    let s = spec();
    bencher.counter(ItemsCount::new(cells)).with_inputs(|| vec![0.0f64; s.len()]).bench_local_values(|mut grid| {
        for e in &es {
            for_each_entered_span_reference(e, &s, |j, lo, hi| {
                for v in &mut grid[j * s.nx + lo..=j * s.nx + hi] {
                    *v += 1.0;
                }
            });
        }
        grid
    });
}

#[divan::bench(sample_count = 5, sample_size = 1)]
fn raster_only_100k(bencher: divan::Bencher) {
    let es: Vec<_> = echoes(100_000).iter().map(|e| e.ellipse().expect("valid")).collect();
    let cells = cells_of(&echoes(100_000));
    let s = spec();
    bencher.counter(ItemsCount::new(cells)).bench_local(|| {
        let mut n = 0usize;
        for e in &es {
            for_each_entered_span(e, &s, |_, lo, hi| n += hi - lo + 1);
        }
        n
    });
}

#[divan::bench(sample_count = 5, sample_size = 1)]
fn raster_only_reference_100k(bencher: divan::Bencher) {
    let es: Vec<_> = echoes(100_000).iter().map(|e| e.ellipse().expect("valid")).collect();
    let cells = cells_of(&echoes(100_000));
    let s = spec();
    bencher.counter(ItemsCount::new(cells)).bench_local(|| {
        let mut n = 0usize;
        for e in &es {
            for_each_entered_span_reference(e, &s, |_, lo, hi| n += hi - lo + 1);
        }
        n
    });
}

/// Peer: the machine's rate of adding 1 to pseudo-random cells of an 8 MB
/// f64 grid (xorshift64, Marsaglia 2003; index by multiply-high), as many
/// increments as `fast_100k` makes.
#[divan::bench(sample_count = 5, sample_size = 1)]
fn peer_random_increments(bencher: divan::Bencher) {
    let cells = cells_of(&echoes(100_000));
    let len = spec().len() as u64;
    bencher.counter(ItemsCount::new(cells)).with_inputs(|| vec![0.0f64; len as usize]).bench_local_values(
        |mut grid| {
            let mut x = 0x9e37_79b9_7f4a_7c15u64;
            for _ in 0..cells {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let i = ((u128::from(x) * u128::from(len)) >> 64) as usize;
                grid[i] += 1.0;
            }
            grid
        },
    );
}

/// Peer: the exact span sequence of the first 10 000 echoes (start index,
/// length), recorded once, replayed as additions only: memory traffic with no
/// rasterising.
#[divan::bench(sample_count = 5, sample_size = 1)]
fn peer_span_replay(bencher: divan::Bencher) {
    let s = spec();
    let es = echoes(10_000);
    let mut spans: Vec<(u32, u32)> = Vec::new();
    for e in &es {
        for_each_entered_span(&e.ellipse().expect("valid"), &s, |j, lo, hi| {
            spans.push(((j * s.nx + lo) as u32, (hi - lo + 1) as u32));
        });
    }
    let cells: u64 = spans.iter().map(|&(_, n)| u64::from(n)).sum();
    bencher.counter(ItemsCount::new(cells)).with_inputs(|| vec![0.0f64; s.len()]).bench_local_values(|mut grid| {
        for &(start, n) in &spans {
            for v in &mut grid[start as usize..(start + n) as usize] {
                *v += 1.0;
            }
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
