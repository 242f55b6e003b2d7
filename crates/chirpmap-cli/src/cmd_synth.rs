//! `chirpmap synth`: render what the scene's listeners record (issue 5).

use anyhow::{Context, Result, anyhow, bail};
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

/// A sibling temporary path for `path` (created parent directory included).
fn staging_path(path: &Path) -> Result<PathBuf> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let name = path.file_name().with_context(|| format!("{} is not a file path", path.display()))?;
    let mut tmp = name.to_os_string();
    tmp.push(format!(".partial-{}", std::process::id()));
    Ok(path.with_file_name(tmp))
}

/// Writes one output to the path it is given.
type Writer<'a> = Box<dyn FnOnce(&Path) -> Result<()> + 'a>;

/// Writes every output through a sibling temporary file and moves them all
/// into place only when every one was written: a failure leaves none of
/// them (not a WAV without its poses).
fn write_all_or_nothing(outputs: Vec<(&Path, Writer<'_>)>) -> Result<()> {
    let mut staged: Vec<(PathBuf, &Path)> = Vec::new();
    let cleanup = |staged: &[(PathBuf, &Path)]| {
        for (tmp, _) in staged {
            std::fs::remove_file(tmp).ok();
        }
    };
    for (path, write) in outputs {
        let tmp = match staging_path(path) {
            Ok(t) => t,
            Err(e) => {
                cleanup(&staged);
                return Err(e);
            }
        };
        staged.push((tmp.clone(), path));
        if let Err(e) = write(&tmp) {
            cleanup(&staged);
            return Err(e);
        }
    }
    for (i, (tmp, path)) in staged.iter().enumerate() {
        if let Err(e) = std::fs::rename(tmp, path) {
            cleanup(&staged[i..]);
            // Outputs already moved would be half a result: remove them.
            for (_, done) in &staged[..i] {
                std::fs::remove_file(done).ok();
            }
            return Err(e).with_context(|| format!("cannot move output to {}", path.display()));
        }
    }
    Ok(())
}

pub fn run(args: &SynthArgs) -> Result<()> {
    let started = Instant::now();
    let text =
        std::fs::read_to_string(&args.scene).with_context(|| format!("cannot read scene {}", args.scene.display()))?;
    let (scene, cfg) = parse_scene_with_synth(&text).map_err(|e| anyhow!("{}: {e}", args.scene.display()))?;
    let scene_name = args.scene.display();
    let syn = synthesize(&scene, &cfg).with_context(|| format!("{scene_name}"))?;
    let fmt = cfg.format().with_context(|| format!("{scene_name}: [synth]"))?;
    let chans: Vec<&[f32]> = syn.channels.iter().map(Vec::as_slice).collect();
    let mut outputs: Vec<(&Path, Writer<'_>)> = Vec::new();
    outputs.push((&args.out, Box::new(|p: &Path| Ok(write_wav(p, syn.sample_rate_hz, fmt, &chans)?))));
    if let Some(pp) = &args.poses {
        if pp == &args.out {
            bail!("--poses and --out are the same file {}", pp.display());
        }
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
        outputs.push((
            pp.as_path(),
            Box::new(move |p: &Path| std::fs::write(p, &s).with_context(|| format!("cannot write {}", p.display()))),
        ));
    }
    write_all_or_nothing(outputs)?;
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
