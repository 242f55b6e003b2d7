//! The mapping benchmark (issue 9): both mappers side by side on a fixed
//! suite of scenes, each judged against truth that is not a mapper's own
//! output — exact reflection geometry (image sources, specular points), the
//! particle simulator, and synthesized recordings.
//!
//! Cases:
//! - the paper's Table I scenes (3 random circles, one listener, spin 0) at
//!   1, 10 and 50 ms sampling, particle echoes, `runs` runs each;
//! - a loop past the three circles of `examples/three-circles`, exact echoes;
//! - an 8 m × 6 m room with a pillar, a loop inside, exact first- and
//!   second-order (corner) echoes;
//! - an L-shaped corridor walked end to end, exact first-order echoes;
//! - the paper's field environments A (a wall) and B (a pole, §IV), from
//!   particle echoes and from `synth` recordings at 20 dB SNR ranged frame
//!   by frame (the `map --wav` pipeline);
//! - the room with a pillar from a `synth` recording of a listener circling
//!   inside it.

use chirpmap::core::exact::{ExactOptions, ExactScene, Pose, exact_echoes};
use chirpmap::core::{Circle, Polygon, Shape};
use chirpmap::{
    ChirpSpec, Echo, MapOptions, MapperKind, MovingOptions, Obstacle, Point, PoseTrack, Scene, WavMethod, evaluate,
    map_echoes,
};
use std::time::Instant;

/// One benchmark scene: echoes and the truth they came from.
#[derive(Debug, Clone)]
pub struct Case {
    /// Scene name (`table1-10ms`, `room-pillar`, …).
    pub name: String,
    /// Where the echoes came from: `exact`, `particles` or `synth`.
    pub echoes_from: &'static str,
    /// Run index (Table I scenes; 0 otherwise).
    pub run: u64,
    /// The echoes.
    pub echoes: Vec<Echo>,
    /// The true obstacles.
    pub truth: Vec<Obstacle>,
    /// Map bounds `[x_min, y_min, x_max, y_max]` (m).
    pub bounds: [f64; 4],
}

/// One mapper on one case.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// The case's name.
    pub case: String,
    /// Where its echoes came from.
    pub echoes_from: &'static str,
    /// Run index.
    pub run: u64,
    /// `paper` or `evidence`.
    pub mapper: &'static str,
    /// Echoes mapped.
    pub n_echoes: usize,
    /// Highlights found.
    pub n_highlights: usize,
    /// Surfaces found (evidence mapper).
    pub n_surfaces: usize,
    /// Paper §III.A scores.
    pub score_obstacle: Option<f64>,
    /// Paper §III.A scores.
    pub score_highlight: Option<f64>,
    /// Surface precision within 0.1 m.
    pub precision: f64,
    /// Surface recall within 0.1 m.
    pub recall: f64,
    /// F1 of the two.
    pub f1: f64,
    /// Symmetric Chamfer distance (m).
    pub chamfer_m: Option<f64>,
    /// Median wall offset error over matched walls (m). The median, as the
    /// back face of a thick wall, never heard, matches the front face's line
    /// at the wall's thickness.
    pub wall_offset_median_m: Option<f64>,
    /// Median wall angle error over matched walls (deg).
    pub wall_angle_median_deg: Option<f64>,
    /// Walls (polygon edges ≥ 0.5 m) with a matching line / all walls.
    pub walls_matched: (usize, usize),
    /// Median distance of the highlights to the nearest true surface (m).
    pub highlight_median_m: Option<f64>,
    /// Mapping time (s).
    pub elapsed_s: f64,
}

fn circle(x: f64, y: f64, r: f64) -> Result<Obstacle, String> {
    let c = Circle::new(Point::new(x, y), r).map_err(|e| e.to_string())?;
    Ok(Obstacle { shape: Shape::Circle(c), roughness: 0.0, absorption: 0.0 })
}

fn polygon(v: &[(f64, f64)]) -> Result<Obstacle, String> {
    let p = Polygon::new(v.iter().map(|&(x, y)| Point::new(x, y)).collect()).map_err(|e| e.to_string())?;
    Ok(Obstacle { shape: Shape::Polygon(p), roughness: 0.0, absorption: 0.0 })
}

/// `n` poses on an ellipse-shaped closed loop, one per second.
fn loop_poses(centre: Point, rx: f64, ry: f64, n: usize) -> Vec<Pose> {
    (0..n)
        .map(|k| {
            let u = std::f64::consts::TAU * k as f64 / n as f64;
            Pose { t_s: k as f64, listener: Point::new(centre.x + rx * u.cos(), centre.y + ry * u.sin()) }
        })
        .collect()
}

/// Poses every `step_m` along a polyline.
fn path_poses(points: &[(f64, f64)], step_m: f64) -> Vec<Pose> {
    let mut out = Vec::new();
    for w in points.windows(2) {
        let (a, b) = (Point::new(w[0].0, w[0].1), Point::new(w[1].0, w[1].1));
        let n = (a.dist(b) / step_m).ceil().max(1.0) as usize;
        for k in 0..n {
            let listener = a + (b - a) * (k as f64 / n as f64);
            out.push(Pose { t_s: out.len() as f64 * 0.1, listener });
        }
    }
    out
}

fn exact_case(
    name: &str,
    source: Point,
    poses: &[Pose],
    truth: Vec<Obstacle>,
    second_order: bool,
    bounds: [f64; 4],
) -> Result<Case, String> {
    let scene = ExactScene::from_obstacles(&truth);
    let opts = ExactOptions { second_order, ..ExactOptions::default() };
    let echoes = exact_echoes(source, poses, &scene, &opts).map_err(|e| format!("{name}: {e}"))?;
    Ok(Case { name: name.into(), echoes_from: "exact", run: 0, echoes, truth, bounds })
}

/// The cases with exact echoes.
pub fn exact_cases() -> Result<Vec<Case>, String> {
    let circles = vec![circle(-10.0, -20.0, 3.0)?, circle(6.0, -26.0, 4.0)?, circle(14.0, -14.0, 2.5)?];
    let room = polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)])?;
    // An L-shaped corridor 2 m wide: the walkable L is bounded by an outer
    // and an inner wall line.
    let outer = polygon(&[(0.0, 0.0), (14.0, 0.0), (14.0, 12.0), (12.0, 12.0), (12.0, 2.0), (0.0, 2.0)])?;
    Ok(vec![
        exact_case(
            "loop-circles",
            Point::new(0.0, 0.0),
            &loop_poses(Point::new(2.0, -12.0), 7.0, 4.0, 160),
            circles,
            false,
            [-25.0, -40.0, 30.0, 10.0],
        )?,
        exact_case(
            "room-pillar",
            Point::new(2.0, 2.5),
            &loop_poses(Point::new(4.0, 3.0), 2.6, 1.8, 160),
            vec![room, circle(5.5, 3.8, 0.3)?],
            true,
            [-3.0, -3.0, 11.0, 9.0],
        )?,
        exact_case(
            "l-corridor",
            Point::new(1.0, 1.0),
            &path_poses(&[(2.0, 1.2), (12.9, 1.2), (12.9, 11.0)], 0.1),
            vec![outer],
            false,
            [-3.0, -3.0, 17.0, 15.0],
        )?,
    ])
}

/// The paper's field environments as scenes: A, a brick wall 6 m behind
/// the speaker; B, a steel pole (radius 0.1 m) 4 m from it. The listener
/// walks past at 1 m/s, as `examples/moving-wall` does.
pub fn field_scene(env: char) -> &'static str {
    match env {
        'A' => {
            "[chirp]\nduration = 0.25\n[source]\nposition = [0.0, 0.0]\n\
             [[obstacles]]\nvertices = [[-30.0, -6.0], [-30.0, -6.3], [30.0, -6.3], [30.0, -6.0]]\nroughness = 0.0\n\
             [[listeners]]\nstart = [-10.0, 3.0]\nspeed = 1.0\n\
             [synth]\nchirps = 40\ngap_s = 0.25\nsnr_db = 20.0\n"
        }
        _ => {
            "[chirp]\nduration = 0.25\n[source]\nposition = [0.0, 0.0]\n\
             [[obstacles]]\ncenter = [1.0, -4.0]\nradius = 0.1\nroughness = 0.0\n\
             [[listeners]]\nstart = [-10.0, 3.0]\nspeed = 1.0\n\
             [synth]\nchirps = 40\ngap_s = 0.25\nsnr_db = 20.0\n"
        }
    }
}

/// The Table I scenes (3 random circles, spin 0) at 1, 10 and 50 ms, runs
/// `0..runs`, plus the field environments, all from particle echoes.
pub fn particle_cases(runs: u64) -> Result<Vec<Case>, String> {
    let mut out = Vec::new();
    for period_ms in [1.0, 10.0, 50.0] {
        for run in 0..runs {
            let mut scene = Scene { run_index: run, ..Scene::default() };
            scene.random_obstacles.count = 3;
            for l in &mut scene.listeners {
                l.sampling.period_ms = Some(period_ms);
                l.sampling.random_ms = None;
            }
            let sim = chirpmap::simulate(&scene).map_err(|e| e.to_string())?;
            out.push(Case {
                name: format!("table1-{period_ms}ms"),
                echoes_from: "particles",
                run,
                echoes: sim.output.echoes,
                truth: sim.resolved.obstacles,
                bounds: sim.resolved.world,
            });
        }
    }
    for env in ['A', 'B'] {
        // The particle simulator renders one chirp: at walking speed the
        // listener would cover 0.25 m while it sounds, a baseline from which no
        // mapper can place a surface. The simulator's own setting (paper §III:
        // 0.5 s chirps, listeners at 10 m/s) gives a 5 m pass instead.
        let (mut scene, _) = chirpmap::parse_scene(field_scene(env)).map_err(|e| e.to_string())?;
        scene.chirp.duration = 0.5;
        for l in &mut scene.listeners {
            l.speed = 10.0;
        }
        let sim = chirpmap::simulate(&scene).map_err(|e| e.to_string())?;
        out.push(Case {
            name: format!("field-{env}"),
            echoes_from: "particles",
            run: 0,
            echoes: sim.output.echoes,
            truth: sim.resolved.obstacles,
            bounds: [-15.0, -10.0, 15.0, 8.0],
        });
    }
    Ok(out)
}

/// The room with a pillar as a recording: a listener circling (radius 2 m,
/// 1 m/s) inside the 8 m × 6 m room, passing 8 cm from the 0.3 m pillar;
/// 60 chirps of 0.25 s at 20 dB SNR; first-order paths (`room-corners`
/// adds the second order).
pub const ROOM_PILLAR_SCENE: &str = include_str!("../../../examples/room-walk/scene.toml");

/// The field environments and the room with a pillar from synthesized
/// recordings (20 dB SNR), ranged per 10 ms frame at the listener's poses
/// with the Doppler-corrected method (`map --wav`'s default: the listener
/// walks, issue 11). The room is the one walk that circles a reflector
/// closely, as a recording: the straight passes of the field scenes missed
/// three faults of the evidence mapper that it showed (EXPERIMENTS.md,
/// session 22).
pub fn synth_cases() -> Result<Vec<Case>, String> {
    let mut out = Vec::new();
    // The room's `[synth]` table is the file's last: its corner echoes
    // (session 23) are one more line of it.
    let corners = format!("{ROOM_PILLAR_SCENE}reflection_order = 2\n");
    let cases = [
        ("field-A", field_scene('A').to_string(), [-15.0, -10.0, 15.0, 8.0]),
        ("field-B", field_scene('B').to_string(), [-15.0, -10.0, 15.0, 8.0]),
        ("room-pillar", ROOM_PILLAR_SCENE.to_string(), [-3.0, -3.0, 11.0, 9.0]),
        ("room-corners", corners, [-3.0, -3.0, 11.0, 9.0]),
    ];
    for (name, text, bounds) in cases {
        let err = |e: chirpmap::Error| format!("{name}: {e}");
        let (scene, cfg) = chirpmap::parse_scene(&text).map_err(err)?;
        let rec = chirpmap::synth(&scene, &cfg).map_err(err)?;
        let fs = f64::from(rec.sample_rate_hz);
        let poses = PoseTrack::new(rec.poses.first().cloned().unwrap_or_default()).map_err(err)?;
        let x = rec.channels.first().cloned().unwrap_or_default();
        let prep = chirpmap::prepare(x, fs, &ChirpSpec::from_scene(&scene)).map_err(err)?;
        let opts = MovingOptions {
            method: WavMethod::Doppler,
            pattern: None,
            period_s: 0.01,
            frame_s: None,
            speaker: Point::new(scene.source.position[0], scene.source.position[1]),
            listener_id: 0,
            echoes_per_frame: WavMethod::Doppler.default_echoes_per_frame(),
        };
        let chirp = ChirpSpec::from_scene(&scene);
        let got = chirpmap::RecordingEchoes::from_moving(&prep, &chirp, &poses, &opts).map_err(err)?;
        // (`map --scene`'s truth: a room around the source is no scene for
        // the particle simulator, which `resolve` checks for.)
        let (truth, _) = chirpmap::scene_truth(&scene).map_err(err)?;
        out.push(Case { name: name.into(), echoes_from: "synth", run: 0, echoes: got.echoes, truth, bounds });
    }
    Ok(out)
}

/// Maps `case` with `mapper` and measures the result.
pub fn run_case(case: &Case, mapper: MapperKind) -> Result<Row, String> {
    let mut opts = MapOptions { bounds: Some(case.bounds), ..MapOptions::default() };
    opts.params.mapper = mapper;
    let started = Instant::now();
    let map = map_echoes(&case.echoes, &[], &opts).map_err(|e| format!("{}: {e}", case.name))?;
    let elapsed_s = started.elapsed().as_secs_f64();
    let e = evaluate(&case.truth, &map, &case.echoes);
    let matched: Vec<_> = e.surfaces.walls.iter().filter(|w| w.offset_m.is_some()).collect();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (!v.is_empty()).then(|| v[v.len() / 2])
    };
    let mut hd: Vec<f64> = map
        .highlights
        .iter()
        .map(|h| case.truth.iter().map(|o| o.surface_distance(h.pos)).fold(f64::INFINITY, f64::min))
        .collect();
    hd.sort_by(f64::total_cmp);
    Ok(Row {
        case: case.name.clone(),
        echoes_from: case.echoes_from,
        run: case.run,
        mapper: match mapper {
            MapperKind::Paper => "paper",
            MapperKind::Evidence => "evidence",
        },
        n_echoes: case.echoes.len(),
        n_highlights: map.highlights.len(),
        n_surfaces: map.surfaces.len(),
        score_obstacle: e.scores.score_obstacle,
        score_highlight: e.scores.score_highlight,
        precision: e.surfaces.precision,
        recall: e.surfaces.recall,
        f1: e.surfaces.f1,
        chamfer_m: e.surfaces.chamfer_m,
        wall_offset_median_m: median(matched.iter().filter_map(|w| w.offset_m).collect()),
        wall_angle_median_deg: median(matched.iter().filter_map(|w| w.angle_deg).collect()),
        walls_matched: (matched.len(), e.surfaces.walls.len()),
        highlight_median_m: (!hd.is_empty()).then(|| hd[hd.len() / 2]),
        elapsed_s,
    })
}

/// Rows as CSV (one per case, run and mapper).
pub fn rows_csv(rows: &[Row]) -> String {
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    let mut s = String::from(
        "case,echoes_from,run,mapper,n_echoes,n_highlights,n_surfaces,score_obstacle,score_highlight,precision,recall,\
         f1,chamfer_m,wall_offset_median_m,wall_angle_median_deg,walls_matched,walls,highlight_median_m,elapsed_s\n",
    );
    for r in rows {
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{:.6},{:.6},{:.6},{},{},{},{},{},{},{:.6}\n",
            r.case,
            r.echoes_from,
            r.run,
            r.mapper,
            r.n_echoes,
            r.n_highlights,
            r.n_surfaces,
            opt(r.score_obstacle),
            opt(r.score_highlight),
            r.precision,
            r.recall,
            r.f1,
            opt(r.chamfer_m),
            opt(r.wall_offset_median_m),
            opt(r.wall_angle_median_deg),
            r.walls_matched.0,
            r.walls_matched.1,
            opt(r.highlight_median_m),
            r.elapsed_s
        );
    }
    s
}

/// A Markdown table: per case and mapper, means over runs.
pub fn rows_markdown(rows: &[Row]) -> String {
    let mut keys: Vec<(String, &'static str, &'static str)> = Vec::new();
    for r in rows {
        let k = (r.case.clone(), r.echoes_from, r.mapper);
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    let f = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |v| format!("{v:.d$}"));
    let mut s = String::from(
        "| case | echoes | mapper | runs | highlights | surfaces | score_obstacle | score_highlight | F1 | Chamfer (m) | \
         walls matched | median wall offset (cm) | median wall angle (°) | median highlight dist (m) | time (s) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (case, from, mapper) in keys {
        let rs: Vec<&Row> =
            rows.iter().filter(|r| r.case == case && r.echoes_from == from && r.mapper == mapper).collect();
        let n = rs.len();
        let m = |g: &dyn Fn(&Row) -> Option<f64>| mean(&rs.iter().filter_map(|r| g(r)).collect::<Vec<f64>>());
        let walls = rs.first().map_or(String::new(), |r| format!("{}/{}", r.walls_matched.0, r.walls_matched.1));
        s += &format!(
            "| {case} | {from} | {mapper} | {n} | {} | {} | {} | {} | {} | {} | {walls} | {} | {} | {} | {} |\n",
            f(m(&|r| Some(r.n_highlights as f64)), 1),
            f(m(&|r| Some(r.n_surfaces as f64)), 1),
            f(m(&|r| r.score_obstacle), 3),
            f(m(&|r| r.score_highlight), 3),
            f(m(&|r| Some(r.f1)), 3),
            f(m(&|r| r.chamfer_m), 3),
            f(m(&|r| r.wall_offset_median_m.map(|v| v * 100.0)), 2),
            f(m(&|r| r.wall_angle_median_deg), 2),
            f(m(&|r| r.highlight_median_m), 3),
            f(m(&|r| Some(r.elapsed_s)), 3),
        );
    }
    s + &paired_markdown(rows)
}

/// Mean of `v`; `None` when empty.
fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Mean and standard error (sample standard deviation / √n) of `v`; `None`
/// below two values.
fn mean_se(v: &[f64]) -> Option<(f64, f64)> {
    let n = v.len();
    if n < 2 {
        return None;
    }
    let mean = mean(v)?;
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1) as f64;
    Some((mean, (var / n as f64).sqrt()))
}

/// The evidence mapper against the paper mapper run by run, for the cases
/// with several runs (Table I): the mean per-run difference of each score
/// with its standard error, and the ratio of the score_highlight means. Five
/// runs are 15 obstacle-runs; a difference within two standard errors is not
/// a verdict (EXPERIMENTS.md, "Table I rows at 100 runs").
fn paired_markdown(rows: &[Row]) -> String {
    let mut keys: Vec<(&str, &'static str)> = Vec::new();
    for r in rows {
        if !keys.contains(&(r.case.as_str(), r.echoes_from)) {
            keys.push((r.case.as_str(), r.echoes_from));
        }
    }
    let mut s = String::new();
    for (case, from) in keys {
        let of = |mapper: &str| -> Vec<&Row> {
            rows.iter().filter(|r| r.case == case && r.echoes_from == from && r.mapper == mapper).collect()
        };
        let (paper, evidence) = (of("paper"), of("evidence"));
        // Runs mapped by both, each with both scores.
        let pairs: Vec<[f64; 4]> = evidence
            .iter()
            .filter_map(|e| {
                let p = paper.iter().find(|p| p.run == e.run)?;
                Some([e.score_obstacle?, p.score_obstacle?, e.score_highlight?, p.score_highlight?])
            })
            .collect();
        let diff = |i: usize| mean_se(&pairs.iter().map(|q| q[i] - q[i + 1]).collect::<Vec<f64>>());
        let (Some((d_obs, se_obs)), Some((d_hl, se_hl))) = (diff(0), diff(2)) else { continue };
        let mean_of = |i: usize| mean(&pairs.iter().map(|q| q[i]).collect::<Vec<f64>>()).unwrap_or(0.0);
        let ratio = if mean_of(3) > 0.0 { format!("{:.2}×", mean_of(2) / mean_of(3)) } else { "–".to_string() };
        if s.is_empty() {
            s = String::from(
                "\nEvidence − paper, paired by run (mean ± standard error):\n\n\
                 | case | echoes | runs | Δ score_obstacle | Δ score_highlight | score_highlight ratio |\n\
                 |---|---|---|---|---|---|\n",
            );
        }
        s += &format!(
            "| {case} | {from} | {} | {d_obs:+.3} ± {se_obs:.3} | {d_hl:+.3} ± {se_hl:.3} | {ratio} |\n",
            pairs.len()
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_cases_have_echoes_and_the_paper_mapper_runs_on_them() {
        let cases = exact_cases().expect("cases");
        assert_eq!(cases.len(), 3);
        for c in &cases {
            assert!(c.echoes.len() > 50, "{}: {} echoes", c.name, c.echoes.len());
            let r = run_case(c, MapperKind::Paper).expect("mapped");
            assert!(r.n_highlights > 0, "{}", c.name);
        }
        let csv = rows_csv(&[run_case(&cases[0], MapperKind::Paper).expect("row")]);
        assert_eq!(csv.lines().count(), 2);
    }

    /// The paired table against values worked by hand, rows shuffled so that
    /// only pairing by run gives them: "t" pairs runs 0–2 (run 3 has no
    /// paper row), score_obstacle differences (0.3, 0.4, −0.1): mean 0.2,
    /// standard error √(0.07/3) = 0.153; score_highlight differences (0.25,
    /// 0.25, 0.4): mean 0.3, standard error 0.05; ratio of the means
    /// 0.5333 / 0.2333 = 2.29. "zero" has a paper mean of 0: no ratio.
    #[test]
    fn paired_table_has_mean_and_standard_error_of_the_run_differences() {
        let cases = exact_cases().expect("cases");
        let base = run_case(&cases[0], MapperKind::Paper).expect("row");
        let row = |case: &str, run: u64, mapper: &'static str, obs: f64, hl: f64| Row {
            case: case.into(),
            run,
            mapper,
            score_obstacle: Some(obs),
            score_highlight: Some(hl),
            ..base.clone()
        };
        let rows = vec![
            row("t", 2, "evidence", 0.5, 0.5),
            row("t", 0, "paper", 0.4, 0.25),
            row("t", 1, "evidence", 0.9, 0.6),
            row("t", 3, "evidence", 1.0, 1.0),
            row("t", 0, "evidence", 0.7, 0.5),
            row("t", 2, "paper", 0.6, 0.1),
            row("t", 1, "paper", 0.5, 0.35),
            row("zero", 0, "paper", 0.5, 0.0),
            row("zero", 0, "evidence", 0.5, 0.2),
            row("zero", 1, "evidence", 0.5, 0.4),
            row("zero", 1, "paper", 0.5, 0.0),
            // A single-run case gets no paired row.
            row("single", 0, "evidence", 1.0, 1.0),
            row("single", 0, "paper", 1.0, 1.0),
        ];
        let md = rows_markdown(&rows);
        assert!(md.contains("| t | exact | 3 | +0.200 ± 0.153 | +0.300 ± 0.050 | 2.29× |"), "{md}");
        assert!(md.contains("| zero | exact | 2 | +0.000 ± 0.000 | +0.300 ± 0.100 | – |"), "{md}");
        assert!(!md.contains("| single | exact | 1 |"), "{md}");
        assert_eq!(mean_se(&[1.0]), None);
    }
}
