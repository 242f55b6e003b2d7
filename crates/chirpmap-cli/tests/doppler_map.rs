//! Issue 11 end to end: `chirpmap synth` with chirp patterns, `chirpmap map
//! --wav` with the Doppler-corrected default, its `delta_d_rate` column and
//! the map's wall, checked against the wall's exact position (face y = −6 m).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_chirpmap")).args(args).output().expect("spawn chirpmap")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("chirpmap-doppler-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const SCENE: &str = include_str!("../../../examples/moving-wall/scene.toml");

/// The moving-wall scene at `speed` m/s, 16 chirps, with `extra` [synth] lines.
fn scene(d: &Path, speed: f64, extra: &str) -> PathBuf {
    let text = SCENE
        .replace("speed = 1.0", &format!("speed = {speed}"))
        .replace("chirps = 40", "chirps = 16")
        .replace("snr_db = 20.0", &format!("snr_db = 20.0\n{extra}"));
    let p = d.join("scene.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn synth(scene: &Path, d: &Path) -> (PathBuf, PathBuf) {
    let (wav, poses) = (d.join("rec.wav"), d.join("poses.csv"));
    let o =
        run(&["synth", scene.to_str().unwrap(), "--out", wav.to_str().unwrap(), "--poses", poses.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    (wav, poses)
}

fn map_wav(wav: &Path, poses: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["map", "--wav", wav.to_str().unwrap(), "--poses", poses.to_str().unwrap()];
    args.extend_from_slice(&["--speaker", "0,0", "--out", out.to_str().unwrap()]);
    args.extend_from_slice(extra);
    run(&args)
}

/// Echoes CSV rows as maps column → values.
fn read_csv(p: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(p).unwrap();
    let mut lines = text.lines();
    let head: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    (head, lines.map(|l| l.split(',').map(String::from).collect()).collect())
}

#[test]
fn default_map_wav_corrects_doppler_and_writes_delta_d_rate() {
    let d = tmp("default");
    let sc = scene(&d, 2.0, "");
    let (wav, poses) = synth(&sc, &d);
    let out = d.join("map");
    let o = map_wav(&wav, &poses, &out, &["--scene", sc.to_str().unwrap(), "--cell", "0.02", "--bounds=-20,-8,20,4"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("by doppler"), "{}", stderr(&o));
    let (head, rows) = read_csv(&out.join("echoes.csv"));
    assert_eq!(head.last().unwrap(), "delta_d_rate");
    let col = |h: &str| head.iter().position(|c| c == h).unwrap();
    let (lx, ly, dd, rate) = (col("listener_x"), col("listener_y"), col("delta_d"), col("delta_d_rate"));
    let mut errs = Vec::new();
    for r in &rows {
        let l = (r[lx].parse::<f64>().unwrap(), r[ly].parse::<f64>().unwrap());
        // Exact Δd: image source (0, −12) of the speaker in the wall face y = −6.
        let truth = (l.0.hypot(l.1 + 12.0)) - l.0.hypot(l.1);
        errs.push((r[dd].parse::<f64>().unwrap() - truth).abs());
        let v: f64 = r[rate].parse().unwrap();
        assert!(v.abs() <= 4.0 + 1e-9, "Δḋ {v} beyond twice the listener's speed");
    }
    errs.sort_by(f64::total_cmp);
    assert!(errs.len() > 250, "{} echoes", errs.len());
    assert!(errs[errs.len() / 2] < 0.01 && errs[errs.len() * 9 / 10] < 0.03, "median {}", errs[errs.len() / 2]);
    // The strongest highlight lies on the wall face, within 3 cm (2 cm cells).
    let (_, h) = read_csv(&out.join("highlights.csv"));
    let best = h.iter().max_by(|a, b| a[2].parse::<f64>().unwrap().total_cmp(&b[2].parse::<f64>().unwrap())).unwrap();
    let y: f64 = best[1].parse().unwrap();
    assert!((y + 6.0).abs() <= 0.03, "strongest highlight at y = {y}");
    // The written file maps again through --echoes (the extra column is ignored).
    let again = d.join("again");
    let o = run(&[
        "map",
        "--echoes",
        out.join("echoes.csv").to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
        "--cell",
        "0.02",
        "--bounds=-20,-8,20,4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_to_string(again.join("highlights.csv")).unwrap(),
        std::fs::read_to_string(out.join("highlights.csv")).unwrap()
    );
}

#[test]
fn alternating_pattern_from_the_scene_and_the_methods_that_refuse_it() {
    let d = tmp("updown");
    let sc = scene(&d, 2.0, "pattern = \"updown\"");
    let (wav, poses) = synth(&sc, &d);
    let out = d.join("map");
    let o = map_wav(&wav, &poses, &out, &["--scene", sc.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("16 chirp(s)"), "{}", stderr(&o));
    // gap ranges one sweep direction: refused, naming the method and the pattern.
    let o = map_wav(&wav, &poses, &d.join("gap"), &["--scene", sc.to_str().unwrap(), "--method", "gap"]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("method") && e.contains("updown") && !e.contains("panicked"), "{e}");
    assert!(!d.join("gap").exists());
    // Several echoes per frame need the doppler method's tracks; 0 or more
    // than a frame resolves are refused, naming the field, writing nothing.
    for (extra, says) in [
        (&["--method", "gap", "--echoes-per-frame", "3"][..], "one echo per frame"),
        (&["--echoes-per-frame", "0"][..], "must be in 1..=64"),
        (&["--echoes-per-frame", "65"][..], "must be in 1..=64"),
    ] {
        let out = d.join("k");
        let mut args = vec!["--scene", sc.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = map_wav(&wav, &poses, &out, &args);
        let e = stderr(&o);
        assert!(!o.status.success() && e.contains("echoes per frame") && e.contains(says), "{extra:?}: {e}");
        assert!(!e.contains("panicked") && !out.exists(), "{e}");
    }
    // An unknown pattern is refused by the scene parser, naming it.
    let bad = scene(&d, 2.0, "pattern = \"sideways\"");
    let o = run(&["synth", bad.to_str().unwrap(), "--out", d.join("bad.wav").to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("pattern") || stderr(&o).contains("sideways"), "{}", stderr(&o));
    let o = map_wav(&wav, &poses, &d.join("x"), &["--pattern", "sideways"]);
    assert!(!o.status.success() && stderr(&o).contains("sideways"), "{}", stderr(&o));
}

#[test]
fn hyperbolic_sweeps_synthesize_and_map_with_the_doppler_method() {
    let d = tmp("hyper");
    let sc = scene(&d, 2.0, "");
    let text =
        std::fs::read_to_string(&sc).unwrap().replace("duration = 0.25", "duration = 0.25\nkind = \"hyperbolic\"");
    std::fs::write(&sc, text).unwrap();
    let (wav, poses) = synth(&sc, &d);
    let out = d.join("map");
    let o = map_wav(&wav, &poses, &out, &["--scene", sc.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("16 chirp(s)"), "{}", stderr(&o));
}

/// A listener circling inside an 8 m × 6 m room with a 0.3 m pillar
/// (passing 8 cm from it), synthesized at 20 dB SNR and mapped from the
/// recording with the evidence mapper. Session 22: the pillar was not among
/// the 37 points reported (the strongest 1.85 m off it): the first-order
/// circle model, a fit that never converged at its radius bound, and free
/// space carved by the frames that missed the pillar. Session 23: `synth`
/// rendered a polygon's outer side only, so the room's walls were not in the
/// recording at all; once they were, one echo per frame (the first) gave 0
/// of the 4 walls, and the default now tracks up to 8 echoes per frame.
#[test]
fn a_room_walked_round_a_pillar_is_its_four_walls_and_the_pillar_from_the_recording() {
    let d = tmp("pillar");
    for order in [1, 2] {
        let sc = d.join(format!("scene{order}.toml"));
        std::fs::write(
            &sc,
            format!(
                "[chirp]\nf_start = 10000.0\nf_end = 200.0\nduration = 0.25\n[source]\nposition = [2.0, 2.5]\n\
                 [[obstacles]]\nvertices = [[0.0, 0.0], [8.0, 0.0], [8.0, 6.0], [0.0, 6.0]]\nroughness = 0.0\nabsorption = 0.2\n\
                 [[obstacles]]\ncenter = [5.5, 3.8]\nradius = 0.3\nroughness = 0.0\nabsorption = 0.2\n\
                 [[listeners]]\nstart = [4.0, 1.2]\nspeed = 1.0\nspin_rate = 0.5\n\
                 [synth]\nchirps = 60\ngap_s = 0.25\nsnr_db = 20.0\nreflection_order = {order}\n\
                 [mapping]\nmapper = \"evidence\"\n"
            ),
        )
        .unwrap();
        let (wav, poses) = synth(&sc, &d);
        let out = d.join(format!("map{order}"));
        let o = Command::new(env!("CARGO_BIN_EXE_chirpmap"))
            .args(["map", "--wav", wav.to_str().unwrap(), "--poses", poses.to_str().unwrap()])
            .args(["--speaker", "2,2.5", "--scene", sc.to_str().unwrap(), "--out", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        let (head, rows) = read_csv(&out.join("surfaces.csv"));
        assert_eq!(head[..3], ["kind", "x0", "y0"]);
        // First order: the room and the pillar alone. Second: corner echoes
        // may leave small points, but none inside the room (below).
        assert!(order == 2 || rows.len() <= 6, "{} surfaces: {rows:?}", rows.len());
        let num = |r: &Vec<String>, i: usize| -> f64 { r[i].parse().unwrap() };
        // Each wall (a point on it, its direction) as one of the four strongest
        // surfaces: a line whose ends are within 2 cm of the wall's line and
        // whose direction is within 1°.
        let walls =
            [((0.0, 0.0), (1.0, 0.0)), ((8.0, 0.0), (0.0, 1.0)), ((0.0, 6.0), (1.0, 0.0)), ((0.0, 0.0), (0.0, 1.0))];
        for ((px, py), (dx, dy)) in walls {
            let found = rows.iter().take(4).any(|r| {
                let (x0, y0, x1, y1) = (num(r, 1), num(r, 2), num(r, 3), num(r, 4));
                let off = |x: f64, y: f64| ((x - px) * dy - (y - py) * dx).abs();
                let len = (x1 - x0).hypot(y1 - y0);
                let sin = (((x1 - x0) * dy - (y1 - y0) * dx) / len).abs();
                r[0] == "line" && off(x0, y0) <= 0.02 && off(x1, y1) <= 0.02 && sin <= 1f64.to_radians().sin()
            });
            assert!(found, "order {order}: no line on the wall through ({px}, {py}): {rows:?}");
        }
        let pillar = rows.iter().find(|r| r[0] == "point").expect("a point");
        let off = ((num(pillar, 1) - 5.5).hypot(num(pillar, 2) - 3.8) - 0.3).abs();
        assert!(off <= 0.05, "order {order}: the point is {off:.3} m off the pillar: {rows:?}");
        // Nothing inside the room more than 0.2 m from a true surface (issue 9).
        for r in rows.iter().filter(|r| r[0] == "point") {
            let (x, y) = (num(r, 1), num(r, 2));
            let to_pillar = ((x - 5.5).hypot(y - 3.8) - 0.3).abs();
            let to_wall = x.min(8.0 - x).min(y).min(6.0 - y);
            assert!(to_wall <= 0.2 || to_pillar <= 0.2, "order {order}: a point at ({x}, {y}) in the room: {rows:?}");
        }
    }
    let _ = std::fs::remove_dir_all(&d);
}
