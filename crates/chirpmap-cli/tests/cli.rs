//! End-to-end tests of the `chirpmap` binary.
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use chirpmap_core::geometry::{point_segment_distance, specular_point_on_circle};
use chirpmap_core::{Circle, Point};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_chirpmap"))
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("spawn chirpmap")
}

/// `chirpmap map --echoes ECHOES --scene SCENE [EXTRA…] --out OUT`, which
/// must succeed.
fn map_scored(echoes: &Path, scene: &Path, extra: &[&str], out: &Path) {
    let mut args = vec!["map", "--echoes", echoes.to_str().unwrap(), "--scene", scene.to_str().unwrap()];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", out.to_str().unwrap()]);
    let o = run(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

fn circles() -> Vec<Circle> {
    [(-10.0, -20.0, 3.0), (6.0, -26.0, 4.0), (14.0, -14.0, 2.5)]
        .iter()
        .map(|&(x, y, r)| Circle::new(Point::new(x, y), r).unwrap())
        .collect()
}

/// Echoes computed exactly by specular-reflection geometry: a listener at
/// y = 10 m passing x = −20 … 20 m in 0.1 m steps above a source at the
/// origin, one echo per visible specular point per pose (paths that another
/// circle blocks are dropped).
fn exact_echoes_csv() -> String {
    let cs = circles();
    let source = Point::new(0.0, 0.0);
    let mut s = String::from("source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener\n");
    for k in 0..=400 {
        let listener = Point::new(-20.0 + 0.1 * f64::from(k), 10.0);
        for (n, c) in cs.iter().enumerate() {
            let Some(p) = specular_point_on_circle(source, listener, c) else { continue };
            let blocked = cs.iter().enumerate().any(|(m, o)| {
                m != n
                    && (point_segment_distance(o.center, source, p) <= o.radius_m
                        || point_segment_distance(o.center, p, listener) <= o.radius_m)
            });
            if blocked {
                continue;
            }
            let dd = p.dist(source) + p.dist(listener) - listener.dist(source);
            let _ = writeln!(s, "0,0,{:.1},10,{dd:.6},1,{:.2},0", listener.x, f64::from(k) * 0.01);
        }
    }
    s
}

#[test]
fn example_echoes_are_the_exact_specular_echoes() {
    let path = repo().join("examples/three-circles/echoes.csv");
    let want = exact_echoes_csv();
    if std::env::var_os("CHIRPMAP_BLESS").is_some() {
        std::fs::write(&path, &want).unwrap();
    }
    let have = std::fs::read_to_string(&path).unwrap();
    assert_eq!(have, want, "examples/three-circles/echoes.csv is stale; rerun with CHIRPMAP_BLESS=1");
}

fn read_highlights(dir: &Path) -> Vec<Point> {
    let text = std::fs::read_to_string(dir.join("highlights.csv")).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x,y,value"));
    lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            Point::new(v[0], v[1])
        })
        .collect()
}

#[test]
fn map_finds_each_of_three_circles_from_exact_echoes() {
    let tmp = tempfile::tempdir().unwrap();
    let echoes = tmp.path().join("echoes.csv");
    std::fs::write(&echoes, exact_echoes_csv()).unwrap();
    let out = tmp.path().join("out");
    let scene = repo().join("examples/three-circles/scene.toml");
    map_scored(&echoes, &scene, &[], &out);
    let hs = read_highlights(&out);
    for c in circles() {
        let best = hs.iter().map(|h| (h.dist(c.center) - c.radius_m).abs()).fold(f64::INFINITY, f64::min);
        assert!(best <= 0.5, "no highlight within 0.5 m of circle {c:?}: best {best} among {hs:?}");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["n_highlights"].as_u64().unwrap() as usize, hs.len());
    assert!(summary["n_echoes"].as_u64().unwrap() > 800);
    assert!(summary["elapsed_s"].as_f64().unwrap() > 0.0);
    assert!(summary["score_obstacle"].as_f64().unwrap() > 0.9, "{summary}");
    assert!(summary["score_highlight"].as_f64().unwrap() > 0.0);
    let png = std::fs::read(out.join("map.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    // Nothing staged is left behind.
    let names: Vec<String> =
        std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(!names.iter().any(|n| n.starts_with(".chirpmap-partial")), "{names:?}");
    let mut visible: Vec<&String> = names.iter().filter(|n| !n.starts_with('.')).collect();
    visible.sort();
    assert_eq!(visible, ["highlights.csv", "map.npy", "map.pgm", "map.png", "map.yaml", "summary.json"], "{names:?}");
}

#[test]
fn bad_input_fails_cleanly_without_output() {
    let tmp = tempfile::tempdir().unwrap();
    let head = "source_x,source_y,listener_x,listener_y,delta_d\n";
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "missing column",
            b"source_x,source_y,listener_x,delta_d\n0,0,1,2\n".to_vec(),
            ":1: missing column `listener_y`",
        ),
        ("not a number", format!("{head}0,0,1,1,2\n0,0,1,x,2\n").into_bytes(), ":3: `listener_y`"),
        ("nan", format!("{head}0,0,1,1,nan\n").into_bytes(), ":2: `delta_d` = \"nan\" is not finite"),
        ("negative", format!("{head}0,0,1,1,-3\n").into_bytes(), ":2: delta_d must be >= 0"),
        ("same point", format!("{head}2,2,2,2,3\n").into_bytes(), ":2: source and listener coincide"),
        ("empty", head.as_bytes().to_vec(), "no echoes"),
        ("garbage", (0u8..=255).cycle().take(3000).collect(), ""),
        ("huge", format!("{head}0,0,1,1,1e9\n").into_bytes(), "more than the cap"),
        ("absurd", format!("{head}0,0,1,1,2\n0,0,1,1,1e12\n").into_bytes(), ":3: invalid geometry"),
        // Finite weights whose map exceeds float32: map.npy held +inf (exit 0).
        (
            "f32 overflow",
            "source_x,source_y,listener_x,listener_y,delta_d,weight\n0,0,-20,10,26,1e300\n".as_bytes().to_vec(),
            "map.npy: cell (",
        ),
    ];
    for (name, bytes, want) in cases {
        let f = tmp.path().join(format!("{name}.csv"));
        std::fs::write(&f, bytes).unwrap();
        let out = tmp.path().join(format!("out-{name}"));
        let o = run(&["map", "--echoes", f.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(want), "{name}: {err:?} lacks {want:?}");
        let names_file = err.contains(f.file_name().unwrap().to_str().unwrap());
        assert!(names_file || ["huge", "f32 overflow"].contains(&name), "{name}: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(!out.exists(), "{name}: output directory was left behind");
    }
    let o = run(&["map", "--echoes", "/nonexistent.csv", "--out", tmp.path().join("x").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent.csv"));
    let o = run(&["map", "--echoes", "a.csv", "--out", "x", "--bounds", "1,2,0,3"]);
    assert_eq!(o.status.code(), Some(2), "clap rejects bad bounds");
}

#[test]
fn explicit_bounds_and_params_are_honoured() {
    let tmp = tempfile::tempdir().unwrap();
    let f = tmp.path().join("e.csv");
    std::fs::write(&f, "source_x,source_y,listener_x,listener_y,delta_d\n0,0,4,0,2\n").unwrap();
    let out = tmp.path().join("o");
    let o = run(&[
        "map",
        "--echoes",
        f.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--bounds",
        "-10,-10,10,10",
        "--cell",
        "0.5",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["grid"]["nx"], 40);
    assert_eq!(s["mapping"]["cell"], 0.5);
}

fn summary_without_timings(dir: &Path) -> serde_json::Value {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let obj = v.as_object_mut().unwrap();
    assert!(obj.remove("elapsed_s").unwrap().as_f64().unwrap() > 0.0);
    assert!(obj.remove("simulate_elapsed_s").unwrap().as_f64().unwrap() > 0.0);
    // The command line names the output directory.
    assert!(obj.remove("run").unwrap()["command_line"].is_array());
    v
}

#[test]
fn simulate_default_scene_is_reproducible_and_replayable() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (tmp.path().join("a"), tmp.path().join("b"), tmp.path().join("c"));
    for dir in [&a, &b] {
        let o = run(&["simulate", "--out", dir.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(String::from_utf8_lossy(&o.stdout).contains("score_obstacle = "));
    }
    let mut names: Vec<String> =
        std::fs::read_dir(&a).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(
        names,
        [
            ".chirpmap-outputs",
            "echoes.csv",
            "highlights.csv",
            "map.npy",
            "map.pgm",
            "map.png",
            "map.yaml",
            "scene.toml",
            "summary.json"
        ]
    );
    // Same seed: the same summary, bit for bit (timings aside), and the same files.
    let sa = summary_without_timings(&a);
    assert_eq!(sa, summary_without_timings(&b));
    for f in ["echoes.csv", "highlights.csv", "scene.toml", "map.npy", "map.pgm"] {
        assert_eq!(std::fs::read(a.join(f)).unwrap(), std::fs::read(b.join(f)).unwrap(), "{f}");
    }
    assert_eq!(sa["seed"], 1);
    assert_eq!(sa["n_obstacles"], 3);
    assert!(sa["n_echoes"].as_u64().unwrap() > 50, "{sa}");
    assert!(sa["n_highlights"].as_u64().unwrap() > 0);
    assert!(sa["score_obstacle"].as_f64().unwrap() > 0.0);
    // The resolved scene (random obstacles listed) replays the run exactly.
    let scene = a.join("scene.toml");
    let o = run(&["simulate", scene.to_str().unwrap(), "--out", c.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(sa, summary_without_timings(&c));
    assert_eq!(std::fs::read(a.join("echoes.csv")).unwrap(), std::fs::read(c.join("echoes.csv")).unwrap());
    // `chirpmap map` replays the echoes on the same grid to the same highlights.
    let m = tmp.path().join("m");
    let echoes = a.join("echoes.csv");
    map_scored(&echoes, &scene, &["--bounds", "-50,-50,50,50"], &m);
    assert_eq!(read_highlights(&m), read_highlights(&a));
}

#[test]
fn simulate_seed_flag_and_spectra() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let o = run(&["simulate", "--out", out.to_str().unwrap(), "--seed", "7", "--spectra"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary_without_timings(&out);
    assert_eq!(s["seed"], 7);
    assert!(std::fs::read_to_string(out.join("scene.toml")).unwrap().contains("seed = 7"));
    let spectra = std::fs::read_to_string(out.join("spectra.csv")).unwrap();
    assert!(spectra.starts_with("listener,t,listener_x,listener_y,f_lo_hz,f_hi_hz,loudness\n"));
    assert!(spectra.lines().count() > 100);
    let peaks = std::fs::read_to_string(out.join("peaks.csv")).unwrap();
    let direct = peaks.lines().filter(|l| l.contains(",direct,")).count();
    let reflected = peaks.lines().filter(|l| l.contains(",reflected,")).count();
    assert!(direct > 30, "{direct}");
    assert_eq!(reflected as u64, s["n_echoes"].as_u64().unwrap());
    assert_eq!(&std::fs::read(out.join("spectrum.png")).unwrap()[1..4], b"PNG");
}

#[test]
fn simulate_seed_above_i64_max_is_refused() {
    // scene.toml records the seed as a TOML integer (i64): a larger one could
    // not be written, and the replay would silently run another scene.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let o = run(&["simulate", "--out", out.to_str().unwrap(), "--seed", "9223372036854775808"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("--seed") && err.contains("9223372036854775807"), "{err}");
    assert!(!out.exists());
}

#[test]
fn simulate_bad_scenes_fail_cleanly_without_output() {
    let tmp = tempfile::tempdir().unwrap();
    let cases: Vec<(&str, &str, &str)> = vec![
        ("toml", "[world]\nspeed_of_sound = = 3\n", "line 2"),
        ("unknown key", "[particles]\nper_tik = 5\n", "per_tik"),
        ("zero speed of sound", "[world]\nspeed_of_sound = 0.0\n", "world.speed_of_sound must be finite and > 0"),
        ("negative listener speed", "[[listeners]]\nspeed = -10.0\n", "listeners[0].speed"),
        ("zero radius", "[[listeners]]\nradius = 0.0\n", "listeners[0].radius"),
        ("zero tick", "[particles]\ntick_ms = 0.0\n", "particles.tick_ms"),
        ("zero particles", "[particles]\nper_tick = 0\n", "particles.per_tick"),
        ("negative particles", "[particles]\nper_tick = -5\n", "per_tick"),
        ("flat chirp", "[chirp]\nf_start = 300.0\nf_end = 300.0\n", "f_start and f_end"),
        ("source inside", "[[obstacles]]\ncenter = [1.0, 1.0]\nradius = 3.0\n", "contains the source"),
        (
            "overlap",
            "[[obstacles]]\ncenter = [0.0, -20.0]\nradius = 4.0\n[[obstacles]]\nvertices = [[2.0, -22.0], [9.0, -22.0], [9.0, -18.0]]\n",
            "overlaps",
        ),
        ("listener outside", "[[listeners]]\nstart = [0.0, 60.0]\n", "outside world"),
        ("listener leaves", "[[listeners]]\nspeed = 100.0\n", "at t = 0.5300 s"),
        ("huge spin", "[[listeners]]\nspin_rate = 1e300\n", "listeners[0].spin_rate"),
        ("huge radius", "[[listeners]]\nradius = 15.0\n", "listeners[0].radius"),
        ("obstacle on path", "[[obstacles]]\ncenter = [3.0, 10.0]\nradius = 1.0\n", "path of listeners[0]"),
        ("huge per_tick", "[chirp]\nduration = 0.0005\n[particles]\nper_tick = 2000000000\n", "particles.per_tick"),
    ];
    for (name, toml, want) in cases {
        let f = tmp.path().join(format!("{name}.toml"));
        std::fs::write(&f, toml).unwrap();
        let out = tmp.path().join(format!("out-{name}"));
        let o = run(&["simulate", f.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(want), "{name}: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(!out.exists(), "{name}: partial output left");
    }
    let out = tmp.path().join("out-missing");
    let o = run(&["simulate", "no/such/scene.toml", "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot read scene"));
    assert!(!out.exists());
}

#[test]
fn map_scene_with_random_obstacles_is_scored_like_simulate() {
    let tmp = tempfile::tempdir().unwrap();
    let sim = tmp.path().join("sim");
    let o = run(&["simulate", "--out", sim.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The default scene's random obstacles, declared (an empty file is the
    // default scene to `simulate`, but to `map` a file of settings only).
    let empty = tmp.path().join("empty.toml");
    std::fs::write(&empty, "[random_obstacles]\n").unwrap();
    let out = tmp.path().join("map");
    let echoes = sim.join("echoes.csv");
    map_scored(&echoes, &empty, &["--bounds", "-50,-50,50,50"], &out);
    let read = |p: &Path| -> serde_json::Value { serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap() };
    let (m, s) = (read(&out.join("summary.json")), read(&sim.join("summary.json")));
    assert_eq!(m["score_obstacle"], s["score_obstacle"], "{m} vs {s}");
    assert_eq!(m["score_highlight"], s["score_highlight"]);
    assert_eq!(m["n_highlights"], s["n_highlights"]);
}

#[test]
fn rerun_into_the_same_directory_drops_the_previous_runs_extra_files_only() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("o");
    let o = run(&["simulate", "--out", out.to_str().unwrap(), "--spectra"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("spectra.csv").exists());
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let o = run(&["simulate", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!out.join("spectra.csv").exists(), "stale output of the earlier run left behind");
    assert!(!out.join("spectrum.png").exists());
    assert!(out.join("summary.json").exists() && out.join("map.png").exists());
    assert_eq!(std::fs::read_to_string(out.join("notes.txt")).unwrap(), "mine", "a user's file was touched");
}

/// The evidence mapper on echoes without `t` and `listener` columns (the
/// README's minimal format): each row's pose is told apart by its
/// position, so the three circles map as they do with times (before, every
/// row was one measurement and the map had no surface). A scene file with
/// only `[mapping]` sets the mapper and is not scored against the default
/// scene's random obstacles; Algorithm 1's threshold flags are refused with
/// the evidence mapper, which would ignore them.
#[test]
fn evidence_mapper_on_minimal_echoes_with_a_parameters_only_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let full = std::fs::read_to_string(repo().join("examples/three-circles/echoes.csv")).unwrap();
    let minimal: String = full.lines().map(|l| l.splitn(6, ',').take(5).collect::<Vec<_>>().join(",") + "\n").collect();
    assert!(minimal.starts_with("source_x,source_y,listener_x,listener_y,delta_d\n"), "{}", &minimal[..80]);
    let (with_t, without_t) = (tmp.path().join("full.csv"), tmp.path().join("minimal.csv"));
    std::fs::write(&with_t, &full).unwrap();
    std::fs::write(&without_t, minimal).unwrap();
    let params = tmp.path().join("params.toml");
    std::fs::write(&params, "[mapping]\nmapper = \"evidence\"\n").unwrap();
    let surfaces = |echoes: &Path, name: &str| {
        let out = tmp.path().join(name);
        let o = run(&[
            "map",
            "--echoes",
            echoes.to_str().unwrap(),
            "--scene",
            params.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(stderr.contains("holds settings only (no scene tables)"), "{stderr}");
        assert!(!String::from_utf8_lossy(&o.stdout).contains("score_obstacle"), "scored against no truth");
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
        assert_eq!(summary["mapper"], "evidence");
        assert!(summary["score_obstacle"].is_null(), "{summary}");
        std::fs::read_to_string(out.join("surfaces.csv")).unwrap()
    };
    // A file with any scene table (here [world]) is a scene: its default
    // random obstacles are scored, as `simulate` would place them.
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, "[world]\nspeed_of_sound = 343.0\n[mapping]\nmapper = \"evidence\"\n").unwrap();
    let o = run(&[
        "map",
        "--echoes",
        with_t.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        tmp.path().join("scored").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("score_obstacle"));
    let timed = surfaces(&with_t, "timed");
    assert!(timed.lines().count() > 1, "{timed}");
    assert_eq!(surfaces(&without_t, "untimed"), timed);
    let out = tmp.path().join("refused");
    let o = run(&[
        "map",
        "--echoes",
        with_t.to_str().unwrap(),
        "--mapper",
        "evidence",
        "--peak-radius",
        "3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success() && !out.exists());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("--peak-radius applies to --mapper paper only"), "{stderr}");
}

#[test]
fn evidence_mapper_writes_surfaces_grid_data_and_metrics() {
    let out = std::env::temp_dir().join(format!("chirpmap-cli-evidence-{}", std::process::id()));
    std::fs::remove_dir_all(&out).ok();
    let (echoes, scene) =
        (repo().join("examples/three-circles/echoes.csv"), repo().join("examples/three-circles/scene.toml"));
    map_scored(&echoes, &scene, &["--mapper", "evidence", "--plot-format", "svg"], &out);
    let surfaces = std::fs::read_to_string(out.join("surfaces.csv")).unwrap();
    assert!(surfaces.starts_with("kind,x0,y0,x1,y1,support,ambiguous\n"), "{surfaces}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["mapper"], "evidence");
    assert_eq!(summary["grid"]["values"], "log-odds of occupancy");
    assert!(summary["surface_f1"].is_number() && summary["score_obstacle"].is_number(), "{summary}");
    // map.npy: NumPy v1.0, float32, shape (ny, nx) as the summary says.
    let npy = std::fs::read(out.join("map.npy")).unwrap();
    assert_eq!(&npy[..6], b"\x93NUMPY");
    let (nx, ny) = (summary["grid"]["nx"].as_u64().unwrap(), summary["grid"]["ny"].as_u64().unwrap());
    let header = String::from_utf8_lossy(&npy[10..128.min(npy.len())]).into_owned();
    assert!(header.contains(&format!("'shape': ({ny}, {nx})")) && header.contains("'<f4'"), "{header}");
    let yaml = std::fs::read_to_string(out.join("map.yaml")).unwrap();
    assert!(yaml.contains("image: map.pgm") && yaml.contains("resolution: 0.1"), "{yaml}");
    assert!(std::fs::read_to_string(out.join("map.svg")).unwrap().contains("<svg"));
    assert!(!out.join("map.png").exists());
}

/// `--bounds` that no ellipse reaches: the run succeeds (the map is what was
/// asked for) but says the map is empty, instead of a silent blank map.
#[test]
fn an_empty_map_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let echoes = repo().join("examples/three-circles/echoes.csv");
    let out = tmp.path().join("far");
    let o = run(&[
        "map",
        "--echoes",
        echoes.to_str().unwrap(),
        "--bounds",
        "500,500,510,510",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("warning: the map is empty") && err.contains("x 500..510, y 500..510 m"), "{err}");
    let out = tmp.path().join("near");
    let o = run(&["map", "--echoes", echoes.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success() && !String::from_utf8_lossy(&o.stderr).contains("empty"));
    // A bad mapping flag is named as typed.
    for (flag, value, want) in
        [("--keep-top", "2", "--keep-top: must be in (0, 1]"), ("--cell", "-1", "--cell: must be")]
    {
        let bad = tmp.path().join(format!("bad{flag}"));
        let o = run(&[
            "map",
            "--echoes",
            echoes.to_str().unwrap(),
            &format!("{flag}={value}"),
            "--out",
            bad.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(want), "{flag}: {err}");
    }
}

/// A scene made for `synth` and `range` (a still listener, which the
/// particle simulator refuses) still scores a map: its listed obstacles are
/// the truth (`chirpmap::scene_truth`). Before, `map --scene` stopped with
/// "listeners[0].speed must be finite and > 0".
#[test]
fn map_scores_against_a_scene_with_a_still_listener() {
    let out = std::env::temp_dir().join(format!("chirpmap-cli-still-{}", std::process::id()));
    std::fs::remove_dir_all(&out).ok();
    std::fs::create_dir_all(&out).unwrap();
    // Two echoes of the examples/wall scene's wall (y = −6, source at the
    // origin, listener at (1.5, 0.5)): image source (0, −12).
    let echoes = out.join("echoes.csv");
    let dd = Point::new(1.5, 12.5).norm() - Point::new(1.5, 0.5).norm();
    std::fs::write(&echoes, format!("source_x,source_y,listener_x,listener_y,delta_d\n0,0,1.5,0.5,{dd}\n")).unwrap();
    let scene = repo().join("examples/wall/scene.toml");
    let map_dir = out.join("map");
    map_scored(&echoes, &scene, &["--plot-format", "svg"], &map_dir);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(map_dir.join("summary.json")).unwrap()).unwrap();
    assert!(summary["score_obstacle"].as_f64().is_some_and(|s| s > 0.0), "{summary}");
    std::fs::remove_dir_all(&out).ok();
}

/// Errors found by a reliability review (session 20) stay on one line, with
/// numbers as a person writes them, and absurd or repeated benchmark speeds
/// are refused before any work.
#[test]
fn review_errors_are_one_short_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let one_line = |o: &Output| -> String {
        assert!(!o.status.success());
        let e = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(e.trim_end().lines().count(), 1, "{e}");
        assert!(e.len() < 400, "{e}");
        e
    };
    // A sweep value of the wrong type: the key was on a second line.
    let sweep = d("s.toml");
    std::fs::write(
        &sweep,
        "name = \"x\"\nruns = 1\nseed = 1\n[[params]]\nname = \"d\"\npath = \"particles.doppler\"\nvalues = [true, \"yes\"]\n",
    )
    .unwrap();
    let e = one_line(&run(&["sweep", &sweep, "--out", &d("so")]));
    assert!(e.contains("expected a boolean in `particles.doppler`"), "{e}");
    // Speeds of the doppler suite.
    let e = one_line(&run(&["benchmark", "doppler", "--speeds", "1e-300", "--out", &d("b1")]));
    assert!(e.contains("1e-300 m/s is outside [0.01, 30]"), "{e}");
    let e = one_line(&run(&["benchmark", "doppler", "--speeds", "1,2,1", "--out", &d("b2")]));
    assert!(e.contains("1 m/s is given twice (speed 3 of the list)"), "{e}");
    assert!(!dir.path().join("b1").exists() && !dir.path().join("b2").exists());
}

/// A file name that is not UTF-8 is an ordinary input and output name: the
/// summary's command line recorded `std::env::args()`, which panicked on it
/// (exit 101; session 20's review of the Python package found it).
#[cfg(unix)]
#[test]
fn a_file_name_that_is_not_utf8_is_no_panic() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join(std::ffi::OsStr::from_bytes(b"sc\xff.toml"));
    std::fs::write(&scene, "[particles]\nper_tick = 360\n").unwrap();
    let out = dir.path().join(std::ffi::OsStr::from_bytes(b"o\xffx"));
    let o = bin().arg("--no-progress").arg("simulate").arg(&scene).arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let line: Vec<&str> =
        summary["run"]["command_line"].as_array().unwrap().iter().filter_map(|v| v.as_str()).collect();
    assert!(line.last().is_some_and(|a| a.ends_with("o\u{fffd}x")), "{line:?}");
}
