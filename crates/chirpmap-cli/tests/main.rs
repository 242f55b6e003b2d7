//! The integration tests of `chirpmap-cli`, one module per file, linked into one
//! test executable (one link instead of 9: issue 13, time to first result).
//! Every `tests/*.rs` file must be listed here: chirpmap-cli's
//! `every_test_file_is_a_module` fails otherwise (Cargo.toml sets `autotests = false`; a file that must run
//! alone in its process is its own `[[test]]` there instead).

mod audio;
mod cli;
mod doppler_map;
mod fuzz_csv;
mod range_echoes;
mod range_echoes_dechorate;
mod range_stream;
mod safety;
mod sweep;

// The binary's file readers, compiled in for `fuzz_csv` (at the crate root,
// where `poses_csv` finds `crate::echoes_csv` as it does in the binary).
#[allow(dead_code)]
#[path = "../src/echoes_csv.rs"]
mod echoes_csv;
#[allow(dead_code)]
#[path = "../src/files.rs"]
mod files;
#[allow(dead_code)]
#[path = "../src/poses_csv.rs"]
mod poses_csv;

/// With `autotests = false`, a test file not listed in its crate's
/// tests/main.rs would silently never run: checked for every crate.
#[test]
fn every_test_file_is_a_module() {
    let crates = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut missing = Vec::new();
    for krate in std::fs::read_dir(&crates).expect("crates/ is readable") {
        let dir = krate.expect("crates/ entry").path();
        let Ok(main) = std::fs::read_to_string(dir.join("tests/main.rs")) else { continue };
        let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).expect("the crate's Cargo.toml");
        for entry in std::fs::read_dir(dir.join("tests")).expect("tests/ is readable") {
            let path = entry.expect("tests/ entry").path();
            let Some(stem) = path.file_stem().and_then(|s| s.to_str()) else { continue };
            if path.extension().is_some_and(|e| e == "rs")
                && stem != "main"
                && !main.contains(&format!("\nmod {stem};\n"))
                && !manifest.contains(&format!("path = \"tests/{stem}.rs\""))
            {
                missing.push(path.display().to_string());
            }
        }
    }
    assert!(missing.is_empty(), "add `mod NAME;` to the crate's tests/main.rs for: {missing:?}");
}
