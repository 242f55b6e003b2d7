//! The echoes CSV of docs/file-formats.md: one ellipse a row, header required, extra
//! columns ignored; `weight` defaults to 1, `t`, `listener` and `sigma_m`
//! (the 1-σ uncertainty of Δd, m) are optional.
//!
//! Records are read as bytes, so a non-UTF-8 byte in an ignored column is
//! fine; line numbers are counted by us over `\n`, `\r\n` and `\r` alike
//! (the `csv` crate counts only `\n`, so CRLF and CR-only files were
//! reported on the wrong line; issue 8, item 14).

use anyhow::{Context, Result, anyhow, bail};
use chirpmap_core::echo::MAX_SIGMA_M;
use chirpmap_core::error::Num;
use chirpmap_core::{Echo, Point};
use std::io::Write;
use std::path::Path;

const REQUIRED: [&str; 5] = ["source_x", "source_y", "listener_x", "listener_y", "delta_d"];

/// Longest quoted input value in an error (characters).
const QUOTE_CHARS: usize = 40;

/// `s`, cut to [`QUOTE_CHARS`] characters with `…`, for error messages.
pub fn short(s: &str) -> String {
    if s.chars().count() <= QUOTE_CHARS { s.to_string() } else { s.chars().take(QUOTE_CHARS).chain(['…']).collect() }
}

/// Byte offsets at which lines start, counting `\r\n`, `\n` and a lone `\r`
/// each as one line end, to turn a record's byte offset into its line.
#[derive(Debug)]
pub struct LineIndex<'a> {
    bytes: &'a [u8],
    starts: Vec<u64>,
}

impl<'a> LineIndex<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        let mut starts = vec![0u64];
        let mut i = 0;
        while i < bytes.len() {
            match bytes[i] {
                b'\n' => starts.push(i as u64 + 1),
                b'\r' if bytes.get(i + 1) == Some(&b'\n') => {
                    starts.push(i as u64 + 2);
                    i += 1;
                }
                b'\r' => starts.push(i as u64 + 1),
                _ => {}
            }
            i += 1;
        }
        Self { bytes, starts }
    }

    /// 1-based line of the record starting at byte `offset`. The `csv`
    /// crate may report a record as starting on the line end before it (the
    /// `\n` of a `\r\n`), and no record starts with a line end, so those
    /// bytes are skipped first.
    pub fn line_of(&self, offset: u64) -> u64 {
        let mut o = usize::try_from(offset).unwrap_or(usize::MAX);
        while matches!(self.bytes.get(o), Some(b'\r' | b'\n')) {
            o += 1;
        }
        self.starts.partition_point(|&s| s <= o as u64) as u64
    }
}

/// Refuses a file that ends inside a quoted field, naming the line where
/// the quote opened. The `csv` crate reads such a last field up to the end
/// of the file and reports nothing (RFC 4180 leaves it undefined), so a
/// file cut short after `"26.5` would be read as a complete row, and an
/// unclosed quote earlier would swallow every line after it. The scan
/// follows csv-core's quoting rules: a quote opens a quoted field only as
/// the field's first byte, `""` inside one is a literal quote, and any other
/// quote ends it.
pub fn check_quotes_closed(bytes: &[u8], lines: &LineIndex<'_>, name: &str) -> Result<()> {
    #[derive(Clone, Copy)]
    enum At {
        FieldStart,
        Unquoted,
        Quoted,
        QuoteInQuoted,
    }
    let mut at = At::FieldStart;
    let mut opened = 0;
    // A UTF-8 byte-order mark, which the csv crate skips, is not a field's first byte.
    let skip = if bytes.starts_with(b"\xEF\xBB\xBF") { 3 } else { 0 };
    for (i, &b) in bytes.iter().enumerate().skip(skip) {
        let ends_field = matches!(b, b',' | b'\n' | b'\r');
        at = match (at, b) {
            (At::FieldStart, b'"') => {
                opened = i;
                At::Quoted
            }
            (At::Quoted, b'"') => At::QuoteInQuoted,
            (At::Quoted, _) => At::Quoted,
            (At::QuoteInQuoted, b'"') => At::Quoted,
            (_, _) if ends_field => At::FieldStart,
            (_, _) => At::Unquoted,
        };
    }
    if matches!(at, At::Quoted) {
        bail!(
            "{name}:{}: a quoted field opened here is never closed (the file ends inside it)",
            lines.line_of(opened as u64)
        );
    }
    Ok(())
}

/// Reads and validates every row; errors name the file, line and column.
pub fn read_echoes(path: &Path) -> Result<Vec<Echo>> {
    let bytes = crate::files::read_input(path, "echoes file", crate::files::MAX_CSV_BYTES)?;
    parse_echoes(&bytes[..], &path.display().to_string())
}

/// Parses an echoes CSV held in memory; `name` is used in messages.
pub fn parse_echoes(bytes: &[u8], name: &str) -> Result<Vec<Echo>> {
    crate::files::check_csv_lines(bytes, name)?;
    let lines = LineIndex::new(bytes);
    check_quotes_closed(bytes, &lines, name)?;
    let mut rdr = csv::ReaderBuilder::new().trim(csv::Trim::All).from_reader(bytes);
    let headers: Vec<String> = rdr
        .byte_headers()
        .with_context(|| format!("{name}: cannot read the CSV header"))?
        .iter()
        .map(|h| String::from_utf8_lossy(h).into_owned())
        .collect();
    for (k, h) in headers.iter().enumerate() {
        if !h.is_empty() && headers[..k].contains(h) {
            bail!("{name}:1: column `{}` appears twice in the header", short(h));
        }
    }
    let col = |h: &str| headers.iter().position(|c| c == h);
    let mut idx = [0usize; 5];
    for (k, h) in REQUIRED.iter().enumerate() {
        idx[k] = col(h)
            .ok_or_else(|| anyhow!("{name}:1: missing column `{h}` (header must include {})", REQUIRED.join(",")))?;
    }
    let (i_w, i_t, i_l, i_s) = (col("weight"), col("t"), col("listener"), col("sigma_m"));
    let mut echoes = Vec::new();
    for rec in rdr.byte_records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map_or(0, |p| lines.line_of(p.byte()));
            let what = match e.kind() {
                csv::ErrorKind::UnequalLengths { expected_len, len, .. } => {
                    format!("{len} fields where the header has {expected_len}")
                }
                _ => short(&e.to_string()),
            };
            anyhow!("{name}:{line}: malformed CSV: {what}")
        })?;
        let line = rec.position().map_or(0, |p| lines.line_of(p.byte()));
        let text = |i: usize, h: &str| -> Result<Option<&str>> {
            match rec.get(i) {
                None => Ok(None),
                Some(raw) => {
                    std::str::from_utf8(raw).map(Some).map_err(|_| anyhow!("{name}:{line}: `{h}` is not valid UTF-8"))
                }
            }
        };
        let field = |i: usize, h: &str| -> Result<f64> {
            let raw = text(i, h)?.ok_or_else(|| anyhow!("{name}:{line}: missing value for `{h}`"))?;
            let v: f64 = raw.parse().map_err(|_| anyhow!("{name}:{line}: `{h}` = {:?} is not a number", short(raw)))?;
            if !v.is_finite() {
                bail!("{name}:{line}: `{h}` = {:?} is not finite", short(raw));
            }
            Ok(v)
        };
        let optional = |i: Option<usize>, h: &str| -> Result<Option<f64>> {
            match i {
                Some(i) if text(i, h)?.is_some_and(|raw| !raw.is_empty()) => field(i, h).map(Some),
                _ => Ok(None),
            }
        };
        let v: Vec<f64> = REQUIRED.iter().zip(idx).map(|(h, i)| field(i, h)).collect::<Result<_>>()?;
        let weight = optional(i_w, "weight")?.unwrap_or(1.0);
        let t = optional(i_t, "t")?.unwrap_or(0.0);
        let listener = optional(i_l, "listener")?.unwrap_or(0.0);
        if listener < 0.0 || listener.fract() != 0.0 || listener > f64::from(u32::MAX) {
            bail!("{name}:{line}: `listener` = {} must be a non-negative integer id", Num(listener));
        }
        let (source, mic) = (Point::new(v[0], v[1]), Point::new(v[2], v[3]));
        for (what, p) in [("source", source), ("listener", mic)] {
            if !p.is_sane() {
                bail!("{name}:{line}: {what} {p} is beyond ±{} m", Num(chirpmap_core::geometry::MAX_COORD_M));
            }
        }
        let mut echo =
            Echo::new(source, mic, v[4], weight, t, listener as u32).map_err(|e| anyhow!("{name}:{line}: {e}"))?;
        if let Some(sigma) = optional(i_s, "sigma_m")? {
            if sigma <= 0.0 {
                bail!("{name}:{line}: `sigma_m` = {} must be > 0 (the 1-σ uncertainty of delta_d, m)", Num(sigma));
            }
            if sigma > MAX_SIGMA_M {
                bail!("{name}:{line}: `sigma_m` = {} must be at most {} m", Num(sigma), Num(MAX_SIGMA_M));
            }
            echo = echo.with_sigma_m(sigma).map_err(|e| anyhow!("{name}:{line}: {e}"))?;
        }
        echoes.push(echo);
    }
    Ok(echoes)
}

/// Writes echoes in the same format, full precision; the `sigma_m` column
/// is written when any echo has one (empty for those without).
pub fn write_echoes(mut w: impl Write, echoes: &[Echo]) -> std::io::Result<()> {
    let with_sigma = echoes.iter().any(|e| e.sigma_m.is_some());
    let sigma_head = if with_sigma { ",sigma_m" } else { "" };
    writeln!(w, "source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener{sigma_head}")?;
    for e in echoes {
        write!(
            w,
            "{},{},{},{},{},{},{},{}",
            e.source.x, e.source.y, e.listener.x, e.listener.y, e.delta_d_m, e.weight, e.t_s, e.listener_id
        )?;
        match (with_sigma, e.sigma_m) {
            (true, Some(s)) => writeln!(w, ",{s}")?,
            (true, None) => writeln!(w, ",")?,
            (false, _) => writeln!(w)?,
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<Vec<Echo>> {
        parse_echoes(s.as_bytes(), "e.csv")
    }

    #[test]
    fn parses_minimal_and_full_rows() {
        let e = parse("listener_y,source_x,source_y,listener_x,delta_d,extra\n10,0,0,-2.5,12.3,x\n").unwrap();
        assert_eq!(e.len(), 1);
        assert_eq!((e[0].listener.x, e[0].listener.y, e[0].delta_d_m, e[0].weight), (-2.5, 10.0, 12.3, 1.0));
        let mut buf = Vec::new();
        write_echoes(&mut buf, &e).unwrap();
        assert!(!std::str::from_utf8(&buf).unwrap().contains("sigma_m"));
        assert_eq!(parse(std::str::from_utf8(&buf).unwrap()).unwrap(), e);
    }

    #[test]
    fn sigma_m_is_read_validated_and_written() {
        let head = "source_x,source_y,listener_x,listener_y,delta_d,sigma_m\n";
        let e = parse(&format!("{head}0,0,1,1,2,0.05\n0,0,1,1,3,\n")).unwrap();
        assert_eq!((e[0].sigma_m, e[1].sigma_m), (Some(0.05), None));
        let mut buf = Vec::new();
        write_echoes(&mut buf, &e).unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert!(text.lines().next().unwrap().ends_with(",sigma_m"), "{text}");
        assert_eq!(parse(&text).unwrap(), e);
        for (bad, want) in [
            ("0", "must be > 0"),
            ("-1", "must be > 0"),
            ("nan", "not finite"),
            ("x", "not a number"),
            ("1e300", "`sigma_m` = 1e300 must be at most 1000000 m"),
        ] {
            let err = format!("{:#}", parse(&format!("{head}0,0,1,1,2,{bad}\n")).unwrap_err());
            assert!(err.contains("e.csv:2") && err.contains(want), "{bad}: {err}");
        }
    }

    /// Issue 8, item 14.
    #[test]
    fn line_ends_duplicates_and_bytes() {
        let head = "source_x,source_y,listener_x,listener_y,delta_d";
        for eol in ["\n", "\r\n", "\r"] {
            let text = format!("{head}{eol}0,0,1,1,2{eol}0,0,1,1,2{eol}0,0,1,1,abc{eol}");
            let err = format!("{:#}", parse(&text).unwrap_err());
            assert!(err.starts_with("e.csv:4: `delta_d`"), "{eol:?}: {err}");
            let text = format!("{head}{eol}0,0,1,1,2{eol}0,0,1{eol}");
            let err = format!("{:#}", parse(&text).unwrap_err());
            assert!(err.starts_with("e.csv:3: malformed CSV"), "{eol:?}: {err}");
        }
        let err = format!("{:#}", parse(&format!("{head},delta_d\n0,0,1,1,2,3\n")).unwrap_err());
        assert!(err.contains("e.csv:1: column `delta_d` appears twice"), "{err}");
        let mut bytes = format!("{head},note\n0,0,1,1,2,").into_bytes();
        bytes.extend([0xff, 0xfe, b'\n']);
        assert_eq!(parse_echoes(&bytes, "e.csv").unwrap().len(), 1);
        // A UTF-8 byte-order mark and quoted names.
        let text = "\u{feff}\"source_x\",source_y,listener_x,listener_y,delta_d\n0,0,1,1,2\n";
        assert_eq!(parse(text).unwrap().len(), 1);
        // A huge bad value is quoted short.
        let err = format!("{:#}", parse(&format!("{head}\n0,0,1,1,{}\n", "9x".repeat(100_000))).unwrap_err());
        assert!(err.len() < 200, "{} chars", err.len());
        let err = format!("{:#}", parse(&format!("{head}\n1e300,0,1,1,2\n")).unwrap_err());
        assert!(err.contains("source (1e300, 0) is beyond"), "{err}");
    }

    #[test]
    fn a_quote_never_closed_is_refused_naming_its_line() {
        let head = "source_x,source_y,listener_x,listener_y,delta_d,note";
        for eol in ["\n", "\r\n", "\r"] {
            // Cut short inside the last field: the csv crate alone reads `"26.5` as 26.5.
            let text = format!("{head}{eol}0,0,1,1,2,a{eol}0,0,1,1,\"26.5");
            let err = format!("{:#}", parse(&text.replace(",note", "").replace(",a", "")).unwrap_err());
            assert!(err.starts_with("e.csv:3: a quoted field opened here is never closed"), "{eol:?}: {err}");
            // Opened early, it would swallow the lines after it.
            let text = format!("{head}{eol}0,0,1,1,2,\"a{eol}0,0,1,1,2,b{eol}0,0,1,1,2,c{eol}");
            let err = format!("{:#}", parse(&text).unwrap_err());
            assert!(err.starts_with("e.csv:2: a quoted field"), "{eol:?}: {err}");
            // Closed quotes, escaped quotes, commas and line ends inside quotes, and quotes
            // inside an unquoted field are all fine.
            let text = format!(
                "{head}{eol}\"0\",0,1,1,2,\"say \"\"hi\"\", then{eol}go\"{eol}0,0,1,1,2,5\"{eol}0,0,1,1,\"2\",\"x\""
            );
            assert_eq!(parse(&text).unwrap().len(), 3, "{eol:?}");
        }
        let bom = "\u{feff}\"source_x,source_y,listener_x,listener_y,delta_d\n0,0,1,1,2\n";
        assert!(format!("{:#}", parse(bom).unwrap_err()).starts_with("e.csv:1: a quoted field"));
    }

    #[test]
    fn errors_name_line_and_column() {
        let head = "source_x,source_y,listener_x,listener_y,delta_d,weight\n";
        let cases = [
            ("source_x,source_y,listener_x,delta_d\n0,0,1,1\n", "e.csv:1: missing column `listener_y`"),
            (&format!("{head}0,0,1,1,2,1\n0,0,1,abc,2,1\n"), "e.csv:3: `listener_y` = \"abc\""),
            (&format!("{head}0,0,1,1,NaN,1\n"), "e.csv:2: `delta_d` = \"NaN\" is not finite"),
            (&format!("{head}0,0,1,1,-2,1\n"), "e.csv:2: delta_d must be >= 0"),
            (&format!("{head}1,1,1,1,2,1\n"), "e.csv:2: source and listener coincide"),
            (&format!("{head}0,0,1,1,2,-1\n"), "e.csv:2: invalid mapping parameter weight"),
            (&format!("{head}0,0,1,1,2\n"), "e.csv:2: malformed CSV"),
        ];
        for (input, want) in cases {
            let err = format!("{:#}", parse(input).unwrap_err());
            assert!(err.contains(want), "{err:?} should contain {want:?}");
        }
    }
}
