//! The Rust side of the Python binding's mapping benchmark
//! (`crates/chirpmap-py/bench/bench_map.py` runs it; BENCHMARKS.md): loads
//! echoes from a file of little-endian f64 rows `source_x, source_y,
//! listener_x, listener_y, delta_d, weight, t, listener`, then times
//! `chirpmap::map_echoes` (default options: Algorithm 1, 0.1 m cells,
//! bounds covering every ellipse) `reps` times and prints each wall time
//! in seconds, one a line, and the checksum of the last map.
//!
//! `cargo run --release -p chirpmap --example map_bench -- ECHOES.f64 [REPS]`

use chirpmap::{Echo, MapOptions, Point};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args.next().ok_or("usage: map_bench ECHOES.f64 [REPS]")?;
    let reps: usize = args.next().map_or(Ok(1), |s| s.parse())?;
    let bytes = std::fs::read(&path)?;
    if bytes.len() % 64 != 0 {
        return Err(format!("{path}: {} bytes are not rows of 8 f64", bytes.len()).into());
    }
    let values: Vec<f64> =
        bytes.chunks_exact(8).map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])).collect();
    let echoes: Vec<Echo> = values
        .chunks_exact(8)
        .map(|r| Echo::new(Point::new(r[0], r[1]), Point::new(r[2], r[3]), r[4], r[5], r[6], r[7] as u32))
        .collect::<Result<_, _>>()?;
    let opts = MapOptions::default();
    let mut checksum = 0.0;
    for _ in 0..reps {
        let started = Instant::now();
        let map = chirpmap::map_echoes(&echoes, &[], &opts)?;
        let elapsed_s = started.elapsed().as_secs_f64();
        checksum = map.grid.data.iter().sum::<f64>() + map.highlights.len() as f64;
        println!("{elapsed_s}");
    }
    println!("checksum {checksum}");
    Ok(())
}
