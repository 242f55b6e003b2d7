//! Frequency sweeps (paper §II.A, Eq. 1–3).
//!
//! The paper's Eq. 1 writes `f_end + (f_start - f_end)(t - t_start)/T`, which
//! starts at `f_end`; its text and field set-up ("10 kHz to 0.2 kHz") use time
//! order. We use time order: `f(0) = f_start`, `f(T) = f_end`.
//!
//! Any strictly monotonic sweep works with the method: a listener that hears
//! the direct sound at `f_direct` and a reflection at `f_reflected` knows the
//! reflection left the source `Δt = τ(f_direct) − τ(f_reflected)` earlier,
//! where `τ` is the sweep's inverse (frequency → emission time).

use crate::error::{CoreError, Num};

/// A strictly monotonic frequency sweep of finite duration.
pub trait Sweep: Send + Sync + std::fmt::Debug {
    /// Frequency at the start of the sweep (Hz).
    fn f_start_hz(&self) -> f64;
    /// Frequency at the end of the sweep (Hz).
    fn f_end_hz(&self) -> f64;
    /// Sweep duration T (s).
    fn duration_s(&self) -> f64;
    /// Instantaneous frequency at `t_s` seconds after the sweep began; `None`
    /// outside `[0, T]`.
    fn freq_at(&self, t_s: f64) -> Option<f64>;
    /// Emission time (s after the start) of frequency `f_hz`; `None` if the
    /// sweep never plays it.
    fn time_of(&self, f_hz: f64) -> Option<f64>;
    /// Instantaneous phase (cycles) at `t_s` within the sweep; used to render waveforms.
    fn phase_cycles(&self, t_s: f64) -> f64;

    /// Emission-time gap between the direct and a reflected arrival heard at
    /// the same instant (paper Eq. 2, generalised). Positive when the
    /// reflection left earlier, as it must physically.
    fn delta_t_s(&self, f_direct_hz: f64, f_reflected_hz: f64) -> Option<f64> {
        Some(self.time_of(f_direct_hz)? - self.time_of(f_reflected_hz)?)
    }

    /// Path-length difference Δd = a·Δt (paper Eq. 3).
    fn delta_d_m(&self, f_direct_hz: f64, f_reflected_hz: f64, speed_of_sound_mps: f64) -> Option<f64> {
        self.delta_t_s(f_direct_hz, f_reflected_hz).map(|dt| dt * speed_of_sound_mps)
    }

    /// Frequency gap `f_reflected − f_direct` that a path difference `delta_d_m`
    /// produces when the direct sound is heard at `f_direct_hz`.
    fn gap_for_delta_d(&self, f_direct_hz: f64, delta_d_m: f64, speed_of_sound_mps: f64) -> Option<f64> {
        let t_direct = self.time_of(f_direct_hz)?;
        Some(self.freq_at(t_direct - delta_d_m / speed_of_sound_mps)? - f_direct_hz)
    }
}

fn validate(f_start_hz: f64, f_end_hz: f64, duration_s: f64) -> Result<(), CoreError> {
    for (name, v) in [("f_start", f_start_hz), ("f_end", f_end_hz), ("duration", duration_s)] {
        if !v.is_finite() || v <= 0.0 {
            return Err(CoreError::InvalidChirp(format!("{name} must be finite and > 0, got {}", Num(v))));
        }
    }
    if f_start_hz == f_end_hz {
        return Err(CoreError::InvalidChirp(format!(
            "f_start and f_end are both {f_start_hz} Hz; a sweep must change frequency"
        )));
    }
    Ok(())
}

/// Linear sweep, Eq. 1 in time order: `f(t) = f_start + (f_end − f_start)·t/T`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearChirp {
    f_start_hz: f64,
    f_end_hz: f64,
    duration_s: f64,
}

impl LinearChirp {
    /// A linear sweep from `f_start_hz` to `f_end_hz` (Hz) over `duration_s` (s).
    /// Errors unless both frequencies are finite and > 0, they differ, and the
    /// duration is finite and > 0.
    pub fn new(f_start_hz: f64, f_end_hz: f64, duration_s: f64) -> Result<Self, CoreError> {
        validate(f_start_hz, f_end_hz, duration_s)?;
        Ok(Self { f_start_hz, f_end_hz, duration_s })
    }

    /// Sweep rate (Hz/s), negative for a down-chirp.
    pub fn rate_hz_per_s(&self) -> f64 {
        (self.f_end_hz - self.f_start_hz) / self.duration_s
    }

    /// Eq. 2–3 with time order: Δd = a·|Δf|·T/|f_start − f_end|.
    pub fn delta_d_from_gap(&self, delta_f_hz: f64, speed_of_sound_mps: f64) -> f64 {
        speed_of_sound_mps * delta_f_hz.abs() * self.duration_s / (self.f_start_hz - self.f_end_hz).abs()
    }
}

impl Sweep for LinearChirp {
    fn f_start_hz(&self) -> f64 {
        self.f_start_hz
    }
    fn f_end_hz(&self) -> f64 {
        self.f_end_hz
    }
    fn duration_s(&self) -> f64 {
        self.duration_s
    }
    fn freq_at(&self, t_s: f64) -> Option<f64> {
        (0.0..=self.duration_s).contains(&t_s).then(|| self.f_start_hz + self.rate_hz_per_s() * t_s)
    }
    fn time_of(&self, f_hz: f64) -> Option<f64> {
        let (lo, hi) = min_max(self.f_start_hz, self.f_end_hz);
        (lo..=hi).contains(&f_hz).then(|| (f_hz - self.f_start_hz) / self.rate_hz_per_s())
    }
    fn phase_cycles(&self, t_s: f64) -> f64 {
        self.f_start_hz * t_s + 0.5 * self.rate_hz_per_s() * t_s * t_s
    }
}

/// Exponential (logarithmic) sweep: `f(t) = f_start·(f_end/f_start)^(t/T)`.
/// Equal ratios of frequency take equal times, so Δt depends on the ratio of
/// the two heard frequencies rather than their difference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExponentialChirp {
    f_start_hz: f64,
    f_end_hz: f64,
    duration_s: f64,
}

impl ExponentialChirp {
    /// An exponential sweep from `f_start_hz` to `f_end_hz` (Hz) over `duration_s` (s).
    /// Errors under the same conditions as [`LinearChirp::new`].
    pub fn new(f_start_hz: f64, f_end_hz: f64, duration_s: f64) -> Result<Self, CoreError> {
        validate(f_start_hz, f_end_hz, duration_s)?;
        Ok(Self { f_start_hz, f_end_hz, duration_s })
    }
    /// ln(f_end/f_start)/T, the log-frequency rate (1/s).
    fn k(&self) -> f64 {
        (self.f_end_hz / self.f_start_hz).ln() / self.duration_s
    }
}

impl Sweep for ExponentialChirp {
    fn f_start_hz(&self) -> f64 {
        self.f_start_hz
    }
    fn f_end_hz(&self) -> f64 {
        self.f_end_hz
    }
    fn duration_s(&self) -> f64 {
        self.duration_s
    }
    fn freq_at(&self, t_s: f64) -> Option<f64> {
        (0.0..=self.duration_s).contains(&t_s).then(|| self.f_start_hz * (self.k() * t_s).exp())
    }
    fn time_of(&self, f_hz: f64) -> Option<f64> {
        let (lo, hi) = min_max(self.f_start_hz, self.f_end_hz);
        (lo..=hi).contains(&f_hz).then(|| (f_hz / self.f_start_hz).ln() / self.k())
    }
    fn phase_cycles(&self, t_s: f64) -> f64 {
        self.f_start_hz * ((self.k() * t_s).exp() - 1.0) / self.k()
    }
}

/// Hyperbolic (linear-period) sweep: the period `1/f` changes linearly in
/// time, `1/f(t) = 1/f_start + (1/f_end − 1/f_start)·t/T`, the sweep of many
/// bats' FM calls (Altes & Titlebaum 1970, "Bat signals as optimally Doppler
/// tolerant waveforms"): a Doppler scaling of the whole call only shifts it in
/// time, so a matched filter keeps its peak for a moving listener.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HyperbolicChirp {
    f_start_hz: f64,
    f_end_hz: f64,
    duration_s: f64,
}

impl HyperbolicChirp {
    /// A linear-period sweep from `f_start_hz` to `f_end_hz` (Hz) over `duration_s` (s).
    /// Errors under the same conditions as [`LinearChirp::new`].
    pub fn new(f_start_hz: f64, f_end_hz: f64, duration_s: f64) -> Result<Self, CoreError> {
        validate(f_start_hz, f_end_hz, duration_s)?;
        Ok(Self { f_start_hz, f_end_hz, duration_s })
    }
    /// Rate of change of the period, (1/f_end − 1/f_start)/T (s/s).
    fn c(&self) -> f64 {
        (1.0 / self.f_end_hz - 1.0 / self.f_start_hz) / self.duration_s
    }
}

impl Sweep for HyperbolicChirp {
    fn f_start_hz(&self) -> f64 {
        self.f_start_hz
    }
    fn f_end_hz(&self) -> f64 {
        self.f_end_hz
    }
    fn duration_s(&self) -> f64 {
        self.duration_s
    }
    fn freq_at(&self, t_s: f64) -> Option<f64> {
        (0.0..=self.duration_s).contains(&t_s).then(|| 1.0 / (1.0 / self.f_start_hz + self.c() * t_s))
    }
    fn time_of(&self, f_hz: f64) -> Option<f64> {
        let (lo, hi) = min_max(self.f_start_hz, self.f_end_hz);
        (lo..=hi).contains(&f_hz).then(|| (1.0 / f_hz - 1.0 / self.f_start_hz) / self.c())
    }
    fn phase_cycles(&self, t_s: f64) -> f64 {
        // ∫ dt / (p0 + c·t) = ln(1 + c·t/p0) / c, p0 = 1/f_start.
        let c = self.c();
        (c * t_s * self.f_start_hz).ln_1p() / c
    }
}

fn min_max(a: f64, b: f64) -> (f64, f64) {
    if a < b { (a, b) } else { (b, a) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn linear_is_in_time_order() {
        let c = LinearChirp::new(10_000.0, 200.0, 0.5).unwrap();
        assert_eq!(c.freq_at(0.0), Some(10_000.0));
        assert!((c.freq_at(0.5).unwrap() - 200.0).abs() < 1e-9);
        assert!((c.freq_at(0.25).unwrap() - 5_100.0).abs() < 1e-9);
        assert_eq!(c.freq_at(0.51), None);
    }

    #[test]
    fn linear_gap_matches_paper_eq_2_3() {
        // Hand computation: Δf = 98 Hz on a 9800 Hz / 0.5 s sweep is 5 ms, 1.715 m.
        let c = LinearChirp::new(10_000.0, 200.0, 0.5).unwrap();
        assert!((c.delta_d_from_gap(98.0, 343.0) - 1.715).abs() < 1e-12);
        // Down-chirp: the reflection left earlier, so it is heard higher.
        let dd = c.delta_d_m(5_000.0, 5_098.0, 343.0).unwrap();
        assert!((dd - 1.715).abs() < 1e-9, "{dd}");
    }

    #[test]
    fn equal_frequencies_are_rejected() {
        assert!(LinearChirp::new(1000.0, 1000.0, 1.0).is_err());
        assert!(ExponentialChirp::new(1000.0, 0.0, 1.0).is_err());
        assert!(LinearChirp::new(1000.0, 200.0, f64::NAN).is_err());
    }

    #[test]
    fn exponential_passes_through_geometric_mean_at_half_time() {
        let c = ExponentialChirp::new(10_000.0, 100.0, 1.0).unwrap();
        assert!((c.freq_at(0.5).unwrap() - 1000.0).abs() < 1e-6);
        // A reflection 10 ms earlier is heard at f·(f_end/f_start)^(-0.01).
        let f_dir = 1000.0;
        let f_ref = f_dir * (100.0f64 / 10_000.0).powf(-0.01);
        assert!((c.delta_t_s(f_dir, f_ref).unwrap() - 0.01).abs() < 1e-9);
    }

    #[test]
    fn hyperbolic_period_is_linear_in_time() {
        // Hand computation: 1/f goes from 0.1 ms to 5 ms over 0.25 s, so at
        // t = 0.125 s the period is 2.55 ms (f = 392.157 Hz).
        let c = HyperbolicChirp::new(10_000.0, 200.0, 0.25).unwrap();
        assert!((c.freq_at(0.125).unwrap() - 1.0 / 2.55e-3).abs() < 1e-9);
        assert!((c.freq_at(0.25).unwrap() - 200.0).abs() < 1e-9);
        assert!((c.time_of(1.0 / 2.55e-3).unwrap() - 0.125).abs() < 1e-12);
        assert!(HyperbolicChirp::new(200.0, 0.0, 1.0).is_err());
    }

    /// The phase is the integral of the frequency: a central difference of
    /// `phase_cycles` (the naive oracle) equals `freq_at`.
    #[test]
    fn phases_differentiate_to_frequencies() {
        let sweeps: [Box<dyn Sweep>; 3] = [
            Box::new(LinearChirp::new(10_000.0, 200.0, 0.25).unwrap()),
            Box::new(ExponentialChirp::new(10_000.0, 200.0, 0.25).unwrap()),
            Box::new(HyperbolicChirp::new(200.0, 10_000.0, 0.25).unwrap()),
        ];
        for s in &sweeps {
            assert_eq!(s.phase_cycles(0.0), 0.0);
            for k in 1..50 {
                let t = 0.25 * f64::from(k) / 50.0;
                let h = 1e-6;
                let num = (s.phase_cycles(t + h) - s.phase_cycles(t - h)) / (2.0 * h);
                let f = s.freq_at(t).unwrap();
                assert!((num - f).abs() < 1e-5 * f, "{s:?} at {t}: {num} vs {f}");
            }
        }
    }

    proptest! {
        #[test]
        fn inverse_round_trips(fs in 100.0..20_000.0f64, fe in 100.0..20_000.0f64, t in 0.05..2.0f64, u in 0.0..1.0f64) {
            prop_assume!((fs - fe).abs() > 1.0);
            let sweeps: [Box<dyn Sweep>; 3] = [
                Box::new(LinearChirp::new(fs, fe, t).unwrap()),
                Box::new(ExponentialChirp::new(fs, fe, t).unwrap()),
                Box::new(HyperbolicChirp::new(fs, fe, t).unwrap()),
            ];
            for s in &sweeps {
                let time = u * t;
                let f = s.freq_at(time).unwrap();
                let back = s.time_of(f.clamp(fs.min(fe), fs.max(fe))).unwrap();
                prop_assert!((back - time).abs() < 1e-9 * t.max(1.0), "{s:?} {time} {back}");
            }
        }

        #[test]
        fn gap_and_delta_d_are_inverse(dd in 0.0..30.0f64, u in 0.3..0.9f64) {
            let s = LinearChirp::new(10_000.0, 200.0, 0.5).unwrap();
            let f_dir = s.freq_at(u * 0.5).unwrap();
            let gap = s.gap_for_delta_d(f_dir, dd, 343.0).unwrap();
            prop_assert!(gap >= 0.0);
            let back = s.delta_d_m(f_dir, f_dir + gap, 343.0).unwrap();
            prop_assert!((back - dd).abs() < 1e-9);
            prop_assert!((s.delta_d_from_gap(gap, 343.0) - dd).abs() < 1e-9);
        }
    }
}
