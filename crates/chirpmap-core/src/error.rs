use thiserror::Error;

/// Errors of the core library. Each names the field or quantity at fault so
/// the CLI can point the user at the offending line.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CoreError {
    /// A number that must be finite was NaN or infinite.
    #[error("{field} must be finite, got {}", Num(*value))]
    NotFinite {
        /// Name of the offending field.
        field: &'static str,
        /// The value given.
        value: f64,
    },
    /// A path-length difference Δd (m) was negative; an echo path is never
    /// shorter than the direct path.
    #[error("delta_d must be >= 0 m, got {}", Num(*.0))]
    NegativeDeltaD(f64),
    /// Source and listener at the same point: the ellipse of Eq. 4 degenerates.
    #[error("source and listener coincide at ({}, {}); the ellipse is undefined", Num(*x), Num(*y))]
    CoincidentFoci {
        /// x of the shared point (m).
        x: f64,
        /// y of the shared point (m).
        y: f64,
    },
    /// A chirp parameter (frequency, duration) is out of range.
    #[error("invalid chirp: {0}")]
    InvalidChirp(String),
    /// A shape (circle, polygon) is degenerate or not finite.
    #[error("invalid geometry: {0}")]
    InvalidGeometry(String),
    /// Grid bounds or cell size are invalid.
    #[error("invalid grid: {0}")]
    InvalidGrid(String),
    /// The grid would need more memory than the allowed cap.
    #[error(
        "grid of {nx} x {ny} cells needs {bytes} bytes to map, more than the cap of {cap} bytes; \
         pass smaller --bounds or a larger --cell"
    )]
    GridTooLarge {
        /// Cells along x.
        nx: usize,
        /// Cells along y.
        ny: usize,
        /// Bytes the map would need.
        bytes: u128,
        /// The cap (bytes).
        cap: u128,
    },
    /// A mapping parameter is out of range.
    #[error("invalid mapping parameter {field}: {reason}")]
    InvalidParam {
        /// Name of the parameter.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A scene file is inconsistent; the message names the field.
    #[error("invalid scene: {0}")]
    InvalidScene(String),
}

/// Returns `value` if finite, otherwise a [`CoreError::NotFinite`] naming `field`.
pub fn finite(field: &'static str, value: f64) -> Result<f64, CoreError> {
    if value.is_finite() { Ok(value) } else { Err(CoreError::NotFinite { field, value }) }
}

/// A number as a person writes it, for error messages: at most six
/// significant digits, plain notation from 10⁻⁴ to 10⁹ and scientific beyond
/// (`1e300`, not 301 digits), and `NaN`, `inf`, `-inf` for non-finite values.
/// Used wherever a user's value is quoted back (issue 8, item 16).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

fn trim_zeros(s: &str) -> &str {
    if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.') } else { s }
}

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = self.0;
        if v.is_nan() {
            return f.write_str("NaN");
        }
        if v.is_infinite() {
            return f.write_str(if v > 0.0 { "inf" } else { "-inf" });
        }
        if v == 0.0 {
            return f.write_str("0");
        }
        let mag = v.abs();
        if (1e-4..1e9).contains(&mag) {
            // Six significant digits: decimals = 5 − ⌊log10 |v|⌋.
            let decimals = (5 - mag.log10().floor() as i32).max(0) as usize;
            let s = format!("{v:.decimals$}");
            f.write_str(trim_zeros(&s))
        } else {
            let s = format!("{v:.5e}");
            let (mantissa, exp) = s.split_once('e').unwrap_or((&s, "0"));
            write!(f, "{}e{exp}", trim_zeros(mantissa))
        }
    }
}

/// Longest excerpt of an offending input line quoted in an error (characters).
pub const EXCERPT_CHARS: usize = 60;

/// At most [`EXCERPT_CHARS`] characters of `line` around character column
/// `col` (0-based), with `…` where it was cut: a 1 MB line is quoted as a
/// short excerpt, once (issue 8, item 15).
pub fn excerpt(line: &str, col: usize) -> String {
    let chars: Vec<char> = line.chars().collect();
    if chars.len() <= EXCERPT_CHARS {
        return chars.iter().collect();
    }
    let start = col.saturating_sub(EXCERPT_CHARS / 2).min(chars.len() - EXCERPT_CHARS);
    let end = start + EXCERPT_CHARS;
    let mut s = String::new();
    if start > 0 {
        s.push('…');
    }
    s.extend(&chars[start..end]);
    if end < chars.len() {
        s.push('…');
    }
    s
}

/// Longest error message kept from a parser (characters): room for the list
/// of every key of `[mapping.evidence]` that an unknown key's message gives
/// (it was cut after the second key), while each quoted part is an excerpt.
const MESSAGE_CHARS: usize = 800;

/// The first line of a parser's message, with every `` `quoted` `` part (a
/// key or value from the input, possibly megabytes long) cut to an excerpt,
/// and the whole cut to `MESSAGE_CHARS` characters. Lists of expected keys survive.
pub fn short_message(message: &str) -> String {
    let first = message.lines().next().unwrap_or("");
    let parts: Vec<String> = first
        .split('`')
        .enumerate()
        .map(|(k, part)| if k % 2 == 1 { excerpt(part, 0) } else { part.to_string() })
        .collect();
    let joined = parts.join("`");
    if joined.chars().count() > MESSAGE_CHARS {
        joined.chars().take(MESSAGE_CHARS).chain(['…']).collect()
    } else {
        joined
    }
}

/// Most values (array elements, keys, tables) a scene or sweep TOML may
/// hold: a scene of [`crate::scene::MAX_OBSTACLES`] polygons of
/// [`crate::scene::MAX_POLYGON_VERTICES`] vertices has ~3·10⁶. Parsed
/// TOML takes ~200 bytes a value (a 66 MB array of `1,` took 7 GB before
/// its first check), so the values are counted before parsing.
pub const MAX_TOML_VALUES: usize = 4_000_000;

/// Refuses a TOML text with more than [`MAX_TOML_VALUES`] values, counted
/// from above by their separators (`,` `=` `[` `{` and line ends), before it
/// is parsed; the error names the count and the memory it would take.
pub fn check_toml_values(text: &str) -> Result<(), String> {
    let n = text.bytes().filter(|b| matches!(b, b',' | b'=' | b'[' | b'{' | b'\n')).count();
    if n > MAX_TOML_VALUES {
        return Err(format!(
            "holds up to {n} values (separators), more than the {MAX_TOML_VALUES} a scene or sweep may have \
             (parsing would take ~{} MB)",
            n / 5_000
        ));
    }
    Ok(())
}

/// A one-line description of a TOML error in `text`: `line L, column C: what
/// (near `excerpt`)`. The `toml` crate's own `Display` quotes the whole
/// offending line (and the message may repeat the value), so a 1 MB value
/// gave megabytes of error text; this quotes a short excerpt once.
pub fn toml_error(text: &str, e: &toml::de::Error) -> String {
    let msg = short_message(e.message());
    let Some(span) = e.span() else { return msg };
    let at = span.start.min(text.len());
    let at = (0..=at).rev().find(|&i| text.is_char_boundary(i)).unwrap_or(0);
    let line_start = text[..at].rfind('\n').map_or(0, |p| p + 1);
    let line_end = text[at..].find('\n').map_or(text.len(), |p| at + p);
    let line_no = text[..line_start].matches('\n').count() + 1;
    let line = text[line_start..line_end].trim_end_matches('\r');
    let col = text[line_start..at].chars().count();
    format!("line {line_no}, column {}: {msg} (near `{}`)", col + 1, excerpt(line, col))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A TOML of more values than a scene or sweep may hold is refused
    /// before it is parsed (a 66 MB array took 7 GB), by the scene's and
    /// the sweep's readers alike; the largest scene the schema allows is not.
    #[test]
    fn toml_of_too_many_values_is_refused_before_parsing() {
        let huge = format!("[world]\nbounds = [{}1]\n", "1,".repeat(MAX_TOML_VALUES));
        let e = check_toml_values(&huge).unwrap_err();
        assert!(e.starts_with(&format!("holds up to {} values", MAX_TOML_VALUES + 5)), "{e}");
        let e = crate::Scene::from_toml_str(&huge).unwrap_err().to_string();
        assert!(e.contains("more than the 4000000 a scene or sweep may have") && !e.contains('\n'), "{e}");
        // 1000 polygons of 1000 vertices.
        let ring: String = (0..crate::scene::MAX_POLYGON_VERTICES).map(|k| format!("[{k}.5, 1.25],")).collect();
        let obstacle = format!("[[obstacles]]\nvertices = [{ring}]\n");
        check_toml_values(&obstacle.repeat(crate::scene::MAX_OBSTACLES)).unwrap();
    }

    #[test]
    fn numbers_print_as_a_person_writes_them() {
        let cases = [
            (0.0, "0"),
            (343.0, "343"),
            (0.1, "0.1"),
            (0.1 + 0.2, "0.3"),
            (-2.5, "-2.5"),
            (1e300, "1e300"),
            (4294967295.0, "4.29497e9"),
            (1e-9, "1e-9"),
            (123456.789, "123457"),
            (f64::NAN, "NaN"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
            (f64::MAX, "1.79769e308"),
        ];
        for (v, want) in cases {
            assert_eq!(Num(v).to_string(), want, "{v:e}");
        }
        let e = CoreError::NotFinite { field: "x", value: f64::NAN }.to_string();
        assert_eq!(e, "x must be finite, got NaN");
        let e = CoreError::NegativeDeltaD(-1e300).to_string();
        assert!(e.len() < 40, "{e}");
    }

    proptest::proptest! {
        #[test]
        fn formatted_numbers_are_short_and_close(v in proptest::num::f64::ANY) {
            let s = Num(v).to_string();
            proptest::prop_assert!(s.len() <= 13, "{} -> {}", v, s);
            if v.is_finite() {
                let back: f64 = s.parse().unwrap();
                proptest::prop_assert!((back - v).abs() <= 1e-5 * v.abs() + 1e-300, "{} -> {}", v, s);
            }
        }
    }

    #[test]
    fn toml_errors_quote_a_short_excerpt_once() {
        let long = "x".repeat(1_000_000);
        let text = format!("[world]\nspeed_of_sound = \"{long}\" junk\n");
        let e = toml::from_str::<toml::Table>(&text).unwrap_err();
        let msg = toml_error(&text, &e);
        assert!(msg.len() < 300, "{} chars: {}", msg.len(), &msg[..300.min(msg.len())]);
        assert!(msg.starts_with("line 2, column "), "{msg}");
        // A megabyte-long unknown key is quoted short; the expected keys stay listed.
        let text = format!("[world]\n{long} = 1\n");
        let e = toml::from_str::<crate::Scene>(&text).unwrap_err();
        let msg = toml_error(&text, &e);
        assert!(
            msg.len() < 400 && msg.contains("speed_of_sound"),
            "{} chars: {}",
            msg.len(),
            &msg[..300.min(msg.len())]
        );
        assert_eq!(excerpt("abc", 1), "abc");
        let cut = excerpt(&"0123456789".repeat(20), 100);
        assert!(cut.starts_with('…') && cut.ends_with('…') && cut.chars().count() == EXCERPT_CHARS + 2, "{cut}");
    }
}
