//! Fuzz harness (proptest) for scene resolution: scene files built from the
//! schema with hostile values go through parsing, the shared validation and
//! `resolve` (issue 8, "Fuzzing, kept"). Nothing panics, every refusal is an
//! error, and a resolved plan keeps its promises (finite, bounded, at least
//! one measurement per listener).
//!
//! Bounded for CI; `CHIRPMAP_FUZZ_CASES=N` raises the number of cases.
#![allow(clippy::unwrap_used)]

use chirpmap_core::Scene;
use chirpmap_sim::resolve;
use chirpmap_sim::resolve::MAX_MEASUREMENTS;
use proptest::prelude::*;

fn cases(default: u32) -> u32 {
    std::env::var("CHIRPMAP_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn value(plain: std::ops::Range<f64>) -> impl Strategy<Value = String> {
    prop_oneof![
        30 => plain.prop_map(|v| format!("{v:?}")),
        1 => prop_oneof![
            Just("nan"), Just("inf"), Just("-inf"), Just("1e300"), Just("-1e300"), Just("1e-300"), Just("0.0"),
            Just("-1.0"), Just("1e9"),
        ]
        .prop_map(String::from),
    ]
}

fn scene_text() -> impl Strategy<Value = String> {
    (
        value(0.05..1.0),                                         // tick_ms
        prop_oneof![Just(None), value(0.01..2.0).prop_map(Some)], // duration_s
        value(200.0..1500.0),                                     // speed_of_sound
        value(-45.0..45.0),                                       // listener x
        value(-45.0..45.0),                                       // listener y
        value(0.0..10.0),                                         // speed
        value(-7.0..7.0),                                         // spin
        value(0.2..2.0),                                          // radius
        value(0.5..50.0),                                         // period_ms
        (0u32..6, value(0.05..20.0)),                             // random count, cell
        value(-40.0..30.0),                                       // region corner
        any::<bool>(),                                            // explicit obstacle
    )
        .prop_map(|(tick, dur, a, lx, ly, speed, spin, radius, period, (count, cell), corner, explicit)| {
            let mut t = String::new();
            if let Some(d) = dur {
                t.push_str(&format!("duration_s = {d}\n"));
            }
            t.push_str(&format!("[world]\nspeed_of_sound = {a}\n"));
            t.push_str("[chirp]\nduration = 0.05\n");
            t.push_str(&format!("[particles]\nper_tick = 90\ntick_ms = {tick}\n"));
            t.push_str(&format!("[mapping]\ncell = {cell}\n"));
            t.push_str(&format!(
                "[random_obstacles]\ncount = {count}\ndiameter = [1.0, 3.0]\nregion = [{corner}, -40.0, 40.0, -20.0]\n"
            ));
            if explicit {
                t.push_str("[[obstacles]]\ncenter = [20.0, 20.0]\nradius = 2.0\n");
            }
            t.push_str(&format!(
                "[[listeners]]\nstart = [{lx}, {ly}]\nspeed = {speed}\nspin_rate = {spin}\nradius = {radius}\n\
                 sampling = {{ period_ms = {period} }}\n"
            ));
            t
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(128)))]

    #[test]
    fn fuzz_resolve_hostile_scenes(text in scene_text()) {
        let Ok(scene) = Scene::from_toml_str(&text) else { return Ok(()) };
        match resolve(&scene) {
            Err(e) => prop_assert!(!e.to_string().is_empty()),
            Ok(r) => {
                scene.validate().unwrap();
                prop_assert!(r.tick_s.is_finite() && r.tick_s > 0.0 && r.step_m.is_finite());
                prop_assert!(r.measurement_count() >= 1 && r.measurement_count() <= MAX_MEASUREMENTS);
                for l in &r.listeners {
                    prop_assert!(!l.ticks.is_empty());
                    prop_assert!(l.positions.iter().all(|p| p.is_finite()));
                }
                prop_assert!(r.step_m <= 2.0 * r.listeners.iter().map(|l| l.radius_m).fold(f64::INFINITY, f64::min) + 1e-12);
                // The resolved scene replays to the same plan.
                let again = resolve(&r.scene).unwrap();
                prop_assert_eq!(again.obstacles, r.obstacles);
            }
        }
    }
}
