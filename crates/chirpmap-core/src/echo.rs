//! `Echo`: one candidate ellipse, the narrow waist between sensors and mappers.

use crate::ellipse::Ellipse;
use crate::error::{CoreError, finite};
use crate::geometry::Point;

/// Largest 1-σ Δd uncertainty an echo may carry (m): no larger than the
/// largest coordinate accepted ([`crate::geometry::MAX_COORD_M`]). The
/// evidence mapper's bands reach Δd ± 10σ, and σ = 1e300 made it fail on an
/// invalid ellipse of Δd 3e300 that named neither the echo nor `sigma_m`.
pub const MAX_SIGMA_M: f64 = crate::geometry::MAX_COORD_M;

/// One reflection heard by one listener at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Echo {
    /// Where the chirp was emitted (one focus of the ellipse), world frame (m).
    pub source: Point,
    /// Where the echo was heard (the other focus), world frame (m).
    pub listener: Point,
    /// Path-length difference Δd (m).
    pub delta_d_m: f64,
    /// Weight added to every cell the ellipse enters (paper: peak intensity).
    pub weight: f64,
    /// Measurement time (s).
    pub t_s: f64,
    /// Listener id.
    pub listener_id: u32,
    /// 1-σ uncertainty of `delta_d_m` (m), from the ranging method (issue 9,
    /// item 1). `None`: the mapper's default applies (the evidence mapper's
    /// `default_sigma_m`); Algorithm 1 ignores it.
    pub sigma_m: Option<f64>,
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
        let echo = Self { source, listener, delta_d_m, weight, t_s, listener_id, sigma_m: None };
        echo.ellipse()?;
        Ok(echo)
    }

    /// The same echo with a known 1-σ Δd uncertainty (m): finite, > 0 and at
    /// most [`MAX_SIGMA_M`].
    pub fn with_sigma_m(self, sigma_m: f64) -> Result<Self, CoreError> {
        finite("sigma", sigma_m)?;
        if sigma_m <= 0.0 {
            return Err(CoreError::InvalidParam { field: "sigma", reason: format!("must be > 0 m, got {sigma_m}") });
        }
        if sigma_m > MAX_SIGMA_M {
            return Err(CoreError::InvalidParam {
                field: "sigma",
                reason: format!(
                    "must be at most {} m, got {}",
                    crate::error::Num(MAX_SIGMA_M),
                    crate::error::Num(sigma_m)
                ),
            });
        }
        Ok(Self { sigma_m: Some(sigma_m), ..self })
    }

    /// The acoustic ellipse of this echo (paper Eq. 4): foci at source and
    /// listener, path-length sum `D + Δd`. Errors if the foci coincide or Δd is
    /// negative or not finite.
    pub fn ellipse(&self) -> Result<Ellipse, CoreError> {
        Ellipse::new(self.source, self.listener, self.delta_d_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigma_defaults_to_none_and_is_validated() {
        let e = Echo::new(Point::new(0.0, 0.0), Point::new(1.0, 0.0), 0.5, 1.0, 0.0, 0).expect("valid echo");
        assert_eq!(e.sigma_m, None);
        assert_eq!(e.with_sigma_m(0.02).map(|e| e.sigma_m), Ok(Some(0.02)));
        assert_eq!(e.with_sigma_m(MAX_SIGMA_M).map(|e| e.sigma_m), Ok(Some(MAX_SIGMA_M)));
        assert!(e.with_sigma_m(1e300).is_err(), "σ = 1e300 made the evidence mapper fail naming no echo");
        assert!(e.with_sigma_m(0.0).is_err());
        assert!(e.with_sigma_m(-1.0).is_err());
        assert!(e.with_sigma_m(f64::NAN).is_err());
    }
}
