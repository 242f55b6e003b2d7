//! Fuzz harness (proptest) for what a sweep reads back when it resumes or
//! merges: runs.csv, sweep.toml and shard.txt, mutated, truncated or
//! replaced by arbitrary bytes (issue 8, "Fuzzing, kept"). Resuming or
//! merging never panics; when it succeeds, the directory holds exactly the
//! plan's runs, each once, with the stand-in's results.
//!
//! Bounded for CI; `CHIRPMAP_FUZZ_CASES=N` raises the number of cases.
#![allow(clippy::unwrap_used)]

use chirpmap_core::Scene;
use chirpmap_experiments::driver::{merge, run_sweep};
use chirpmap_experiments::runs::{RUNS_FILE, SHARD_FILE, SWEEP_FILE, read_rows};
use chirpmap_experiments::{RunMetrics, Shard, SweepDef};
use proptest::prelude::*;
use std::path::Path;

fn cases(default: u32) -> u32 {
    std::env::var("CHIRPMAP_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

const SWEEP: &str = r#"
name = "fuzz"
runs = 3
seed = 5
[[params]]
name = "n"
path = "random_obstacles.count"
values = [1, 2]
"#;

fn fake(scene: &Scene, run: u64) -> Result<RunMetrics, String> {
    let x = ((run * 2654435761 + scene.seed) % 1000) as f64 / 1000.0;
    Ok(RunMetrics {
        score_obstacle: Some(x),
        score_highlight: if run.is_multiple_of(2) { None } else { Some(1.0 - x) },
        surface_f1: Some(x / 2.0),
        chamfer_m: if run.is_multiple_of(3) { None } else { Some(x) },
        n_highlights: run as usize,
        n_echoes: usize::from(scene.random_obstacles.count as u8),
    })
}

/// One mutation of a file's bytes.
#[derive(Debug, Clone)]
enum Edit {
    Set(usize, u8),
    Truncate(usize),
    Append(Vec<u8>),
    Replace(Vec<u8>),
    Remove,
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        4 => (0usize..400, any::<u8>()).prop_map(|(i, b)| Edit::Set(i, b)),
        2 => (0usize..400).prop_map(Edit::Truncate),
        2 => prop_oneof![
            Just(b"0,1,0,5,0.1,,0,1,0.5\n".to_vec()),
            Just(b"1,2,2,5,nan,inf,3,3,0\n".to_vec()),
            Just(b"9,1,0,5,,,0,0,0\n".to_vec()),
            Just(b"0,1,18446744073709551615,5,,,0,0,0\n".to_vec()),
            Just(b"\"unterminated\n".to_vec()),
            proptest::collection::vec(any::<u8>(), 0..40),
        ]
        .prop_map(Edit::Append),
        1 => proptest::collection::vec(any::<u8>(), 0..80).prop_map(Edit::Replace),
        1 => Just(Edit::Remove),
    ]
}

fn apply(path: &Path, edits: &[Edit]) {
    let mut bytes = std::fs::read(path).unwrap_or_default();
    for e in edits {
        match e {
            Edit::Set(i, b) => {
                if let Some(x) = bytes.get_mut(*i) {
                    *x = *b;
                }
            }
            Edit::Truncate(n) => bytes.truncate(*n),
            Edit::Append(a) => bytes.extend(a),
            Edit::Replace(r) => bytes.clone_from(r),
            Edit::Remove => {
                let _ = std::fs::remove_file(path);
                return;
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(128)))]

    #[test]
    fn fuzz_resume_from_damaged_files(
        runs_edits in proptest::collection::vec(edit(), 0..4),
        sweep_edits in prop_oneof![3 => Just(vec![]), 1 => proptest::collection::vec(edit(), 1..3)],
        shard_edits in prop_oneof![3 => Just(vec![]), 1 => proptest::collection::vec(edit(), 1..3)],
        partial in any::<bool>(),
    ) {
        let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let good = tmp.path().join("good");
        // A complete sweep, or one cut short after two runs.
        let done = std::sync::atomic::AtomicUsize::new(0);
        let _ = run_sweep(&plan, &good, Shard::ALL, 1, |s, r| {
            if partial && done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) >= 2 { Err("cut".into()) } else { fake(s, r) }
        }, |_, _| {});
        let dir = tmp.path().join("dir");
        copy_dir(&good, &dir);
        apply(&dir.join(RUNS_FILE), &runs_edits);
        apply(&dir.join(SWEEP_FILE), &sweep_edits);
        apply(&dir.join(SHARD_FILE), &shard_edits);
        if let Ok(o) = run_sweep(&plan, &dir, Shard::ALL, 1, fake, |_, _| {}) {
            let jobs = plan.jobs();
            prop_assert_eq!(o.rows.iter().map(|r| r.job).collect::<Vec<_>>(), jobs.clone());
            // (Rows resumed from a damaged file keep whatever numbers parse: a
            // resume trusts its own file's rows, so the results are not compared.)
            let back = read_rows(&dir.join(RUNS_FILE), &plan).unwrap();
            prop_assert_eq!(back.len(), jobs.len());
        }
        // Merging the damaged directory with the good one never panics either.
        let out = tmp.path().join("merged");
        let _ = merge(&[good.as_path(), dir.as_path()], &out, |d| d.plan(|_| Ok(())));
    }

    #[test]
    fn fuzz_sweep_toml_arbitrary_text(text in "[a-z_=\\[\\]0-9.,\"\n \\-]{0,200}") {
        if let Ok(def) = SweepDef::from_toml_str(&text) {
            let _ = def.plan(|_| Ok(()));
        }
    }
}
