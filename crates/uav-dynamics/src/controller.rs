//! Position controller that flies on a caller-supplied estimate, and a stepping closed-loop
//! simulator in which a corrupted estimate moves the true vehicle (the setting of
//! sec:state_estimation / alg:alg3).
//!
//! Controller (PX4 multicopter position control structure, cascaded P–P, which is a PD law):
//!
//! ```text
//! v_sp  = v_ref + sat(K_p (p_ref − p̂))                      (velocity set point)
//! a_cmd = a_ref + τ·j_ref + K_v (v_sp − v̂)                  (acceleration command)
//! ```
//!
//! i.e. PD on position and velocity error with gains `K_v K_p` and `K_v`, plus the reference
//! acceleration as feedforward (and the jerk feedforward `τ·j_ref` that cancels the thrust lag
//! below). Only the estimate `(p̂, v̂)` enters: the controller never sees the truth.
//!
//! Vehicle: point mass whose specific thrust vector `t` (world frame, `a = t + g`) follows the
//! command `t_cmd = a_cmd − g` with a first-order lag `ṫ = (t_cmd − t)/τ`, modelling the
//! attitude and thrust loops; `τ = 1/MC_ROLL_P`. Attitude, body rates and accelerometer
//! reading follow from `(a, ṫ, ψ_ref, ψ̇_ref)` by differential flatness
//! ([`flat_attitude`]), so IMU samples are consistent with the true
//! motion. Yaw follows the reference. Integration: `p ← p + v dt + ½a dt²`, `v ← v + a dt`,
//! `t ← t + ṫ dt` at the IMU rate. World ENU, SI units throughout.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::sim::{GRAVITY, Kinematics, SensorModel, SensorStep, SimConfig, flat_attitude, gravity};
use crate::trajectory::{FlatOutput, Trajectory};

/// Gains and limits of the position controller.
///
/// Defaults are PX4 v1.14 multicopter position-control parameter defaults (named per field).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerConfig {
    /// Horizontal position gain `K_p` in 1/s. Default 0.95 (PX4 MPC_XY_P).
    pub xy_pos_p: f64,
    /// Horizontal velocity gain `K_v` in 1/s. Default 1.8 (PX4 MPC_XY_VEL_P_ACC).
    pub xy_vel_p: f64,
    /// Vertical position gain in 1/s. Default 1.0 (PX4 MPC_Z_P).
    pub z_pos_p: f64,
    /// Vertical velocity gain in 1/s. Default 4.0 (PX4 MPC_Z_VEL_P_ACC).
    pub z_vel_p: f64,
    /// Limit of the horizontal velocity correction in m/s. Default 12 (PX4 MPC_XY_VEL_MAX).
    pub xy_vel_max: f64,
    /// Limit of the vertical velocity correction in m/s. Default 3 (PX4 MPC_Z_VEL_MAX_UP).
    pub z_vel_max: f64,
    /// Largest tilt of the thrust vector in degrees. Default 45 (PX4 MPC_TILTMAX_AIR).
    pub tilt_max_deg: f64,
    /// Thrust-vector lag `τ` in seconds. Default 1/6.5 ≈ 0.154 (PX4 MC_ROLL_P = 6.5 1/s,
    /// the attitude loop's proportional gain).
    pub thrust_lag_s: f64,
}

impl Default for ControllerConfig {
    fn default() -> Self {
        Self {
            xy_pos_p: 0.95,
            xy_vel_p: 1.8,
            z_pos_p: 1.0,
            z_vel_p: 4.0,
            xy_vel_max: 12.0,
            z_vel_max: 3.0,
            tilt_max_deg: 45.0,
            thrust_lag_s: 1.0 / 6.5,
        }
    }
}

impl ControllerConfig {
    /// Check every gain and limit is positive and finite and the tilt below 80°.
    ///
    /// # Errors
    /// [`Error::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        let fields = [
            ("xy_pos_p", self.xy_pos_p),
            ("xy_vel_p", self.xy_vel_p),
            ("z_pos_p", self.z_pos_p),
            ("z_vel_p", self.z_vel_p),
            ("xy_vel_max", self.xy_vel_max),
            ("z_vel_max", self.z_vel_max),
            ("tilt_max_deg", self.tilt_max_deg),
            ("thrust_lag_s", self.thrust_lag_s),
        ];
        for (field, v) in fields {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::Config { field, msg: format!("must be positive and finite, got {v}") });
            }
        }
        if self.tilt_max_deg >= 80.0 {
            return Err(Error::Config {
                field: "tilt_max_deg",
                msg: format!("{} must be below 80", self.tilt_max_deg),
            });
        }
        Ok(())
    }
}

/// What the navigation estimator reports to the controller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavEstimate {
    /// Estimated position `p̂` in metres (ENU).
    pub p: Vector3<f64>,
    /// Estimated velocity `v̂` in m/s (ENU).
    pub v: Vector3<f64>,
}

/// The position controller (module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionController {
    cfg: ControllerConfig,
}

impl PositionController {
    /// Controller with checked gains.
    ///
    /// # Errors
    /// [`Error::Config`] from [`ControllerConfig::check`].
    pub fn new(cfg: ControllerConfig) -> Result<Self> {
        cfg.check()?;
        Ok(Self { cfg })
    }

    /// The gains.
    #[must_use]
    pub fn config(&self) -> &ControllerConfig {
        &self.cfg
    }

    /// Commanded specific thrust vector `t_cmd = a_cmd − g` (world frame, m/s²) for the
    /// reference `r` and the estimate `est`, with the vertical thrust kept in
    /// `[0.3 g, 2 g]` and the tilt below the limit.
    #[must_use]
    pub fn thrust_command(&self, r: &FlatOutput, est: &NavEstimate) -> Vector3<f64> {
        let c = &self.cfg;
        let e_p = r.p - est.p;
        // Velocity set point with saturated position correction (PX4 structure).
        let mut corr_xy = e_p.xy() * c.xy_pos_p;
        let n_xy = corr_xy.norm();
        if n_xy > c.xy_vel_max {
            corr_xy *= c.xy_vel_max / n_xy;
        }
        let corr_z = (e_p.z * c.z_pos_p).clamp(-c.z_vel_max, c.z_vel_max);
        let v_sp = r.v + Vector3::new(corr_xy.x, corr_xy.y, corr_z);
        let e_v = v_sp - est.v;
        let fb = Vector3::new(e_v.x * c.xy_vel_p, e_v.y * c.xy_vel_p, e_v.z * c.z_vel_p);
        let a_cmd = r.a + r.j * c.thrust_lag_s + fb;
        let mut t = a_cmd - gravity();
        t.z = t.z.clamp(0.3 * GRAVITY, 2.0 * GRAVITY);
        let max_xy = t.z * c.tilt_max_deg.to_radians().tan();
        let n = t.xy().norm();
        if n > max_xy {
            let k = max_xy / n;
            t.x *= k;
            t.y *= k;
        }
        if t.iter().all(|x| x.is_finite()) { t } else { Vector3::new(0.0, 0.0, GRAVITY) }
    }
}

/// Everything produced by one closed-loop step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutput {
    /// Sensor samples at this step (truth, IMU, and any GPS/attitude/VO due).
    pub sensors: SensorStep,
    /// The reference at this step.
    pub reference: FlatOutput,
    /// The commanded specific thrust vector `t_cmd` (world, m/s²).
    pub thrust_cmd: Vector3<f64>,
}

/// A closed-loop flight: the controller flies on the caller's estimate and the true vehicle
/// responds (module doc). Call [`ClosedLoopSim::step`] once per IMU period.
pub struct ClosedLoopSim<'a> {
    traj: &'a dyn Trajectory,
    ctrl: PositionController,
    sensors: SensorModel,
    k: u64,
    p: Vector3<f64>,
    v: Vector3<f64>,
    thrust: Vector3<f64>,
}

impl std::fmt::Debug for ClosedLoopSim<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClosedLoopSim")
            .field("k", &self.k)
            .field("p", &self.p)
            .field("v", &self.v)
            .finish_non_exhaustive()
    }
}

impl<'a> ClosedLoopSim<'a> {
    /// Start at rest-consistent reference state `traj(0)` (position, velocity, thrust).
    ///
    /// # Errors
    /// [`Error::Config`] for an invalid simulator or controller config.
    pub fn new(cfg: &SimConfig, ctrl: ControllerConfig, traj: &'a dyn Trajectory, seed: u64) -> Result<Self> {
        let valid = cfg.check()?;
        let ctrl = PositionController::new(ctrl)?;
        let r0 = traj.flat_output(0.0);
        Ok(Self {
            traj,
            ctrl,
            sensors: SensorModel::new(valid, seed),
            k: 0,
            p: r0.p,
            v: r0.v,
            thrust: r0.a - gravity(),
        })
    }

    /// Index of the next step.
    #[must_use]
    pub fn step_idx(&self) -> u64 {
        self.k
    }

    /// Time of the next step in seconds.
    #[must_use]
    pub fn time_s(&self) -> f64 {
        self.sensors.config().time_of_step(self.k)
    }

    /// IMU period in seconds.
    #[must_use]
    pub fn dt_s(&self) -> f64 {
        self.sensors.config().dt_s()
    }

    /// The initial estimate a perfectly initialised estimator would report (the true start).
    #[must_use]
    pub fn initial_estimate(&self) -> NavEstimate {
        NavEstimate { p: self.p, v: self.v }
    }

    /// One IMU period: compute the control from `estimate` (the estimator's state at the
    /// current time, e.g. its prediction `x̂_{k|k−1}`), emit the sensor samples at `t_k`, and
    /// advance the true vehicle to `t_{k+1}`.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a non-finite estimate; [`Error::Flatness`] if the vehicle state
    /// cannot be mapped to an attitude (it cannot with the command limits, barring NaN).
    pub fn step(&mut self, estimate: &NavEstimate) -> Result<StepOutput> {
        if !(estimate.p.iter().chain(estimate.v.iter()).all(|x| x.is_finite())) {
            return Err(Error::NonFinite { what: "navigation estimate" });
        }
        let t = self.time_s();
        let dt = self.dt_s();
        let r = self.traj.flat_output(t);
        let thrust_cmd = self.ctrl.thrust_command(&r, estimate);
        // ṫ = (t_cmd − t)/τ; jerk of the true motion = ṫ.
        let thrust_dot = (thrust_cmd - self.thrust) / self.ctrl.cfg.thrust_lag_s;
        let a = self.thrust + gravity();
        let att = flat_attitude(&a, &thrust_dot, r.yaw, r.yaw_rate, t)?;
        let sensors = self.sensors.step(self.k, &Kinematics { p: self.p, v: self.v, att });
        self.p += self.v * dt + a * (0.5 * dt * dt);
        self.v += a * dt;
        self.thrust += thrust_dot * dt;
        self.k += 1;
        Ok(StepOutput { sensors, reference: r, thrust_cmd })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hover_command_is_gravity_compensation() {
        let ctrl = PositionController::new(ControllerConfig::default()).unwrap();
        let r = FlatOutput::hover(Vector3::new(1.0, 2.0, 3.0), 0.0);
        let est = NavEstimate { p: r.p, v: Vector3::zeros() };
        assert!((ctrl.thrust_command(&r, &est) - Vector3::new(0.0, 0.0, GRAVITY)).norm() < 1e-12);
    }

    #[test]
    fn command_respects_tilt_limit() {
        let ctrl = PositionController::new(ControllerConfig::default()).unwrap();
        let r = FlatOutput::hover(Vector3::new(1000.0, 0.0, 0.0), 0.0);
        let est = NavEstimate { p: Vector3::zeros(), v: Vector3::zeros() };
        let t = ctrl.thrust_command(&r, &est);
        assert!(t.xy().norm() <= t.z * 45f64.to_radians().tan() + 1e-9);
        assert!(matches!(
            PositionController::new(ControllerConfig { xy_vel_p: -1.0, ..Default::default() }),
            Err(Error::Config { field: "xy_vel_p", .. })
        ));
    }
}
