//! Summary statistics of per-chirp estimates (paper §IV.B: the median per
//! configuration with a 95 % confidence interval).

/// Median of finite values; `None` when there are none.
pub fn median(values: &[f64]) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) })
}

/// Distribution-free 95 % confidence interval of the median: the order
/// statistics at ranks n/2 ∓ 1.96·√n/2 (normal approximation of the
/// binomial; the paper does not say how its interval was computed).
/// With fewer than 6 values the interval is [min, max].
pub fn median_ci95(values: &[f64]) -> Option<[f64; 2]> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n < 6 {
        return Some([v[0], v[n - 1]]);
    }
    let nf = n as f64;
    let half = 1.96 * nf.sqrt() / 2.0;
    let lo = ((nf / 2.0 - half).floor().max(1.0) as usize) - 1;
    let hi = ((nf / 2.0 + half).ceil() as usize).min(n) - 1;
    Some([v[lo], v[hi]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_ci() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
        assert_eq!(median(&[f64::NAN]), None);
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        // n = 100: ranks 50 ∓ 9.8 → the 40th (floor 40.2) and 60th (ceil 59.8) values.
        assert_eq!(median_ci95(&v), Some([40.0, 60.0]));
    }
}
