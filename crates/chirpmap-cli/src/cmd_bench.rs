//! `chirpmap benchmark maps`: both mappers side by side on the fixed scene
//! suite of `chirpmap_experiments::maps` (issue 9); writes maps.csv and
//! maps.md.

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
    /// and corner echoes, an L-shaped corridor, field environments A and B).
    pub suite: String,
    /// Output directory (maps.csv: one row per case, run and mapper; maps.md: means per case and mapper).
    #[arg(long)]
    pub out: PathBuf,
    /// Runs of each Table I scene (1, 10, 50 ms).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub runs: u64,
}

pub fn run(args: &BenchArgs) -> Result<()> {
    if args.suite != "maps" {
        bail!("unknown benchmark suite {:?} (suites: maps)", crate::args::excerpt(&args.suite));
    }
    let mut out = Staged::dir(&args.out, &["maps.csv", "maps.md"], &[])?;
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
