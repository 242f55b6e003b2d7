//! The integration tests of `chirpmap-sim`, one module per file, linked into one
//! test executable (one link instead of 4: issue 13, time to first result).
//! Every `tests/*.rs` file must be listed here: chirpmap-cli's
//! `every_test_file_is_a_module` fails otherwise (Cargo.toml sets `autotests = false`; a file that must run
//! alone in its process is its own `[[test]]` there instead).

mod fuzz_resolve;
mod oracle;
mod physics;
mod threads;
mod validation;
