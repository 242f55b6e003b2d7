//! `chirpmap`: turn sound into maps (see `chirpmap --help`).

mod cmd_map;
mod cmd_range;
mod cmd_synth;
mod echoes_csv;
mod output;
mod plot;
mod plot_audio;
mod poses_csv;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Debug, Parser)]
#[command(
    name = "chirpmap",
    version,
    about = "Acoustic-ellipse mapping: frequency sweeps in, obstacle maps out",
    long_about = "chirpmap implements \"Acoustic Ellipses\" (Swissler, Burke, Hyland Bruno): a Source plays a \
                  frequency sweep, moving Listeners hear direct and reflected sound at once, each frequency gap \
                  gives an ellipse of possible reflection points, and ellipses accumulated on a grid reveal \
                  obstacles."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Accumulate echo ellipses on a grid (paper Algorithm 1) and extract highlights.
    Map(cmd_map::MapArgs),
    /// Render what the scene's listeners record: chirp train, direct path and specular reflections, noise.
    Synth(cmd_synth::SynthArgs),
    /// Range a recording: find every chirp, Δd to the first reflection, wall distance (paper §IV).
    Range(cmd_range::RangeArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Map(args) => cmd_map::run(&args),
        Command::Synth(args) => cmd_synth::run(&args),
        Command::Range(args) => cmd_range::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
