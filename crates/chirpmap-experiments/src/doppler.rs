//! The Doppler benchmark (issue 11): a listener walking or flying past a
//! speaker in front of a wall (`examples/moving-wall`), synthesized with
//! exact per-sample propagation delays (so with exact Doppler), ranged frame
//! by frame by each `map --wav` method, every echo's Δd compared with the
//! exact geometry of the wall at the listener's pose (image sources,
//! `chirpmap_core::exact`, not the synthesizer's code).
//!
//! Columns (as in the issue): median |Δd error| and bias and p90 over the
//! wall echoes (|error| ≤ [`WALL_TOL_M`]); spurious echoes (the rest, or any
//! echo while the wall is not heard); frames with the wall (the share of
//! 10 ms slots during which the wall is audible that hold a wall echo within
//! half a slot); chirps found; and the map's wall: the strongest paper-mapper
//! highlight within 1 m of the wall (its distance to the wall's surface, on
//! a 2 cm grid) and the evidence mapper's wall line offset.

use chirpmap::audio::doppler::{MovingOptions, WavMethod};
use chirpmap::audio::synth::ChirpPattern;
use chirpmap::core::exact::{ExactOptions, ExactScene, Pose, exact_reflections};
use chirpmap::core::scene::SweepKind;
use chirpmap::{ChirpSpec, MapOptions, MapperKind, Point, PoseTrack, Prepared, RecordingEchoes, evaluate, map_echoes};
use std::fmt::Write as _;
use std::time::Instant;

/// The moving-wall scene (a listener along y = 3 m past a speaker at the
/// origin, wall face at y = −6 m, 40 chirps of 0.25 s 10 → 0.2 kHz, 20 dB).
pub const MOVING_WALL_SCENE: &str = include_str!("../../../examples/moving-wall/scene.toml");

/// An echo within this distance (m) of the true Δd is a wall echo (ours).
pub const WALL_TOL_M: f64 = 0.5;

/// Slot length (s) for "frames with the wall": the measurement period.
pub const SLOT_S: f64 = 0.01;

/// One benchmark case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DopplerCase {
    /// Listener speed (m/s).
    pub speed_mps: f64,
    /// Echo extraction method.
    pub method: WavMethod,
    /// Chirp pattern.
    pub pattern: ChirpPattern,
    /// Sweep shape.
    pub kind: SweepKind,
}

/// One benchmark row.
#[derive(Debug, Clone, PartialEq)]
pub struct DopplerRow {
    /// The case.
    pub case: DopplerCase,
    /// Echoes extracted.
    pub echoes: usize,
    /// Wall echoes (|Δd error| ≤ [`WALL_TOL_M`]).
    pub wall_echoes: usize,
    /// Median |Δd error| of the wall echoes (m).
    pub median_abs_err_m: Option<f64>,
    /// Median signed Δd error of the wall echoes (m).
    pub bias_m: Option<f64>,
    /// 90th percentile of |Δd error| of the wall echoes (m).
    pub p90_abs_err_m: Option<f64>,
    /// Slots in which the wall is audible.
    pub wall_slots: usize,
    /// Of those, slots holding a wall echo.
    pub wall_slots_heard: usize,
    /// Chirps detected.
    pub chirps_found: usize,
    /// Chirps played.
    pub chirps_played: usize,
    /// Distance (m) from the strongest paper-mapper highlight within 1 m of
    /// the wall to the wall's surface (2 cm grid); `None` without one.
    pub highlight_offset_m: Option<f64>,
    /// Evidence mapper: offset (m) of the line matched to the wall face.
    pub surface_offset_m: Option<f64>,
    /// Median |Δḋ error| (m/s) of the wall echoes against the exact rate.
    pub rate_median_abs_err_mps: Option<f64>,
    /// Extraction time (s), synthesis excluded.
    pub elapsed_s: f64,
}

/// Quantile `q` of sorted values (nearest rank).
fn quantile(sorted: &[f64], q: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let i = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    Some(sorted[i])
}

/// The first (smallest-Δd) first-order reflection at each position, exact.
fn truth_at(source: Point, walls: &ExactScene, positions: &[Point]) -> Result<Vec<Option<f64>>, String> {
    let poses: Vec<Pose> = positions.iter().map(|&p| Pose { t_s: 0.0, listener: p }).collect();
    let refl = exact_reflections(source, &poses, walls, &ExactOptions::default()).map_err(|e| e.to_string())?;
    let mut out = vec![None; positions.len()];
    for r in refl {
        if r.order == 1 {
            let slot: &mut Option<f64> = &mut out[r.pose_index];
            *slot = Some(slot.map_or(r.delta_d_m, |v: f64| v.min(r.delta_d_m)));
        }
    }
    Ok(out)
}

/// Synthesizes the moving-wall scene for `case` and measures one method.
pub fn run_case(case: DopplerCase) -> Result<DopplerRow, String> {
    let name = format!("{} m/s {} {}", case.speed_mps, case.method.name(), case.pattern.name());
    let err = |e: chirpmap::Error| format!("{name}: {e}");
    let (mut scene, mut cfg) = chirpmap::parse_scene(MOVING_WALL_SCENE).map_err(err)?;
    scene.listeners[0].speed = case.speed_mps;
    scene.chirp.kind = case.kind;
    cfg.pattern = Some(case.pattern);
    // The scene's 0.5 s tail cuts off the last chirp beyond about 3 m/s (at
    // 10 m/s it arrives 0.55 s after it left, 190 m away): the tail is
    // lengthened so that every chirp played is in the recording.
    let end_s = cfg.start_s + cfg.chirps as f64 * (scene.chirp.duration + cfg.gap_s);
    let far_m = scene
        .listeners
        .iter()
        .map(|l| {
            Point::new(l.start[0], l.start[1]).dist(Point::new(scene.source.position[0], scene.source.position[1]))
                + l.speed * end_s
        })
        .fold(0.0, f64::max);
    cfg.tail_s = cfg.tail_s.max(far_m / scene.world.speed_of_sound + 0.1);
    let rec = chirpmap::synth(&scene, &cfg).map_err(err)?;
    let fs = f64::from(rec.sample_rate_hz);
    let rows = rec.poses.first().cloned().unwrap_or_default();
    let poses = PoseTrack::new(rows).map_err(err)?;
    let x = rec.channels.first().cloned().unwrap_or_default();
    let chirp = ChirpSpec::from_scene(&scene);
    let started = Instant::now();
    let prep = Prepared::for_moving(x, fs, &chirp).map_err(err)?;
    let speaker = Point::new(scene.source.position[0], scene.source.position[1]);
    let opts = MovingOptions {
        method: case.method,
        pattern: Some(case.pattern),
        period_s: 0.01,
        frame_s: None,
        speaker,
        listener_id: 0,
        echoes_per_frame: case.method.default_echoes_per_frame(),
    };
    let got = RecordingEchoes::from_moving(&prep, &chirp, &poses, &opts);
    let elapsed_s = started.elapsed().as_secs_f64();
    let truth_obstacles = chirpmap::sim::resolve(&scene).map_err(|e| format!("{name}: {e}"))?.obstacles;
    let walls = ExactScene::from_obstacles(&truth_obstacles);
    let a = scene.world.speed_of_sound;
    // Audible slots: the direct and the wall's sound both inside a chirp.
    let t_chirp = scene.chirp.duration;
    let period = t_chirp + cfg.gap_s;
    let mut slot_t = Vec::new();
    let mut slot_pos = Vec::new();
    let (p0, p1) = poses.span();
    let mut t = p0;
    while t <= p1 {
        if let Some(pos) = poses.at(t) {
            slot_t.push(t);
            slot_pos.push(pos);
        }
        t += SLOT_S;
    }
    let slot_truth = truth_at(speaker, &walls, &slot_pos)?;
    let in_chirp = |tau: f64| {
        let k = (tau / period).floor();
        k >= 0.0 && (k as usize) < cfg.chirps && tau - k * period <= t_chirp
    };
    let audible: Vec<bool> = slot_t
        .iter()
        .zip(&slot_pos)
        .zip(&slot_truth)
        .map(|((&t, p), tr)| {
            tr.is_some_and(|dd| {
                let tau_d = t - speaker.dist(*p) / a - cfg.start_s;
                in_chirp(tau_d)
                    && in_chirp(tau_d - dd / a)
                    && ((tau_d / period).floor() == ((tau_d - dd / a) / period).floor())
            })
        })
        .collect();
    let wall_slots = audible.iter().filter(|v| **v).count();
    let (echoes, rates, chirps_found) = match got {
        Ok(g) => (g.echoes, g.delta_d_rates_mps, g.chirps),
        Err(_) => (Vec::new(), Vec::new(), 0),
    };
    let positions: Vec<Point> = echoes.iter().map(|e| e.listener).collect();
    let truth = truth_at(speaker, &walls, &positions)?;
    // Exact Δḋ by a central difference of the exact Δd along the track.
    let h = 1e-3;
    let ahead: Vec<Point> = echoes.iter().filter_map(|e| poses.at(e.t_s + h).or(Some(e.listener))).collect();
    let behind: Vec<Point> = echoes.iter().filter_map(|e| poses.at(e.t_s - h).or(Some(e.listener))).collect();
    let (ta, tb) = (truth_at(speaker, &walls, &ahead)?, truth_at(speaker, &walls, &behind)?);
    let mut errs = Vec::new();
    let mut rate_errs = Vec::new();
    let mut heard_t = Vec::new();
    for (i, e) in echoes.iter().enumerate() {
        if let Some(tr) = truth[i] {
            let err = e.delta_d_m - tr;
            if err.abs() <= WALL_TOL_M {
                errs.push(err);
                heard_t.push(e.t_s);
                if let (Some(Some(r)), Some(fa), Some(fb)) = (rates.get(i), ta[i], tb[i]) {
                    rate_errs.push((r - (fa - fb) / (2.0 * h)).abs());
                }
            }
        }
    }
    heard_t.sort_by(f64::total_cmp);
    let wall_slots_heard = slot_t
        .iter()
        .zip(&audible)
        .filter(|(t, a)| {
            **a && {
                let k = heard_t.partition_point(|&h| h < **t - 0.5 * SLOT_S);
                heard_t.get(k).is_some_and(|&h| h <= **t + 0.5 * SLOT_S)
            }
        })
        .count();
    let mut abs: Vec<f64> = errs.iter().map(|e| e.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let mut signed = errs.clone();
    signed.sort_by(f64::total_cmp);
    rate_errs.sort_by(f64::total_cmp);
    // The map: the paper mapper on a 2 cm grid and the evidence mapper.
    let (mut highlight_offset_m, mut surface_offset_m) = (None, None);
    if !echoes.is_empty() {
        let bounds = [-20.0, -8.0, 20.0, 4.0];
        let mut opts = MapOptions { bounds: Some(bounds), ..MapOptions::default() };
        opts.params.cell = 0.02;
        opts.params.mapper = MapperKind::Paper;
        if let Ok(map) = map_echoes(&echoes, &[], &opts) {
            highlight_offset_m = map
                .highlights
                .iter()
                .filter_map(|h| {
                    let d = truth_obstacles.iter().map(|o| o.surface_distance(h.pos)).fold(f64::INFINITY, f64::min);
                    (d <= 1.0).then_some((h.value, d))
                })
                .max_by(|a, b| a.0.total_cmp(&b.0))
                .map(|(_, d)| d);
        }
        let mut opts = MapOptions { bounds: Some(bounds), ..MapOptions::default() };
        opts.params.mapper = MapperKind::Evidence;
        if let Ok(map) = map_echoes(&echoes, &[], &opts) {
            let e = evaluate(&truth_obstacles, &map, &echoes);
            // The wall face: the matched edge nearest the speaker.
            surface_offset_m = e
                .surfaces
                .walls
                .iter()
                .min_by(|x, y| {
                    let dx = chirpmap::core::geometry::point_segment_distance(speaker, x.a, x.b);
                    let dy = chirpmap::core::geometry::point_segment_distance(speaker, y.a, y.b);
                    dx.total_cmp(&dy)
                })
                .and_then(|w| w.offset_m);
        }
    }
    Ok(DopplerRow {
        case,
        echoes: echoes.len(),
        wall_echoes: errs.len(),
        median_abs_err_m: quantile(&abs, 0.5),
        bias_m: quantile(&signed, 0.5),
        p90_abs_err_m: quantile(&abs, 0.9),
        wall_slots,
        wall_slots_heard,
        chirps_found,
        chirps_played: cfg.chirps,
        highlight_offset_m,
        surface_offset_m,
        rate_median_abs_err_mps: quantile(&rate_errs, 0.5),
        elapsed_s,
    })
}

/// The benchmark's cases: every speed × method × pattern that the method
/// supports (gap and dechirp range one sweep direction), linear sweeps,
/// plus hyperbolic down-sweeps with the doppler method.
pub fn cases(speeds: &[f64]) -> Vec<DopplerCase> {
    let mut out = Vec::new();
    for &speed_mps in speeds {
        for pattern in [ChirpPattern::Down, ChirpPattern::Up, ChirpPattern::Updown] {
            for method in WavMethod::ALL {
                if pattern == ChirpPattern::Updown && method != WavMethod::Doppler {
                    continue;
                }
                out.push(DopplerCase { speed_mps, method, pattern, kind: SweepKind::Linear });
            }
        }
        out.push(DopplerCase {
            speed_mps,
            method: WavMethod::Doppler,
            pattern: ChirpPattern::Down,
            kind: SweepKind::Hyperbolic,
        });
    }
    out
}

fn cm(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{:.1}", 100.0 * v))
}

/// The rows as CSV (lengths in m, rates in m/s).
pub fn rows_csv(rows: &[DopplerRow]) -> String {
    let mut s = String::from(
        "speed_mps,method,pattern,sweep,echoes,wall_echoes,spurious,median_abs_err_m,bias_m,p90_abs_err_m,\
         wall_slots,wall_slots_heard,chirps_found,chirps_played,highlight_offset_m,surface_offset_m,\
         rate_median_abs_err_mps,elapsed_s\n",
    );
    let o = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3}",
            r.case.speed_mps,
            r.case.method.name(),
            r.case.pattern.name(),
            format!("{:?}", r.case.kind).to_lowercase(),
            r.echoes,
            r.wall_echoes,
            r.echoes - r.wall_echoes,
            o(r.median_abs_err_m),
            o(r.bias_m),
            o(r.p90_abs_err_m),
            r.wall_slots,
            r.wall_slots_heard,
            r.chirps_found,
            r.chirps_played,
            o(r.highlight_offset_m),
            o(r.surface_offset_m),
            o(r.rate_median_abs_err_mps),
            r.elapsed_s
        );
    }
    s
}

/// The rows as a markdown table (the columns, lengths in cm).
pub fn rows_markdown(rows: &[DopplerRow]) -> String {
    let mut s = String::from(
        "| speed (m/s) | method | pattern | sweep | median abs. error (cm) | bias (cm) | p90 (cm) | spurious echoes | \
         frames with the wall | chirps found | strongest highlight to wall (cm) | evidence wall offset (cm) | \
         median abs. Δḋ error (m/s) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let pct = if r.wall_slots > 0 { 100.0 * r.wall_slots_heard as f64 / r.wall_slots as f64 } else { 0.0 };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} / {} | {:.0} % | {} / {} | {} | {} | {} |",
            r.case.speed_mps,
            r.case.method.name(),
            r.case.pattern.name(),
            format!("{:?}", r.case.kind).to_lowercase(),
            cm(r.median_abs_err_m),
            cm(r.bias_m),
            cm(r.p90_abs_err_m),
            r.echoes - r.wall_echoes,
            r.echoes,
            pct,
            r.chirps_found,
            r.chirps_played,
            cm(r.highlight_offset_m),
            cm(r.surface_offset_m),
            r.rate_median_abs_err_mps.map_or("–".into(), |v| format!("{v:.3}")),
        );
    }
    s
}
