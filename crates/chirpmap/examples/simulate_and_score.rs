//! Simulate the paper's default scene, map it with both mappers, score both.
//!
//! `cargo run --release -p chirpmap --example simulate_and_score`

use chirpmap::{MapOptions, MapperKind, Scene, evaluate, map_echoes, simulate};

fn main() -> Result<(), chirpmap::Error> {
    let run = simulate(&Scene::default())?;
    println!(
        "{} measurements, {} echoes, {} obstacles",
        run.output.measurements.len(),
        run.output.echoes.len(),
        run.resolved.obstacles.len()
    );
    for mapper in [MapperKind::Paper, MapperKind::Evidence] {
        let mut opts = MapOptions { bounds: Some(run.resolved.world), ..MapOptions::default() };
        opts.params.mapper = mapper;
        let map = map_echoes(&run.output.echoes, &[], &opts)?;
        let e = evaluate(&run.resolved.obstacles, &map, &run.output.echoes);
        println!(
            "{mapper:?}: {} highlights, {} surfaces, score_obstacle {:?}, score_highlight {:?}, surface F1 {:.3}",
            map.highlights.len(),
            map.surfaces.len(),
            e.scores.score_obstacle,
            e.scores.score_highlight,
            e.surfaces.f1
        );
    }
    Ok(())
}
