//! `chirpmap`: turn sound into maps (see `chirpmap --help`).

/// `println!` that ends quietly when stdout is closed early (e.g. piped into
/// `head`) instead of panicking; the command's results are in its files.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

mod args;
mod cmd_bench;
mod cmd_map;
mod cmd_range;
mod cmd_simulate;
mod cmd_sweep;
mod cmd_synth;
mod echoes_csv;
mod files;
mod inputs;
mod mapdata;
mod mapout;
mod output;
mod plot;
mod plot_audio;
mod plot_summary;
mod poses_csv;
mod tables;

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
    /// Draw no progress bar (any command; long-running ones draw one on stderr), e.g. in batch jobs.
    #[arg(long, global = true)]
    no_progress: bool,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Simulate a scene with the paper's particle model (§II.B), map the echoes, score the map.
    Simulate(cmd_simulate::SimulateArgs),
    /// Accumulate echo ellipses on a grid (paper Algorithm 1) and extract highlights.
    Map(cmd_map::MapArgs),
    /// Run a parameter sweep (presets: table1, table2) in parallel; resumable and shardable.
    Sweep(cmd_sweep::SweepArgs),
    /// Join the output directories of a sharded sweep.
    Merge(cmd_sweep::MergeArgs),
    /// Render what the scene's listeners record: chirp train, direct path and specular reflections, noise.
    Synth(cmd_synth::SynthArgs),
    /// Benchmark suites: `maps` runs both mappers side by side on a fixed scene suite (EXPERIMENTS.md).
    Benchmark(cmd_bench::BenchArgs),
    /// Range a recording: find every chirp, Δd to the first reflection, wall distance (paper §IV).
    Range(cmd_range::RangeArgs),
}

/// On Ctrl-C, SIGTERM or SIGHUP: removes the run's unfinished outputs
/// (its staging folders, [`output::abandon_all`]) and exits with 128 + the
/// signal, as the shell reports a killed process. Without this, an
/// interrupted hour-long `synth` left 600 MB of hidden debris until the next
/// run in that directory. Sweeps need nothing more: runs.csv holds whole
/// rows, and a rerun resumes.
#[cfg(unix)]
fn clean_up_on_interrupt() {
    use signal_hook::consts::signal::{SIGHUP, SIGINT, SIGTERM};
    // If the handler cannot be installed, a signal kills at once, as before.
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) else { return };
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            let _no_commit_from_now = output::abandon_all();
            eprintln!("interrupted: unfinished outputs removed");
            std::process::exit(128 + signal);
        }
    });
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    #[cfg(unix)]
    clean_up_on_interrupt();
    let result = match cli.command {
        Command::Simulate(args) => cmd_simulate::run(&args),
        Command::Map(args) => cmd_map::run(&args),
        Command::Sweep(args) => cmd_sweep::run_sweep_cmd(&args, cli.no_progress),
        Command::Merge(args) => cmd_sweep::run_merge_cmd(&args),
        Command::Synth(args) => cmd_synth::run(&args),
        Command::Range(args) => cmd_range::run(&args),
        Command::Benchmark(args) => cmd_bench::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
