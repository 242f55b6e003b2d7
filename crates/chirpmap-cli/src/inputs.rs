//! Reading the commands' input files into the facade's plain data, naming
//! the file in every error.

use crate::files::{MAX_TOML_BYTES, read_text_input};
use anyhow::{Context, Result, anyhow, bail};
use chirpmap::{ChirpSpec, Prepared, Scene, SynthConfig};
use std::path::Path;

/// Loads a scene file (with its optional `[synth]` table).
pub fn load_scene(path: &Path) -> Result<(Scene, SynthConfig)> {
    Ok(load_scene_declaring(path)?.0)
}

/// The tables a file of settings for `map` may hold: `[mapping]` (and
/// `[mapping.evidence]`), `[chirp]`, `[synth]`, `[source]`.
const SETTINGS_TABLES: [&str; 4] = ["mapping", "chirp", "synth", "source"];

/// Loads a scene file, and says whether it describes a scene to score
/// against: any table beyond [`SETTINGS_TABLES`] (`[[obstacles]]`,
/// `[random_obstacles]`, `[[listeners]]`, `[world]`, a seed…) makes it a
/// scene, resolved as `simulate` resolves it. A file of settings only (or
/// an empty one) is not the default scene's three random obstacles.
pub fn load_scene_declaring(path: &Path) -> Result<((Scene, SynthConfig), bool)> {
    let text = read_text_input(path, "scene", MAX_TOML_BYTES)?;
    let scene = chirpmap::parse_scene(&text).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    // parse_scene accepted the text, so it parses as a TOML table.
    let declares = text.parse::<toml::Table>().is_ok_and(|t| t.keys().any(|k| !SETTINGS_TABLES.contains(&k.as_str())));
    Ok((scene, declares))
}

/// Reads one channel of a WAV and prepares it for ranging; also returns the
/// number of clipped samples.
pub fn prepare_wav(wav: &Path, channel: usize, chirp: &ChirpSpec) -> Result<(Prepared, usize)> {
    let rec = chirpmap::audio::read_wav(wav).with_context(|| format!("{}", wav.display()))?;
    if rec.clipped_samples > 0 {
        eprintln!(
            "warning: {}: {} sample(s) at full scale (clipping); estimates may be degraded",
            wav.display(),
            rec.clipped_samples
        );
    }
    let fs = f64::from(rec.sample_rate_hz);
    let clipped = rec.clipped_samples;
    let n_channels = rec.channels.len();
    rec.channel(channel).with_context(|| format!("{}", wav.display()))?;
    let mut channels = rec.channels;
    let x = channels.swap_remove(channel);
    if x.iter().all(|v| *v == 0.0) {
        let hint =
            if n_channels > 1 { format!(" (it has {n_channels} channels: try --channel)") } else { String::new() };
        bail!("{}: channel {channel} is silent (every sample is zero){hint}", wav.display());
    }
    let prep = chirpmap::prepare(x, fs, chirp).map_err(|e| match e {
        chirpmap::Error::Field { field, reason } => {
            anyhow!("{}: --{}: {reason}", wav.display(), field.replace('_', "-"))
        }
        e => anyhow!("{}: {e}", wav.display()),
    })?;
    Ok((prep, clipped))
}
