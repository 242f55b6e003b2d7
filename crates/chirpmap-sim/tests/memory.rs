//! Memory stays bounded for a large listener disc: `simulate` streams sensed
//! particles into per-measurement frequency bins, one emission tick at a
//! time, instead of keeping every sensed particle.
//!
//! Alone in its own test binary, so the process's peak resident set
//! (`VmHWM`, Linux) is this test's.
#![allow(clippy::unwrap_used)]

use chirpmap_core::Scene;
use chirpmap_core::scene::Sampling;
use chirpmap_sim::{resolve, simulate};

fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

#[test]
fn large_listener_disc_does_not_keep_every_sensed_particle() {
    // A 4 m disc sampled every 1 ms senses ~6·10⁶ particles over the run
    // (~250 MB as a list of sensed particles); as bins it is a few MB.
    let mut s = Scene::default();
    s.listeners[0].radius = 4.0;
    s.listeners[0].sampling = Sampling { period_ms: Some(1.0), random_ms: None };
    let r = resolve(&s).unwrap();
    let out = simulate(&r);
    let sensed: u64 = out.measurements.iter().map(|m| u64::from(m.n_sensed)).sum();
    assert!(sensed > 3_000_000, "{sensed} sensed");
    if let Some(peak) = peak_rss_mib() {
        assert!(peak < 100.0, "peak resident set {peak:.0} MiB for {sensed} sensed particles");
    }
}
