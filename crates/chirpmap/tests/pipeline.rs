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

fn slab(v: &[(f64, f64)]) -> chirpmap::Obstacle {
    let v = v.iter().map(|&(x, y)| chirpmap::Point::new(x, y)).collect();
    chirpmap::Obstacle {
        shape: chirpmap::core::Shape::Polygon(chirpmap::core::Polygon::new(v).expect("polygon")),
        roughness: 0.0,
        absorption: 0.0,
    }
}

fn segment(a: chirpmap::Point, b: chirpmap::Point) -> chirpmap::Surface {
    chirpmap::Surface { kind: chirpmap::SurfaceKind::Line, p0: a, p1: b, support: 1, ambiguous: false }
}

/// A corridor walked along its centre line from a source on that line: both
/// walls give the same path at every pose, and both were heard (the exact
/// model's echoes merge equal paths into one echo; the observed points must
/// not, or one wall is dropped from the metrics).
#[test]
fn both_walls_of_a_corridor_walked_on_its_centre_line_are_heard() -> Result<(), chirpmap::Error> {
    use chirpmap::core::metrics::{MetricParams, surface_metrics};
    let truth = [
        slab(&[(-10.0, 2.0), (10.0, 2.0), (10.0, 2.3), (-10.0, 2.3)]),
        slab(&[(-10.0, -2.3), (10.0, -2.3), (10.0, -2.0), (-10.0, -2.0)]),
    ];
    let poses: Vec<Pose> = (0..200)
        .map(|i| Pose { t_s: i as f64, listener: chirpmap::Point::new(-4.975 + 0.05 * i as f64, 0.0) })
        .collect();
    let source = chirpmap::Point::new(0.0, 0.0);
    let echoes = exact_echoes(source, &poses, &ExactScene::from_obstacles(&truth), &ExactOptions::default())?;
    let observed = chirpmap::observed_points(&truth, &echoes).expect("reflections");
    for y in [2.0, -2.0] {
        assert!(observed.iter().any(|p| (p.y - y).abs() < 1e-9), "no bounce on y = {y}: {observed:?}");
    }
    let map = [
        segment(chirpmap::Point::new(-2.5, 2.0), chirpmap::Point::new(2.5, 2.0)),
        segment(chirpmap::Point::new(-2.5, -2.0), chirpmap::Point::new(2.5, -2.0)),
    ];
    let m = surface_metrics(&map, &truth, Some(&observed), &MetricParams::default());
    let mut scored: Vec<f64> = m.walls.iter().map(|w| w.a.y).collect();
    scored.sort_by(f64::total_cmp);
    assert_eq!(scored, vec![-2.0, 2.0], "{:?}", m.walls);
    assert!(m.walls.iter().all(|w| w.offset_m == Some(0.0)));
    Ok(())
}

/// A short wall (0.52 m, 45°) beside a dense diagonal walk is scored at
/// every position along the walk where the walk's bounces land on it: the
/// listener positions are thinned to 0.25 m squares, but any bounce on the
/// wall hears it. Without reflections (every direct path blocked) every
/// true surface counts, as without echoes.
#[test]
fn a_short_wall_beside_a_diagonal_walk_is_scored_wherever_it_is_heard() -> Result<(), chirpmap::Error> {
    use chirpmap::core::exact::exact_reflections;
    use chirpmap::core::metrics::{MetricParams, surface_metrics};
    let u = chirpmap::Point::new(1.0, 1.0) * std::f64::consts::FRAC_1_SQRT_2;
    let n = chirpmap::Point::new(-u.y, u.x);
    let poses: Vec<Pose> = (0..2000)
        .map(|i| Pose { t_s: i as f64, listener: chirpmap::Point::new(0.005 * i as f64, 0.005 * i as f64) })
        .collect();
    let mut heard = 0;
    for j in 0..100 {
        let a = u * (2.0 + 0.02 * j as f64) - n * 0.2;
        let b = a + u * 0.52;
        let wall =
            slab(&[(a.x, a.y), (b.x, b.y), ((b - n * 0.02).x, (b - n * 0.02).y), ((a - n * 0.02).x, (a - n * 0.02).y)]);
        let truth = [wall];
        let source = a + u * 0.25 + n * 10.0;
        let scene = ExactScene::from_obstacles(&truth);
        let dense = exact_reflections(source, &poses, &scene, &ExactOptions::default())?;
        let on_face = |p: &chirpmap::Point| {
            let along = (*p - a).dot(u);
            (*p - a).dot(n).abs() < 1e-9 && along > 1e-6 && along < 0.52 - 1e-6
        };
        if !dense.iter().flat_map(|r| r.bounces.iter()).any(on_face) {
            continue;
        }
        heard += 1;
        let echoes: Vec<chirpmap::Echo> = dense
            .iter()
            .map(|r| chirpmap::Echo::new(source, poses[r.pose_index].listener, r.delta_d_m, 1.0, 0.0, 0))
            .collect::<Result<_, _>>()
            .map_err(chirpmap::Error::Core)?;
        let observed = chirpmap::observed_points(&truth, &echoes).expect("reflections");
        let m = surface_metrics(&[segment(a, b)], &truth, Some(&observed), &MetricParams::default());
        assert!(m.walls.iter().any(|w| w.a == a && w.b == b), "j = {j}: face not scored, {observed:?}");
    }
    assert!(heard >= 50, "{heard}");
    // Every direct path blocked: no reflection, so no observed points.
    let truth = [
        slab(&[(-5.0, 2.0), (5.0, 2.0), (5.0, 2.3), (-5.0, 2.3)]),
        slab(&[(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]),
    ];
    let blocked =
        chirpmap::Echo::new(chirpmap::Point::new(-3.0, 0.0), chirpmap::Point::new(3.0, 0.0), 1.0, 1.0, 0.0, 0)
            .map_err(chirpmap::Error::Core)?;
    assert_eq!(chirpmap::observed_points(&truth, &[blocked]), None);
    Ok(())
}
