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
