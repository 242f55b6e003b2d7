//! Times the paper's high-pass on 10 minutes of 48 kHz noise plus a DC
//! offset (28.8 M samples): the segmented filter (`Sos::filter_in_place`)
//! against the plain recursion (`Sos::filter_sequential_in_place`), and
//! counts the samples where the two differ.
//! `cargo run --release -p chirpmap-audio --example highpass_speed`

use chirpmap_audio::filter::paper_highpass;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n = 600 * 48_000;
    let mut r = 0x9e37_79b9_7f4a_7c15u64;
    let x: Vec<f32> = (0..n)
        .map(|i| {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            0.2 + 0.3 * ((r >> 40) as f32 / 16_777_216.0 - 0.5) + 0.1 * (i as f32 * 0.01).sin()
        })
        .collect();
    let sos = paper_highpass(48_000.0)?;
    let (mut best_seq, mut best_seg) = (f64::INFINITY, f64::INFINITY);
    let (mut a, mut b) = (x.clone(), x.clone());
    for _ in 0..3 {
        a.copy_from_slice(&x);
        let t = Instant::now();
        sos.filter_sequential_in_place(&mut a);
        best_seq = best_seq.min(t.elapsed().as_secs_f64());
        b.copy_from_slice(&x);
        let t = Instant::now();
        sos.filter_in_place(&mut b);
        best_seg = best_seg.min(t.elapsed().as_secs_f64());
    }
    let differ = a.iter().zip(&b).filter(|(p, q)| p.to_bits() != q.to_bits()).count();
    let max_diff = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
    println!(
        "{n} samples: sequential {best_seq:.3} s, segmented {best_seg:.3} s ({:.1}x); {differ} samples differ, max |diff| {max_diff:e}",
        best_seq / best_seg
    );
    Ok(())
}
