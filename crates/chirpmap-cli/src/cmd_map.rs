//! `chirpmap map`: echoes CSV (or a moving listener's recording) → the
//! facade's map → highlights, plot, summary.

use crate::args::{ChirpArgs, parse_bounds, parse_mapper, parse_point};
use crate::echoes_csv::read_echoes;
use crate::inputs::{load_scene_declaring, prepare_wav};
use crate::mapout::{PlotFormat, map_outputs, map_summary, provenance, write_map};
use crate::output::Staged;
use crate::plot::MapPlot;
use crate::tables::fmt_score;
use anyhow::{Context, Result, anyhow, bail};
use chirpmap::audio::doppler::{MovingOptions, WavMethod};
use chirpmap::audio::synth::ChirpPattern;
use chirpmap::{ChirpSpec, Echo, MapOptions, MappingParams, Obstacle, Point};
use chirpmap_core::error::Num;
use clap::Args;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Args)]
#[command(group = clap::ArgGroup::new("input").required(true).args(["echoes", "wav"]))]
pub struct MapArgs {
    /// Echoes CSV (header: `source_x,source_y,listener_x,listener_y,delta_d[,weight,t,listener,sigma_m]`).
    #[arg(long, conflicts_with = "wav")]
    pub echoes: Option<PathBuf>,
    /// Instead of --echoes: a recording of a moving listener (needs --poses and --speaker); the echoes
    /// it yields are written to DIR/echoes.csv.
    #[arg(long, requires_all = ["poses", "speaker"])]
    pub wav: Option<PathBuf>,
    /// Listener poses for --wav: CSV `t,x,y[,listener]` (as written by `chirpmap synth --poses`); with a
    /// `listener` column, the rows of listener --channel are used.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Speaker position X,Y (m) for --wav.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    pub speaker: Option<[f64; 2]>,
    /// Echo extraction for --wav: doppler (Doppler-corrected, for moving listeners; issue 11), gap (the
    /// paper's, uncorrected) or dechirp (uncorrected).
    #[arg(long, default_value = "doppler")]
    pub method: WavMethod,
    /// Sweep directions of the recording's chirps for --wav: down, up or updown (alternating, starting
    /// down) [default: the --scene's [synth] pattern, else every chirp as --f-start/--f-end give it].
    #[arg(long)]
    pub pattern: Option<ChirpPattern>,
    /// Time between measurements for --wav (ms). Paper: 1, 10, 50 ms.
    #[arg(long, default_value_t = 10.0)]
    pub period_ms: f64,
    /// Measurement frame length for --wav (ms). Default: the method's.
    #[arg(long)]
    pub frame_ms: Option<f64>,
    /// Most echoes taken from each frame for --wav, earliest first, each tracked across its chirp with its
    /// own Doppler correction (doppler method only; with a linear sweep the default frame is then twice
    /// as long, to separate them): 1 keeps the first reflection alone (the paper's §IV) [default: 8 for
    /// doppler, else 1].
    #[arg(long)]
    pub echoes_per_frame: Option<usize>,
    #[command(flatten)]
    pub chirp: ChirpArgs,
    /// Output directory (created): highlights.csv, map.png (or .svg), map.npy, map.pgm + map.yaml,
    /// summary.json; surfaces.csv with the evidence mapper; echoes.csv with --wav.
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
    /// Mapper: paper (Algorithm 1) or evidence (surfaces, free space, ghosts removed; docs/evidence-mapper.md)
    /// [default: paper, or the scene's [mapping] mapper with --scene].
    #[arg(long, value_parser = parse_mapper)]
    pub mapper: Option<chirpmap::MapperKind>,
    /// Figure format (map.png or map.svg).
    #[arg(long, value_enum, default_value_t = PlotFormat::Png)]
    pub plot_format: PlotFormat,
    /// Scene TOML: its obstacles (listed or random, resolved exactly as `simulate` does) are drawn and
    /// scored (score_obstacle / score_highlight); its [mapping] gives the defaults above, and its [chirp]
    /// the chirp of --wav. A file of settings only ([mapping], [mapping.evidence], [chirp], [synth],
    /// [source]; say, for a real recording) is not scored.
    #[arg(long)]
    pub scene: Option<PathBuf>,
}

pub fn run(args: &MapArgs) -> Result<()> {
    let started = Instant::now();
    let mut settings_only = false;
    let (obstacles, base, chirp_base, pattern_base): (Vec<Obstacle>, MappingParams, ChirpSpec, _) = match &args.scene {
        Some(p) => {
            // Parsing validated the whole scene; a file of settings only
            // places no obstacles.
            let ((scene, synth), declares) = load_scene_declaring(p)?;
            settings_only = !declares;
            let (obstacles, scene) = if declares {
                chirpmap::scene_truth(&scene).map_err(|e| anyhow!("{}: {e}", p.display()))?
            } else {
                (Vec::new(), scene)
            };
            let chirp = ChirpSpec::from_scene(&scene);
            (obstacles, scene.mapping, chirp, synth.pattern)
        }
        None => (Vec::new(), MappingParams::default(), ChirpSpec::default(), None),
    };
    let params = MappingParams {
        cell: args.cell.unwrap_or(base.cell),
        keep_top: args.keep_top.unwrap_or(base.keep_top),
        min_of_max: args.min_of_max.unwrap_or(base.min_of_max),
        peak_radius: args.peak_radius.unwrap_or(base.peak_radius),
        mapper: args.mapper.unwrap_or(base.mapper),
        ..base
    };
    params.validate().map_err(|e| match e {
        // Name the flag when the value came from one (else the scene's [mapping]).
        chirpmap_core::CoreError::InvalidParam { field, reason }
            if [
                ("cell", args.cell.is_some()),
                ("keep_top", args.keep_top.is_some()),
                ("min_of_max", args.min_of_max.is_some()),
                ("peak_radius", args.peak_radius.is_some()),
            ]
            .contains(&(field, true)) =>
        {
            anyhow!("--{}: {reason}", field.replace('_', "-"))
        }
        e => e.into(),
    })?;
    if params.mapper == chirpmap::MapperKind::Evidence {
        // Algorithm 1's thresholds: the evidence mapper has its own highlight
        // rule, so a flag it would ignore is refused rather than recorded in
        // summary.json as if applied.
        let paper_only = [
            ("--keep-top", args.keep_top.is_some()),
            ("--min-of-max", args.min_of_max.is_some()),
            ("--peak-radius", args.peak_radius.is_some()),
        ];
        if let Some((flag, _)) = paper_only.iter().find(|(_, given)| *given) {
            bail!(
                "{flag} applies to --mapper paper only; the evidence mapper's highlights are set in a scene's \
                 [mapping.evidence] (peak_radius_m, highlight_min_logodds; docs/evidence-mapper.md)"
            );
        }
    }
    if let Some(p) = args.scene.as_ref().filter(|_| settings_only) {
        eprintln!(
            "note: {} holds settings only (no scene tables): its settings are used, nothing is scored",
            p.display()
        );
    }
    let mut outputs = map_outputs(params.mapper, args.plot_format);
    outputs.push("summary.json");
    if args.wav.is_some() {
        outputs.push("echoes.csv");
    }
    let inputs: Vec<&Path> =
        [&args.echoes, &args.wav, &args.poses, &args.scene].into_iter().flatten().map(PathBuf::as_path).collect();
    let mut out = Staged::dir(&args.out, "map", &outputs, &inputs)?;
    let (echoes, rates, label) = match (&args.echoes, &args.wav) {
        (Some(p), _) => (read_echoes(p)?, Vec::new(), p.clone()),
        (None, Some(w)) => {
            let (e, r) = echoes_from_wav(args, w, args.chirp.spec(chirp_base), args.pattern.or(pattern_base))?;
            (e, r, w.clone())
        }
        (None, None) => bail!("give --echoes or --wav"),
    };
    if echoes.is_empty() {
        bail!("{}: no echoes", label.display());
    }
    let extra: Vec<(Point, Point)> = obstacles.iter().map(|o| o.shape.bbox()).collect();
    let opts = MapOptions { params, bounds: args.bounds, ..MapOptions::default() };
    let map = chirpmap::map_echoes(&echoes, &extra, &opts).with_context(|| format!("{}", label.display()))?;
    let (sources, listeners) = chirpmap::foci(&echoes);
    // One marker per map cell is all a figure can show; 300 000 distinct
    // sources would otherwise cost more to draw than to map.
    let sources = one_per_cell(&sources, &map.grid.spec);
    if args.wav.is_some() {
        out.write("echoes.csv", echoes_with_rates(&echoes, &rates)?)?;
    }
    let eval = (!obstacles.is_empty()).then(|| chirpmap::evaluate(&obstacles, &map, &echoes));
    let mut title = format!("{} echoes, {} highlights", echoes.len(), map.highlights.len());
    if !map.surfaces.is_empty() {
        title += &format!(", {} surfaces", map.surfaces.len());
    }
    if let Some(e) = &eval {
        title += &format!(
            ", score_obstacle {}, score_highlight {}",
            fmt_score(e.scores.score_obstacle, 3),
            fmt_score(e.scores.score_highlight, 3)
        );
    }
    let plot = MapPlot {
        title,
        grid: &map.grid,
        highlights: &map.highlights,
        sources: &sources,
        listener_positions: &listeners,
        listener_radius_m: None,
        obstacles: &obstacles,
    };
    write_map(&mut out, &map, &plot, args.plot_format)?;
    let mut summary = map_summary(&map, eval.as_ref());
    summary["n_echoes"] = json!(echoes.len());
    summary["mapping"] = json!(params);
    summary["run"] = provenance();
    summary["elapsed_s"] = json!(started.elapsed().as_secs_f64());
    out.write("summary.json", serde_json::to_string_pretty(&summary)? + "\n")?;
    let dir = out.commit()?;
    if map.grid.data.iter().all(|v| *v == 0.0) {
        let s = map.grid.spec;
        eprintln!(
            "warning: the map is empty: no echo's ellipse reaches the mapped area x {}..{}, y {}..{} m; check --bounds",
            Num(s.x_min_m),
            Num(s.x_max_m()),
            Num(s.y_min_m),
            Num(s.y_max_m())
        );
    }
    say!(
        "{} echoes -> {} highlights, {} surfaces in {:.3} s; wrote {}",
        echoes.len(),
        map.highlights.len(),
        map.surfaces.len(),
        started.elapsed().as_secs_f64(),
        dir.display()
    );
    if let Some(e) = &eval {
        say!(
            "score_obstacle = {}, score_highlight = {}, surface F1 = {:.4}",
            fmt_score(e.scores.score_obstacle, 4),
            fmt_score(e.scores.score_highlight, 4),
            e.surfaces.f1
        );
    }
    Ok(())
}

/// The first point in each grid cell (points off the grid are kept).
fn one_per_cell(points: &[Point], spec: &chirpmap::GridSpec) -> Vec<Point> {
    let mut seen = std::collections::HashSet::new();
    points
        .iter()
        .copied()
        .filter(|p| {
            let i = ((p.x - spec.x_min_m) / spec.cell_m).floor();
            let j = ((p.y - spec.y_min_m) / spec.cell_m).floor();
            !(i.is_finite() && j.is_finite()) || seen.insert((i as i64, j as i64))
        })
        .collect()
}

/// The echoes CSV of docs/file-formats.md with, when any echo has one, the
/// optional `delta_d_rate` column (Δḋ, m/s; issue 11) appended; readers
/// ignore extra columns, so `map --echoes` reads it back unchanged.
fn echoes_with_rates(echoes: &[Echo], rates: &[Option<f64>]) -> Result<Vec<u8>> {
    let mut buf = Vec::new();
    crate::echoes_csv::write_echoes(&mut buf, echoes)?;
    if !rates.iter().any(Option::is_some) {
        return Ok(buf);
    }
    let text = String::from_utf8(buf)?;
    let mut out = String::with_capacity(text.len() + 12 * echoes.len());
    for (i, line) in text.lines().enumerate() {
        out.push_str(line);
        match i.checked_sub(1) {
            None => out.push_str(",delta_d_rate"),
            Some(k) => {
                out.push(',');
                if let Some(Some(r)) = rates.get(k) {
                    out.push_str(&r.to_string());
                }
            }
        }
        out.push('\n');
    }
    Ok(out.into_bytes())
}

/// `map --wav`: the facade's echoes of a moving listener's recording, and
/// their path-difference rates.
fn echoes_from_wav(
    args: &MapArgs,
    wav: &Path,
    chirp: ChirpSpec,
    pattern: Option<ChirpPattern>,
) -> Result<(Vec<Echo>, Vec<Option<f64>>)> {
    let poses_path = args.poses.as_ref().context("--wav needs --poses")?;
    let [sx, sy] = args.speaker.context("--wav needs --speaker")?;
    let listener_id = u32::try_from(args.chirp.channel).context("--channel is too large")?;
    let poses = crate::poses_csv::read_poses(poses_path, listener_id)?;
    poses.check_speed(chirp.speed_of_sound_mps)?;
    // The doppler method ranges any sweep through its inverse; the prepared
    // channel does not depend on the shape (only its template, unused there).
    let linear = ChirpSpec { kind: chirpmap::core::scene::SweepKind::Linear, ..chirp };
    let (prep, _) =
        prepare_wav(wav, args.chirp.channel, if args.method == WavMethod::Doppler { &linear } else { &chirp })?;
    poses.check_span(prep.duration_s).with_context(|| format!("poses for {}", wav.display()))?;
    let opts = MovingOptions {
        method: args.method,
        pattern,
        period_s: args.period_ms / 1000.0,
        frame_s: args.frame_ms.map(|m| m / 1000.0),
        speaker: Point::new(sx, sy),
        listener_id,
        echoes_per_frame: args.echoes_per_frame.unwrap_or(args.method.default_echoes_per_frame()),
    };
    let got = chirpmap::RecordingEchoes::from_moving(&prep, &chirp, &poses, &opts)
        .with_context(|| format!("{} with poses {}", wav.display(), poses_path.display()))?;
    if got.chirps_without_pose > 0 {
        let (p0, p1) = poses.span();
        eprintln!(
            "warning: {}: the poses span {p0:.3}–{p1:.3} s, the recording {} 0–{:.3} s; {} of {} chirp(s) have no pose \
             and are skipped",
            poses_path.display(),
            wav.display(),
            prep.duration_s,
            got.chirps_without_pose,
            got.chirps
        );
    }
    eprintln!("{}: {} chirp(s), {} echo(es) by {}", wav.display(), got.chirps, got.echoes.len(), args.method.name());
    Ok((got.echoes, got.delta_d_rates_mps))
}
