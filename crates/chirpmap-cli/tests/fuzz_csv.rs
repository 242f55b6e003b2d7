//! Fuzz harness (proptest) for the CLI's file-format readers: the echoes CSV
//! and the poses CSV (issue 8, "Fuzzing, kept"). Arbitrary bytes, and rows
//! built from hostile values under valid headers with every line ending,
//! never panic; what parses satisfies the readers' promises.
//!
//! The readers live in the `chirpmap` binary, so they are compiled into this
//! test executable from their source files (tests/main.rs). `CHIRPMAP_FUZZ_CASES=N` raises the case count.
#![allow(clippy::unwrap_used, dead_code)]

use crate::{echoes_csv, poses_csv};

use proptest::prelude::*;

fn cases(default: u32) -> u32 {
    std::env::var("CHIRPMAP_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn cell() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        4 => (-100.0f64..100.0).prop_map(|v| format!("{v}").into_bytes()),
        2 => (0u32..10).prop_map(|v| v.to_string().into_bytes()),
        1 => Just(b"nan".to_vec()),
        1 => Just(b"inf".to_vec()),
        1 => Just(b"1e300".to_vec()),
        1 => Just(b"-0".to_vec()),
        1 => Just(b"".to_vec()),
        1 => Just(b"\"1,5\"".to_vec()),
        1 => Just(b"\"unterminated".to_vec()),
        1 => Just(vec![0xff, 0xfe]),
        1 => Just(b"\xef\xbb\xbf".to_vec()),
        1 => "[a-z0-9.\\-]{0,6}".prop_map(String::into_bytes),
    ]
}

fn eol() -> impl Strategy<Value = &'static [u8]> {
    prop_oneof![Just(&b"\n"[..]), Just(&b"\r\n"[..]), Just(&b"\r"[..])]
}

/// A header and rows, most with as many cells as the header has columns.
fn table(header: &'static str) -> impl Strategy<Value = Vec<u8>> {
    let n = header.split(',').count();
    let row = prop_oneof![
        4 => proptest::collection::vec(cell(), n..=n),
        1 => proptest::collection::vec(cell(), 0..n + 2),
    ];
    (proptest::collection::vec(row, 0..8), eol(), any::<bool>()).prop_map(move |(rows, eol, bom)| {
        let mut out = Vec::new();
        if bom {
            out.extend_from_slice(b"\xef\xbb\xbf");
        }
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(eol);
        for r in rows {
            out.extend(r.join(&b","[..]));
            out.extend_from_slice(eol);
        }
        out
    })
}

const ECHOES_HEADER: &str = "source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener,sigma_m,note";

fn check_echoes(bytes: &[u8]) {
    if let Ok(echoes) = echoes_csv::parse_echoes(bytes, "f.csv") {
        for e in &echoes {
            assert!(e.delta_d_m >= 0.0 && e.delta_d_m.is_finite() && e.weight.is_finite() && e.weight >= 0.0);
            assert!(e.source.is_sane() && e.listener.is_sane());
            assert!(e.sigma_m.is_none_or(|s| s.is_finite() && s > 0.0));
        }
        // What was read is written and read back identically.
        let mut buf = Vec::new();
        echoes_csv::write_echoes(&mut buf, &echoes).unwrap();
        assert_eq!(echoes_csv::parse_echoes(&buf, "back.csv").unwrap(), echoes);
    }
}

fn check_poses(bytes: &[u8]) {
    for listener in [0, 1] {
        if let Ok(p) = poses_csv::parse_poses(bytes, "p.csv", listener) {
            let rows = p.rows();
            assert!(!rows.is_empty());
            assert!(rows.windows(2).all(|w| w[0].0 < w[1].0), "{rows:?}");
            assert!(rows.iter().all(|(t, q)| t.is_finite() && q.is_sane()));
            let (t0, t1) = p.span();
            assert!(p.at(t0).is_some() && p.at(t1).is_some());
            let _ = p.check_span(1.0);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(256)))]

    #[test]
    fn fuzz_echoes_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        check_echoes(&bytes);
    }

    #[test]
    fn fuzz_echoes_hostile_rows(bytes in table(ECHOES_HEADER)) {
        check_echoes(&bytes);
    }

    #[test]
    fn fuzz_poses_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        check_poses(&bytes);
    }

    #[test]
    fn fuzz_poses_hostile_rows(bytes in table("t,x,y,listener")) {
        check_poses(&bytes);
    }
}
