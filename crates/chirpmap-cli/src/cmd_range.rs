//! `chirpmap range`: the paper's field pipeline (§IV) on a WAV file — find
//! every chirp, estimate Δd to the first reflection per chirp, and (with a
//! wall normal) the speaker-to-wall distance; median and 95 % CI. The work
//! is the facade's `prepare` and `range`; this file reads and writes.

use crate::args::{ChirpArgs, parse_point};
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
    /// Speaker position X,Y (m).
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    pub speaker: [f64; 2],
    /// Microphone position X,Y (m).
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    pub mic: [f64; 2],
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
    /// Ranging method: gap (the paper's), matched or dechirp.
    #[arg(long, default_value = "gap")]
    pub method: Method,
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
    let started = Instant::now();
    let fmt = args.plot_format;
    let mut outputs = vec!["chirps.csv", "summary.json", fmt.spectrogram(), fmt.spectrum()];
    if args.compare {
        outputs.push("compare.csv");
    }
    let inputs: Vec<&Path> =
        [Some(&args.wav), args.scene.as_ref()].into_iter().flatten().map(PathBuf::as_path).collect();
    let geom = RangeGeometry {
        speaker: Point::new(args.speaker[0], args.speaker[1]),
        mic: Point::new(args.mic[0], args.mic[1]),
        wall_normal: args.wall_normal.map(|[x, y]| Point::new(x, y)),
    };
    geom.validate()?;
    let mut out = Staged::dir(&args.out, &outputs, &inputs)?;
    let base = match &args.scene {
        Some(p) => ChirpSpec::from_scene(&load_scene(p)?.0),
        None => ChirpSpec::default(),
    };
    let chirp = args.chirp.spec(base);
    let (prep, clipped) = prepare_wav(&args.wav, args.chirp.channel, &chirp)?;
    let methods: Vec<Method> = if args.compare { Method::ALL.to_vec() } else { vec![args.method] };
    let report = chirpmap::range(&prep, &methods, &geom).with_context(|| format!("{}", args.wav.display()))?;
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
    let primary = if args.compare { methods.iter().position(|&m| m == args.method).unwrap_or(0) } else { 0 };
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
    plot_chirp(&mut out, &prep, det.onset_sample, est, mid, results.len(), fmt)?;
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

fn plot_chirp(
    out: &mut Staged,
    prep: &Prepared,
    onset: usize,
    est: Option<Estimate>,
    index: usize,
    count: usize,
    fmt: PlotFormat,
) -> Result<()> {
    let fs = prep.sample_rate_hz;
    let tpl = &prep.tpl;
    let mut cache = FftCache::default();
    let pre = (0.05 * fs) as usize;
    let s0 = onset.saturating_sub(pre);
    let s1 = (onset + tpl.len() + (0.15 * fs) as usize).min(prep.x.len());
    let frame = Ranger::gap_frame_len(tpl);
    let nfft = (frame * 4).next_power_of_two();
    let hop = (frame / 2).max(1);
    let frames = stft_magnitude(&mut cache, &prep.x[s0..s1], frame, hop, nfft);
    let f_max = tpl.chirp.f_start_hz().max(tpl.chirp.f_end_hz()) * 1.15;
    render_spectrogram(
        &out.path(fmt.spectrogram())?,
        &format!("chirp {} of {count}: spectrogram", index + 1),
        &frames,
        s0 as f64 / fs,
        hop as f64 / fs,
        fs / nfft as f64,
        f_max.min(fs / 2.0),
    )?;
    // Amplitude spectrum of the middle frame of the chirp.
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
        &out.path(fmt.spectrum())?,
        &format!("chirp {} of {count}: frame at {:.3} s into the chirp", index + 1, off as f64 / fs),
        &freqs,
        &amps,
        f_d,
        f_r,
    )
}
