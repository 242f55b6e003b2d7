//! Brute-force time-stepped simulator of the same model, the test oracle (and
//! the baseline of the speed benchmark): every alive particle moves every tick
//! (bouncing as often as needed within the step), and at each measurement tick
//! every alive particle is tested against every measuring listener. This is
//! how the paper's Matlab simulator works (§II.B).

use crate::Sensed;
use crate::analysis::{SimOutput, analyse};
use crate::fast::heard_hz;
use crate::physics::{T_MIN_M, apply_bounce, emission_dir, nearest_hit, world_exit_m};
use crate::resolve::Resolved;
use chirpmap_core::Point;

#[derive(Debug, Clone, Copy)]
struct Particle {
    pos: Point,
    dir: Point,
    loudness: f64,
    freq_hz: f64,
    id: u64,
    bounces: u32,
    /// Path length since the last bounce (m); rays ignore hits closer than
    /// [`T_MIN_M`] to the bounce point, as the path tracer does.
    since_bounce_m: f64,
}

/// Runs the stepper and extracts spectra, peaks and echoes.
pub fn simulate_stepped(r: &Resolved) -> SimOutput {
    analyse(r, sense_stepped(r))
}

/// Advances one particle by one tick; `false` when it has left or faded.
fn step(r: &Resolved, p: &mut Particle) -> bool {
    let mut rem = r.step_m;
    loop {
        let exit = world_exit_m(p.pos, p.dir, &r.world);
        let t_min = (T_MIN_M - p.since_bounce_m).max(0.0);
        match nearest_hit(&r.obstacles, p.pos, p.dir, t_min) {
            Some((h, i)) if h.t < exit && h.t <= rem => {
                rem -= h.t;
                p.pos = h.point;
                (p.dir, p.loudness) =
                    apply_bounce(&r.obstacles[i], p.dir, h.normal, p.loudness, r.bounce_key, p.id, p.bounces);
                p.bounces += 1;
                p.since_bounce_m = 0.0;
                if p.loudness < r.min_loudness {
                    return false;
                }
            }
            _ => {
                if exit <= rem {
                    return false;
                }
                p.pos = p.pos + p.dir * rem;
                p.since_bounce_m += rem;
                return true;
            }
        }
    }
}

/// Every particle sensed by every listener at every measurement, by stepping.
pub fn sense_stepped(r: &Resolved) -> Vec<Sensed> {
    let mut out = Vec::new();
    let mut alive: Vec<Particle> = Vec::new();
    let mut next: Vec<usize> = vec![0; r.listeners.len()];
    for tick in 0..=r.last_tick {
        if tick > 0 {
            alive.retain_mut(|p| step(r, p));
        }
        if tick < r.n_emit_ticks {
            let k = tick as usize;
            for j in 0..r.per_tick {
                alive.push(Particle {
                    pos: r.source,
                    dir: emission_dir(r.dir_table[j as usize], r.emit_rot[k]),
                    loudness: 1.0,
                    freq_hz: r.emit_freq_hz[k],
                    id: tick * u64::from(r.per_tick) + u64::from(j),
                    bounces: 0,
                    since_bounce_m: f64::INFINITY,
                });
            }
        }
        for (li, l) in r.listeners.iter().enumerate() {
            let idx = next[li];
            if l.ticks.get(idx) != Some(&tick) {
                continue;
            }
            next[li] += 1;
            let centre = l.positions[idx];
            let r2 = l.radius_m * l.radius_m;
            for p in &alive {
                let w = p.pos - centre;
                let d2 = w.dot(w);
                if d2 <= r2 {
                    out.push(Sensed {
                        measurement: (l.first_measurement + idx) as u32,
                        particle: p.id,
                        freq_hz: heard_hz(r, p.freq_hz, p.dir, l.velocities[idx]),
                        loudness: p.loudness,
                        dist_m: d2.sqrt(),
                    });
                }
            }
        }
    }
    out
}
