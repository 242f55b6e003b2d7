//! Listener poses CSV (`t,x,y[,listener]`, seconds and metres), as written
//! by `chirpmap synth --poses`; read for `chirpmap map --wav`.

use anyhow::{Context, Result, bail};
use chirpmap_core::Point;
use std::path::Path;

/// One listener's track, sorted by time, linearly interpolated.
#[derive(Debug, Clone)]
pub struct Track {
    rows: Vec<(f64, Point)>,
}

impl Track {
    /// First and last pose times (s).
    pub fn span(&self) -> (f64, f64) {
        (self.rows.first().map_or(0.0, |r| r.0), self.rows.last().map_or(0.0, |r| r.0))
    }

    /// Position at `t_s`; `None` outside the recorded span.
    pub fn at(&self, t_s: f64) -> Option<Point> {
        let k = self.rows.partition_point(|r| r.0 <= t_s);
        if k == 0 || k > self.rows.len() {
            return None;
        }
        let (t0, p0) = self.rows[k - 1];
        let Some(&(t1, p1)) = self.rows.get(k) else {
            return (t_s - t0 < 1e-9).then_some(p0);
        };
        let u = if t1 > t0 { (t_s - t0) / (t1 - t0) } else { 0.0 };
        Some(p0 + (p1 - p0) * u)
    }
}

pub fn read_poses(path: &Path, listener: u32) -> Result<Track> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read poses {}", path.display()))?;
    let mut lines = text.lines().enumerate();
    let header: Vec<String> =
        lines.next().map(|(_, l)| l.split(',').map(|h| h.trim().to_string()).collect()).unwrap_or_default();
    let col = |name: &str| header.iter().position(|h| h == name);
    let (Some(ct), Some(cx), Some(cy)) = (col("t"), col("x"), col("y")) else {
        bail!("{}: header must name columns t,x,y (optionally listener)", path.display());
    };
    let cl = col("listener");
    let mut rows = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let field = |c: usize| -> Result<&str> {
            f.get(c).copied().with_context(|| format!("{}:{}: missing column {}", path.display(), i + 1, header[c]))
        };
        let num = |c: usize| -> Result<f64> {
            let v: f64 = field(c)?.parse().map_err(|_| {
                anyhow::anyhow!(
                    "{}:{}: column {}: {:?} is not a number",
                    path.display(),
                    i + 1,
                    header[c],
                    field(c).unwrap_or("")
                )
            })?;
            if !v.is_finite() {
                bail!("{}:{}: column {}: value must be finite", path.display(), i + 1, header[c]);
            }
            Ok(v)
        };
        if let Some(c) = cl {
            let raw = field(c)?;
            let id: u32 = raw.parse().map_err(|_| {
                anyhow::anyhow!(
                    "{}:{}: column listener: {raw:?} is not a listener number (a whole number from 0)",
                    path.display(),
                    i + 1
                )
            })?;
            if id != listener {
                continue;
            }
        }
        rows.push((num(ct)?, Point::new(num(cx)?, num(cy)?)));
    }
    if rows.is_empty() {
        bail!("{}: no poses for listener {listener}", path.display());
    }
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(Track { rows })
}
