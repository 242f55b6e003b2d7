//! Scenes the reviewer found could crash, hang, exhaust memory or silently
//! replay the wrong run: each must be a clear error naming the field.
#![allow(clippy::unwrap_used)]

use chirpmap_core::Scene;
use chirpmap_core::scene::{ListenerSpec, ObstacleSpec, Sampling};
use chirpmap_sim::resolve;

fn err_of(s: &Scene) -> String {
    resolve(s).unwrap_err().to_string()
}

#[test]
fn seed_and_run_index_above_i64_max_are_rejected() {
    // TOML integers are i64: a larger seed would make scene.toml unserialisable.
    let big = i64::MAX as u64 + 1;
    let s = Scene { seed: big, ..Scene::default() };
    let e = err_of(&s);
    assert!(e.contains("seed"), "{e}");
    let s = Scene { run_index: u64::MAX, ..Scene::default() };
    assert!(err_of(&s).contains("run_index"));
    // The largest allowed seed round-trips through scene.toml.
    let s = Scene { seed: i64::MAX as u64, ..Scene::default() };
    let r = resolve(&s).unwrap();
    let back = Scene::from_toml_str(&r.scene.to_toml_string()).unwrap();
    assert_eq!(back.seed, i64::MAX as u64);
}

#[test]
fn spin_rate_is_bounded() {
    for spin in [1e300, -1e300, 1e5, 7.0] {
        let mut s = Scene::default();
        s.listeners[0].spin_rate = spin;
        let e = err_of(&s);
        assert!(e.contains("listeners[0].spin_rate"), "{spin}: {e}");
    }
    // The paper's π/4 and one full turn per second are fine.
    for spin in [std::f64::consts::FRAC_PI_4, -std::f64::consts::TAU] {
        let mut s = Scene::default();
        s.listeners[0].spin_rate = spin;
        s.listeners[0].speed = 1.0;
        resolve(&s).unwrap();
    }
    // A slow spin over a very long run is as many capsules as a fast one.
    let mut s = Scene { duration_s: Some(5000.0), ..Scene::default() };
    s.listeners[0].spin_rate = 0.1;
    s.listeners[0].speed = 0.01;
    s.listeners[0].sampling = Sampling { period_ms: Some(1000.0), random_ms: None };
    let e = err_of(&s);
    assert!(e.contains("listeners[0].spin_rate") && e.contains("turn"), "{e}");
}

#[test]
fn per_tick_is_capped_on_its_own() {
    // One emission tick of 2·10⁹ particles passes a total-particle cap but
    // would allocate a 32 GB direction table.
    let mut s = Scene::default();
    s.chirp.duration = 0.0005;
    s.particles.per_tick = 2_000_000_000;
    let e = err_of(&s);
    assert!(e.contains("particles.per_tick"), "{e}");
}

#[test]
fn measurements_are_capped_across_listeners() {
    // 2000 listeners × 6000 measurements = 1.2·10⁷: each is under a
    // per-listener cap of 10⁷ but the total overflows the budget.
    let mut s = Scene { duration_s: Some(6.0), ..Scene::default() };
    s.listeners = (0..2000)
        .map(|i| ListenerSpec {
            start: [-40.0 + 0.01 * f64::from(i), 40.0],
            speed: 0.1,
            sampling: Sampling { period_ms: Some(1.0), random_ms: None },
            ..ListenerSpec::default()
        })
        .collect();
    let e = err_of(&s);
    assert!(e.contains("measurements") && e.contains("all listeners"), "{e}");
}

#[test]
fn listener_radius_is_bounded() {
    let mut s = Scene::default();
    s.listeners[0].radius = 15.0;
    let e = err_of(&s);
    assert!(e.contains("listeners[0].radius"), "{e}");
    s.listeners[0].radius = 10.0;
    resolve(&s).unwrap();
}

#[test]
fn explicit_obstacle_on_the_listener_path_is_rejected() {
    // Default listener: from (−3, 10) heading +x at 10 m/s for 0.706 s, to x ≈ 4.1.
    let mut s =
        Scene { obstacles: vec![ObstacleSpec::circle(chirpmap_core::Point::new(3.0, 10.0), 1.0)], ..Scene::default() };
    let e = err_of(&s);
    assert!(e.contains("obstacles[0]") && e.contains("path of listeners[0]"), "{e}");
    // A polygon whose edge the disc (radius 0.5) grazes is on the path too.
    s.obstacles[0] = ObstacleSpec {
        center: None,
        radius: None,
        vertices: Some(vec![[0.0, 10.3], [1.0, 10.3], [1.0, 12.0], [0.0, 12.0]]),
        roughness: 0.1,
        absorption: 0.2,
    };
    let e = err_of(&s);
    assert!(e.contains("obstacles[0]") && e.contains("path of listeners[0]"), "{e}");
    // Clear of the disc's sweep: fine.
    s.obstacles[0] = ObstacleSpec::circle(chirpmap_core::Point::new(3.0, 13.0), 2.0);
    resolve(&s).unwrap();
}

#[test]
fn listener_leaving_the_world_is_rejected_with_the_time() {
    // 100 m/s from x = −3 reaches x = 50 at t = 0.53 s, within the 0.706 s run.
    let mut s = Scene::default();
    s.listeners[0].speed = 100.0;
    let e = err_of(&s);
    assert!(e.contains("listeners[0]") && e.contains("leaves world.bounds") && e.contains("t = 0.53"), "{e}");
    // An arc that stays inside is fine.
    s.listeners[0].speed = 10.0;
    s.listeners[0].spin_rate = std::f64::consts::FRAC_PI_4;
    resolve(&s).unwrap();
}

/// Issue 8, item 12: runs that cannot measure anything are refused before any
/// work, by the same `Scene::validate` that every command calls.
#[test]
fn runs_that_cannot_measure_anything_are_refused() {
    let cases = [
        ("[particles]\ntick_ms = 1000.0\n", "particles.tick_ms"),
        ("duration_s = 1e-9\n", "duration_s"),
        ("[world]\nspeed_of_sound = 1e6\n", "world.speed_of_sound"),
        ("[random_obstacles]\nregion = [100.0, 100.0, 200.0, 200.0]\n", "random_obstacles.region"),
        ("[mapping]\ncell = 1e9\n", "mapping.cell"),
        ("[random_obstacles]\ncount = 0\n", "random_obstacles.count"),
        ("[source]\nposition = [1.0, 2.0, 3.0]\n", "expected an array of 2 numbers, got 3"),
        ("[random_obstacles]\nroughness = nan\n[[obstacles]]\ncenter = [10.0, -20.0]\nradius = 2.0\n", "roughness"),
    ];
    for (toml, want) in cases {
        let err = match Scene::from_toml_str(toml) {
            Err(e) => e.to_string(),
            Ok(s) => {
                let shared = s.validate().unwrap_err().to_string();
                let e = err_of(&s);
                assert_eq!(e, shared, "resolve and Scene::validate disagree on {toml:?}");
                e
            }
        };
        assert!(err.contains(want), "{toml:?}: {err}");
    }
}

/// A listener whose first measurement falls after the end of the run.
#[test]
fn a_listener_without_measurements_is_refused() {
    let mut s = Scene { duration_s: Some(0.05), ..Scene::default() };
    s.listeners[0].sampling = Sampling { period_ms: Some(100.0), random_ms: None };
    let e = err_of(&s);
    assert!(e.contains("listeners[0] makes no measurement"), "{e}");
}
