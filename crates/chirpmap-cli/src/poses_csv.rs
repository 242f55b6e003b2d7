//! Listener poses CSV (`t,x,y[,listener]`, seconds and metres), as written
//! by `chirpmap synth --poses`; read for `chirpmap map --wav`.

use anyhow::{Context, Result, bail};
use chirpmap::{Point, PoseTrack};
use std::path::Path;

/// Reads listener `listener`'s poses (the facade's `PoseTrack` checks them).
pub fn read_poses(path: &Path, listener: u32) -> Result<PoseTrack> {
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
    PoseTrack::new(rows).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}
