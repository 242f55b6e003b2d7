//! Reading whole input files with a size cap (no other dependency, so the
//! integration tests compile it in with the CSV readers).

use anyhow::{Context, Result, anyhow};
use std::path::Path;

/// Largest scene or sweep TOML read: 1000 obstacles of 1000 vertices
/// (`Scene::validate`'s limits) take ~30 MB.
pub const MAX_TOML_BYTES: u64 = 64 << 20;
/// Largest echoes or poses CSV read: 10⁷ rows of ~60 bytes.
pub const MAX_CSV_BYTES: u64 = 1 << 30;
/// Most lines an echoes or poses CSV may have (rows, the header and blank
/// lines): short rows under [`MAX_CSV_BYTES`] were 10⁸ echoes, 9.6 GB of
/// memory before the first bad value was found.
pub const MAX_CSV_LINES: usize = 10_000_001;

/// Refuses a CSV held in `bytes` with more than [`MAX_CSV_LINES`] lines
/// (ended by LF, CRLF or a lone CR, as the readers accept), before anything
/// is parsed; `name` is used in the message.
pub fn check_csv_lines(bytes: &[u8], name: &str) -> Result<()> {
    let count = |c: u8| bytes.iter().filter(|&&b| b == c).count();
    let (lf, cr) = (count(b'\n'), count(b'\r'));
    // A CRLF is one line end; the pairs are looked for only when a CR is there.
    let crlf = if cr == 0 { 0 } else { bytes.windows(2).filter(|w| w == b"\r\n").count() };
    let n = lf + cr - crlf + usize::from(bytes.last().is_some_and(|&b| b != b'\n' && b != b'\r'));
    if n > MAX_CSV_LINES {
        return Err(anyhow!("{name}: {n} lines, more than the {MAX_CSV_LINES} read (10 000 000 rows and a header)"));
    }
    Ok(())
}

/// Reads a whole input file of at most `cap` bytes; `what` names it in
/// errors. A larger regular file is refused before it is read, and an
/// endless stream (`/dev/zero`, a FIFO fed forever) stops at the cap: both
/// were read whole and grew until memory ran out.
pub fn read_input(path: &Path, what: &str, cap: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let file = std::fs::File::open(path).with_context(|| format!("cannot read {what} {}", path.display()))?;
    let refuse = |size: String| anyhow!("{what} {} is too large: {size} (the limit is {cap} bytes)", path.display());
    if let Ok(m) = file.metadata()
        && m.is_file()
        && m.len() > cap
    {
        return Err(refuse(format!("{} bytes", m.len())));
    }
    let mut bytes = Vec::new();
    file.take(cap + 1).read_to_end(&mut bytes).with_context(|| format!("cannot read {what} {}", path.display()))?;
    if bytes.len() as u64 > cap {
        return Err(refuse(format!("more than {cap} bytes")));
    }
    Ok(bytes)
}

/// [`read_input`] of a text file: UTF-8, or an error naming the file.
pub fn read_text_input(path: &Path, what: &str, cap: u64) -> Result<String> {
    String::from_utf8(read_input(path, what, cap)?).map_err(|e| {
        anyhow!("cannot read {what} {}: not UTF-8 text (byte {})", path.display(), e.utf8_error().valid_up_to())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Line counts are capped before parsing; a last line without its
    /// newline counts.
    #[test]
    fn csv_lines_beyond_the_cap_are_refused_before_parsing() {
        let mut bytes = vec![b'\n'; MAX_CSV_LINES];
        check_csv_lines(&bytes, "e.csv").expect("at the cap");
        bytes.push(b'x');
        let e = check_csv_lines(&bytes, "e.csv").expect_err("one more").to_string();
        assert_eq!(
            e,
            format!(
                "e.csv: {} lines, more than the {MAX_CSV_LINES} read (10 000 000 rows and a header)",
                MAX_CSV_LINES + 1
            )
        );
        check_csv_lines(b"", "e.csv").expect("empty");
        // Lone CRs end lines too; CRLF is one end.
        let mut cr = vec![b'\r'; MAX_CSV_LINES];
        check_csv_lines(&cr, "e.csv").expect("at the cap");
        cr.push(b'\r');
        assert!(check_csv_lines(&cr, "e.csv").is_err());
        let crlf = b"\r\n".repeat(MAX_CSV_LINES);
        check_csv_lines(&crlf, "e.csv").expect("CRLF counts once");
    }

    #[test]
    fn inputs_beyond_the_cap_are_refused_even_endless_ones() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("s.toml");
        std::fs::write(&p, "0123456789").expect("write");
        assert_eq!(read_input(&p, "scene", 10).expect("fits"), b"0123456789");
        let e = read_input(&p, "scene", 9).expect_err("too large").to_string();
        assert!(e.contains("scene") && e.contains("s.toml is too large: 10 bytes (the limit is 9 bytes)"), "{e}");
        if cfg!(target_os = "linux") {
            let e = read_input(Path::new("/dev/zero"), "echoes file", 1000).expect_err("endless").to_string();
            assert!(e.contains("/dev/zero is too large: more than 1000 bytes"), "{e}");
        }
        std::fs::write(&p, [b'a', 0xff, b'b']).expect("write");
        let e = read_text_input(&p, "scene", 10).expect_err("not UTF-8").to_string();
        assert!(e.contains("not UTF-8 text (byte 1)"), "{e}");
    }
}
