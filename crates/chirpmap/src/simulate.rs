//! Scene → particle simulator (paper §II.B) → echoes → map → scores.

use crate::error::Result;
use crate::mapping::{MapResult, Scores, map_on_grid, score};
use chirpmap_audio::SynthConfig;
use chirpmap_core::grid::DEFAULT_MEMORY_CAP_BYTES;
use chirpmap_core::{GridSpec, Obstacle, Scene};
use chirpmap_sim::{Resolved, SimOutput, resolve};
use std::time::Instant;

/// Everything one simulated run produces.
#[derive(Debug)]
pub struct Simulation {
    /// The validated scene with its random parts drawn (obstacles listed,
    /// duration explicit): `resolved.scene` replays the run exactly.
    pub resolved: Resolved,
    /// Measurements and echoes.
    pub output: SimOutput,
    /// The map of the echoes on the scene's world.
    pub map: MapResult,
    /// The paper's scores of the map's highlights.
    pub scores: Scores,
    /// Wall time of the particle simulation alone (s).
    pub simulate_elapsed_s: f64,
}

/// Parses a scene TOML (every field optional, unknown keys are errors); an
/// optional `[synth]` table holds the waveform settings of [`crate::synth`].
pub fn parse_scene(text: &str) -> Result<(Scene, SynthConfig)> {
    Ok(chirpmap_audio::synth::parse_scene_with_synth(text)?)
}

/// Checks a scene the way [`simulate`] would, without simulating.
pub fn validate_scene(scene: &Scene) -> Result<()> {
    resolve(scene)?;
    Ok(())
}

/// The obstacles a map of `scene`'s echoes is scored against, and the scene
/// with its random obstacles listed. Random obstacles are placed as
/// [`simulate`] places them, which takes the particle simulator's whole
/// scene (its listeners must move); listed obstacles need only the schema
/// every command shares, so the scene of a `synth` recording with a still
/// listener scores the map of its `range --echoes` too.
pub fn scene_truth(scene: &Scene) -> Result<(Vec<Obstacle>, Scene)> {
    // The simulator places random obstacles only when none is listed.
    if !scene.obstacles.is_empty() || scene.random_obstacles.count == 0 {
        scene.validate()?;
        scene.chirp.build()?;
        scene.mapping.validate()?;
        return Ok((scene.explicit_obstacles()?, scene.clone()));
    }
    let resolved = resolve(scene)?;
    Ok((resolved.obstacles, resolved.scene))
}

/// Simulates `scene` (its `seed` and `run_index` fix the run bit for bit),
/// maps the echoes on the scene's world with its `[mapping]`, and scores
/// the highlights against the scene's obstacles.
pub fn simulate(scene: &Scene) -> Result<Simulation> {
    let resolved = resolve(scene)?;
    let started = Instant::now();
    let output = chirpmap_sim::simulate(&resolved);
    let simulate_elapsed_s = started.elapsed().as_secs_f64();
    let params = resolved.scene.mapping;
    let spec = GridSpec::from_bounds(resolved.world, params.cell, DEFAULT_MEMORY_CAP_BYTES)?;
    let map = map_on_grid(&output.echoes, spec, params)?;
    let scores = score(&resolved.obstacles, &map.highlight_points());
    Ok(Simulation { resolved, output, map, scores, simulate_elapsed_s })
}

/// Listener 0's start and path length (m) in the paper's default scene; the
/// two-listener patterns of Table II are placed relative to it.
pub fn default_listener_path() -> ([f64; 2], f64) {
    let scene = Scene::default();
    let l0 = &scene.listeners[0];
    let duration_s = resolve(&scene).map_or(0.0, |r| r.last_tick as f64 * r.tick_s);
    (l0.start, l0.speed * duration_s)
}
