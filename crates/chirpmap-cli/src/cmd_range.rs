//! `chirpmap range`: the paper's field pipeline (§IV) on a WAV file — find
//! every chirp, estimate Δd to the first reflection per chirp, and (with a
//! wall normal) the speaker-to-wall distance; median and 95 % CI. The work
//! is the facade's `prepare` and `range`; this file reads and writes.

use crate::args::{ChirpArgs, PointArg, parse_point, parse_point_2or3};
use crate::inputs::{load_scene, prepare_wav};
use crate::mapout::{PlotFormat, provenance};
use crate::output::Staged;
use crate::plot_audio::{render_spectrogram, render_spectrum};
use anyhow::{Context, Result};
use chirpmap::audio::filter::SavitzkyGolay;
use chirpmap::audio::ranging::Estimate;
use chirpmap::audio::spectrum::{FftCache, magnitude_spectrum, stft_magnitude};
use chirpmap::audio::{Method, Ranger};
use chirpmap::core::Sweep;
use chirpmap::{ChirpSpec, Point, Prepared, RangeGeometry};
use clap::Args;
use serde_json::{Value, json};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Args)]
pub struct RangeArgs {
    /// Recording (WAV: 16/24/32-bit integer or 32-bit float, any channels).
    pub wav: PathBuf,
    /// Speaker position X,Y or X,Y,Z (m). With heights, `--echoes` measures 3D path differences and
    /// projects them for the 2D map.
    #[arg(long, value_parser = parse_point_2or3, allow_hyphen_values = true)]
    pub speaker: PointArg,
    /// Microphone position X,Y or X,Y,Z (m).
    #[arg(long, value_parser = parse_point_2or3, allow_hyphen_values = true)]
    pub mic: PointArg,
    /// Direction from the speaker toward the wall, NX,NY; adds the
    /// speaker-to-wall distance to every row and the summary.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    pub wall_normal: Option<[f64; 2]>,
    #[command(flatten)]
    pub chirp: ChirpArgs,
    /// Scene TOML whose [chirp] and speed of sound are the recording's (as `synth` rendered it); the chirp
    /// flags override it.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Ranging method: gap (the paper's), matched or dechirp [default: gap; matched with --echoes,
    /// which needs the impulse response].
    #[arg(long)]
    pub method: Option<Method>,
    /// List up to K reflections per chirp (default K: 20), not only the first: echoes.csv (the
    /// echoes format `map --echoes` reads), echogram.csv and the echogram figure.
    #[arg(long, num_args = 0..=1, default_missing_value = "20", value_name = "K")]
    pub echoes: Option<usize>,
    /// What the WAV holds: `wav` (a recording of chirps) or `rir` (an impulse response, time zero =
    /// emission; needs --echoes).
    #[arg(long, default_value = "wav", value_parser = ["wav", "rir"])]
    pub input: String,
    /// A recording of the direct sound alone (same chirp, or an impulse response with --input rir):
    /// its response models the loudspeaker's ringing instead of each chirp's own direct sound.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Floor height (m): echoes matching the floor's image source are labelled `floor` and left out
    /// of the map (needs heights in --speaker and --mic).
    #[arg(long, allow_hyphen_values = true)]
    pub floor_z: Option<f64>,
    /// Ceiling height (m): echoes matching the ceiling's image source are labelled `ceiling` and left
    /// out of the map.
    #[arg(long, allow_hyphen_values = true)]
    pub ceiling_z: Option<f64>,
    /// Length of the loudspeaker's ringing after the direct peak (ms); estimated from the direct
    /// sound, nothing closer is reported.
    #[arg(long, default_value_t = 2.0, allow_hyphen_values = true)]
    pub ringing_ms: f64,
    /// Length of the system response after its peak that is matched to each echo (ms).
    #[arg(long, default_value_t = 0.6, allow_hyphen_values = true)]
    pub echo_atom_ms: f64,
    /// An echo within this distance (m) of a predicted floor or ceiling echo is labelled (the nearest).
    #[arg(long, default_value_t = 0.08, allow_hyphen_values = true)]
    pub plane_tolerance: f64,
    /// Weakest echo reported, relative to the direct sound (dB).
    #[arg(long, default_value_t = -30.0, allow_hyphen_values = true)]
    pub echo_threshold_db: f64,
    /// Listener id written to echoes.csv [default: the channel], so that several microphones'
    /// echoes concatenate into one map.
    #[arg(long)]
    pub listener: Option<u32>,
    /// Run all three methods; chirps.csv gets a `method` column and
    /// compare.csv one row per method.
    #[arg(long)]
    pub compare: bool,
    /// Figure format (spectrogram and spectrum as .png or .svg).
    #[arg(long, value_enum, default_value_t = PlotFormat::Png)]
    pub plot_format: PlotFormat,
    /// Output directory (chirps.csv, summary.json, spectrogram.png, spectrum.png).
    #[arg(long)]
    pub out: PathBuf,
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |v| format!("{v:.6}"))
}

pub fn run(args: &RangeArgs) -> Result<()> {
    if args.echoes.is_some() {
        return run_echoes(args);
    }
    if args.input != "wav" {
        anyhow::bail!("--input {} needs --echoes (an impulse response has no chirp to range)", args.input);
    }
    for (flag, given) in [
        ("--calibration", args.calibration.is_some()),
        ("--floor-z", args.floor_z.is_some()),
        ("--ceiling-z", args.ceiling_z.is_some()),
    ] {
        if given {
            anyhow::bail!("{flag} applies to --echoes");
        }
    }
    if args.speaker.z.is_some() || args.mic.z.is_some() {
        eprintln!(
            "warning: heights (the Z of --speaker/--mic) are used by --echoes; ranging the first reflection in 2D"
        );
    }
    let method = args.method.unwrap_or(Method::Gap);
    let started = Instant::now();
    let fmt = args.plot_format;
    let mut outputs = vec!["chirps.csv", "summary.json", fmt.spectrogram(), fmt.spectrum()];
    if args.compare {
        outputs.push("compare.csv");
    }
    let inputs: Vec<&Path> =
        [Some(&args.wav), args.scene.as_ref()].into_iter().flatten().map(PathBuf::as_path).collect();
    let geom = RangeGeometry {
        speaker: Point::new(args.speaker.x, args.speaker.y),
        mic: Point::new(args.mic.x, args.mic.y),
        wall_normal: args.wall_normal.map(|[x, y]| Point::new(x, y)),
    };
    geom.validate()?;
    let mut out = Staged::dir(&args.out, "range", &outputs, &inputs)?;
    let base = match &args.scene {
        Some(p) => ChirpSpec::from_scene(&load_scene(p)?.0),
        None => ChirpSpec::default(),
    };
    let chirp = args.chirp.spec(base);
    let methods: Vec<Method> = if args.compare { Method::ALL.to_vec() } else { vec![method] };
    // The recording is read as a stream (issue 14, item 4); CHIRPMAP_RANGE_IN_MEMORY=1 reads it
    // whole, as before (same outputs; the benchmark's baseline).
    let streamed = if std::env::var_os("CHIRPMAP_RANGE_IN_MEMORY").is_some() {
        None
    } else {
        // The header's errors (a missing file, a bad format) with their causes, as `read_wav` gave them.
        chirpmap::audio::wav::WavStream::open(&args.wav, args.chirp.channel)
            .with_context(|| format!("{}", args.wav.display()))?;
        chirpmap::RangeReport::from_wav_stream(&args.wav, args.chirp.channel, &chirp, &methods, &geom)
            .map_err(field_err(&args.wav))?
    };
    // `window_start`: where `prep.x` (the middle chirp's window when streamed) starts in the recording.
    let (prep, clipped, report, window_start) = match streamed {
        Some(s) => {
            if s.clipped_samples > 0 {
                eprintln!(
                    "warning: {}: {} sample(s) at full scale (clipping); estimates may be degraded",
                    args.wav.display(),
                    s.clipped_samples
                );
            }
            (s.prep, s.clipped_samples, s.report, s.window_start)
        }
        None => {
            if std::env::var_os("CHIRPMAP_RANGE_IN_MEMORY").is_none() {
                eprintln!(
                    "note: {}: the level changes too much along the recording for streamed detection; reading it \
                     into memory",
                    args.wav.display()
                );
            }
            let (prep, clipped) = prepare_wav(&args.wav, args.chirp.channel, &chirp)?;
            let report = chirpmap::range(&prep, &methods, &geom).with_context(|| format!("{}", args.wav.display()))?;
            (prep, clipped, report, 0)
        }
    };
    let results = &report.chirps;

    let mut csv = String::from(if args.compare { "method," } else { "" });
    csv.push_str("index,onset_s,delta_f_hz,delta_d_m,wall_distance_m\n");
    for (k, rows) in report.per_method.iter().enumerate() {
        for r in rows {
            if args.compare {
                csv.push_str(methods[k].name());
                csv.push(',');
            }
            let e = r.estimate;
            let wall = e.and_then(|e| chirpmap::wall_distance(&geom, e.delta_d_m));
            let _ = writeln!(
                csv,
                "{},{:.6},{},{},{}",
                r.index,
                r.onset_s,
                fmt_opt(e.map(|e| e.delta_f_hz)),
                fmt_opt(e.map(|e| e.delta_d_m)),
                fmt_opt(wall)
            );
        }
    }
    let summaries: Vec<Value> = report.summaries.iter().map(serde_json::to_value).collect::<Result<_, _>>()?;
    let primary = if args.compare { methods.iter().position(|&m| m == method).unwrap_or(0) } else { 0 };
    let mut summary = serde_json::to_value(report.summary(&prep, &chirp, &geom, primary))?;
    summary["wav"] = json!(args.wav.display().to_string());
    summary["clipped_samples"] = json!(clipped);
    summary["run"] = provenance();

    out.write("chirps.csv", &csv)?;
    if args.compare {
        let mut c = String::from(
            "method,chirps,estimates,delta_d_median,delta_d_ci95_low,delta_d_ci95_high,wall_distance_median,wall_distance_ci95_low,wall_distance_ci95_high\n",
        );
        for s in &summaries {
            let g = |k: &str| s.get(k).and_then(Value::as_f64);
            let ci = |k: &str, i: usize| s.get(k).and_then(|v| v.get(i)).and_then(Value::as_f64);
            let _ = writeln!(
                c,
                "{},{},{},{},{},{},{},{},{}",
                s["method"].as_str().unwrap_or(""),
                s["chirps"],
                s["estimates"],
                fmt_opt(g("delta_d_median")),
                fmt_opt(ci("delta_d_ci95", 0)),
                fmt_opt(ci("delta_d_ci95", 1)),
                fmt_opt(g("wall_distance_median")),
                fmt_opt(ci("wall_distance_ci95", 0)),
                fmt_opt(ci("wall_distance_ci95", 1)),
            );
        }
        out.write("compare.csv", c)?;
    }
    // Figures of one chirp (the middle one), as the paper's Fig. 8.
    let mid = results.len() / 2;
    let (det, est) = (&results[mid].0, results[mid].1[primary]);
    plot_chirp(&mut out, &prep, (window_start, det.onset_sample - window_start), est, mid, results.len(), fmt)?;
    summary["elapsed_s"] = json!(started.elapsed().as_secs_f64());
    out.write("summary.json", serde_json::to_string_pretty(&summary)? + "\n")?;
    // A previous `--compare` run's compare.csv is dropped by the output manifest.
    let dir = out.commit()?;
    for s in &summaries {
        let wall = match s.get("wall_distance_median").and_then(Value::as_f64) {
            Some(w) => format!(", wall distance median {w:.3} m"),
            None => String::new(),
        };
        say!(
            "{}: {} chirps, {} estimates, Δd median {}{}",
            s["method"].as_str().unwrap_or(""),
            s["chirps"],
            s["estimates"],
            s["delta_d_median"].as_f64().map_or("n/a".into(), |v| format!("{v:.4} m")),
            wall
        );
    }
    say!("wrote {} in {:.2} s", dir.display(), started.elapsed().as_secs_f64());
    Ok(())
}

/// `prep.x` starts at sample `window_start` of the recording; `onset` is the chirp's within `prep.x`.
fn plot_chirp(
    out: &mut Staged,
    prep: &Prepared,
    (window_start, onset): (usize, usize),
    est: Option<Estimate>,
    index: usize,
    count: usize,
    fmt: PlotFormat,
) -> Result<()> {
    let fs = prep.sample_rate_hz;
    let tpl = &prep.tpl;
    let pre = (0.05 * fs) as usize;
    let s0 = onset.saturating_sub(pre);
    let s1 = (onset + tpl.len() + (0.15 * fs) as usize).min(prep.x.len());
    let frame = Ranger::gap_frame_len(tpl);
    let f_max = tpl.chirp.f_start_hz().max(tpl.chirp.f_end_hz()) * 1.15;
    let (spectrogram_path, spectrum_path) = (out.path(fmt.spectrogram())?, out.path(fmt.spectrum())?);
    let (spectrogram_shown, spectrum_shown) = (out.shown(fmt.spectrogram()), out.shown(fmt.spectrum()));
    // The two figures are independent: drawn at the same time.
    let spectrogram = || {
        let mut cache = FftCache::default();
        let nfft = (frame * 4).next_power_of_two();
        let hop = (frame / 2).max(1);
        let frames = stft_magnitude(&mut cache, &prep.x[s0..s1], frame, hop, nfft);
        render_spectrogram(
            &spectrogram_path,
            &format!("chirp {} of {count}: spectrogram", index + 1),
            &frames,
            (window_start + s0) as f64 / fs,
            hop as f64 / fs,
            fs / nfft as f64,
            f_max.min(fs / 2.0),
        )
    };
    // Amplitude spectrum of the middle frame of the chirp.
    let spectrum = || {
        let mut cache = FftCache::default();
        let off = (tpl.len() / 2).min(tpl.len().saturating_sub(frame));
        let nfft = (frame * 8).next_power_of_two();
        let seg = prep.x.get(onset + off..onset + off + frame).unwrap_or(&[]);
        let sg = SavitzkyGolay::new((nfft / frame) | 1, 2)?;
        let spec = sg.smooth(&magnitude_spectrum(&mut cache, seg, nfft));
        let bin_hz = fs / nfft as f64;
        let f_d = tpl.chirp.freq_at((off as f64 + 0.5 * frame as f64) / fs);
        let f_r = f_d.zip(est).map(|(f, e)| f + tpl.direction() * e.delta_f_hz);
        let centre = f_d.unwrap_or(0.5 * f_max);
        let span = est.map_or(1000.0, |e| e.delta_f_hz.abs() * 2.5).max(300.0);
        let (lo, hi) = ((centre - span).max(0.0), (centre + span).min(fs / 2.0));
        let idx: Vec<usize> = (0..spec.len()).filter(|&k| (lo..=hi).contains(&(k as f64 * bin_hz))).collect();
        let freqs: Vec<f64> = idx.iter().map(|&k| k as f64 * bin_hz).collect();
        let amps: Vec<f64> = idx.iter().map(|&k| spec[k]).collect();
        render_spectrum(
            &spectrum_path,
            &format!("chirp {} of {count}: frame at {:.3} s into the chirp", index + 1, off as f64 / fs),
            &freqs,
            &amps,
            f_d,
            f_r,
        )
    };
    let (first, second) = rayon::join(spectrogram, spectrum);
    first.with_context(|| format!("cannot write {}", spectrogram_shown.display()))?;
    second.with_context(|| format!("cannot write {}", spectrum_shown.display()))
}

/// Reads one channel of a WAV (clipping warned about, silence refused with a hint).
fn read_channel(wav: &Path, channel: usize) -> Result<(Vec<f32>, f64, usize)> {
    let rec = chirpmap::audio::read_wav(wav).with_context(|| format!("{}", wav.display()))?;
    if rec.clipped_samples > 0 {
        eprintln!(
            "warning: {}: {} sample(s) at full scale (clipping); estimates may be degraded",
            wav.display(),
            rec.clipped_samples
        );
    }
    let fs = f64::from(rec.sample_rate_hz);
    let n_channels = rec.channels.len();
    rec.channel(channel).with_context(|| format!("{}", wav.display()))?;
    let clipped = rec.clipped_samples;
    let mut channels = rec.channels;
    let x = channels.swap_remove(channel);
    if x.iter().all(|v| *v == 0.0) {
        let hint =
            if n_channels > 1 { format!(" (it has {n_channels} channels: try --channel)") } else { String::new() };
        anyhow::bail!("{}: channel {channel} is silent (every sample is zero){hint}", wav.display());
    }
    Ok((x, fs, clipped))
}

fn field_err(file: &Path) -> impl Fn(chirpmap::Error) -> anyhow::Error + '_ {
    move |e| match e {
        chirpmap::Error::Field { field, reason } => {
            anyhow::anyhow!("{}: --{}: {reason}", file.display(), field.replace('_', "-"))
        }
        e => anyhow::anyhow!("{}: {e}", file.display()),
    }
}

/// `range --echoes`: every reflection of every chirp (issue 10).
fn run_echoes(args: &RangeArgs) -> Result<()> {
    let started = Instant::now();
    let method = args.method.unwrap_or(Method::Matched);
    if method != Method::Matched {
        anyhow::bail!(
            "--echoes lists every reflection from the impulse response (--method matched); {} measures one \
             reflection per chirp: drop --method or use --method matched",
            method.name()
        );
    }
    if args.compare {
        anyhow::bail!("--compare ranges the first reflection by every method; it does not combine with --echoes");
    }
    let rir = args.input == "rir";
    let k = args.echoes.unwrap_or(chirpmap::DEFAULT_MAX_ECHOES);
    let heights = match (args.speaker.z, args.mic.z) {
        (Some(a), Some(b)) => Some((a, b)),
        (None, None) => None,
        _ => anyhow::bail!("give heights for both --speaker and --mic (X,Y,Z), or for neither"),
    };
    let geom = chirpmap::RoomGeometry {
        speaker: Point::new(args.speaker.x, args.speaker.y),
        mic: Point::new(args.mic.x, args.mic.y),
        heights_m: heights,
        floor_z_m: args.floor_z,
        ceiling_z_m: args.ceiling_z,
    };
    geom.validate().map_err(|e| match e {
        chirpmap::Error::Field { field, reason } => anyhow::anyhow!("--{}: {reason}", field.replace('_', "-")),
        e => anyhow::anyhow!("{e}"),
    })?;
    let mut opts = chirpmap::EchoOptions {
        max_echoes: k,
        threshold_db: args.echo_threshold_db,
        ringing_s: args.ringing_ms * 1e-3,
        echo_atom_s: args.echo_atom_ms * 1e-3,
        plane_tolerance_m: args.plane_tolerance,
        ..chirpmap::EchoOptions::default()
    };
    opts.validate().map_err(|e| match e {
        chirpmap::Error::Field { field, reason } => anyhow::anyhow!("--{}: {reason}", field.replace('_', "-")),
        e => anyhow::anyhow!("{e}"),
    })?;
    let fmt = args.plot_format;
    let echogram_fig = if matches!(fmt, PlotFormat::Svg) { "echogram.svg" } else { "echogram.png" };
    let mut outputs = vec!["echoes.csv", "echogram.csv", echogram_fig, "summary.json"];
    if !rir {
        outputs.push("chirps.csv");
    }
    let inputs: Vec<&Path> = [Some(&args.wav), args.scene.as_ref(), args.calibration.as_ref()]
        .into_iter()
        .flatten()
        .map(PathBuf::as_path)
        .collect();
    let mut out = Staged::dir(&args.out, "range", &outputs, &inputs)?;
    let base = match &args.scene {
        Some(p) => ChirpSpec::from_scene(&load_scene(p)?.0),
        None => ChirpSpec::default(),
    };
    let chirp = args.chirp.spec(base);
    // A recording of chirps is read as a stream (issue 14, item 4); only its header here.
    let (mut x, mut clipped) = (Vec::new(), 0);
    let fs = if rir {
        let (xr, fs, c) = read_channel(&args.wav, args.chirp.channel)?;
        (x, clipped) = (xr, c);
        fs
    } else {
        let head = chirpmap::audio::wav::WavStream::open(&args.wav, args.chirp.channel)
            .with_context(|| format!("{}", args.wav.display()))?;
        f64::from(head.sample_rate_hz)
    };
    if let Some(cal) = &args.calibration {
        let (cx, cfs, _) = read_channel(cal, args.chirp.channel)?;
        if cfs != fs {
            anyhow::bail!("{}: sampled at {cfs} Hz but the recording at {fs} Hz", cal.display());
        }
        opts.calibration = Some(if rir {
            chirpmap::calibration_response_rir(&cx, cfs, &opts).map_err(field_err(cal))?
        } else {
            let cprep = chirpmap::prepare_room(cx, cfs, &chirp).map_err(field_err(cal))?;
            chirpmap::calibration_response(&cprep, &opts).map_err(field_err(cal))?
        });
    }
    let a = chirp.speed_of_sound_mps;
    let report = if rir {
        let max_dd = chirpmap::rir_max_delta_d(chirp.max_delta_d_m, a, x.len(), fs)?;
        chirpmap::rir_echoes(&x, fs, a, max_dd, &geom, &opts).map_err(field_err(&args.wav))?
    } else {
        // CHIRPMAP_RANGE_IN_MEMORY=1: the recording read whole, as before issue 14 (the
        // benchmark's baseline, scripts/bench/range-memory.sh; same outputs).
        let streamed = if std::env::var_os("CHIRPMAP_RANGE_IN_MEMORY").is_some() {
            None
        } else {
            chirpmap::RoomReport::from_wav_stream(&args.wav, args.chirp.channel, &chirp, &geom, &opts)
                .map_err(field_err(&args.wav))?
        };
        match streamed {
            Some(s) => {
                clipped = s.clipped_samples;
                if clipped > 0 {
                    eprintln!(
                        "warning: {}: {} sample(s) at full scale (clipping); estimates may be degraded",
                        args.wav.display(),
                        clipped
                    );
                }
                s.report
            }
            None => {
                if std::env::var_os("CHIRPMAP_RANGE_IN_MEMORY").is_none() {
                    eprintln!(
                        "note: {}: the level changes too much along the recording for streamed detection; \
                         reading it into memory",
                        args.wav.display()
                    );
                }
                let (xr, _, c) = read_channel(&args.wav, args.chirp.channel)?;
                clipped = c;
                let prep = chirpmap::prepare_room(xr, fs, &chirp).map_err(field_err(&args.wav))?;
                chirpmap::room_echoes(&prep, &geom, &opts).map_err(field_err(&args.wav))?
            }
        }
    };
    let listener = args.listener.unwrap_or(u32::try_from(args.chirp.channel).unwrap_or(u32::MAX));
    // echoes.csv: the map's columns, then ours.
    let mut csv = String::from(
        "source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener,chirp,rank,path_delta_m,strength_db,plane\n",
    );
    for e in &report.echoes {
        let _ = writeln!(
            csv,
            "{},{},{},{},{:.6},{},{:.6},{},{},{},{:.6},{:.2},{}",
            geom.speaker.x,
            geom.speaker.y,
            geom.mic.x,
            geom.mic.y,
            e.delta_d_m,
            if e.maps() { 1 } else { 0 },
            e.t_s,
            listener,
            e.chirp,
            e.rank,
            e.path_delta_m,
            e.strength_db,
            e.plane.unwrap_or("")
        );
    }
    out.write("echoes.csv", &csv)?;
    let mut gram = String::from("path_delta_m,level_db\n");
    for (d, l) in &report.echogram {
        let _ = writeln!(gram, "{d:.5},{l:.3}");
    }
    out.write("echogram.csv", &gram)?;
    if !rir {
        let mut c = String::from("index,onset_s,echoes,first_path_delta_m,first_delta_d_m\n");
        for (i, t) in report.chirp_onsets_s.iter().enumerate() {
            let mine: Vec<&chirpmap::RoomEcho> = report.echoes.iter().filter(|e| e.chirp == i).collect();
            let first = mine.iter().find(|e| e.maps());
            let _ = writeln!(
                c,
                "{i},{t:.6},{},{},{}",
                mine.len(),
                fmt_opt(first.map(|e| e.path_delta_m)),
                fmt_opt(first.map(|e| e.delta_d_m))
            );
        }
        out.write("chirps.csv", &c)?;
    }
    let marks: Vec<(f64, String)> =
        report.clusters.iter().map(|c| (c.path_delta_m, c.plane.map_or(String::new(), str::to_string))).collect();
    let shown = out.shown(echogram_fig);
    crate::plot_audio::render_echogram(
        &out.path(echogram_fig)?,
        &format!(
            "echogram: median of {} {}",
            report.chirp_onsets_s.len(),
            if rir { "impulse response" } else { "chirp(s)" }
        ),
        &report.echogram,
        &marks,
        &report.predicted,
    )
    .with_context(|| format!("cannot write {}", shown.display()))?;
    let n_low = report.echoes.iter().filter(|e| e.path_delta_m < 0.45).count();
    let summary = json!({
        "method": "matched",
        "input": args.input,
        "wav": args.wav.display().to_string(),
        "calibration": args.calibration.as_ref().map(|p| p.display().to_string()),
        "sample_rate_hz": fs,
        "chirps": report.chirp_onsets_s.len(),
        "echoes": report.echoes.len(),
        "echoes_below_0_45_m": n_low,
        "max_echoes_per_chirp": k,
        "echo_threshold_db": opts.threshold_db,
        "ringing_ms": opts.ringing_s * 1e3,
        "echo_atom_ms": opts.echo_atom_s * 1e3,
        "min_delta_d_m": report.min_delta_d_m,
        "max_delta_d_m": report.max_delta_d_m,
        "speaker": [geom.speaker.x, geom.speaker.y, args.speaker.z],
        "mic": [geom.mic.x, geom.mic.y, args.mic.z],
        "floor_z": args.floor_z,
        "ceiling_z": args.ceiling_z,
        "predicted": report.predicted.iter().map(|(l, d)| json!({"plane": l, "path_delta_m": d})).collect::<Vec<_>>(),
        "clusters": report.clusters,
        "chirp": {"f_start": chirp.f_start_hz, "f_end": chirp.f_end_hz, "duration": chirp.duration_s,
                  "kind": chirp.kind, "speed_of_sound": a},
        "clipped_samples": clipped,
        "run": provenance(),
        "elapsed_s": started.elapsed().as_secs_f64(),
    });
    out.write("summary.json", serde_json::to_string_pretty(&summary)? + "\n")?;
    let dir = out.commit()?;
    say!(
        "{} chirp(s), {} echo(es); found in at least half of them: {}",
        report.chirp_onsets_s.len(),
        report.echoes.len(),
        report
            .clusters
            .iter()
            .map(|c| format!("{:.3} m{}", c.path_delta_m, c.plane.map_or(String::new(), |p| format!(" ({p})"))))
            .collect::<Vec<_>>()
            .join(", ")
    );
    say!("wrote {} in {:.2} s", dir.display(), started.elapsed().as_secs_f64());
    Ok(())
}
