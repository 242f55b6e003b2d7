//! End-to-end tests of `chirpmap sweep` and `chirpmap merge`.
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use std::path::Path;
use std::process::{Command, Output, Stdio};

fn chirpmap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_chirpmap")).args(args).output().unwrap()
}

/// A cheap sweep: few particles, coarse sampling.
fn write_sweep(dir: &Path, runs: u64, seed: u64) -> String {
    let p = dir.join(format!("sweep-{runs}-{seed}.toml"));
    std::fs::write(
        &p,
        format!(
            r#"name = "small"
runs = {runs}
seed = {seed}
[base.particles]
per_tick = 720
[[params]]
name = "n_obstacles"
path = "random_obstacles.count"
values = [1, 3]
[[params]]
name = "sample"
path = "listeners.*.sampling"
values = [{{ period_ms = 20.0 }}, {{ random_ms = [10.0, 100.0] }}]
labels = ["20 ms", "U(10,100) ms"]
"#
        ),
    )
    .unwrap();
    p.to_str().unwrap().to_string()
}

/// runs.csv without the elapsed_s column.
fn rows(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join("runs.csv"))
        .unwrap()
        .lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string())
        .collect()
}

#[test]
fn sweep_writes_tables_and_is_thread_count_independent() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = write_sweep(tmp.path(), 3, 5);
    let a = tmp.path().join("a");
    let b = tmp.path().join("b");
    let o = chirpmap(&["sweep", &sweep, "--out", a.to_str().unwrap(), "--threads", "1", "--no-progress"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = chirpmap(&["sweep", &sweep, "--out", b.to_str().unwrap(), "--threads", "2", "--no-progress"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ra = rows(&a);
    assert_eq!(ra.len(), 1 + 4 * 3);
    assert_eq!(
        ra[0],
        "config,n_obstacles,sample,run,seed,score_obstacle,score_highlight,surface_f1,chamfer_m,n_highlights,n_echoes"
    );
    assert_eq!(ra, rows(&b));
    for f in ["summary.csv", "summary.md", "summary.png", "sweep.toml"] {
        assert!(a.join(f).exists(), "{f}");
    }
    let md = std::fs::read_to_string(a.join("summary.md")).unwrap();
    assert!(md.contains("| 3 | U(10,100) ms | 3 |"), "{md}");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("score_obstacle"), "summary printed: {stdout}");
    // The figure was staged and moved into place: no hidden leftovers.
    let hidden: Vec<String> = std::fs::read_dir(&a)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".chirpmap-summary"))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");
    // A thread count out of 1..=1024 is refused by the argument parser, before anything is written.
    for bad in ["0", "1025", "18446744073709551615"] {
        let c = tmp.path().join(format!("c{bad}"));
        let o = chirpmap(&["sweep", &sweep, "--out", c.to_str().unwrap(), "--threads", bad, "--no-progress"]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains("--threads") && e.contains("1..=1024"), "{bad}: {e}");
        assert!(!c.exists());
    }
}

#[test]
fn killed_sweep_resumes_without_loss_or_duplicates() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = write_sweep(tmp.path(), 8, 6);
    let full = tmp.path().join("full");
    let o = chirpmap(&["sweep", &sweep, "--out", full.to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success());

    let cut = tmp.path().join("cut");
    let mut child = Command::new(env!("CARGO_BIN_EXE_chirpmap"))
        .args(["sweep", &sweep, "--out", cut.to_str().unwrap(), "--threads", "1", "--no-progress"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kill (SIGKILL) once a few rows are on disk.
    let runs = cut.join("runs.csv");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    loop {
        let n = std::fs::read_to_string(&runs).map(|s| s.lines().count()).unwrap_or(0);
        if n >= 4 || std::time::Instant::now() > deadline {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let partial = std::fs::read_to_string(&runs).unwrap().lines().count();
    assert!(partial < 33, "the sweep finished before it could be killed ({partial} lines)");

    let o = chirpmap(&["sweep", &sweep, "--out", cut.to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("resumed"), "{err}");
    assert_eq!(rows(&cut), rows(&full));
}

#[test]
fn shards_merge_to_the_unsharded_sweep() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = write_sweep(tmp.path(), 3, 7);
    let full = tmp.path().join("full");
    assert!(chirpmap(&["sweep", &sweep, "--out", full.to_str().unwrap(), "--no-progress"]).status.success());
    let mut shards = Vec::new();
    for i in 0..3 {
        let d = tmp.path().join(format!("shard{i}"));
        let o =
            chirpmap(&["sweep", &sweep, "--out", d.to_str().unwrap(), "--shard", &format!("{i}/3"), "--no-progress"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        shards.push(d.to_str().unwrap().to_string());
    }
    let merged = tmp.path().join("merged");
    let mut args = vec!["merge"];
    args.extend(shards.iter().map(String::as_str));
    args.extend(["--out", merged.to_str().unwrap()]);
    let o = chirpmap(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(rows(&merged), rows(&full));
    assert_eq!(
        std::fs::read_to_string(merged.join("summary.csv")).unwrap(),
        std::fs::read_to_string(full.join("summary.csv")).unwrap()
    );
    // A missing shard is reported.
    let o = chirpmap(&["merge", &shards[0], &shards[1], "--out", tmp.path().join("m2").to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("runs are missing"));
}

#[test]
fn bad_sweeps_fail_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = write_sweep(tmp.path(), 2, 8);
    let out = tmp.path().join("o");
    let o = chirpmap(&["sweep", "table9", "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown preset \"table9\""));
    let empty = tmp.path().join("empty.toml");
    std::fs::write(&empty, std::fs::read_to_string(&sweep).unwrap().replace("values = [1, 3]", "values = []")).unwrap();
    let o = chirpmap(&["sweep", empty.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("empty grid"));
    let badparam = tmp.path().join("bad.toml");
    std::fs::write(
        &badparam,
        std::fs::read_to_string(&sweep).unwrap().replace("random_obstacles.count", "random_obstacles.cnt"),
    )
    .unwrap();
    let o = chirpmap(&["sweep", badparam.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("cnt"));
    let badscene = tmp.path().join("badscene.toml");
    std::fs::write(&badscene, std::fs::read_to_string(&sweep).unwrap().replace("per_tick = 720", "per_tick = 0"))
        .unwrap();
    let o = chirpmap(&["sweep", badscene.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("per_tick"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = chirpmap(&["sweep", &sweep, "--out", out.to_str().unwrap(), "--shard", "3/3"]);
    assert_eq!(o.status.code(), Some(2), "clap rejects the shard");
    assert!(!out.exists(), "no output directory for rejected sweeps");
    // A directory of another sweep is refused.
    assert!(chirpmap(&["sweep", &sweep, "--out", out.to_str().unwrap(), "--no-progress"]).status.success());
    let other = write_sweep(tmp.path(), 2, 9);
    let o = chirpmap(&["sweep", &other, "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("different sweep"));
}

/// A sweep that cannot write sweep.toml (a file size limit of 0 kills it at
/// the first byte, as a full disk stops a write) leaves no empty sweep.toml:
/// it wrote one in place, and every later run there was refused as "a
/// different sweep".
#[cfg(unix)]
#[test]
fn a_sweep_stopped_while_writing_sweep_toml_leaves_none() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = write_sweep(tmp.path(), 1, 4);
    let out = tmp.path().join("o");
    let o = Command::new("sh")
        .args(["-c", "ulimit -f 0; exec \"$0\" sweep \"$1\" --out \"$2\" --no-progress"])
        .args([env!("CARGO_BIN_EXE_chirpmap"), &sweep, out.to_str().unwrap()])
        .stdout(Stdio::null())
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(!out.join("sweep.toml").exists(), "an empty sweep.toml was left");
    let o = chirpmap(&["sweep", &sweep, "--out", out.to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
