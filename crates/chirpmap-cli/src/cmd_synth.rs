//! `chirpmap synth`: render what the scene's listeners record (issue 5).

use anyhow::{Context, Result, anyhow};
use chirpmap_audio::synth::{parse_scene_with_synth, synthesize};
use chirpmap_audio::write_wav;
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

/// Writes through a sibling temporary file so a failure leaves no partial output.
fn write_atomically(path: &Path, f: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let tmp = path.with_extension(format!("partial-{}", std::process::id()));
    match f(&tmp) {
        Ok(()) => std::fs::rename(&tmp, path).with_context(|| format!("cannot move output to {}", path.display())),
        Err(e) => {
            std::fs::remove_file(&tmp).ok();
            Err(e)
        }
    }
}

pub fn run(args: &SynthArgs) -> Result<()> {
    let started = Instant::now();
    let text =
        std::fs::read_to_string(&args.scene).with_context(|| format!("cannot read scene {}", args.scene.display()))?;
    let (scene, cfg) = parse_scene_with_synth(&text).map_err(|e| anyhow!("{}: {e}", args.scene.display()))?;
    let syn = synthesize(&scene, &cfg)?;
    let fmt = cfg.format()?;
    let chans: Vec<&[f32]> = syn.channels.iter().map(Vec::as_slice).collect();
    write_atomically(&args.out, |p| Ok(write_wav(p, syn.sample_rate_hz, fmt, &chans)?))?;
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
        write_atomically(pp, |p| std::fs::write(p, &s).with_context(|| format!("cannot write {}", p.display())))?;
    }
    let secs = syn.channels.first().map_or(0, Vec::len) as f64 / f64::from(syn.sample_rate_hz);
    println!(
        "{} chirp(s), {} listener(s), {secs:.2} s at {} Hz -> {} in {:.2} s",
        cfg.chirps,
        syn.channels.len(),
        syn.sample_rate_hz,
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
