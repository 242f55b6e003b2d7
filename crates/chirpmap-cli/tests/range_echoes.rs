//! End-to-end tests of `chirpmap range --echoes` (issue 10): synthetic box
//! rooms rendered here by image sources (exact delays, a loudspeaker
//! response with a ringing tail), and a real dEchorate impulse response
//! (crates/chirpmap-audio/tests/data/dechorate/README.md).
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use chirpmap_audio::{SampleFormat, read_wav, write_wav};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const FS: f64 = 48_000.0;
const A: f64 = 343.0;

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_chirpmap")).args(args).output().expect("spawn chirpmap")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("chirpmap-range-echoes-{}-{name}", std::process::id()));
    std::fs::remove_dir_all(&d).ok();
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn ok(o: &Output) {
    assert!(o.status.success(), "stderr: {}", String::from_utf8_lossy(&o.stderr));
}

/// Deterministic standard normal numbers (xorshift64* and Box–Muller).
struct Gauss(u64);
impl Gauss {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn next(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Linear,
    Exponential,
}

/// The emitted sweep at `t` (s) after its start: 10 → 0.2 kHz over `t_s`,
/// 5 ms raised-cosine ends (what `synth` renders).
fn sweep(kind: Kind, t: f64, t_s: f64) -> f64 {
    if !(0.0..=t_s).contains(&t) {
        return 0.0;
    }
    let (f0, f1) = (10_000.0f64, 200.0f64);
    let ph = match kind {
        Kind::Linear => f0 * t + 0.5 * (f1 - f0) / t_s * t * t,
        Kind::Exponential => {
            let k = (f1 / f0).ln() / t_s;
            f0 * ((k * t).exp() - 1.0) / k
        }
    };
    let edge = t.min(t_s - t);
    let g = if edge >= 0.005 { 1.0 } else { 0.5 - 0.5 * (std::f64::consts::PI * edge / 0.005).cos() };
    g * (std::f64::consts::TAU * (ph - ph.floor())).sin()
}

/// The loudspeaker: an impulse followed by a decaying 2.5 kHz ring
/// (−9 dB at its onset, time constant 0.6 ms, 3 ms long).
fn speaker_response() -> Vec<f64> {
    (0..(0.003 * FS) as usize)
        .map(|n| {
            let t = n as f64 / FS;
            if n == 0 { 1.0 } else { 0.35 * (-t / 0.0006).exp() * (std::f64::consts::TAU * 2500.0 * t).sin() }
        })
        .collect()
}

/// A chirp train through `paths` (length m, gain) and the loudspeaker,
/// with white noise `snr_db` below the signal's power while it sounds.
fn render(kind: Kind, paths: &[(f64, f64)], t_s: f64, chirps: usize, snr_db: f64, seed: u64) -> Vec<f32> {
    let (start, gap) = (0.2, 0.3);
    let n = ((start + chirps as f64 * (t_s + gap) + 0.3) * FS) as usize;
    let mut y = vec![0.0f64; n];
    for k in 0..chirps {
        let t0 = start + k as f64 * (t_s + gap);
        for &(r, g) in paths {
            let tau = t0 + r / A;
            let lo = (tau * FS).floor() as usize;
            for (i, v) in y.iter_mut().enumerate().skip(lo).take((t_s * FS) as usize + 2) {
                *v += g * sweep(kind, i as f64 / FS - tau, t_s);
            }
        }
    }
    let h = speaker_response();
    let mut z = vec![0.0f64; n];
    for (i, v) in y.iter().enumerate().filter(|(_, v)| **v != 0.0) {
        for (j, hj) in h.iter().enumerate() {
            if let Some(o) = z.get_mut(i + j) {
                *o += v * hj;
            }
        }
    }
    let on: Vec<f64> = z.iter().copied().filter(|v| v.abs() > 1e-9).collect();
    let power = on.iter().map(|v| v * v).sum::<f64>() / on.len() as f64;
    let sigma = (power / 10f64.powf(snr_db / 10.0)).sqrt();
    let mut g = Gauss(seed);
    let out: Vec<f64> = z.iter().map(|v| v + sigma * g.next()).collect();
    let peak = out.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    out.iter().map(|v| (0.5 * v / peak) as f32).collect()
}

/// Speaker and mic in the box [0, 6] × [0, 5] × [0, 3] m and the six
/// first-order image paths (plane, length).
const SPK: [f64; 3] = [2.0, 1.6, 1.3];
const MIC: [f64; 3] = [3.1, 2.2, 1.0];
const ROOM: [f64; 3] = [6.0, 5.0, 3.0];

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn box_paths(spk: [f64; 3], mic: [f64; 3]) -> (f64, Vec<(&'static str, f64)>) {
    let mut out = Vec::new();
    for (axis, (lo, hi)) in [("x", 0), ("y", 1), ("z", 2)].iter().map(|(n, k)| (*k, (format!("{n}0"), format!("{n}L"))))
    {
        for (name, wall) in [(lo, 0.0), (hi, ROOM[axis])] {
            let mut img = spk;
            img[axis] = 2.0 * wall - spk[axis];
            out.push((Box::leak(name.into_boxed_str()) as &'static str, dist(img, mic)));
        }
    }
    (dist(spk, mic), out)
}

fn room_wav(dir: &Path, kind: Kind, spk: [f64; 3], mic: [f64; 3], seed: u64) -> (PathBuf, Vec<(&'static str, f64)>) {
    let (d, planes) = box_paths(spk, mic);
    let mut paths = vec![(d, 1.0 / d)];
    paths.extend(planes.iter().map(|&(_, r)| (r, 0.7 / r)));
    let y = render(kind, &paths, 0.25, 4, 30.0, seed);
    let wav = dir.join("room.wav");
    write_wav(&wav, 48_000, SampleFormat::Float32, &[&y]).unwrap();
    (wav, planes.iter().map(|&(n, r)| (n, r - d)).collect())
}

/// Rows of echoes.csv as (chirp, path_delta_m, delta_d, weight, plane).
fn echoes(dir: &Path) -> Vec<(usize, f64, f64, f64, String)> {
    let text = std::fs::read_to_string(dir.join("echoes.csv")).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(
        head,
        [
            "source_x",
            "source_y",
            "listener_x",
            "listener_y",
            "delta_d",
            "weight",
            "t",
            "listener",
            "chirp",
            "rank",
            "path_delta_m",
            "strength_db",
            "plane"
        ]
    );
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[8].parse().unwrap(), f[10].parse().unwrap(), f[4].parse().unwrap(), f[5].parse().unwrap(), f[12].into())
        })
        .collect()
}

fn pt(p: [f64; 3]) -> String {
    format!("{},{},{}", p[0], p[1], p[2])
}

/// Every plane's path difference within `tol` m in every chirp.
fn assert_planes(rows: &[(usize, f64, f64, f64, String)], truth: &[(&str, f64)], chirps: usize, tol: f64) {
    for &(name, dd) in truth {
        for c in 0..chirps {
            let best = rows.iter().filter(|r| r.0 == c).map(|r| (r.1 - dd).abs()).fold(f64::INFINITY, f64::min);
            assert!(best <= tol, "plane {name} (Δd {dd:.4} m), chirp {c}: nearest echo {best:.4} m off");
        }
    }
}

#[test]
fn box_room_all_six_planes_within_a_centimetre_and_floor_ceiling_labelled() {
    let dir = tmp("box");
    let (wav, truth) = room_wav(&dir, Kind::Linear, SPK, MIC, 7);
    let out = dir.join("out");
    let o = run(&[
        "range",
        wav.to_str().unwrap(),
        "--speaker",
        &pt(SPK),
        "--mic",
        &pt(MIC),
        "--floor-z",
        "0",
        "--ceiling-z",
        "3",
        "--duration",
        "0.25",
        "--speed-of-sound",
        "343",
        "--max-delta-d",
        "8",
        "--echoes",
        "10",
        "--out",
        out.to_str().unwrap(),
    ]);
    ok(&o);
    let rows = echoes(&out);
    assert_planes(&rows, &truth, 4, 0.01);
    // Nothing from the loudspeaker's ringing (Δd 0.69 m and below), and every
    // echo within 20 dB of the direct sound is one of the six planes.
    assert!(rows.iter().all(|r| r.1 > 0.69), "{rows:?}");
    let text = std::fs::read_to_string(out.join("echoes.csv")).unwrap();
    for l in text.lines().skip(1) {
        let f: Vec<f64> = l.split(',').take(12).map(|v| v.parse().unwrap()).collect();
        if f[11] > -20.0 {
            assert!(truth.iter().any(|t| (f[10] - t.1).abs() < 0.01), "strong false echo: {l}");
        }
    }
    // Floor and ceiling labelled and out of the map; walls in it, with the
    // horizontal Δd of a vertical reflector.
    let (d, dz) = (dist(SPK, MIC), SPK[2] - MIC[2]);
    for r in &rows {
        let near = |n: &str| truth.iter().find(|t| t.0 == n).is_some_and(|t| (r.1 - t.1).abs() < 0.01);
        if near("z0") {
            assert_eq!((r.4.as_str(), r.3), ("floor", 0.0));
        } else if near("zL") {
            assert_eq!((r.4.as_str(), r.3), ("ceiling", 0.0));
        } else if ["x0", "xL", "y0", "yL"].iter().any(|n| near(n)) {
            assert_eq!((r.4.as_str(), r.3), ("", 1.0));
            let h = ((d + r.1).powi(2) - dz * dz).sqrt() - (d * d - dz * dz).sqrt();
            assert!((r.2 - h).abs() < 1e-5, "{r:?} vs {h}");
        }
    }
    for f in ["echogram.csv", "echogram.png", "chirps.csv", "summary.json"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // The echoes map directly.
    let m =
        run(&["map", "--echoes", out.join("echoes.csv").to_str().unwrap(), "--out", dir.join("map").to_str().unwrap()]);
    ok(&m);
}

#[test]
fn exponential_sweep_box_room_by_farina_deconvolution() {
    let dir = tmp("exp");
    let (wav, truth) = room_wav(&dir, Kind::Exponential, SPK, MIC, 11);
    let out = dir.join("out");
    ok(&run(&[
        "range",
        wav.to_str().unwrap(),
        "--sweep",
        "exponential",
        "--speaker",
        &pt(SPK),
        "--mic",
        &pt(MIC),
        "--duration",
        "0.25",
        "--speed-of-sound",
        "343",
        "--max-delta-d",
        "8",
        "--echoes",
        "10",
        "--out",
        out.to_str().unwrap(),
    ]));
    assert_planes(&echoes(&out), &truth, 4, 0.01);
}

#[test]
fn calibration_reveals_an_echo_inside_the_ringing() {
    // Speaker and mic low over the floor: its echo at Δd 0.48 m arrives
    // within the 2 ms ringing window (0.69 m).
    let (spk, mic) = ([2.0, 1.6, 0.6], [3.25, 1.6, 0.6]);
    let dir = tmp("cal");
    let (wav, truth) = room_wav(&dir, Kind::Linear, spk, mic, 5);
    let floor = truth.iter().find(|t| t.0 == "z0").unwrap().1;
    assert!((0.45..0.6).contains(&floor), "{floor}");
    // The calibration: the direct sound alone (no room).
    let cal = dir.join("cal.wav");
    let c = render(Kind::Linear, &[(0.5, 2.0)], 0.25, 4, 40.0, 3);
    write_wav(&cal, 48_000, SampleFormat::Float32, &[&c]).unwrap();
    let common = ["--speaker", "2,1.6", "--mic", "3.25,1.6", "--duration", "0.25", "--speed-of-sound", "343"];
    let (own, calibrated) = (dir.join("own"), dir.join("calibrated"));
    let args = |out: &Path, cal: Option<&Path>| {
        let mut v: Vec<String> = vec!["range".into(), wav.to_str().unwrap().into()];
        v.extend(common.iter().map(|s| s.to_string()));
        v.extend(["--max-delta-d", "8", "--echoes", "10", "--out", out.to_str().unwrap()].map(String::from));
        if let Some(c) = cal {
            v.extend(["--calibration".to_string(), c.to_str().unwrap().to_string()]);
        }
        v
    };
    let a1 = args(&own, None);
    ok(&run(&a1.iter().map(String::as_str).collect::<Vec<_>>()));
    let a2 = args(&calibrated, Some(&cal));
    ok(&run(&a2.iter().map(String::as_str).collect::<Vec<_>>()));
    let near = |rows: &[(usize, f64, f64, f64, String)]| rows.iter().filter(|r| (r.1 - floor).abs() < 0.01).count();
    assert_eq!(near(&echoes(&own)), 0, "within the ringing window nothing is reported");
    let cal_rows = echoes(&calibrated);
    assert_eq!(near(&cal_rows), 4, "{cal_rows:?}");
    // Still no false echo from the ringing itself.
    assert!(cal_rows.iter().all(|r| r.1 > 0.4), "{cal_rows:?}");
}

fn dechorate(file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../chirpmap-audio/tests/data/dechorate").join(file)
}

/// (positions, annotated Δd of `zL` and `x0`) of one row of the dEchorate index.
fn dechorate_row(file: &str) -> ([f64; 3], [f64; 3], f64, f64) {
    let text = std::fs::read_to_string(dechorate("rirs_index.csv")).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let row: Vec<&str> = lines.find(|l| l.starts_with(file)).unwrap().split(',').collect();
    let v = |n: &str| row[head.iter().position(|h| *h == n).unwrap()].parse::<f64>().unwrap();
    ([v("src_x"), v("src_y"), v("src_z")], [v("mic_x"), v("mic_y"), v("mic_z")], v("dd_annot_zL"), v("dd_annot_x0"))
}

#[test]
fn real_dechorate_rir_ceiling_and_wall_within_three_centimetres() {
    let file = "rirs/cfg011100_src1_mic01.wav";
    let (spk, mic, zl, x0) = dechorate_row(file);
    let rec = read_wav(&dechorate(file)).unwrap();
    let h = &rec.channels[0];
    // The paper's chirp (linear 10 → 0.2 kHz, here 0.5 s) three times, 30 dB SNR.
    let (t_s, a) = (0.5, 345.844);
    let (start, gap, chirps) = (0.3, 0.5, 3usize);
    let n = ((start + chirps as f64 * (t_s + gap) + 0.5) * FS) as usize;
    let mut x = vec![0.0f64; n];
    for k in 0..chirps {
        let i0 = ((start + k as f64 * (t_s + gap)) * FS) as usize;
        for i in 0..(t_s * FS) as usize {
            x[i0 + i] = sweep(Kind::Linear, i as f64 / FS, t_s);
        }
    }
    // Direct convolution over the RIR's first 0.1 s (Δd up to 34 m).
    let taps: Vec<(usize, f64)> =
        h.iter().take(4800).enumerate().filter(|(_, v)| **v != 0.0).map(|(j, v)| (j, f64::from(*v))).collect();
    let mut y = vec![0.0f64; n];
    for (i, xi) in x.iter().enumerate().filter(|(_, v)| **v != 0.0) {
        for &(j, hj) in &taps {
            if let Some(o) = y.get_mut(i + j) {
                *o += xi * hj;
            }
        }
    }
    let on: Vec<f64> = y.iter().copied().filter(|v| v.abs() > 1e-12).collect();
    let sigma = (on.iter().map(|v| v * v).sum::<f64>() / on.len() as f64 / 1e3).sqrt();
    let mut g = Gauss(42);
    let peak = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let y: Vec<f32> = y.iter().map(|v| (0.5 * (v + sigma * g.next()) / peak) as f32).collect();
    let dir = tmp("dechorate");
    let wav = dir.join("rec.wav");
    write_wav(&wav, 48_000, SampleFormat::Float32, &[&y]).unwrap();
    let out = dir.join("out");
    let a_s = a.to_string();
    let geom = ["--speaker", &pt(spk), "--mic", &pt(mic), "--floor-z", "0", "--ceiling-z", "2.355"];
    let mut args = vec!["range", wav.to_str().unwrap(), "--duration", "0.5", "--speed-of-sound", &a_s];
    args.extend(geom);
    args.extend(["--max-delta-d", "8", "--echoes", "10", "--method", "matched", "--out", out.to_str().unwrap()]);
    ok(&run(&args));
    let rows = echoes(&out);
    for c in 0..chirps {
        let mine: Vec<_> = rows.iter().filter(|r| r.0 == c).collect();
        let ceil = mine.iter().find(|r| r.4 == "ceiling").unwrap();
        assert!((ceil.1 - zl).abs() <= 0.03, "ceiling {} vs annotated {zl}", ceil.1);
        assert!(mine.iter().any(|r| (r.1 - x0).abs() <= 0.03 && r.3 == 1.0), "wall x0 {x0}: {mine:?}");
        assert!(mine.iter().all(|r| r.1 >= 0.45), "{mine:?}");
    }
    // The same RIR given directly.
    let out2 = dir.join("rir");
    let mut args: Vec<String> =
        vec!["range".into(), dechorate(file).to_str().unwrap().to_owned(), "--input".into(), "rir".into()];
    args.extend(["--speed-of-sound", &a_s].map(String::from));
    args.extend(geom.map(String::from));
    args.extend(["--max-delta-d", "8", "--echoes", "10", "--out", out2.to_str().unwrap()].map(String::from));
    ok(&run(&args.iter().map(String::as_str).collect::<Vec<_>>()));
    let rows = echoes(&out2);
    assert!(rows.iter().any(|r| r.4 == "ceiling" && (r.1 - zl).abs() <= 0.03), "{rows:?}");
    assert!(!out2.join("chirps.csv").exists());
}

#[test]
fn refusals_name_the_flag() {
    let dir = tmp("refuse");
    let (wav, _) = room_wav(&dir, Kind::Linear, SPK, MIC, 1);
    let w = wav.to_str().unwrap();
    let o = dir.join("o");
    let o = o.to_str().unwrap();
    let base = ["range", w, "--duration", "0.25", "--out", o];
    let cases: [(&[&str], &str); 6] = [
        (&["--speaker", "0,0", "--mic", "1,0", "--echoes", "--method", "gap"], "--method matched"),
        (&["--speaker", "0,0", "--mic", "1,0", "--input", "rir"], "needs --echoes"),
        (&["--speaker", "0,0,1", "--mic", "1,0", "--echoes"], "heights for both"),
        (&["--speaker", "0,0", "--mic", "1,0", "--echoes", "--floor-z", "0"], "--floor-z"),
        (&["--speaker", "0,0,1", "--mic", "1,0,1", "--echoes", "--floor-z", "1.5"], "--floor-z"),
        (&["--speaker", "0,0", "--mic", "1,0", "--echoes", "--ringing-ms", "-1"], "--ringing-ms"),
    ];
    for (extra, want) in cases {
        let mut a: Vec<&str> = base.to_vec();
        a.extend(extra);
        let r = run(&a);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && err.contains(want), "{extra:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{err}");
    }
}
