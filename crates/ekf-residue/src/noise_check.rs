//! Is the filter's measurement noise right for this flight? The NIS check of a clean stretch,
//! and the measurement σ estimated from it by covariance matching.
//!
//! On a clean stretch the innovations of a consistent filter satisfy `E[r_k r_kᵀ] = S_k`, so the
//! mean NIS is the channel count `m`, and each channel's mean of `r_i² / S_ii` is 1
//! (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and Navigation*,
//! 2001, §5.4). [`nis_check`] measures both on the flight's first clean stretch
//! ([`clean_stretch`]); a channel far from 1 names the σ that is mis-set even when the others
//! dilute the total.
//!
//! [`estimate_measurement_noise`] matches covariances (Mehra, "On the identification of
//! variances and adaptive Kalman filtering", IEEE TAC 15(2), 1970; Mohamed & Schwarz, "Adaptive
//! Kalman filtering for INS/GPS", J. Geodesy 73, 1999): with `S_k = H P Hᵀ + R`, each channel's
//! variance is re-estimated as `σ² ← σ² + mean(r²) − mean(S_ii)` over the stretch, the filter is
//! run again with the new σ, and so on until the σ settle. A step may shrink a σ by at most
//! [`MAX_SHRINK`] per round (the `H P Hᵀ` part is itself the old σ's doing), and no σ goes below
//! [`SIGMA_FLOOR`].

use std::ops::Range;

use uav_dynamics::SensorStreams;

use crate::error::FilterError;
use crate::residues::{FilterConfig, generate_residues};
use crate::series::ResidueSeries;

/// Seconds after the first residue step skipped as the filter's convergence.
pub const CONVERGENCE_S: f64 = 2.0;
/// Longest clean stretch used, seconds.
pub const MAX_STRETCH_S: f64 = 60.0;
/// Fewest steps a stretch needs for the check to say anything (the mean of 50 χ²₁ draws has a
/// standard deviation of 0.2, so a ratio of 2 is not chance).
pub const MIN_STEPS: usize = 50;
/// A channel is "far" when its mean `r_i² / S_ii` lies outside `[1 / NIS_FACTOR, NIS_FACTOR]`:
/// its σ off by about √2 or more.
pub const NIS_FACTOR: f64 = 2.0;
/// A round of [`estimate_measurement_noise`] shrinks a σ at most by this factor.
pub const MAX_SHRINK: f64 = 10.0;
/// Smallest σ the estimate returns (metres or radians).
pub const SIGMA_FLOOR: f64 = 1e-4;
/// Rounds of [`estimate_measurement_noise`] at most; it stops earlier when no σ moves by 2 %.
pub const MAX_ROUNDS: usize = 12;

/// The steps of the first clean stretch: from [`CONVERGENCE_S`] after the first step to the
/// first attacked step (`attacked[k]`), at most [`MAX_STRETCH_S`] long.
#[must_use]
pub fn clean_stretch(t: &[f64], attacked: Option<&[bool]>) -> Range<usize> {
    let Some(&t_first) = t.first() else { return 0..0 };
    let start = t.partition_point(|&x| x < t_first + CONVERGENCE_S);
    let mut end = start;
    while end < t.len()
        && t[end] <= t[start] + MAX_STRETCH_S
        && !attacked.is_some_and(|a| a.get(end).copied().unwrap_or(false))
    {
        end += 1;
    }
    start..end
}

/// The NIS of a clean stretch against its expectation.
#[derive(Debug, Clone, PartialEq)]
pub struct NisCheck {
    /// Mean NIS over the stretch.
    pub mean_nis: f64,
    /// Channel count `m`, the mean NIS of a consistent filter.
    pub channels: usize,
    /// Per channel, the mean of `r_i² / S_ii` (1 for a consistent filter).
    pub channel_ratios: Vec<(String, f64)>,
    /// First and last step time of the stretch, seconds.
    pub t_span: (f64, f64),
    /// Steps in the stretch.
    pub steps: usize,
}

impl NisCheck {
    /// `mean NIS / m`.
    #[must_use]
    #[allow(clippy::cast_precision_loss)] // channel counts are small
    pub fn ratio(&self) -> f64 {
        self.mean_nis / self.channels as f64
    }

    /// The channels whose ratio lies outside `[1 / NIS_FACTOR, NIS_FACTOR]`.
    #[must_use]
    pub fn far_channels(&self) -> Vec<(String, f64)> {
        self.channel_ratios.iter().filter(|(_, r)| !(*r >= 1.0 / NIS_FACTOR && *r <= NIS_FACTOR)).cloned().collect()
    }

    /// Whether any channel is far ([`NisCheck::far_channels`]).
    #[must_use]
    pub fn is_far(&self) -> bool {
        !self.far_channels().is_empty()
    }
}

/// The NIS check of the first clean stretch, or `None` when it has fewer than [`MIN_STEPS`].
#[must_use]
pub fn nis_check(series: &ResidueSeries, attacked: Option<&[bool]>) -> Option<NisCheck> {
    let range = clean_stretch(series.t(), attacked);
    if range.len() < MIN_STEPS {
        return None;
    }
    #[allow(clippy::cast_precision_loss)]
    let n = range.len() as f64;
    let mean_nis = series.nis()[range.clone()].iter().sum::<f64>() / n;
    let m = series.dim();
    let channel_ratios = series
        .channels()
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let sum: f64 = range
                .clone()
                .map(|k| {
                    let r = series.r()[k * m + i];
                    r * r / series.s()[k * m * m + i * m + i]
                })
                .sum();
            (c.clone(), sum / n)
        })
        .collect();
    Some(NisCheck {
        mean_nis,
        channels: m,
        channel_ratios,
        t_span: (series.t()[range.start], series.t()[range.end - 1]),
        steps: range.len(),
    })
}

/// One channel's σ before and after [`estimate_measurement_noise`].
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSigma {
    /// Residue channel, e.g. `gps_x`.
    pub channel: String,
    /// σ the filter had.
    pub before: f64,
    /// σ estimated from the stretch.
    pub after: f64,
}

/// The outcome of [`estimate_measurement_noise`].
#[derive(Debug, Clone)]
pub struct NoiseEstimate {
    /// The filter with the estimated measurement σ.
    pub config: FilterConfig,
    /// Per channel, the σ before and after.
    pub sigmas: Vec<ChannelSigma>,
    /// The stretch the estimate used (step times), and its step count.
    pub t_span: (f64, f64),
    /// Steps in the stretch.
    pub steps: usize,
    /// Rounds run.
    pub rounds: usize,
}

/// The measurement-noise entry of `cfg` that a residue channel's σ lives in.
fn sigma_slot<'a>(cfg: &'a mut FilterConfig, channel: &str) -> Option<&'a mut f64> {
    let meas = &mut cfg.meas;
    let (arr, axis) = match channel {
        "gps_x" => (&mut meas.gps_sigma_m, 0),
        "gps_y" => (&mut meas.gps_sigma_m, 1),
        "gps_z" => (&mut meas.gps_sigma_m, 2),
        "att_roll" => (&mut meas.attitude_sigma_rad, 0),
        "att_pitch" => (&mut meas.attitude_sigma_rad, 1),
        "att_yaw" => (&mut meas.attitude_sigma_rad, 2),
        "vo_x" => (&mut meas.vo_pos_sigma_m, 0),
        "vo_y" => (&mut meas.vo_pos_sigma_m, 1),
        "vo_z" => (&mut meas.vo_pos_sigma_m, 2),
        "vo_roll" => (&mut meas.vo_att_sigma_rad, 0),
        "vo_pitch" => (&mut meas.vo_att_sigma_rad, 1),
        "vo_yaw" => (&mut meas.vo_att_sigma_rad, 2),
        _ => return None,
    };
    arr.get_mut(axis)
}

/// Estimates the measurement σ of every residue channel from the first clean stretch (module
/// doc). `attacked` maps the residue step times to their labels (all clean when unknown).
///
/// # Errors
/// Any [`FilterError`] of the filter runs; [`FilterError::NoData`] when the clean stretch has
/// fewer than [`MIN_STEPS`] steps.
pub fn estimate_measurement_noise(
    streams: &SensorStreams,
    cfg: &FilterConfig,
    attacked: &dyn Fn(&[f64]) -> Vec<bool>,
) -> Result<NoiseEstimate, FilterError> {
    let mut current = *cfg;
    let mut rounds = 0;
    loop {
        let series = generate_residues(streams, &current)?.series;
        let labels = attacked(series.t());
        let range = clean_stretch(series.t(), Some(&labels));
        if range.len() < MIN_STEPS {
            return Err(FilterError::NoData {
                msg: format!(
                    "the first clean stretch has {} residue steps, fewer than the {MIN_STEPS} a noise estimate needs",
                    range.len()
                ),
            });
        }
        let m = series.dim();
        #[allow(clippy::cast_precision_loss)]
        let n = range.len() as f64;
        let mut moved = false;
        let mut next = current;
        for (i, channel) in series.channels().iter().enumerate() {
            let (mut r2, mut s_ii) = (0.0, 0.0);
            for k in range.clone() {
                let r = series.r()[k * m + i];
                r2 += r * r;
                s_ii += series.s()[k * m * m + i * m + i];
            }
            let Some(slot) = sigma_slot(&mut next, channel) else { continue };
            let old = *slot;
            let var = old * old + (r2 - s_ii) / n;
            let new = var.max(0.0).sqrt().max(old / MAX_SHRINK).max(SIGMA_FLOOR);
            moved |= (new - old).abs() > 0.02 * old;
            *slot = new;
        }
        rounds += 1;
        current = next;
        if !moved || rounds >= MAX_ROUNDS {
            let sigmas = series
                .channels()
                .iter()
                .filter_map(|c| {
                    let before = *sigma_slot(&mut { *cfg }, c)?;
                    let after = *sigma_slot(&mut current, c)?;
                    Some(ChannelSigma { channel: c.clone(), before, after })
                })
                .collect();
            return Ok(NoiseEstimate {
                config: current,
                sigmas,
                t_span: (series.t()[range.start], series.t()[range.end - 1]),
                steps: range.len(),
                rounds,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::residues::ModelKind;
    use uav_dynamics::sim::{SimConfig, simulate};
    use uav_dynamics::trajectory::{ShapeConfig, square};

    #[test]
    fn the_stretch_skips_convergence_and_stops_at_the_first_attack() {
        let t: Vec<f64> = (0..100).map(|k| f64::from(k) * 0.1).collect();
        assert_eq!(clean_stretch(&t, None), 20..100);
        let mut attacked = vec![false; 100];
        attacked[50] = true;
        assert_eq!(clean_stretch(&t, Some(&attacked)), 20..50);
        assert_eq!(clean_stretch(&[], None), 0..0);
    }

    /// A filter told 4× the simulator's GPS σ has a low NIS; the estimate finds the true σ
    /// within 25 % and brings the mean NIS back near `m`.
    #[test]
    fn mis_set_gps_sigma_is_flagged_and_estimated() {
        let sim = SimConfig::default();
        let flight = simulate(&sim, &square(&ShapeConfig::default()).unwrap(), 40.0, 3).unwrap();
        let right = FilterConfig::for_sim(ModelKind::ModelI, &sim);
        let mut wrong = right;
        for s in &mut wrong.meas.gps_sigma_m {
            *s *= 4.0;
        }
        let series = generate_residues(&flight.streams, &right).unwrap().series;
        let ok = nis_check(&series, None).unwrap();
        assert!(!ok.is_far(), "{ok:?}");
        let series = generate_residues(&flight.streams, &wrong).unwrap().series;
        let far = nis_check(&series, None).unwrap();
        let far_names: Vec<String> = far.far_channels().into_iter().map(|(c, _)| c).collect();
        assert_eq!(far_names, ["gps_x", "gps_y", "gps_z"], "{far:?}");

        let est = estimate_measurement_noise(&flight.streams, &wrong, &|t| vec![false; t.len()]).unwrap();
        for (k, truth) in right.meas.gps_sigma_m.iter().enumerate() {
            let got = est.config.meas.gps_sigma_m[k];
            assert!((got / truth - 1.0).abs() < 0.25, "gps axis {k}: {got} vs {truth}");
        }
        let series = generate_residues(&flight.streams, &est.config).unwrap().series;
        let after = nis_check(&series, None).unwrap();
        assert!(!after.is_far(), "{after:?}");
        assert_eq!(est.sigmas.len(), 6);
    }
}
