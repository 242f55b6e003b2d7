//! `range --echoes` streams its recording (issue 14, item 4): the streamed
//! pipeline (`RoomReport::from_wav_stream`) gives the same report, bit for
//! bit, as the in-memory one (`prepare_room` then `room_echoes`) it
//! replaces, on recordings rendered by `chirpmap synth` in several formats
//! and channel layouts.
#![allow(clippy::unwrap_used)] // Tests may panic on broken fixtures.

use chirpmap::{ChirpSpec, EchoOptions, Point, RoomGeometry, RoomReport};
use chirpmap_audio::{SampleFormat, read_wav, write_wav};
use std::path::{Path, PathBuf};
use std::process::Command;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("chirpmap-range-stream-{}-{name}", std::process::id()));
    std::fs::remove_dir_all(&d).ok();
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A static listener 1.5 m from the speaker, a wall 6 m behind it (as the
/// hour benchmark), `chirps` chirps of `duration` s.
fn synth(dir: &Path, chirps: usize, duration: f64, snr_db: f64) -> (PathBuf, PathBuf) {
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        format!(
            "[chirp]\nf_start = 10000.0\nf_end = 200.0\nduration = {duration}\n\n[[obstacles]]\n\
             vertices = [[-30.0, -6.0], [-30.0, -6.3], [30.0, -6.3], [30.0, -6.0]]\nroughness = 0.0\n\
             absorption = 0.2\n\n[[listeners]]\nstart = [1.5, 0.5]\nheading_deg = 0.0\nspeed = 0.0\n\n\
             [synth]\nchirps = {chirps}\ngap_s = 0.5\nstart_s = 0.3\ntail_s = 0.5\nsnr_db = {snr_db}\n"
        ),
    )
    .unwrap();
    let wav = dir.join("rec.wav");
    let o = Command::new(env!("CARGO_BIN_EXE_chirpmap"))
        .args(["synth", scene.to_str().unwrap(), "--out", wav.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (wav, scene)
}

fn geom() -> RoomGeometry {
    RoomGeometry {
        speaker: Point::new(0.0, 0.0),
        mic: Point::new(1.5, 0.5),
        heights_m: None,
        floor_z_m: None,
        ceiling_z_m: None,
    }
}

fn chirp_of(scene: &Path) -> ChirpSpec {
    let (s, _) = chirpmap::parse_scene(&std::fs::read_to_string(scene).unwrap()).unwrap();
    ChirpSpec::from_scene(&s)
}

/// The in-memory report and the streamed one for the same file and channel.
fn both(wav: &Path, channel: usize, chirp: &ChirpSpec, opts: &EchoOptions) -> (RoomReport, RoomReport) {
    let rec = read_wav(wav).unwrap();
    let x = rec.channel(channel).unwrap().to_vec();
    let prep = chirpmap::prepare_room(x, f64::from(rec.sample_rate_hz), chirp).unwrap();
    let mem = chirpmap::room_echoes(&prep, &geom(), opts).unwrap();
    let s = RoomReport::from_wav_stream(wav, channel, chirp, &geom(), opts).unwrap().unwrap();
    assert_eq!(s.clipped_samples, rec.clipped_samples);
    assert_eq!(s.max_delta_d_m, prep.max_delta_d_m);
    (mem, s.report)
}

#[test]
fn streamed_report_is_the_in_memory_one() {
    let d = tmp("same");
    // Chirps of 0.3 s: blocks of the correlation (nfft = 2^16) hold several.
    let (wav, scene) = synth(&d, 40, 0.3, 20.0);
    let chirp = chirp_of(&scene);
    let opts = EchoOptions::default();
    let (mem, streamed) = both(&wav, 0, &chirp, &opts);
    assert_eq!(mem.chirp_onsets_s.len(), 40, "{:?}", mem.chirp_onsets_s);
    assert!(!mem.echoes.is_empty());
    assert_eq!(mem, streamed);
    // The wall 6 m behind the speaker: image source at (0, −12), mic at (1.5, 0.5);
    // Δd = |(1.5, 12.5)| − |(1.5, 0.5)| (exact geometry, not our code).
    let truth = 1.5f64.hypot(12.5) - 1.5f64.hypot(0.5);
    assert!(mem.clusters.iter().any(|c| (c.path_delta_m - truth).abs() < 0.02), "{:?}", mem.clusters);
}

#[test]
fn streamed_report_is_the_same_in_every_format_and_channel() {
    let d = tmp("formats");
    let (wav, scene) = synth(&d, 12, 0.25, 10.0);
    let chirp = chirp_of(&scene);
    let rec = read_wav(&wav).unwrap();
    let x = rec.channel(0).unwrap();
    // A second channel of other noise-free samples, the recording in channel 1.
    let other: Vec<f32> = x.iter().map(|v| 0.5 * v).collect();
    for format in [SampleFormat::Int(16), SampleFormat::Int(24), SampleFormat::Int(32), SampleFormat::Float32] {
        let f = d.join("two.wav");
        write_wav(&f, rec.sample_rate_hz, format, &[&other, x]).unwrap();
        let opts = EchoOptions { max_echoes: 5, ..EchoOptions::default() };
        let (mem, streamed) = both(&f, 1, &chirp, &opts);
        assert_eq!(mem, streamed, "{format:?}");
        assert_eq!(mem.chirp_onsets_s.len(), 12);
    }
}

#[test]
fn streamed_errors_name_the_problem() {
    let d = tmp("errors");
    let (wav, scene) = synth(&d, 3, 0.25, 20.0);
    let chirp = chirp_of(&scene);
    let rec = read_wav(&wav).unwrap();
    let silent = vec![0.0f32; rec.len_samples()];
    let f = d.join("silent.wav");
    write_wav(&f, rec.sample_rate_hz, SampleFormat::Int(16), &[&silent, &silent]).unwrap();
    let e = RoomReport::from_wav_stream(&f, 1, &chirp, &geom(), &EchoOptions::default()).unwrap_err().to_string();
    assert_eq!(e, "channel 1 is silent (every sample is zero) (it has 2 channels: try --channel)");
    let e = RoomReport::from_wav_stream(&wav, 3, &chirp, &geom(), &EchoOptions::default()).unwrap_err().to_string();
    assert!(e.contains("channel"), "{e}");
    let long = ChirpSpec { duration_s: 1e3, ..chirp };
    let e = RoomReport::from_wav_stream(&wav, 0, &long, &geom(), &EchoOptions::default()).unwrap_err().to_string();
    assert!(e.contains("longer than the recording"), "{e}");
}

/// Plain `range` (first reflection, every method): the streamed report's
/// detections and estimates are the in-memory ones, and its window holds
/// the middle chirp's samples.
#[test]
fn streamed_range_is_the_in_memory_one() {
    let d = tmp("range");
    let (wav, scene) = synth(&d, 15, 0.3, 15.0);
    let chirp = chirp_of(&scene);
    let geom = chirpmap::RangeGeometry {
        speaker: Point::new(0.0, 0.0),
        mic: Point::new(1.5, 0.5),
        wall_normal: Some(Point::new(0.0, -1.0)),
    };
    let methods = chirpmap::Method::ALL.to_vec();
    let rec = read_wav(&wav).unwrap();
    let prep = chirpmap::prepare(rec.channel(0).unwrap().to_vec(), f64::from(rec.sample_rate_hz), &chirp).unwrap();
    let mem = chirpmap::range(&prep, &methods, &geom).unwrap();
    let s = chirpmap::RangeReport::from_wav_stream(&wav, 0, &chirp, &methods, &geom).unwrap().unwrap();
    assert_eq!(mem.chirps, s.report.chirps);
    assert_eq!(mem.per_method, s.report.per_method);
    assert_eq!(mem.summaries, s.report.summaries);
    assert_eq!(mem.chirps.len(), 15);
    let mid = mem.chirps[mem.chirps.len() / 2].0.onset_sample;
    let w = &prep.x[s.window_start..s.window_start + s.prep.x.len()];
    assert!(w.iter().zip(&s.prep.x).all(|(a, b)| a.to_bits() == b.to_bits()));
    assert!(s.window_start < mid && mid < s.window_start + s.prep.x.len());
    assert_eq!(s.report.summary(&s.prep, &chirp, &geom, 0), mem.summary(&prep, &chirp, &geom, 0));
    // Δd of the wall (image-source geometry, as above) by the matched filter.
    let truth = 1.5f64.hypot(12.5) - 1.5f64.hypot(0.5);
    let med = s.report.summaries[1].delta_d_median.unwrap();
    assert!((med - truth).abs() < 0.05, "{med} vs {truth}");
}

/// `CHIRPMAP_STREAM_WAV=hour.wav CHIRPMAP_STREAM_SCENE=scene.toml cargo test --release -p chirpmap-cli
/// --test integration range_stream:: -- --ignored`: the same check on a given recording (the hour benchmark).
#[test]
#[ignore = "needs CHIRPMAP_STREAM_WAV and CHIRPMAP_STREAM_SCENE"]
fn streamed_report_is_the_in_memory_one_on_a_given_recording() {
    let wav = PathBuf::from(std::env::var("CHIRPMAP_STREAM_WAV").unwrap());
    let scene = PathBuf::from(std::env::var("CHIRPMAP_STREAM_SCENE").unwrap());
    let (mem, streamed) = both(&wav, 0, &chirp_of(&scene), &EchoOptions::default());
    assert_eq!(mem, streamed);
}
