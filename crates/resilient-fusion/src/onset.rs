//! Where a spoof the filter fused began: the change point of the whitened GPS innovations
//! before an alarm, so that a rollback undoes every fix the spoof corrupted, not only those of a
//! fixed look-back (docs/decisions/097-rollback-to-onset.md).
//!
//! A spoof the filter fuses for a while, a drift most of all, leaves its innovations with a mean
//! the clean ones do not have: the estimate lags the growing offset. For the GPS innovations
//! whitened by their own covariance, `u_i = L_i⁻¹ r_i` with `S_i = L_i L_iᵀ` (standard normal on
//! clean fixes), twice the log of the generalised likelihood ratio of a constant mean shift from
//! fix `j` to the newest fix searched, `k`, is
//!
//! `Λ(j) = ‖Σ_{i=j}^{k} u_i‖² / (k − j + 1)`,
//!
//! χ²₃-distributed on clean fixes for each `j` (Basseville and Nikiforov, *Detection of Abrupt
//! Changes*, 1993, sec. 2.4: the change time is the maximiser of the likelihood ratio). The onset
//! is the `j` that maximises `Λ`, taken only when its `Λ` passes a threshold. The threshold
//! applies to the largest of the span's `Λ(j)`: over 50 clean fixes (5 s at 10 Hz) of Gaussian
//! innovations the largest passes the χ²₃ 0.999 quantile in about 1 % of spans, not 0.1 %.
//! The whitening assumes a shift constant in `r`; where `S_i` grows along the span (a replayed
//! exclusion) the test weighs the later fixes less.

use nalgebra::{Matrix3, Vector3};

/// The whitened GPS innovation `L⁻¹ r` of one fix, for innovation `r` with covariance
/// `s = L Lᵀ`; `None` when `s` is not positive definite or anything is not finite.
#[must_use]
pub fn whiten(r: &Vector3<f64>, s: &Matrix3<f64>) -> Option<Vector3<f64>> {
    if !r.iter().chain(s.iter()).all(|v| v.is_finite()) {
        return None;
    }
    s.cholesky()?.l().solve_lower_triangular(r)
}

/// The time of the fix from which the mean shift of the whitened innovations `u` (time order,
/// newest last) is most likely, when its likelihood ratio `Λ` exceeds `threshold`; `None`
/// otherwise or for an empty `u`.
#[must_use]
pub fn mean_shift_onset(u: &[(f64, Vector3<f64>)], threshold: f64) -> Option<f64> {
    let mut sum = Vector3::zeros();
    let mut best: Option<(f64, f64)> = None;
    for (n, (t, ui)) in u.iter().rev().enumerate() {
        sum += ui;
        #[allow(clippy::cast_precision_loss)]
        let lambda = sum.norm_squared() / (n + 1) as f64;
        if best.is_none_or(|(b, _)| lambda > b) {
            best = Some((lambda, *t));
        }
    }
    best.filter(|&(lambda, _)| lambda > threshold).map(|(_, t)| t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    fn noise(n: usize, seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n).map(|_| Vector3::from_fn(|_, _| StandardNormal.sample(&mut rng))).collect()
    }

    fn timed(u: Vec<Vector3<f64>>) -> Vec<(f64, Vector3<f64>)> {
        #[allow(clippy::cast_precision_loss)]
        u.into_iter().enumerate().map(|(i, v)| (i as f64 * 0.1, v)).collect()
    }

    #[test]
    fn a_shift_is_dated_to_its_first_fix() {
        // 30 clean fixes, then 20 with a mean of one σ along x (a lagged drift).
        let mut u = noise(50, 1);
        for v in &mut u[30..] {
            v.x += 1.0;
        }
        let t = mean_shift_onset(&timed(u), 16.266).expect("a 20-fix shift of 1 σ passes");
        assert!((t - 3.0).abs() <= 0.35, "onset {t} s, the shift began at 3.0 s");
    }

    #[test]
    fn a_single_outlying_newest_fix_is_its_own_onset() {
        let mut u = noise(50, 2);
        u[49].y += 20.0;
        assert_eq!(mean_shift_onset(&timed(u), 16.266), Some(4.9));
    }

    #[test]
    fn clean_fixes_rarely_give_an_onset() {
        // Under no shift each Λ(j) is χ²₃; the maximum over 50 of them passes the 0.999
        // quantile in a few per cent of windows.
        let hits = (0..200).filter(|&s| mean_shift_onset(&timed(noise(50, 100 + s)), 16.266).is_some()).count();
        assert!(hits <= 20, "{hits} of 200 clean windows dated an onset");
        assert_eq!(mean_shift_onset(&[], 0.0), None);
    }

    #[test]
    fn whitening_uses_the_cholesky_factor() {
        // S = diag(4, 1, 9): u = r / σ per axis.
        let u = whiten(&Vector3::new(2.0, -1.0, 6.0), &Matrix3::from_diagonal(&Vector3::new(4.0, 1.0, 9.0))).unwrap();
        assert!((u - Vector3::new(1.0, -1.0, 2.0)).norm() < 1e-12);
        // Correlated: uᵀu is the NIS rᵀ S⁻¹ r.
        let s = Matrix3::new(2.0, 0.5, 0.1, 0.5, 1.0, 0.2, 0.1, 0.2, 3.0);
        let r = Vector3::new(0.3, -1.2, 0.7);
        let u = whiten(&r, &s).unwrap();
        let nis = r.dot(&(s.try_inverse().unwrap() * r));
        assert!((u.norm_squared() - nis).abs() < 1e-12);
        assert!(whiten(&r, &Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0))).is_none());
        assert!(whiten(&Vector3::new(f64::NAN, 0.0, 0.0), &s).is_none());
    }
}
