//! `chirpmap simulate`: scene → particle simulator (paper §II.B) → echoes →
//! Algorithm 1 → highlights → scores (§III.A), with plots.

use crate::echoes_csv::write_echoes;
use crate::inputs::load_scene;
use crate::mapout::{PlotFormat, map_outputs, map_summary, provenance, write_map};
use crate::output::Staged;
use crate::plot::{MapPlot, SpectrumPlot, render_spectrum};
use crate::tables::fmt_score;
use anyhow::{Context, Result, anyhow};
use chirpmap::sim::{BIN_HZ, Measurement, Resolved, SimOutput};
use chirpmap::{Point, Scene};
use clap::Args;
use serde_json::{Value, json};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Scene TOML (every field optional; unknown keys are errors). Default: the paper's default scene
    /// (3 random obstacles, one listener at 10 m/s, 10 ms sampling).
    pub scene: Option<PathBuf>,
    /// Output directory: summary.json, echoes.csv, highlights.csv, scene.toml, map.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Master seed, overriding the scene's `seed` (0 to 2^63 − 1: scene.toml records it as a TOML integer).
    #[arg(long, value_parser = clap::value_parser!(u64).range(..=i64::MAX as u64))]
    pub seed: Option<u64>,
    /// Figure format (map.png or map.svg, spectrum.png or spectrum.svg).
    #[arg(long, value_enum, default_value_t = PlotFormat::Png)]
    pub plot_format: PlotFormat,
    /// Also write spectra.csv, peaks.csv and spectrum.png (one listener spectrum with its peaks).
    #[arg(long)]
    pub spectra: bool,
}

pub fn run(args: &SimulateArgs) -> Result<()> {
    let started = Instant::now();
    let (mut scene, name) = match &args.scene {
        Some(p) => (load_scene(p)?.0, p.display().to_string()),
        None => (Scene::default(), "default scene".to_string()),
    };
    let fmt = args.plot_format;
    let mut outputs = vec!["echoes.csv", "scene.toml", "summary.json"];
    outputs.extend(map_outputs(scene.mapping.mapper, fmt));
    if args.spectra {
        outputs.extend(["spectra.csv", "peaks.csv", fmt.spectrum()]);
    }
    let inputs: Vec<&Path> = args.scene.iter().map(PathBuf::as_path).collect();
    let mut staged = Staged::dir(&args.out, "simulate", &outputs, &inputs)?;
    if let Some(seed) = args.seed {
        scene.seed = seed;
    }
    let run = chirpmap::simulate(&scene).map_err(|e| anyhow!("{name}: {e}"))?;
    let (resolved, out, map) = (&run.resolved, &run.output, &run.map);
    let (so, sh) = (run.scores.score_obstacle, run.scores.score_highlight);

    // The evaluation (the obstacles' exact reflection points for the
    // surface metrics, a few ms) runs beside the files: the data files leave
    // a core idle while the figure is drawn.
    let eval = std::thread::scope(|scope| -> Result<_> {
        let eval = scope.spawn(|| chirpmap::evaluate(&resolved.obstacles, map, &out.echoes));
        let mut echoes_csv = Vec::new();
        write_echoes(&mut echoes_csv, &out.echoes)?;
        staged.write("echoes.csv", echoes_csv)?;
        staged.write("scene.toml", resolved_scene_toml(resolved))?;
        let path = trajectory_points(resolved);
        let radius = resolved.listeners.first().map(|l| l.radius_m);
        write_map(
            &mut staged,
            map,
            &MapPlot {
                title: format!(
                    "seed {}: {} echoes, {} highlights, score_obstacle {}, score_highlight {}",
                    resolved.scene.seed,
                    out.echoes.len(),
                    map.highlights.len(),
                    fmt_score(so, 3),
                    fmt_score(sh, 3)
                ),
                grid: &map.grid,
                highlights: &map.highlights,
                sources: &[resolved.source],
                listener_positions: &path,
                listener_radius_m: radius,
                obstacles: &resolved.obstacles,
            },
            fmt,
        )?;
        if args.spectra {
            write_spectra(&mut staged, resolved, out, fmt)?;
        }
        eval.join().map_err(|_| anyhow!("evaluating the map failed"))
    })?;
    let mut summary = map_summary(map, Some(&eval));
    let sim = json!({
        "n_echoes": out.echoes.len(),
        "n_measurements": out.measurements.len(),
        "n_obstacles": resolved.obstacles.len(),
        "n_particles": resolved.n_emit_ticks * u64::from(resolved.per_tick),
        "seed": resolved.scene.seed,
        "run_index": resolved.scene.run_index,
        "simulated_s": resolved.last_tick as f64 * resolved.tick_s,
        "simulate_elapsed_s": run.simulate_elapsed_s,
        "elapsed_s": started.elapsed().as_secs_f64(),
        "run": provenance(),
    });
    if let (Some(s), Value::Object(fields)) = (summary.as_object_mut(), sim) {
        s.extend(fields);
    }
    staged.write("summary.json", serde_json::to_string_pretty(&summary)? + "\n")?;
    let dir = staged.commit()?;
    say!(
        "{} measurements -> {} echoes -> {} highlights in {:.3} s; wrote {}",
        out.measurements.len(),
        out.echoes.len(),
        map.highlights.len(),
        started.elapsed().as_secs_f64(),
        dir.display()
    );
    say!("score_obstacle = {}, score_highlight = {}", fmt_score(so, 4), fmt_score(sh, 4));
    Ok(())
}

fn resolved_scene_toml(r: &Resolved) -> String {
    format!(
        "# Fully resolved scene written by `chirpmap simulate` (random obstacles listed).\n\
         # `chirpmap simulate scene.toml` replays this run exactly.\n{}",
        r.scene.to_toml_string()
    )
}

/// Listener trajectories sampled at ~2000 points each, for the map's path.
fn trajectory_points(r: &Resolved) -> Vec<Point> {
    let step = (r.last_tick / 2000).max(1);
    let mut pts = Vec::new();
    for l in &r.listeners {
        let mut k = 0;
        while k <= r.last_tick {
            pts.push(l.trajectory.position(r.time_s(k)));
            k += step;
        }
    }
    pts
}

/// A peak of one measurement, classified against its direct peak.
#[derive(Debug)]
struct PeakRow {
    f_hz: f64,
    intensity: f64,
    lo_hz: f64,
    hi_hz: f64,
    kind: &'static str,
    delta_d_m: Option<f64>,
}

fn peak_rows(r: &Resolved, m: &Measurement) -> Vec<PeakRow> {
    m.peaks
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let (kind, dd) = match m.direct {
                Some(d) if d == i => ("direct", Some(0.0)),
                Some(d) => match r.sweep.delta_d_m(m.peaks[d].f_hz, p.f_hz, r.speed_of_sound_mps) {
                    Some(dd) if dd > 0.0 => ("reflected", Some(dd)),
                    _ => ("unpaired", None),
                },
                None => ("unpaired", None),
            };
            PeakRow { f_hz: p.f_hz, intensity: p.intensity, lo_hz: p.lo_hz, hi_hz: p.hi_hz, kind, delta_d_m: dd }
        })
        .collect()
}

fn write_spectra(staged: &mut Staged, r: &Resolved, out: &SimOutput, fmt: PlotFormat) -> Result<()> {
    let mut spectra = String::from("listener,t,listener_x,listener_y,f_lo_hz,f_hi_hz,loudness\n");
    let mut peaks = String::from("listener,t,f_hz,intensity,lo_hz,hi_hz,kind,delta_d\n");
    for m in &out.measurements {
        for &(b, v) in &m.bins {
            let lo = b as f64 * BIN_HZ;
            let _ = writeln!(
                spectra,
                "{},{},{},{},{lo},{},{v}",
                m.listener_id,
                m.t_s,
                m.position.x,
                m.position.y,
                lo + BIN_HZ
            );
        }
        for p in peak_rows(r, m) {
            let dd = p.delta_d_m.map(|d| d.to_string()).unwrap_or_default();
            let _ = writeln!(
                peaks,
                "{},{},{},{},{},{},{},{dd}",
                m.listener_id, m.t_s, p.f_hz, p.intensity, p.lo_hz, p.hi_hz, p.kind
            );
        }
    }
    staged.write("spectra.csv", spectra)?;
    staged.write("peaks.csv", peaks)?;
    // The measurement with the most echoes (the first one on ties) shows the method best.
    let echoes_of = |m: &Measurement| peak_rows(r, m).iter().filter(|p| p.kind == "reflected").count();
    let best = out
        .measurements
        .iter()
        .filter(|m| m.direct.is_some())
        .max_by_key(|m| (echoes_of(m), std::cmp::Reverse(m.tick)));
    let (f_a, f_b) = (r.sweep.f_start_hz(), r.sweep.f_end_hz());
    let f_range_hz = (f_a.min(f_b) - 100.0, f_a.max(f_b) + 100.0);
    let (png, shown) = (staged.path(fmt.spectrum())?, staged.shown(fmt.spectrum()));
    let drawn = match best {
        Some(m) => {
            let bins: Vec<(f64, f64)> = m.bins.iter().map(|&(b, v)| (b as f64 * BIN_HZ, v)).collect();
            let rows = peak_rows(r, m);
            let reflected: Vec<f64> = rows.iter().filter(|p| p.kind == "reflected").map(|p| p.f_hz).collect();
            render_spectrum(
                &png,
                &SpectrumPlot {
                    title: format!(
                        "listener {} at t = {:.3} s, ({:.2}, {:.2}) m: {} particles, {} echoes",
                        m.listener_id,
                        m.t_s,
                        m.position.x,
                        m.position.y,
                        m.n_sensed,
                        reflected.len()
                    ),
                    bins: &bins,
                    bin_hz: BIN_HZ,
                    f_range_hz,
                    direct_hz: m.direct.map(|d| m.peaks[d].f_hz),
                    reflected_hz: &reflected,
                },
            )
        }
        None => render_spectrum(
            &png,
            &SpectrumPlot {
                title: "no measurement heard the direct sound".into(),
                bins: &[],
                bin_hz: BIN_HZ,
                f_range_hz,
                direct_hz: None,
                reflected_hz: &[],
            },
        ),
    };
    drawn.with_context(|| format!("cannot write {}", shown.display()))
}
