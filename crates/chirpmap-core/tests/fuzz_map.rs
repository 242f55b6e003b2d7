//! Fuzz harness (proptest) for the map path up to the plot: random echoes,
//! hostile weights included, into `AccumulationMapper`, then thresholding
//! and highlights (issue 8, item 7 and "Fuzzing, kept"). Every echo is
//! either refused with an error or mapped, and the map stays finite (the
//! plot's colour bar over 0..inf hung `map`).
//!
//! Bounded for CI; `CHIRPMAP_FUZZ_CASES=N` raises the number of cases.
#![allow(clippy::unwrap_used)]

use chirpmap_core::{AccumulationMapper, Echo, GridSpec, Mapper, MappingParams, Point};
use proptest::prelude::*;

fn cases(default: u32) -> u32 {
    std::env::var("CHIRPMAP_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn weight() -> impl Strategy<Value = f64> {
    prop_oneof![0.0f64..10.0, Just(9e307), Just(f64::MAX), Just(1e300), Just(0.0), Just(f64::MIN_POSITIVE)]
}

/// Issue 8, item 7: two rows of weight 9e307 used to make cells infinite.
#[test]
fn weights_overflowing_to_infinity_are_an_error() {
    let spec = GridSpec::from_bounds([-10.0, -10.0, 10.0, 10.0], 0.1, u128::MAX).unwrap();
    // With N points per ellipse a cell can get the weight N times: 9e305 × 100.
    for (points, w) in [(0, 9e307), (100, 9e305)] {
        let params = MappingParams { ellipse_points: points, ..MappingParams::default() };
        let mut m = AccumulationMapper::new(spec, params).unwrap();
        let e = Echo::new(Point::new(0.0, 0.0), Point::new(1.0, 0.0), 2.0, w, 0.0, 0).unwrap();
        m.add_echo(&e).unwrap();
        let err = m.add_echo(&e).unwrap_err().to_string();
        assert!(err.contains("weight") && err.contains("infinite"), "{err}");
        assert!(m.grid().data.iter().all(|v| v.is_finite()));
        assert!(m.grid().max().is_finite());
    }
    // An echo built by hand with an infinite weight is refused too.
    let mut m = AccumulationMapper::new(spec, MappingParams::default()).unwrap();
    let mut e = Echo::new(Point::new(0.0, 0.0), Point::new(1.0, 0.0), 2.0, 1.0, 0.0, 0).unwrap();
    e.weight = f64::INFINITY;
    assert!(m.add_echo(&e).is_err());
    e.weight = f64::NAN;
    assert!(m.add_echo(&e).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(64)))]

    #[test]
    fn fuzz_random_echoes_map_to_a_finite_grid(
        echoes in proptest::collection::vec(
            (-30.0f64..30.0, -30.0f64..30.0, -30.0f64..30.0, -30.0f64..30.0, 0.0f64..80.0, weight()),
            0..12,
        ),
        cell in prop_oneof![Just(0.1), Just(0.5), Just(1.0)],
        points in prop_oneof![Just(0u32), 1u32..2000],
        keep_top in 0.01f64..=1.0,
    ) {
        let spec = GridSpec::from_bounds([-20.0, -20.0, 20.0, 20.0], cell, 1 << 30).unwrap();
        let params = MappingParams { cell, keep_top, ellipse_points: points, ..MappingParams::default() };
        let mut m = AccumulationMapper::new(spec, params).unwrap();
        for (sx, sy, lx, ly, dd, w) in echoes {
            let Ok(e) = Echo::new(Point::new(sx, sy), Point::new(lx, ly), dd, w, 0.0, 0) else { continue };
            let _ = m.add_echo(&e);
            prop_assert!(m.grid().max().is_finite());
        }
        for h in m.highlights() {
            prop_assert!(h.value.is_finite() && h.value > 0.0 && h.pos.is_finite());
            prop_assert!(spec.cell_of(h.pos).is_some());
        }
    }
}
