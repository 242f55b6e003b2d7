//! `chirpmap synth`: render what the scene's listeners record (issue 5).

use crate::inputs::load_scene;
use crate::output::StagedFiles;
use anyhow::{Context, Result};
use chirpmap::audio::write_wav;
use clap::Args;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Scene TOML; an optional `[synth]` table sets chirps, gap_s, snr_db,
    /// sample_rate_hz, bits, … (see README).
    pub scene: PathBuf,
    /// Output WAV (one channel per listener).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the listeners' positions (CSV `t,x,y[,listener]`).
    #[arg(long)]
    pub poses: Option<PathBuf>,
}

pub fn run(args: &SynthArgs) -> Result<()> {
    let started = Instant::now();
    let outputs: Vec<&Path> = std::iter::once(args.out.as_path()).chain(args.poses.as_deref()).collect();
    let mut out = StagedFiles::new(&outputs, &[&args.scene])?;
    let (scene, cfg) = load_scene(&args.scene)?;
    let scene_name = args.scene.display();
    let syn = chirpmap::synth(&scene, &cfg).with_context(|| format!("{scene_name}"))?;
    let fmt = cfg.format().with_context(|| format!("{scene_name}: [synth]"))?;
    let chans: Vec<&[f32]> = syn.channels.iter().map(Vec::as_slice).collect();
    let wav_tmp = out.path(&args.out)?;
    write_wav(&wav_tmp, syn.sample_rate_hz, fmt, &chans)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    if let Some(pp) = &args.poses {
        let multi = syn.poses.len() > 1;
        let mut s = String::from(if multi { "t,x,y,listener\n" } else { "t,x,y\n" });
        for (li, poses) in syn.poses.iter().enumerate() {
            for (t, p) in poses {
                if multi {
                    let _ = writeln!(s, "{t:.6},{:.6},{:.6},{li}", p.x, p.y);
                } else {
                    let _ = writeln!(s, "{t:.6},{:.6},{:.6}", p.x, p.y);
                }
            }
        }
        let tmp = out.path(pp)?;
        std::fs::write(&tmp, &s).with_context(|| format!("cannot write {}", pp.display()))?;
    }
    out.commit()?;
    let secs = syn.channels.first().map_or(0, Vec::len) as f64 / f64::from(syn.sample_rate_hz);
    say!(
        "{} chirp(s), {} listener(s), {secs:.2} s at {} Hz -> {} in {:.2} s",
        cfg.chirps,
        syn.channels.len(),
        syn.sample_rate_hz,
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
