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
        let o = run(&[
            "map",
            "--wav",
            wav.to_str().unwrap(),
            "--poses",
            poses.to_str().unwrap(),
            "--speaker",
            "0,0",
            "--duration",
            "0.25",
            "--method",
            method,
            "--scene",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
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
