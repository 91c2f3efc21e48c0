//! Distribution functions the textbook thresholds need: chi-squared CDF and quantile, standard
//! normal CDF, and the Markov-chain false-alarm rate of the CUSUM detector (Murguia & Ruths,
//! CCA 2016, and "Characterization of Model-Based Detectors for CPS Sensor Faults/Attacks",
//! arXiv 1710.04407).
//!
//! The χ² distribution itself lives with the filter's innovations ([`ekf_residue::chi2`]) and
//! is re-exported here.

use ekf_residue::chi2::bisect;
pub use ekf_residue::chi2::{chi2_cdf, gamma_p, ln_gamma};

use crate::error::{BaselineError, Result};

/// The `p`-quantile of chi-squared with `dof` degrees of freedom
/// ([`ekf_residue::chi2::chi2_quantile`]), e.g. `chi2_quantile(6.0, 0.99) ≈ 16.812` (the 1 %
/// false-alarm threshold of a 6-channel NIS test).
///
/// # Errors
/// [`BaselineError::Config`] unless `dof > 0` and `0 < p < 1`.
pub fn chi2_quantile(dof: f64, p: f64) -> Result<f64> {
    if !(dof > 0.0 && dof.is_finite()) {
        return Err(BaselineError::Config { field: "dof", msg: format!("must be positive, got {dof}") });
    }
    ekf_residue::chi2::chi2_quantile(dof, p)
        .ok_or_else(|| BaselineError::Config { field: "p", msg: format!("must lie in (0, 1), got {p}") })
}

/// Standard normal CDF `Φ(x)`, via `P(1/2, x²/2)`.
pub fn normal_cdf(x: f64) -> f64 {
    let half = 0.5 * gamma_p(0.5, 0.5 * x * x);
    if x >= 0.0 { 0.5 + half } else { 0.5 - half }
}

/// Stationary alarm probability per step of the CUSUM `S_k = max(0, S_{k−1} + z_k − b)` with
/// alarm and reset to 0 above `tau`, when the `z_k` are i.i.d. with CDF `cdf` (Murguia & Ruths'
/// Markov-chain approximation).
///
/// The state space is the atom `S = 0` plus `n_bins` equal bins on `(0, tau]`, each represented
/// by its midpoint. From state `s`: `P(next = 0) = F(b − s)`, bin `j` gets
/// `F(hi_j + b − s) − F(lo_j + b − s)`, and `1 − F(tau + b − s)` is the alarm probability (the
/// chain then restarts at 0). The stationary distribution comes from power iteration; the rate
/// is `Σ_i π_i · alarm_i`. Checked against Monte Carlo in the tests.
pub fn cusum_false_alarm_rate(cdf: &dyn Fn(f64) -> f64, b: f64, tau: f64, n_bins: usize) -> f64 {
    let n_bins = n_bins.max(1);
    let n = n_bins + 1;
    let width = tau / n_bins as f64;
    let state = |i: usize| if i == 0 { 0.0 } else { (i as f64 - 0.5) * width };
    // Row-major transition matrix over the non-alarm successors, plus the alarm column.
    let mut trans = vec![0.0; n * n];
    let mut alarm = vec![0.0; n];
    for i in 0..n {
        let s = state(i);
        trans[i * n] = cdf(b - s);
        for j in 1..n {
            let lo = (j - 1) as f64 * width;
            let hi = j as f64 * width;
            trans[i * n + j] = cdf(hi + b - s) - cdf(lo + b - s);
        }
        alarm[i] = 1.0 - cdf(tau + b - s);
        // After an alarm the statistic is reset to 0.
        trans[i * n] += alarm[i];
    }
    let mut pi = vec![1.0 / n as f64; n];
    let mut next = vec![0.0; n];
    for _ in 0..10_000 {
        next.iter_mut().for_each(|v| *v = 0.0);
        for i in 0..n {
            let p = pi[i];
            if p == 0.0 {
                continue;
            }
            for j in 0..n {
                next[j] += p * trans[i * n + j];
            }
        }
        let total: f64 = next.iter().sum();
        let mut diff = 0.0;
        for (p, q) in pi.iter_mut().zip(&next) {
            let q = q / total;
            diff += (*p - q).abs();
            *p = q;
        }
        if diff < 1e-13 {
            break;
        }
    }
    pi.iter().zip(&alarm).map(|(p, a)| p * a).sum()
}

/// The CUSUM threshold `tau` whose Markov-chain false-alarm rate is `far` at bias `b`, by
/// bisection (the rate falls monotonically in `tau`).
///
/// # Errors
/// [`BaselineError::Config`] unless `0 < far < 1` and `b > 0`, or when no `tau ≤ 1e6` reaches
/// the target (drift `E[z] − b` not negative).
pub fn cusum_tau_for_far(cdf: &dyn Fn(f64) -> f64, b: f64, far: f64, n_bins: usize) -> Result<f64> {
    if !(far > 0.0 && far < 1.0) {
        return Err(BaselineError::Config { field: "far", msg: format!("must lie in (0, 1), got {far}") });
    }
    if !(b > 0.0 && b.is_finite()) {
        return Err(BaselineError::Config { field: "b", msg: format!("must be positive, got {b}") });
    }
    let mut hi = b.max(1.0);
    while cusum_false_alarm_rate(cdf, b, hi, n_bins) > far {
        hi *= 2.0;
        if hi > 1e6 {
            return Err(BaselineError::Config {
                field: "b",
                msg: format!("no threshold reaches a false-alarm rate of {far} at b = {b} (is b > E[z_k]?)"),
            });
        }
    }
    // Decreasing in tau: bisect on far − rate, which increases with tau.
    Ok(bisect(|tau| far - cusum_false_alarm_rate(cdf, b, tau, n_bins), 0.0, hi))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn chi2_quantiles_match_tables() {
        // Reference values: standard χ² tables (3 decimals).
        for (dof, p, q) in
            [(1.0, 0.99, 6.635), (3.0, 0.99, 11.345), (6.0, 0.99, 16.812), (6.0, 0.95, 12.592), (9.0, 0.999, 27.877)]
        {
            assert_relative_eq!(chi2_quantile(dof, p).unwrap(), q, epsilon = 1.5e-3);
        }
        assert!(chi2_quantile(0.0, 0.5).is_err());
        assert!(chi2_quantile(3.0, 1.0).is_err());
    }

    #[test]
    fn normal_cdf_known_points() {
        assert_relative_eq!(normal_cdf(0.0), 0.5, epsilon = 1e-14);
        assert_relative_eq!(normal_cdf(1.959_963_984_540_054), 0.975, epsilon = 1e-12);
        assert_relative_eq!(normal_cdf(-3.0), 0.001_349_898_031_630_094_6, max_relative = 1e-9);
    }

    #[test]
    fn cusum_markov_chain_matches_reference_and_monte_carlo() {
        // Reference: (m, b, tau) = (3, 4, 10) → 0.0108; (6, 8, 10) → 0.0149, from a 4·10⁵-step
        // Monte Carlo run of the same recursion.
        let f3 = |x: f64| chi2_cdf(3.0, x);
        let f6 = |x: f64| chi2_cdf(6.0, x);
        assert_relative_eq!(cusum_false_alarm_rate(&f3, 4.0, 10.0, 150), 0.0108, max_relative = 0.05);
        assert_relative_eq!(cusum_false_alarm_rate(&f6, 8.0, 10.0, 150), 0.0149, max_relative = 0.05);
        // Monte Carlo of the same recursion with chi2_3 increments (seeded, 200k steps).
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let (mut s, mut alarms, n) = (0.0_f64, 0usize, 200_000);
        for _ in 0..n {
            let z: f64 = (0..3).map(|_| gaussian(&mut rng).powi(2)).sum();
            s = (s + z - 4.0).max(0.0);
            if s > 10.0 {
                alarms += 1;
                s = 0.0;
            }
        }
        assert_relative_eq!(alarms as f64 / n as f64, 0.0108, max_relative = 0.15);
        let tau = cusum_tau_for_far(&f3, 4.0, 0.0108, 150).unwrap();
        assert_relative_eq!(tau, 10.0, max_relative = 0.05);
        assert!(cusum_tau_for_far(&f3, 4.0, 1.5, 50).is_err());
    }

    fn gaussian(rng: &mut rand::rngs::StdRng) -> f64 {
        let u1: f64 = rng.random::<f64>().max(1e-300);
        let u2: f64 = rng.random();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    proptest! {
        #[test]
        fn chi2_quantile_inverts_cdf(dof in 1u32..20, p in 0.01f64..0.999) {
            let q = chi2_quantile(f64::from(dof), p).unwrap();
            prop_assert!((chi2_cdf(f64::from(dof), q) - p).abs() < 1e-9);
        }

        #[test]
        fn gamma_p_is_monotone(a in 0.5f64..10.0, x in 0.0f64..30.0, dx in 0.001f64..5.0) {
            prop_assert!(gamma_p(a, x) <= gamma_p(a, x + dx) + 1e-15);
        }
    }
}
