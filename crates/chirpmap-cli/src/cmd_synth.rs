//! `chirpmap synth`: render what the scene's listeners record (issue 5),
//! streamed to the WAV file in memory that does not grow with the
//! recording (issue 14).

use crate::inputs::load_scene;
use crate::output::StagedFiles;
use anyhow::{Context, Result};
use chirpmap::audio::synth::{SynthStream, listener_poses};
use chirpmap::audio::wav::WavSink;
use clap::Args;
use std::io::Write as _;
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
    let fmt = cfg.format().with_context(|| format!("{scene_name}: [synth]"))?;
    let wav_tmp = out.path(&args.out)?;
    // The unscaled samples wait in the staging folder beside the output
    // (removed with it, and by the next run if this one is killed).
    let mut scratch = wav_tmp.clone().into_os_string();
    scratch.push(".unscaled-f32");
    let stream = SynthStream::new(&scene, &cfg).with_context(|| format!("{scene_name}"))?;
    let mut sink = WavSink::create(&wav_tmp, stream.sample_rate_hz(), fmt, stream.n_channels(), stream.frames() as u64)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    stream.run(Path::new(&scratch), |chans| sink.write(chans)).with_context(|| format!("{scene_name}"))?;
    sink.finalize().with_context(|| format!("cannot write {}", args.out.display()))?;
    if let Some(pp) = &args.poses {
        let tmp = out.path(pp)?;
        let werr = || format!("cannot write {}", pp.display());
        let file = std::fs::File::create(&tmp).with_context(werr)?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        let multi = scene.listeners.len() > 1;
        w.write_all(if multi { b"t,x,y,listener\n" } else { b"t,x,y\n" }).with_context(werr)?;
        for li in 0..scene.listeners.len() {
            for (t, p) in listener_poses(&scene, &cfg, li) {
                if multi {
                    writeln!(w, "{t:.6},{:.6},{:.6},{li}", p.x, p.y).with_context(werr)?;
                } else {
                    writeln!(w, "{t:.6},{:.6},{:.6}", p.x, p.y).with_context(werr)?;
                }
            }
        }
        w.flush().with_context(werr)?;
    }
    out.commit()?;
    let secs = stream.frames() as f64 / f64::from(stream.sample_rate_hz());
    say!(
        "{} chirp(s), {} listener(s), {secs:.2} s at {} Hz -> {} in {:.2} s",
        cfg.chirps,
        stream.n_channels(),
        stream.sample_rate_hz(),
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
