//! Streamed synthesis (issue 14) against the synthesizer as it was before
//! it streamed: the in-memory [`synthesize`], the streamed
//! [`synthesize_streamed`] and the old code (copied below, verbatim but for
//! names) must agree bit for bit, and so must the WAV bytes written in one
//! go, written in blocks, and written by the old writer; over listeners
//! that stand, walk and turn, polygon and circle reflectors, linear and
//! exponential sweeps, chirp patterns, tapers or none, noise or none, and
//! every sample format.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use chirpmap_audio::AudioError;
use chirpmap_audio::detect::taper_gain;
use chirpmap_audio::synth::{
    CHUNK_FRAMES, SynthConfig, SynthStream, Synthesized, listener_poses, listener_position, parse_scene_with_synth,
    pattern_cycle, synthesize, synthesize_streamed,
};
use chirpmap_audio::wav::{SampleFormat, WavSink, write_wav};
use chirpmap_core::error::Num;
use chirpmap_core::geometry::specular_point_on_circle;
use chirpmap_core::scene::{ChirpSpec, SweepKind};
use chirpmap_core::{Obstacle, Point, Scene, Shape};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

/// One propagation path during a pose block: length `base + |x_L − q|`.
#[derive(Debug, Clone, Copy)]
struct Path {
    base_m: f64,
    q: Point,
    gain: f64,
}

fn polygon_images(source: Point, obstacle: &Obstacle, listener: Point, out: &mut Vec<Path>) {
    let Shape::Polygon(poly) = &obstacle.shape else { return };
    let ccw = poly.signed_area() > 0.0;
    for (a, b) in poly.edges() {
        let e = b - a;
        let len = e.norm();
        if len < 1e-12 {
            continue;
        }
        let n = if ccw { Point::new(e.y, -e.x) } else { Point::new(-e.y, e.x) } * (1.0 / len);
        let hs = (source - a).dot(n);
        let hl = (listener - a).dot(n);
        if hs <= 0.0 || hl <= 0.0 {
            continue;
        }
        let image = source - n * (2.0 * hs);
        // Where the image→listener segment crosses the edge's line.
        let u = hs / (hs + hl);
        let hit = image + (listener - image) * u;
        let along = (hit - a).dot(e) / (len * len);
        if !(0.0..=1.0).contains(&along) {
            continue;
        }
        out.push(Path { base_m: 0.0, q: image, gain: 1.0 - obstacle.absorption });
    }
}

fn paths_at(source: Point, obstacles: &[Obstacle], listener: Point, out: &mut Vec<Path>) {
    out.clear();
    out.push(Path { base_m: 0.0, q: source, gain: 1.0 });
    for o in obstacles {
        match &o.shape {
            Shape::Circle(c) => {
                if let Some(p) = specular_point_on_circle(source, listener, c) {
                    out.push(Path { base_m: source.dist(p), q: p, gain: 1.0 - o.absorption });
                }
            }
            Shape::Polygon(_) => polygon_images(source, o, listener, out),
        }
    }
}

/// `synthesize` as it was before issue 14 (commit b168ed1), verbatim but
/// for its name and the memory cap.
fn reference_synthesize(scene: &Scene, cfg: &SynthConfig) -> Result<Synthesized, AudioError> {
    scene.validate()?;
    cfg.validate()?;
    let cycle = pattern_cycle(&scene.chirp, cfg.pattern);
    let sweeps: Vec<Box<dyn chirpmap_core::Sweep>> = cycle.iter().map(ChirpSpec::build).collect::<Result<_, _>>()?;
    let obstacles = scene.explicit_obstacles()?;
    let a = scene.world.speed_of_sound;
    if !(a.is_finite() && a > 0.0) {
        return Err(AudioError::InvalidParam { field: "world.speed_of_sound", reason: format!("{a}") });
    }
    let fs = f64::from(cfg.sample_rate_hz);
    if scene.chirp.f_start.max(scene.chirp.f_end) >= fs / 2.0 {
        return Err(AudioError::InvalidParam {
            field: "chirp",
            reason: format!("the sweep exceeds the Nyquist frequency {} Hz", fs / 2.0),
        });
    }
    let t_chirp = scene.chirp.duration;
    // Linear sweeps (the paper's) get an inlined phase; others use the trait.
    let linear: Vec<Option<(f64, f64)>> = cycle
        .iter()
        .map(|c| match c.kind {
            SweepKind::Linear => Some((c.f_start, 0.5 * (c.f_end - c.f_start) / t_chirp)),
            SweepKind::Exponential | SweepKind::Hyperbolic => None,
        })
        .collect();
    let period = t_chirp + cfg.gap_s;
    let total_s = cfg.start_s + cfg.chirps as f64 * period - cfg.gap_s + cfg.tail_s;
    let n = (total_s * fs).ceil() as usize;
    if n > 2_000_000_000 {
        return Err(AudioError::InvalidParam { field: "synth", reason: format!("{} s is too long", Num(total_s)) });
    }
    let source = scene.source_position();
    let block = 64usize;
    let mut channels = Vec::new();
    let mut poses = Vec::new();
    let mut paths = Vec::new();
    for (li, l) in scene.listeners.iter().enumerate() {
        let mut y = vec![0.0f32; n];
        let mut p_a = listener_position(l, 0.0);
        for b0 in (0..n).step_by(block) {
            let b1 = (b0 + block).min(n);
            let p_b = listener_position(l, b1 as f64 / fs);
            paths_at(source, &obstacles, p_a, &mut paths);
            let len = (b1 - b0) as f64;
            for p in &paths {
                // Path length at both block ends; the delay is linear in
                // between to well below a nanosecond (64 samples).
                let (ra, rb) = (p.base_m + p.q.dist(p_a), p.base_m + p.q.dist(p_b));
                let gain = p.gain / ra.max(0.1);
                // Emission time (relative to the first chirp) at the block ends.
                let te_a = b0 as f64 / fs - ra / a - cfg.start_s;
                let te_b = b1 as f64 / fs - rb / a - cfg.start_s;
                let dte = (te_b - te_a) / len;
                // Skip blocks in which this path carries no chirp.
                let (k_a, k_b) = ((te_a / period).floor(), (te_b / period).floor());
                let silent = te_b < 0.0 || k_a >= cfg.chirps as f64 || (k_a == k_b && te_a - k_a * period > t_chirp);
                if silent {
                    continue;
                }
                for (k, out) in y[b0..b1].iter_mut().enumerate() {
                    let te = te_a + dte * k as f64;
                    if te < 0.0 {
                        continue;
                    }
                    let idx = (te / period).floor();
                    if idx >= cfg.chirps as f64 {
                        continue;
                    }
                    let tau = te - idx * period;
                    if tau > t_chirp {
                        continue;
                    }
                    let which = (idx as usize) % sweeps.len();
                    let ph = match linear[which] {
                        Some((f0, half_rate)) => tau * (f0 + half_rate * tau),
                        None => sweeps[which].phase_cycles(tau),
                    };
                    let sv = (std::f32::consts::TAU * (ph - ph.floor()) as f32).sin();
                    let g = if tau < cfg.taper_s || t_chirp - tau < cfg.taper_s {
                        gain * taper_gain(tau, t_chirp, cfg.taper_s)
                    } else {
                        gain
                    };
                    *out += (g * f64::from(sv)) as f32;
                }
            }
            p_a = p_b;
        }
        if let Some(snr) = cfg.snr_db {
            let (mut pw, mut cnt) = (0.0f64, 0usize);
            for v in &y {
                if *v != 0.0 {
                    pw += f64::from(*v) * f64::from(*v);
                    cnt += 1;
                }
            }
            if cnt > 0 {
                let sigma = ((pw / cnt as f64) / 10f64.powf(snr / 10.0)).sqrt() as f32;
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(cfg.noise_seed);
                rng.set_stream(li as u64);
                for v in y.iter_mut() {
                    let g: f32 = StandardNormal.sample(&mut rng);
                    *v += sigma * g;
                }
            }
        }
        let step = cfg.pose_period_s;
        let n_pose = (total_s / step).floor() as usize + 1;
        poses.push((0..n_pose).map(|k| (k as f64 * step, listener_position(l, k as f64 * step))).collect());
        channels.push(y);
    }
    let peak = channels.iter().flat_map(|c| c.iter()).fold(0.0f32, |m, v| m.max(v.abs()));
    if peak > 0.0 {
        let g = cfg.peak as f32 / peak;
        for c in channels.iter_mut() {
            for v in c.iter_mut() {
                *v *= g;
            }
        }
    }
    let chirp_starts_s = (0..cfg.chirps).map(|k| cfg.start_s + k as f64 * period).collect();
    Ok(Synthesized { sample_rate_hz: cfg.sample_rate_hz, channels, poses, chirp_starts_s })
}

fn reference_write_wav(
    path: &std::path::Path,
    sample_rate_hz: u32,
    format: SampleFormat,
    channels: &[&[f32]],
) -> Result<(), AudioError> {
    let n_ch = channels.len();
    let frames = channels.first().map_or(0, |c| c.len());
    if n_ch == 0 || n_ch > usize::from(u16::MAX) || channels.iter().any(|c| c.len() != frames) {
        return Err(AudioError::InvalidParam {
            field: "channels",
            reason: "need at least one channel, all of equal length".into(),
        });
    }
    let (bits, sample_format) = match format {
        SampleFormat::Int(b) => (b, hound::SampleFormat::Int),
        SampleFormat::Float32 => (32, hound::SampleFormat::Float),
    };
    let spec =
        hound::WavSpec { channels: n_ch as u16, sample_rate: sample_rate_hz, bits_per_sample: bits, sample_format };
    let werr = |e: hound::Error| AudioError::Write(format!("{}: {e}", path.display()));
    let file =
        std::fs::File::create(path).map_err(|source| AudioError::Io { path: path.display().to_string(), source })?;
    let mut w = hound::WavWriter::new(std::io::BufWriter::with_capacity(1 << 20, file), spec).map_err(werr)?;
    match format {
        SampleFormat::Int(16) => {
            let mut w16 = w.get_i16_writer((frames * n_ch) as u32);
            for i in 0..frames {
                for c in channels {
                    w16.write_sample((f64::from(c[i]) * 32_768.0).round().clamp(-32_768.0, 32_767.0) as i16);
                }
            }
            w16.flush().map_err(werr)?;
        }
        SampleFormat::Int(b) => {
            let full = 2f64.powi(i32::from(b) - 1);
            for i in 0..frames {
                for c in channels {
                    w.write_sample((f64::from(c[i]) * full).round().clamp(-full, full - 1.0) as i32).map_err(werr)?;
                }
            }
        }
        SampleFormat::Float32 => {
            for i in 0..frames {
                for c in channels {
                    w.write_sample(c[i].clamp(-1.0, 1.0)).map_err(werr)?;
                }
            }
        }
    }
    w.finalize().map_err(werr)
}

/// A fresh directory under the system's temporary one, removed when dropped.
struct TempDir(std::path::PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let p = std::env::temp_dir().join(format!("chirpmap-synth-stream-{name}-{}", std::process::id()));
        std::fs::remove_dir_all(&p).ok();
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }
    fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        std::fs::remove_dir_all(&self.0).ok();
    }
}

/// Scenes that exercise every branch of the renderer.
fn scenes() -> Vec<String> {
    let wall =
        "[[obstacles]]\nvertices = [[-30.0, -4.0], [-30.0, -4.3], [30.0, -4.3], [30.0, -4.0]]\nabsorption = 0.2\n";
    let circle = "[[obstacles]]\ncenter = [3.0, 2.0]\nradius = 0.5\nabsorption = 0.1\n";
    vec![
        // Static listener, a wall, 16-bit, noise (the benchmark's kind).
        format!(
            "[chirp]\nf_start = 10000.0\nf_end = 200.0\nduration = 0.4\n{wall}\
             [[listeners]]\nstart = [1.5, 0.5]\nspeed = 0.0\n\
             [synth]\nchirps = 5\ngap_s = 0.4\nstart_s = 0.05\ntail_s = 0.3\nsnr_db = 20.0\n"
        ),
        // Two moving listeners (one turning), a wall and a circle, f32, up/down chirps.
        format!(
            "[chirp]\nf_start = 9000.0\nf_end = 500.0\nduration = 0.3\n{wall}{circle}\
             [[listeners]]\nstart = [1.5, 0.5]\nheading_deg = 30.0\nspeed = 1.5\nspin_rate = 0.4\n\
             [[listeners]]\nstart = [-2.0, 1.0]\nspeed = 40.0\n\
             [synth]\nchirps = 7\ngap_s = 0.25\nstart_s = 0.0\ntail_s = 0.5\nsnr_db = 10.0\nbits = \"f32\"\n\
             pattern = \"updown\"\nnoise_seed = 7\npose_period_s = 0.003\n"
        ),
        // Exponential sweep, no taper, no noise, 24-bit, 3 listeners at 16 kHz.
        format!(
            "[chirp]\nf_start = 6000.0\nf_end = 300.0\nduration = 0.5\nkind = \"exponential\"\n{circle}\
             [[listeners]]\nstart = [1.0, -1.0]\nspeed = 0.7\nspin_rate = -0.2\n\
             [[listeners]]\nstart = [0.5, 0.5]\nspeed = 0.0\n\
             [[listeners]]\nstart = [2.0, 3.0]\nheading_deg = 200.0\nspeed = 3.0\n\
             [synth]\nchirps = 6\ngap_s = 0.7\nstart_s = 0.2\ntail_s = 0.1\ntaper_s = 0.0\nbits = \"24\"\n\
             sample_rate_hz = 16000\n"
        ),
        // 32-bit, up sweeps, a long taper, noise at 0 dB, a source off the origin.
        format!(
            "[chirp]\nf_start = 2000.0\nf_end = 12000.0\nduration = 0.2\n[source]\nposition = [0.5, -0.5]\n{wall}\
             [[listeners]]\nstart = [3.0, 0.0]\nheading_deg = 90.0\nspeed = 2.0\nspin_rate = 1.0\n\
             [synth]\nchirps = 9\ngap_s = 0.1\nstart_s = 0.5\ntail_s = 0.5\ntaper_s = 0.05\nsnr_db = 0.0\n\
             bits = \"32\"\npattern = \"up\"\npeak = 0.9\n"
        ),
    ]
}

fn bits(c: &[Vec<f32>]) -> Vec<Vec<u32>> {
    c.iter().map(|v| v.iter().map(|x| x.to_bits()).collect()).collect()
}

fn streamed(scene: &Scene, cfg: &SynthConfig, dir: &std::path::Path) -> Vec<Vec<f32>> {
    let scratch = dir.join("scratch.f32");
    let mut got: Vec<Vec<f32>> = vec![Vec::new(); scene.listeners.len()];
    synthesize_streamed(scene, cfg, &scratch, |chans| {
        assert_eq!(chans.len(), got.len());
        assert!(chans[0].len() <= CHUNK_FRAMES && !chans[0].is_empty());
        for (g, c) in got.iter_mut().zip(chans) {
            g.extend_from_slice(c);
        }
        Ok(())
    })
    .unwrap();
    assert!(!scratch.exists(), "the scratch file is removed");
    got
}

#[test]
fn streamed_in_memory_and_the_old_code_agree_bit_for_bit() {
    let dir = TempDir::new("agree");
    for (i, text) in scenes().iter().enumerate() {
        let (scene, cfg) = parse_scene_with_synth(text).unwrap_or_else(|e| panic!("scene {i}: {e}"));
        let old = reference_synthesize(&scene, &cfg).unwrap();
        let new = synthesize(&scene, &cfg).unwrap();
        assert!(old.channels[0].len() > 2 * CHUNK_FRAMES / 3, "scene {i} is long enough to stream in pieces");
        assert!(new.channels.iter().all(|c| c.iter().any(|v| *v != 0.0)));
        assert_eq!(bits(&new.channels), bits(&old.channels), "scene {i}: in-memory vs old");
        assert_eq!(new.poses, old.poses, "scene {i}: poses");
        assert_eq!(new.chirp_starts_s, old.chirp_starts_s);
        let st = streamed(&scene, &cfg, dir.path());
        assert_eq!(bits(&st), bits(&old.channels), "scene {i}: streamed vs old");
        for (li, p) in old.poses.iter().enumerate() {
            assert_eq!(&listener_poses(&scene, &cfg, li).collect::<Vec<_>>(), p);
        }
        let s = SynthStream::new(&scene, &cfg).unwrap();
        assert_eq!(
            (s.frames(), s.n_channels(), s.sample_rate_hz()),
            (old.channels[0].len(), old.channels.len(), cfg.sample_rate_hz)
        );
    }
}

/// A longer recording than one chunk, with odd block sizes in the writer:
/// the WAV bytes equal the old writer's for every format.
#[test]
fn wav_bytes_written_in_blocks_equal_the_old_writer() {
    let dir = TempDir::new("wav");
    let (scene, cfg) = parse_scene_with_synth(&scenes()[1]).unwrap();
    let syn = synthesize(&scene, &cfg).unwrap();
    // Values beyond full scale, NaN and ties test the rounding and clipping.
    let mut chans = syn.channels.clone();
    let edges = [
        1.5,
        -1.5,
        f32::NAN,
        0.5 / 32_768.0,
        -0.5 / 32_768.0,
        1.5 / 32_768.0,
        -2.5 / 32_768.0,
        1.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
        -1e6,
        1e30,
        -0.0,
    ];
    chans[0][..edges.len()].copy_from_slice(&edges);
    let refs: Vec<&[f32]> = chans.iter().map(Vec::as_slice).collect();
    for fmt in [SampleFormat::Int(16), SampleFormat::Int(24), SampleFormat::Int(32), SampleFormat::Float32] {
        let (a, b, c) = (dir.path().join("a.wav"), dir.path().join("b.wav"), dir.path().join("c.wav"));
        reference_write_wav(&a, 44_100, fmt, &refs).unwrap();
        write_wav(&b, 44_100, fmt, &refs).unwrap();
        let n = refs[0].len();
        let mut sink = WavSink::create(&c, 44_100, fmt, refs.len(), n as u64).unwrap();
        let mut at = 0;
        for step in [1usize, 7, 4096, 65_537, 3].iter().cycle() {
            let end = (at + step).min(n);
            let part: Vec<&[f32]> = refs.iter().map(|r| &r[at..end]).collect();
            sink.write(&part).unwrap();
            at = end;
            if at == n {
                break;
            }
        }
        sink.finalize().unwrap();
        let want = std::fs::read(&a).unwrap();
        assert_eq!(std::fs::read(&b).unwrap(), want, "{fmt:?}: write_wav");
        assert_eq!(std::fs::read(&c).unwrap(), want, "{fmt:?}: WavSink in blocks");
    }
}

#[test]
fn the_scratch_file_must_be_new_and_bad_sinks_are_refused() {
    let dir = TempDir::new("scratch");
    let (scene, cfg) = parse_scene_with_synth(&scenes()[0]).unwrap();
    let scratch = dir.path().join("mine.txt");
    std::fs::write(&scratch, "the user's").unwrap();
    let e = synthesize_streamed(&scene, &cfg, &scratch, |_| Ok(())).unwrap_err();
    assert!(matches!(e, AudioError::Io { .. }), "{e}");
    assert_eq!(std::fs::read_to_string(&scratch).unwrap(), "the user's");
    // An error from the consumer stops the rendering and removes the scratch file.
    let scratch = dir.path().join("s.f32");
    let e = synthesize_streamed(&scene, &cfg, &scratch, |_| Err(AudioError::Write("full".into()))).unwrap_err();
    assert!(e.to_string().contains("full"), "{e}");
    assert!(!scratch.exists());
    // A sink refuses more frames than declared, unequal channels, and an
    // unfinished file; a WAV beyond 4 GiB is refused before it is created.
    let p = dir.path().join("x.wav");
    let mut sink = WavSink::create(&p, 8_000, SampleFormat::Int(16), 2, 3).unwrap();
    assert!(sink.write(&[&[0.0; 2], &[0.0; 3]]).is_err());
    assert!(sink.write(&[&[0.0; 4], &[0.0; 4]]).is_err());
    sink.write(&[&[0.0; 2], &[0.0; 2]]).unwrap();
    assert!(sink.finalize().is_err());
    let big = dir.path().join("big.wav");
    assert!(WavSink::create(&big, 48_000, SampleFormat::Float32, 2, 600_000_000).is_err());
    assert!(!big.exists());
}
