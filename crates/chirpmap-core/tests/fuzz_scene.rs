//! Fuzz harness (proptest) for the scene TOML parser and the shared scene
//! validation (issue 8, "Fuzzing, kept"): no input makes them panic, and a
//! scene they accept satisfies the documented bounds.
//!
//! Bounded for CI; `CHIRPMAP_FUZZ_CASES=N` raises the number of cases per
//! property (see RELIABILITY.md for the long runs).
#![allow(clippy::unwrap_used)]

use chirpmap_core::Scene;
use chirpmap_core::geometry::MAX_COORD_M;
use proptest::prelude::*;

fn cases(default: u32) -> u32 {
    std::env::var("CHIRPMAP_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Numbers a hostile or careless user writes.
fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        (-100.0f64..100.0).prop_map(|v| format!("{v:?}")),
        (0u32..5000).prop_map(|v| v.to_string()),
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("1e300".to_string()),
        Just("-1e300".to_string()),
        Just("1e-300".to_string()),
        Just("0.0".to_string()),
        Just("-0.0".to_string()),
        Just("4294967295".to_string()),
        Just("18446744073709551615".to_string()),
        Just("\"x\"".to_string()),
        Just("[1.0, 2.0, 3.0]".to_string()),
    ]
}

fn array(n: std::ops::Range<usize>) -> impl Strategy<Value = String> {
    proptest::collection::vec(number(), n).prop_map(|v| format!("[{}]", v.join(", ")))
}

const KEYS: [(&str, &str, usize); 24] = [
    ("", "seed", 0),
    ("", "run_index", 0),
    ("", "duration_s", 0),
    ("world", "speed_of_sound", 0),
    ("world", "bounds", 4),
    ("chirp", "f_start", 0),
    ("chirp", "f_end", 0),
    ("chirp", "duration", 0),
    ("source", "position", 2),
    ("particles", "per_tick", 0),
    ("particles", "tick_ms", 0),
    ("particles", "min_loudness", 0),
    ("random_obstacles", "count", 0),
    ("random_obstacles", "diameter", 2),
    ("random_obstacles", "region", 4),
    ("random_obstacles", "roughness", 0),
    ("mapping", "cell", 0),
    ("mapping", "keep_top", 0),
    ("mapping", "ellipse_points", 0),
    ("mapping", "peak_radius", 0),
    ("[listeners]", "start", 2),
    ("[listeners]", "speed", 0),
    ("[listeners]", "spin_rate", 0),
    ("[obstacles]", "center", 2),
];

/// A scene file from the schema's keys with hostile values.
fn scene_text() -> impl Strategy<Value = String> {
    proptest::collection::vec((0..KEYS.len(), number(), array(0..6)), 0..8).prop_map(|picks| {
        let mut top = String::new();
        let mut tables: std::collections::BTreeMap<&str, String> = Default::default();
        for (k, num, arr) in picks {
            let (table, key, arity) = KEYS[k];
            let value = if arity > 0 { arr } else { num };
            let line = format!("{key} = {value}\n");
            if table.is_empty() { top.push_str(&line) } else { tables.entry(table).or_default().push_str(&line) }
        }
        for (t, body) in tables {
            let extra = if t == "[obstacles]" { "radius = 2.0\n" } else { "" };
            top.push_str(&format!("[{t}]\n{body}{extra}"));
        }
        top
    })
}

fn check(text: &str) {
    if let Ok(scene) = Scene::from_toml_str(text)
        && scene.validate().is_ok()
    {
        let w = scene.world.bounds;
        assert!(w.iter().all(|v| v.is_finite() && v.abs() <= MAX_COORD_M), "{text}");
        assert!(scene.world.speed_of_sound.is_finite() && scene.world.speed_of_sound > 0.0, "{text}");
        assert!(scene.random_obstacles.count >= 1, "{text}");
        for l in &scene.listeners {
            assert!(l.speed.is_finite() && l.spin_rate.is_finite() && l.radius > 0.0, "{text}");
        }
        // A valid scene survives its own round trip.
        let back = Scene::from_toml_str(&scene.to_toml_string()).unwrap();
        back.validate().unwrap();
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(256)))]

    #[test]
    fn fuzz_scene_from_the_schema_never_panics(text in scene_text()) {
        check(&text);
    }

    #[test]
    fn fuzz_scene_arbitrary_text_never_panics(text in "[\\[\\]a-z_=0-9.,\"\n \\-]{0,200}") {
        check(&text);
    }

    #[test]
    fn fuzz_scene_arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        check(&String::from_utf8_lossy(&bytes));
    }
}
