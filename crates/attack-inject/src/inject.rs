//! Batch injection of an [`AttackPlan`] into a recorded GPS stream (paper eq:fdi), with the
//! per-sample offsets `d_k` (metres, ENU) and ground-truth labels.

use nalgebra::Vector3;
use uav_dynamics::GpsSample;

use crate::error::{AttackError, Result};
use crate::plan::AttackPlan;

/// An attacked GPS stream, aligned sample by sample with the clean one.
#[derive(Debug, Clone, PartialEq)]
pub struct AttackedGps {
    /// The fixes the estimator receives (same time stamps as the clean stream).
    pub gps: Vec<GpsSample>,
    /// `d_k = attacked − clean` in metres; zero outside attacks.
    pub offset: Vec<Vector3<f64>>,
    /// `true` where the sent fix differs from the clean one.
    pub labels: Vec<bool>,
}

impl AttackedGps {
    /// Number of samples.
    #[must_use]
    pub fn len(&self) -> usize {
        self.gps.len()
    }

    /// Whether the stream is empty.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.gps.is_empty()
    }

    /// Fraction of samples labelled attacked (0 for an empty stream).
    #[must_use]
    pub fn attacked_fraction(&self) -> f64 {
        if self.labels.is_empty() {
            return 0.0;
        }
        #[allow(clippy::cast_precision_loss)] // Sample counts are far below 2^52.
        let frac = self.labels.iter().filter(|&&l| l).count() as f64 / self.labels.len() as f64;
        frac
    }
}

/// Check that a GPS stream has finite values and strictly increasing time stamps.
///
/// # Errors
/// [`AttackError::NonFiniteGps`] or [`AttackError::UnorderedGps`] naming the sample.
pub fn check_gps(gps: &[GpsSample]) -> Result<()> {
    let mut t_prev = f64::NEG_INFINITY;
    for (step_idx, g) in gps.iter().enumerate() {
        if !g.t.is_finite() {
            return Err(AttackError::NonFiniteGps { step_idx, what: "t" });
        }
        if !g.p.iter().all(|v| v.is_finite()) {
            return Err(AttackError::NonFiniteGps { step_idx, what: "p" });
        }
        if g.t <= t_prev {
            return Err(AttackError::UnorderedGps { step_idx, t_prev, t: g.t });
        }
        t_prev = g.t;
    }
    Ok(())
}

/// Attack a whole clean GPS stream with `plan`; sample `k` sees the clean fixes `0..k` as
/// history (what a replaying or freezing attacker has recorded).
///
/// # Errors
/// [`AttackError::NonFiniteGps`] or [`AttackError::UnorderedGps`] if the stream is malformed.
pub fn inject(gps: &[GpsSample], plan: &AttackPlan) -> Result<AttackedGps> {
    check_gps(gps)?;
    let mut out = AttackedGps {
        gps: Vec::with_capacity(gps.len()),
        offset: Vec::with_capacity(gps.len()),
        labels: Vec::with_capacity(gps.len()),
    };
    for (k, clean) in gps.iter().enumerate() {
        let a = plan.apply(clean, gps.get(..k).unwrap_or_default());
        out.gps.push(a.gps);
        out.offset.push(a.offset);
        out.labels.push(a.attacked);
    }
    Ok(out)
}
