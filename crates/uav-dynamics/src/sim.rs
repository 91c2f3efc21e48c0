//! Flight simulator: true quadrotor states from a reference by differential flatness, and the
//! multi-rate sensor streams of Model I and Model II (paper eq:model1f, eq:model1g,
//! eq:model2g; default rates of docs/decisions/020-sensor-noise-and-rates.md).
//!
//! Truth (world ENU, z up, `g = [0, 0, −9.81]` m/s², ZYX Euler `q = [φ, θ, ψ]`):
//!
//! - specific thrust `t = a − g`, body z axis `z_B = t/|t|`, yaw `ψ` from the reference; with
//!   `w = Rz(−ψ)·z_B = [cφ sθ, −sφ, cφ cθ]` the roll and pitch are `θ = atan2(w_x, w_z)`,
//!   `φ = atan2(−w_y, √(w_x² + w_z²))` ([`flat_attitude`]);
//! - Euler rates from the derivative of `w` (which needs the jerk), body rates `ω = G(q)·q̇`.
//!
//! Sensors at step `k` (time `t_k = k / f_IMU`, all times exact multiples of their period from
//! `t = 0`, so GPS, attitude and VO at 10 Hz coincide with every 20th IMU sample):
//!
//! - IMU: `ω_m = ω + b_g + n_g`, `a_m = Rᵀ(a − g) + b_a + n_a`; per-sample σ = density·√f_IMU;
//!   biases random-walk `b ← b + σ_rw·√dt·n` after each sample;
//! - GPS: `p + n_p` (local ENU metres, after alg:alg1's coordinate transformation);
//! - attitude reference: `wrap(q + n_q)`;
//! - VO: relative pose to the current keyframe `[R(q_F)ᵀ(p − p_F) + n; wrap(Euler(R(q_F)ᵀR(q)) + n)]`
//!   (eq:model2g); a keyframe starts every `keyframe_period_s`, at a VO sample time, with the
//!   true pose; its first sample has zero relative pose up to noise.
//!
//! Every noise term has the configured [`NoiseShape`](crate::noise::NoiseShape) and σ.
//! Noise figures and their sources are listed in docs/sensors.md.

use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;
use rand::rngs::StdRng;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::noise::NoiseConfig;
use crate::rotation::{euler_from_matrix, euler_rate_to_body, rotation_matrix, wrap_angle, wrap_euler};
use crate::sensors::{AttitudeSample, Flight, GpsSample, ImuSample, SensorStreams, TruthSample, VoSample};
use crate::trajectory::Trajectory;

/// Standard gravity in m/s² (ENU: `g = [0, 0, −GRAVITY]`).
pub const GRAVITY: f64 = 9.81;

/// Gravity vector `g` in the ENU world frame.
#[must_use]
pub fn gravity() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, -GRAVITY)
}

/// Simulator configuration: sensor rates, noise figures and noise shape.
///
/// Every default cites its source; docs/sensors.md collects them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    /// IMU rate in Hz. Default 200 (EuRoC VI-sensor ADIS16448; docs/decisions/020).
    pub imu_rate_hz: u32,
    /// GPS rate in Hz; must divide the IMU rate. Default 10 (u-blox M8/M9 receivers run at
    /// 5–10 Hz; docs/decisions/020).
    pub gps_rate_hz: u32,
    /// Attitude reference rate in Hz; must divide the IMU rate. Default 10, the GPS rate, so that
    /// Model I pairs every fix with an attitude sample (docs/decisions/020).
    pub attitude_rate_hz: u32,
    /// VO rate in Hz; must divide the IMU rate. Default 10, the GPS rate (EuRoC cameras run at
    /// 20 Hz; docs/decisions/020).
    pub vo_rate_hz: u32,
    /// Keyframe period in seconds; a whole number of VO periods. Default 1 (a choice;
    /// docs/decisions/020).
    pub keyframe_period_s: f64,
    /// Gyroscope white-noise density in rad/s/√Hz. Default 1.6968e-4 (EuRoC ADIS16448
    /// sensor.yaml).
    pub gyro_noise_density: f64,
    /// Gyroscope bias random walk in rad/s²/√Hz. Default 1.9393e-5 (EuRoC ADIS16448 sensor.yaml).
    pub gyro_bias_walk: f64,
    /// Accelerometer white-noise density in m/s²/√Hz. Default 2.0e-3 (EuRoC ADIS16448
    /// sensor.yaml).
    pub accel_noise_density: f64,
    /// Accelerometer bias random walk in m/s³/√Hz. Default 3.0e-3 (EuRoC ADIS16448 sensor.yaml).
    pub accel_bias_walk: f64,
    /// Standard deviation of the initial gyroscope bias per axis in rad/s. Default 0: the
    /// autopilot calibrates gyros at start-up (PX4 SITL's turn-on figure is 0.5°/s ≈ 8.7e-3).
    pub gyro_bias_init_sigma: f64,
    /// Standard deviation of the initial accelerometer bias per axis in m/s². Default 0: the
    /// vehicle is calibrated before take-off (PX4 SITL's turn-on figure is 0.196).
    pub accel_bias_init_sigma: f64,
    /// GPS position σ per ENU axis in metres. Default `[0.5, 0.5, 0.75]`: PX4 EKF2_GPS_P_NOISE
    /// 0.5 m horizontal, vertical 1.5× horizontal (PX4 gnss_height_control.cpp).
    pub gps_sigma_m: [f64; 3],
    /// Attitude reference σ per Euler angle in radians. Default `[0.0175, 0.0175, 0.035]`:
    /// 1° roll/pitch (dynamic) and 2° heading, VectorNav VN-100 AHRS datasheet class.
    pub attitude_sigma_rad: [f64; 3],
    /// VO relative-position σ per axis in metres. Default 0.1 (PX4 EKF2_EVP_NOISE).
    pub vo_pos_sigma_m: f64,
    /// VO relative-attitude σ per Euler angle in radians. Default 0.05 (between the PX4
    /// EKF2_EVA_NOISE 0.1 rad tuning floor and the 0.02 rad of typical stereo VO; see
    /// docs/sensors.md).
    pub vo_att_sigma_rad: f64,
    /// Noise shape and its centring/scaling switches. Default Gaussian, centred, equal σ.
    #[serde(default)]
    pub noise: NoiseConfig,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            imu_rate_hz: 200,
            gps_rate_hz: 10,
            attitude_rate_hz: 10,
            vo_rate_hz: 10,
            keyframe_period_s: 1.0,
            gyro_noise_density: 1.6968e-4,
            gyro_bias_walk: 1.9393e-5,
            accel_noise_density: 2.0e-3,
            accel_bias_walk: 3.0e-3,
            gyro_bias_init_sigma: 0.0,
            accel_bias_init_sigma: 0.0,
            gps_sigma_m: [0.5, 0.5, 0.75],
            attitude_sigma_rad: [0.0175, 0.0175, 0.035],
            vo_pos_sigma_m: 0.1,
            vo_att_sigma_rad: 0.05,
            noise: NoiseConfig::default(),
        }
    }
}

impl SimConfig {
    /// Same configuration with every noise σ, bias walk and initial bias set to zero (for
    /// tests that need exact sensor values).
    #[must_use]
    pub fn noiseless(&self) -> Self {
        Self {
            gyro_noise_density: 0.0,
            gyro_bias_walk: 0.0,
            accel_noise_density: 0.0,
            accel_bias_walk: 0.0,
            gyro_bias_init_sigma: 0.0,
            accel_bias_init_sigma: 0.0,
            gps_sigma_m: [0.0; 3],
            attitude_sigma_rad: [0.0; 3],
            vo_pos_sigma_m: 0.0,
            vo_att_sigma_rad: 0.0,
            ..self.clone()
        }
    }

    /// Per-sample gyroscope σ in rad/s (`density·√f_IMU`).
    #[must_use]
    pub fn gyro_sigma(&self) -> f64 {
        self.gyro_noise_density * f64::from(self.imu_rate_hz).sqrt()
    }

    /// Per-sample accelerometer σ in m/s² (`density·√f_IMU`).
    #[must_use]
    pub fn accel_sigma(&self) -> f64 {
        self.accel_noise_density * f64::from(self.imu_rate_hz).sqrt()
    }

    /// Validate and derive the integer step ratios.
    ///
    /// # Errors
    /// [`Error::Config`] naming the field: a zero rate, a rate that does not divide the IMU
    /// rate, a keyframe period that is not a whole number of VO periods, or a negative or
    /// non-finite σ.
    pub fn check(&self) -> Result<ValidSimConfig> {
        if self.imu_rate_hz == 0 {
            return Err(Error::Config { field: "imu_rate_hz", msg: "must be positive".into() });
        }
        let ratio = |field: &'static str, rate: u32| -> Result<u64> {
            if rate == 0 || !self.imu_rate_hz.is_multiple_of(rate) {
                return Err(Error::Config {
                    field,
                    msg: format!("{rate} Hz must be positive and divide imu_rate_hz = {}", self.imu_rate_hz),
                });
            }
            Ok(u64::from(self.imu_rate_hz / rate))
        };
        let imu_per_gps = ratio("gps_rate_hz", self.gps_rate_hz)?;
        let imu_per_attitude = ratio("attitude_rate_hz", self.attitude_rate_hz)?;
        let imu_per_vo = ratio("vo_rate_hz", self.vo_rate_hz)?;
        let vo_per_kf_f = self.keyframe_period_s * f64::from(self.vo_rate_hz);
        let vo_per_keyframe = vo_per_kf_f.round();
        if !(vo_per_kf_f.is_finite() && vo_per_keyframe >= 1.0 && (vo_per_kf_f - vo_per_keyframe).abs() < 1e-9) {
            return Err(Error::Config {
                field: "keyframe_period_s",
                msg: format!(
                    "{} s is not a whole number of VO periods (1/{} s)",
                    self.keyframe_period_s, self.vo_rate_hz
                ),
            });
        }
        let scalars = [
            ("gyro_noise_density", self.gyro_noise_density),
            ("gyro_bias_walk", self.gyro_bias_walk),
            ("accel_noise_density", self.accel_noise_density),
            ("accel_bias_walk", self.accel_bias_walk),
            ("gyro_bias_init_sigma", self.gyro_bias_init_sigma),
            ("accel_bias_init_sigma", self.accel_bias_init_sigma),
            ("vo_pos_sigma_m", self.vo_pos_sigma_m),
            ("vo_att_sigma_rad", self.vo_att_sigma_rad),
        ];
        let arrays = [("gps_sigma_m", self.gps_sigma_m), ("attitude_sigma_rad", self.attitude_sigma_rad)];
        let all = scalars.into_iter().chain(arrays.into_iter().flat_map(|(f, a)| a.map(|v| (f, v))));
        for (field, v) in all {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::Config { field, msg: format!("must be finite and non-negative, got {v}") });
            }
        }
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let vo_per_keyframe = vo_per_keyframe as u64;
        Ok(ValidSimConfig { cfg: self.clone(), imu_per_gps, imu_per_attitude, imu_per_vo, vo_per_keyframe })
    }
}

/// A [`SimConfig`] that passed [`SimConfig::check`], with the derived step ratios.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidSimConfig {
    cfg: SimConfig,
    imu_per_gps: u64,
    imu_per_attitude: u64,
    imu_per_vo: u64,
    vo_per_keyframe: u64,
}

impl ValidSimConfig {
    /// The checked configuration.
    #[must_use]
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// IMU period in seconds.
    #[must_use]
    pub fn dt_s(&self) -> f64 {
        1.0 / f64::from(self.cfg.imu_rate_hz)
    }

    /// Time of IMU step `k`, computed as `k / f_IMU` so that coinciding sensor times are
    /// bit-identical.
    #[must_use]
    #[allow(clippy::cast_precision_loss)]
    pub fn time_of_step(&self, k: u64) -> f64 {
        k as f64 / f64::from(self.cfg.imu_rate_hz)
    }

    /// Number of IMU steps with `t_k ≤ duration_s` (at least one).
    #[must_use]
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    pub fn n_steps(&self, duration_s: f64) -> u64 {
        let n = (duration_s.max(0.0) * f64::from(self.cfg.imu_rate_hz) + 1e-9).floor();
        if n.is_finite() { n as u64 + 1 } else { 1 }
    }
}

/// Attitude, body rates and thrust of a quadrotor following given flat outputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlatAttitude {
    /// ZYX Euler angles `[φ, θ, ψ]`, wrapped to (−π, π].
    pub q: Vector3<f64>,
    /// Body → world rotation `R(q)`.
    pub r: Matrix3<f64>,
    /// Body angular rate `ω` in rad/s.
    pub omega: Vector3<f64>,
    /// Magnitude of the specific thrust `|a − g|` in m/s² (the accelerometer's true z reading).
    pub thrust: f64,
}

/// Smallest specific thrust the flatness map accepts, m/s² (below it the thrust direction,
/// and with it the attitude, is undefined).
pub const MIN_THRUST: f64 = 0.05 * GRAVITY;

/// Attitude and body rates from acceleration `a`, jerk `j`, yaw and yaw rate (differential
/// flatness in the ZYX convention; formulas in the module doc).
///
/// # Errors
/// [`Error::Flatness`] (at time `t_s`) when the specific thrust is below [`MIN_THRUST`], points
/// below the horizon, or an input is non-finite.
pub fn flat_attitude(a: &Vector3<f64>, j: &Vector3<f64>, yaw: f64, yaw_rate: f64, t_s: f64) -> Result<FlatAttitude> {
    let thrust_vec = a - gravity();
    let f = thrust_vec.norm();
    if !(f.is_finite() && j.iter().all(|x| x.is_finite()) && yaw.is_finite() && yaw_rate.is_finite()) {
        return Err(Error::Flatness { t_s, msg: "non-finite acceleration, jerk or yaw".into() });
    }
    if f < MIN_THRUST {
        return Err(Error::Flatness { t_s, msg: format!("specific thrust {f:.3} m/s² (free fall)") });
    }
    let z_b = thrust_vec / f;
    let (sp, cp) = yaw.sin_cos();
    // w = Rz(−ψ)·z_B.
    let w = Vector3::new(cp * z_b.x + sp * z_b.y, -sp * z_b.x + cp * z_b.y, z_b.z);
    if w.z <= 1e-6 {
        return Err(Error::Flatness { t_s, msg: format!("thrust direction {z_b:?} at or below the horizon") });
    }
    let rho2 = w.x * w.x + w.z * w.z;
    let rho = rho2.sqrt();
    let theta = w.x.atan2(w.z);
    let phi = (-w.y).atan2(rho);
    // ż_B = (j − z_B (z_B·j)) / |t|;  ẇ = Rz(−ψ)(ż_B − ψ̇ e₃ × z_B).
    let zd = (j - z_b * z_b.dot(j)) / f;
    let u = zd - Vector3::new(-z_b.y, z_b.x, 0.0) * yaw_rate;
    let wd = Vector3::new(cp * u.x + sp * u.y, -sp * u.x + cp * u.y, u.z);
    let theta_dot = (w.z * wd.x - w.x * wd.z) / rho2;
    let rho_dot = (w.x * wd.x + w.z * wd.z) / rho;
    let phi_dot = (w.y * rho_dot - rho * wd.y) / (rho2 + w.y * w.y);
    let q = Vector3::new(phi, theta, wrap_angle(yaw));
    // ω = G(q)·q̇ (rotation module doc).
    let omega = euler_rate_to_body(&q) * Vector3::new(phi_dot, theta_dot, yaw_rate);
    Ok(FlatAttitude { q, r: rotation_matrix(&q), omega, thrust: f })
}

/// Kinematic truth of one IMU step, as input to the sensor models.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Kinematics {
    pub p: Vector3<f64>,
    pub v: Vector3<f64>,
    pub att: FlatAttitude,
}

/// Sensor samples produced at one IMU step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorStep {
    /// The true state at this step (biases included).
    pub truth: TruthSample,
    /// The IMU sample.
    pub imu: ImuSample,
    /// A GPS fix if one is due at this step.
    pub gps: Option<GpsSample>,
    /// An attitude reference sample if one is due.
    pub attitude: Option<AttitudeSample>,
    /// A VO sample if one is due.
    pub vo: Option<VoSample>,
}

/// Stateful sensor models (IMU biases, VO keyframe, random stream) shared by the open-loop
/// [`simulate`] and the closed-loop simulator.
#[derive(Debug)]
pub(crate) struct SensorModel {
    cfg: ValidSimConfig,
    rng: StdRng,
    b_g: Vector3<f64>,
    b_a: Vector3<f64>,
    keyframe: Option<(Vector3<f64>, Matrix3<f64>)>,
    keyframe_idx: u32,
    gyro_sigma: Vector3<f64>,
    accel_sigma: Vector3<f64>,
    gyro_walk: Vector3<f64>,
    accel_walk: Vector3<f64>,
}

impl SensorModel {
    pub(crate) fn new(cfg: ValidSimConfig, seed: u64) -> Self {
        let mut rng = StdRng::seed_from_u64(seed);
        let c = cfg.config();
        let noise = c.noise;
        let b_g = noise.sample3(&mut rng, &Vector3::repeat(c.gyro_bias_init_sigma));
        let b_a = noise.sample3(&mut rng, &Vector3::repeat(c.accel_bias_init_sigma));
        let sqrt_dt = cfg.dt_s().sqrt();
        Self {
            gyro_sigma: Vector3::repeat(c.gyro_sigma()),
            accel_sigma: Vector3::repeat(c.accel_sigma()),
            gyro_walk: Vector3::repeat(c.gyro_bias_walk * sqrt_dt),
            accel_walk: Vector3::repeat(c.accel_bias_walk * sqrt_dt),
            cfg,
            rng,
            b_g,
            b_a,
            keyframe: None,
            keyframe_idx: 0,
        }
    }

    pub(crate) fn config(&self) -> &ValidSimConfig {
        &self.cfg
    }

    /// Samples due at IMU step `k` for the kinematic truth `kin`; then advances the biases.
    pub(crate) fn step(&mut self, k: u64, kin: &Kinematics) -> SensorStep {
        let t = self.cfg.time_of_step(k);
        let c = &self.cfg.cfg;
        let noise = c.noise;
        let truth = TruthSample { t, p: kin.p, q: kin.att.q, v: kin.v, b_g: self.b_g, b_a: self.b_a };
        // IMU: ω_m = ω + b_g + n_g;  a_m = Rᵀ(a − g) + b_a + n_a = [0, 0, |t|] + b_a + n_a.
        let gyro = kin.att.omega + self.b_g + noise.sample3(&mut self.rng, &self.gyro_sigma);
        let f_body = Vector3::new(0.0, 0.0, kin.att.thrust);
        let accel = f_body + self.b_a + noise.sample3(&mut self.rng, &self.accel_sigma);
        let imu = ImuSample { t, gyro, accel };
        let gps = k
            .is_multiple_of(self.cfg.imu_per_gps)
            .then(|| GpsSample { t, p: kin.p + noise.sample3(&mut self.rng, &Vector3::from(c.gps_sigma_m)) });
        let attitude = k.is_multiple_of(self.cfg.imu_per_attitude).then(|| AttitudeSample {
            t,
            q: wrap_euler(&(kin.att.q + noise.sample3(&mut self.rng, &Vector3::from(c.attitude_sigma_rad)))),
        });
        let vo = if k.is_multiple_of(self.cfg.imu_per_vo) {
            let vo_idx = k / self.cfg.imu_per_vo;
            if vo_idx.is_multiple_of(self.cfg.vo_per_keyframe) {
                if self.keyframe.is_some() {
                    self.keyframe_idx = self.keyframe_idx.saturating_add(1);
                }
                self.keyframe = Some((kin.p, kin.att.r));
            }
            self.keyframe.map(|(p_f, r_f)| {
                // eq:model2g: [R(q_F)ᵀ(p − p_F); Euler(R(q_F)ᵀR(q))].
                let p_rel = r_f.transpose() * (kin.p - p_f);
                let q_rel = euler_from_matrix(&(r_f.transpose() * kin.att.r));
                VoSample {
                    t,
                    keyframe: self.keyframe_idx,
                    p_rel: p_rel + noise.sample3(&mut self.rng, &Vector3::repeat(c.vo_pos_sigma_m)),
                    q_rel: wrap_euler(&(q_rel + noise.sample3(&mut self.rng, &Vector3::repeat(c.vo_att_sigma_rad)))),
                }
            })
        } else {
            None
        };
        // Bias random walk to the next step.
        self.b_g += noise.sample3(&mut self.rng, &self.gyro_walk);
        self.b_a += noise.sample3(&mut self.rng, &self.accel_walk);
        SensorStep { truth, imu, gps, attitude, vo }
    }
}

/// Most IMU steps one simulated flight may hold: 10 M, 13.9 hours at the default 200 Hz and
/// about 2 GB of samples and truth. A longer flight is a configuration error, not an
/// allocation the process cannot make.
pub const MAX_IMU_STEPS: u64 = 10_000_000;

/// Simulate a flight along `traj` for `duration_s` seconds (IMU steps `t_k = k/f_IMU ≤
/// duration_s`) with the sensor models of `cfg`, all noise drawn from `seed`.
///
/// The true vehicle follows the reference exactly (differential flatness, module doc).
///
/// # Errors
/// [`Error::Config`] for an invalid `cfg` or a negative/non-finite duration;
/// [`Error::Flatness`] if the reference is not flyable at some step.
pub fn simulate(cfg: &SimConfig, traj: &dyn Trajectory, duration_s: f64, seed: u64) -> Result<Flight> {
    let valid = cfg.check()?;
    if !(duration_s.is_finite() && duration_s >= 0.0) {
        return Err(Error::Config {
            field: "duration_s",
            msg: format!("must be finite and non-negative, got {duration_s}"),
        });
    }
    let n = valid.n_steps(duration_s);
    if n > MAX_IMU_STEPS {
        return Err(Error::Config {
            field: "duration_s",
            msg: format!(
                "{duration_s} s at {} Hz is {n} IMU steps, more than the {MAX_IMU_STEPS} one flight may hold",
                cfg.imu_rate_hz
            ),
        });
    }
    let cap = usize::try_from(n).unwrap_or(usize::MAX);
    let slow = |ratio: u64| usize::try_from(n / ratio + 1).unwrap_or(0);
    let mut streams = SensorStreams {
        imu: Vec::with_capacity(cap),
        gps: Vec::with_capacity(slow(valid.imu_per_gps)),
        attitude: Vec::with_capacity(slow(valid.imu_per_attitude)),
        vo: Vec::with_capacity(slow(valid.imu_per_vo)),
    };
    let mut truth = Vec::with_capacity(cap);
    let mut sensors = SensorModel::new(valid, seed);
    for k in 0..n {
        let t = sensors.config().time_of_step(k);
        let r = traj.flat_output(t);
        let att = flat_attitude(&r.a, &r.j, r.yaw, r.yaw_rate, t)?;
        let out = sensors.step(k, &Kinematics { p: r.p, v: r.v, att });
        truth.push(out.truth);
        streams.imu.push(out.imu);
        streams.gps.extend(out.gps);
        streams.attitude.extend(out.attitude);
        streams.vo.extend(out.vo);
    }
    Ok(Flight { streams, truth })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rotation::skew;

    /// `[ω]×` from central differences of `R(t)` must match the flatness body rate.
    #[test]
    fn body_rates_match_rotation_derivative() {
        let cases = [
            (Vector3::new(1.0, -2.0, 0.5), Vector3::new(0.3, 0.7, -0.2), 0.4, 0.25),
            (Vector3::new(-3.0, 1.0, -1.0), Vector3::new(-1.0, 0.2, 0.4), -2.9, -0.5),
            (Vector3::zeros(), Vector3::new(0.5, 0.0, 0.0), 3.1, 0.0),
        ];
        for (a, j, yaw, yaw_rate) in cases {
            let h = 1e-6;
            let at = |s: f64| flat_attitude(&(a + j * s), &j, yaw + yaw_rate * s, yaw_rate, s).unwrap();
            let (m, c, p) = (at(-h), at(0.0), at(h));
            let w_fd = c.r.transpose() * (p.r - m.r) / (2.0 * h);
            assert!((w_fd - skew(&c.omega)).norm() < 1e-6, "{w_fd} vs {}", skew(&c.omega));
            assert!((c.r * Vector3::z() * c.thrust - (a - gravity())).norm() < 1e-12);
        }
    }

    #[test]
    fn free_fall_is_an_error() {
        let a = gravity();
        assert!(matches!(flat_attitude(&a, &Vector3::zeros(), 0.0, 0.0, 1.5), Err(Error::Flatness { .. })));
    }
}
