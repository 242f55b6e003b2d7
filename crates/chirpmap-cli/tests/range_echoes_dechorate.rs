//! `range --echoes` on all ten real dEchorate RIRs
//! (crates/chirpmap-audio/tests/data/dechorate/README.md), each convolved
//! with three linear 10 → 0.2 kHz chirps of 0.5 s at 30 dB SNR. The truth is
//! the dataset's manual echo annotation (`dd_annot_*`), not our code.
//! Regression floor of EXPERIMENTS.md's real-room results (measured there
//! with ten 1 s chirps): the first vertical-plane echo (floor or ceiling)
//! within 3 cm in every recording, the ceiling in every `cfg011100` one,
//! the nearest side wall in at least half, no echo below Δd 0.45 m. And the
//! static-array workflow end to end: `range --input rir --echoes` on the
//! five `cfg011100` microphones, concatenated, mapped by the evidence mapper.
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use chirpmap_audio::{SampleFormat, read_wav, write_wav};
use std::path::{Path, PathBuf};
use std::process::Command;

const FS: f64 = 48_000.0;
const A: f64 = 345.844;

fn data(file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../chirpmap-audio/tests/data/dechorate").join(file)
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

fn chirp(t: f64, t_s: f64) -> f64 {
    let ph = 10_000.0 * t + 0.5 * (200.0 - 10_000.0) / t_s * t * t;
    let edge = t.min(t_s - t);
    let g = if edge >= 0.005 { 1.0 } else { 0.5 - 0.5 * (std::f64::consts::PI * edge / 0.005).cos() };
    g * (std::f64::consts::TAU * (ph - ph.floor())).sin()
}

fn recording(h: &[f32], seed: u64) -> Vec<f32> {
    let (t_s, start, gap, chirps) = (0.5, 0.3, 0.5, 3usize);
    let n = ((start + chirps as f64 * (t_s + gap) + 0.3) * FS) as usize;
    let m = (t_s * FS) as usize;
    let mut x = vec![0.0f64; n];
    for k in 0..chirps {
        let i0 = ((start + k as f64 * (t_s + gap)) * FS) as usize;
        for i in 0..m {
            x[i0 + i] = chirp(i as f64 / FS, t_s);
        }
    }
    // The first 30 ms of the RIR: the direct sound and every path up to Δd 8 m.
    let taps: Vec<(usize, f64)> = h.iter().take(1440).enumerate().map(|(j, v)| (j, f64::from(*v))).collect();
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
    let mut g = Gauss(seed);
    let y: Vec<f64> = y.iter().map(|v| v + sigma * g.next()).collect();
    let peak = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    y.iter().map(|v| (0.5 * v / peak) as f32).collect()
}

#[test]
fn ten_real_rirs_floor_or_ceiling_walls_and_no_ringing() {
    let text = std::fs::read_to_string(data("rirs_index.csv")).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let dir = std::env::temp_dir().join(format!("chirpmap-range-echoes-dechorate-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).unwrap();
    let (mut vertical, mut ceiling_011100, mut wall, mut low, mut total) = (0, 0, 0, 0, 0);
    for (i, line) in lines.enumerate() {
        let row: Vec<&str> = line.split(',').collect();
        let s = |n: &str| row[head.iter().position(|h| *h == n).unwrap()];
        let v = |n: &str| s(n).parse::<f64>().unwrap();
        let rec = read_wav(&data(s("file"))).unwrap();
        let wav = dir.join(format!("{i}.wav"));
        write_wav(&wav, 48_000, SampleFormat::Float32, &[&recording(&rec.channels[0], 100 + i as u64)]).unwrap();
        let out = dir.join(format!("out{i}"));
        let (spk, mic) = (
            format!("{},{},{}", s("src_x"), s("src_y"), s("src_z")),
            format!("{},{},{}", s("mic_x"), s("mic_y"), s("mic_z")),
        );
        let a = A.to_string();
        let o = Command::new(env!("CARGO_BIN_EXE_chirpmap"))
            .args(["range", wav.to_str().unwrap(), "--duration", "0.5", "--speed-of-sound", &a])
            .args(["--speaker", &spk, "--mic", &mic, "--max-delta-d", "8", "--echoes", "10"])
            .args(["--out", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let csv = std::fs::read_to_string(out.join("echoes.csv")).unwrap();
        let mut per: Vec<Vec<f64>> = vec![Vec::new(); 3];
        for l in csv.lines().skip(1) {
            let f: Vec<&str> = l.split(',').collect();
            let c: usize = f[8].parse().unwrap();
            let pd: f64 = f[10].parse().unwrap();
            per[c].push(pd);
            total += 1;
            low += usize::from(pd < 0.45);
        }
        // Found: within 3 cm in at least two of the three chirps.
        let found = |plane: &str| {
            let dd = v(&format!("dd_annot_{plane}"));
            per.iter().filter(|ch| ch.iter().any(|p| (p - dd).abs() <= 0.03)).count() >= 2
        };
        vertical += usize::from(found("zL") || found("z0"));
        if s("config") == "011100" {
            ceiling_011100 += usize::from(found("zL"));
        }
        let side = ["x0", "xL", "y0", "yL"]
            .into_iter()
            .min_by(|a, b| v(&format!("dd_annot_{a}")).total_cmp(&v(&format!("dd_annot_{b}"))))
            .unwrap();
        wall += usize::from(found(side));
    }
    println!(
        "floor or ceiling {vertical}/10, ceiling (011100) {ceiling_011100}/5, nearest wall {wall}/10, {low}/{total} below 0.45 m"
    );
    assert_eq!(vertical, 10);
    assert_eq!(ceiling_011100, 5);
    assert!(wall >= 5, "nearest side wall in {wall}/10");
    assert_eq!(low, 0);
    assert!(total >= 250, "{total} echoes");
}

/// The real-room workflow the docs describe: `range --input rir --echoes`
/// on each microphone of the `cfg011100` array, the files concatenated in
/// the array's order (every row t = 0 of listener 0), then `map` with the
/// evidence mapper and a file of `[mapping]` settings only. Each row's
/// microphone position is its own pose, so the array's five positions give
/// runs of tangent ellipses: lines, every one mirror-ambiguous (a linear
/// array), one of them on the wall x = 0. Before, the five microphones were
/// one measurement and the map had no surface; and the settings file was
/// scored against the default scene's three random obstacles.
#[test]
fn a_static_array_maps_walls_from_concatenated_range_output() {
    let text = std::fs::read_to_string(data("rirs_index.csv")).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let tmp = tempfile::tempdir().unwrap();
    let mut all = String::new();
    for line in lines {
        let row: Vec<&str> = line.split(',').collect();
        let s = |n: &str| row[head.iter().position(|h| *h == n).unwrap()];
        if s("config") != "011100" {
            continue;
        }
        let out = tmp.path().join(format!("mic{}", s("mic_id")));
        let (spk, mic) = (
            format!("{},{},{}", s("src_x"), s("src_y"), s("src_z")),
            format!("{},{},{}", s("mic_x"), s("mic_y"), s("mic_z")),
        );
        let o = Command::new(env!("CARGO_BIN_EXE_chirpmap"))
            .args(["--no-progress", "range", data(s("file")).to_str().unwrap(), "--input", "rir"])
            .args(["--speed-of-sound", &A.to_string(), "--max-delta-d", "8", "--speaker", &spk, "--mic", &mic])
            .args(["--floor-z", "0", "--ceiling-z", "2.355", "--echoes", "--out", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let csv = std::fs::read_to_string(out.join("echoes.csv")).unwrap();
        let skip = usize::from(!all.is_empty());
        for l in csv.lines().skip(skip) {
            all.push_str(l);
            all.push('\n');
        }
    }
    let echoes = tmp.path().join("array.csv");
    std::fs::write(&echoes, &all).unwrap();
    let params = tmp.path().join("params.toml");
    std::fs::write(
        &params,
        "[mapping]\nmapper = \"evidence\"\ncell = 0.05\n[mapping.evidence]\nmin_line_length_m = 0.0\n",
    )
    .unwrap();
    let out = tmp.path().join("map");
    let o = Command::new(env!("CARGO_BIN_EXE_chirpmap"))
        .args(["--no-progress", "map", "--echoes", echoes.to_str().unwrap(), "--scene", params.to_str().unwrap()])
        .args(["--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!String::from_utf8_lossy(&o.stdout).contains("score_obstacle"), "scored against no truth");
    let surfaces = std::fs::read_to_string(out.join("surfaces.csv")).unwrap();
    let walls: Vec<[f64; 4]> = surfaces
        .lines()
        .skip(1)
        .filter(|l| l.starts_with("line,"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f[6], "true", "a line from a linear array that is not ambiguous: {l}");
            [f[1].parse().unwrap(), f[2].parse().unwrap(), f[3].parse().unwrap(), f[4].parse().unwrap()]
        })
        .collect();
    assert!(walls.len() >= 4, "{surfaces}");
    // The wall x = 0: both ends within 5 cm of it, within 3 degrees of vertical.
    let on_x0 = walls.iter().any(|&[x0, y0, x1, y1]| {
        x0.abs() <= 0.05 && x1.abs() <= 0.05 && ((x1 - x0).abs() / (y1 - y0).abs()).atan().to_degrees() <= 3.0
    });
    assert!(on_x0, "{surfaces}");
}
