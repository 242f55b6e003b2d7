//! What one sweep run is: the facade's simulate → map → score, reduced to
//! the metrics a runs.csv row records.

use crate::runs::RunMetrics;
use chirpmap::Scene;

/// Scene checks for sweeps: everything `simulate` would refuse.
pub fn validate_scene(scene: &Scene) -> Result<(), String> {
    chirpmap::validate_scene(scene).map_err(|e| e.to_string())
}

/// Run `run` (the random stream) of `scene`, simulated, mapped and scored.
pub fn run_metrics(scene: &Scene, run: u64) -> Result<RunMetrics, String> {
    let mut scene = scene.clone();
    scene.run_index = run;
    let sim = chirpmap::simulate(&scene).map_err(|e| e.to_string())?;
    let obstacles = sim.resolved.scene.explicit_obstacles().map_err(|e| e.to_string())?;
    let surfaces = chirpmap::evaluate(&obstacles, &sim.map, &sim.output.echoes).surfaces;
    Ok(RunMetrics {
        score_obstacle: sim.scores.score_obstacle,
        score_highlight: sim.scores.score_highlight,
        surface_f1: Some(surfaces.f1),
        chamfer_m: surfaces.chamfer_m,
        n_highlights: sim.map.highlights.len(),
        n_echoes: sim.output.echoes.len(),
    })
}
