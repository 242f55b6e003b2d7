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
        let num = |c: usize| -> Result<f64> {
            let v: f64 = f
                .get(c)
                .with_context(|| format!("{}:{}: missing column {c}", path.display(), i + 1))?
                .parse()
                .with_context(|| format!("{}:{}: not a number", path.display(), i + 1))?;
            if !v.is_finite() {
                bail!("{}:{}: value must be finite", path.display(), i + 1);
            }
            Ok(v)
        };
        if let Some(c) = cl
            && num(c)? as u32 != listener
        {
            continue;
        }
        rows.push((num(ct)?, Point::new(num(cx)?, num(cy)?)));
    }
    if rows.is_empty() {
        bail!("{}: no poses for listener {listener}", path.display());
    }
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(Track { rows })
}
