//! The integration tests of `chirpmap-core`, one module per file, linked into one
//! test executable (one link instead of 5: issue 13, time to first result).
//! Every `tests/*.rs` file must be listed here: chirpmap-cli's
//! `every_test_file_is_a_module` fails otherwise (Cargo.toml sets `autotests = false`; a file that must run
//! alone in its process is its own `[[test]]` there instead).

mod evidence_dechorate;
mod evidence_props;
mod evidence_scenes;
mod fuzz_map;
mod fuzz_scene;
