//! CSV tables the commands write (besides echoes.csv).

use chirpmap::Highlight;
use std::fmt::Write as _;

/// `x,y,value` rows, as Algorithm 1 returns them.
pub fn highlights_csv(highlights: &[Highlight]) -> String {
    let mut s = String::from("x,y,value\n");
    for h in highlights {
        let _ = writeln!(s, "{},{},{}", h.pos.x, h.pos.y, h.value);
    }
    s
}

/// A score, or "n/a" when undefined (no obstacles).
pub fn fmt_score(s: Option<f64>, digits: usize) -> String {
    s.map_or_else(|| "n/a".into(), |v| format!("{v:.digits$}"))
}

/// `kind,x0,y0,x1,y1,support,ambiguous`, strongest first (a point's x1,y1
/// are empty).
pub fn surfaces_csv(surfaces: &[chirpmap::Surface]) -> String {
    let mut s = String::from("kind,x0,y0,x1,y1,support,ambiguous\n");
    for f in surfaces {
        let _ = match f.kind {
            chirpmap::SurfaceKind::Line => {
                writeln!(s, "line,{},{},{},{},{},{}", f.p0.x, f.p0.y, f.p1.x, f.p1.y, f.support, f.ambiguous)
            }
            chirpmap::SurfaceKind::Point => {
                writeln!(s, "point,{},{},,,{},{}", f.p0.x, f.p0.y, f.support, f.ambiguous)
            }
        };
    }
    s
}
