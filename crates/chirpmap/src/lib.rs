//! # chirpmap: turn sound into maps
//!
//! The pipeline of *Acoustic Ellipses* (Swissler, Burke, Hyland Bruno, 2026)
//! as a small library. A stationary Source plays a frequency sweep; a moving
//! Listener hears the direct and the reflected sound at once; the frequency
//! gap between them is a path-length difference Δd (paper Eq. 1–3); each Δd
//! is an ellipse of possible reflection points (Eq. 4); ellipses accumulated
//! on a grid reveal obstacles (Algorithm 1), which the scores of §III.A judge.
//!
//! Every step takes and returns plain data (slices and structs, no files):
//!
//! | step | function |
//! |---|---|
//! | simulate a scene (particle model, §II.B), map and score it | [`simulate`] |
//! | map echoes you measured (Algorithm 1, or the evidence mapper) | [`map_echoes`] |
//! | score highlights against known obstacles (§III.A) | [`score`] |
//! | score a map and its surfaces (F1, Chamfer, wall errors) | [`evaluate`] |
//! | synthesize what the listeners record | [`synth`] |
//! | range a recording: Δd per chirp (§IV) | [`prepare`] then [`range`] |
//! | a moving listener's recording to echoes, then a map | [`echoes_from_recording`] then [`map_echoes`] |
//!
//! ```
//! use chirpmap::{MapOptions, Scene, map_echoes, score, simulate};
//!
//! // The paper's default scene: three random circles, one listener at 10 m/s.
//! let run = simulate(&Scene::default())?;
//! println!("{} echoes, scores {:?}", run.output.echoes.len(), run.scores);
//!
//! // Map the same echoes again, yourself, with a coarser grid.
//! let mut opts = MapOptions::default();
//! opts.params.cell = 0.2;
//! let map = map_echoes(&run.output.echoes, &[], &opts)?;
//! let scores = score(&run.resolved.obstacles, &map.highlight_points());
//! assert_eq!(map.grid.spec.cell_m, 0.2);
//! assert!(scores.score_obstacle.is_some());
//! # Ok::<(), chirpmap::Error>(())
//! ```
//!
//! The layers below are re-exported for what this facade does not wrap:
//! [`core`] (geometry, chirps, ellipses, mappers, scores), [`sim`] (the
//! particle simulator) and [`audio`] (WAV, detection, ranging, synthesis).

#![warn(missing_docs)]

mod error;
mod mapping;
mod recording;
mod rooms;
mod simulate;

pub use chirpmap_audio as audio;
pub use chirpmap_core as core;
pub use chirpmap_sim as sim;

pub use chirpmap_audio::doppler::{MovingOptions, WavMethod};
pub use chirpmap_audio::synth::{ChirpPattern, Synthesized};
pub use chirpmap_audio::{Method, SynthConfig};
pub use chirpmap_core::metrics::{SurfaceMetrics, WallMatch};
pub use chirpmap_core::{
    Echo, EvidenceParams, Grid, GridSpec, Highlight, MapperKind, MappingParams, Obstacle, Point, Scene, Surface,
    SurfaceKind,
};
pub use error::{Error, Result};
pub use mapping::{
    Evaluation, MapOptions, MapResult, Scores, covering_bounds, evaluate, foci, map_echoes, map_on_grid,
    observed_points, score,
};
pub use recording::{
    ChirpSpec, ChirpSummary, FrameParams, MAX_SPAN_RATIO, MethodSummary, PoseTrack, Prepared, RangeGeometry,
    RangeReport, RangeSummary, RecordingEchoes, SPEED_OF_SOUND_RANGE_MPS, StreamedRange, WallStats,
    echoes_from_recording, prepare, range, wall_distance,
};
pub use rooms::{
    DEFAULT_MAX_ECHOES, ECHOGRAM_CHIRPS, EchoCluster, EchoOptions, RIR_DEFAULT_MAX_DELTA_D_M, RoomEcho, RoomGeometry,
    RoomPrepared, RoomReport, StreamedRoom, calibration_response, calibration_response_rir, prepare_room, rir_echoes,
    rir_max_delta_d, room_echoes,
};
pub use simulate::{Simulation, default_listener_path, parse_scene, scene_truth, simulate, validate_scene};

/// Renders what every listener of `scene` records: the chirp train, the
/// direct path, specular reflections and noise, with exact per-sample
/// propagation delays (so a moving listener's Doppler is in the signal).
pub fn synth(scene: &Scene, cfg: &SynthConfig) -> Result<Synthesized> {
    Ok(chirpmap_audio::synthesize(scene, cfg)?)
}
