//! Plain-Rust half of `chirpmap.room_echoes` (issue 10, item 1, "every
//! reflection"): what `chirpmap range --echoes` computes
//! (crates/chirpmap-cli/src/cmd_range.rs, `run_echoes`), from samples in
//! memory instead of WAV files. The work is the facade's
//! ([`chirpmap::prepare_room`], [`chirpmap::room_echoes`],
//! [`chirpmap::rir_echoes`], [`chirpmap::calibration_response`]); this
//! file only assembles its inputs as the CLI does and names the Python
//! argument in every error. No Python here, so the unit tests run without
//! an interpreter.

use crate::convert::error_text;
use chirpmap::core::scene::SweepKind;
use chirpmap::{ChirpSpec, EchoOptions, Point, RoomGeometry, RoomReport};

/// Largest `max_echoes` (per chirp) the facade accepts ([`EchoOptions::validate`]).
pub const MAX_ECHOES_LIMIT: usize = 1000;

/// What the samples hold: a recording of chirps, or an impulse response
/// whose time zero is the emission (`range --input wav|rir`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Input {
    /// A recording of chirps (the CLI's `wav`).
    Recording,
    /// An impulse response (the CLI's `rir`).
    Rir,
}

impl std::str::FromStr for Input {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "recording" => Ok(Self::Recording),
            "rir" => Ok(Self::Rir),
            other => Err(format!(
                "input: {:?} is not an input kind (recording or rir)",
                chirpmap::core::error::excerpt(other, 0)
            )),
        }
    }
}

/// Parses a sweep shape as a scene's `[chirp] kind` (and the CLI's `--sweep`) spells it.
pub fn parse_sweep(s: &str) -> Result<SweepKind, String> {
    serde_json::from_value(serde_json::Value::String(s.to_owned())).map_err(|_| {
        format!(
            "sweep: {:?} is not a sweep shape (linear, exponential or hyperbolic)",
            chirpmap::core::error::excerpt(s, 0)
        )
    })
}

/// The positions as the CLI takes them: `(x, y)` each, heights for both or neither.
pub fn geometry(
    speaker: [f64; 2],
    mic: [f64; 2],
    heights_m: Option<(f64, f64)>,
    floor_z_m: Option<f64>,
    ceiling_z_m: Option<f64>,
) -> Result<RoomGeometry, String> {
    if heights_m.is_none() {
        for (name, given) in [("floor_z", floor_z_m.is_some()), ("ceiling_z", ceiling_z_m.is_some())] {
            if given {
                return Err(format!("{name}: needs heights: give speaker=(x, y, z) and mic=(x, y, z)"));
            }
        }
    }
    let geom = RoomGeometry {
        speaker: Point::new(speaker[0], speaker[1]),
        mic: Point::new(mic[0], mic[1]),
        heights_m,
        floor_z_m,
        ceiling_z_m,
    };
    geom.validate().map_err(|e| error_text(&e))?;
    Ok(geom)
}

/// The echo options, validated; errors name the Python keyword.
pub fn echo_options(
    max_echoes: usize,
    echo_threshold_db: f64,
    ringing_ms: f64,
    echo_atom_ms: f64,
    plane_tolerance_m: f64,
) -> Result<EchoOptions, String> {
    if max_echoes == 0 || max_echoes > MAX_ECHOES_LIMIT {
        return Err(format!("max_echoes: must be in 1..={MAX_ECHOES_LIMIT}, got {max_echoes}"));
    }
    let opts = EchoOptions {
        max_echoes,
        threshold_db: echo_threshold_db,
        ringing_s: ringing_ms * 1e-3,
        echo_atom_s: echo_atom_ms * 1e-3,
        plane_tolerance_m,
        ..EchoOptions::default()
    };
    opts.validate().map_err(|e| error_text(&e))?;
    Ok(opts)
}

/// Every reflection of `x` (a recording or an impulse response at
/// `sample_rate_hz`), as `range --echoes` reports them; `calibration`: the
/// direct sound alone (same kind of input, same rate). The steps and their
/// order are the CLI's, so the same samples give the same report bit for
/// bit (a recording is prepared in memory, which the facade guarantees
/// equal to the CLI's streamed reading, [`RoomReport::from_wav_stream`]).
pub fn room_report(
    x: Vec<f32>,
    sample_rate_hz: f64,
    input: Input,
    chirp: &ChirpSpec,
    geom: &RoomGeometry,
    mut opts: EchoOptions,
    calibration: Option<Vec<f32>>,
) -> Result<RoomReport, String> {
    if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
        return Err(format!("sample_rate: must be finite and > 0 Hz, got {sample_rate_hz}"));
    }
    if let Some(cx) = calibration {
        if cx.iter().all(|v| *v == 0.0) {
            return Err("calibration: the channel is silent (every sample is zero)".into());
        }
        let response = match input {
            Input::Rir => chirpmap::calibration_response_rir(&cx, sample_rate_hz, &opts),
            Input::Recording => chirpmap::prepare_room(cx, sample_rate_hz, chirp)
                .and_then(|prep| chirpmap::calibration_response(&prep, &opts)),
        };
        opts.calibration = Some(response.map_err(|e| format!("calibration: {}", error_text(&e)))?);
    }
    let report = match input {
        Input::Rir => {
            let a = chirp.speed_of_sound_mps;
            chirpmap::rir_max_delta_d(chirp.max_delta_d_m, a, x.len(), sample_rate_hz)
                .and_then(|max_dd| chirpmap::rir_echoes(&x, sample_rate_hz, a, max_dd, geom, &opts))
        }
        Input::Recording => {
            chirpmap::prepare_room(x, sample_rate_hz, chirp).and_then(|prep| chirpmap::room_echoes(&prep, geom, &opts))
        }
    };
    report.map_err(|e| error_text(&e))
}

/// The columns of `echoes.csv` that `range --echoes` adds after the map's
/// eight (weight 1 for walls, 0 for labelled floor and ceiling echoes):
/// per echo `chirp, rank, path_delta_m, strength_db, plane` (`""` = none).
pub type RoomColumns = (Vec<i64>, Vec<i64>, Vec<f64>, Vec<f64>, Vec<&'static str>);

/// Splits the report's echoes into the extra columns of echoes.csv.
pub fn room_columns(report: &RoomReport) -> RoomColumns {
    let n = report.echoes.len();
    let mut cols: RoomColumns =
        (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n), Vec::new());
    for e in &report.echoes {
        cols.0.push(i64::try_from(e.chirp).unwrap_or(i64::MAX));
        cols.1.push(i64::try_from(e.rank).unwrap_or(i64::MAX));
        cols.2.push(e.path_delta_m);
        cols.3.push(e.strength_db);
        cols.4.push(e.plane.unwrap_or(""));
    }
    cols
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chirp() -> ChirpSpec {
        ChirpSpec { duration_s: 0.1, ..ChirpSpec::default() }
    }

    #[test]
    fn errors_name_the_python_argument() {
        let g = geometry([0.0, 0.0], [1.0, 0.0], None, Some(0.0), None).expect_err("floor without heights");
        assert!(g.starts_with("floor_z: needs heights"), "{g}");
        let g = geometry([0.0, 0.0], [1.0, 0.0], None, None, Some(3.0)).expect_err("ceiling without heights");
        assert!(g.starts_with("ceiling_z: needs heights"), "{g}");
        let g = geometry([0.0, 0.0], [1.0, 0.0], Some((1.0, 1.0)), Some(1.5), None).expect_err("floor too high");
        assert!(g.starts_with("floor_z: 1.5 m is not below"), "{g}");
        let g = geometry([1.0, 0.0], [1.0, 0.0], None, None, None).expect_err("same point");
        assert!(g.contains("same point"), "{g}");
        assert!(echo_options(0, -30.0, 2.0, 0.6, 0.08).expect_err("0").starts_with("max_echoes: must be in 1..=1000"));
        assert!(echo_options(20, 3.0, 2.0, 0.6, 0.08).expect_err("dB").starts_with("echo_threshold_db: "));
        assert!(echo_options(20, -30.0, -1.0, 0.6, 0.08).expect_err("ringing").starts_with("ringing_ms: "));
        assert!(echo_options(20, -30.0, 2.0, f64::NAN, 0.08).expect_err("atom").starts_with("echo_atom_ms: "));
        assert!(echo_options(20, -30.0, 2.0, 0.6, 0.0).expect_err("tol").starts_with("plane_tolerance: "));
        assert!("wav".parse::<Input>().expect_err("wav").starts_with("input: \"wav\" is not"));
        assert_eq!(parse_sweep("exponential"), Ok(SweepKind::Exponential));
        assert!(parse_sweep("log").expect_err("log").starts_with("sweep: \"log\" is not a sweep shape"));
    }

    #[test]
    fn the_facade_defaults_pass() {
        let d = EchoOptions::default();
        let o = echo_options(d.max_echoes, d.threshold_db, d.ringing_s * 1e3, d.echo_atom_s * 1e3, d.plane_tolerance_m)
            .expect("defaults");
        assert_eq!(o, d);
    }

    #[test]
    fn bad_samples_are_errors_not_panics() {
        let geom = geometry([0.0, 0.0], [1.0, 0.0], None, None, None).expect("valid");
        let opts = EchoOptions::default();
        let silent = vec![0.0f32; 9600];
        let err = room_report(silent.clone(), 48_000.0, Input::Recording, &chirp(), &geom, opts.clone(), None)
            .expect_err("silent recording");
        assert!(err.contains("silent"), "{err}");
        let err =
            room_report(silent.clone(), 48_000.0, Input::Rir, &chirp(), &geom, opts.clone(), None).expect_err("rir");
        assert!(err.contains("impulse response is silent"), "{err}");
        let mut click = vec![0.0f32; 9600];
        click[100] = 1.0;
        let err = room_report(click.clone(), 48_000.0, Input::Rir, &chirp(), &geom, opts.clone(), Some(silent))
            .expect_err("silent calibration");
        assert!(err.starts_with("calibration: "), "{err}");
        let err =
            room_report(click.clone(), f64::NAN, Input::Rir, &chirp(), &geom, opts.clone(), None).expect_err("rate");
        assert!(err.starts_with("sample_rate: "), "{err}");
        let err = room_report(click[..101].to_vec(), 48_000.0, Input::Recording, &chirp(), &geom, opts, None)
            .expect_err("short");
        assert!(err.starts_with("duration: "), "{err}");
    }

    #[test]
    fn an_impulse_response_gives_its_echo() {
        // A click and a half-strength copy 5 ms later (beyond the 2 ms
        // ringing): Δd = 240 samples · a / fs = 1.715 m, −6 dB.
        let fs = 48_000.0;
        let mut h = vec![0.0f32; 4800];
        h[200] = 1.0;
        h[200 + 240] = 0.5;
        let geom = geometry([0.0, 0.0], [1.0, 0.0], None, None, None).expect("valid");
        let r = room_report(h, fs, Input::Rir, &chirp(), &geom, EchoOptions::default(), None).expect("report");
        let (chirps, ranks, pd, db, planes) = room_columns(&r);
        assert_eq!((chirps.as_slice(), ranks.as_slice(), planes.as_slice()), (&[0][..], &[1][..], &[""][..]));
        assert!((pd[0] - 240.0 / fs * 343.0).abs() < 0.01, "{pd:?}");
        assert!((db[0] + 6.02).abs() < 0.5, "{db:?}");
    }
}
