//! Plain-Rust halves of the bindings: rows of a numpy array to echoes and
//! back, scenes from TOML, a dict (as JSON) or a file, and error text. No
//! Python here, so the unit tests run without an interpreter.

use chirpmap::core::error::Num;
use chirpmap::core::geometry::MAX_COORD_M;
use chirpmap::{Echo, EvidenceParams, Highlight, MapperKind, MappingParams, Point, Scene, Surface, SynthConfig};

/// Columns of `echoes.csv` (docs/file-formats.md), in the order the bindings' N × k
/// arrays use: the first five are required, then `weight`, `t`, `listener`
/// and `sigma_m` (the 1-σ uncertainty of Δd, m; NaN = none).
pub const ECHO_COLUMNS: [&str; 9] =
    ["source_x", "source_y", "listener_x", "listener_y", "delta_d", "weight", "t", "listener", "sigma_m"];

/// The message of an error and of every error below it, joined by `: `, as
/// the CLI prints errors (`anyhow`'s `{:#}`), skipping a cause whose text
/// the message already ends with (transparent wrappers repeat it).
pub fn error_text(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let m = c.to_string();
        if !text.ends_with(&m) {
            text.push_str(": ");
            text.push_str(&m);
        }
        cause = c.source();
    }
    text
}

/// Echoes from a row-major `n × cols` table (`cols` ∈ {5, 6, 7, 8, 9}, the
/// columns of [`ECHO_COLUMNS`]), validated as the CLI validates echoes.csv:
/// every value finite (but an absent `sigma_m` is NaN), positions within
/// ±[`MAX_COORD_M`], `listener` a non-negative integer id, Δd ≥ 0, weight ≥ 0.
/// `sigma_m`, when given, overrides or supplies the ninth column (NaN = none).
pub fn echoes_from_rows(data: &[f64], cols: usize, sigma_m: Option<&[f64]>) -> Result<Vec<Echo>, String> {
    if !(5..=9).contains(&cols) {
        return Err(format!("echoes must have 5 to 9 columns ({}), got {cols}", ECHO_COLUMNS.join(",")));
    }
    if !data.len().is_multiple_of(cols) {
        return Err(format!("echoes: {} values do not make rows of {cols}", data.len()));
    }
    let n = data.len() / cols;
    if let Some(s) = sigma_m
        && s.len() != n
    {
        return Err(format!("sigma: {} values for {n} echoes", s.len()));
    }
    let mut echoes = Vec::with_capacity(n);
    for (i, row) in data.chunks_exact(cols).enumerate() {
        let at = |k: usize| -> Result<f64, String> {
            let v = row[k];
            if v.is_finite() { Ok(v) } else { Err(format!("echoes[{i}]: `{}` = {v} is not finite", ECHO_COLUMNS[k])) }
        };
        let optional = |k: usize, default: f64| if k < cols { at(k) } else { Ok(default) };
        let (source, mic) = (Point::new(at(0)?, at(1)?), Point::new(at(2)?, at(3)?));
        let delta_d_m = at(4)?;
        let weight = optional(5, 1.0)?;
        let t_s = optional(6, 0.0)?;
        let listener = optional(7, 0.0)?;
        if listener < 0.0 || listener.fract() != 0.0 || listener > f64::from(u32::MAX) {
            return Err(format!("echoes[{i}]: `listener` = {} must be a non-negative integer id", Num(listener)));
        }
        for (what, p) in [("source", source), ("listener", mic)] {
            if !p.is_sane() {
                return Err(format!("echoes[{i}]: {what} {p} is beyond ±{} m", Num(MAX_COORD_M)));
            }
        }
        let mut echo =
            Echo::new(source, mic, delta_d_m, weight, t_s, listener as u32).map_err(|e| format!("echoes[{i}]: {e}"))?;
        let sigma = match sigma_m {
            Some(s) => s[i],
            None if cols == 9 => row[8],
            None => f64::NAN,
        };
        if !sigma.is_nan() {
            if !(sigma.is_finite() && sigma > 0.0) {
                return Err(format!(
                    "echoes[{i}]: `sigma_m` = {} must be > 0 (the 1-σ uncertainty of delta_d, m)",
                    Num(sigma)
                ));
            }
            echo = echo.with_sigma_m(sigma).map_err(|e| format!("echoes[{i}]: {e}"))?;
        }
        echoes.push(echo);
    }
    Ok(echoes)
}

/// Echoes as a row-major `n × 9` table in [`ECHO_COLUMNS`] order (`sigma_m`
/// NaN where absent), or `n × 8` when no echo has a `sigma_m` — the columns
/// `echoes.csv` holds.
pub fn echoes_to_rows(echoes: &[Echo]) -> (Vec<f64>, usize) {
    let with_sigma = echoes.iter().any(|e| e.sigma_m.is_some());
    let cols = if with_sigma { 9 } else { 8 };
    let mut v = Vec::with_capacity(echoes.len() * cols);
    for e in echoes {
        v.extend([
            e.source.x,
            e.source.y,
            e.listener.x,
            e.listener.y,
            e.delta_d_m,
            e.weight,
            e.t_s,
            f64::from(e.listener_id),
        ]);
        if with_sigma {
            v.push(e.sigma_m.unwrap_or(f64::NAN));
        }
    }
    (v, cols)
}

/// Highlights as a row-major `n × 3` table `x, y, value` (highlights.csv).
pub fn highlights_to_rows(highlights: &[Highlight]) -> Vec<f64> {
    highlights.iter().flat_map(|h| [h.pos.x, h.pos.y, h.value]).collect()
}

/// A surface as the fields of surfaces.csv: `kind, x0, y0, x1, y1, support,
/// ambiguous` (a point's `x1, y1` equal its `x0, y0`).
pub fn surface_fields(s: &Surface) -> (&'static str, [f64; 4], usize, bool) {
    let kind = match s.kind {
        chirpmap::SurfaceKind::Line => "line",
        chirpmap::SurfaceKind::Point => "point",
    };
    (kind, [s.p0.x, s.p0.y, s.p1.x, s.p1.y], s.support, s.ambiguous)
}

/// Where a scene comes from (decided by the Python wrapper).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneSource<'a> {
    /// The paper's default scene.
    Default,
    /// Scene TOML text.
    Toml(&'a str),
    /// A dict, serialised by Python's `json.dumps`.
    Json(&'a str),
    /// A scene file (any name the OS allows, UTF-8 or not).
    Path(&'a std::path::Path),
}

/// The scene and its `[synth]` table, plus a name for error messages (the
/// file's path, as the CLI names it).
pub fn load_scene(src: SceneSource<'_>) -> Result<(Scene, SynthConfig, String), String> {
    match src {
        SceneSource::Default => Ok((Scene::default(), SynthConfig::default(), "default scene".into())),
        SceneSource::Toml(text) => {
            check_scene_size(text, "scene (TOML text)")?;
            let (s, c) = chirpmap::parse_scene(text).map_err(|e| format!("scene: {}", error_text(&e)))?;
            Ok((s, c, "scene".into()))
        }
        SceneSource::Json(json) => {
            // Before the conversions (JSON, a TOML table, TOML text), which
            // took 3 GB for a dict of a million obstacles.
            check_scene_size(json, "scene dict (as JSON)")?;
            let table: toml::Table = serde_json::from_str(json).map_err(|e| {
                // Name the key: serde's message gives a column of JSON the
                // user never wrote.
                let value: Option<serde_json::Value> = serde_json::from_str(json).ok();
                match value.as_ref().and_then(|v| first_unrepresentable(v, String::new())) {
                    Some((key, what)) => format!("scene dict: `{key}` is {what}, which a scene cannot hold"),
                    None => format!("scene dict: not a TOML table: {e}"),
                }
            })?;
            let text = toml::to_string(&table).map_err(|e| format!("scene dict: {e}"))?;
            let (s, c) = chirpmap::parse_scene(&text).map_err(|e| format!("scene dict: {}", error_text(&e)))?;
            Ok((s, c, "scene dict".into()))
        }
        SceneSource::Path(file) => {
            let path = file.display().to_string();
            // Capped as the CLI caps it: an endless stream (`/dev/zero`) or a
            // huge file is refused instead of read until memory runs out.
            // A FIFO blocks `open` until a writer comes, and a call cannot
            // be interrupted (the review of session 20 found one hanging).
            #[cfg(unix)]
            if std::fs::metadata(file).is_ok_and(|m| std::os::unix::fs::FileTypeExt::is_fifo(&m.file_type())) {
                return Err(format!("scene {path} is a FIFO (named pipe): give a scene file or the scene's text"));
            }
            let mut text = String::new();
            std::fs::File::open(file)
                .and_then(|f| {
                    std::io::Read::read_to_string(&mut std::io::Read::take(f, MAX_SCENE_BYTES + 1), &mut text)
                })
                .map_err(|e| format!("cannot read scene {path}: {}", error_text(&e)))?;
            if text.len() as u64 > MAX_SCENE_BYTES {
                return Err(format!("scene {path} is too large: more than {MAX_SCENE_BYTES} bytes (the limit)"));
            }
            let (s, c) = chirpmap::parse_scene(&text).map_err(|e| format!("{path}: {}", error_text(&e)))?;
            Ok((s, c, path))
        }
    }
}

/// Largest scene read, as text, a dict's JSON or a file: the CLI's cap.
const MAX_SCENE_BYTES: u64 = 64 << 20;

/// Refuses scene text (TOML, or a dict's JSON) beyond the CLI's size cap or
/// with more values than a scene may have, before it is parsed.
fn check_scene_size(text: &str, what: &str) -> Result<(), String> {
    if text.len() as u64 > MAX_SCENE_BYTES {
        return Err(format!("{what} is too large: {} bytes (the limit is {MAX_SCENE_BYTES} bytes)", text.len()));
    }
    chirpmap::core::error::check_toml_values(text).map_err(|e| format!("{what}: {e}"))
}

/// The first value of a scene dict that TOML cannot hold (`None`; the
/// Python wrapper refuses integers beyond TOML's 64-bit range, which JSON
/// would carry as floats), with its key path (`listeners[0].start`) and
/// what it is.
fn first_unrepresentable(v: &serde_json::Value, at: String) -> Option<(String, String)> {
    use serde_json::Value;
    match v {
        Value::Null => Some((at, "None".into())),
        Value::Array(items) => {
            items.iter().enumerate().find_map(|(i, x)| first_unrepresentable(x, format!("{at}[{i}]")))
        }
        Value::Object(map) => map.iter().find_map(|(k, x)| {
            let key = if at.is_empty() { k.clone() } else { format!("{at}.{k}") };
            first_unrepresentable(x, key)
        }),
        _ => None,
    }
}

/// The evidence mapper's parameters from the JSON of a dict. On a value of
/// the wrong type, the key is named: serde's message gives a column of
/// JSON the user never wrote, so each key is tried alone (the others at
/// their defaults) to find the one refused.
fn evidence_params(json: &str) -> Result<EvidenceParams, String> {
    serde_json::from_str(json).map_err(|e| {
        let keys: Option<serde_json::Map<String, serde_json::Value>> = serde_json::from_str(json).ok();
        let bad = keys.iter().flatten().find_map(|(k, v)| {
            let one = serde_json::Value::Object(std::iter::once((k.clone(), v.clone())).collect());
            serde_json::from_value::<EvidenceParams>(one).err().map(|e| (k.clone(), e))
        });
        match bad {
            Some((k, e)) => {
                let msg = e.to_string();
                // serde's "invalid type: …, expected u32" without a position.
                let msg = msg.split(" at line ").next().unwrap_or(&msg).to_owned();
                if msg.starts_with("unknown field") {
                    format!("evidence: {msg}")
                } else {
                    format!("evidence.{k}: {msg}")
                }
            }
            None => format!("evidence: {e}"),
        }
    })
}

/// Algorithm 1's parameters (and the mapper) from the Python keywords; the
/// evidence mapper's table comes as JSON of a dict (unknown keys refused).
/// Algorithm 1's thresholds default to [`MappingParams::default`]'s and are
/// refused with the evidence mapper, which would ignore them (as
/// `chirpmap map` refuses its flags).
pub fn mapping_params(
    cell: f64,
    keep_top: Option<f64>,
    min_of_max: Option<f64>,
    peak_radius: Option<f64>,
    ellipse_points: u32,
    mapper: &str,
    evidence_json: Option<&str>,
) -> Result<MappingParams, String> {
    let mapper = match mapper {
        "paper" => MapperKind::Paper,
        "evidence" => MapperKind::Evidence,
        other => {
            return Err(format!(
                "mapper: {:?} is not a mapper (paper or evidence)",
                chirpmap::core::error::excerpt(other, 0)
            ));
        }
    };
    let paper_only = [("keep_top", keep_top), ("min_of_max", min_of_max), ("peak_radius", peak_radius)];
    if mapper == MapperKind::Evidence
        && let Some((name, _)) = paper_only.iter().find(|(_, v)| v.is_some())
    {
        return Err(format!(
            "{name}: applies to mapper='paper' only; the evidence mapper's highlights are set in evidence= \
             (peak_radius_m, highlight_min_logodds)"
        ));
    }
    // The other mapper's settings are refused too, rather than ignored.
    if mapper == MapperKind::Evidence && ellipse_points != 0 {
        return Err("ellipse_points: applies to mapper='paper' only (the evidence mapper draws no ellipses)".into());
    }
    if mapper == MapperKind::Paper && evidence_json.is_some() {
        return Err("evidence: applies to mapper='evidence' only; pass mapper='evidence' to use it".into());
    }
    let paper = MappingParams::default();
    let (keep_top, min_of_max, peak_radius) = (
        keep_top.unwrap_or(paper.keep_top),
        min_of_max.unwrap_or(paper.min_of_max),
        peak_radius.unwrap_or(paper.peak_radius),
    );
    let evidence: EvidenceParams = match evidence_json {
        None => EvidenceParams::default(),
        Some(j) => evidence_params(j)?,
    };
    let params = MappingParams { cell, keep_top, min_of_max, peak_radius, ellipse_points, mapper, evidence };
    params.validate().map_err(|e| error_text(&e))?;
    Ok(params)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(v: &[f64]) -> Result<Vec<Echo>, String> {
        echoes_from_rows(v, v.len(), None)
    }

    #[test]
    fn columns_default_as_in_echoes_csv() {
        let e = row(&[0.0, 0.0, 1.0, 1.0, 2.0]).expect("valid");
        assert_eq!((e[0].weight, e[0].t_s, e[0].listener_id, e[0].sigma_m), (1.0, 0.0, 0, None));
        let e = row(&[0.0, 0.0, 1.0, 1.0, 2.0, 3.0, 0.5, 7.0, 0.05]).expect("valid");
        assert_eq!((e[0].weight, e[0].t_s, e[0].listener_id, e[0].sigma_m), (3.0, 0.5, 7, Some(0.05)));
        let e = row(&[0.0, 0.0, 1.0, 1.0, 2.0, 3.0, 0.5, 7.0, f64::NAN]).expect("valid");
        assert_eq!(e[0].sigma_m, None);
    }

    #[test]
    fn round_trip_through_rows() {
        let data = [0.0, 0.0, 1.0, 1.0, 2.0, 3.0, 0.5, 7.0, 4.0, 5.0, -1.0, 2.5, 0.25, 1.0, 0.0, 0.0];
        let e = echoes_from_rows(&data, 8, None).expect("valid");
        let (back, cols) = echoes_to_rows(&e);
        assert_eq!((back.as_slice(), cols), (&data[..], 8));
        let s = [0.1, f64::NAN];
        let e = echoes_from_rows(&data, 8, Some(&s)).expect("valid");
        let (back, cols) = echoes_to_rows(&e);
        assert_eq!(cols, 9);
        assert_eq!(back[8], 0.1);
        assert!(back[17].is_nan());
    }

    #[test]
    fn bad_rows_name_row_and_column() {
        let cases: [(&[f64], &str); 7] = [
            (&[0.0, 0.0, 1.0, 1.0, f64::NAN], "echoes[0]: `delta_d` = NaN is not finite"),
            (&[0.0, 0.0, 1.0, 1.0, -2.0], "echoes[0]: delta_d must be >= 0"),
            (&[1.0, 1.0, 1.0, 1.0, 2.0], "echoes[0]: source and listener coincide"),
            (&[0.0, 0.0, 1.0, 1.0, 2.0, -1.0], "echoes[0]: invalid mapping parameter weight"),
            (&[0.0, 0.0, 1.0, 1.0, 2.0, 1.0, 0.0, 1.5], "`listener` = 1.5 must be a non-negative integer id"),
            (&[1e300, 0.0, 1.0, 1.0, 2.0], "echoes[0]: source (1e300, 0) is beyond"),
            (&[0.0, 0.0, 1.0, 1.0, 2.0, 1.0, 0.0, 0.0, 0.0], "`sigma_m` = 0 must be > 0"),
        ];
        for (v, want) in cases {
            let err = row(v).expect_err(want);
            assert!(err.contains(want), "{err:?} should contain {want:?}");
        }
        assert!(echoes_from_rows(&[0.0; 4], 4, None).expect_err("4 columns").contains("5 to 9 columns"));
        assert!(echoes_from_rows(&[0.0; 5], 5, Some(&[1.0, 2.0])).expect_err("length").contains("sigma: 2 values"));
    }

    #[test]
    fn scenes_from_text_dict_and_file() {
        let (s, _, _) = load_scene(SceneSource::Toml("seed = 7")).expect("valid");
        assert_eq!(s.seed, 7);
        let (s, c, name) =
            load_scene(SceneSource::Json(r#"{"seed": 9, "synth": {"chirps": 2}, "world": {"speed_of_sound": 340.0}}"#))
                .expect("valid");
        assert_eq!((s.seed, c.chirps, s.world.speed_of_sound, name.as_str()), (9, 2, 340.0, "scene dict"));
        let err = load_scene(SceneSource::Json(r#"{"sede": 9}"#)).expect_err("unknown key");
        assert!(err.starts_with("scene dict: ") && err.contains("sede"), "{err}");
        // What TOML cannot hold is named by its key.
        let err = load_scene(SceneSource::Json(r#"{"seed": null}"#)).expect_err("null");
        assert_eq!(err, "scene dict: `seed` is None, which a scene cannot hold");
        let err = load_scene(SceneSource::Json(r#"{"listeners": [{"start": [0, null]}]}"#)).expect_err("null");
        assert_eq!(err, "scene dict: `listeners[0].start[1]` is None, which a scene cannot hold");
        let err = load_scene(SceneSource::Path(std::path::Path::new("/nonexistent/scene.toml"))).expect_err("missing");
        assert!(err.starts_with("cannot read scene /nonexistent/scene.toml: "), "{err}");
        assert_eq!(load_scene(SceneSource::Default).expect("default").0, Scene::default());
    }

    #[test]
    fn mapping_params_refuse_bad_values() {
        assert!(mapping_params(0.1, None, None, None, 0, "paper", None).is_ok());
        let err = mapping_params(0.1, None, None, None, 0, "nope", None).expect_err("mapper");
        assert!(err.contains("not a mapper"), "{err}");
        let err = mapping_params(-1.0, None, None, None, 0, "paper", None).expect_err("cell");
        assert!(err.contains("cell"), "{err}");
        let err = mapping_params(0.1, None, None, None, 0, "evidence", Some(r#"{"angle_bins": 2}"#)).expect_err("bins");
        assert!(err.contains("angle_bins"), "{err}");
        let err = mapping_params(0.1, None, None, None, 0, "evidence", Some(r#"{"bogus": 2}"#)).expect_err("unknown");
        assert!(err.contains("bogus"), "{err}");
        let err = mapping_params(0.1, None, None, Some(3.0), 0, "evidence", None).expect_err("paper only");
        assert!(err.starts_with("peak_radius: applies to mapper='paper' only"), "{err}");
        let err = mapping_params(0.1, None, None, None, 64, "evidence", None).expect_err("paper only");
        assert!(err.starts_with("ellipse_points: applies to mapper='paper' only"), "{err}");
        let err = mapping_params(0.1, None, None, None, 0, "paper", Some("{}")).expect_err("evidence only");
        assert!(err.starts_with("evidence: applies to mapper='evidence' only"), "{err}");
        let err =
            mapping_params(0.1, None, None, None, 0, "evidence", Some(r#"{"angle_bins": 360, "min_support": 6.0}"#))
                .expect_err("type");
        assert_eq!(err, "evidence.min_support: invalid type: floating point `6.0`, expected u32");
        let p = mapping_params(0.1, None, Some(0.05), None, 0, "paper", None).expect("paper");
        assert_eq!((p.keep_top, p.min_of_max, p.peak_radius), (MappingParams::default().keep_top, 0.05, 5.0));
    }
}
