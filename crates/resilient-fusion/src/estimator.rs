//! Resilient state estimation, paper alg:alg3 (sec:state_estimation): fuse GPS + VO + IMU
//! (Model II EKF, eq:model2f, eq:model2g) while no alarm is raised, fuse VO + IMU only while the
//! detector alarms on GPS, and re-admit GPS after a clean hold time.
//!
//! Per measurement time `t_k` (10 Hz; the IMU propagates in between):
//!
//! 1. The GPS innovation against the prior `x̂_{k|k−1}` (with the simultaneous VO innovation,
//!    channels chosen by [`ResilientConfig::detector_channels`]) is computed on a copy of the
//!    filter and fed to the [`OnlineDetector`]. Its decision becomes available at
//!    `t_k + latency_s` (the paper's edge device needs about 1 s).
//! 2. Decisions whose time has come drive a two-state machine: an alarm excludes GPS
//!    (`Admitted → Excluded`); GPS is re-admitted once no alarm has arrived for `hold_s`
//!    (hysteresis), and on re-admission the position covariance is inflated by
//!    `readmit_inflation_m2` so the first fixes pull the VO-drifted estimate back quickly.
//!    An alarm that opens an exclusion rewinds the filter ([`Rollback::ReplayWithoutGps`]) to
//!    before the alarmed step, or [`ResilientConfig::rollback_lookback_s`] earlier, or to the
//!    onset of a spoof the GPS innovations of the last [`ResilientConfig::rollback_onset_s`]
//!    date ([`crate::onset`]), whichever is earliest, and replays without GPS.
//! 3. The filter updates with VO and, unless excluded, the GPS fix (alg:alg3 lines 2–4). While
//!    excluded the GPS innovation is still computed against the prior, so the detector keeps
//!    watching the stream.
//! 4. Optionally ([`ResilientConfig::readmit_nis`]), an exclusion also ends when the fixes
//!    agree with the prediction: once every GPS fix for `hold_s` has passed a χ² gate on its
//!    innovation against the prior, whose covariance has grown with the dead reckoning, GPS is
//!    re-admitted although the detector still alarms, and its alarms go unheeded until it
//!    clears once. A false alarm then costs a short exclusion instead of locking GPS out: the
//!    drifted estimate makes honest fixes look unusual to a detector, but not to the filter's
//!    own covariance. A spoof larger than the prediction's uncertainty stays excluded.
//! 5. Optionally, as PX4 EKF2 does (`reset_timeout_max` = 7 s in `EKF/common.h`), GPS that has
//!    been excluded for [`ResilientConfig::reset_after_s`] is re-admitted with a position
//!    reset onto the fix ([`Estimator::reset_onto_fix`]), so the estimate jumps onto whatever
//!    the receiver reports. Its velocity, left uncorrected as long, takes the velocity error
//!    that the trend of the last unfused fixes' innovations reveals ([`crate::innovation_trend`],
//!    as EKF2 resets onto the receiver's velocity), or is forgotten when a straight line does
//!    not explain those fixes; the accelerometer bias is forgotten. The fixes that follow
//!    re-estimate what was forgotten. The reset is a decision to trust GPS: as after step 4,
//!    the detector's alarms go unheeded until it clears once, and no rollback rewinds past it,
//!    so an alarm stuck on the drift its own exclusion caused costs one bounded exclusion, not
//!    one every `reset_after_s`. A rollback that rewinds to before the re-admission ending an
//!    exclusion undoes every fix fused since and reopens that exclusion, so its clock counts all
//!    the dead reckoning, however often an alarm returns within the latency and rewind of
//!    each re-admission.
//!
//! Positions in local ENU metres, times in seconds.

use std::collections::VecDeque;

use ekf_residue::detector::{OnlineDecision, OnlineDetector};
use ekf_residue::residues::{
    Estimator, FilterConfig, GPS_CHANNELS, GpsFusion, Measurements, StateEstimate, UpdateOutcome,
};
use ekf_residue::series::ResidueStep;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use uav_dynamics::sensors::ImuSample;

use crate::error::{FusionError, Result};
use crate::innovation_trend::InnovationTrend;
use crate::onset;

/// What happens to the GPS fixes fused during the decision latency once an alarm arrives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Rollback {
    /// Rewind the filter to just before the alarmed residue step and replay the buffered IMU
    /// and VO data without GPS (default), so fixes fused during the latency leave no trace.
    #[default]
    ReplayWithoutGps,
    /// Keep them: exclusion starts when the decision arrives (alg:alg3 taken literally); the
    /// bias absorbed during the latency stays in the estimate.
    Off,
}

/// Settings of the resilient estimator (alg:alg3 and its hysteresis).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResilientConfig {
    /// Delay from a residue step to the detector's decision being usable, seconds. Default 1.0
    /// (paper sec. "Real-world Experiment": inference takes about 1 s on the edge device).
    pub latency_s: f64,
    /// Time without alarms before GPS is re-admitted, seconds. Default 1.0 (PX4 re-accepts GNSS
    /// after max(1 s, EKF2_REQ_GPS_H/10) of passing checks, gnss_checks.cpp). With 0 every
    /// alarmed fix is excluded and the next fix without an alarm is fused again.
    pub hold_s: f64,
    /// Variance added to each position axis on re-admission, m². Default 1.0 (σ = 1 m, twice
    /// the GPS σ; docs/decisions/023-resilient-fusion.md).
    pub readmit_inflation_m2: f64,
    /// Innovation channels the detector reads, in its order. Default the GPS channels
    /// `gps_x gps_y gps_z`; a detector trained on Model II's stacked residue uses
    /// `vo_x … vo_yaw gps_x gps_y gps_z`.
    pub detector_channels: Vec<String>,
    /// Treatment of fixes fused during the latency. Default [`Rollback::ReplayWithoutGps`]
    /// (docs/decisions/023-resilient-fusion.md).
    #[serde(default)]
    pub rollback: Rollback,
    /// How far before the alarmed residue step the rollback rewinds, seconds, so the fixes
    /// fused during the detector's own detection delay are undone too (a spoof fused before the
    /// first alarm corrupts the velocity and accelerometer-bias estimates, and the dead
    /// reckoning that follows diverges). Default 0: rewind to the alarmed step. Applies at
    /// every latency, 0 included, with [`Rollback::ReplayWithoutGps`].
    #[serde(default)]
    pub rollback_lookback_s: f64,
    /// How far before the alarmed residue step the rollback looks for the onset of a spoof the
    /// filter fused ([`crate::onset`]), seconds: when the whitened GPS innovations of that span
    /// show a mean shift (the largest log-likelihood ratio above the χ²₃ 0.999 quantile, which
    /// about 1 % of clean 5 s spans of Gaussian innovations pass), the rollback rewinds to its
    /// first fix if that lies before `rollback_lookback_s`. The span's fixes are searched
    /// whether or not they were fused. Default 0: no search.
    #[serde(default)]
    pub rollback_onset_s: f64,
    /// Exclusion time after which GPS is re-admitted with a reset onto the fix (module doc,
    /// step 5: the position moves onto it, the velocity takes the fixes' trend, the accelerometer
    /// bias is forgotten), seconds. Default `None`: exclusion lasts while alarms do. PX4
    /// EKF2 behaves as `Some(7.0)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reset_after_s: Option<f64>,
    /// Window of unfused fixes whose innovation trend gives the velocity a reset takes, seconds
    /// (module doc, step 5; [`crate::innovation_trend`]); its variance is at most
    /// `InitConfig::sigma_v0²`. Default 2.0. With 0, or when the window holds fewer than
    /// [`crate::innovation_trend::MIN_FIXES`] fixes of the current exclusion, spanning less than a
    /// quarter of it, or fixes that a straight line does not explain, the reset forgets the
    /// velocity as at initialisation.
    #[serde(default = "default_reset_velocity_window_s")]
    pub reset_velocity_window_s: f64,
    /// NIS gate of the GPS channels (`gps_x gps_y gps_z`, against the prior) under which an
    /// exclusion ends although the detector alarms (module doc, step 4). Default `None`:
    /// exclusion lasts while alarms do. [`ResilientConfig::CHI2_3_99`] is the χ²₃ 0.99 quantile.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub readmit_nis: Option<f64>,
}

impl Default for ResilientConfig {
    fn default() -> Self {
        Self {
            latency_s: 1.0,
            hold_s: 1.0,
            readmit_inflation_m2: 1.0,
            detector_channels: GPS_CHANNELS.iter().map(|s| (*s).to_string()).collect(),
            rollback: Rollback::default(),
            rollback_lookback_s: 0.0,
            rollback_onset_s: 0.0,
            reset_after_s: None,
            reset_velocity_window_s: default_reset_velocity_window_s(),
            readmit_nis: None,
        }
    }
}

fn default_reset_velocity_window_s() -> f64 {
    2.0
}

impl ResilientConfig {
    /// χ²₃ quantile at 0.99 (11.345 in standard χ² tables): the re-admission gate of the
    /// closed-loop experiment.
    pub const CHI2_3_99: f64 = 11.345;

    /// Check the ranges.
    ///
    /// # Errors
    /// [`FusionError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        for (field, v) in [
            ("latency_s", self.latency_s),
            ("hold_s", self.hold_s),
            ("readmit_inflation_m2", self.readmit_inflation_m2),
            ("rollback_lookback_s", self.rollback_lookback_s),
            ("rollback_onset_s", self.rollback_onset_s),
            ("reset_velocity_window_s", self.reset_velocity_window_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(FusionError::Config { field, msg: format!("must be finite and non-negative, got {v}") });
            }
        }
        for (field, v) in [("reset_after_s", self.reset_after_s), ("readmit_nis", self.readmit_nis)] {
            if let Some(v) = v
                && !(v.is_finite() && v > 0.0)
            {
                return Err(FusionError::Config { field, msg: format!("must be finite and positive, got {v}") });
            }
        }
        if self.detector_channels.is_empty() {
            return Err(FusionError::Config {
                field: "detector_channels",
                msg: "must name at least one channel".into(),
            });
        }
        Ok(())
    }
}

/// A detector decision waiting for its availability time.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pending {
    t_residue: f64,
    t_avail: f64,
    alarm: bool,
}

/// A buffered input for replay after a rollback.
#[derive(Debug, Clone)]
enum Event {
    /// An IMU sample fed with [`Estimator::imu`].
    Imu(ImuSample),
    /// A measurement group, with the filter state just before it was processed and, once it
    /// was, its whitened GPS innovation (for [`crate::onset`]).
    Meas(Measurements, Box<Estimator>, Option<Vector3<f64>>),
}

/// What happened at one measurement time.
#[derive(Debug, Clone, PartialEq)]
pub struct FusionStep {
    /// Time in seconds.
    pub t: f64,
    /// The detector's decision on this step's residue (`None` without a detector or GPS fix).
    pub decision: Option<OnlineDecision>,
    /// Whether GPS was excluded at this step.
    pub gps_excluded: bool,
    /// Whether a GPS fix was fused at this step.
    pub gps_fused: bool,
    /// Whether GPS was re-admitted at this step with a position reset onto the fix.
    pub reset: bool,
    /// The filter's innovation of this step against the prior, every channel of the group
    /// (also a GPS fix that was not fused): the residue a detector trained on this estimator's
    /// output sees.
    pub outcome: Option<UpdateOutcome>,
}

/// The resilient estimator: a Model II (or Model I) EKF, an optional online detector and the
/// exclusion state machine of the module doc.
pub struct ResilientEstimator<'d> {
    filter_cfg: FilterConfig,
    cfg: ResilientConfig,
    est: Option<Estimator>,
    detector: Option<Box<dyn OnlineDetector + 'd>>,
    pending: VecDeque<Pending>,
    excluded_since: Option<f64>,
    last_alarm_avail: f64,
    /// While excluded: time of the first of the current run of fixes inside `readmit_nis`.
    consistent_since: Option<f64>,
    /// Alarms are unheeded until the detector clears (after a re-admission by consistency).
    alarms_overridden: bool,
    excluded_intervals: Vec<(f64, f64)>,
    /// Time of the last reset onto a fix: no rollback undoes it, nor reopens the exclusion it
    /// ended.
    last_reset: f64,
    /// GPS innovations of the recent fixes, for the velocity of a reset.
    trend: InnovationTrend,
    alarm_times: Vec<f64>,
    buffer: VecDeque<Event>,
    n_rollbacks: usize,
    n_resets: usize,
}

impl std::fmt::Debug for ResilientEstimator<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ResilientEstimator")
            .field("cfg", &self.cfg)
            .field("initialised", &self.est.is_some())
            .field("has_detector", &self.detector.is_some())
            .field("excluded_since", &self.excluded_since)
            .finish_non_exhaustive()
    }
}

impl<'d> ResilientEstimator<'d> {
    /// A resilient estimator; without a detector it is the plain EKF (GPS always fused).
    ///
    /// # Errors
    /// [`FusionError::Config`] from [`ResilientConfig::check`], [`FusionError::Filter`] for an
    /// invalid filter configuration.
    pub fn new(
        filter_cfg: &FilterConfig,
        cfg: &ResilientConfig,
        detector: Option<Box<dyn OnlineDetector + 'd>>,
    ) -> Result<Self> {
        cfg.check()?;
        filter_cfg.check()?;
        Ok(Self {
            filter_cfg: *filter_cfg,
            cfg: cfg.clone(),
            est: None,
            detector,
            pending: VecDeque::new(),
            excluded_since: None,
            last_alarm_avail: f64::NEG_INFINITY,
            consistent_since: None,
            alarms_overridden: false,
            excluded_intervals: Vec::new(),
            last_reset: f64::NEG_INFINITY,
            trend: InnovationTrend::default(),
            alarm_times: Vec::new(),
            buffer: VecDeque::new(),
            n_rollbacks: 0,
            n_resets: 0,
        })
    }

    /// The current estimate (`None` before the first GPS fix with an attitude sample).
    #[must_use]
    pub fn estimate(&self) -> Option<StateEstimate> {
        self.est.as_ref().map(Estimator::estimate)
    }

    /// Whether GPS is currently excluded.
    #[must_use]
    pub fn gps_excluded(&self) -> bool {
        self.excluded_since.is_some()
    }

    /// Closed intervals `(start, end)` during which GPS was excluded; an exclusion still open
    /// is closed at `t_end`.
    #[must_use]
    pub fn excluded_intervals(&self, t_end: f64) -> Vec<(f64, f64)> {
        let mut v = self.excluded_intervals.clone();
        if let Some(t0) = self.excluded_since {
            v.push((t0, t_end.max(t0)));
        }
        v
    }

    /// How many times the filter was rewound and replayed without GPS.
    #[must_use]
    pub fn n_rollbacks(&self) -> usize {
        self.n_rollbacks
    }

    /// How many times GPS was re-admitted with a position reset ([`ResilientConfig::reset_after_s`]).
    #[must_use]
    pub fn n_resets(&self) -> usize {
        self.n_resets
    }

    /// Whether inputs must be buffered for a rollback.
    fn buffering(&self) -> bool {
        self.detector.is_some()
            && self.cfg.rollback == Rollback::ReplayWithoutGps
            && self.cfg.latency_s + self.cfg.rollback_lookback_s.max(self.cfg.rollback_onset_s) > 0.0
    }

    /// Residue times of every alarm the detector raised.
    #[must_use]
    pub fn alarm_times(&self) -> &[f64] {
        &self.alarm_times
    }

    /// Feed the IMU sample and the (possibly attacked) measurements of one IMU step, both at
    /// time `imu.t` (`meas.t` must equal it when `meas` holds anything).
    ///
    /// The filter starts at the first step with a GPS fix and an attitude sample (pose from
    /// those, velocity `InitConfig::v0`); the VO sample of that step opens its keyframe.
    ///
    /// # Errors
    /// [`FusionError::Filter`] (bad input, divergence), [`FusionError::Detect`],
    /// [`FusionError::MissingChannel`].
    pub fn process(&mut self, imu: &ImuSample, meas: &Measurements) -> Result<Option<FusionStep>> {
        let has_meas = meas.gps.is_some() || meas.vo.is_some() || meas.attitude.is_some();
        let buffering = self.buffering();
        let Some(est) = self.est.as_mut() else {
            if let (Some(p0), Some(q0)) = (meas.gps, meas.attitude) {
                let mut est = Estimator::new(&self.filter_cfg, imu.t, &p0, &q0, true, Some(imu))?;
                if meas.vo.is_some() {
                    let vo_only = Measurements { t: meas.t, gps: None, attitude: None, vo: meas.vo };
                    est.measure(&vo_only, GpsFusion::Fuse)?;
                }
                self.est = Some(est);
            }
            return Ok(None);
        };
        est.imu(imu)?;
        if buffering {
            self.buffer.push_back(Event::Imu(*imu));
        }
        if !has_meas {
            return Ok(None);
        }
        let t = meas.t;
        let mut decision = None;
        let mut gps_nis = None;
        if let (Some(det), Some(_)) = (self.detector.as_mut(), meas.gps) {
            // alg:alg3 input A_i: the detector's verdict on this step's innovation against the
            // prior, computed on a copy so the real update can still choose to skip GPS.
            let mut probe = est.clone();
            if let Some(out) = probe.measure(meas, GpsFusion::Skip)? {
                if self.cfg.readmit_nis.is_some() {
                    gps_nis = Some(select_channels(&out, &GPS_CHANNELS)?.2);
                }
                let (r, s, nis) = select_channels(&out, &self.cfg.detector_channels)?;
                let step = ResidueStep { t, r_k: r.as_slice(), s_k: s.as_slice(), nis };
                let d = det.update(&step).map_err(|source| FusionError::Detect { t, source })?;
                if d.alarm {
                    self.alarm_times.push(t);
                }
                self.pending.push_back(Pending { t_residue: t, t_avail: t + self.cfg.latency_s, alarm: d.alarm });
                decision = Some(d);
            }
        }
        self.apply_decisions(t, meas.gps.is_some())?;
        self.readmit_if_consistent(t, gps_nis)?;
        let reset = meas.gps.is_some() && self.reset_due(t);
        if reset {
            // Step 5 of the module doc: re-admit GPS with a position reset onto this fix.
            if let Some(t0) = self.excluded_since.take() {
                self.excluded_intervals.push((t0, t));
            }
            if let (Some(est), Some(p)) = (self.est.as_mut(), meas.gps) {
                let init = &self.filter_cfg.init;
                let velocity = self
                    .trend
                    .velocity_correction(
                        t,
                        self.cfg.reset_velocity_window_s,
                        &self.filter_cfg.meas.gps_sigma_m,
                        init.sigma_ba0,
                    )
                    .map(|c| (est.estimate().v + c.dv, c.var.min(init.sigma_v0 * init.sigma_v0)));
                est.reset_onto_fix(&p, velocity)?;
            }
            self.alarms_overridden = true;
            self.buffer.clear();
            self.last_reset = t;
            self.n_resets += 1;
        }
        let excluded = self.excluded_since.is_some();
        let fusion = if excluded { GpsFusion::Skip } else { GpsFusion::Fuse };
        if buffering {
            // Keep what a rollback to this step needs: the prior state and the measurements.
            let horizon = t - self.cfg.latency_s - self.cfg.rollback_lookback_s.max(self.cfg.rollback_onset_s) - 1.0;
            while let Some(Event::Imu(ImuSample { t: t_old, .. }) | Event::Meas(Measurements { t: t_old, .. }, ..)) =
                self.buffer.front()
            {
                if *t_old >= horizon {
                    break;
                }
                self.buffer.pop_front();
            }
            if let Some(est) = self.est.as_ref() {
                self.buffer.push_back(Event::Meas(*meas, Box::new(est.clone()), None));
            }
        }
        let Some(est) = self.est.as_mut() else { return Ok(None) };
        let outcome = est.measure(meas, fusion)?;
        let u = outcome.as_ref().and_then(|out| self.note_gps(out));
        if buffering && let Some(Event::Meas(_, _, slot)) = self.buffer.back_mut() {
            *slot = u;
        }
        let gps_fused = outcome.as_ref().is_some_and(|o| o.gps_fused);
        Ok(Some(FusionStep { t, decision, gps_excluded: excluded, gps_fused, reset, outcome }))
    }

    /// How long the GPS innovations are kept for the velocity of a later reset; `None` when
    /// resets do not happen or do not take a velocity.
    fn trend_keep_s(&self) -> Option<f64> {
        let w = self.cfg.reset_velocity_window_s;
        (self.cfg.reset_after_s.is_some() && w > 0.0).then_some(w)
    }

    /// Keep what later resets and rollbacks read of a group's GPS innovation: the innovation
    /// for the velocity trend, and its whitened form (returned, for the rollback buffer) when
    /// rollbacks search an onset. `None` for a group without a fix.
    fn note_gps(&mut self, out: &UpdateOutcome) -> Option<Vector3<f64>> {
        let (r, s) = gps_innovation(out)?;
        if let Some(keep_s) = self.trend_keep_s() {
            self.trend.push(out.t, r, out.gps_fused, keep_s);
        }
        (self.cfg.rollback_onset_s > 0.0).then(|| onset::whiten(&r, &s)).flatten()
    }

    /// Whether GPS has been excluded for [`ResilientConfig::reset_after_s`] at `t`.
    fn reset_due(&self, t: f64) -> bool {
        match (self.cfg.reset_after_s, self.excluded_since) {
            (Some(after), Some(t0)) => t - t0 >= after - 1e-9,
            _ => false,
        }
    }

    /// Apply every decision available at `t` and run the hysteresis; GPS is only re-admitted
    /// on a step that carries a fix (`has_gps`), so with `hold_s = 0` an attitude- or VO-only
    /// step between fixes does not end an exclusion.
    fn apply_decisions(&mut self, t: f64, has_gps: bool) -> Result<()> {
        // Tolerance: decision times are sums of sample times and the latency.
        let eps = 1e-9;
        let mut alarm_now = false;
        while let Some(p) = self.pending.front().copied() {
            if p.t_avail > t + eps {
                break;
            }
            self.pending.pop_front();
            if !p.alarm {
                self.alarms_overridden = false;
            }
            if p.alarm && !self.alarms_overridden {
                alarm_now = true;
                self.last_alarm_avail = p.t_avail;
                if self.excluded_since.is_none() {
                    // alg:alg3 line 4: X ← Fuse(camera, IMU).
                    self.excluded_since = Some(t);
                    if self.buffering() {
                        self.rollback_to(p.t_residue)?;
                    }
                }
            }
        }
        // A step whose own decision alarms is never the one that re-admits (this matters for
        // `hold_s = 0`, where the next step without an alarm re-admits).
        if let Some(t0) = self.excluded_since
            && has_gps
            && !alarm_now
            && t - self.last_alarm_avail >= self.cfg.hold_s - eps
        {
            // Re-admission: inflate the position covariance so GPS re-converges the estimate.
            if let Some(est) = self.est.as_mut() {
                est.inflate_position_covariance(self.cfg.readmit_inflation_m2)?;
            }
            self.excluded_intervals.push((t0, t));
            self.excluded_since = None;
        }
        Ok(())
    }

    /// Step 4 of the module doc: while excluded, track the run of fixes whose GPS NIS passes
    /// [`ResilientConfig::readmit_nis`]; after `hold_s` of them, re-admit GPS (with the usual
    /// inflation) and leave the detector's alarms unheeded until it clears.
    fn readmit_if_consistent(&mut self, t: f64, gps_nis: Option<f64>) -> Result<()> {
        let (Some(gate), Some(t0), Some(nis)) = (self.cfg.readmit_nis, self.excluded_since, gps_nis) else {
            if self.excluded_since.is_none() {
                self.consistent_since = None;
            }
            return Ok(());
        };
        if nis > gate {
            self.consistent_since = None;
            return Ok(());
        }
        let since = *self.consistent_since.get_or_insert(t);
        if t - since >= self.cfg.hold_s - 1e-9 {
            if let Some(est) = self.est.as_mut() {
                est.inflate_position_covariance(self.cfg.readmit_inflation_m2)?;
            }
            self.excluded_intervals.push((t0, t));
            self.excluded_since = None;
            self.consistent_since = None;
            self.alarms_overridden = true;
        }
        Ok(())
    }
}

impl ResilientEstimator<'_> {
    /// Rewind to the state before the first buffered measurement group at or after
    /// `t_residue − rollback_lookback_s`, or at the onset [`crate::onset`] dates among the
    /// buffered fixes of the last [`ResilientConfig::rollback_onset_s`] up to `t_residue` when
    /// that is earlier, and replay every buffered input since, fusing no GPS (the fixes from
    /// `t_residue` on are the alarmed ones, those before it the ones the detection delay let
    /// through). The alarmed fix is among those searched only when its decision arrives after
    /// it was processed (latency above 0); at latency 0 the search ends at the fix before.
    ///
    /// A rewind to a step at or before the re-admission that ended an earlier exclusion undoes
    /// every fix fused since, so the exclusion is reopened: it runs on from its own start, and
    /// so does the clock of [`ResilientConfig::reset_after_s`]. Otherwise a detector that alarms
    /// again within the look-back of each re-admission would keep the estimate dead reckoning
    /// without ever reaching the reset that bounds it. An exclusion ended by a reset stays
    /// closed: the buffer starts at the reset, and replaying skips its fix but keeps the reset.
    fn rollback_to(&mut self, t_residue: f64) -> Result<()> {
        let mut from = t_residue - self.cfg.rollback_lookback_s - 1e-9;
        if self.cfg.rollback_onset_s > 0.0 {
            let since = t_residue - self.cfg.rollback_onset_s - 1e-9;
            let u: Vec<(f64, Vector3<f64>)> = self
                .buffer
                .iter()
                .filter_map(|e| match e {
                    Event::Meas(m, _, Some(u)) if m.t >= since && m.t <= t_residue + 1e-9 => Some((m.t, *u)),
                    _ => None,
                })
                .collect();
            if let Some(t_onset) = onset::mean_shift_onset(&u, NisGate::CHI2_3_999) {
                from = from.min(t_onset - 1e-9);
            }
        }
        let Some(start) = self.buffer.iter().position(|e| matches!(e, Event::Meas(m, ..) if m.t >= from)) else {
            return Ok(());
        };
        let Some(Event::Meas(m, ckpt, _)) = self.buffer.get(start) else { return Ok(()) };
        while let Some(&(t0, t1)) = self.excluded_intervals.last()
            && t1 >= m.t - 1e-9
            && t1 > self.last_reset + 1e-9
        {
            self.excluded_intervals.pop();
            self.excluded_since = Some(t0);
        }
        self.trend.truncate_from(m.t);
        let est = (**ckpt).clone();
        // The buffer is taken out while it is replayed, so each replayed group's innovation can
        // be noted on `self`; it is put back whatever the replay gives.
        let mut buffer = std::mem::take(&mut self.buffer);
        let replayed = self.replay(&mut buffer, start, est);
        self.buffer = buffer;
        self.est = Some(replayed?);
        self.n_rollbacks += 1;
        Ok(())
    }

    /// Replay `buffer` from index `start` onto `est` without GPS, refreshing each group's
    /// checkpoint and noted innovation ([`Self::note_gps`]).
    fn replay(&mut self, buffer: &mut VecDeque<Event>, start: usize, mut est: Estimator) -> Result<Estimator> {
        for ev in buffer.iter_mut().skip(start) {
            match ev {
                Event::Imu(s) => est.imu(s)?,
                Event::Meas(m, ck, u) => {
                    **ck = est.clone();
                    *u = est.measure(m, GpsFusion::Skip)?.and_then(|out| self.note_gps(&out));
                }
            }
        }
        Ok(est)
    }
}

/// The GPS part (`gps_x gps_y gps_z`) of an innovation and its covariance block, if the group
/// has a fix.
fn gps_innovation(out: &UpdateOutcome) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let mut idx = [0; 3];
    for (i, c) in GPS_CHANNELS.iter().enumerate() {
        idx[i] = out.channels.iter().position(|k| k == c)?;
    }
    Some((Vector3::from_fn(|i, _| out.r_k[idx[i]]), Matrix3::from_fn(|i, j| out.s_k[(idx[i], idx[j])])))
}

/// Pick `channels` (in that order) from an innovation: the sub-vector of `r_k`, the sub-block
/// of `S_k` (row-major) and its NIS `rᵀS⁻¹r`.
///
/// # Errors
/// [`FusionError::MissingChannel`] when a channel is absent; [`FusionError::Detect`] when the
/// sub-block is not positive definite.
pub fn select_channels<S: AsRef<str>>(out: &UpdateOutcome, channels: &[S]) -> Result<(Vec<f64>, Vec<f64>, f64)> {
    let mut idx = Vec::with_capacity(channels.len());
    for c in channels.iter().map(AsRef::as_ref) {
        match out.channels.iter().position(|k| *k == c) {
            Some(i) => idx.push(i),
            None => {
                return Err(FusionError::MissingChannel {
                    channel: c.to_owned(),
                    t: out.t,
                    available: out.channels.iter().map(|s| (*s).to_string()).collect(),
                });
            }
        }
    }
    let m = idx.len();
    let r = DVector::from_fn(m, |i, _| out.r_k[idx[i]]);
    let s = DMatrix::from_fn(m, m, |i, j| out.s_k[(idx[i], idx[j])]);
    let chol = s.clone().cholesky().ok_or_else(|| FusionError::Detect {
        t: out.t,
        source: ekf_residue::error::DetectError::Numerical {
            what: "innovation covariance sub-block not positive definite".into(),
        },
    })?;
    let nis = r.dot(&chol.solve(&r));
    let s_row_major: Vec<f64> = (0..m).flat_map(|i| (0..m).map(move |j| (i, j))).map(|(i, j)| s[(i, j)]).collect();
    Ok((r.iter().copied().collect(), s_row_major, nis))
}

/// The simplest online detector: alarm when the step's NIS exceeds a chi-squared quantile.
///
/// With the GPS channels (3-D) a threshold of 16.27 is the χ²₃ 0.999 quantile
/// (16.266 in standard χ² tables).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NisGate {
    threshold: f64,
}

impl NisGate {
    /// χ²₃ quantile at 1 − 0.001.
    pub const CHI2_3_999: f64 = 16.266;

    /// A gate with the given NIS threshold.
    ///
    /// # Errors
    /// [`FusionError::Config`] for a non-positive or non-finite threshold.
    pub fn new(threshold: f64) -> Result<Self> {
        if !(threshold.is_finite() && threshold > 0.0) {
            return Err(FusionError::Config { field: "threshold", msg: format!("must be positive, got {threshold}") });
        }
        Ok(Self { threshold })
    }
}

impl OnlineDetector for NisGate {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, ekf_residue::error::DetectError> {
        Ok(OnlineDecision { score: step.nis, alarm: step.nis > self.threshold })
    }

    fn reset(&mut self) {}
}
