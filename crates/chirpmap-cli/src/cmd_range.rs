//! `chirpmap range`: the paper's field pipeline (§IV) on a WAV file — find
//! every chirp, estimate Δd to the first reflection per chirp, and (with a
//! wall normal) the speaker-to-wall distance; median and 95 % CI.

use crate::output::Staged;
use crate::plot_audio::{render_spectrogram, render_spectrum};
use anyhow::{Context, Result, bail};
use chirpmap_audio::filter::{SavitzkyGolay, paper_highpass};
use chirpmap_audio::ranging::{ChirpResult, Estimate, range_signal};
use chirpmap_audio::spectrum::{FftCache, magnitude_spectrum, stft_magnitude};
use chirpmap_audio::stats::{median, median_ci95};
use chirpmap_audio::{ChirpTemplate, Method, RangeLimits, Ranger, read_wav, wall_distance_m};
use chirpmap_core::{LinearChirp, Point, Sweep};
use clap::Args;
use serde_json::{Value, json};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

pub fn parse_point(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|_| format!("{p:?} is not a number")))
        .collect::<Result<_, _>>()?;
    let p: [f64; 2] = v.try_into().map_err(|_| "expected X,Y".to_string())?;
    if p.iter().any(|x| !x.is_finite()) {
        return Err("need finite values".into());
    }
    Ok(p)
}

/// The known chirp and how to read the recording (shared with `map --wav`).
#[derive(Debug, Args, Clone)]
pub struct ChirpArgs {
    /// Chirp start frequency (Hz). Paper field test: 10 kHz.
    #[arg(long, default_value_t = 10_000.0)]
    pub f_start: f64,
    /// Chirp end frequency (Hz). Paper field test: 0.2 kHz.
    #[arg(long, default_value_t = 200.0)]
    pub f_end: f64,
    /// Chirp duration T (s). Paper field test: 1, 0.5 or 0.25.
    #[arg(long, default_value_t = 1.0)]
    pub duration: f64,
    /// Speed of sound (m/s).
    #[arg(long, default_value_t = 343.0)]
    pub speed_of_sound: f64,
    /// Channel to analyse (from 0).
    #[arg(long, default_value_t = 0)]
    pub channel: usize,
    /// Largest path difference searched (m). Default: min(60, a·T/2).
    #[arg(long)]
    pub max_delta_d: Option<f64>,
}

/// Plausible speeds of sound (m/s): from cold air's ~330 with wide margins
/// for other gases, up to water's ~1500.
pub const SPEED_OF_SOUND_RANGE: (f64, f64) = (100.0, 2000.0);

/// A loaded, high-passed channel and the chirp template.
#[derive(Debug)]
pub struct Prepared {
    pub x: Vec<f32>,
    pub tpl: ChirpTemplate,
    pub lim: RangeLimits,
    pub sample_rate_hz: f64,
    pub clipped: usize,
    pub duration_s: f64,
}

pub fn prepare(wav: &std::path::Path, c: &ChirpArgs) -> Result<Prepared> {
    let rec = read_wav(wav).with_context(|| format!("{}", wav.display()))?;
    if rec.clipped_samples > 0 {
        eprintln!(
            "warning: {}: {} sample(s) at full scale (clipping); estimates may be degraded",
            wav.display(),
            rec.clipped_samples
        );
    }
    let fs = f64::from(rec.sample_rate_hz);
    rec.channel(c.channel)?;
    let (clipped, mut channels) = (rec.clipped_samples, rec.channels);
    let mut x = channels.swap_remove(c.channel);
    if x.iter().all(|v| *v == 0.0) {
        bail!("{}: channel {} is silent (every sample is zero)", wav.display(), c.channel);
    }
    let chirp = LinearChirp::new(c.f_start, c.f_end, c.duration)?;
    let tpl = ChirpTemplate::new(chirp, fs).with_context(|| format!("{}", wav.display()))?;
    if tpl.len() > x.len() {
        bail!(
            "{}: the chirp ({} s) is longer than the recording ({:.3} s); check --duration",
            wav.display(),
            c.duration,
            x.len() as f64 / fs
        );
    }
    if !(c.speed_of_sound.is_finite() && (SPEED_OF_SOUND_RANGE.0..=SPEED_OF_SOUND_RANGE.1).contains(&c.speed_of_sound))
    {
        bail!(
            "--speed-of-sound must be between {} and {} m/s (air: about 343), got {}",
            SPEED_OF_SOUND_RANGE.0,
            SPEED_OF_SOUND_RANGE.1,
            c.speed_of_sound
        );
    }
    paper_highpass(fs)?.filter_in_place(&mut x);
    let mut lim = RangeLimits::for_chirp(c.duration, c.speed_of_sound);
    if let Some(m) = c.max_delta_d {
        if !(m.is_finite() && m > lim.min_delta_d_m) {
            bail!("--max-delta-d must be > {} m", lim.min_delta_d_m);
        }
        // A reflection later than one chirp no longer overlaps its direct
        // sound, and the search window would reach the next chirp.
        let most = c.speed_of_sound * c.duration;
        if m > most {
            bail!(
                "--max-delta-d {m} m is longer than a·T = {most:.1} m (speed of sound × --duration); \
                 echoes that late are not ranged"
            );
        }
        lim.max_delta_d_m = m;
    }
    let duration_s = x.len() as f64 / fs;
    Ok(Prepared { x, tpl, lim, sample_rate_hz: fs, clipped, duration_s })
}

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
    /// Ranging method: gap (the paper's), matched or dechirp.
    #[arg(long, default_value = "gap")]
    pub method: Method,
    /// Run all three methods; chirps.csv gets a `method` column and
    /// compare.csv one row per method.
    #[arg(long)]
    pub compare: bool,
    /// Output directory (chirps.csv, summary.json, spectrogram.png, spectrum.png).
    #[arg(long)]
    pub out: PathBuf,
}

fn method_summary(method: Method, rows: &[ChirpResult], speaker: Point, mic: Point, normal: Option<Point>) -> Value {
    let dds: Vec<f64> = rows.iter().filter_map(|r| r.estimate.map(|e| e.delta_d_m)).collect();
    let mut s = json!({
        "method": method.name(),
        "chirps": rows.len(),
        "estimates": dds.len(),
        "delta_d_median": median(&dds),
        "delta_d_ci95": median_ci95(&dds),
    });
    if let Some(n) = normal {
        let ws: Vec<f64> = dds.iter().filter_map(|&d| wall_distance_m(speaker, mic, n, d)).collect();
        s["wall_distance_median"] = json!(median(&ws));
        s["wall_distance_ci95"] = json!(median_ci95(&ws));
    }
    s
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |v| format!("{v:.6}"))
}

pub fn run(args: &RangeArgs) -> Result<()> {
    let started = Instant::now();
    let speaker = Point::new(args.speaker[0], args.speaker[1]);
    let mic = Point::new(args.mic[0], args.mic[1]);
    if speaker.dist(mic) < 1e-9 {
        bail!("--speaker and --mic are the same point ({}, {}); the direct distance must be > 0", speaker.x, speaker.y);
    }
    let normal = match args.wall_normal {
        Some([nx, ny]) if (nx * nx + ny * ny).sqrt() < 1e-12 => bail!("--wall-normal must not be zero"),
        Some([nx, ny]) => Some(Point::new(nx, ny)),
        None => None,
    };
    let prep = prepare(&args.wav, &args.chirp)?;
    let methods: Vec<Method> = if args.compare { Method::ALL.to_vec() } else { vec![args.method] };
    let results =
        range_signal(&prep.x, &prep.tpl, &methods, &prep.lim).with_context(|| format!("{}", args.wav.display()))?;
    let fs = prep.sample_rate_hz;
    let per_method: Vec<Vec<ChirpResult>> = (0..methods.len())
        .map(|k| {
            results
                .iter()
                .enumerate()
                .map(|(i, (d, e))| ChirpResult { index: i, onset_s: d.onset_sample as f64 / fs, estimate: e[k] })
                .collect()
        })
        .collect();

    let mut csv = String::from(if args.compare { "method," } else { "" });
    csv.push_str("index,onset_s,delta_f_hz,delta_d_m,wall_distance_m\n");
    for (k, rows) in per_method.iter().enumerate() {
        for r in rows {
            if args.compare {
                csv.push_str(methods[k].name());
                csv.push(',');
            }
            let e = r.estimate;
            let wall = e.zip(normal).and_then(|(e, n)| wall_distance_m(speaker, mic, n, e.delta_d_m));
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
    let summaries: Vec<Value> =
        per_method.iter().zip(&methods).map(|(rows, &m)| method_summary(m, rows, speaker, mic, normal)).collect();
    let primary = if args.compare { methods.iter().position(|&m| m == args.method).unwrap_or(0) } else { 0 };
    let mut summary = summaries[primary].clone();
    summary["wav"] = json!(args.wav.display().to_string());
    summary["sample_rate_hz"] = json!(fs);
    summary["recording_s"] = json!(prep.duration_s);
    summary["clipped_samples"] = json!(prep.clipped);
    summary["speaker"] = json!(args.speaker);
    summary["mic"] = json!(args.mic);
    summary["chirp"] =
        json!({"f_start": args.chirp.f_start, "f_end": args.chirp.f_end, "duration": args.chirp.duration});
    summary["max_delta_d_m"] = json!(prep.lim.max_delta_d_m);
    summary["gap_resolution_floor_m"] =
        json!(chirpmap_audio::ranging::gap_floor_m(&prep.tpl, prep.lim.speed_of_sound_mps));
    if args.compare {
        summary["compare"] = json!(summaries);
    }

    let mut out = Staged::new(&args.out)?;
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
    plot_chirp(&mut out, &prep, det.onset_sample, est, mid, results.len())?;
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
        &out.path("spectrogram.png"),
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
        &out.path("spectrum.png"),
        &format!("chirp {} of {count}: frame at {:.3} s into the chirp", index + 1, off as f64 / fs),
        &freqs,
        &amps,
        f_d,
        f_r,
    )
}
