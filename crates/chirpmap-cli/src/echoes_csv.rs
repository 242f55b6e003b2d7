//! The echoes CSV of DESIGN.md: one ellipse a row, header required, extra
//! columns ignored; `weight` defaults to 1, `t` and `listener` are optional.

use anyhow::{Context, Result, anyhow, bail};
use chirpmap_core::{Echo, Point};
use std::io::{Read, Write};
use std::path::Path;

const REQUIRED: [&str; 5] = ["source_x", "source_y", "listener_x", "listener_y", "delta_d"];

/// Reads and validates every row; errors name the file, line and column.
pub fn read_echoes(path: &Path) -> Result<Vec<Echo>> {
    let file = std::fs::File::open(path).with_context(|| format!("cannot open echoes file {}", path.display()))?;
    parse_echoes(file, &path.display().to_string())
}

pub fn parse_echoes(reader: impl Read, name: &str) -> Result<Vec<Echo>> {
    let mut rdr = csv::ReaderBuilder::new().trim(csv::Trim::All).from_reader(reader);
    let headers = rdr.headers().with_context(|| format!("{name}: cannot read the CSV header"))?.clone();
    let col = |h: &str| headers.iter().position(|c| c == h);
    let mut idx = [0usize; 5];
    for (k, h) in REQUIRED.iter().enumerate() {
        idx[k] = col(h)
            .ok_or_else(|| anyhow!("{name}:1: missing column `{h}` (header must include {})", REQUIRED.join(",")))?;
    }
    let (i_w, i_t, i_l) = (col("weight"), col("t"), col("listener"));
    let mut echoes = Vec::new();
    for rec in rdr.records() {
        let rec = rec.with_context(|| format!("{name}: malformed CSV"))?;
        let line = rec.position().map_or(0, |p| p.line());
        let field = |i: usize, h: &str| -> Result<f64> {
            let raw = rec.get(i).ok_or_else(|| anyhow!("{name}:{line}: missing value for `{h}`"))?;
            let v: f64 = raw.parse().map_err(|_| anyhow!("{name}:{line}: `{h}` = {raw:?} is not a number"))?;
            if !v.is_finite() {
                bail!("{name}:{line}: `{h}` = {raw:?} is not finite");
            }
            Ok(v)
        };
        let optional = |i: Option<usize>, h: &str, default: f64| -> Result<f64> {
            match i.and_then(|i| rec.get(i)) {
                Some(raw) if !raw.is_empty() => field(i.unwrap_or_default(), h),
                _ => Ok(default),
            }
        };
        let v: Vec<f64> = REQUIRED.iter().zip(idx).map(|(h, i)| field(i, h)).collect::<Result<_>>()?;
        let weight = optional(i_w, "weight", 1.0)?;
        let t = optional(i_t, "t", 0.0)?;
        let listener = optional(i_l, "listener", 0.0)?;
        if listener < 0.0 || listener.fract() != 0.0 || listener > f64::from(u32::MAX) {
            bail!("{name}:{line}: `listener` = {listener} must be a non-negative integer id");
        }
        let echo = Echo::new(Point::new(v[0], v[1]), Point::new(v[2], v[3]), v[4], weight, t, listener as u32)
            .map_err(|e| anyhow!("{name}:{line}: {e}"))?;
        echoes.push(echo);
    }
    Ok(echoes)
}

/// Writes echoes in the same format, full precision.
#[allow(dead_code)] // The simulators' commands write echoes; `map` only reads them.
pub fn write_echoes(mut w: impl Write, echoes: &[Echo]) -> std::io::Result<()> {
    writeln!(w, "source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener")?;
    for e in echoes {
        writeln!(
            w,
            "{},{},{},{},{},{},{},{}",
            e.source.x, e.source.y, e.listener.x, e.listener.y, e.delta_d_m, e.weight, e.t_s, e.listener_id
        )?;
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
        assert_eq!(parse(std::str::from_utf8(&buf).unwrap()).unwrap(), e);
    }

    proptest::proptest! {
        #[test]
        fn garbage_never_panics(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..400)) {
            let _ = parse_echoes(bytes.as_slice(), "g.csv");
        }

        #[test]
        fn garbage_rows_after_a_valid_header_never_panic(rows in "[0-9a-zA-Z,.\\-\n\"]{0,300}") {
            let text = format!("source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener\n{rows}");
            let _ = parse_echoes(text.as_bytes(), "g.csv");
        }
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
            (&format!("{head}0,0,1,1,2\n"), "e.csv: malformed CSV"),
        ];
        for (input, want) in cases {
            let err = format!("{:#}", parse(input).unwrap_err());
            assert!(err.contains(want), "{err:?} should contain {want:?}");
        }
    }
}
