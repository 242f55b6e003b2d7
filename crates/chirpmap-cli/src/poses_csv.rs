//! Listener poses CSV (`t,x,y[,listener]`, seconds and metres), as written
//! by `chirpmap synth --poses`; read for `chirpmap map --wav`.
//!
//! Read with the `csv` crate (as the echoes CSV is), so a UTF-8 byte-order
//! mark, quoted header names, CRLF or CR-only line ends and extra columns
//! are fine. Each listener's times must be in order; a repeated time with
//! the same position is kept once, with another position it is refused
//! (issue 8, item 13). Errors name the file and the line.

use crate::echoes_csv::{LineIndex, check_quotes_closed};
use anyhow::{Context, Result, anyhow, bail};
use chirpmap::{Point, PoseTrack};
use chirpmap_core::error::Num;
use std::path::Path;

/// One listener's poses, read from a file: the facade's [`PoseTrack`]
/// (it dereferences to it) plus the file's name for messages.
#[derive(Debug, Clone)]
pub struct Poses {
    track: PoseTrack,
    name: String,
    /// The fastest step between consecutive poses: (speed in m/s, its
    /// line, the line before it).
    fastest: Option<(f64, u64, u64)>,
}

impl std::ops::Deref for Poses {
    type Target = PoseTrack;
    fn deref(&self) -> &PoseTrack {
        &self.track
    }
}

impl Poses {
    /// Refuses poses between which the listener moves at or above
    /// `speed_of_sound_mps`, naming the line: echoes cannot be ranged from
    /// such a walk (a scene refuses such a listener alike), and such poses
    /// are a unit or column mix-up (a map was made of a listener jumping
    /// 30 m every 10 ms, and took 66 times as long).
    pub fn check_speed(&self, speed_of_sound_mps: f64) -> Result<()> {
        match self.fastest {
            Some((v, line, prev)) if v >= speed_of_sound_mps => bail!(
                "{}:{line}: the listener moves at {} m/s from the pose of line {prev}, at least the speed of sound \
                 ({} m/s): are the times in seconds and the positions in metres?",
                self.name,
                Num(v),
                Num(speed_of_sound_mps)
            ),
            _ => Ok(()),
        }
    }

    /// Checks the poses' times against a recording of `recording_s` seconds
    /// ([`PoseTrack::check_span`]), naming the file.
    pub fn check_span(&self, recording_s: f64) -> Result<()> {
        self.track.check_span(recording_s).map_err(|e| anyhow!("{}: {e}", self.name))
    }
}

/// Reads listener `listener`'s poses from `path`.
pub fn read_poses(path: &Path, listener: u32) -> Result<Poses> {
    let bytes = crate::files::read_input(path, "poses file", crate::files::MAX_CSV_BYTES)?;
    parse_poses(&bytes, &path.display().to_string(), listener)
}

/// Parses a poses CSV held in memory; `name` is used in messages.
pub fn parse_poses(bytes: &[u8], name: &str, listener: u32) -> Result<Poses> {
    crate::files::check_csv_lines(bytes, name)?;
    let lines = LineIndex::new(bytes);
    check_quotes_closed(bytes, &lines, name)?;
    let mut rdr = csv::ReaderBuilder::new().trim(csv::Trim::All).flexible(true).from_reader(bytes);
    let header: Vec<String> = rdr
        .byte_headers()
        .with_context(|| format!("{name}: cannot read the CSV header"))?
        .iter()
        .map(|h| String::from_utf8_lossy(h).into_owned())
        .collect();
    for (k, h) in header.iter().enumerate() {
        if !h.is_empty() && header[..k].contains(h) {
            bail!("{name}:1: column `{h}` appears twice in the header");
        }
    }
    let col = |c: &str| header.iter().position(|h| h == c);
    let (Some(ct), Some(cx), Some(cy)) = (col("t"), col("x"), col("y")) else {
        bail!("{name}:1: the header must name columns t,x,y (optionally listener), got {:?}", header.join(","));
    };
    let cl = col("listener");
    // (t, position, line) in file order.
    let mut rows: Vec<(f64, Point, u64)> = Vec::new();
    let mut fastest: Option<(f64, u64, u64)> = None;
    for rec in rdr.byte_records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map_or(0, |p| lines.line_of(p.byte()));
            anyhow!("{name}:{line}: malformed CSV: {}", short_csv_error(&e))
        })?;
        let line = rec.position().map_or(0, |p| lines.line_of(p.byte()));
        if rec.iter().all(<[u8]>::is_empty) {
            continue;
        }
        let text = |c: usize| -> Result<&str> {
            let raw = rec.get(c).ok_or_else(|| anyhow!("{name}:{line}: missing column `{}`", header[c]))?;
            std::str::from_utf8(raw).map_err(|_| anyhow!("{name}:{line}: column `{}` is not valid UTF-8", header[c]))
        };
        if let Some(c) = cl {
            let raw = text(c)?;
            let id: u32 = raw.parse().map_err(|_| {
                anyhow!(
                    "{name}:{line}: column listener: {:?} is not a listener number (a whole number from 0)",
                    crate::echoes_csv::short(raw)
                )
            })?;
            if id != listener {
                continue;
            }
        }
        let num = |c: usize| -> Result<f64> {
            let raw = text(c)?;
            let v: f64 = raw.parse().map_err(|_| {
                anyhow!("{name}:{line}: column {}: {:?} is not a number", header[c], crate::echoes_csv::short(raw))
            })?;
            if !v.is_finite() {
                bail!("{name}:{line}: column {}: value must be finite, got {}", header[c], Num(v));
            }
            Ok(v)
        };
        let (t, p) = (num(ct)?, Point::new(num(cx)?, num(cy)?));
        if !p.is_sane() {
            bail!("{name}:{line}: position {p} is beyond ±{} m", Num(chirpmap_core::geometry::MAX_COORD_M));
        }
        if let Some(&(t_prev, p_prev, line_prev)) = rows.last() {
            if t < t_prev {
                bail!(
                    "{name}:{line}: t = {} s comes before t = {} s of line {line_prev}: poses must be in time order",
                    Num(t),
                    Num(t_prev)
                );
            }
            if t == t_prev {
                if p != p_prev {
                    bail!(
                        "{name}:{line}: two different positions at t = {} s ({p} here, {p_prev} at line {line_prev})",
                        Num(t)
                    );
                }
                continue;
            }
            let v = p.dist(p_prev) / (t - t_prev);
            if fastest.is_none_or(|(f, _, _)| v > f) {
                fastest = Some((v, line, line_prev));
            }
        }
        rows.push((t, p, line));
    }
    if rows.is_empty() {
        bail!("{name}: no poses for listener {listener}");
    }
    let track =
        PoseTrack::new(rows.into_iter().map(|(t, p, _)| (t, p)).collect()).map_err(|e| anyhow!("{name}: {e}"))?;
    Ok(Poses { track, name: name.to_string(), fastest })
}

/// The `csv` crate's message without its position (we give the line).
fn short_csv_error(e: &csv::Error) -> String {
    match e.kind() {
        csv::ErrorKind::UnequalLengths { expected_len, len, .. } => {
            format!("{len} fields where the header has {expected_len}")
        }
        _ => crate::echoes_csv::short(&e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<Poses> {
        parse_poses(s.as_bytes(), "p.csv", 0)
    }

    fn err(s: &str) -> String {
        format!("{:#}", parse(s).err().unwrap_or_else(|| anyhow!("(parsed)")))
    }

    #[test]
    fn reads_bom_quotes_crlf_and_other_listeners() {
        let p = parse("\u{feff}\"t\",\"x\",\"y\",listener\r\n0,0,0,0\r\n0,5,5,1\r\n1,2,0,0\r\n").unwrap();
        assert_eq!(p.span(), (0.0, 1.0));
        assert_eq!(p.at(0.5), Some(Point::new(1.0, 0.0)));
        let p = parse("t,x,y\r0,0,0\r2,4,0\r").unwrap();
        assert_eq!(p.at(1.0), Some(Point::new(2.0, 0.0)));
        // A repeated identical pose is kept once.
        assert_eq!(parse("t,x,y\n0,0,0\n0,0,0\n1,1,1\n").unwrap().rows().len(), 2);
    }

    /// Poses implying a listener at or above the speed of sound (a jump of
    /// 30 m in 10 ms) are refused naming the line; a walk passes, and so
    /// does a fast step where sound is faster still (water).
    #[test]
    fn a_listener_faster_than_sound_is_refused_naming_the_line() {
        let p = parse("t,x,y\n0,0,0\n0.01,0.01,0\n0.02,30,0\n0.03,30.01,0\n").unwrap();
        let e = p.check_speed(343.0).unwrap_err().to_string();
        assert!(e.starts_with("p.csv:4: the listener moves at 2999 m/s from the pose of line 3"), "{e}");
        assert!(!e.contains('\n'), "{e}");
        p.check_speed(3000.0).unwrap();
        parse("t,x,y\n0,0,0\n1,1.4,0\n2,2.8,0\n").unwrap().check_speed(343.0).unwrap();
        parse("t,x,y\n0,0,0\n").unwrap().check_speed(343.0).unwrap();
    }

    #[test]
    fn bad_poses_are_refused_naming_file_and_line() {
        let cases = [
            ("t,x,y\n0,0,0\n1,1,0\n0.5,2,0\n", "p.csv:4: t = 0.5 s comes before t = 1 s of line 3"),
            ("t,x,y\r\n0,0,0\r\n1,1,0\r\n1,2,0\r\n", "p.csv:4: two different positions at t = 1 s ((2, 0) here"),
            ("t,x,y\r0,0,0\rabc,1,0\r", "p.csv:3: column t: \"abc\" is not a number"),
            ("t,x,y\n0,0,nan\n", "p.csv:2: column y: value must be finite, got NaN"),
            ("t,x,y\n0,1e300,0\n", "p.csv:2: position (1e300, 0) is beyond ±1000000 m"),
            ("t,x,t\n0,0,0\n", "p.csv:1: column `t` appears twice"),
            ("a,b\n0,0\n", "p.csv:1: the header must name columns t,x,y"),
            ("t,x,y,listener\n0,0,0,-1\n", "p.csv:2: column listener"),
            ("t,x,y,listener\n0,0,0,1\n", "no poses for listener 0"),
            ("t,x,y\n0,0\n", "p.csv:2: missing column `y`"),
            ("t,x,y\n0,0,0\n1,1,\"0\n", "p.csv:3: a quoted field opened here is never closed"),
        ];
        for (input, want) in cases {
            let e = err(input);
            assert!(e.contains(want), "{input:?}: {e:?} should contain {want:?}");
        }
    }

    #[test]
    fn times_in_milliseconds_are_refused_against_the_recording() {
        let p = parse("t,x,y\n0,0,0\n3600,1,0\n").unwrap();
        let e = format!("{:#}", p.check_span(3.6).unwrap_err());
        assert!(e.contains("p.csv") && e.contains("milliseconds"), "{e}");
        let late = parse("t,x,y\n100,0,0\n200,1,0\n").unwrap();
        assert!(format!("{:#}", late.check_span(10.0).unwrap_err()).contains("do not overlap"));
        parse("t,x,y\n0,0,0\n3.6,1,0\n").unwrap().check_span(3.6).unwrap();
        parse("t,x,y\n0,0,0\n30,1,0\n").unwrap().check_span(3.6).unwrap();
    }
}
