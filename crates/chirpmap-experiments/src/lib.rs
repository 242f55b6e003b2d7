//! Sweeps over scene parameters that reproduce the paper's Tables I and II
//! (§III.B, §III.C): definitions and presets, a parallel resumable runner,
//! sharding, merging and summaries with 95 % confidence intervals.
//!
//! Run `i` of every configuration uses the random stream
//! `ChaCha8Rng::seed_from_u64(master)` + `set_stream(i)`, so results depend on
//! neither thread count nor shard split, and run `i` sees the same obstacles in
//! every configuration (the paper relies on this).

#![warn(missing_docs)]

pub mod doppler;
pub mod driver;
pub mod error;
pub mod maps;
pub mod pipeline;
pub mod presets;
pub mod runner;
pub mod runs;
pub mod stats;
pub mod summary;
pub mod sweep;

pub use error::ExperimentError;
pub use runs::{RunMetrics, RunRow, RunsFile};
pub use sweep::{Config, Job, Param, Plan, Shard, SweepDef};
