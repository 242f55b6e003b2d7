//! No command writes over or deletes a file it did not create, or one of its
//! own inputs; a refused output is refused before any work (issue 8, items
//! 1–6 and 17).
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_chirpmap")).args(args).output().expect("spawn chirpmap")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("chirpmap-cli-safety-{}-{name}", std::process::id()));
    std::fs::remove_dir_all(&d).ok();
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Every file under `dir` with its contents, to prove nothing changed.
fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_file())
        .map(|e| (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).unwrap()))
        .collect();
    v.sort();
    v
}

/// A small, fast scene: one circle, a short simulation.
const SCENE: &str = "seed = 3\n[[obstacles]]\ncenter = [0.0, -8.0]\nradius = 2.0\n[[listeners]]\nstart = [-5.0, 5.0]\n\
                     [particles]\nper_tick = 720\n[mapping]\npeak_radius = 2.0\n";

#[test]
fn map_into_a_simulate_output_keeps_its_inputs() {
    let d = tmp("map-into-sim");
    let scene = d.join("in.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let out = d.join("run");
    let o = run(&["simulate", s(&scene), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let echoes = std::fs::read(out.join("echoes.csv")).unwrap();
    let resolved = std::fs::read(out.join("scene.toml")).unwrap();
    let (e, sc) = (out.join("echoes.csv"), out.join("scene.toml"));
    let o = run(&["map", "--echoes", s(&e), "--scene", s(&sc), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(out.join("echoes.csv")).unwrap(), echoes, "map deleted or changed its input");
    assert_eq!(std::fs::read(out.join("scene.toml")).unwrap(), resolved);
    // And once more: the inputs are still kept (they stay in the manifest).
    let o = run(&["map", "--echoes", s(&e), "--scene", s(&sc), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("echoes.csv").exists() && out.join("scene.toml").exists());
}

#[test]
fn simulate_refuses_to_replace_its_own_scene() {
    let d = tmp("sim-own-scene");
    let scene = d.join("scene.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let before = snapshot(&d);
    let o = run(&["simulate", s(&scene), "--out", s(&d)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("would replace the input"), "{}", stderr(&o));
    assert_eq!(snapshot(&d), before);
}

#[test]
fn outputs_never_replace_a_users_file() {
    let d = tmp("user-file");
    std::fs::write(d.join("summary.json"), "my notes").unwrap();
    let before = snapshot(&d);
    let o = run(&["simulate", "--out", s(&d)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not written by chirpmap"), "{}", stderr(&o));
    assert_eq!(snapshot(&d), before);
}

#[test]
fn synth_refuses_outputs_that_are_its_input_however_spelled() {
    let d = tmp("synth-input");
    let scene = d.join("s.toml");
    std::fs::write(&scene, "[[listeners]]\nstart = [1.0, 1.0]\nspeed = 0.0\n[synth]\nchirps = 1\n").unwrap();
    let before = snapshot(&d);
    let dotted = d.join(".").join("s.toml");
    for args in [
        vec!["synth", s(&scene), "--out", s(&dotted)],
        vec!["synth", s(&scene), "--out", s(&d.join("r.wav")), "--poses", s(&dotted)],
    ] {
        let o = run(&args);
        assert!(!o.status.success(), "{args:?}");
        assert!(stderr(&o).contains("would replace the input"), "{}", stderr(&o));
        assert_eq!(snapshot(&d), before, "{args:?}");
    }
}

#[test]
fn failed_synth_keeps_the_users_existing_output() {
    let d = tmp("synth-fail");
    let scene = d.join("s.toml");
    std::fs::write(&scene, "[[listeners]]\nstart = [1.0, 1.0]\nspeed = 0.0\n[synth]\nchirps = 1\n").unwrap();
    let wav = d.join("r.wav");
    std::fs::write(&wav, "user's recording").unwrap();
    std::fs::create_dir(d.join("poses_dir")).unwrap();
    let o = run(&["synth", s(&scene), "--out", s(&wav), "--poses", s(&d.join("poses_dir"))]);
    assert!(!o.status.success());
    assert_eq!(std::fs::read_to_string(&wav).unwrap(), "user's recording");
    // A synth output written by chirpmap may be rewritten; the user's may not.
    let own = d.join("own.wav");
    for _ in 0..2 {
        let o = run(&["synth", s(&scene), "--out", s(&own)]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let o = run(&["synth", s(&scene), "--out", s(&wav)]);
    assert!(!o.status.success());
    assert_eq!(std::fs::read_to_string(&wav).unwrap(), "user's recording");
}

#[test]
fn out_that_is_a_file_is_refused_before_work() {
    let d = tmp("out-file");
    let f = d.join("not-a-dir");
    std::fs::write(&f, "x").unwrap();
    let o = run(&["simulate", "--out", s(&f)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("is not a directory"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&f).unwrap(), "x");
    // A dangling symbolic link, and a single-file output ending in `/`.
    #[cfg(unix)]
    {
        let link = d.join("dangling");
        std::os::unix::fs::symlink(d.join("nowhere"), &link).unwrap();
        let o = run(&["simulate", "--out", s(&link)]);
        assert!(!o.status.success() && stderr(&o).contains("symbolic link to nothing"), "{}", stderr(&o));
    }
    let scene = d.join("s.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let slash = format!("{}/", s(&d.join("new")));
    let o = run(&["synth", s(&scene), "--out", &slash]);
    assert!(!o.status.success() && stderr(&o).contains("names a directory"), "{}", stderr(&o));
    assert!(!d.join("new").exists());
}

#[test]
fn debris_of_a_killed_run_is_removed_by_the_next_run() {
    let d = tmp("debris");
    let out = d.join("run");
    // A killed run's staging folder: its lock file is there, and nobody holds it.
    std::fs::create_dir_all(out.join(".chirpmap-partial-4000000000")).unwrap();
    std::fs::write(out.join(".chirpmap-partial-4000000000/lock"), "").unwrap();
    std::fs::write(out.join(".chirpmap-partial-4000000000/map.png"), "half").unwrap();
    // A user's file that only looks like debris (older chirpmaps removed it).
    std::fs::write(d.join("thesis.tex.partial-4000000000"), "draft").unwrap();
    let scene = d.join("s.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let o = run(&["simulate", s(&scene), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join(".chirpmap-partial-4000000000").exists());
    let o = run(&["synth", s(&scene), "--out", s(&d.join("x.wav"))]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(d.join("thesis.tex.partial-4000000000")).unwrap(), "draft");
}

/// Runs started together into one place (`make -j`, a resubmitted job): every
/// one succeeds, the manifest records every file, and each output can be
/// written again; no run deletes another's staging folder.
#[test]
fn concurrent_runs_into_one_place_keep_every_record() {
    let d = tmp("concurrent");
    let scene = d.join("s.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let spawn = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_chirpmap"))
            .args(args)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    for round in 0..3 {
        let wavs: Vec<PathBuf> = (0..4).map(|i| d.join(format!("r{round}-{i}.wav"))).collect();
        let kids: Vec<_> = wavs.iter().map(|w| spawn(&["synth", s(&scene), "--out", s(w)])).collect();
        for k in kids {
            let o = k.wait_with_output().unwrap();
            assert!(o.status.success(), "{}", stderr(&o));
        }
        let listed = std::fs::read_to_string(d.join(".chirpmap-files")).unwrap();
        for w in &wavs {
            let name = w.file_name().unwrap().to_str().unwrap();
            assert!(listed.lines().any(|l| l.split('\t').next() == Some(name)), "{name} not recorded:\n{listed}");
        }
    }
    let out = d.join("same");
    for _ in 0..3 {
        let kids: Vec<_> = (0..3).map(|_| spawn(&["simulate", s(&scene), "--out", s(&out)])).collect();
        for k in kids {
            let o = k.wait_with_output().unwrap();
            assert!(o.status.success(), "{}", stderr(&o));
        }
        let o = run(&["simulate", s(&scene), "--out", s(&out)]);
        assert!(o.status.success(), "a rerun was refused: {}", stderr(&o));
    }
    assert!(std::fs::read_dir(&d).unwrap().flatten().all(|e| !e.file_name().to_string_lossy().contains("partial")));
}

/// Ctrl-C or SIGTERM during a run: exit 128 + the signal, and neither the
/// staging folder nor the `--out` the run created is left behind.
#[cfg(unix)]
#[test]
fn an_interrupted_run_leaves_nothing_behind() {
    let d = tmp("interrupt");
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let out = d.join(format!("bench{code}"));
        let mut kid = Command::new(env!("CARGO_BIN_EXE_chirpmap"))
            .args(["--no-progress", "benchmark", "maps", "--runs", "1", "--out", s(&out)])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Wait until the run is at work: its staging folder exists.
        let started = std::time::Instant::now();
        while !std::fs::read_dir(&out).is_ok_and(|mut e| e.any(|e| e.is_ok())) {
            assert!(started.elapsed().as_secs() < 60, "the run never started");
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
        let k = Command::new("kill").args([signal, &kid.id().to_string()]).status().unwrap();
        assert!(k.success());
        let status = kid.wait().unwrap();
        let mut err = String::new();
        std::io::Read::read_to_string(kid.stderr.as_mut().unwrap(), &mut err).unwrap();
        assert_eq!(status.code(), Some(code), "{err}");
        assert!(err.contains("interrupted: unfinished outputs removed"), "{err}");
        assert!(!out.exists(), "left {:?}", std::fs::read_dir(&out).map(|e| e.count()));
    }
}
