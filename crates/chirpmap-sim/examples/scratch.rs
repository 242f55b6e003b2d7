#![allow(clippy::unwrap_used)]
use chirpmap_core::Scene;
use chirpmap_sim::{resolve, simulate, sense_fast};
fn main() {
    let mut s = Scene::default();
    if let Some(p) = std::env::args().nth(1) { s.listeners[0].sampling.period_ms = Some(p.parse().unwrap()); }
    let r = resolve(&s).unwrap();
    let t = std::time::Instant::now();
    let sensed = sense_fast(&r);
    let t1 = t.elapsed();
    let out = simulate(&r);
    println!("sense {:?} total {:?} sensed {} meas {} echoes {}", t1, t.elapsed(), sensed.len(), out.measurements.len(), out.echoes.len());
    for o in &r.obstacles { println!("{:?}", o.shape); }
    for m in out.measurements.iter().step_by(out.measurements.len() / 15 + 1) {
        println!("t={:.3} n={} peaks={:?} direct={:?} pred={:?}", m.t_s, m.n_sensed, m.peaks.iter().map(|p| (p.f_hz.round(), (p.intensity*10.0).round()/10.0)).collect::<Vec<_>>(), m.direct, m.predicted_direct_hz.map(|f| f.round()));
    }
    let mut dd: Vec<f64> = out.echoes.iter().map(|e| e.delta_d_m).collect();
    dd.sort_by(f64::total_cmp);
    println!("dd sample {:?}", dd.iter().step_by(dd.len()/20+1).map(|x| (x*10.0).round()/10.0).collect::<Vec<_>>());
}
