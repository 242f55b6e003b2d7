//! Core of chirpmap: the chirp model (paper Eq. 1–3), planar geometry, the
//! acoustic ellipse (Eq. 4), mappers (Algorithm 1), highlight extraction and
//! the scores of §III.A. No I/O and no printing happens here.

#![warn(missing_docs)]

pub mod chirp;
pub mod echo;
pub mod ellipse;
/// Error type of the core library.
pub mod error;
pub mod evidence;
pub mod exact;
pub mod geometry;
pub mod grid;
pub mod mapper;
pub mod metrics;
pub mod raster;
pub mod scene;
pub mod scores;

pub use chirp::{ExponentialChirp, LinearChirp, Sweep};
pub use echo::Echo;
pub use ellipse::Ellipse;
pub use error::CoreError;
pub use evidence::{EvidenceMap, EvidenceParams, Surface, SurfaceKind, map_evidence};
pub use geometry::{Circle, Obstacle, Point, Polygon, Ray, Shape};
pub use grid::{Grid, GridSpec};
pub use mapper::{AccumulationMapper, Highlight, Mapper, MapperKind, MappingParams};
pub use scene::Scene;
pub use scores::{score_highlight, score_obstacle};
