//! `chirpmap map`: echoes CSV → accumulation grid → highlights, plot, summary.

use crate::echoes_csv::read_echoes;
use crate::output::Staged;
use crate::plot::{MapPlot, render_map};
use anyhow::{Context, Result, anyhow, bail};
use chirpmap_core::grid::DEFAULT_MEMORY_CAP_BYTES;
use chirpmap_core::{
    AccumulationMapper, Echo, GridSpec, Highlight, Mapper, MappingParams, Obstacle, Point, Scene, score_highlight,
    score_obstacle,
};
use clap::Args;
use serde_json::json;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Args)]
pub struct MapArgs {
    /// Echoes CSV (header: source_x,source_y,listener_x,listener_y,delta_d[,weight,t,listener]).
    #[arg(long, required_unless_present = "wav", conflicts_with = "wav")]
    pub echoes: Option<PathBuf>,
    /// Instead of --echoes: a recording of a moving listener (needs --poses and --speaker).
    #[arg(long, requires_all = ["poses", "speaker"])]
    pub wav: Option<PathBuf>,
    /// Listener poses for --wav: CSV `t,x,y[,listener]` (as written by `chirpmap synth --poses`).
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Speaker position X,Y (m) for --wav.
    #[arg(long, value_parser = crate::cmd_range::parse_point, allow_hyphen_values = true)]
    pub speaker: Option<[f64; 2]>,
    /// Echo extraction for --wav: gap (the paper's) or dechirp.
    #[arg(long, default_value = "gap")]
    pub method: chirpmap_audio::Method,
    /// Time between measurements for --wav (ms). Paper: 1, 10, 50 ms.
    #[arg(long, default_value_t = 10.0)]
    pub period_ms: f64,
    /// Measurement frame length for --wav (ms). Default: the method's.
    #[arg(long)]
    pub frame_ms: Option<f64>,
    #[command(flatten)]
    pub chirp: crate::cmd_range::ChirpArgs,
    /// Output directory (created; highlights.csv, map.png, summary.json).
    #[arg(long)]
    pub out: PathBuf,
    /// Grid cell size (m) [default: 0.1, or the scene's [mapping] with --scene].
    #[arg(long)]
    pub cell: Option<f64>,
    /// Fraction of non-zero cells kept by the percentile threshold [default: 0.1, or the scene's [mapping] with --scene].
    #[arg(long)]
    pub keep_top: Option<f64>,
    /// Cells below this fraction of the maximum are zeroed [default: 0.01, or the scene's [mapping] with --scene].
    #[arg(long)]
    pub min_of_max: Option<f64>,
    /// A highlight is the maximum within this radius (m) [default: 5.0, or the scene's [mapping] with --scene].
    #[arg(long)]
    pub peak_radius: Option<f64>,
    /// Grid bounds XMIN,YMIN,XMAX,YMAX (m). Default: the region the ellipses cover.
    #[arg(long, value_parser = parse_bounds, allow_hyphen_values = true)]
    pub bounds: Option<[f64; 4]>,
    /// Scene TOML: its obstacles (listed or random, resolved exactly as `simulate` does) are drawn and
    /// scored (score_obstacle / score_highlight); its [mapping] gives the defaults above.
    #[arg(long)]
    pub scene: Option<PathBuf>,
}

pub fn parse_bounds(s: &str) -> Result<[f64; 4], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|_| format!("{p:?} is not a number")))
        .collect::<Result<_, _>>()?;
    let b: [f64; 4] = v.try_into().map_err(|_| "expected XMIN,YMIN,XMAX,YMAX".to_string())?;
    if b.iter().any(|x| !x.is_finite()) || b[0] >= b[2] || b[1] >= b[3] {
        return Err("need finite values with XMIN < XMAX and YMIN < YMAX".into());
    }
    Ok(b)
}

/// Loads a scene file, naming the file in any error. A `[synth]` table
/// (waveform settings for `chirpmap synth`) is accepted and ignored here.
pub fn load_scene(path: &Path) -> Result<Scene> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    chirpmap_audio::synth::parse_scene_with_synth(&text).map(|(s, _)| s).map_err(|e| anyhow!("{}: {e}", path.display()))
}

/// Bounds covering every ellipse, focus and extra point, snapped outward to
/// whole cells.
pub fn covering_bounds(echoes: &[Echo], extra: &[(Point, Point)], cell_m: f64) -> Option<[f64; 4]> {
    let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    let mut grow = |lo: Point, hi: Point| {
        b = [b[0].min(lo.x), b[1].min(lo.y), b[2].max(hi.x), b[3].max(hi.y)];
    };
    for e in echoes {
        if let Ok(el) = e.ellipse() {
            let (lo, hi) = el.bbox();
            grow(lo, hi);
        }
    }
    for &(lo, hi) in extra {
        grow(lo, hi);
    }
    if !b.iter().all(|v| v.is_finite()) {
        return None;
    }
    let snap_lo = |v: f64| (v / cell_m).floor() * cell_m - cell_m;
    let snap_hi = |v: f64| (v / cell_m).ceil() * cell_m + cell_m;
    Some([snap_lo(b[0]), snap_lo(b[1]), snap_hi(b[2]), snap_hi(b[3])])
}

/// Result of mapping a set of echoes.
#[derive(Debug)]
pub struct MapOutcome {
    pub mapper: AccumulationMapper,
    pub highlights: Vec<Highlight>,
}

pub fn map_echoes(echoes: &[Echo], spec: GridSpec, params: MappingParams) -> Result<MapOutcome> {
    let mut mapper = AccumulationMapper::new(spec, params)?;
    for e in echoes {
        mapper.add_echo(e)?;
    }
    let highlights = mapper.highlights();
    Ok(MapOutcome { mapper, highlights })
}

pub fn highlights_csv(highlights: &[Highlight]) -> String {
    let mut s = String::from("x,y,value\n");
    for h in highlights {
        let _ = writeln!(s, "{},{},{}", h.pos.x, h.pos.y, h.value);
    }
    s
}

/// Unique sources and listener positions of the echoes, for plotting.
pub fn foci(echoes: &[Echo]) -> (Vec<Point>, Vec<Point>) {
    let mut sources: Vec<Point> = Vec::new();
    let mut listeners: Vec<Point> = Vec::new();
    for e in echoes {
        if !sources.contains(&e.source) {
            sources.push(e.source);
        }
        if listeners.last() != Some(&e.listener) {
            listeners.push(e.listener);
        }
    }
    (sources, listeners)
}

pub fn run(args: &MapArgs) -> Result<()> {
    let started = Instant::now();
    let (obstacles, base): (Vec<Obstacle>, MappingParams) = match &args.scene {
        Some(p) => {
            let resolved = chirpmap_sim::resolve(&load_scene(p)?).map_err(|e| anyhow!("{}: {e}", p.display()))?;
            (resolved.obstacles, resolved.scene.mapping)
        }
        None => (Vec::new(), MappingParams::default()),
    };
    let params = MappingParams {
        cell: args.cell.unwrap_or(base.cell),
        keep_top: args.keep_top.unwrap_or(base.keep_top),
        min_of_max: args.min_of_max.unwrap_or(base.min_of_max),
        peak_radius: args.peak_radius.unwrap_or(base.peak_radius),
        ..base
    };
    params.validate()?;
    let (echoes, label) = match (&args.echoes, &args.wav) {
        (Some(p), _) => (read_echoes(p)?, p.clone()),
        (None, Some(w)) => (echoes_from_wav(args, w)?, w.clone()),
        (None, None) => bail!("give --echoes or --wav"),
    };
    if echoes.is_empty() {
        bail!("{}: no echoes", label.display());
    }
    let bounds = match args.bounds {
        Some(b) => b,
        None => {
            let extra: Vec<(Point, Point)> = obstacles.iter().map(|o| o.shape.bbox()).collect();
            covering_bounds(&echoes, &extra, params.cell).context("cannot derive bounds from the echoes")?
        }
    };
    let spec = GridSpec::from_bounds(bounds, params.cell, DEFAULT_MEMORY_CAP_BYTES)?;
    let outcome = map_echoes(&echoes, spec, params)?;
    let points: Vec<Point> = outcome.highlights.iter().map(|h| h.pos).collect();
    let (sources, listeners) = foci(&echoes);

    let mut out = Staged::new(&args.out)?;
    out.write("highlights.csv", highlights_csv(&outcome.highlights))?;
    if args.wav.is_some() {
        let mut buf = Vec::new();
        crate::echoes_csv::write_echoes(&mut buf, &echoes)?;
        out.write("echoes.csv", buf)?;
    }
    let png = out.path("map.png");
    render_map(
        &png,
        &MapPlot {
            title: format!("{} echoes, {} highlights", echoes.len(), outcome.highlights.len()),
            grid: outcome.mapper.grid(),
            highlights: &outcome.highlights,
            sources: &sources,
            listener_positions: &listeners,
            listener_radius_m: None,
            obstacles: &obstacles,
        },
    )?;
    let mut summary = json!({
        "n_echoes": echoes.len(),
        "n_highlights": outcome.highlights.len(),
        "cells_updated": outcome.mapper.cells_updated(),
        "grid": { "bounds": [spec.x_min_m, spec.y_min_m, spec.x_max_m(), spec.y_max_m()], "nx": spec.nx, "ny": spec.ny },
        "mapping": params,
    });
    if args.scene.is_some() {
        summary["score_obstacle"] = json!(score_obstacle(&obstacles, &points));
        summary["score_highlight"] = json!(score_highlight(&obstacles, &points));
    }
    summary["elapsed_s"] = json!(started.elapsed().as_secs_f64());
    out.write("summary.json", serde_json::to_string_pretty(&summary)? + "\n")?;
    let dir = out.commit()?;
    say!(
        "{} echoes -> {} highlights in {:.3} s; wrote {}",
        echoes.len(),
        outcome.highlights.len(),
        started.elapsed().as_secs_f64(),
        dir.display()
    );
    if let (Some(so), Some(sh)) = (summary.get("score_obstacle"), summary.get("score_highlight")) {
        say!("score_obstacle = {so}, score_highlight = {sh}");
    }
    Ok(())
}

/// `map --wav`: detect chirps, then one measurement per period at the
/// listener's pose (issue 5, item 4).
fn echoes_from_wav(args: &MapArgs, wav: &Path) -> Result<Vec<Echo>> {
    let poses_path = args.poses.as_ref().context("--wav needs --poses")?;
    let [sx, sy] = args.speaker.context("--wav needs --speaker")?;
    let poses = crate::poses_csv::read_poses(poses_path, args.chirp.channel as u32)?;
    let prep = crate::cmd_range::prepare(wav, &args.chirp)?;
    let mut cache = chirpmap_audio::spectrum::FftCache::default();
    let dets = chirpmap_audio::detect_chirps(
        &prep.x,
        &prep.tpl,
        &mut cache,
        prep.lim.max_delta_d_m / prep.lim.speed_of_sound_mps,
    )
    .with_context(|| format!("{}", wav.display()))?;
    let (p0, p1) = poses.span();
    let t_end = |d: &chirpmap_audio::Detection| (d.onset_sample + prep.tpl.len()) as f64 / prep.sample_rate_hz;
    let covered = dets.iter().filter(|d| poses.at(d.onset_sample as f64 / prep.sample_rate_hz).is_some()).count();
    if covered == 0 {
        bail!(
            "{}: the poses span {p0:.3}–{p1:.3} s but the recording {} spans 0–{:.3} s and its {} chirp(s) lie at \
             {:.3}–{:.3} s: no chirp has a pose (wrong poses file?)",
            poses_path.display(),
            wav.display(),
            prep.duration_s,
            dets.len(),
            dets.first().map_or(0.0, |d| d.onset_sample as f64 / prep.sample_rate_hz),
            dets.last().map_or(0.0, t_end),
        );
    }
    if covered < dets.len() {
        eprintln!(
            "warning: {}: the poses span {p0:.3}–{p1:.3} s, the recording {} 0–{:.3} s; {} of {} chirp(s) have no pose \
             and are skipped",
            poses_path.display(),
            wav.display(),
            prep.duration_s,
            dets.len() - covered,
            dets.len()
        );
    }
    let params = chirpmap_audio::frames::FrameParams {
        method: args.method,
        period_s: args.period_ms / 1000.0,
        frame_s: args.frame_ms.map(|m| m / 1000.0),
        speaker: Point::new(sx, sy),
        listener_id: args.chirp.channel as u32,
    };
    let pose_at = |t: f64| poses.at(t);
    let echoes = chirpmap_audio::frames::extract_echoes(&prep.x, &prep.tpl, &prep.lim, &dets, &pose_at, &params)?;
    eprintln!("{}: {} chirp(s), {} echo(es) by {}", wav.display(), dets.len(), echoes.len(), args.method.name());
    Ok(echoes)
}
