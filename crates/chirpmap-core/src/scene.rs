//! The scene file (TOML). Every field has a default, so an empty file is the
//! paper's default scene (DESIGN.md, "Parameters"). Unknown keys are errors.

use crate::chirp::{ExponentialChirp, LinearChirp, Sweep};
use crate::error::CoreError;
use crate::geometry::{Circle, Obstacle, Point, Polygon, Shape};
use crate::mapper::MappingParams;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Scene {
    /// Master seed of the run's random stream (DESIGN.md: `ChaCha8Rng::seed_from_u64(seed)`).
    pub seed: u64,
    /// Run index: the stream of the master generator (`set_stream(run_index)`), so run i of a
    /// sweep draws the same obstacles in every configuration (paper §III).
    pub run_index: u64,
    /// Simulated time (s) from the start of the chirp. Default (absent): the chirp duration plus
    /// the time sound needs to cross the world from the source to its farthest corner.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    pub world: World,
    pub chirp: ChirpSpec,
    pub source: SourceSpec,
    pub particles: ParticleSpec,
    /// Explicit obstacles; when empty, `random_obstacles` generates them.
    pub obstacles: Vec<ObstacleSpec>,
    pub random_obstacles: RandomObstacles,
    pub listeners: Vec<ListenerSpec>,
    pub mapping: MappingParams,
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            seed: 1,
            run_index: 0,
            duration_s: None,
            world: World::default(),
            chirp: ChirpSpec::default(),
            source: SourceSpec::default(),
            particles: ParticleSpec::default(),
            obstacles: Vec::new(),
            random_obstacles: RandomObstacles::default(),
            listeners: vec![ListenerSpec::default()],
            mapping: MappingParams::default(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct World {
    /// Speed of sound a (m/s). Paper: 343.
    pub speed_of_sound: f64,
    /// `[xmin, ymin, xmax, ymax]` (m): particles leave here; the map covers it.
    pub bounds: [f64; 4],
}

impl Default for World {
    fn default() -> Self {
        Self { speed_of_sound: 343.0, bounds: [-50.0, -50.0, 50.0, 50.0] }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SweepKind {
    #[default]
    Linear,
    Exponential,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChirpSpec {
    pub f_start: f64,
    pub f_end: f64,
    /// Sweep duration T (s).
    pub duration: f64,
    pub kind: SweepKind,
}

impl Default for ChirpSpec {
    fn default() -> Self {
        Self { f_start: 10_000.0, f_end: 200.0, duration: 0.5, kind: SweepKind::Linear }
    }
}

impl ChirpSpec {
    pub fn build(&self) -> Result<Box<dyn Sweep>, CoreError> {
        Ok(match self.kind {
            SweepKind::Linear => Box::new(LinearChirp::new(self.f_start, self.f_end, self.duration)?),
            SweepKind::Exponential => Box::new(ExponentialChirp::new(self.f_start, self.f_end, self.duration)?),
        })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SourceSpec {
    pub position: [f64; 2],
}

impl Default for SourceSpec {
    fn default() -> Self {
        Self { position: [0.0, 0.0] }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ParticleSpec {
    /// Particles emitted per tick. Paper: 3600.
    pub per_tick: u32,
    /// Tick length (ms). Paper: 1.
    pub tick_ms: f64,
    /// Shift heard frequencies by the listener's motion (paper: supported, off).
    pub doppler: bool,
    /// Particles quieter than this (relative to emission) are dropped.
    pub min_loudness: f64,
}

impl Default for ParticleSpec {
    fn default() -> Self {
        Self { per_tick: 3600, tick_ms: 1.0, doppler: false, min_loudness: 1e-3 }
    }
}

/// A circle (`center` + `radius`) or a polygon (`vertices`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 2]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vertices: Option<Vec<[f64; 2]>>,
    #[serde(default = "default_roughness")]
    pub roughness: f64,
    #[serde(default = "default_absorption")]
    pub absorption: f64,
}

fn default_roughness() -> f64 {
    0.1
}
fn default_absorption() -> f64 {
    0.2
}

impl ObstacleSpec {
    pub fn circle(center: Point, radius_m: f64) -> Self {
        Self {
            center: Some([center.x, center.y]),
            radius: Some(radius_m),
            vertices: None,
            roughness: default_roughness(),
            absorption: default_absorption(),
        }
    }

    pub fn build(&self, index: usize) -> Result<Obstacle, CoreError> {
        let ctx = |msg: String| CoreError::InvalidScene(format!("obstacles[{index}]: {msg}"));
        for (name, v) in [("roughness", self.roughness), ("absorption", self.absorption)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(ctx(format!("{name} must be in [0, 1], got {v}")));
            }
        }
        let shape = match (&self.center, self.radius, &self.vertices) {
            (Some(c), Some(r), None) => {
                Shape::Circle(Circle::new(Point::new(c[0], c[1]), r).map_err(|e| ctx(e.to_string()))?)
            }
            (None, None, Some(v)) => Shape::Polygon(
                Polygon::new(v.iter().map(|p| Point::new(p[0], p[1])).collect()).map_err(|e| ctx(e.to_string()))?,
            ),
            _ => return Err(ctx("give either `center` and `radius` (circle) or `vertices` (polygon)".into())),
        };
        Ok(Obstacle { shape, roughness: self.roughness, absorption: self.absorption })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RandomObstacles {
    pub count: u32,
    /// Diameter range (m). Paper: U(5, 10).
    pub diameter: [f64; 2],
    /// Region for centres `[xmin, ymin, xmax, ymax]` (m).
    pub region: [f64; 4],
    pub roughness: f64,
    pub absorption: f64,
}

impl Default for RandomObstacles {
    fn default() -> Self {
        Self { count: 3, diameter: [5.0, 10.0], region: [-20.0, -35.0, 20.0, -10.0], roughness: 0.1, absorption: 0.2 }
    }
}

/// How often a listener measures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sampling {
    /// Constant period (ms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub period_ms: Option<f64>,
    /// Uniformly random period range (ms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub random_ms: Option<[f64; 2]>,
}

impl Default for Sampling {
    fn default() -> Self {
        Self { period_ms: Some(10.0), random_ms: None }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ListenerSpec {
    pub start: [f64; 2],
    pub heading_deg: f64,
    /// m/s. Paper: 10.
    pub speed: f64,
    /// rad/s; positive turns counter-clockwise. Paper: 0 or π/4.
    pub spin_rate: f64,
    /// Detection radius (m).
    pub radius: f64,
    pub sampling: Sampling,
}

impl Default for ListenerSpec {
    fn default() -> Self {
        Self {
            start: [-3.0, 10.0],
            heading_deg: 0.0,
            speed: 10.0,
            spin_rate: 0.0,
            radius: 0.5,
            sampling: Sampling::default(),
        }
    }
}

impl Scene {
    /// Parses a scene; TOML errors carry line and column.
    pub fn from_toml_str(text: &str) -> Result<Self, CoreError> {
        toml::from_str(text).map_err(|e| CoreError::InvalidScene(e.to_string()))
    }

    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# could not serialise scene: {e}\n"))
    }

    pub fn source_position(&self) -> Point {
        Point::new(self.source.position[0], self.source.position[1])
    }

    /// The explicitly listed obstacles, validated.
    pub fn explicit_obstacles(&self) -> Result<Vec<Obstacle>, CoreError> {
        self.obstacles.iter().enumerate().map(|(i, o)| o.build(i)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_file_is_default_scene() {
        assert_eq!(Scene::from_toml_str("").unwrap(), Scene::default());
    }

    #[test]
    fn unknown_keys_are_errors_with_position() {
        let err = Scene::from_toml_str("[world]\nspeed_of_sond = 1.0\n").unwrap_err().to_string();
        assert!(err.contains("speed_of_sond") && err.contains("line 2"), "{err}");
    }

    #[test]
    fn round_trips_through_toml() {
        let mut s = Scene::default();
        s.obstacles.push(ObstacleSpec::circle(Point::new(1.0, -20.0), 3.0));
        s.obstacles.push(ObstacleSpec {
            center: None,
            radius: None,
            vertices: Some(vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]),
            roughness: 0.0,
            absorption: 0.5,
        });
        s.listeners[0].sampling = Sampling { period_ms: None, random_ms: Some([10.0, 100.0]) };
        let back = Scene::from_toml_str(&s.to_toml_string()).unwrap();
        assert_eq!(back, s);
        assert_eq!(back.explicit_obstacles().unwrap().len(), 2);
    }

    #[test]
    fn half_specified_obstacle_is_an_error() {
        let s = Scene::from_toml_str("[[obstacles]]\ncenter = [1.0, 2.0]\n").unwrap();
        let err = s.explicit_obstacles().unwrap_err().to_string();
        assert!(err.contains("obstacles[0]"), "{err}");
    }
}
