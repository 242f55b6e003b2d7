//! Issue 9 targets on exact echoes (crate::exact), side by side with the
//! paper's Algorithm 1. Run with `--nocapture` to see both mappers' numbers.

use chirpmap_core::exact::{ExactOptions, ExactScene, Pose, exact_echoes, exact_reflections};
use chirpmap_core::metrics::{MetricParams, sample_surfaces, surface_metrics, truth_distance};
use chirpmap_core::{
    AccumulationMapper, Circle, Echo, EvidenceParams, GridSpec, Mapper, MappingParams, Obstacle, Point, Polygon, Shape,
    SurfaceKind, map_evidence,
};

fn circle(x: f64, y: f64, r: f64) -> Obstacle {
    Obstacle {
        shape: Shape::Circle(Circle::new(Point::new(x, y), r).expect("valid circle")),
        roughness: 0.0,
        absorption: 0.0,
    }
}

fn polygon(v: &[(f64, f64)]) -> Obstacle {
    let pts = v.iter().map(|&(x, y)| Point::new(x, y)).collect();
    Obstacle { shape: Shape::Polygon(Polygon::new(pts).expect("valid polygon")), roughness: 0.0, absorption: 0.0 }
}

/// Poses on an ellipse-shaped closed loop.
fn loop_poses(centre: Point, rx: f64, ry: f64, n: usize) -> Vec<Pose> {
    (0..n)
        .map(|k| {
            let u = k as f64 * std::f64::consts::TAU / n as f64;
            Pose { t_s: k as f64, listener: Point::new(centre.x + rx * u.cos(), centre.y + ry * u.sin()) }
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() { f64::NAN } else { v[v.len() / 2] }
}

fn paper_highlights(echoes: &[Echo], spec: GridSpec) -> Vec<Point> {
    let mut m = AccumulationMapper::new(spec, MappingParams::default()).expect("valid mapper");
    for e in echoes {
        m.add_echo(e).expect("valid echo");
    }
    m.highlights().iter().map(|h| h.pos).collect()
}

#[test]
fn loop_past_three_circles() {
    // The circles of examples/three-circles; the listener walks a closed loop
    // between them and the source.
    let truth = [circle(-10.0, -20.0, 3.0), circle(6.0, -26.0, 4.0), circle(14.0, -14.0, 2.5)];
    let scene = ExactScene::from_obstacles(&truth);
    let source = Point::new(0.0, 0.0);
    let poses = loop_poses(Point::new(2.0, -12.0), 7.0, 4.0, 160);
    let echoes = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact echoes");
    let spec = GridSpec::from_bounds([-25.0, -40.0, 30.0, 10.0], 0.1, u128::MAX).expect("grid");
    let t0 = std::time::Instant::now();
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
    let t_evidence = t0.elapsed();
    let t0 = std::time::Instant::now();
    let paper = paper_highlights(&echoes, spec);
    let t_paper = t0.elapsed();

    let per_obstacle: Vec<f64> = truth
        .iter()
        .map(|o| {
            sample_surfaces(&map.surfaces, 0.05).iter().map(|&p| o.surface_distance(p)).fold(f64::INFINITY, f64::min)
        })
        .collect();
    let paper_per_obstacle: Vec<f64> =
        truth.iter().map(|o| paper.iter().map(|&p| o.surface_distance(p)).fold(f64::INFINITY, f64::min)).collect();
    let hl: Vec<f64> = map.highlights.iter().map(|h| truth_distance(&truth, h.pos)).collect();
    let paper_hl: Vec<f64> = paper.iter().map(|&p| truth_distance(&truth, p)).collect();
    let m = surface_metrics(&map.surfaces, &truth, None, &MetricParams::default());
    println!("loop past three circles: {} echoes", echoes.len());
    println!(
        "  evidence: {} surfaces, obstacle distances {per_obstacle:.3?}, {} highlights, median {:.3} m, max {:.3} m, precision {:.3}, time {t_evidence:?}",
        map.surfaces.len(),
        hl.len(),
        median(hl.clone()),
        hl.iter().copied().fold(0.0, f64::max),
        m.precision
    );
    println!(
        "  paper:    obstacle distances {paper_per_obstacle:.3?}, {} highlights, median {:.3} m, max {:.3} m, time {t_paper:?}",
        paper_hl.len(),
        median(paper_hl.clone()),
        paper_hl.iter().copied().fold(0.0, f64::max)
    );
    for s in &map.surfaces {
        println!(
            "    {:?} ({:.2}, {:.2})-({:.2}, {:.2}) support {} ambiguous {}",
            s.kind, s.p0.x, s.p0.y, s.p1.x, s.p1.y, s.support, s.ambiguous
        );
    }
    assert!(per_obstacle.iter().all(|&d| d <= 0.15), "{per_obstacle:?}");
    assert!(!hl.is_empty() && median(hl) <= 0.15);
    assert!(map.surfaces.iter().all(|s| !s.ambiguous), "a closed loop is not mirror-ambiguous");
}

#[test]
fn room_with_pillar_and_corner_echoes() {
    let (w, h) = (8.0, 6.0);
    let room = polygon(&[(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]);
    let pillar = circle(5.5, 3.8, 0.3);
    let truth = [room, pillar];
    let scene = ExactScene::from_obstacles(&truth);
    let source = Point::new(2.0, 2.5);
    let poses = loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, 160);
    let opts = ExactOptions { second_order: true, ..ExactOptions::default() };
    let refl = exact_reflections(source, &poses, &scene, &opts).expect("exact");
    let echoes = exact_echoes(source, &poses, &scene, &opts).expect("exact echoes");
    let n2 = refl.iter().filter(|r| r.order == 2).count();
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let t0 = std::time::Instant::now();
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
    let t_evidence = t0.elapsed();
    let t0 = std::time::Instant::now();
    let paper = paper_highlights(&echoes, spec);
    let t_paper = t0.elapsed();
    let observed: Vec<Point> = refl.iter().filter(|r| r.order == 1).flat_map(|r| r.bounces.clone()).collect();
    let m = surface_metrics(&map.surfaces, &truth, Some(&observed), &MetricParams::default());
    println!("room 8 x 6 m with a pillar: {} echoes ({n2} second-order)", echoes.len());
    println!(
        "  evidence: {} surfaces, P {:.3} R {:.3} F1 {:.3} chamfer {:?}, {} highlights, time {t_evidence:?}",
        map.surfaces.len(),
        m.precision,
        m.recall,
        m.f1,
        m.chamfer_m,
        map.highlights.len()
    );
    for wm in &m.walls {
        println!(
            "    wall ({:.1},{:.1})-({:.1},{:.1}): offset {:?} angle {:?}",
            wm.a.x, wm.a.y, wm.b.x, wm.b.y, wm.offset_m, wm.angle_deg
        );
    }
    for s in &map.surfaces {
        println!(
            "    {:?} ({:.3}, {:.3})-({:.3}, {:.3}) support {} ambiguous {}",
            s.kind, s.p0.x, s.p0.y, s.p1.x, s.p1.y, s.support, s.ambiguous
        );
    }
    let paper_hl: Vec<f64> = paper.iter().map(|&p| truth_distance(&truth, p)).collect();
    println!("  paper: {} highlights at {paper_hl:.3?} m from truth, time {t_paper:?}", paper.len());

    // The four strongest lines are the four walls: offset ≤ 2 cm, angle ≤ 1°.
    let lines: Vec<_> = map.surfaces.iter().filter(|s| s.kind == SurfaceKind::Line).take(4).collect();
    assert_eq!(lines.len(), 4);
    let top4 =
        surface_metrics(&lines.iter().map(|s| **s).collect::<Vec<_>>(), &truth[..1], None, &MetricParams::default());
    for wm in &top4.walls {
        let (off, ang) = (wm.offset_m.expect("wall matched"), wm.angle_deg.expect("wall matched"));
        assert!(off <= 0.02 && ang <= 1.0, "wall {wm:?}");
    }
    // The pillar within 0.1 m of a surface.
    let pillar_d = sample_surfaces(&map.surfaces, 0.05)
        .iter()
        .map(|&p| truth[1].surface_distance(p))
        .fold(f64::INFINITY, f64::min);
    println!("  pillar distance {pillar_d:.3} m");
    assert!(pillar_d <= 0.1, "pillar {pillar_d}");
    // Nothing inside the room more than 0.2 m from a true surface.
    let inside_bad: Vec<Point> = sample_surfaces(&map.surfaces, 0.05)
        .into_iter()
        .filter(|&p| truth[0].shape.contains(p) && truth_distance(&truth, p) > 0.2)
        .collect();
    assert!(
        inside_bad.is_empty(),
        "{} samples inside the room off every surface, e.g. {:?}",
        inside_bad.len(),
        inside_bad.first()
    );
    // No point beyond the walls: the corners' second reflections are their
    // walls' images, not reflectors (the vote for points put three there).
    let outside: Vec<_> =
        map.surfaces.iter().filter(|s| s.kind == SurfaceKind::Point && !truth[0].shape.contains(s.p0)).collect();
    assert!(outside.is_empty(), "points outside the room: {outside:?}");
}

#[test]
fn rough_reflector_from_sparse_poses_is_a_point() {
    // Table I at 50 ms in miniature: a listener at 10 m/s heard every 50 ms
    // (eight poses 0.5 m apart) passes a pole 15 m away whose rough face
    // scatters Δd by up to 1.5σ (σ = 0.1 m, the particle bins), and two
    // poses hear a stray return 8–9σ off. Consecutive ellipses cross metres
    // apart, so the envelope finds nothing; the strays break the runs of
    // three consecutive poses a line needs; the bands still overlap at the
    // pole, and the vote finds it there once the strays are trimmed.
    let pole = Point::new(2.0, -12.0);
    let truth = [circle(pole.x, pole.y, 0.2)];
    let scene = ExactScene::from_obstacles(&truth);
    let source = Point::new(0.0, 0.0);
    let poses: Vec<Pose> =
        (0..8).map(|k| Pose { t_s: 0.05 * k as f64, listener: Point::new(-3.0 + 0.5 * k as f64, 3.0) }).collect();
    let mut echoes = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact");
    assert_eq!(echoes.len(), 8);
    for (e, noise) in echoes.iter_mut().zip([0.05, -0.1, 0.8, 0.12, -0.9, 0.1, -0.05, 0.15]) {
        e.delta_d_m += noise;
        e.sigma_m = Some(0.1);
    }
    let spec = GridSpec::from_bounds([-50.0, -50.0, 50.0, 50.0], 0.1, u128::MAX).expect("grid");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("map");
    print_surfaces("rough pole, sparse poses", &map.surfaces);
    let off = |p: Point| truth_distance(&truth, p);
    let best = map.surfaces.iter().map(|s| off(s.p0)).fold(f64::INFINITY, f64::min);
    assert!(best <= 1.0, "nearest surface {best:.2} m off the pole");
    let hl = map.highlights.iter().map(|h| off(h.pos)).fold(f64::INFINITY, f64::min);
    assert!(hl <= 1.0, "nearest highlight {hl:.2} m off the pole");
}

#[test]
fn straight_pass_is_mirror_ambiguous() {
    // Source on the pass line: every ellipse is symmetric about y = 0, so the
    // wall y = 3 and its mirror y = −3 explain the same echoes.
    let truth = [polygon(&[(-5.0, 3.0), (15.0, 3.0), (15.0, 3.5), (-5.0, 3.5)])];
    let scene = ExactScene::from_obstacles(&truth);
    let source = Point::new(0.0, 0.0);
    let poses: Vec<Pose> =
        (0..60).map(|k| Pose { t_s: k as f64, listener: Point::new(1.0 + 0.15 * k as f64, 0.0) }).collect();
    let echoes = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact");
    let spec = GridSpec::from_bounds([-8.0, -8.0, 18.0, 8.0], 0.1, u128::MAX).expect("grid");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("map");
    for s in &map.surfaces {
        println!(
            "  {:?} ({:.3}, {:.3})-({:.3}, {:.3}) support {} ambiguous {}",
            s.kind, s.p0.x, s.p0.y, s.p1.x, s.p1.y, s.support, s.ambiguous
        );
    }
    assert!(!map.surfaces.is_empty());
    assert!(map.surfaces.iter().all(|s| s.ambiguous));
    // Both the wall and its mirror are reported, so the ghost is not presented as the wall.
    let near = |y: f64| {
        map.surfaces
            .iter()
            .any(|s| s.kind == SurfaceKind::Line && (s.p0.y - y).abs() < 0.05 && (s.p1.y - y).abs() < 0.05)
    };
    assert!(near(3.0) && near(-3.0));

    // A straight pass at a slant, source off the pass line: the listeners
    // are still collinear, so reflecting the wall's image source across
    // their line gives a second wall with the same echoes. Still ambiguous.
    let slant: Vec<Pose> = (0..60)
        .map(|k| Pose { t_s: k as f64, listener: Point::new(1.0 + 0.15 * k as f64, -1.0 + 0.05 * k as f64) })
        .collect();
    let echoes = exact_echoes(source, &slant, &scene, &ExactOptions::default()).expect("exact");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("map");
    print_surfaces("slanted straight pass", &map.surfaces);
    assert!(map.surfaces.iter().any(|s| s.kind == SurfaceKind::Line && (s.p0.y - 3.0).abs() < 0.05));
    assert!(map.surfaces.iter().all(|s| s.ambiguous));

    // A curved pass (a parabola bending 1.8 m): no mirror, not ambiguous.
    let curved: Vec<Pose> = (0..60)
        .map(|k| {
            let u = k as f64 - 30.0;
            Pose { t_s: k as f64, listener: Point::new(1.0 + 0.15 * k as f64, 0.3 - 0.002 * (900.0 - u * u)) }
        })
        .collect();
    let echoes = exact_echoes(source, &curved, &scene, &ExactOptions::default()).expect("exact");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("map");
    print_surfaces("curved pass", &map.surfaces);
    let wall = map.surfaces.iter().find(|s| s.kind == SurfaceKind::Line && (s.p0.y - 3.0).abs() < 0.05);
    assert!(wall.is_some_and(|w| !w.ambiguous && (w.p1.y - 3.0).abs() < 0.05), "{wall:?}");
}

fn print_surfaces(label: &str, surfaces: &[chirpmap_core::Surface]) {
    println!("  {label}:");
    for s in surfaces {
        println!(
            "    {:?} ({:.3}, {:.3})-({:.3}, {:.3}) support {} ambiguous {}",
            s.kind, s.p0.x, s.p0.y, s.p1.x, s.p1.y, s.support, s.ambiguous
        );
    }
}

/// Sparse poses (1 m apart, as Table I's 50 ms sampling at 10 m/s gives 0.5 m):
/// the wall's tangency points fall in different cells, no cell's log-odds
/// reaches the highlight threshold, yet every reported surface must be
/// represented among the highlights, on the surface.
#[test]
fn sparse_poses_still_give_a_highlight_per_surface() {
    let truth = [polygon(&[(-5.0, 4.0), (15.0, 4.0), (15.0, 4.5), (-5.0, 4.5)])];
    let scene = ExactScene::from_obstacles(&truth);
    let source = Point::new(0.0, -1.0);
    let poses: Vec<Pose> =
        (0..12).map(|k| Pose { t_s: k as f64, listener: Point::new(1.0 + k as f64, 0.2 * k as f64) }).collect();
    let echoes = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact");
    let spec = GridSpec::from_bounds([-8.0, -8.0, 18.0, 8.0], 0.1, u128::MAX).expect("grid");
    let params = EvidenceParams::default();
    let map = map_evidence(&echoes, spec, &params).expect("map");
    print_surfaces("sparse", &map.surfaces);
    assert!(!map.surfaces.is_empty(), "the wall is found");
    for s in &map.surfaces {
        let one = std::slice::from_ref(s);
        let d = map
            .highlights
            .iter()
            .map(|h| chirpmap_core::metrics::surface_distance(one, h.pos))
            .fold(f64::INFINITY, f64::min);
        assert!(d <= params.peak_radius_m.max(0.1), "surface {s:?} has no highlight (nearest {d} m)");
    }
    let wall = map.highlights.iter().map(|h| truth_distance(&truth, h.pos)).fold(f64::INFINITY, f64::min);
    assert!(wall <= 0.1, "a highlight on the wall face: {wall} m");
}

/// The evidence mapper votes lines and scans its grid on rayon's threads:
/// the map (every cell's bits), the surfaces and the highlights must not
/// depend on the thread count.
#[test]
fn room_map_is_identical_whatever_the_thread_count() {
    let room = polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)]);
    let scene = ExactScene::from_obstacles(&[room, circle(5.5, 3.8, 0.3)]);
    let poses = loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, 160);
    let opts = ExactOptions { second_order: true, ..ExactOptions::default() };
    let echoes = exact_echoes(Point::new(2.0, 2.5), &poses, &scene, &opts).expect("exact echoes");
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
        pool.install(|| map_evidence(&echoes, spec, &EvidenceParams::default())).expect("evidence map")
    };
    let one = on(1);
    assert!(one.surfaces.len() >= 4, "{} surfaces", one.surfaces.len());
    let bits = |m: &chirpmap_core::EvidenceMap| m.grid.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    for threads in [2, 3] {
        let many = on(threads);
        assert_eq!(bits(&one), bits(&many), "{threads} threads: grid");
        assert_eq!(one, many, "{threads} threads");
    }
}

/// An echoes file without `t` or `listener` columns gives every row t = 0
/// of listener 0. Measurements are then told apart by the listener's
/// position, in the file's order: the room walked without times maps as it
/// does with them (before, the whole walk was one measurement and the map
/// had no surface). Two microphones on one robot under one id are two poses
/// at each time, not one measurement holding both microphones' echoes.
#[test]
fn rows_without_times_are_poses_in_file_order() {
    let room = polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)]);
    let scene = ExactScene::from_obstacles(&[room, circle(5.5, 3.8, 0.3)]);
    let poses = loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, 160);
    let echoes = exact_echoes(Point::new(2.0, 2.5), &poses, &scene, &ExactOptions::default()).expect("exact echoes");
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let params = EvidenceParams::default();
    let timed = map_evidence(&echoes, spec, &params).expect("evidence map");
    assert!(timed.surfaces.iter().filter(|s| s.kind == SurfaceKind::Line).count() >= 4);
    let untimed: Vec<Echo> = echoes.iter().map(|e| Echo { t_s: 0.0, ..*e }).collect();
    let untimed = map_evidence(&untimed, spec, &params).expect("evidence map");
    assert_eq!(untimed.surfaces, timed.surfaces);
    assert_eq!(untimed.highlights, timed.highlights);
    // The grid's bits too, without printing half a million cells on failure.
    assert!(untimed.grid.data.iter().map(|v| v.to_bits()).eq(timed.grid.data.iter().map(|v| v.to_bits())));

    // A second microphone 0.3 m beside the first, the same id and times:
    // its echoes interleaved with the first's, pose by pose.
    let beside: Vec<Pose> =
        poses.iter().map(|p| Pose { t_s: p.t_s, listener: p.listener + Point::new(0.0, 0.3) }).collect();
    let second = exact_echoes(Point::new(2.0, 2.5), &beside, &scene, &ExactOptions::default()).expect("exact echoes");
    let mut both: Vec<Echo> = Vec::new();
    for t in 0..poses.len() {
        let at = |e: &&Echo| e.t_s == t as f64;
        both.extend(echoes.iter().filter(at).copied());
        both.extend(second.iter().filter(at).copied());
    }
    let map = map_evidence(&both, spec, &params).expect("evidence map");
    let lines = map.surfaces.iter().filter(|s| s.kind == SurfaceKind::Line && !s.ambiguous).count();
    assert!(lines >= 4, "{lines} walls from two microphones under one id");
    let most = map.surfaces.iter().map(|s| s.support).max().unwrap_or(0);
    assert!(most <= 2 * poses.len(), "support {most} from {} poses of two microphones", poses.len());
}

/// A grid cropped to part of a room (as `map --bounds` does) keeps the
/// walls beyond it: the line vote reaches every echo's tangent lines, so
/// the wall x = 0, 3 m outside the crop, still explains its echoes. Before,
/// the vote covered only lines within the grid's half-diagonal: the wall
/// was lost, and its echoes became compact reflectors inside the crop where
/// nothing is (a synthesized room walk gave two, at (7.55, 1.32) and
/// (7.31, 5.30)).
#[test]
fn cropping_the_grid_keeps_walls_beyond_it() {
    let room = polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)]);
    let truth = [room, circle(5.5, 3.8, 0.3)];
    let scene = ExactScene::from_obstacles(&truth);
    let poses = loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, 160);
    let echoes = exact_echoes(Point::new(2.0, 2.5), &poses, &scene, &ExactOptions::default()).expect("exact echoes");
    let params = EvidenceParams::default();
    let full = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let crop = GridSpec::from_bounds([3.0, 1.0, 9.0, 7.0], 0.1, u128::MAX).expect("grid");
    let (whole, cropped) =
        (map_evidence(&echoes, full, &params).expect("map"), map_evidence(&echoes, crop, &params).expect("map"));
    let lines = |m: &chirpmap_core::EvidenceMap| -> Vec<chirpmap_core::Surface> {
        m.surfaces.iter().filter(|s| s.kind == SurfaceKind::Line).copied().collect()
    };
    assert_eq!(lines(&whole).len(), 4, "{:?}", whole.surfaces);
    for w in lines(&whole) {
        let kept = lines(&cropped).iter().any(|c| c.p0.dist(w.p0) < 0.01 && c.p1.dist(w.p1) < 0.01);
        assert!(kept, "wall {w:?} lost by the crop: {:?}", cropped.surfaces);
    }
    for s in &cropped.surfaces {
        let d = truth_distance(&truth, s.p0).min(truth_distance(&truth, s.p1));
        assert!(d <= 0.35, "{s:?} is {d:.2} m from every surface");
    }
}

/// Rows repeated in a file (each echo three times over) are the same
/// evidence: the same map, bit for bit, as the echoes once (a walk's echoes
/// repeated 99 times took 34 s and gave six points beside its wall).
#[test]
fn repeated_echoes_are_the_same_map() {
    let room = polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)]);
    let scene = ExactScene::from_obstacles(&[room, circle(5.5, 3.8, 0.3)]);
    let poses = loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, 60);
    let echoes = exact_echoes(Point::new(2.0, 2.5), &poses, &scene, &ExactOptions::default()).expect("exact echoes");
    let thrice: Vec<_> = echoes.iter().chain(&echoes).chain(&echoes).cloned().collect();
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let params = EvidenceParams::default();
    let (once, again) =
        (map_evidence(&echoes, spec, &params).expect("map"), map_evidence(&thrice, spec, &params).expect("map"));
    assert_eq!(once.surfaces, again.surfaces);
    assert!(once.grid.data.iter().zip(&again.grid.data).all(|(a, b)| a.to_bits() == b.to_bits()));
    assert_eq!(once.highlights.len(), again.highlights.len());
}

/// A grid too wide for the line vote's offset bins (at most 2²⁰ a row):
/// the bins are widened to cover its whole reach, up to twice what the
/// echoes' σ asks for, and past that the map is refused. Before, the row was
/// cut at 2²⁰ bins from one edge, so walls whose offsets lay beyond were
/// never voted for: here, a room 30 km from the centre of an 80 km grid
/// lost all four walls (a helper's audit, session 27, found a wall lost on
/// a 2 000 km grid).
#[test]
fn a_grid_too_wide_for_the_vote_keeps_its_walls_or_is_refused() {
    let dx = 30_000.0;
    let room = polygon(&[(dx, 0.0), (dx + 8.0, 0.0), (dx + 8.0, 6.0), (dx, 6.0)]);
    let scene = ExactScene::from_obstacles(&[room]);
    let poses = loop_poses(Point::new(dx + 4.0, 3.0), 2.6, 1.8, 160);
    let echoes =
        exact_echoes(Point::new(dx + 2.0, 2.5), &poses, &scene, &ExactOptions::default()).expect("exact echoes");
    let params = EvidenceParams::default();
    let wide = GridSpec::from_bounds([-40_000.0, -3.0, 40_000.0, 9.0], 1.0, u128::MAX).expect("grid");
    let map = map_evidence(&echoes, wide, &params).expect("map");
    let walls = [
        ((dx, 0.0), (dx + 8.0, 0.0)),
        ((dx + 8.0, 0.0), (dx + 8.0, 6.0)),
        ((dx, 6.0), (dx + 8.0, 6.0)),
        ((dx, 0.0), (dx, 6.0)),
    ];
    for (a, b) in walls {
        let (a, b) = (Point::new(a.0, a.1), Point::new(b.0, b.1));
        let on = |p: Point| {
            let d = b - a;
            ((p - a).x * d.y - (p - a).y * d.x).abs() / d.norm() < 0.05
        };
        let found = map.surfaces.iter().any(|s| s.kind == SurfaceKind::Line && on(s.p0) && on(s.p1));
        assert!(found, "wall {a}–{b} lost: {:?}", map.surfaces);
    }
    let wider = GridSpec::from_bounds([-100_000.0, -3.0, 100_000.0, 9.0], 1.0, u128::MAX).expect("grid");
    let err = map_evidence(&echoes, wider, &params).expect_err("bins widened 3×");
    assert!(err.to_string().contains("offset bins"), "{err}");
}

#[test]
fn pole_beside_a_straight_walk_is_one_point() {
    // The paper's field environment B: a 0.1 m pole 4 m from the source, a
    // listener walking a straight line past both, Δd with a few millimetres
    // of noise (as ranged from a recording). Consecutive ellipses also cross
    // on the far side of the walk; those crossings lie on a curve, not a
    // point, and must not become surfaces once the pole explains its echoes.
    let pole = Point::new(1.0, -4.0);
    let truth = [circle(pole.x, pole.y, 0.1)];
    let scene = ExactScene::from_obstacles(&truth);
    let source = Point::new(0.0, 0.0);
    let poses: Vec<Pose> =
        (0..1000).map(|k| Pose { t_s: 0.02 * k as f64, listener: Point::new(-10.0 + 0.02 * k as f64, 3.0) }).collect();
    let mut echoes = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact");
    // Uniform noise of ±5 mm from a fixed LCG (σ ≈ 2.9 mm).
    let mut x = 7u64;
    for e in &mut echoes {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        e.delta_d_m += 0.01 * ((x >> 11) as f64 / (1u64 << 53) as f64 - 0.5);
    }
    let spec = GridSpec::from_bounds([-15.0, -10.0, 15.0, 8.0], 0.1, u128::MAX).expect("grid");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("map");
    print_surfaces("pole beside a straight walk", &map.surfaces);
    let off_pole = |p: Point| (p.dist(pole) - 0.1).abs();
    assert_eq!(map.surfaces.len(), 1, "one surface, the pole");
    let s = &map.surfaces[0];
    assert_eq!(s.kind, SurfaceKind::Point);
    assert!(off_pole(s.p0) < 0.1, "pole found {:.3} m off its surface", off_pole(s.p0));
    // Most of its echoes (echoes a rejected line candidate owns take no part
    // in the envelope: the module docs).
    assert!(s.support * 10 >= echoes.len() * 7, "the pole explains {} of {} echoes", s.support, echoes.len());
    // Its mirror across the walk, (1, 10), is 5.9 m further from the source:
    // the echoes tell the two apart, so the pole is not flagged ambiguous.
    assert!(!s.ambiguous, "a pole off the line of source and walk is not mirror-ambiguous");

    // A walk along y = 2 through the source (its poses miss the source by
    // 1 cm): the pole's mirror across the walk, (1, 8), is as far from every
    // focus as the pole, so the echoes cannot tell them apart; flagged.
    let source = Point::new(0.0, 2.0);
    let poses: Vec<Pose> =
        (0..1000).map(|k| Pose { t_s: 0.02 * k as f64, listener: Point::new(-10.01 + 0.02 * k as f64, 2.0) }).collect();
    let echoes = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("map");
    print_surfaces("pole beside a walk through the source", &map.surfaces);
    let points: Vec<_> = map.surfaces.iter().filter(|s| s.kind == SurfaceKind::Point).collect();
    assert!(!points.is_empty() && points.iter().all(|s| s.ambiguous), "on the walk's line: ambiguous");
}

/// The echoes of tests/data/`name`/echoes.csv: the eight columns of
/// echoes.csv in their order, and `sigma_m` when a ninth is there (files
/// written by a generator, so no checks but the echo's own).
fn echoes_of(name: &str) -> Vec<Echo> {
    let path = format!("{}/tests/data/{name}/echoes.csv", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).expect("test data");
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().expect("number")).collect();
            let e =
                Echo::new(Point::new(v[0], v[1]), Point::new(v[2], v[3]), v[4], v[5], v[6], v[7] as u32).expect("echo");
            match v.get(8) {
                Some(&s) => e.with_sigma_m(s).expect("sigma"),
                None => e,
            }
        })
        .collect()
}

/// Echoes of a 0.2 m pole from a listener walking an arc of radius 3.7 m
/// past it (160 poses, σ = 2 cm noise): `scene_sweep`'s scene 246, written
/// out by it (tests/data/arc-past-pole/echoes.csv). Along the walk's last
/// 29 poses, almost straight, the pole's echoes are also those of a line
/// 9 m away on the far side; found first, that line took them, and the
/// rest no longer piled up on the pole: ten points, nine of them strays,
/// on any grid reaching the line. The envelope now looks for compact
/// reflectors once more with ambiguous lines' echoes open, and a line a
/// reflector of twice its support explains is dropped before the search.
#[test]
fn pole_past_an_arc_walk_is_one_point_whatever_the_grid() {
    let echoes = echoes_of("arc-past-pole");
    assert_eq!(echoes.len(), 160);
    let pole = circle(2.36, 3.10, 0.20);
    // The sweep's grid (the scene's box plus 2 m), and one 14 m wider each way.
    for pad in [2.0, 14.0] {
        let spec =
            GridSpec::from_bounds([-3.67 - pad, -2.45 - pad, 2.63 + pad, 3.35 + pad], 0.1, u128::MAX).expect("grid");
        let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
        print_surfaces(&format!("pole past an arc walk, grid padded {pad} m"), &map.surfaces);
        let off: Vec<f64> = map.surfaces.iter().map(|s| pole.surface_distance(s.p0)).collect();
        assert!(off.iter().any(|&d| d <= 0.15), "pole not found: {off:?}");
        assert!(off.iter().all(|&d| d <= 0.35), "surfaces more than 0.35 m off the pole: {off:?}");
    }
}

/// 20 poses of a walk past a 0.058 m pole at (2.19, 0.65), with a wall at
/// y = −3.66 and σ = 2 cm of noise (a scene the review of session 26
/// generated; tests/data/wall-walk-pole). Its ambiguous lines were taken
/// by a point on the pole that rested on echoes of another ambiguous line;
/// the search without them then found the pole's mirror and nothing near
/// the pole. A line is dropped now only if the new search's points take its
/// echoes, so the line through the pole stays.
#[test]
fn a_line_is_dropped_only_for_a_reflector_found_again() {
    let echoes = echoes_of("wall-walk-pole");
    assert_eq!(echoes.len(), 40);
    let pole = Point::new(2.1865, 0.6532);
    // `map --echoes`'s default grid for these echoes.
    let spec = GridSpec::from_bounds([-5.9, -3.8, 9.8, 9.8], 0.1, u128::MAX).expect("grid");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
    print_surfaces("walk past a pole beside a wall", &map.surfaces);
    let nearest = map
        .surfaces
        .iter()
        .map(|s| chirpmap_core::geometry::point_segment_distance(pole, s.p0, s.p1))
        .fold(f64::INFINITY, f64::min);
    assert!(nearest <= 0.2, "nothing within 0.2 m of the pole (nearest {nearest:.2} m)");
}

/// A room's four walls from precise echoes (σ = 1 cm, as matched-filter
/// ranging gives) whatever the grid's bounds and cell. With the line vote's
/// offset bins a whole cell wide, a wall's offset fell between two bins, the
/// peak's own line missed the 3 cm band, screening dropped it, and one to
/// three walls were found depending on the bounds and cell (6 of these 12
/// maps had all four; `lines::vote_rho_bin`).
#[test]
fn room_walls_from_precise_echoes_whatever_the_grid() {
    let (w, h) = (8.0, 6.0);
    let truth = [polygon(&[(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)])];
    let scene = ExactScene::from_obstacles(&truth);
    let source = Point::new(2.0, 1.5);
    // A wandering loop (so no wall is mirror-ambiguous), 400 poses.
    let poses: Vec<Pose> = (0..400)
        .map(|k| {
            let u = k as f64 * std::f64::consts::TAU / 400.0;
            let listener =
                Point::new(4.0 + 2.6 * u.cos() + 0.3 * (3.0 * u).sin(), 3.0 + 1.8 * u.sin() + 0.3 * (2.0 * u).cos());
            Pose { t_s: k as f64, listener }
        })
        .collect();
    let echoes: Vec<Echo> = exact_echoes(source, &poses, &scene, &ExactOptions::default())
        .expect("exact echoes")
        .into_iter()
        .map(|e| e.with_sigma_m(0.01).expect("sigma"))
        .collect();
    let walls = [(0.0, true), (w, true), (0.0, false), (h, false)];
    let mut complete = 0;
    let mut cases = 0;
    for bounds in [[-6.0, -6.0, 14.0, 12.0], [-1.0, -1.0, 9.0, 7.0], [-3.0, -2.0, 11.0, 9.0], [-2.02, -1.01, 10.0, 8.0]]
    {
        for cell in [0.05, 0.1, 0.2] {
            let spec = GridSpec::from_bounds(bounds, cell, u128::MAX).expect("grid");
            let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
            let found = walls
                .iter()
                .filter(|&&(at, vertical)| {
                    map.surfaces.iter().any(|s| {
                        let (a, b) = if vertical { (s.p0.x, s.p1.x) } else { (s.p0.y, s.p1.y) };
                        s.kind == SurfaceKind::Line && (a - at).abs() <= 0.02 && (b - at).abs() <= 0.02
                    })
                })
                .count();
            println!("bounds {bounds:?} cell {cell}: {found} of 4 walls, {} surfaces", map.surfaces.len());
            cases += 1;
            complete += usize::from(found == 4);
        }
    }
    assert_eq!(complete, cases, "every grid gives the four walls");
}

/// The room's walls when a third of the echoes are clutter: 2 000 poses of a
/// wandering walk, four noisy wall echoes (σ = 1 cm) and two false echoes (Δd
/// uniform in 0.5–10 m) per pose. A point reflector needs its vote to stand
/// out of the clutter's: seeded on any cell with `min_support` votes, the
/// vote for points fitted two points to echoes that agree by chance.
#[test]
fn room_walls_in_clutter_and_nothing_else() {
    let (w, h) = (8.0, 6.0);
    let truth = [polygon(&[(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)])];
    let map = room_walk_in_clutter(&truth);
    print_surfaces("room walls in clutter", &map.surfaces);
    let on_wall = |p: Point| p.x.abs().min((p.x - w).abs()).min(p.y.abs()).min((p.y - h).abs()) <= 0.02;
    assert_eq!(map.surfaces.len(), 4, "four walls and nothing else");
    assert!(map.surfaces.iter().all(|s| s.kind == SurfaceKind::Line && on_wall(s.p0) && on_wall(s.p1)));
}

/// The same walk with a 0.3 m pillar in the room: every surface on a wall or
/// the pillar. The envelope once left four points more than 0.35 m off
/// every true surface here (higher-order echoes of pillar and walls; a
/// known limit; none by session 26), and the
/// vote for points, without its consensus rule, added six more.
#[test]
fn pillar_in_clutter_gets_no_stray_points_from_the_vote() {
    let (w, h) = (8.0, 6.0);
    let truth = [polygon(&[(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]), circle(5.0, 2.0, 0.3)];
    let map = room_walk_in_clutter(&truth);
    print_surfaces("pillar in clutter", &map.surfaces);
    let stray = map.surfaces.iter().filter(|s| truth_distance(&truth, s.p0) > 0.35).count();
    assert_eq!(stray, 0, "surfaces more than 0.35 m off every true surface");
    let pillar = map.surfaces.iter().map(|s| truth[1].surface_distance(s.p0)).fold(f64::INFINITY, f64::min);
    assert!(pillar <= 0.1, "pillar {pillar:.3} m off");
}

/// A loop in the 8 m × 6 m room (σ = 1 cm) and, at five poses, a second
/// measurement whose only echo is a false one of 11 m (its first echo, the
/// wall's, missed; clutter heard). Each such measurement carves free space
/// inside an 11 m ellipse, across every wall. Any two carvings made a wall
/// sample free, so the free-space ghost test removed all four walls; the
/// carving must outweigh the wall's own support.
#[test]
fn room_walls_survive_measurements_of_false_echoes_only() {
    let (w, h) = (8.0, 6.0);
    let truth = [polygon(&[(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)])];
    let source = Point::new(2.0, 1.5);
    let n = 200;
    let poses = loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, n);
    let mut echoes: Vec<Echo> =
        exact_echoes(source, &poses, &ExactScene::from_obstacles(&truth), &ExactOptions::default()).expect("echoes");
    for p in poses.iter().step_by(n / 5) {
        echoes.push(Echo::new(source, p.listener, 11.0, 1.0, p.t_s + 0.5, 0).expect("false echo"));
    }
    let echoes: Vec<Echo> = echoes.into_iter().map(|e| e.with_sigma_m(0.01).expect("sigma")).collect();
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
    print_surfaces("room with measurements of false echoes only", &map.surfaces);
    let on_wall = |p: Point| p.x.abs().min((p.x - w).abs()).min(p.y.abs()).min((p.y - h).abs()) <= 0.02;
    let walls = map.surfaces.iter().filter(|s| s.kind == SurfaceKind::Line && on_wall(s.p0) && on_wall(s.p1)).count();
    assert_eq!(walls, 4, "four walls");
}

/// Evidence map of a 2 000-pose wandering walk in the 8 m × 6 m room of
/// `truth`, with noisy echoes and two false echoes per pose.
fn room_walk_in_clutter(truth: &[Obstacle]) -> chirpmap_core::EvidenceMap {
    let scene = ExactScene::from_obstacles(truth);
    let source = Point::new(2.0, 1.5);
    let n = 2000;
    let poses: Vec<Pose> = (0..n)
        .map(|k| {
            let u = 0.002 * k as f64;
            let listener =
                Point::new(4.0 + 2.6 * u.cos() + 0.3 * (3.1 * u).sin(), 3.0 + 1.8 * u.sin() + 0.3 * (2.3 * u).cos());
            Pose { t_s: 0.01 * k as f64, listener }
        })
        .collect();
    let mut echoes: Vec<Echo> = exact_echoes(source, &poses, &scene, &ExactOptions::default())
        .expect("exact echoes")
        .into_iter()
        .map(|e| e.with_sigma_m(0.01).expect("sigma"))
        .collect();
    let mut x = 11u64;
    let mut uniform = || {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    // Wall echoes with noise of σ = 1 cm (the sum of three uniforms).
    for e in &mut echoes {
        e.delta_d_m += 0.02 * (uniform() + uniform() + uniform() - 1.5);
    }
    for p in &poses {
        for _ in 0..2 {
            let dd = 0.5 + 9.5 * uniform();
            let e = Echo::new(source, p.listener, dd, 1.0, p.t_s, 0).expect("echo");
            echoes.push(e.with_sigma_m(0.01).expect("sigma"));
        }
    }
    let spec = GridSpec::from_bounds([-6.0, -6.0, 14.0, 12.0], 0.1, u128::MAX).expect("grid");
    map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map")
}

/// Echoes of a 0.3 m pillar from a listener circling beside it (passing
/// 8 cm from its surface), as `map --wav` ranges a synthesized walk round a
/// pillar (session 22): Δd with noise of σ = `sigma_m` (the sum of three
/// uniforms), and, when `missed` is set, 100 consecutive measurements whose
/// pillar echo was missed and a later one (+0.3 m) reported instead; `n`
/// poses round the 2 m circle.
fn pillar_circled(sigma_m: f64, missed: bool, n: usize) -> (Vec<Echo>, Obstacle) {
    let pillar = circle(5.5, 3.8, 0.3);
    let scene = ExactScene::from_obstacles(std::slice::from_ref(&pillar));
    let source = Point::new(2.0, 2.5);
    let poses: Vec<Pose> = (0..n)
        .map(|k| {
            let u = k as f64 * std::f64::consts::TAU / n as f64 - std::f64::consts::FRAC_PI_2;
            Pose { t_s: 0.01 * k as f64, listener: Point::new(4.0 + 2.0 * u.cos(), 3.2 + 2.0 * u.sin()) }
        })
        .collect();
    let mut echoes = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact echoes");
    // Where the listener passes behind the pillar the echo merges with the
    // direct sound; ranging resolves neither (nor a negative Δd with noise).
    echoes.retain(|e| e.delta_d_m > 0.3);
    let mut x = 7u64;
    let mut uniform = || {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    for (i, e) in echoes.iter_mut().enumerate() {
        e.delta_d_m += 2.0 * sigma_m * (uniform() + uniform() + uniform() - 1.5);
        if missed && (200..300).contains(&i) {
            e.delta_d_m += 0.3;
        }
    }
    let echoes = echoes.into_iter().map(|e| e.with_sigma_m(sigma_m).expect("sigma")).collect();
    (echoes, pillar)
}

/// One pillar is one compact reflector, whatever the echoes' noise: the
/// first-order circle model was off by up to 4.7 cm this close, and its fit
/// never converged with the radius at its bound, so echoes ranged to 1–2 cm
/// made 25–28 points (the pillar's echoes split among them).
#[test]
fn pillar_circled_closely_with_noisy_echoes_is_one_point() {
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    for sigma_m in [0.005, 0.01, 0.02] {
        let (echoes, pillar) = pillar_circled(sigma_m, false, 1000);
        let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
        print_surfaces(&format!("pillar circled, sigma {sigma_m} m"), &map.surfaces);
        assert_eq!(map.surfaces.len(), 1, "sigma {sigma_m}: one surface");
        let s = map.surfaces[0];
        assert_eq!(s.kind, SurfaceKind::Point);
        assert!(pillar.surface_distance(s.p0) <= 0.03, "sigma {sigma_m}: {:.3} m off", pillar.surface_distance(s.p0));
        assert!(10 * s.support >= 9 * echoes.len(), "sigma {sigma_m}: {} of {} echoes", s.support, echoes.len());
    }
}

/// A measurement whose first echo was missed carves free space through the
/// reflector it missed. A hundred such measurements (a tenth) carved the
/// pillar free, when any two carvings made a point free: its crossings were
/// dropped and its echoes seeded points elsewhere. Carvings now count against
/// the echoes a reflector explains, as they do for lines.
#[test]
fn a_pillar_outweighs_the_measurements_that_missed_it() {
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let (echoes, pillar) = pillar_circled(0.01, true, 1000);
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
    print_surfaces("pillar circled, 100 measurements that missed it", &map.surfaces);
    let s = map.surfaces[0];
    assert_eq!(s.kind, SurfaceKind::Point, "the strongest surface is the pillar");
    assert!(pillar.surface_distance(s.p0) <= 0.03, "{:.3} m off", pillar.surface_distance(s.p0));
    assert!(10 * s.support >= 8 * echoes.len(), "{} of {} echoes", s.support, echoes.len());
    assert!(map.surfaces.len() <= 4, "{} surfaces", map.surfaces.len());
}

/// A straight walk past a 0.1 m pole (field B's geometry, 0.1 m steps),
/// echoes with Gaussian noise of σ = 1 cm, twenty draws. With noise the
/// densest crossing may lie 0.2–0.3 m off the pole, in space truly carved
/// free: free space was tested there rather than where the pole is reported,
/// the pole was refused, and its echoes went to ghost points on the far side
/// of the walk (found by the review of session 22).
#[test]
fn a_pole_beside_a_noisy_walk_is_tested_for_free_space_where_it_is_reported() {
    let pole = circle(1.0, -4.0, 0.1);
    let scene = ExactScene::from_obstacles(std::slice::from_ref(&pole));
    let source = Point::new(0.0, 0.0);
    let poses: Vec<Pose> =
        (0..200).map(|k| Pose { t_s: 0.1 * k as f64, listener: Point::new(-10.0 + 0.1 * k as f64, 3.0) }).collect();
    let exact = exact_echoes(source, &poses, &scene, &ExactOptions::default()).expect("exact echoes");
    let spec = GridSpec::from_bounds([-15.0, -10.0, 15.0, 8.0], 0.1, u128::MAX).expect("grid");
    let (mut ghosts, mut found) = (0, 0);
    for draw in 0..20u64 {
        let mut x = 1000 + draw;
        let mut uniform = || {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let echoes: Vec<Echo> = exact
            .iter()
            .map(|e| {
                // Box–Muller.
                let z = (-2.0 * uniform().ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos();
                let mut e = e.with_sigma_m(0.01).expect("sigma");
                e.delta_d_m += 0.01 * z;
                e
            })
            .collect();
        let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
        let off: Vec<f64> = map.surfaces.iter().map(|s| pole.surface_distance(s.p0)).collect();
        ghosts += off.iter().filter(|&&d| d > 0.35).count();
        found += usize::from(off.iter().any(|&d| d <= 0.05));
    }
    println!("pole beside a noisy walk, 20 draws: found in {found}, {ghosts} surfaces more than 0.35 m off");
    assert_eq!(found, 20, "the pole in every draw");
    assert!(ghosts <= 2, "{ghosts} surfaces more than 0.35 m off the pole");
}

/// The same walk sampled every 3 mm (4 000 poses; `map --wav --period-ms 3`
/// at 1 m/s): the envelope paired a pose only with one of the next eight at
/// least 5 cm away, found none, and the pillar gave no surface (found by the
/// review of session 22).
#[test]
fn a_pillar_circled_by_densely_sampled_poses_is_one_point() {
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let (echoes, pillar) = pillar_circled(0.01, false, 4000);
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
    print_surfaces("pillar circled, 4 000 poses 3 mm apart", &map.surfaces);
    assert_eq!(map.surfaces.len(), 1, "one surface");
    let s = map.surfaces[0];
    assert!(pillar.surface_distance(s.p0) <= 0.03, "{:.3} m off", pillar.surface_distance(s.p0));
    assert!(10 * s.support >= 9 * echoes.len(), "{} of {} echoes", s.support, echoes.len());
}

/// The walk sampled every millimetre (12 566 poses), with a tracker's
/// jitter of 3 mm on each pose: the path travelled runs well ahead of the
/// straight distance, and the eight poses from where it reached the baseline
/// were all within 1–2 cm, so again no pair and no surface (the second
/// review of session 22).
#[test]
fn a_pillar_circled_by_jittery_dense_poses_is_one_point() {
    let spec = GridSpec::from_bounds([-3.0, -3.0, 11.0, 9.0], 0.1, u128::MAX).expect("grid");
    let (mut echoes, pillar) = pillar_circled(0.01, false, 12_566);
    let mut x = 99u64;
    let mut uniform = || {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    for e in &mut echoes {
        // Box–Muller, one coordinate each.
        let (r, a) = ((-2.0 * uniform().ln()).sqrt(), std::f64::consts::TAU * uniform());
        e.listener = Point::new(e.listener.x + 0.003 * r * a.cos(), e.listener.y + 0.003 * r * a.sin());
    }
    let map = map_evidence(&echoes, spec, &EvidenceParams::default()).expect("evidence map");
    print_surfaces("pillar circled, 12 566 jittery poses 1 mm apart", &map.surfaces);
    let s = map.surfaces.first().expect("a surface");
    assert!(pillar.surface_distance(s.p0) <= 0.03, "{:.3} m off", pillar.surface_distance(s.p0));
    assert!(10 * s.support >= 9 * echoes.len(), "{} of {} echoes", s.support, echoes.len());
}
