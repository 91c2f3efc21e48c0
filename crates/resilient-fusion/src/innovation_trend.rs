//! The velocity error a dead reckoning reveals to the GPS fixes it does not fuse, for the reset
//! that ends a long exclusion (module doc of [`crate::estimator`], step 5).
//!
//! While GPS is excluded the estimate moves on the IMU (and VO in Model II) alone, and the GPS
//! innovation against the prior, `r_k = p_k − p̂_{k|k−1}`, grows with the velocity error: over
//! a few seconds the accelerometer-bias error adds only `½ δb_a τ²`, so
//! `r(τ) ≈ δp + δv τ + noise`. The least-squares slope of the recent innovations is the
//! velocity error `δv`, the velocity a GNSS receiver would report is `v̂ + δv`, and the reset
//! can take it as PX4 EKF2 takes the receiver's velocity (`resetVelocityToGnss`) instead of
//! forgetting the velocity altogether.
//!
//! The slope is trusted only where the straight line explains the fixes: per axis, the residual
//! sum of squares divided by the GPS variance must pass the χ²_{n−2} 0.99 quantile. A burst
//! that starts or ends inside the window is a step, not a line: over 20 fixes of σ 0.5 m a step
//! larger than about 2.6 m in the middle of the window fails the test, and the reset then
//! forgets the velocity as at initialisation. A smaller step passes and biases the slope by
//! 1.5 times its size over the window's length (a 2.5 m step by about 1.9 m/s over 2 s). A
//! constant offset (a bias spoof) moves the intercept, not the slope; a drifting spoof adds its
//! rate, as the receiver's own velocity would. Only the trailing run of unfused fixes counts,
//! so the fit never spans two dead reckonings. The variance of the velocity is that of the
//! slope, with the residual variance no smaller than the GPS variance, plus what an
//! accelerometer-bias error of `σ_ba0` adds between the window's mean time and the reset.

use std::collections::VecDeque;

use ekf_residue::chi2::chi2_quantile;
use nalgebra::Vector3;

/// Fewest unfused fixes a slope is fitted on.
pub const MIN_FIXES: usize = 5;

/// A velocity for the reset: `v̂ + dv`, each axis with variance at most `var`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityCorrection {
    /// The velocity error of the estimate, m/s (ENU).
    pub dv: Vector3<f64>,
    /// Variance of the corrected velocity on each axis (the largest of the three), (m/s)².
    pub var: f64,
}

/// The GPS innovations of the recent fixes, each marked fused or not.
#[derive(Debug, Clone, Default)]
pub struct InnovationTrend {
    samples: VecDeque<(f64, Vector3<f64>, bool)>,
}

impl InnovationTrend {
    /// Record the innovation `r` of the fix at `t` (fused or not) and forget samples older than
    /// `keep_s` before it.
    pub fn push(&mut self, t: f64, r: Vector3<f64>, fused: bool, keep_s: f64) {
        self.samples.push_back((t, r, fused));
        while self.samples.front().is_some_and(|&(t0, ..)| t0 < t - keep_s - 1e-9) {
            self.samples.pop_front();
        }
    }

    /// Forget the samples at or after `t` (a rollback replays them).
    pub fn truncate_from(&mut self, t: f64) {
        while self.samples.back().is_some_and(|&(t1, ..)| t1 >= t - 1e-9) {
            self.samples.pop_back();
        }
    }

    /// The velocity error revealed by the trailing run of unfused fixes within `window_s` before
    /// `t` (one dead reckoning, never two), or `None` when they are fewer than [`MIN_FIXES`],
    /// span less than a quarter of the window, or a straight line does not explain them (module
    /// doc). `gps_sigma_m` is the fix's σ per axis, `sigma_ba0` the accelerometer-bias σ (m/s²).
    #[must_use]
    pub fn velocity_correction(
        &self,
        t: f64,
        window_s: f64,
        gps_sigma_m: &[f64; 3],
        sigma_ba0: f64,
    ) -> Option<VelocityCorrection> {
        let mut pts: Vec<(f64, Vector3<f64>)> = self
            .samples
            .iter()
            .rev()
            .skip_while(|&&(ti, ..)| ti > t + 1e-9)
            .take_while(|&&(ti, _, fused)| !fused && ti >= t - window_s - 1e-9)
            .map(|&(ti, r, _)| (ti, r))
            .collect();
        pts.reverse();
        let n = pts.len();
        if n < MIN_FIXES || pts[n - 1].0 - pts[0].0 < 0.25 * window_s {
            return None;
        }
        let t_mean = pts.iter().map(|p| p.0).sum::<f64>() / n as f64;
        let r_mean = pts.iter().map(|p| p.1).sum::<Vector3<f64>>() / n as f64;
        let sxx: f64 = pts.iter().map(|p| (p.0 - t_mean).powi(2)).sum();
        if sxx <= 0.0 || !sxx.is_finite() {
            return None;
        }
        let dv = pts.iter().map(|p| (p.1 - r_mean) * (p.0 - t_mean)).sum::<Vector3<f64>>() / sxx;
        let gate = chi2_quantile((n - 2) as f64, 0.99)?;
        let lever = t - t_mean;
        let mut var: f64 = 0.0;
        for (a, sigma) in gps_sigma_m.iter().enumerate() {
            let rss: f64 = pts.iter().map(|p| (p.1[a] - r_mean[a] - dv[a] * (p.0 - t_mean)).powi(2)).sum();
            let r_var = sigma * sigma;
            if !(rss.is_finite() && rss / r_var <= gate) {
                return None;
            }
            let resid_var = (rss / (n - 2) as f64).max(r_var);
            var = var.max(resid_var / sxx + (sigma_ba0 * lever).powi(2));
        }
        dv.iter().all(|v| v.is_finite()).then_some(VelocityCorrection { dv, var })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIGMA: [f64; 3] = [0.5, 0.5, 0.75];

    fn trend(f: impl Fn(f64) -> Vector3<f64>, n: usize, fused: bool) -> InnovationTrend {
        let mut tr = InnovationTrend::default();
        for k in 0..n {
            let t = 10.0 + 0.1 * k as f64;
            tr.push(t, f(t), fused, 5.0);
        }
        tr
    }

    #[test]
    fn a_linear_drift_gives_its_slope_with_a_small_variance() {
        let v = Vector3::new(1.5, -0.7, 0.2);
        // ±0.15 m of alternating noise on every axis.
        let tr = trend(
            |t| {
                Vector3::new(3.0, -2.0, 1.0)
                    + v * (t - 10.0)
                    + Vector3::repeat(0.3 * (t * 10.0).round().rem_euclid(2.0) - 0.15)
            },
            21,
            false,
        );
        let c = tr.velocity_correction(12.0, 2.0, &SIGMA, 0.44).unwrap();
        assert!((c.dv - v).norm() < 0.1, "{:?}", c.dv);
        assert!(c.var > 0.0 && c.var < 0.5, "{}", c.var);
    }

    #[test]
    fn a_constant_offset_reveals_no_velocity_error() {
        let tr = trend(|_| Vector3::new(10.0, 10.0, 0.0), 20, false);
        let c = tr.velocity_correction(12.0, 2.0, &SIGMA, 0.44).unwrap();
        assert!(c.dv.norm() < 1e-9);
    }

    #[test]
    fn a_step_inside_the_window_is_not_a_velocity() {
        let tr = trend(|t| if t < 11.0 { Vector3::zeros() } else { Vector3::new(20.0, 0.0, 0.0) }, 20, false);
        assert!(tr.velocity_correction(12.0, 2.0, &SIGMA, 0.44).is_none());
    }

    #[test]
    fn fused_fixes_and_too_few_fixes_give_nothing() {
        let tr = trend(Vector3::repeat, 20, true);
        assert!(tr.velocity_correction(12.0, 2.0, &SIGMA, 0.44).is_none());
        let tr = trend(Vector3::repeat, MIN_FIXES - 1, false);
        assert!(tr.velocity_correction(12.0, 2.0, &SIGMA, 0.44).is_none());
        // Five fixes within 4 ms span too little time for a slope.
        let mut tr = InnovationTrend::default();
        for k in 0..5 {
            tr.push(12.0 - 1e-3 * f64::from(k), Vector3::repeat(f64::from(k)), false, 5.0);
        }
        assert!(tr.velocity_correction(12.0, 2.0, &SIGMA, 0.44).is_none());
    }

    #[test]
    fn only_the_trailing_run_of_unfused_fixes_counts() {
        // Unfused fixes drifting at 3 m/s, one fused fix, then ten unfused ones at rest: the
        // slope is that of the last run alone.
        let mut tr = InnovationTrend::default();
        for k in 0..20 {
            let t = 10.0 + 0.1 * f64::from(k);
            let (r, fused) = match k {
                0..9 => (Vector3::new(3.0 * t, 0.0, 0.0), false),
                9 => (Vector3::zeros(), true),
                _ => (Vector3::new(5.0, 0.0, 0.0), false),
            };
            tr.push(t, r, fused, 5.0);
        }
        let c = tr.velocity_correction(12.0, 2.0, &SIGMA, 0.44).unwrap();
        assert!(c.dv.norm() < 1e-9, "{:?}", c.dv);
    }

    #[test]
    fn the_variance_adds_the_accelerometer_bias_over_the_lever_to_the_reset() {
        let tr = trend(Vector3::repeat, 20, false);
        let with_ba = tr.velocity_correction(11.9, 2.0, &SIGMA, 0.44).unwrap();
        let without = tr.velocity_correction(11.9, 2.0, &SIGMA, 0.0).unwrap();
        // σ_ba0 times the time from the window's mean (10.95 s) to the reset.
        assert!((with_ba.var - without.var - (0.44f64 * 0.95).powi(2)).abs() < 1e-9);
    }

    #[test]
    fn truncation_drops_the_replayed_samples() {
        let mut tr = trend(Vector3::repeat, 20, false);
        tr.truncate_from(11.0);
        assert_eq!(tr.samples.len(), 10);
        assert!(tr.samples.back().unwrap().0 < 11.0);
    }
}
