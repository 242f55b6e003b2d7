//! A walking listener's recording to a map: synthesize what the microphone
//! hears beside a wall, find every chirp, measure an echo per frame at the
//! listener's pose, and map the echoes.
//!
//! `cargo run --release -p chirpmap --example recording_to_map`

use chirpmap::{ChirpSpec, FrameParams, MapOptions, Method, PoseTrack, echoes_from_recording, map_echoes, parse_scene};

/// A wall 6 m from the speaker; the listener walks along it at 1 m/s.
const SCENE: &str = r#"
[chirp]
duration = 0.25
[[obstacles]]
vertices = [[-30.0, -6.0], [-30.0, -6.3], [30.0, -6.3], [30.0, -6.0]]
[[listeners]]
start = [-4.0, 1.0]
speed = 1.0
[synth]
chirps = 12
gap_s = 0.25
snr_db = 20.0
"#;

fn main() -> Result<(), chirpmap::Error> {
    let (scene, synth_cfg) = parse_scene(SCENE)?;
    let rec = chirpmap::synth(&scene, &synth_cfg)?;
    let fs = f64::from(rec.sample_rate_hz);
    let poses = PoseTrack::new(rec.poses[0].clone())?;
    let prep = chirpmap::prepare(rec.channels[0].clone(), fs, &ChirpSpec::from_scene(&scene))?;
    let params = FrameParams {
        method: Method::Dechirp,
        period_s: 0.01,
        frame_s: None,
        speaker: chirpmap::Point::new(scene.source.position[0], scene.source.position[1]),
        listener_id: 0,
    };
    let got = echoes_from_recording(&prep, &poses, &params)?;
    println!("{} chirps, {} echoes", got.chirps, got.echoes.len());
    let map = map_echoes(&got.echoes, &[], &MapOptions::default())?;
    for h in map.highlights.iter().take(5) {
        println!("highlight at ({:.2}, {:.2}) m, value {:.1}", h.pos.x, h.pos.y, h.value);
    }
    Ok(())
}
