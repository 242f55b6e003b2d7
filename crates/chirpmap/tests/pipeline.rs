//! The facade's flows end to end, against truth that is not a mapper's own.

use chirpmap::core::exact::{ExactOptions, ExactScene, Pose, exact_echoes};
use chirpmap::{MapOptions, MapperKind, Scene, evaluate, map_echoes, simulate};

#[test]
fn simulate_is_reproducible_and_particle_echoes_carry_their_resolution() -> Result<(), chirpmap::Error> {
    let a = simulate(&Scene::default())?;
    let b = simulate(&Scene::default())?;
    assert_eq!(a.output.echoes, b.output.echoes);
    assert_eq!(a.map.highlights, b.map.highlights);
    assert!(!a.output.echoes.is_empty());
    // One frequency per 1 ms tick at 343 m/s: Δd resolved to 0.343 m, σ = 0.343/√12.
    let want = 343.0 * 0.001 / 12f64.sqrt();
    for e in &a.output.echoes {
        let s = e.sigma_m.expect("particle echoes carry σ");
        assert!((s - want).abs() < 1e-12, "{s}");
    }
    Ok(())
}

#[test]
fn both_mappers_find_a_wall_from_exact_echoes() -> Result<(), chirpmap::Error> {
    // A wall along y = -4 from x = -10 to 10; the listener walks a loop near the source.
    let wall = chirpmap::Obstacle {
        shape: chirpmap::core::Shape::Polygon(
            chirpmap::core::Polygon::new(vec![
                chirpmap::Point::new(-10.0, -4.0),
                chirpmap::Point::new(10.0, -4.0),
                chirpmap::Point::new(10.0, -4.3),
                chirpmap::Point::new(-10.0, -4.3),
            ])
            .map_err(chirpmap::Error::Core)?,
        ),
        roughness: 0.0,
        absorption: 0.0,
    };
    let poses: Vec<Pose> = (0..120)
        .map(|k| {
            let u = std::f64::consts::TAU * k as f64 / 120.0;
            Pose { t_s: k as f64, listener: chirpmap::Point::new(3.0 * u.cos(), 1.0 + 1.5 * u.sin()) }
        })
        .collect();
    let truth = [wall];
    let echoes = exact_echoes(
        chirpmap::Point::new(0.0, 0.0),
        &poses,
        &ExactScene::from_obstacles(&truth),
        &ExactOptions::default(),
    )?;
    assert!(echoes.len() >= 100);
    for mapper in [MapperKind::Paper, MapperKind::Evidence] {
        let mut opts = MapOptions { bounds: Some([-12.0, -8.0, 12.0, 6.0]), ..MapOptions::default() };
        opts.params.mapper = mapper;
        let map = map_echoes(&echoes, &[], &opts)?;
        let e = evaluate(&truth, &map, &echoes);
        assert!(e.scores.score_obstacle.is_some_and(|s| s > 0.9), "{mapper:?}: {e:?}");
        if mapper == MapperKind::Evidence {
            // The front face is a line within 2 cm and 1°.
            let front = e.surfaces.walls.iter().find(|w| (w.a.y + 4.0).abs() < 1e-9 && (w.b.y + 4.0).abs() < 1e-9);
            let front = front.expect("front face listed");
            assert!(front.offset_m.is_some_and(|o| o < 0.02) && front.angle_deg.is_some_and(|a| a < 1.0), "{front:?}");
            // Only the front face was heard, so it is the one wall scored;
            // without the echoes the back face (y = -4.3) is listed too, and
            // the same line is "matched" to it at the wall's thickness.
            assert_eq!(e.surfaces.walls.len(), 1, "{:?}", e.surfaces.walls);
            let blind = evaluate(&truth, &map, &[]);
            let back = blind.surfaces.walls.iter().find(|w| (w.a.y + 4.3).abs() < 1e-9 && (w.b.y + 4.3).abs() < 1e-9);
            assert!(
                back.and_then(|w| w.offset_m).is_some_and(|o| (o - 0.3).abs() < 0.02),
                "{:?}",
                blind.surfaces.walls
            );
            // Recall counts the heard stretch of the front face only.
            assert!(
                e.surfaces.recall > 2.0 * blind.surfaces.recall,
                "{} vs {}",
                e.surfaces.recall,
                blind.surfaces.recall
            );
        }
    }
    Ok(())
}
