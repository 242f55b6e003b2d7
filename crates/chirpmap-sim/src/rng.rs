//! Explicit randomness (docs/architecture.md): every run draws from
//! `ChaCha8Rng::seed_from_u64(seed)` with `set_stream(run_index)`.
//!
//! The master stream is split into purpose sub-seeds drawn in a fixed order,
//! so the obstacles of run i depend only on (seed, i) and the random-obstacle
//! settings, never on particle counts, sampling or listener settings (paper
//! §III: "run 1 has the same obstacles for configuration 1 as it does for run 1
//! of configuration 2").

use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Sub-seeds of one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunSeeds {
    /// Seeds the placement of random obstacles.
    pub obstacles: u64,
    /// Seeds the per-tick random angular offsets of emission.
    pub emission: u64,
    /// Key of the counter-based generator used at bounces (see [`bounce_uniform`]).
    pub bounce_key: u64,
    /// Seeds the listeners' sampling instants (one stream per listener).
    pub sampling: u64,
}

impl RunSeeds {
    /// Sub-seeds of run `run_index` of `seed`, drawn in a fixed order from the master stream.
    pub fn new(seed: u64, run_index: u64) -> Self {
        let mut master = ChaCha8Rng::seed_from_u64(seed);
        master.set_stream(run_index);
        Self {
            obstacles: master.next_u64(),
            emission: master.next_u64(),
            bounce_key: master.next_u64(),
            sampling: master.next_u64(),
        }
    }
}

/// A ChaCha8 generator seeded with `seed` on stream `stream`.
pub fn stream(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}

/// A uniform number in [0, 1) for bounce `bounce` of particle `particle`.
///
/// Counter-based (a keyed SplitMix64 finaliser chain) rather than drawn from a
/// sequential stream, so the value does not depend on the order in which
/// particles are processed: the path tracer (one particle at a time) and the
/// stepper (one tick at a time) see identical bounces.
pub fn bounce_uniform(key: u64, particle: u64, bounce: u32) -> f64 {
    let mut z = key ^ particle.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = mix(z);
    z ^= u64::from(bounce).wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = mix(z);
    (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeds_depend_on_seed_and_run_only() {
        assert_eq!(RunSeeds::new(1, 0), RunSeeds::new(1, 0));
        assert_ne!(RunSeeds::new(1, 0), RunSeeds::new(1, 1));
        assert_ne!(RunSeeds::new(1, 0), RunSeeds::new(2, 0));
    }

    #[test]
    fn bounce_uniform_is_uniform_enough() {
        let n = 100_000u64;
        let mut hist = [0u32; 10];
        for p in 0..n {
            let u = bounce_uniform(42, p, (p % 3) as u32);
            assert!((0.0..1.0).contains(&u));
            hist[(u * 10.0) as usize] += 1;
        }
        for h in hist {
            assert!((f64::from(h) - 10_000.0).abs() < 500.0, "{hist:?}");
        }
        assert_ne!(bounce_uniform(42, 7, 0), bounce_uniform(42, 7, 1));
    }
}
