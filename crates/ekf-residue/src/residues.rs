//! The residue generator of Algorithm 1 (paper alg:alg1): align the streams, initialise, then
//! Predict (eq:ekf_predict) with the IMU and Update (eq:ekf_update) at every measurement time,
//! recording `r_k = y_k − g(x̂_{k|k−1})` and `S_k`.
//!
//! Two entry points:
//! - [`generate_residues`]: one call from [`SensorStreams`] to a [`ResidueOutput`] (the
//!   [`ResidueSeries`] plus the state estimate after each residue step);
//! - [`Estimator`]: the same filter driven step by step (IMU samples and groups of simultaneous
//!   [`Measurements`]), returning the innovation of each update; GPS fusion can be skipped per
//!   update ([`GpsFusion::Skip`]) and the position covariance inflated on re-admission, as the
//!   resilient-fusion layer needs.
//!
//! Residue channels and times (decision record `docs/decisions/011-residue-channels-and-pairing.md`):
//! - Model I (eq:model1g): `gps_x gps_y gps_z att_roll att_pitch att_yaw`, one step per GPS fix
//!   that has an attitude sample within `pair_tolerance_s`; unpaired GPS fixes and attitude
//!   samples are fused alone (3-D updates) and produce no residue step.
//! - Model II (eq:model2g): `vo_x vo_y vo_z vo_roll vo_pitch vo_yaw`, plus `gps_x gps_y gps_z`
//!   when the flight has a GPS stream; one step per VO sample (stacked with its simultaneous GPS
//!   fix into one 9-D update). A VO sample without a simultaneous fix in a flight with GPS is
//!   fused (6-D) but gives no residue step; GPS fixes without VO are fused alone.
//!
//! Initialisation (`InitConfig`): at the first measurement group that holds a GPS fix and an
//! attitude sample (Model I), or a VO sample together with the GPS fix and attitude sample the
//! flight provides (Model II): `p̂ = ` the fix (Model II without GPS: the origin), `q̂ = ` the
//! attitude sample (Model II without attitude: roll and pitch levelled from the last IMU specific
//! force, yaw 0), `v̂ = v0`, biases 0, `P₀` diagonal from `InitConfig`. That group is consumed by
//! the initialisation and yields no residue step. Earlier samples are skipped.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector3};
use serde::{Deserialize, Serialize};
use uav_dynamics::model1::{self, IDX_BA, IDX_BG, IDX_P, IDX_Q, IDX_V, ImuInput};
use uav_dynamics::sensors::{ImuSample, SensorStreams, VoSample};

use crate::align::{AlignedEvent, DEFAULT_TOLERANCE_S, align};
use crate::ekf::{CovarianceUpdate, DivergenceGuard, Ekf, Innovation};
use crate::error::FilterError;
use crate::model1_filter::{ImuNoise, Model1Filter};
use crate::model2_filter::Model2Filter;
use crate::series::ResidueSeries;

/// Which UAV model the residue generator runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ModelKind {
    /// Model I: 15 states, GPS + attitude (eq:model1f, eq:model1g).
    ModelI,
    /// Model II: 21 states, GPS + VO with keyframe cloning (eq:model2f, eq:model2g).
    ModelII,
}

/// Model I residue channel names.
pub const MODEL1_CHANNELS: [&str; 6] = ["gps_x", "gps_y", "gps_z", "att_roll", "att_pitch", "att_yaw"];
/// Model II VO residue channel names.
pub const MODEL2_VO_CHANNELS: [&str; 6] = ["vo_x", "vo_y", "vo_z", "vo_roll", "vo_pitch", "vo_yaw"];
/// GPS-only residue channel names.
pub const GPS_CHANNELS: [&str; 3] = ["gps_x", "gps_y", "gps_z"];
/// Attitude-only residue channel names.
pub const ATT_CHANNELS: [&str; 3] = ["att_roll", "att_pitch", "att_yaw"];
/// Model II stacked VO + GPS residue channel names.
pub const MODEL2_VO_GPS_CHANNELS: [&str; 9] =
    ["vo_x", "vo_y", "vo_z", "vo_roll", "vo_pitch", "vo_yaw", "gps_x", "gps_y", "gps_z"];

/// Measurement noise standard deviations (the filter's `R_k = diag(σ²)`).
///
/// Defaults equal the simulator's sensor figures (`uav_dynamics::sim::SimConfig`, sources
/// collected in docs/sensors.md), so that a filter with default settings is consistent on
/// default simulated flights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasurementNoise {
    /// GPS position σ (E, N, U), metres. Default `[0.5, 0.5, 0.75]`: PX4 `EKF2_GPS_P_NOISE`
    /// 0.5 m horizontal, vertical 1.5× horizontal (PX4 gnss_height_control.cpp comment).
    pub gps_sigma_m: [f64; 3],
    /// Attitude reference σ (roll, pitch, yaw), radians. Default `[0.0175, 0.0175, 0.035]`
    /// (1° roll/pitch, 2° heading: VectorNav VN-100 AHRS data-sheet class).
    pub attitude_sigma_rad: [f64; 3],
    /// VO relative position σ, metres. Default 0.1 (PX4 `EKF2_EVP_NOISE`).
    pub vo_pos_sigma_m: [f64; 3],
    /// VO relative orientation σ, radians. Default 0.05 (simulator default, between PX4
    /// `EKF2_EVA_NOISE` 0.1 rad and typical stereo VO, docs/sensors.md).
    pub vo_att_sigma_rad: [f64; 3],
}

impl Default for MeasurementNoise {
    fn default() -> Self {
        Self {
            gps_sigma_m: [0.5, 0.5, 0.75],
            attitude_sigma_rad: [0.0175, 0.0175, 0.035],
            vo_pos_sigma_m: [0.1; 3],
            vo_att_sigma_rad: [0.05; 3],
        }
    }
}

/// Initial state and covariance (see the module doc for where `p̂` and `q̂` come from).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitConfig {
    /// Initial velocity `v̂₀`, m/s (ENU). Default 0 (flights start in hover).
    pub v0: [f64; 3],
    /// Initial velocity σ, m/s. Default 12: PX4's default horizontal cruise limit
    /// `MPC_XY_VEL_MAX`, so a flight that starts at any speed a default vehicle flies is within
    /// one σ (the first GPS fixes shrink it within a second).
    pub sigma_v0: f64,
    /// Initial gyro bias σ, rad/s. Default 8.7e-3 (0.5 °/s, PX4 SITL gyro turn-on bias σ).
    pub sigma_bg0: f64,
    /// Initial accelerometer bias σ, m/s². Default 0.196 (PX4 SITL accelerometer turn-on σ).
    pub sigma_ba0: f64,
    /// Initial yaw σ when no attitude sample is available (Model II), rad. Default 0.5.
    pub sigma_yaw0_unknown: f64,
}

impl Default for InitConfig {
    fn default() -> Self {
        Self { v0: [0.0; 3], sigma_v0: 12.0, sigma_bg0: 8.7e-3, sigma_ba0: 0.196, sigma_yaw0_unknown: 0.5 }
    }
}

/// Full configuration of the residue generator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    /// Model I or Model II.
    pub model: ModelKind,
    /// IMU noise for the process noise `Q`.
    pub imu: ImuNoise,
    /// Measurement noise `R`.
    pub meas: MeasurementNoise,
    /// Initial state and covariance.
    pub init: InitConfig,
    /// Covariance update form. Default Joseph.
    pub cov_update: CovarianceUpdate,
    /// Divergence criteria.
    pub guard: DivergenceGuard,
    /// Measurements closer than this are simultaneous, seconds. Default 1e-3
    /// ([`DEFAULT_TOLERANCE_S`]).
    pub pair_tolerance_s: f64,
}

impl FilterConfig {
    /// Defaults for the given model (every other field at its documented default).
    #[must_use]
    pub fn new(model: ModelKind) -> Self {
        Self {
            model,
            imu: ImuNoise::default(),
            meas: MeasurementNoise::default(),
            init: InitConfig::default(),
            cov_update: CovarianceUpdate::Joseph,
            guard: DivergenceGuard::default(),
            pair_tolerance_s: DEFAULT_TOLERANCE_S,
        }
    }

    /// A filter whose noise model matches a simulator configuration: IMU per-sample σ and bias
    /// random walks, GPS, attitude and VO σ, and the initial bias σ (floored at the defaults'
    /// 1 % so that `P₀` stays positive definite when the simulator starts unbiased).
    #[must_use]
    pub fn for_sim(model: ModelKind, sim: &uav_dynamics::sim::SimConfig) -> Self {
        let mut cfg = Self::new(model);
        cfg.imu = ImuNoise {
            gyro_sigma: sim.gyro_sigma(),
            accel_sigma: sim.accel_sigma(),
            gyro_bias_rw: sim.gyro_bias_walk,
            accel_bias_rw: sim.accel_bias_walk,
        };
        cfg.meas = MeasurementNoise {
            gps_sigma_m: sim.gps_sigma_m,
            attitude_sigma_rad: sim.attitude_sigma_rad,
            vo_pos_sigma_m: [sim.vo_pos_sigma_m; 3],
            vo_att_sigma_rad: [sim.vo_att_sigma_rad; 3],
        };
        let d = InitConfig::default();
        cfg.init.sigma_bg0 = sim.gyro_bias_init_sigma.max(0.01 * d.sigma_bg0);
        cfg.init.sigma_ba0 = sim.accel_bias_init_sigma.max(0.01 * d.sigma_ba0);
        cfg
    }

    /// Validate the configuration.
    ///
    /// # Errors
    /// [`FilterError::Config`] naming the field.
    pub fn check(&self) -> Result<(), FilterError> {
        let pos = |field: &'static str, v: &[f64]| {
            if v.iter().all(|x| x.is_finite() && *x > 0.0) {
                Ok(())
            } else {
                Err(FilterError::Config { field, msg: format!("must be finite and > 0, got {v:?}") })
            }
        };
        pos("meas.gps_sigma_m", &self.meas.gps_sigma_m)?;
        pos("meas.attitude_sigma_rad", &self.meas.attitude_sigma_rad)?;
        pos("meas.vo_pos_sigma_m", &self.meas.vo_pos_sigma_m)?;
        pos("meas.vo_att_sigma_rad", &self.meas.vo_att_sigma_rad)?;
        pos(
            "init.sigma_*",
            &[self.init.sigma_v0, self.init.sigma_bg0, self.init.sigma_ba0, self.init.sigma_yaw0_unknown],
        )?;
        let imu = [self.imu.gyro_sigma, self.imu.accel_sigma, self.imu.gyro_bias_rw, self.imu.accel_bias_rw];
        if !imu.iter().all(|x| x.is_finite() && *x >= 0.0) {
            return Err(FilterError::Config { field: "imu", msg: format!("must be finite and ≥ 0, got {imu:?}") });
        }
        Ok(())
    }
}

/// Whether a GPS fix is fused (online API).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GpsFusion {
    /// Fuse the fix. Default.
    #[default]
    Fuse,
    /// Compute the innovation against the prior but do not fuse the fix.
    Skip,
}

/// Simultaneous measurements for one update (online API). Positions in local ENU metres,
/// angles in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurements {
    /// Time in seconds.
    pub t: f64,
    /// GPS position fix.
    pub gps: Option<Vector3<f64>>,
    /// Attitude reference (ZYX Euler); used by Model I, ignored by Model II after initialisation.
    pub attitude: Option<Vector3<f64>>,
    /// VO relative pose (Model II; ignored by Model I).
    pub vo: Option<VoSample>,
}

/// The state estimate at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateEstimate {
    /// Time in seconds.
    pub t: f64,
    /// Position, m (ENU).
    pub p: Vector3<f64>,
    /// ZYX Euler angles, rad.
    pub q: Vector3<f64>,
    /// Velocity, m/s (ENU).
    pub v: Vector3<f64>,
    /// Gyro bias, rad/s.
    pub b_g: Vector3<f64>,
    /// Accelerometer bias, m/s².
    pub b_a: Vector3<f64>,
    /// Position covariance, m².
    pub p_cov: Matrix3<f64>,
    /// Orientation covariance, rad².
    pub q_cov: Matrix3<f64>,
    /// Velocity covariance, (m/s)².
    pub v_cov: Matrix3<f64>,
}

/// The innovation of one measurement group (online API).
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateOutcome {
    /// Time in seconds.
    pub t: f64,
    /// Channel names of `r_k` (one of the `*_CHANNELS` constants).
    pub channels: &'static [&'static str],
    /// `r_k` against the prior `x̂_{k|k−1}`, for all measurements in the group (also a skipped
    /// GPS fix), angle parts wrapped.
    pub r_k: DVector<f64>,
    /// `S_k = H P_{k|k−1} Hᵀ + R`.
    pub s_k: DMatrix<f64>,
    /// `r_kᵀ S_k⁻¹ r_k`.
    pub nis: f64,
    /// Whether the GPS fix (if any) was fused.
    pub gps_fused: bool,
}

fn outcome<const M: usize>(
    t: f64,
    channels: &'static [&'static str],
    inn: &Innovation<M>,
    gps_fused: bool,
) -> UpdateOutcome {
    UpdateOutcome {
        t,
        channels,
        r_k: DVector::from_column_slice(inn.r_k.as_slice()),
        s_k: DMatrix::from_column_slice(M, M, inn.s_k.as_slice()),
        nis: inn.nis,
        gps_fused,
    }
}

fn sq<const M: usize>(s: &[f64; M]) -> [f64; M] {
    s.map(|x| x * x)
}

#[derive(Debug, Clone, PartialEq)]
enum Filter {
    One(Box<Model1Filter>),
    Two(Box<Model2Filter>),
}

/// Step-by-step residue generator (Algorithm 1 driven online).
///
/// Feed IMU samples with [`Estimator::imu`] and measurement groups with
/// [`Estimator::measure`], in time order. Propagation uses the most recent IMU sample as a
/// zero-order hold up to each event time (the last IMU interval is split exactly at a
/// measurement time).
#[derive(Debug, Clone, PartialEq)]
pub struct Estimator {
    filter: Filter,
    cfg: FilterConfig,
    held: Option<ImuInput>,
}

impl Estimator {
    /// Start the filter at `t0_s` from an initial pose (position `p0`, ZYX Euler `q0`).
    ///
    /// `q0_known = false` marks the yaw as unknown (σ = `init.sigma_yaw0_unknown`, Model II
    /// without an attitude stream). `held` is the IMU sample to hold from `t0_s` on, if known.
    ///
    /// # Errors
    /// [`FilterError::Config`] for an invalid configuration, or as [`crate::ekf::Ekf::new`].
    pub fn new(
        cfg: &FilterConfig,
        t0_s: f64,
        p0: &Vector3<f64>,
        q0: &Vector3<f64>,
        q0_known: bool,
        held: Option<&ImuSample>,
    ) -> Result<Self, FilterError> {
        cfg.check()?;
        let v0 = Vector3::from(cfg.init.v0);
        let x0 = model1::state(p0, q0, &v0, &Vector3::zeros(), &Vector3::zeros());
        let mut var = [0.0; 15];
        // P₀: the pose variances of the sensors that gave p̂₀ and q̂₀.
        let (pos_sigma, att_sigma) = (cfg.meas.gps_sigma_m, cfg.meas.attitude_sigma_rad);
        for i in 0..3 {
            var[IDX_P + i] = pos_sigma[i] * pos_sigma[i];
            var[IDX_Q + i] = att_sigma[i] * att_sigma[i];
            var[IDX_V + i] = cfg.init.sigma_v0 * cfg.init.sigma_v0;
            var[IDX_BG + i] = cfg.init.sigma_bg0 * cfg.init.sigma_bg0;
            var[IDX_BA + i] = cfg.init.sigma_ba0 * cfg.init.sigma_ba0;
        }
        if !q0_known {
            var[IDX_Q + 2] = cfg.init.sigma_yaw0_unknown * cfg.init.sigma_yaw0_unknown;
        }
        let p0_cov = SMatrix::<f64, 15, 15>::from_diagonal(&SVector::<f64, 15>::from_column_slice(&var));
        let filter = match cfg.model {
            ModelKind::ModelI => {
                Filter::One(Box::new(Model1Filter::new(x0, p0_cov, t0_s, cfg.imu, cfg.cov_update, cfg.guard)?))
            }
            ModelKind::ModelII => {
                Filter::Two(Box::new(Model2Filter::new(x0, p0_cov, t0_s, cfg.imu, cfg.cov_update, cfg.guard)?))
            }
        };
        Ok(Self { filter, cfg: *cfg, held: held.map(ImuInput::from) })
    }

    /// Filter time in seconds.
    #[must_use]
    pub fn t(&self) -> f64 {
        match &self.filter {
            Filter::One(f) => f.t(),
            Filter::Two(f) => f.t(),
        }
    }

    /// The configuration in use.
    #[must_use]
    pub fn config(&self) -> &FilterConfig {
        &self.cfg
    }

    /// Propagate with the held IMU sample to `t_s` (no-op if `t_s` equals the filter time).
    fn propagate_to(&mut self, stream: &'static str, t_s: f64) -> Result<(), FilterError> {
        let t_filter = self.t();
        let dt = t_s - t_filter;
        if dt < 0.0 {
            return Err(FilterError::InThePast { stream, t: t_s, t_filter });
        }
        if dt == 0.0 {
            return Ok(());
        }
        let u = self
            .held
            .ok_or_else(|| FilterError::NoData { msg: format!("no IMU sample before {stream} at t = {t_s} s") })?;
        // eq:ekf_predict with the Euler-discretised model over [t_filter, t_s].
        match &mut self.filter {
            Filter::One(f) => f.predict(&u, dt),
            Filter::Two(f) => f.predict(&u, dt),
        }
    }

    /// Feed one IMU sample: propagate to its time with the previous sample, then hold it.
    ///
    /// # Errors
    /// [`FilterError::NonFiniteInput`], [`FilterError::InThePast`], or a filter error.
    pub fn imu(&mut self, s: &ImuSample) -> Result<(), FilterError> {
        if !(s.t.is_finite() && s.gyro.iter().chain(s.accel.iter()).all(|v| v.is_finite())) {
            return Err(FilterError::NonFiniteInput { stream: "imu", idx: 0, t: s.t, field: "sample" });
        }
        if self.held.is_some() {
            self.propagate_to("imu", s.t)?;
        } else if s.t < self.t() {
            return Err(FilterError::InThePast { stream: "imu", t: s.t, t_filter: self.t() });
        }
        // Without a held sample (none before t0), this first sample is also held over [t0, s.t].
        self.held = Some(ImuInput::from(s));
        Ok(())
    }

    /// Propagate to `m.t` and update with the measurements of the group.
    ///
    /// Returns `None` when the group holds nothing this model uses. The returned innovation is
    /// against the prior and covers every used measurement of the group, including a GPS fix
    /// that is not fused (`gps = GpsFusion::Skip`).
    ///
    /// # Errors
    /// [`FilterError::NonFiniteInput`], [`FilterError::InThePast`], [`FilterError::NoData`]
    /// (no IMU sample yet), or a filter error.
    pub fn measure(&mut self, m: &Measurements, gps: GpsFusion) -> Result<Option<UpdateOutcome>, FilterError> {
        check_measurements(m)?;
        self.propagate_to("measurement", m.t)?;
        let t = m.t;
        let meas = self.cfg.meas;
        let fuse = gps == GpsFusion::Fuse;
        let r_gps = sq(&meas.gps_sigma_m);
        let out = match &mut self.filter {
            Filter::One(f) => {
                let r_att = sq(&meas.attitude_sigma_rad);
                match (m.gps, m.attitude) {
                    (Some(p), Some(q)) => {
                        let r6 = [r_gps[0], r_gps[1], r_gps[2], r_att[0], r_att[1], r_att[2]];
                        let inn = if fuse {
                            f.update_pose(&p, &q, &r6)?
                        } else {
                            let inn = f.pose_innovation(&p, &q, &r6)?;
                            f.update_attitude(&q, &r_att)?;
                            inn
                        };
                        Some(outcome(t, &MODEL1_CHANNELS, &inn, fuse))
                    }
                    (Some(p), None) => {
                        let inn = if fuse { f.update_gps(&p, &r_gps)? } else { f.gps_innovation(&p, &r_gps)? };
                        Some(outcome(t, &GPS_CHANNELS, &inn, fuse))
                    }
                    (None, Some(q)) => Some(outcome(t, &ATT_CHANNELS, &f.update_attitude(&q, &r_att)?, false)),
                    (None, None) => None,
                }
            }
            Filter::Two(f) => {
                let r_vo = [
                    meas.vo_pos_sigma_m[0],
                    meas.vo_pos_sigma_m[1],
                    meas.vo_pos_sigma_m[2],
                    meas.vo_att_sigma_rad[0],
                    meas.vo_att_sigma_rad[1],
                    meas.vo_att_sigma_rad[2],
                ]
                .map(|x| x * x);
                match (m.vo, m.gps) {
                    (Some(vo), Some(p)) => {
                        let r9 = [r_vo[0], r_vo[1], r_vo[2], r_vo[3], r_vo[4], r_vo[5], r_gps[0], r_gps[1], r_gps[2]];
                        let inn = if fuse {
                            f.update_vo_gps(&vo, &p, &r9)?
                        } else {
                            let inn = f.vo_gps_innovation(&vo, &p, &r9)?;
                            f.update_vo(&vo, &r_vo)?;
                            inn
                        };
                        Some(outcome(t, &MODEL2_VO_GPS_CHANNELS, &inn, fuse))
                    }
                    (Some(vo), None) => Some(outcome(t, &MODEL2_VO_CHANNELS, &f.update_vo(&vo, &r_vo)?, false)),
                    (None, Some(p)) => {
                        let inn = if fuse { f.update_gps(&p, &r_gps)? } else { f.gps_innovation(&p, &r_gps)? };
                        Some(outcome(t, &GPS_CHANNELS, &inn, fuse))
                    }
                    (None, None) => None,
                }
            }
        };
        Ok(out)
    }

    /// Add `var_m2` to the position variances (e.g. when re-admitting GPS after an alarm, so
    /// the first fixes pull the estimate back quickly).
    ///
    /// # Errors
    /// [`FilterError::Config`] for a negative or non-finite `var_m2`.
    pub fn inflate_position_covariance(&mut self, var_m2: f64) -> Result<(), FilterError> {
        if !(var_m2.is_finite() && var_m2 >= 0.0) {
            return Err(FilterError::Config {
                field: "var_m2", msg: format!("must be finite and ≥ 0, got {var_m2}")
            });
        }
        let t = self.t();
        match &mut self.filter {
            Filter::One(f) => {
                let mut dp = SMatrix::<f64, 15, 15>::zeros();
                dp.fixed_view_mut::<3, 3>(IDX_P, IDX_P).fill_with_identity();
                f.ekf_mut().add_covariance(&(dp * var_m2), t)
            }
            Filter::Two(f) => {
                let mut dp = SMatrix::<f64, 21, 21>::zeros();
                dp.fixed_view_mut::<3, 3>(IDX_P, IDX_P).fill_with_identity();
                f.ekf_mut().add_covariance(&(dp * var_m2), t)
            }
        }
    }

    /// Reset onto a GNSS fix after a long rejection, as PX4 EKF2 does when GNSS fusion has
    /// timed out (`resetVelocityToGnss` and `resetHorizontalPositionToGnss`): the position
    /// estimate moves onto `p` (metres, ENU). The velocity, whose error drove the dead
    /// reckoning away from the fixes, takes `velocity = Some((v, var))` (m/s, ENU, variance
    /// `var` on each axis, e.g. from the trend of the unfused fixes' innovations; this GPS
    /// reports no velocity of its own), or with `None` is known again only as at initialisation
    /// (variance `InitConfig::sigma_v0²`, estimate kept). The accelerometer bias is always known
    /// again only as at initialisation (variance `sigma_ba0²`). Either block loses its
    /// correlations ([`crate::ekf::Ekf::reset_block`]), so the next fixes re-estimate it. The
    /// position covariance, grown while GPS was rejected, is kept. Model II's keyframe position
    /// moves by the same offset, so the pending VO increment still reads relative to the reset
    /// position.
    ///
    /// # Errors
    /// [`FilterError::NonFiniteState`] for a non-finite `p` or `v`, [`FilterError::Config`]
    /// for a negative or non-finite `var`.
    pub fn reset_onto_fix(
        &mut self,
        p: &Vector3<f64>,
        velocity: Option<(Vector3<f64>, f64)>,
    ) -> Result<(), FilterError> {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t: self.t(), what: "reset position" });
        }
        if velocity.is_some_and(|(v, _)| !v.iter().all(|c| c.is_finite())) {
            return Err(FilterError::NonFiniteState { t: self.t(), what: "reset velocity" });
        }
        if let Some((_, var)) = velocity
            && !(var.is_finite() && var >= 0.0)
        {
            return Err(FilterError::Config { field: "var", msg: format!("must be finite and ≥ 0, got {var}") });
        }
        let var_v = velocity.map_or(self.cfg.init.sigma_v0 * self.cfg.init.sigma_v0, |(_, var)| var);
        let var_ba = self.cfg.init.sigma_ba0 * self.cfg.init.sigma_ba0;
        let v = velocity.map(|(v, _)| v);
        fn reset_states<const N: usize>(
            ekf: &mut Ekf<N>,
            p: &Vector3<f64>,
            v: Option<Vector3<f64>>,
            var_v: f64,
            var_ba: f64,
        ) -> Result<(), FilterError> {
            ekf.map_state(|x| {
                x.fixed_rows_mut::<3>(IDX_P).copy_from(p);
                if let Some(v) = v {
                    x.fixed_rows_mut::<3>(IDX_V).copy_from(&v);
                }
            });
            ekf.reset_block::<3>(IDX_V, var_v)?;
            ekf.reset_block::<3>(IDX_BA, var_ba)
        }
        match &mut self.filter {
            Filter::One(f) => reset_states(f.ekf_mut(), p, v, var_v, var_ba),
            Filter::Two(f) => {
                let ekf = f.ekf_mut();
                ekf.map_state(|x| {
                    let delta = p - x.fixed_rows::<3>(IDX_P);
                    let pf = x.fixed_rows::<3>(uav_dynamics::model2::IDX_PF) + delta;
                    x.fixed_rows_mut::<3>(uav_dynamics::model2::IDX_PF).copy_from(&pf);
                });
                reset_states(ekf, p, v, var_v, var_ba)
            }
        }
    }

    /// The current estimate (first 15 states) with covariance blocks.
    #[must_use]
    pub fn estimate(&self) -> StateEstimate {
        let (x, p): (SVector<f64, 15>, SMatrix<f64, 15, 15>) = match &self.filter {
            Filter::One(f) => (*f.ekf().x(), *f.ekf().p()),
            Filter::Two(f) => {
                (f.ekf().x().fixed_rows::<15>(0).into_owned(), f.ekf().p().fixed_view::<15, 15>(0, 0).into_owned())
            }
        };
        StateEstimate {
            t: self.t(),
            p: model1::block(&x, IDX_P),
            q: model1::block(&x, IDX_Q),
            v: model1::block(&x, IDX_V),
            b_g: model1::block(&x, IDX_BG),
            b_a: model1::block(&x, IDX_BA),
            p_cov: p.fixed_view::<3, 3>(IDX_P, IDX_P).into_owned(),
            q_cov: p.fixed_view::<3, 3>(IDX_Q, IDX_Q).into_owned(),
            v_cov: p.fixed_view::<3, 3>(IDX_V, IDX_V).into_owned(),
        }
    }

    /// Trace of the full covariance `P` (divergence monitoring, tests).
    #[must_use]
    pub fn covariance_trace(&self) -> f64 {
        match &self.filter {
            Filter::One(f) => f.ekf().p().trace(),
            Filter::Two(f) => f.ekf().p().trace(),
        }
    }

    /// The smallest eigenvalue and the largest asymmetry `|P − Pᵀ|` of `P` (tests).
    #[must_use]
    pub fn covariance_health(&self) -> (f64, f64) {
        let p = match &self.filter {
            Filter::One(f) => DMatrix::from_column_slice(15, 15, f.ekf().p().as_slice()),
            Filter::Two(f) => DMatrix::from_column_slice(21, 21, f.ekf().p().as_slice()),
        };
        let asym = (&p - p.transpose()).abs().max();
        let min_eig = p.symmetric_eigenvalues().min();
        (min_eig, asym)
    }
}

fn check_measurements(m: &Measurements) -> Result<(), FilterError> {
    let bad = |stream: &'static str, field: &'static str| FilterError::NonFiniteInput { stream, idx: 0, t: m.t, field };
    if !m.t.is_finite() {
        return Err(bad("measurement", "t"));
    }
    if m.gps.is_some_and(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(bad("gps", "p"));
    }
    if m.attitude.is_some_and(|q| !q.iter().all(|v| v.is_finite())) {
        return Err(bad("attitude", "q"));
    }
    if m.vo.is_some_and(|vo| !vo.p_rel.iter().chain(vo.q_rel.iter()).all(|v| v.is_finite())) {
        return Err(bad("vo", "pose"));
    }
    Ok(())
}

/// Output of [`generate_residues`].
#[derive(Debug, Clone, PartialEq)]
pub struct ResidueOutput {
    /// The residue series (channels per the module doc).
    pub series: ResidueSeries,
    /// The posterior estimate after each residue step (same length as `series`).
    pub estimates: Vec<StateEstimate>,
    /// Measurement groups fused without a residue step (unpaired samples, see module doc).
    pub n_unrecorded_updates: usize,
}

/// Run Algorithm 1 (alg:alg1) over a flight: align, initialise, predict and update, record
/// the residue series.
///
/// # Errors
/// Input errors from [`align`] naming stream, index and time; [`FilterError::NoData`] when the
/// streams cannot initialise the chosen model or give no residue step; filter errors
/// (not positive definite, divergence, gimbal lock) with the filter time.
pub fn generate_residues(streams: &SensorStreams, cfg: &FilterConfig) -> Result<ResidueOutput, FilterError> {
    cfg.check()?;
    let events = align(streams, cfg.pair_tolerance_s)?;
    let has_gps = !streams.gps.is_empty();
    let has_att = !streams.attitude.is_empty();
    let channels: &'static [&'static str] = match cfg.model {
        ModelKind::ModelI => &MODEL1_CHANNELS,
        ModelKind::ModelII if has_gps => &MODEL2_VO_GPS_CHANNELS,
        ModelKind::ModelII => &MODEL2_VO_CHANNELS,
    };
    let mut est: Option<Estimator> = None;
    let mut last_imu: Option<&ImuSample> = None;
    let (mut t, mut r, mut s, mut estimates) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut n_unrecorded = 0;
    for ev in &events {
        match ev {
            AlignedEvent::Imu(i) => {
                let sample = &streams.imu[*i];
                if let Some(e) = est.as_mut() {
                    e.imu(sample)?;
                }
                last_imu = Some(sample);
            }
            AlignedEvent::Measurements(g) => {
                let m = Measurements {
                    t: g.t,
                    gps: g.gps.map(|i| streams.gps[i].p),
                    attitude: g.attitude.map(|i| streams.attitude[i].q),
                    vo: g.vo.map(|i| streams.vo[i]),
                };
                let Some(e) = est.as_mut() else {
                    // Initialisation (module doc).
                    let Some(imu) = last_imu else { continue };
                    let ready = match cfg.model {
                        ModelKind::ModelI => m.gps.is_some() && m.attitude.is_some(),
                        ModelKind::ModelII => {
                            m.vo.is_some() && (m.gps.is_some() || !has_gps) && (m.attitude.is_some() || !has_att)
                        }
                    };
                    if !ready {
                        continue;
                    }
                    let p0 = m.gps.unwrap_or_else(Vector3::zeros);
                    let (q0, known) = match m.attitude {
                        Some(q) => (q, true),
                        None => (level_from_accel(&imu.accel), false),
                    };
                    let mut new = Estimator::new(cfg, m.t, &p0, &q0, known, Some(imu))?;
                    if let (ModelKind::ModelII, Some(vo)) = (cfg.model, m.vo) {
                        // The first VO sample defines the first keyframe.
                        new.measure(
                            &Measurements { t: m.t, gps: None, attitude: None, vo: Some(vo) },
                            GpsFusion::Fuse,
                        )?;
                    }
                    est = Some(new);
                    continue;
                };
                match e.measure(&m, GpsFusion::Fuse)? {
                    Some(out) if out.channels == channels => {
                        t.push(out.t);
                        r.push(out.r_k.as_slice().to_vec());
                        s.push(out.s_k);
                        estimates.push(e.estimate());
                    }
                    Some(_) => n_unrecorded += 1,
                    None => {}
                }
            }
        }
    }
    if est.is_none() {
        return Err(FilterError::NoData {
            msg: format!(
                "{:?} could not initialise: no measurement group with the required sensors after an IMU sample",
                cfg.model
            ),
        });
    }
    let series = ResidueSeries::new(t, channels.iter().map(|c| (*c).to_string()).collect(), r, s)?;
    Ok(ResidueOutput { series, estimates, n_unrecorded_updates: n_unrecorded })
}

/// Roll and pitch from a specific-force sample assuming no acceleration (yaw 0).
fn level_from_accel(a: &Vector3<f64>) -> Vector3<f64> {
    let roll = a[1].atan2(a[2]);
    let pitch = (-a[0]).atan2(a[1].hypot(a[2]));
    Vector3::new(roll, pitch, 0.0)
}
