//! Pieces shared by the statistical detectors: the tuning switch (textbook setting or
//! validation-F1 choice), per-step F1 of alarm sequences, and validation-split helpers.

use detection_metrics::Confusion;
use ekf_residue::{DetectError, LabelledResidues, ResidueSeries};
use serde::{Deserialize, Serialize};

/// How a detector's thresholds and tunable parameters are set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum Tuning {
    /// The textbook setting from the detector's source (e.g. 1 % false-alarm rate under
    /// Gaussian residues, PX4's 5σ gate); the validation split is not looked at.
    Textbook,
    /// Thresholds and tunable parameters chosen on the validation split to maximise per-step
    /// F1 (docs/decisions/001-validation-split-labels.md). Default, as in the paper's tables.
    #[default]
    ValidationF1,
}

/// The labelled flights of a validation split as `(series, labels)` pairs.
///
/// # Errors
/// [`DetectError::Data`] when no flight is labelled or no step is attacked.
pub(crate) fn labelled_valid(valid: &LabelledResidues) -> Result<Vec<(&ResidueSeries, &[bool])>, DetectError> {
    let pairs: Vec<_> = valid.labelled().collect();
    if pairs.is_empty() {
        return Err(DetectError::Data { msg: "validation split has no labelled flight".into() });
    }
    if !pairs.iter().any(|(_, l)| l.iter().any(|&a| a)) {
        return Err(DetectError::Data { msg: "validation split has no attacked step".into() });
    }
    Ok(pairs)
}

/// Per-step F1 of a detector's alarms over several flights.
pub(crate) fn f1_of<F>(pairs: &[(&ResidueSeries, &[bool])], mut alarms: F) -> f64
where
    F: FnMut(&ResidueSeries, &mut Vec<bool>),
{
    let mut total = Confusion::default();
    let mut buf = Vec::new();
    for (series, labels) in pairs {
        buf.clear();
        alarms(series, &mut buf);
        total.add(Confusion::count(&buf, labels));
    }
    total.f1()
}

/// Up to `n` quantiles (evenly spaced in rank) of the finite values, sorted and deduplicated.
pub(crate) fn quantile_grid(values: &[f64], n: usize) -> Vec<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() || n == 0 {
        return Vec::new();
    }
    v.sort_by(f64::total_cmp);
    let mut out: Vec<f64> =
        (0..n).map(|i| v[((i as f64 + 0.5) / n as f64 * (v.len() - 1) as f64).round() as usize]).collect();
    out.dedup();
    out
}

/// Indices of the channels whose names start with `prefix` (the GPS channels).
///
/// # Errors
/// [`DetectError::Data`] naming the prefix and the channels when none matches.
pub(crate) fn gps_indices(channels: &[String], prefix: &str) -> Result<Vec<usize>, DetectError> {
    let idx: Vec<usize> = channels.iter().enumerate().filter(|(_, c)| c.starts_with(prefix)).map(|(i, _)| i).collect();
    if idx.is_empty() {
        return Err(DetectError::Data { msg: format!("no channel starts with `{prefix}` among {channels:?}") });
    }
    Ok(idx)
}

/// Checks that a grid is non-empty with finite values in `(lo, ∞)`.
pub(crate) fn check_grid(field: &'static str, grid: &[f64], lo: f64) -> Result<(), crate::BaselineError> {
    if grid.is_empty() || grid.iter().any(|v| !(v.is_finite() && *v > lo)) {
        return Err(crate::BaselineError::Config {
            field,
            msg: format!("needs finite values above {lo}, got {grid:?}"),
        });
    }
    Ok(())
}

/// The channel set of a fit: the training split's (or the validation split's when training is
/// empty); every validation flight must match it.
///
/// # Errors
/// [`DetectError::Data`] when both splits are empty; [`DetectError::ChannelMismatch`] when the
/// validation split has other channels.
pub(crate) fn fit_channels(train: &LabelledResidues, valid: &LabelledResidues) -> Result<Vec<String>, DetectError> {
    let channels = if train.flights().is_empty() { valid.channels() } else { train.channels() };
    if channels.is_empty() {
        return Err(DetectError::Data { msg: "training and validation splits are both empty".into() });
    }
    for f in valid.flights() {
        ekf_residue::check_channels(channels, f.series())?;
    }
    Ok(channels.to_vec())
}
