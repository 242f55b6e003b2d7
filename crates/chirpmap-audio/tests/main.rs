//! The integration tests of `chirpmap-audio`, one module per file, linked into one
//! test executable (one link instead of 8: issue 13, time to first result).
//! Every `tests/*.rs` file must be listed here: chirpmap-cli's
//! `every_test_file_is_a_module` fails otherwise (Cargo.toml sets `autotests = false`; a file that must run
//! alone in its process is its own `[[test]]` there instead).

mod accuracy;
mod doppler_detect;
mod fuzz_wav;
mod limits;
mod rooms_pursuit;
mod scipy_reference;
mod synth_stream;
mod wav;
mod wav_stream;
