//! The paper's 2D particle audio simulator (§II.B), built to be both faithful
//! and fast.
//!
//! Every tick the Source emits `per_tick` particles evenly around a circle with
//! a random angular offset; each carries the chirp's frequency at emission and
//! a loudness, flies at the speed of sound, reflects off obstacles (roughness
//! perturbs the outgoing angle, absorption scales the loudness) and leaves when
//! it exits the world or becomes too quiet. A Listener senses every particle
//! within its radius, bins them by frequency into a spectrum, finds the peaks,
//! identifies the direct one by prediction and turns every other peak into an
//! [`Echo`](chirpmap_core::Echo).
//!
//! Two implementations of that same model live here:
//! - [`simulate`] (the fast one) traces each particle's path once, at
//!   emission, and for each straight segment computes the ticks in which it
//!   can be inside a listener's disc, testing only those;
//! - [`oracle::simulate_stepped`] steps every particle every tick, as the
//!   paper's Matlab simulator does; tests show both sense the same particles.
//!
//! No I/O and no printing happens here.

#![warn(missing_docs)]

pub mod analysis;
/// Error type of the simulator.
pub mod error;
pub mod fast;
pub mod oracle;
pub mod physics;
pub mod resolve;
pub mod rng;
pub mod trajectory;

pub use analysis::{Measurement, Peak, SimOutput, Spectra, analyse, analyse_spectra};
pub use error::SimError;
pub use fast::{sense_fast, simulate};
pub use resolve::{BIN_HZ, ListenerPlan, Resolved, resolve};
pub use trajectory::Trajectory;

/// One particle sensed by one listener at one measurement instant: the raw
/// material of a spectrum, and what the oracle tests compare.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensed {
    /// Global measurement index (into [`Resolved::measurement_count`] order).
    pub measurement: u32,
    /// Particle id: `emission_tick · per_tick + index_in_tick`.
    pub particle: u64,
    /// Heard frequency (Hz): emission frequency, Doppler-shifted if enabled.
    pub freq_hz: f64,
    /// Loudness relative to emission (1 at emission), after absorption at each bounce.
    pub loudness: f64,
    /// Distance from the listener's centre (m), to judge boundary cases.
    pub dist_m: f64,
}
