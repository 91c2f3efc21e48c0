//! Online detectors that need no training, for the closed-loop experiment: the GNSS innovation
//! gate PX4 EKF2 applies inside its own filter, and the oracle that knows the attack schedule.
//!
//! - [`InnovationGate`]: per GPS axis `i`, `test_ratio_i = ν_i² / (γ² (S_k)_ii)`; the fix is
//!   rejected when `max_i test_ratio_i > 1` (PX4 `EKF/ekf.h` `updateAidSourceStatus`,
//!   `EKF2_GPS_P_GATE` = 5 by default). In the loop it runs with hold 0 and
//!   [`crate::estimator::ResilientConfig::reset_after_s`] = 7 s, which together are EKF2's
//!   behaviour: each rejected fix is skipped, and after 7 s without fusion the position is
//!   reset onto GNSS.
//! - [`Oracle`]: alarms exactly on the steps whose fix the attack plan changes. With latency 0
//!   and hold 0 it excludes GPS exactly on attacked fixes: the ceiling of any detector, and the
//!   estimator whose residues the closed-loop detectors train on.

use attack_inject::AttackPlan;
use ekf_residue::detector::{OnlineDecision, OnlineDetector};
use ekf_residue::error::DetectError;
use ekf_residue::series::ResidueStep;

use crate::error::{FusionError, Result};

/// PX4 EKF2's per-axis GNSS innovation gate (module doc). Reads a step of `m` channels whose
/// innovation covariance `s_k` is row-major `m × m`; every channel is gated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InnovationGate {
    gamma: f64,
}

impl InnovationGate {
    /// PX4's default gate, `EKF2_GPS_P_GATE` = 5 standard deviations (params_gnss.yaml).
    pub const PX4_GAMMA: f64 = 5.0;

    /// A gate of `gamma` standard deviations.
    ///
    /// # Errors
    /// [`FusionError::Config`] for a non-positive or non-finite `gamma`.
    pub fn new(gamma: f64) -> Result<Self> {
        if !(gamma.is_finite() && gamma > 0.0) {
            return Err(FusionError::Config { field: "gamma", msg: format!("must be positive, got {gamma}") });
        }
        Ok(Self { gamma })
    }
}

impl OnlineDetector for InnovationGate {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let m = step.r_k.len();
        if step.s_k.len() != m * m {
            return Err(DetectError::Numerical {
                what: format!("innovation gate: S_k has {} entries for {m} channels", step.s_k.len()),
            });
        }
        let g2 = self.gamma * self.gamma;
        let mut score = 0.0_f64;
        for (i, r) in step.r_k.iter().enumerate() {
            let var = step.s_k[i * m + i];
            if !(var.is_finite() && var > 0.0) {
                return Err(DetectError::Numerical { what: format!("innovation variance of channel {i} is {var}") });
            }
            score = score.max(r * r / (g2 * var));
        }
        Ok(OnlineDecision { score, alarm: score > 1.0 })
    }

    fn reset(&mut self) {}
}

/// Alarms exactly on the steps at which the plan attacks the fix (module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct Oracle {
    plan: AttackPlan,
}

impl Oracle {
    /// The oracle of `plan`.
    #[must_use]
    pub const fn new(plan: AttackPlan) -> Self {
        Self { plan }
    }
}

impl OnlineDetector for Oracle {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let alarm = self.plan.active_at(step.t).is_some();
        Ok(OnlineDecision { score: f64::from(u8::from(alarm)), alarm })
    }

    fn reset(&mut self) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gate_scores_the_worst_axis_against_gamma_sigma() {
        let mut g = InnovationGate::new(5.0).unwrap();
        let s = [4.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 9.0];
        // Axis 1: (4.9)² / (25 · 1) = 0.9604 → passes; axis 2 at 15.3: 234.09 / 225 > 1.
        let pass = g.update(&ResidueStep { t: 0.0, r_k: &[1.0, 4.9, 0.0], s_k: &s, nis: 0.0 }).unwrap();
        assert!(!pass.alarm);
        assert!((pass.score - 0.9604).abs() < 1e-12);
        let fail = g.update(&ResidueStep { t: 0.1, r_k: &[0.0, 0.0, 15.3], s_k: &s, nis: 0.0 }).unwrap();
        assert!(fail.alarm);
        assert!(g.update(&ResidueStep { t: 0.2, r_k: &[0.0, 0.0], s_k: &s, nis: 0.0 }).is_err());
        assert!(InnovationGate::new(0.0).is_err());
    }
}
