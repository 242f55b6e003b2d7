//! End-to-end tests of `chirpmap synth`, `chirpmap range` and `chirpmap map --wav` (issue 5).
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use chirpmap_audio::{SampleFormat, write_wav};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_chirpmap"))
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("spawn chirpmap")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("chirpmap-cli-audio-{}-{name}", std::process::id()));
    std::fs::remove_dir_all(&d).ok();
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A wall `h_m` behind the speaker, a static mic, short chirps.
fn wall_scene(dir: &Path, h_m: f64) -> PathBuf {
    let p = dir.join("scene.toml");
    std::fs::write(
        &p,
        format!(
            "[chirp]\nduration = 0.25\n[[obstacles]]\nvertices = [[-30.0, -{h_m}], [-30.0, -{h2}], [30.0, -{h2}], [30.0, -{h_m}]]\n\
             [[listeners]]\nstart = [1.5, 0.5]\nspeed = 0.0\n[synth]\nchirps = 6\ngap_s = 0.3\nsnr_db = 20.0\n",
            h2 = h_m + 0.3
        ),
    )
    .unwrap();
    p
}

#[test]
fn synth_then_range_recovers_the_wall_with_every_method() {
    let d = tmp("e2e");
    let scene = wall_scene(&d, 5.0);
    let wav = d.join("rec.wav");
    let o = run(&["synth", scene.to_str().unwrap(), "--out", wav.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = d.join("range");
    let o = run(&[
        "range",
        wav.to_str().unwrap(),
        "--speaker",
        "0,0",
        "--mic",
        "1.5,0.5",
        "--wall-normal",
        "0,-1",
        "--duration",
        "0.25",
        "--compare",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["chirps.csv", "summary.json", "spectrogram.png", "spectrum.png", "compare.csv"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["method"], "gap");
    assert_eq!(s["chirps"], 6);
    let ci = s["delta_d_ci95"].as_array().unwrap();
    assert!(ci[0].as_f64().unwrap() <= ci[1].as_f64().unwrap());
    for m in s["compare"].as_array().unwrap() {
        let w = m["wall_distance_median"].as_f64().unwrap();
        let tol = if m["method"] == "gap" { 0.05 * 5.0 } else { 0.005 };
        assert!((w - 5.0).abs() < tol, "{}: wall {w}", m["method"]);
    }
    let rows = std::fs::read_to_string(out.join("chirps.csv")).unwrap();
    assert!(rows.starts_with("method,index,onset_s,delta_f_hz,delta_d_m,wall_distance_m\n"));
    assert_eq!(rows.lines().count(), 1 + 3 * 6);
}

#[test]
fn map_wav_finds_a_wall_from_a_moving_listener() {
    let d = tmp("mapwav");
    let scene = d.join("scene.toml");
    std::fs::write(
        &scene,
        "[chirp]\nduration = 0.25\n[[obstacles]]\nvertices = [[-30.0, -6.0], [-30.0, -6.3], [30.0, -6.3], [30.0, -6.0]]\n\
         [[listeners]]\nstart = [-6.0, 3.0]\nspeed = 1.0\n[synth]\nchirps = 16\ngap_s = 0.25\nsnr_db = 20.0\n",
    )
    .unwrap();
    let (wav, poses, out) = (d.join("rec.wav"), d.join("poses.csv"), d.join("map"));
    let o =
        run(&["synth", scene.to_str().unwrap(), "--out", wav.to_str().unwrap(), "--poses", poses.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&poses).unwrap().starts_with("t,x,y\n"));
    for method in ["gap", "dechirp"] {
        let o = map_wav(&wav, &poses, &out, &["--method", method, "--scene", scene.to_str().unwrap()]);
        assert!(o.status.success(), "{method}: {}", stderr(&o));
        let h = std::fs::read_to_string(out.join("highlights.csv")).unwrap();
        let best: Vec<f64> = h.lines().nth(1).unwrap().split(',').map(|v| v.parse().unwrap()).collect();
        // The strongest highlight lies on the wall's face y = -6.
        assert!((best[1] + 6.0).abs() < 0.3, "{method}: {h}");
        assert!(out.join("echoes.csv").is_file());
    }
}

fn write_test_wav(path: &Path, fmt: SampleFormat, x: &[f32]) {
    write_wav(path, 48_000, fmt, &[x]).unwrap();
}

fn range_err(wav: &Path, extra: &[&str]) -> (bool, String) {
    let out = wav.with_extension("out");
    let mut args = vec!["range", wav.to_str().unwrap(), "--speaker", "0,0", "--mic", "1,0"];
    if !extra.contains(&"--duration") {
        args.extend_from_slice(&["--duration", "0.25"]);
    }
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", out.to_str().unwrap()]);
    let o = run(&args);
    let err = stderr(&o);
    assert!(!err.contains("panicked"), "{err}");
    if !o.status.success() {
        assert!(!out.exists(), "a failed run left {}", out.display());
    }
    (o.status.success(), err)
}

#[test]
fn bad_inputs_give_clear_errors_without_panics() {
    let d = tmp("bad");
    // Not a WAV file.
    let p = d.join("notes.wav");
    std::fs::write(&p, "hello, I am text").unwrap();
    let (ok, e) = range_err(&p, &[]);
    assert!(!ok && e.contains("not a WAV file"), "{e}");
    // Truncated: a valid file cut in half.
    let scene = wall_scene(&d, 4.0);
    let good = d.join("good.wav");
    assert!(run(&["synth", scene.to_str().unwrap(), "--out", good.to_str().unwrap()]).status.success());
    let bytes = std::fs::read(&good).unwrap();
    let cut = d.join("cut.wav");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let (ok, e) = range_err(&cut, &[]);
    assert!(!ok && e.contains("truncated"), "{e}");
    // Unsupported: 8-bit PCM.
    let mut b8 = bytes[..44].to_vec();
    b8[34] = 8; // bits per sample
    let p8 = d.join("8bit.wav");
    std::fs::write(&p8, &b8).unwrap();
    let (ok, e) = range_err(&p8, &[]);
    assert!(!ok && e.contains("unsupported"), "{e}");
    // Silence.
    let silent = d.join("silent.wav");
    write_test_wav(&silent, SampleFormat::Int(16), &vec![0.0; 48_000]);
    let (ok, e) = range_err(&silent, &[]);
    assert!(!ok && e.contains("silent"), "{e}");
    // A NaN sample (a damaged float file): refused, naming the file and the sample, not read as
    // silence or clipping. Every other sample is a valid recording's.
    let mut damaged = chirpmap_audio::read_wav(&good).unwrap().channels.swap_remove(0);
    damaged[30_000] = f32::NAN;
    let pd = d.join("nan.wav");
    write_test_wav(&pd, SampleFormat::Float32, &damaged);
    let (ok, e) = range_err(&pd, &[]);
    assert!(!ok && e.contains("nan.wav") && e.contains("float sample 30000 of channel 0 is NaN"), "{e}");
    assert!(!e.contains("clipping") && !e.contains("silent"), "{e}");
    // No chirp: noise only.
    let noise: Vec<f32> =
        (0..96_000u32).map(|i| ((i.wrapping_mul(2_654_435_761) >> 16) as f32 / 65_536.0 - 0.5) * 0.2).collect();
    let pn = d.join("noise.wav");
    write_test_wav(&pn, SampleFormat::Float32, &noise);
    let (ok, e) = range_err(&pn, &[]);
    assert!(!ok && e.contains("no chirp"), "{e}");
    // Chirp longer than the file.
    let (ok, e) = range_err(&good, &["--duration", "30"]);
    assert!(!ok && e.contains("longer than the recording"), "{e}");
    // Speaker equal to the mic.
    let o = run(&[
        "range",
        good.to_str().unwrap(),
        "--speaker",
        "1,2",
        "--mic",
        "1,2",
        "--out",
        d.join("x").to_str().unwrap(),
    ]);
    assert!(!o.status.success() && stderr(&o).contains("same point"), "{}", stderr(&o));
    assert!(!d.join("x").exists());
    // Huge values print as a person writes them, not as 300 digits.
    for (flag, want) in [
        ("--speed-of-sound", "got 1e300"),
        ("--max-delta-d", "1e300 m is longer than"),
        ("--ringing-ms", "got 1e300 ms"),
    ] {
        let mut args = vec![flag, "1e300"];
        if flag == "--ringing-ms" {
            args.push("--echoes");
        }
        let (ok, e) = range_err(&good, &args);
        assert!(!ok && e.contains(want) && e.len() < 200, "{flag}: {e}");
    }
    // Missing channel.
    let (ok, e) = range_err(&good, &["--channel", "3"]);
    assert!(!ok && e.contains("channel 3"), "{e}");
    // Clipping: a warning with the count, and the run still succeeds.
    let rec = chirpmap_audio::read_wav(&good).unwrap();
    let loud: Vec<f32> = rec.channels[0].iter().map(|v| (v * 4.0).clamp(-1.0, 1.0)).collect();
    let n_clip = loud.iter().filter(|v| v.abs() >= 1.0).count();
    assert!(n_clip > 0);
    let pc = d.join("clip.wav");
    write_test_wav(&pc, SampleFormat::Int(16), &loud);
    let n_file = chirpmap_audio::read_wav(&pc).unwrap().clipped_samples;
    let (ok, e) = range_err(&pc, &[]);
    assert!(ok, "{e}");
    assert!(e.contains(&format!("{n_file} sample(s) at full scale")), "{e}");
}

/// Synthesizes `scene_text` into DIR/rec.wav (and DIR/poses.csv).
fn synth_in(d: &Path, scene_text: &str) -> (PathBuf, PathBuf, PathBuf) {
    let scene = d.join("scene.toml");
    std::fs::write(&scene, scene_text).unwrap();
    let (wav, poses) = (d.join("rec.wav"), d.join("poses.csv"));
    let o =
        run(&["synth", scene.to_str().unwrap(), "--out", wav.to_str().unwrap(), "--poses", poses.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    (scene, wav, poses)
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn max_delta_d_beyond_a_chirp_is_rejected_naming_the_flag() {
    let d = tmp("maxdd");
    let good = d.join("good.wav");
    let scene = wall_scene(&d, 4.0);
    assert!(run(&["synth", scene.to_str().unwrap(), "--out", good.to_str().unwrap()]).status.success());
    // Used to abort allocating terabytes (matched), or to range the next
    // chirp's direct sound as a 686 m echo.
    for extra in [&["--max-delta-d", "1e9", "--method", "matched"][..], &["--max-delta-d", "2000"][..]] {
        let (ok, e) = range_err(&good, extra);
        assert!(!ok && e.contains("--max-delta-d") && e.contains("a·T"), "{e}");
    }
    // Within a·T but longer than the chirp spacing allows: chirps 0.35 s
    // apart, echo window T + 60 m / a = 0.425 s.
    std::fs::write(&scene, std::fs::read_to_string(&scene).unwrap().replace("gap_s = 0.3", "gap_s = 0.1")).unwrap();
    let close = d.join("close.wav");
    assert!(run(&["synth", scene.to_str().unwrap(), "--out", close.to_str().unwrap()]).status.success());
    let (ok, e) = range_err(&close, &["--max-delta-d", "60"]);
    assert!(!ok && e.contains("--max-delta-d") && e.contains("apart"), "{e}");
    let (ok, e) = range_err(&close, &["--max-delta-d", "20"]);
    assert!(ok, "{e}");
}

#[test]
fn a_far_echo_is_not_counted_as_another_chirp() {
    let d = tmp("farecho");
    // A wall 40 m away: the echo comes 0.23 s after the direct sound,
    // beyond 0.9 T for T = 0.25 s.
    let (_, wav, _) = synth_in(
        &d,
        "[chirp]\nduration = 0.25\n[[obstacles]]\nvertices = [[-45.0, -40.0], [-45.0, -40.3], [45.0, -40.3], [45.0, -40.0]]\n\
         [[listeners]]\nstart = [1.5, 0.5]\nspeed = 0.0\n[synth]\nchirps = 10\ngap_s = 0.3\nsnr_db = 20.0\n",
    );
    let out = d.join("range");
    let o = run(&[
        "range",
        wav.to_str().unwrap(),
        "--speaker",
        "0,0",
        "--mic",
        "1.5,0.5",
        "--duration",
        "0.25",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(summary(&out)["chirps"], 10);
}

#[test]
fn wrong_chirp_parameters_find_no_chirp() {
    let d = tmp("wrongchirp");
    let scene = wall_scene(&d, 4.0);
    let good = d.join("good.wav");
    assert!(run(&["synth", scene.to_str().unwrap(), "--out", good.to_str().unwrap()]).status.success());
    // The file holds 0.25 s chirps 10 → 0.2 kHz.
    for extra in [&["--duration", "0.125"][..], &["--f-start", "3000"][..], &["--duration", "0.5"][..]] {
        let (ok, e) = range_err(&good, extra);
        assert!(!ok && e.contains("no chirp found"), "{extra:?}: {e}");
    }
    // A template shorter than 64 samples.
    let (ok, e) = range_err(&good, &["--duration", "0.00001"]);
    assert!(!ok && e.contains("at least 64 samples") && !e.contains("longer than the recording"), "{e}");
    // Implausible speed of sound.
    let (ok, e) = range_err(&good, &["--speed-of-sound", "5"]);
    assert!(!ok && e.contains("--speed-of-sound"), "{e}");
}

#[test]
fn synth_leaves_no_wav_when_the_poses_cannot_be_written() {
    let d = tmp("synthstage");
    let scene = wall_scene(&d, 4.0);
    let (wav, poses) = (d.join("s1.wav"), d.join("isdir.csv"));
    std::fs::create_dir_all(&poses).unwrap();
    let o =
        run(&["synth", scene.to_str().unwrap(), "--out", wav.to_str().unwrap(), "--poses", poses.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(!wav.exists(), "s1.wav left behind: {}", stderr(&o));
    let left: Vec<_> = std::fs::read_dir(&d).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 2, "{left:?}"); // scene.toml and isdir.csv only
    // A bad [synth] value names the scene file.
    let bad = d.join("bad.toml");
    std::fs::write(&bad, std::fs::read_to_string(&scene).unwrap().replace("chirps = 6", "chirps = 0")).unwrap();
    let o = run(&["synth", bad.to_str().unwrap(), "--out", wav.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("bad.toml"), "{}", stderr(&o));
}

#[test]
fn errors_name_the_file_once() {
    let d = tmp("names");
    // 8 kHz recording: the 10 kHz sweep is above its Nyquist frequency.
    let p8 = d.join("eight.wav");
    write_wav(&p8, 8_000, SampleFormat::Int(16), &[&vec![0.1f32; 16_000][..]]).unwrap();
    let (ok, e) = range_err(&p8, &[]);
    assert!(!ok && e.contains("Nyquist") && e.contains("eight.wav"), "{e}");
    // A missing file: the OS error once.
    let (ok, e) = range_err(&d.join("missing.wav"), &[]);
    assert!(!ok && e.contains("missing.wav"), "{e}");
    assert_eq!(e.matches("No such file").count(), 1, "{e}");
}

#[test]
fn range_output_has_no_stale_compare_table() {
    let d = tmp("stale");
    let scene = wall_scene(&d, 4.0);
    let good = d.join("good.wav");
    assert!(run(&["synth", scene.to_str().unwrap(), "--out", good.to_str().unwrap()]).status.success());
    let (ok, e) = range_err(&good, &["--compare"]);
    assert!(ok, "{e}");
    let out = good.with_extension("out");
    assert!(out.join("compare.csv").is_file());
    let (ok, e) = range_err(&good, &[]);
    assert!(ok, "{e}");
    assert!(!out.join("compare.csv").exists(), "stale compare.csv kept");
}

/// `chirpmap map --wav` with the moving-wall example's speaker and chirp, plus `extra` flags.
fn map_wav(wav: &Path, poses: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "map",
        "--wav",
        wav.to_str().unwrap(),
        "--poses",
        poses.to_str().unwrap(),
        "--speaker",
        "0,0",
        "--duration",
        "0.25",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    run(&args)
}

#[test]
fn map_wav_poses_errors_are_specific() {
    let d = tmp("posesbad");
    let (_, wav, poses) = synth_in(
        &d,
        "[chirp]\nduration = 0.25\n[[obstacles]]\nvertices = [[-30.0, -6.0], [-30.0, -6.3], [30.0, -6.3], [30.0, -6.0]]\n\
         [[listeners]]\nstart = [-6.0, 3.0]\nspeed = 1.0\n[synth]\nchirps = 4\ngap_s = 0.25\nsnr_db = 20.0\n",
    );
    let out = d.join("map");
    // Poses from another time span.
    let shifted = d.join("late.csv");
    let mut s = String::from("t,x,y\n");
    for k in 0..100 {
        s.push_str(&format!("{},{},3\n", 100.0 + f64::from(k) * 0.01, -6.0 + f64::from(k) * 0.01));
    }
    std::fs::write(&shifted, s).unwrap();
    let o = map_wav(&wav, &shifted, &out, &[]);
    let e = stderr(&o);
    assert!(
        !o.status.success()
            && e.contains("late.csv")
            && e.contains("100")
            && e.contains("do not overlap")
            && e.contains("rec.wav"),
        "{e}"
    );
    // A negative or fractional listener number is rejected, not read as 0.
    let text = std::fs::read_to_string(&poses).unwrap();
    for bad in ["-1", "0.5"] {
        let p = d.join("listener.csv");
        let mut s = String::from("t,x,y,listener\n");
        for line in text.lines().skip(1) {
            s.push_str(&format!("{line},{bad}\n"));
        }
        std::fs::write(&p, s).unwrap();
        let o = map_wav(&wav, &p, &out, &[]);
        let e = stderr(&o);
        assert!(!o.status.success() && e.contains("listener.csv:2") && e.contains("column listener"), "{e}");
    }
    // A bad number names its column.
    let p = d.join("nan.csv");
    std::fs::write(&p, "t,x,y\n0,abc,1\n").unwrap();
    let o = map_wav(&wav, &p, &out, &[]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("nan.csv:2") && e.contains("column x"), "{e}");
}
