//! Issue 8: every size a user controls in the audio pipeline is bounded, and
//! the memory a step needs is estimated and checked before allocating; the
//! synthesizer validates scenes exactly as `simulate` does.
#![allow(clippy::unwrap_used)]

use chirpmap_audio::detect::{ChirpTemplate, Detection};
use chirpmap_audio::frames::{FrameParams, extract_echoes};
use chirpmap_audio::synth::{parse_scene_with_synth, synth_memory_bytes, synthesize};
use chirpmap_audio::{AudioError, Method, RangeLimits, SynthConfig};
use chirpmap_core::{LinearChirp, Point, Scene};

/// Item 8: `--duration 1e5` asked for a 57 GB template; now an error with the estimate.
#[test]
fn a_huge_chirp_template_is_refused_with_its_estimate() {
    let chirp = LinearChirp::new(10_000.0, 200.0, 1e5).unwrap();
    let e = ChirpTemplate::new(chirp, 48_000.0).unwrap_err();
    assert!(matches!(e, AudioError::TooLarge { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("100000 s chirp template") && msg.contains("57.6 GB") && msg.contains("--duration"), "{msg}");
    let chirp = LinearChirp::new(10_000.0, 200.0, 0.5).unwrap();
    let e = ChirpTemplate::new(chirp, 4_294_967_295.0).unwrap_err().to_string();
    assert!(e.contains("sample rate"), "{e}");
}

/// Item 9: 50 listeners over an hour (~35 GB) is refused with the estimate,
/// before any allocation.
#[test]
fn synth_refuses_a_run_beyond_the_memory_cap() {
    let mut text = String::from("[synth]\nchirps = 2400\ngap_s = 1.0\n");
    for i in 0..50 {
        text.push_str(&format!("[[listeners]]\nstart = [{}, 10.0]\nspeed = 0.0\n", -40.0 + f64::from(i)));
    }
    let (scene, cfg) = parse_scene_with_synth(&text).unwrap();
    let bytes = synth_memory_bytes(&scene, &cfg);
    // 0.5 + 2400 · 1.5 − 1 + 0.5 = 3600 s: 50 × 3600 s · 48 kHz × 4 bytes =
    // 34.56 GB of samples, plus 50 × 360 001 poses × 24 bytes = 0.43 GB.
    assert!((bytes - 34.992e9).abs() < 0.001e9, "{bytes}");
    let e = synthesize(&scene, &cfg).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, AudioError::TooLarge { .. }) && msg.contains("50 listener(s)") && msg.contains("GB"), "{msg}");
    // Poses are counted too: 1500 s every µs is 1.5·10⁹ poses (36 GB).
    let (scene, cfg) = parse_scene_with_synth("[synth]\nchirps = 1000\npose_period_s = 1e-6\n").unwrap();
    assert!(matches!(synthesize(&scene, &cfg), Err(AudioError::TooLarge { .. })));
    let e = parse_scene_with_synth("[synth]\npose_period_s = 1e-12\n").unwrap_err().to_string();
    assert!(e.contains("synth.pose_period_s") && e.contains("1e-12"), "{e}");
}

/// Item 11: what `simulate` refuses, `synth` refuses, by the same validation.
#[test]
fn synth_validates_the_scene_like_simulate() {
    let cases = [
        "[[listeners]]\nspin_rate = nan\n",
        "[[listeners]]\nspeed = inf\n",
        "[world]\nspeed_of_sound = 1e-300\n",
        "[source]\nposition = [nan, 0.0]\n",
        "[source]\nposition = [1.0, 2.0, 3.0]\n",
        "[random_obstacles]\ncount = 0\n",
    ];
    for text in cases {
        let e = parse_scene_with_synth(text).unwrap_err().to_string();
        let shared = match Scene::from_toml_str(text) {
            Ok(s) => s.validate().unwrap_err().to_string(),
            Err(e) => e.to_string(),
        };
        assert_eq!(e, shared, "{text:?}");
        // Also when the scene comes from elsewhere (a program).
        if let Ok(s) = Scene::from_toml_str(text) {
            assert!(synthesize(&s, &SynthConfig::default()).is_err(), "{text:?}");
        }
    }
    let e = parse_scene_with_synth("[synth]\nchirps = 0\n").unwrap_err().to_string();
    assert!(e.contains("synth.chirps"), "{e}");
    let e = parse_scene_with_synth("[synth]\npeak = nan\n").unwrap_err().to_string();
    assert!(e.contains("synth.peak") && e.contains("NaN"), "{e}");
}

/// Item 15: a 1 MB value in the `[synth]` table or the scene is quoted as a
/// short excerpt, once.
#[test]
fn toml_errors_stay_short() {
    let big = "x".repeat(1_000_000);
    for text in [format!("[synth]\nbits = {big}\n"), format!("[synth]\nbits = 5\nfoo = \"{big}\"\n")] {
        let e = parse_scene_with_synth(&text).unwrap_err().to_string();
        assert!(e.len() < 400, "{} chars: {}", e.len(), &e[..200]);
    }
}

/// Item 10: `map --wav --period-ms 1e-9` ran for hours; now refused before any work.
#[test]
fn frame_period_is_bounded() {
    let tpl = ChirpTemplate::new(LinearChirp::new(10_000.0, 200.0, 0.25).unwrap(), 48_000.0).unwrap();
    let lim = RangeLimits::for_chirp(0.25, 343.0);
    let x = vec![0.0f32; 48_000];
    let dets = vec![Detection { onset_sample: 100, strength: 20.0, ncc: 0.9 }; 3];
    let pose = |_t: f64| Some(Point::new(1.0, 0.0));
    let params = |period_s: f64| FrameParams {
        method: Method::Gap,
        period_s,
        frame_s: None,
        speaker: Point::new(0.0, 0.0),
        listener_id: 0,
    };
    for period in [1e-12, 1e-9 / 1e3, f64::NAN, 0.0, -1.0, f64::INFINITY] {
        let e = extract_echoes(&x, &tpl, &lim, &dets, &pose, &params(period)).unwrap_err().to_string();
        assert!(e.contains("period"), "{period}: {e}");
    }
    let many = vec![Detection { onset_sample: 100, strength: 20.0, ncc: 0.9 }; 10_000];
    let e = extract_echoes(&x, &tpl, &lim, &many, &pose, &params(1.0 / 48_000.0)).unwrap_err().to_string();
    assert!(e.contains("cap of 10000000"), "{e}");
    assert!(extract_echoes(&x, &tpl, &lim, &dets, &pose, &params(0.01)).is_ok());
}

/// Errors in a scene file with a `[synth]` table name the file's own lines,
/// in the scene part and in the table (the scene was parsed from a
/// re-serialised copy, and `[synth]` errors had no line); the values read
/// are those of parsing the file whole.
#[test]
fn errors_around_a_synth_table_name_the_files_lines() {
    for eol in ["\n", "\r\n"] {
        let text =
            ["seed = 3", "", "[synth]", "chirps = 5", "", "[[listeners]]", "start = [1.0, 2.0]", "sped = 3.0", ""]
                .join(eol);
        let e = parse_scene_with_synth(&text).unwrap_err().to_string();
        assert!(e.contains("line 8, column 1: unknown field `sped`"), "{eol:?}: {e}");
        let text =
            ["seed = 3", "[synth]", "chirps = 5", "chrips = 3", "[world]", "bounds = [-50.0, -50.0, 50.0, 50.0]", ""]
                .join(eol);
        let e = parse_scene_with_synth(&text).unwrap_err().to_string();
        assert!(e.contains("line 4, column 1: unknown field `chrips`"), "{eol:?}: {e}");
    }
    // Split by lines or read whole (an inline table), the same scene and table.
    let by_lines = "seed = 7\n[synth]\nchirps = 9\nsnr_db = 20.0\n[[listeners]]\nstart = [1.0, 2.0]\n";
    let inline = "seed = 7\nsynth = { chirps = 9, snr_db = 20.0 }\n[[listeners]]\nstart = [1.0, 2.0]\n";
    let (a, b) = (parse_scene_with_synth(by_lines).unwrap(), parse_scene_with_synth(inline).unwrap());
    assert_eq!(a.1, b.1);
    assert_eq!(a.1.chirps, 9);
    assert_eq!(a.0.to_toml_string(), b.0.to_toml_string());
}
