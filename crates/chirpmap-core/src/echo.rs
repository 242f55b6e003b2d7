//! `Echo`: one candidate ellipse, the narrow waist between sensors and mappers.

use crate::ellipse::Ellipse;
use crate::error::{CoreError, finite};
use crate::geometry::Point;

/// One reflection heard by one listener at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Echo {
    pub source: Point,
    pub listener: Point,
    /// Path-length difference Δd (m).
    pub delta_d_m: f64,
    /// Weight added to every cell the ellipse enters (paper: peak intensity).
    pub weight: f64,
    /// Measurement time (s).
    pub t_s: f64,
    /// Listener id.
    pub listener_id: u32,
}

impl Echo {
    /// Validates every field: finite numbers, Δd ≥ 0, weight ≥ 0, distinct foci.
    pub fn new(
        source: Point,
        listener: Point,
        delta_d_m: f64,
        weight: f64,
        t_s: f64,
        listener_id: u32,
    ) -> Result<Self, CoreError> {
        finite("weight", weight)?;
        finite("t", t_s)?;
        if weight < 0.0 {
            return Err(CoreError::InvalidParam { field: "weight", reason: format!("must be >= 0, got {weight}") });
        }
        let echo = Self { source, listener, delta_d_m, weight, t_s, listener_id };
        echo.ellipse()?;
        Ok(echo)
    }

    pub fn ellipse(&self) -> Result<Ellipse, CoreError> {
        Ellipse::new(self.source, self.listener, self.delta_d_m)
    }
}
