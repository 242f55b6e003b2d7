//! Resume, sharding and merge with a deterministic stand-in for the simulator.
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use chirpmap_core::Scene;
use chirpmap_experiments::driver::{merge, run_sweep};
use chirpmap_experiments::{ExperimentError, RunMetrics, Shard, SweepDef};
use std::path::Path;

const SWEEP: &str = r#"
name = "fake"
runs = 7
seed = 3
[[params]]
name = "n_obstacles"
path = "random_obstacles.count"
values = [1, 2, 3]
[[params]]
name = "pattern"
path = "listeners.0.speed"
values = [10.0, 5.0]
labels = ["base", "slow"]
baseline = "base"
"#;

/// Deterministic in (scene, run), like the simulator.
fn fake(scene: &Scene, run: u64) -> Result<RunMetrics, String> {
    let n = f64::from(scene.random_obstacles.count);
    let x = ((run * 2654435761 + scene.seed) % 1000) as f64 / 1000.0;
    Ok(RunMetrics {
        score_obstacle: Some(x / n),
        score_highlight: Some(1.0 - x / scene.listeners[0].speed),
        surface_f1: Some(x),
        chamfer_m: None,
        n_highlights: run as usize,
        n_echoes: 10 * run as usize,
    })
}

fn strip_elapsed(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path).unwrap().lines().map(|l| l.rsplit_once(',').unwrap().0.to_string()).collect()
}

#[test]
fn interrupted_sweep_resumes_without_loss_or_duplicates() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let full = tmp.path().join("full");
    let o = run_sweep(&plan, &full, Shard::ALL, 2, fake, |_, _| {}).unwrap();
    assert_eq!(o.rows.len(), 42);

    // Interrupt after 10 runs (the run function fails), leaving a partial line.
    let cut = tmp.path().join("cut");
    let count = std::sync::atomic::AtomicUsize::new(0);
    let r = run_sweep(
        &plan,
        &cut,
        Shard::ALL,
        1,
        |s, run| {
            if count.fetch_add(1, std::sync::atomic::Ordering::SeqCst) >= 10 {
                Err("killed".into())
            } else {
                fake(s, run)
            }
        },
        |_, _| {},
    );
    assert!(matches!(r, Err(ExperimentError::RunFailed { .. })));
    let runs = cut.join("runs.csv");
    let n_lines = std::fs::read_to_string(&runs).unwrap().lines().count();
    assert_eq!(n_lines, 11, "header + 10 streamed rows");
    let mut f = std::fs::OpenOptions::new().append(true).open(&runs).unwrap();
    std::io::Write::write_all(&mut f, b"3,2,slow,4,3,0.1").unwrap(); // torn write
    drop(f);
    let o = run_sweep(&plan, &cut, Shard::ALL, 2, fake, |_, _| {}).unwrap();
    assert_eq!((o.resumed, o.executed), (10, 32));
    assert_eq!(strip_elapsed(&runs), strip_elapsed(&full.join("runs.csv")));
    assert_eq!(
        std::fs::read_to_string(cut.join("summary.csv")).unwrap(),
        std::fs::read_to_string(full.join("summary.csv")).unwrap()
    );
    // Running again does nothing.
    let o = run_sweep(&plan, &cut, Shard::ALL, 2, fake, |_, _| {}).unwrap();
    assert_eq!((o.resumed, o.executed), (42, 0));
}

#[test]
fn sharded_and_merged_equals_unsharded() {
    let def = SweepDef::from_toml_str(SWEEP).unwrap();
    let plan = def.plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let full = tmp.path().join("full");
    run_sweep(&plan, &full, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    let dirs: Vec<_> = (0..3).map(|i| tmp.path().join(format!("s{i}"))).collect();
    for (i, d) in dirs.iter().enumerate() {
        run_sweep(&plan, d, Shard { index: i, count: 3 }, 2, fake, |_, _| {}).unwrap();
    }
    let merged = tmp.path().join("merged");
    let inputs: Vec<&Path> = dirs.iter().map(|d| d.as_path()).collect();
    let (o, report) = merge(&inputs, &merged, |d| d.plan(|_| Ok(()))).unwrap();
    assert!(report.missing.is_empty() && report.duplicated.is_empty());
    assert_eq!(o.rows.len(), 42);
    assert_eq!(strip_elapsed(&merged.join("runs.csv")), strip_elapsed(&full.join("runs.csv")));
    let md = std::fs::read_to_string(merged.join("summary.md")).unwrap();
    assert_eq!(md, std::fs::read_to_string(full.join("summary.md")).unwrap());
    assert!(md.contains("Δ score_obstacle vs base"), "{md}");

    // Missing shard is reported; duplicated shard is reported.
    let (_, report) = merge(&inputs[..2], &tmp.path().join("m2"), |d| d.plan(|_| Ok(()))).unwrap();
    assert_eq!(report.missing.len(), 14);
    let dup = [inputs[0], inputs[0], inputs[1], inputs[2]];
    let (_, report) = merge(&dup, &tmp.path().join("m3"), |d| d.plan(|_| Ok(()))).unwrap();
    assert_eq!(report.duplicated.len(), 14);
}

#[test]
fn foreign_directories_are_refused() {
    let def = SweepDef::from_toml_str(SWEEP).unwrap();
    let plan = def.plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a");
    run_sweep(&plan, &d, Shard { index: 0, count: 2 }, 1, fake, |_, _| {}).unwrap();
    // Other seed into the same directory.
    let other = SweepDef::from_toml_str(&SWEEP.replace("seed = 3", "seed = 4")).unwrap().plan(|_| Ok(())).unwrap();
    let e = run_sweep(&other, &d, Shard { index: 0, count: 2 }, 1, fake, |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("different sweep"), "{e}");
    // Other shard into the same directory.
    let e = run_sweep(&plan, &d, Shard { index: 1, count: 2 }, 1, fake, |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("holds shard 0/2"), "{e}");
    // Merging different seeds.
    let d2 = tmp.path().join("b");
    run_sweep(&other, &d2, Shard { index: 1, count: 2 }, 1, fake, |_, _| {}).unwrap();
    let e = merge(&[d.as_path(), d2.as_path()], &tmp.path().join("m"), |d| d.plan(|_| Ok(()))).unwrap_err();
    assert!(e.to_string().contains("different seed"), "{e}");
}

/// An empty or cut-short sweep.toml or shard.txt (older chirpmaps wrote them
/// in place; a full disk left them empty) is named as such, with what to do,
/// where it was refused as another sweep's ("holds shard , not 0/2").
#[test]
fn an_empty_or_cut_sweep_toml_or_shard_txt_is_named_as_such() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a");
    let shard = Shard { index: 0, count: 2 };
    run_sweep(&plan, &d, shard, 1, fake, |_, _| {}).unwrap();
    let sweep_toml = std::fs::read_to_string(d.join("sweep.toml")).unwrap();
    for cut in ["", &sweep_toml[..sweep_toml.len() / 2], &sweep_toml[..sweep_toml.len() - 1]] {
        std::fs::write(d.join("sweep.toml"), cut).unwrap();
        let e = run_sweep(&plan, &d, shard, 1, fake, |_, _| {}).unwrap_err().to_string();
        assert!(e.contains("sweep.toml: is empty or cut short") && e.contains("copy sweep.toml"), "{e}");
    }
    std::fs::write(d.join("sweep.toml"), &sweep_toml).unwrap();
    for cut in ["", "0/", "0/2"] {
        std::fs::write(d.join("shard.txt"), cut).unwrap();
        let e = run_sweep(&plan, &d, shard, 1, fake, |_, _| {}).unwrap_err().to_string();
        assert!(e.contains("shard.txt: is empty or cut short") && e.contains("shard 0/2 of this sweep"), "{e}");
    }
    std::fs::write(d.join("shard.txt"), "0/2\n").unwrap();
    assert_eq!(run_sweep(&plan, &d, shard, 1, fake, |_, _| {}).unwrap().executed, 0);
    // Nothing run yet: the empty file is all there is.
    let fresh = tmp.path().join("fresh");
    std::fs::create_dir(&fresh).unwrap();
    std::fs::write(fresh.join("sweep.toml"), "").unwrap();
    let e = run_sweep(&plan, &fresh, shard, 1, fake, |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("is empty or cut short") && e.contains("delete it"), "{e}");
    // A merge into a directory left so, and from one.
    let m = tmp.path().join("m");
    std::fs::create_dir(&m).unwrap();
    std::fs::write(m.join("sweep.toml"), "").unwrap();
    let e = merge(&[d.as_path()], &m, |d| d.plan(|_| Ok(()))).unwrap_err().to_string();
    assert!(e.contains("holds a sweep.toml that is empty or cut short"), "{e}");
    std::fs::write(m.join("sweep.toml"), &sweep_toml).unwrap();
    std::fs::write(m.join("shard.txt"), "").unwrap();
    let e = merge(&[d.as_path()], &m, |d| d.plan(|_| Ok(()))).unwrap_err().to_string();
    assert!(e.contains("holds a shard.txt that is empty or cut short"), "{e}");
    std::fs::write(d.join("sweep.toml"), "").unwrap();
    let e = merge(&[d.as_path()], &tmp.path().join("m2"), |d| d.plan(|_| Ok(()))).unwrap_err().to_string();
    assert!(e.contains("sweep.toml: is empty or cut short"), "{e}");
}

/// Issue 8, item 4: merge refuses an `--out` that holds another sweep, one of
/// its inputs (however spelled) or a user's files, and changes none of them.
#[test]
fn merge_never_writes_over_another_sweep_or_an_input() {
    let def = SweepDef::from_toml_str(SWEEP).unwrap();
    let plan = def.plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let dirs: Vec<_> = (0..2).map(|i| tmp.path().join(format!("s{i}"))).collect();
    for (i, d) in dirs.iter().enumerate() {
        run_sweep(&plan, d, Shard { index: i, count: 2 }, 1, fake, |_, _| {}).unwrap();
    }
    let inputs: Vec<&Path> = dirs.iter().map(|d| d.as_path()).collect();
    let plan_of = |d: &SweepDef| d.plan(|_| Ok(()));
    let snapshot = |d: &Path| -> Vec<(String, Vec<u8>)> {
        let mut v: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).unwrap())
            })
            .collect();
        v.sort();
        v
    };

    // Another sweep's directory.
    let other_plan = SweepDef::from_toml_str(&SWEEP.replace("seed = 3", "seed = 9")).unwrap().plan(|_| Ok(())).unwrap();
    let other = tmp.path().join("other");
    run_sweep(&other_plan, &other, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    let before = snapshot(&other);
    let e = merge(&inputs, &other, plan_of).unwrap_err().to_string();
    assert!(e.contains("holds another sweep"), "{e}");
    assert_eq!(snapshot(&other), before);

    // One of the inputs, also spelled differently.
    let before = snapshot(&dirs[0]);
    let dotted = tmp.path().join(".").join("s0");
    for out in [dirs[0].clone(), dotted, tmp.path().join("s1/../s0")] {
        let e = merge(&inputs, &out, plan_of).unwrap_err().to_string();
        assert!(e.contains("is the input shard directory"), "{}: {e}", out.display());
    }
    assert_eq!(snapshot(&dirs[0]), before);

    // A shard of this sweep that is not an input, and a user's directory.
    let s2 = tmp.path().join("s0b");
    run_sweep(&plan, &s2, Shard { index: 0, count: 2 }, 1, fake, |_, _| {}).unwrap();
    let e = merge(&inputs, &s2, plan_of).unwrap_err().to_string();
    assert!(e.contains("holds shard 0/2"), "{e}");
    let user = tmp.path().join("user");
    std::fs::create_dir(&user).unwrap();
    std::fs::write(user.join("summary.csv"), "mine").unwrap();
    let e = merge(&inputs, &user, plan_of).unwrap_err().to_string();
    assert!(e.contains("not empty"), "{e}");
    assert_eq!(std::fs::read_to_string(user.join("summary.csv")).unwrap(), "mine");
    let file = tmp.path().join("file");
    std::fs::write(&file, "x").unwrap();
    assert!(merge(&inputs, &file, plan_of).is_err());
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "x");

    // A new directory, and again into the same merged output: fine.
    let merged = tmp.path().join("merged");
    merge(&inputs, &merged, plan_of).unwrap();
    let (o, _) = merge(&inputs, &merged, plan_of).unwrap();
    assert_eq!(o.rows.len(), 42);
}

/// Issue 8, item 8: absurd run counts are refused by the plan, before any
/// allocation and before sweep.toml is written.
#[test]
fn run_counts_are_bounded_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    for runs in [u64::MAX, 1_000_000_000, 10_000_000, 2_000_000] {
        let mut def = SweepDef::from_toml_str(SWEEP).unwrap();
        def.runs = runs;
        let started = std::time::Instant::now();
        let e = def.plan(|_| Ok(())).unwrap_err().to_string();
        assert!(started.elapsed().as_secs_f64() < 1.0);
        assert!(e.contains("runs"), "{runs}: {e}");
    }
    // Within the per-configuration cap but beyond the memory estimate's cap.
    let mut def = SweepDef::from_toml_str(SWEEP).unwrap();
    def.runs = 1_000_000;
    let e = def.plan(|_| Ok(())).unwrap_err().to_string();
    assert!(e.contains("bytes of memory") || e.contains("cap of 10000000"), "{e}");
    assert!(std::fs::read_dir(tmp.path()).unwrap().next().is_none());
    // A corrupt sweep file is quoted as a short excerpt, once.
    let big = format!("name = \"{}\" x\n", "n".repeat(1_000_000));
    let e = SweepDef::from_toml_str(&big).unwrap_err().to_string();
    assert!(e.len() < 300, "{} chars", e.len());
    // Two parameters of one name (they would share a runs.csv column).
    let twice = SWEEP.replace("name = \"pattern\"", "name = \"n_obstacles\"");
    let e = SweepDef::from_toml_str(&twice).unwrap().plan(|_| Ok(())).unwrap_err().to_string();
    assert!(e.contains("\"n_obstacles\" is given twice (params[1])"), "{e}");
}

/// The repository's sweeps (definitions and recorded results) still plan
/// under the shared scene validation, so they can be rerun and resumed.
#[test]
fn recorded_sweeps_still_plan() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments");
    let mut files = vec![root.join("cells-vs-points.toml")];
    for d in ["cells-vs-points", "table1", "table2"] {
        files.push(root.join(d).join("sweep.toml"));
    }
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        let def = SweepDef::from_toml_str(&text).unwrap();
        def.plan(|_| Ok(())).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
    }
}

/// Issue 8, item 15: a damaged runs.csv header is quoted as a short excerpt.
#[test]
fn a_damaged_header_is_quoted_short() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a");
    run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    let runs = d.join("runs.csv");
    std::fs::write(&runs, format!("{}\n", "x".repeat(1_000_000))).unwrap();
    let e = run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap_err().to_string();
    assert!(e.len() < 600 && e.contains("does not match"), "{} chars", e.len());
}

/// Issue 13, item 5: a labelled numeric parameter gets its number beside the
/// label (`pattern` = "slow" is `listeners.0.speed` = 5).
#[test]
fn labelled_numeric_parameters_get_a_value_column() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a");
    run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    let text = std::fs::read_to_string(d.join("runs.csv")).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "config,n_obstacles,pattern,pattern_value,run,seed,score_obstacle,score_highlight,surface_f1,chamfer_m,\
         n_highlights,n_echoes,elapsed_s"
    );
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        let want = if f[2] == "slow" { "5" } else { "10" };
        assert_eq!(f[3], want, "{l}");
    }
}

/// A runs.csv written before the value and surface columns resumes: its rows
/// are kept (surface metrics empty) and the file is upgraded in place.
#[test]
fn a_runs_csv_in_the_old_format_resumes_and_is_upgraded() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a");
    run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    let runs = d.join("runs.csv");
    let new = std::fs::read_to_string(&runs).unwrap();
    // Rewrite the first 5 rows in the old layout (no pattern_value, surface_f1, chamfer_m).
    let old: Vec<String> = new
        .lines()
        .take(6)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            [&f[0..3], &f[4..8], &f[10..]].concat().join(",")
        })
        .collect();
    assert!(old[0].starts_with("config,n_obstacles,pattern,run,seed,score_obstacle,score_highlight,n_highlights"));
    std::fs::write(&runs, old.join("\n") + "\n").unwrap();
    let o = run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    assert_eq!((o.resumed, o.executed), (5, 37));
    let upgraded = std::fs::read_to_string(&runs).unwrap();
    assert_eq!(upgraded.lines().next(), new.lines().next());
    assert_eq!(upgraded.lines().count(), new.lines().count());
    // Resumed rows keep their scores and have no surface metrics; the rest are as before.
    let cut = |l: &str| l.split(',').take(8).collect::<Vec<_>>().join(",");
    for (u, n) in upgraded.lines().zip(new.lines()).skip(1) {
        assert_eq!(cut(u), cut(n));
    }
    let row1: Vec<&str> = upgraded.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row1[8], row1[9]), ("", ""));
}

/// A score outside [0, 1] or NaN in a hand-edited runs.csv is refused with
/// its line, on resume as on merge, instead of flowing into the summary.
#[test]
fn scores_out_of_range_in_runs_csv_are_refused() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a");
    run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    let runs = d.join("runs.csv");
    let text = std::fs::read_to_string(&runs).unwrap();
    for (col, value) in [(6, "NaN"), (6, "7.5"), (7, "-0.1"), (8, "inf"), (12, "-1")] {
        let edited: Vec<String> = text
            .lines()
            .enumerate()
            .map(|(i, l)| {
                if i != 1 {
                    return l.to_string();
                }
                let mut f: Vec<&str> = l.split(',').collect();
                f[col] = value;
                f.join(",")
            })
            .collect();
        std::fs::write(&runs, edited.join("\n") + "\n").unwrap();
        let e = run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap_err().to_string();
        assert!(e.contains("line 2: bad"), "{col}={value}: {e}");
        let out = tmp.path().join(format!("m{col}{value}"));
        let e = merge(&[d.as_path()], &out, |d| d.plan(|_| Ok(()))).unwrap_err().to_string();
        assert!(e.contains("line 2: bad"), "merge {col}={value}: {e}");
    }
}

/// A new sweep directory holding a user's summary.md (or summary.csv,
/// summary.png) is refused before anything is written: the sweep would
/// overwrite it at the end.
#[test]
fn a_users_summary_files_are_not_overwritten() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    for name in ["summary.md", "summary.csv", "summary.png"] {
        let d = tmp.path().join(name);
        std::fs::create_dir(&d).unwrap();
        std::fs::write(d.join(name), "my notes").unwrap();
        let e = run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("not ours"), "{e}");
        assert_eq!(std::fs::read_to_string(d.join(name)).unwrap(), "my notes");
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1, "nothing written beside it");
    }
    // An output that is a file: one clear error, the file kept.
    let f = tmp.path().join("sweep.toml");
    std::fs::write(&f, "mine").unwrap();
    let e = run_sweep(&plan, &f, Shard::ALL, 1, fake, |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("is a file"), "{e}");
    assert_eq!(std::fs::read_to_string(&f).unwrap(), "mine");
}

/// A second sweep into a directory another sweep is writing is refused (it
/// used to run every job again beside the first, writing each row twice),
/// and a runs.csv that already holds rows twice with the same results (left
/// by such a pair) resumes, each run kept once; different results are refused.
#[test]
fn a_busy_sweep_directory_is_refused_and_doubled_rows_resume() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let (started_tx, started_rx) = std::sync::mpsc::channel();
    let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
    let go_rx = std::sync::Mutex::new(go_rx);
    std::thread::scope(|scope| {
        let first = scope.spawn(|| {
            let once = std::sync::Once::new();
            run_sweep(
                &plan,
                &dir,
                Shard::ALL,
                1,
                |s, r| {
                    once.call_once(|| {
                        started_tx.send(()).unwrap();
                        go_rx.lock().unwrap().recv().unwrap();
                    });
                    fake(s, r)
                },
                |_, _| {},
            )
        });
        started_rx.recv().unwrap();
        let e = run_sweep(&plan, &dir, Shard::ALL, 1, fake, |_, _| {}).unwrap_err().to_string();
        assert!(e.contains("is locked: another chirpmap sweep is writing into this directory"), "{e}");
        go_tx.send(()).unwrap();
        assert_eq!(first.join().unwrap().unwrap().rows.len(), 42);
    });
    let runs = dir.join("runs.csv");
    let text = std::fs::read_to_string(&runs).unwrap();
    let doubled: String = text.lines().chain(text.lines().skip(1)).map(|l| format!("{l}\n")).collect();
    std::fs::write(&runs, doubled).unwrap();
    let o = run_sweep(&plan, &dir, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    assert_eq!((o.rows.len(), o.resumed, o.executed), (42, 42, 0));
    assert_eq!(std::fs::read_to_string(&runs).unwrap().lines().count(), 43, "each run once, after the header");
    // The same run with another result is a conflict, not a duplicate.
    let mut lines: Vec<String> = std::fs::read_to_string(&runs).unwrap().lines().map(String::from).collect();
    let changed = lines[1].replacen(",0.", ",0.9", 1);
    assert_ne!(changed, lines[1]);
    lines.push(changed);
    std::fs::write(&runs, lines.join("\n") + "\n").unwrap();
    let e = run_sweep(&plan, &dir, Shard::ALL, 1, fake, |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("appears twice with different results"), "{e}");
}

/// Files named as sweeps once named their temporary files (`runs.csv.tmp`,
/// `.sweep.toml.tmp`, ...) are a user's: a sweep and a merge leave them as
/// they were. They were written over and then renamed onto runs.csv,
/// sweep.toml, shard.txt and the summaries.
#[test]
fn files_named_like_old_temporaries_are_left_alone() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let mine = ["runs.csv.tmp", ".sweep.toml.tmp", ".shard.txt.tmp", ".summary.csv.tmp", ".summary.md.tmp"];
    let put = |d: &Path| {
        for n in mine {
            std::fs::write(d.join(n), format!("mine: {n}")).unwrap();
        }
    };
    let names = |d: &Path| -> Vec<String> {
        let mut v: Vec<String> =
            std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    };
    let mut want: Vec<String> = mine.iter().map(|s| s.to_string()).collect();
    want.extend(["runs.csv", "shard.txt", "summary.csv", "summary.md", "sweep.toml"].map(String::from));
    want.sort();
    let d = tmp.path().join("s");
    std::fs::create_dir(&d).unwrap();
    put(&d);
    assert_eq!(run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap().rows.len(), 42);
    for n in mine {
        assert_eq!(std::fs::read_to_string(d.join(n)).unwrap(), format!("mine: {n}"));
    }
    assert_eq!(names(&d), want, "nothing left beside the sweep's own files");
    // A merge into a directory of this sweep (its earlier merge) alike.
    let m = tmp.path().join("m");
    merge(&[d.as_path()], &m, |d| d.plan(|_| Ok(()))).unwrap();
    put(&m);
    merge(&[d.as_path()], &m, |d| d.plan(|_| Ok(()))).unwrap();
    for n in mine {
        assert_eq!(std::fs::read_to_string(m.join(n)).unwrap(), format!("mine: {n}"));
    }
    assert_eq!(names(&m), want);
}

/// A whole sweep.toml in `--out` that is no sweep definition is a user's
/// file (or a damaged one), not one chirpmap cut short: refused as not
/// ours, without the cut-short advice to delete it, and left as it was.
#[test]
fn a_users_sweep_toml_is_not_called_cut_short() {
    let plan = SweepDef::from_toml_str(SWEEP).unwrap().plan(|_| Ok(())).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let s0 = tmp.path().join("s0");
    run_sweep(&plan, &s0, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    for text in ["name = \"mine\"\nruns = 3\n[base]\n", "hello\n"] {
        let d = tmp.path().join("user");
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("sweep.toml"), text).unwrap();
        let e = run_sweep(&plan, &d, Shard::ALL, 1, fake, |_, _| {}).unwrap_err().to_string();
        assert!(e.contains("sweep.toml: is no sweep definition chirpmap wrote") && e.contains("not ours"), "{e}");
        assert!(!e.contains("delete") && !e.contains('\n'), "{e}");
        let e = merge(&[s0.as_path()], &d, |d| d.plan(|_| Ok(()))).unwrap_err().to_string();
        assert!(e.contains("is no sweep definition chirpmap wrote"), "{e}");
        assert_eq!(std::fs::read_to_string(d.join("sweep.toml")).unwrap(), text);
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1, "nothing written beside it");
    }
}

/// Merging into an earlier merge (or a whole sweep) of the same sweep adds
/// the inputs' runs to the runs already there, which keep their times: it
/// replaced them with the inputs' alone, losing every run no input held. A
/// run there with other results than an input's is refused, and a sweep
/// writing into `--out` makes a merge wait its turn (refused, as a second
/// sweep is).
#[test]
fn merging_into_an_earlier_merge_keeps_its_runs() {
    let def = SweepDef::from_toml_str(SWEEP).unwrap();
    let plan = def.plan(|_| Ok(())).unwrap();
    let plan_of = |d: &SweepDef| d.plan(|_| Ok(()));
    let tmp = tempfile::tempdir().unwrap();
    let shards: Vec<_> = (0..2).map(|i| tmp.path().join(format!("s{i}"))).collect();
    for (i, d) in shards.iter().enumerate() {
        run_sweep(&plan, d, Shard { index: i, count: 2 }, 1, fake, |_, _| {}).unwrap();
    }
    let full = tmp.path().join("full");
    run_sweep(&plan, &full, Shard::ALL, 1, fake, |_, _| {}).unwrap();
    let m = tmp.path().join("m");
    assert_eq!(merge(&[shards[0].as_path()], &m, plan_of).unwrap().0.rows.len(), 21);
    let first = std::fs::read_to_string(m.join("runs.csv")).unwrap();
    let (o, report) = merge(&[shards[1].as_path()], &m, plan_of).unwrap();
    assert_eq!((o.rows.len(), report.missing.len(), report.duplicated.len()), (42, 0, 0));
    assert_eq!(strip_elapsed(&m.join("runs.csv")), strip_elapsed(&full.join("runs.csv")));
    let now = std::fs::read_to_string(m.join("runs.csv")).unwrap();
    assert!(first.lines().skip(1).all(|l| now.lines().any(|n| n == l)), "the first merge's rows, times and all");
    // Into the whole sweep: its rows and times stay.
    let before = std::fs::read_to_string(full.join("runs.csv")).unwrap();
    merge(&[shards[0].as_path(), shards[1].as_path()], &full, plan_of).unwrap();
    assert_eq!(std::fs::read_to_string(full.join("runs.csv")).unwrap(), before);
    // A run of `m` with other results than an input's.
    let mut lines: Vec<String> = now.lines().map(String::from).collect();
    lines[1] = lines[1].replacen(",0.", ",0.9", 1);
    std::fs::write(m.join("runs.csv"), lines.join("\n") + "\n").unwrap();
    let e = merge(&[shards[0].as_path(), shards[1].as_path()], &m, plan_of).unwrap_err().to_string();
    assert!(e.contains("with results other than the inputs'"), "{e}");
    // A sweep holding `full`.
    let held = chirpmap_experiments::RunsFile::open(&full, &plan, Shard::ALL).unwrap();
    let e = merge(&[shards[0].as_path()], &full, plan_of).unwrap_err().to_string();
    assert!(e.contains("is locked"), "{e}");
    drop(held);
    merge(&[shards[0].as_path()], &full, plan_of).unwrap();
}

/// A sweep's base scene or parameter value that puts an array where a
/// table belongs is refused naming it (serde filled the struct from it).
#[test]
fn a_sweep_with_an_array_for_a_table_is_refused() {
    let base = SweepDef::from_toml_str(&SWEEP.replace("seed = 3", "seed = 3\n[base]\nmapping = [0.5]")).unwrap();
    let e = base.plan(|_| Ok(())).unwrap_err().to_string();
    assert!(e.contains("base scene: `mapping` must be a table"), "{e}");
    let param = format!("{SWEEP}[[params]]\nname = \"m\"\npath = \"mapping\"\nvalues = [[0.5]]\n");
    let e = SweepDef::from_toml_str(&param).unwrap().plan(|_| Ok(())).unwrap_err().to_string();
    assert!(e.contains("configuration 0: `mapping` must be a table"), "{e}");
}
