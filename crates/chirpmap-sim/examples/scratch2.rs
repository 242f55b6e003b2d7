#![allow(clippy::unwrap_used)]
use chirpmap_core::scene::{ObstacleSpec, Sampling};
use chirpmap_core::{Point, Scene};
use chirpmap_sim::{resolve, simulate};
fn main() {
    let mut s = Scene::default();
    s.random_obstacles.count = 0;
    s.listeners[0].sampling = Sampling { period_ms: Some(10.0), random_ms: None };
    s.listeners[0].heading_deg = std::env::args().nth(1).unwrap().parse().unwrap();
    let rough: f64 = std::env::args().nth(2).unwrap().parse().unwrap();
    s.obstacles = vec![ObstacleSpec { center: None, radius: None, vertices: Some(vec![[-45.0, -20.0], [45.0, -20.0], [45.0, -21.0], [-45.0, -21.0]]), roughness: rough, absorption: 0.2 }];
    let out = simulate(&resolve(&s).unwrap());
    for e in &out.echoes {
        let spec = e.listener.dist(Point::new(0.0, -40.0)) - e.listener.dist(Point::new(0.0, 0.0));
        println!("t={:.2} L=({:.2},{:.2}) dd={:.2} spec={:.2} w={:.1}", e.t_s, e.listener.x, e.listener.y, e.delta_d_m, spec, e.weight);
    }
}
