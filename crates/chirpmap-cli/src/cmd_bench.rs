//! `chirpmap benchmark maps`: both mappers side by side on the fixed scene
//! suite of `chirpmap_experiments::maps` (issue 9); writes maps.csv and
//! maps.md. `chirpmap benchmark doppler`: moving-listener ranging by method,
//! speed and chirp pattern (issue 11); writes doppler.csv and doppler.md.

use crate::output::Staged;
use anyhow::{Result, anyhow, bail};
use chirpmap::MapperKind;
use chirpmap_experiments::maps::{Case, exact_cases, particle_cases, rows_csv, rows_markdown, run_case, synth_cases};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Debug, Args)]
pub struct BenchArgs {
    /// The suite: `maps` (the mapping benchmark: Table I scenes, a loop past circles, a room with a pillar
    /// and corner echoes, an L-shaped corridor, field environments A and B) or `doppler` (the moving-wall
    /// scene at several listener speeds, every `map --wav` method and chirp pattern).
    pub suite: String,
    /// Output directory (maps.csv: one row per case, run and mapper; maps.md: means per case and mapper, and the Table I scores paired by run with standard errors).
    #[arg(long)]
    pub out: PathBuf,
    /// Runs of each Table I scene (1, 10, 50 ms).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub runs: u64,
    /// Listener speeds (m/s) of the doppler suite, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,5,10")]
    pub speeds: Vec<f64>,
}

fn run_doppler(args: &BenchArgs) -> Result<()> {
    if let Some(s) = args.speeds.iter().find(|s| !(s.is_finite() && **s >= 0.01 && **s <= 30.0)) {
        bail!(
            "--speeds: {} m/s is outside [0.01, 30] (a listener of the doppler suite walks past the wall)",
            chirpmap_core::error::Num(*s)
        );
    }
    if let Some((k, s)) = args.speeds.iter().enumerate().find(|(k, s)| args.speeds[..*k].contains(s)) {
        bail!("--speeds: {} m/s is given twice (speed {} of the list)", chirpmap_core::error::Num(*s), k + 1);
    }
    let mut out = Staged::dir(&args.out, "benchmark doppler", &["doppler.csv", "doppler.md"], &[])?;
    let started = Instant::now();
    let mut rows = Vec::new();
    for c in chirpmap_experiments::doppler::cases(&args.speeds) {
        let row = chirpmap_experiments::doppler::run_case(c).map_err(|e| anyhow!(e))?;
        eprintln!(
            "{} m/s {} {}: {} echoes, {} chirps, {:.1} s",
            c.speed_mps,
            c.method.name(),
            c.pattern.name(),
            row.echoes,
            row.chirps_found,
            row.elapsed_s
        );
        rows.push(row);
    }
    out.write("doppler.csv", chirpmap_experiments::doppler::rows_csv(&rows))?;
    let md = chirpmap_experiments::doppler::rows_markdown(&rows);
    out.write("doppler.md", &md)?;
    let dir = out.commit()?;
    say!("{md}");
    say!("wrote {} in {:.1} s", dir.display(), started.elapsed().as_secs_f64());
    Ok(())
}

pub fn run(args: &BenchArgs) -> Result<()> {
    if args.suite == "doppler" {
        return run_doppler(args);
    }
    if args.suite != "maps" {
        bail!("unknown benchmark suite {:?} (suites: maps, doppler)", crate::args::excerpt(&args.suite));
    }
    let mut out = Staged::dir(&args.out, "benchmark maps", &["maps.csv", "maps.md"], &[])?;
    let started = Instant::now();
    let mut cases: Vec<Case> = exact_cases().map_err(|e| anyhow!(e))?;
    cases.extend(particle_cases(args.runs).map_err(|e| anyhow!(e))?);
    cases.extend(synth_cases().map_err(|e| anyhow!(e))?);
    eprintln!("{} cases built in {:.1} s", cases.len(), started.elapsed().as_secs_f64());
    let mut rows = Vec::new();
    for c in &cases {
        for mapper in [MapperKind::Paper, MapperKind::Evidence] {
            rows.push(run_case(c, mapper).map_err(|e| anyhow!(e))?);
        }
    }
    out.write("maps.csv", rows_csv(&rows))?;
    let md = rows_markdown(&rows);
    out.write("maps.md", &md)?;
    let dir = out.commit()?;
    say!("{md}");
    say!("wrote {} in {:.1} s", dir.display(), started.elapsed().as_secs_f64());
    Ok(())
}
