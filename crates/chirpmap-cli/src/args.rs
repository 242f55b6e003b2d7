//! Argument types shared by several commands (parsed here, used by the facade).

use chirpmap::ChirpSpec;
use clap::Args;

/// Parses `X,Y` (m).
pub fn parse_point(s: &str) -> Result<[f64; 2], String> {
    let v = parse_numbers(s)?;
    let p: [f64; 2] = v.try_into().map_err(|_| "expected X,Y".to_string())?;
    Ok(p)
}

/// Parses `XMIN,YMIN,XMAX,YMAX` (m).
pub fn parse_bounds(s: &str) -> Result<[f64; 4], String> {
    let v = parse_numbers(s)?;
    let b: [f64; 4] = v.try_into().map_err(|_| "expected XMIN,YMIN,XMAX,YMAX".to_string())?;
    if b[0] >= b[2] || b[1] >= b[3] {
        return Err("need XMIN < XMAX and YMIN < YMAX".into());
    }
    Ok(b)
}

/// Largest coordinate accepted on the command line (m): far beyond any room
/// or field, small enough that distances and squares stay exact enough.
pub const MAX_COORD_M: f64 = 1e6;

fn parse_numbers(s: &str) -> Result<Vec<f64>, String> {
    s.split(',')
        .map(|p| {
            let v: f64 = p.trim().parse().map_err(|_| format!("{:?} is not a number", excerpt(p.trim())))?;
            if !v.is_finite() || v.abs() > MAX_COORD_M {
                return Err(format!("{} must be finite and within ±{MAX_COORD_M} m", excerpt(p.trim())));
            }
            Ok(v)
        })
        .collect()
}

/// At most 40 characters of user text, for error messages.
pub fn excerpt(s: &str) -> String {
    let mut e: String = s.chars().take(40).collect();
    if e.len() < s.len() {
        e.push('…');
    }
    e
}

/// The known chirp and how to read the recording (`range`, `map --wav`).
#[derive(Debug, Args, Clone)]
pub struct ChirpArgs {
    /// Chirp start frequency (Hz) [default: 10000, or the --scene's].
    #[arg(long)]
    pub f_start: Option<f64>,
    /// Chirp end frequency (Hz) [default: 200, or the --scene's].
    #[arg(long)]
    pub f_end: Option<f64>,
    /// Chirp duration T (s) [default: 0.5 as in the scene, or the --scene's]. Paper field test: 1, 0.5 or 0.25.
    #[arg(long)]
    pub duration: Option<f64>,
    /// Speed of sound (m/s) [default: 343, or the --scene's].
    #[arg(long)]
    pub speed_of_sound: Option<f64>,
    /// Channel of the WAV to analyse (from 0); with `map --wav` also the listener id read from the poses file.
    #[arg(long, default_value_t = 0)]
    pub channel: usize,
    /// Largest path difference searched (m). Default: min(60, a·T/2).
    #[arg(long)]
    pub max_delta_d: Option<f64>,
    /// Sweep shape: linear (the paper's), exponential or hyperbolic [default: linear, or the --scene's].
    #[arg(long, value_parser = parse_sweep)]
    pub sweep: Option<chirpmap::core::scene::SweepKind>,
}

impl ChirpArgs {
    /// The chirp: flags over `base` (the scene's chirp, or the defaults).
    pub fn spec(&self, base: ChirpSpec) -> ChirpSpec {
        ChirpSpec {
            f_start_hz: self.f_start.unwrap_or(base.f_start_hz),
            f_end_hz: self.f_end.unwrap_or(base.f_end_hz),
            duration_s: self.duration.unwrap_or(base.duration_s),
            speed_of_sound_mps: self.speed_of_sound.unwrap_or(base.speed_of_sound_mps),
            max_delta_d_m: self.max_delta_d.or(base.max_delta_d_m),
            kind: self.sweep.unwrap_or(base.kind),
        }
    }
}

/// Parses a sweep shape as a scene's `[chirp] kind` spells it.
pub fn parse_sweep(s: &str) -> Result<chirpmap::core::scene::SweepKind, String> {
    serde_json::from_value(serde_json::Value::String(s.to_owned()))
        .map_err(|_| format!("{:?} is not a sweep shape (linear, exponential or hyperbolic)", excerpt(s)))
}

/// Parses `paper` or `evidence`.
pub fn parse_mapper(s: &str) -> Result<chirpmap::MapperKind, String> {
    match s {
        "paper" => Ok(chirpmap::MapperKind::Paper),
        "evidence" => Ok(chirpmap::MapperKind::Evidence),
        _ => Err(format!("{:?} is not a mapper (paper or evidence)", excerpt(s))),
    }
}

/// A position on the command line: `X,Y` (2D) or `X,Y,Z` (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointArg {
    /// X (m).
    pub x: f64,
    /// Y (m).
    pub y: f64,
    /// Height Z (m), when three numbers were given.
    pub z: Option<f64>,
}

/// Parses `X,Y` or `X,Y,Z` (m).
pub fn parse_point_2or3(s: &str) -> Result<PointArg, String> {
    match parse_numbers(s)?.as_slice() {
        [x, y] => Ok(PointArg { x: *x, y: *y, z: None }),
        [x, y, z] => Ok(PointArg { x: *x, y: *y, z: Some(*z) }),
        _ => Err("expected X,Y or X,Y,Z".into()),
    }
}
