//! The fast path tracer against the brute-force stepper (the oracle) on fixed
//! seeds: both must sense the same particles with the same frequencies and
//! loudness, and so produce the same spectra, peaks and echoes.
//!
//! Tolerance: the stepper moves particles by repeated additions of a·dt while
//! the tracer evaluates positions in closed form, so positions differ by a few
//! ULPs (~1e-13 m). A particle can therefore only be sensed by one and not the
//! other if it is within 1e-9 m of the disc's edge; such cases are allowed
//! (and reported), anything else fails. In practice none occur, and the
//! spectra then agree bit for bit because sums run in particle order.
#![allow(clippy::unwrap_used)]

use chirpmap_core::Scene;
use chirpmap_core::scene::{ListenerSpec, ObstacleSpec, Sampling};
use chirpmap_sim::oracle::{sense_stepped, simulate_stepped};
use chirpmap_sim::{Sensed, analyse, resolve, sense_fast};
use proptest::prelude::*;

fn small_scene(seed: u64) -> Scene {
    let mut s = Scene { seed, ..Scene::default() };
    s.world.bounds = [-35.0, -35.0, 35.0, 35.0];
    s.particles.per_tick = 720;
    s.chirp.duration = 0.15;
    s.listeners[0].sampling = Sampling { period_ms: Some(1.0), random_ms: None };
    s
}

fn compare(scene: &Scene) -> usize {
    let r = resolve(scene).unwrap();
    let mut fast = sense_fast(&r);
    let mut slow = sense_stepped(&r);
    let key = |s: &Sensed| (s.measurement, s.particle);
    fast.sort_by_key(key);
    slow.sort_by_key(key);
    let (mut i, mut j, mut edge) = (0, 0, 0);
    while i < fast.len() || j < slow.len() {
        let (a, b) = (fast.get(i), slow.get(j));
        match (a, b) {
            (Some(a), Some(b)) if key(a) == key(b) => {
                assert!((a.freq_hz - b.freq_hz).abs() <= 1e-9 * a.freq_hz, "{a:?} vs {b:?}");
                assert_eq!(a.loudness, b.loudness, "{a:?} vs {b:?}");
                assert!((a.dist_m - b.dist_m).abs() < 1e-6, "{a:?} vs {b:?}");
                i += 1;
                j += 1;
            }
            (Some(a), b) if b.is_none_or(|b| key(a) < key(b)) => {
                let radius = r.listeners.iter().map(|l| l.radius_m).fold(0.0, f64::max);
                assert!((a.dist_m - radius).abs() < 1e-6, "only the tracer sensed {a:?}");
                edge += 1;
                i += 1;
            }
            (_, Some(b)) => {
                let radius = r.listeners.iter().map(|l| l.radius_m).fold(0.0, f64::max);
                assert!((b.dist_m - radius).abs() < 1e-6, "only the stepper sensed {b:?}");
                edge += 1;
                j += 1;
            }
            _ => unreachable!(),
        }
    }
    assert!(edge <= 2, "{edge} edge cases");
    if edge == 0 {
        // Same particles ⇒ identical spectra, peaks and echoes, bit for bit;
        // and `simulate`, which streams the same sensing into bins one
        // emission tick at a time instead of keeping the list, agrees too.
        let from_list = analyse(&r, fast.clone());
        assert_eq!(from_list, analyse(&r, slow));
        assert_eq!(chirpmap_sim::simulate(&r), from_list);
    }
    fast.len()
}

#[test]
fn tracer_matches_stepper_with_random_circles() {
    for seed in [1, 2, 3] {
        let n = compare(&small_scene(seed));
        assert!(n > 1000, "seed {seed}: only {n} sensed");
    }
}

#[test]
fn tracer_matches_stepper_with_polygons_arcs_doppler_and_two_listeners() {
    let mut s = small_scene(11);
    s.particles.doppler = true;
    s.obstacles = vec![
        ObstacleSpec::circle(chirpmap_core::Point::new(6.0, -15.0), 4.0),
        // A concave L-shaped wall, so reflected particles can bounce again.
        ObstacleSpec {
            center: None,
            radius: None,
            vertices: Some(vec![
                [-30.0, -25.0],
                [10.0, -25.0],
                [10.0, -24.0],
                [-29.0, -24.0],
                [-29.0, 5.0],
                [-30.0, 5.0],
            ]),
            roughness: 0.3,
            absorption: 0.1,
        },
        ObstacleSpec {
            roughness: 0.0,
            absorption: 0.5,
            ..ObstacleSpec::circle(chirpmap_core::Point::new(20.0, 5.0), 3.0)
        },
    ];
    s.listeners[0].spin_rate = std::f64::consts::FRAC_PI_4;
    s.listeners.push(ListenerSpec {
        start: [-3.0, 15.0],
        heading_deg: 180.0,
        spin_rate: -1.0,
        radius: 0.8,
        sampling: Sampling { period_ms: None, random_ms: Some([1.0, 5.0]) },
        ..ListenerSpec::default()
    });
    let n = compare(&s);
    assert!(n > 1000, "only {n} sensed");
}

#[test]
fn oracle_echoes_equal_fast_echoes_on_default_geometry() {
    let s = small_scene(5);
    let r = resolve(&s).unwrap();
    let fast = chirpmap_sim::simulate(&r);
    let slow = simulate_stepped(&r);
    assert_eq!(fast.echoes, slow.echoes);
    assert!(!fast.echoes.is_empty());
}

#[test]
fn run_shorter_than_the_chirp_is_simulated_not_a_panic() {
    // duration_s < chirp duration: emission stops with the run.
    let mut s = small_scene(4);
    s.duration_s = Some(0.05);
    let r = resolve(&s).unwrap();
    assert_eq!(r.n_emit_ticks, r.last_tick + 1);
    let n = compare(&s);
    assert!(n > 100, "only {n} sensed");
    let out = chirpmap_sim::simulate(&r);
    assert_eq!(out, simulate_stepped(&r));
    assert!(out.measurements.iter().any(|m| m.direct.is_some()));
}

proptest! {
    // A fixed seed keeps CI deterministic: the same 6 scenes every run (plus
    // the cases saved in oracle.proptest-regressions). To explore, raise
    // `cases` and change the seed locally (200 cases on several seeds passed).
    #![proptest_config(ProptestConfig {
        cases: 6,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6368_6972_706d_6170),
        ..ProptestConfig::default()
    })]

    /// Random listener motion, radius and sampling, random seeds and obstacles.
    #[test]
    fn tracer_matches_stepper_on_random_listeners(
        seed in 0u64..1000,
        x in -20.0..20.0f64,
        y in -5.0..25.0f64,
        heading in 0.0..360.0f64,
        spin in -2.0..2.0f64,
        radius in 0.2..2.0f64,
        period in 1.0..4.0f64,
        rough in 0.0..1.0f64,
        doppler in any::<bool>(),
    ) {
        let s = random_listener_scene(seed, [x, y], heading, spin, radius, period, rough, doppler);
        // Scenes where the generator cannot place obstacles clear of the listener are skipped.
        if resolve(&s).is_ok() {
            compare(&s);
        }
    }
}

/// The scene `tracer_matches_stepper_on_random_listeners` builds.
#[allow(clippy::too_many_arguments)]
fn random_listener_scene(
    seed: u64,
    [x, y]: [f64; 2],
    heading: f64,
    spin: f64,
    radius: f64,
    period: f64,
    rough: f64,
    doppler: bool,
) -> Scene {
    let mut s = small_scene(seed);
    s.chirp.duration = 0.08;
    s.particles.doppler = doppler;
    s.random_obstacles.roughness = rough;
    s.random_obstacles.region = [-25.0, -30.0, 25.0, -8.0];
    s.listeners[0] = ListenerSpec {
        start: [x, y],
        heading_deg: heading,
        spin_rate: spin,
        radius,
        sampling: Sampling { period_ms: Some(period), random_ms: None },
        ..ListenerSpec::default()
    };
    s
}

/// Proptest-found mismatch: particle 29424 leaves obstacle 1 after a rough
/// bounce almost tangentially from a bounce point rounded a hair inside the
/// circle; the tracer took the way out (6e-9 m later, past `T_MIN_M`) for a
/// second hit on the same circle, the stepper did not, so only the stepper
/// sensed it (measurement 221, 0.1 m inside the disc). Exits are no longer hits.
#[test]
fn regression_seed_829_rough_rebounce() {
    let s = random_listener_scene(
        829,
        [-5.673723871870915, 2.4739653479003483],
        224.681387119284,
        0.0,
        0.2,
        1.0,
        0.97287706692307,
        false,
    );
    compare(&s);
}

/// A review's scene (session 19): 100 circles of 0.13–0.27 m, roughness
/// 0.001. After several bounces a particle's direction and the circle's
/// normal are no longer unit (lengths drift in `circle_hit`), and the
/// bounce cull, which took them as unit, stopped 2 particles that the
/// stepper senses. Bounces of non-unit vectors are no longer stopped.
///
/// The drift itself makes the tracer's and the stepper's distances differ by
/// ~1e-6 m here (older than the cull, both simulators have it), beyond
/// [`compare`]'s tolerance, so only which particles are sensed is compared:
/// every particle only one of them senses lies within 1e-5 m of the disc's
/// edge.
#[test]
fn regression_many_small_circles_drifting_directions() {
    let s = Scene::from_toml_str(include_str!("data/many-small-circles.toml")).unwrap();
    let r = resolve(&s).unwrap();
    let radius = r.listeners.iter().map(|l| l.radius_m).fold(0.0, f64::max);
    let key = |s: &Sensed| (s.measurement, s.particle);
    let (fast, slow) = (sense_fast(&r), sense_stepped(&r));
    let keys = |v: &[Sensed]| v.iter().map(key).collect::<std::collections::HashSet<_>>();
    let (fast_keys, slow_keys) = (keys(&fast), keys(&slow));
    for (only, other, who) in [(&fast, &slow_keys, "tracer"), (&slow, &fast_keys, "stepper")] {
        for s in only.iter().filter(|s| !other.contains(&key(s))) {
            assert!((s.dist_m - radius).abs() < 1e-5, "only the {who} sensed {s:?}");
        }
    }
}

/// A pentagram turns the same way at every vertex, so the bounce cull took
/// it for convex and let particles leaving one spike skip the others: 992
/// particles the stepper senses were lost (a review, session 19).
#[test]
fn regression_pentagram_is_not_convex() {
    let s = Scene::from_toml_str(
        r#"
seed = 1
[world]
bounds = [-40.0, -40.0, 40.0, 40.0]
[chirp]
duration = 0.02
[particles]
per_tick = 1800
[[obstacles]]
vertices = [[0.0, -12.0], [5.878, -28.09], [-9.511, -16.91], [9.511, -16.91], [-5.878, -28.09]]
roughness = 0.3
absorption = 0.0
[[listeners]]
start = [-3.0, 10.0]
speed = 10.0
radius = 2.0
[listeners.sampling]
period_ms = 1.0
"#,
    )
    .unwrap();
    compare(&s);
}
