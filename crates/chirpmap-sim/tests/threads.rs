//! The simulator traces emission ticks on rayon's threads: its output must
//! be bit-identical whatever the thread count (issue 14).

use chirpmap_core::Scene;
use chirpmap_core::scene::Sampling;
use chirpmap_sim::{SimOutput, resolve, simulate};

fn run_on(threads: usize, scene: &Scene) -> SimOutput {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
    let r = resolve(scene).expect("valid scene");
    pool.install(|| simulate(&r))
}

#[test]
fn output_is_identical_on_one_two_and_five_threads() {
    // The default scene sampled every 1 ms: 700 emission ticks, many waves
    // and tasks, echoes from three obstacles; plus a second seed.
    for seed in [1, 7] {
        let mut s = Scene { seed, ..Scene::default() };
        s.listeners[0].sampling = Sampling { period_ms: Some(1.0), random_ms: None };
        let one = run_on(1, &s);
        assert!(one.echoes.len() > 100, "{} echoes", one.echoes.len());
        for threads in [2, 5] {
            let many = run_on(threads, &s);
            // PartialEq on f64 fields; bits compared for the echoes' Δd.
            assert_eq!(one, many, "seed {seed}, {threads} threads");
            let bits = |o: &SimOutput| o.echoes.iter().map(|e| e.delta_d_m.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&one), bits(&many));
        }
    }
}
