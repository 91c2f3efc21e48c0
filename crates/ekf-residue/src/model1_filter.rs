//! The Model I filter: 15 states `[p, q, v, b_g, b_a]` propagated with the IMU (paper
//! eq:model1f, Euler discretisation) and updated with the pose measurement `[p; q]`
//! (eq:model1g: GPS position in local ENU metres + attitude reference in ZYX Euler radians).
//!
//! Prediction uses the block sparsity of `F = I + A·dt` (only the `q`- and `v`-rows differ from
//! the identity plus the `p`-`v` coupling), in the spirit of PX4's generated covariance
//! prediction; [`predict_covariance_sparse`] equals the dense `F P Fᵀ + Q` (tested).
//!
//! Discrete process noise per IMU step (`n` are per-sample IMU noises, bias random walks are
//! continuous densities):
//!
//! ```text
//! Q_qq = dt² G⁻¹ diag(σ_g²) G⁻ᵀ,   Q_vv = dt² R diag(σ_a²) Rᵀ,
//! Q_bg = σ_bg,rw² dt I,            Q_ba = σ_ba,rw² dt I         (V Q Vᵀ with V = U·dt)
//! ```
//!
//! Innovations: `r_k = y_k − g(x̂_{k|k−1})`, with the angle part wrapped to (−π, π].

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use serde::{Deserialize, Serialize};
use uav_dynamics::model1::{self, IDX_BA, IDX_BG, IDX_P, IDX_Q, IDX_V, ImuInput, JacobianBlocks};
use uav_dynamics::rotation::{wrap_angle, wrap_euler};

use crate::ekf::{CovarianceUpdate, DivergenceGuard, Ekf, Innovation};
use crate::error::FilterError;

/// 15×15 covariance of Model I.
pub type Cov15 = SMatrix<f64, 15, 15>;

/// IMU noise figures used to build the process noise `Q`.
///
/// Defaults: the EuRoC VI-sensor ADIS16448 values of the dataset's `imu0/sensor.yaml` at 200 Hz
/// (gyro noise density 1.6968e-4 rad/s/√Hz → 2.4e-3 rad/s per sample, accelerometer 2.0e-3
/// m/s²/√Hz → 0.028 m/s² per sample, random walks 1.9393e-5 rad/s²/√Hz and 3.0e-3 m/s³/√Hz).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuNoise {
    /// Gyroscope white noise, standard deviation per IMU sample, rad/s. Default 2.4e-3.
    pub gyro_sigma: f64,
    /// Accelerometer white noise, standard deviation per IMU sample, m/s². Default 0.028.
    pub accel_sigma: f64,
    /// Gyroscope bias random walk density, rad/s/√s. Default 1.9393e-5.
    pub gyro_bias_rw: f64,
    /// Accelerometer bias random walk density, m/s²/√s. Default 3.0e-3.
    pub accel_bias_rw: f64,
}

impl Default for ImuNoise {
    fn default() -> Self {
        Self { gyro_sigma: 2.4e-3, accel_sigma: 0.028, gyro_bias_rw: 1.9393e-5, accel_bias_rw: 3.0e-3 }
    }
}

/// `F·M` for `F = I + A·dt` of Model I, using the block structure of `A` (row operations only).
fn apply_f<const C: usize>(m: &SMatrix<f64, 15, C>, b: &JacobianBlocks, dt_s: f64) -> SMatrix<f64, 15, C> {
    let mut out = *m;
    let m_q = m.fixed_rows::<3>(IDX_Q);
    let m_v = m.fixed_rows::<3>(IDX_V);
    let f_qq = Matrix3::identity() + b.a_qq * dt_s;
    let f_qg = b.g_inv * (-dt_s);
    let f_vq = b.a_vq * dt_s;
    let f_va = b.r * (-dt_s);
    // p-rows: p + dt·v
    let new_p = m.fixed_rows::<3>(IDX_P) + m_v * dt_s;
    // q-rows: (I + dt·∂q̇/∂q) q − dt·G⁻¹ b_g
    let new_q = f_qq * m_q + f_qg * m.fixed_rows::<3>(IDX_BG);
    // v-rows: dt·∂v̇/∂q q + v − dt·R b_a
    let new_v = f_vq * m_q + m_v + f_va * m.fixed_rows::<3>(IDX_BA);
    out.fixed_rows_mut::<3>(IDX_P).copy_from(&new_p);
    out.fixed_rows_mut::<3>(IDX_Q).copy_from(&new_q);
    out.fixed_rows_mut::<3>(IDX_V).copy_from(&new_v);
    out
}

/// `F·M` for a 15×C matrix at the linearisation point `b` (used by Model II for the
/// cross-covariance with the keyframe clone).
#[must_use]
pub fn apply_transition<const C: usize>(m: &SMatrix<f64, 15, C>, b: &JacobianBlocks, dt_s: f64) -> SMatrix<f64, 15, C> {
    apply_f(m, b, dt_s)
}

/// Discrete process noise `Q` of one IMU step (module doc), block-diagonal.
#[must_use]
pub fn process_noise(b: &JacobianBlocks, noise: &ImuNoise, dt_s: f64) -> Cov15 {
    let mut q = Cov15::zeros();
    let dt2 = dt_s * dt_s;
    let q_qq = b.g_inv * b.g_inv.transpose() * (noise.gyro_sigma * noise.gyro_sigma * dt2);
    let q_vv = b.r * b.r.transpose() * (noise.accel_sigma * noise.accel_sigma * dt2);
    q.fixed_view_mut::<3, 3>(IDX_Q, IDX_Q).copy_from(&q_qq);
    q.fixed_view_mut::<3, 3>(IDX_V, IDX_V).copy_from(&q_vv);
    for i in 0..3 {
        q[(IDX_BG + i, IDX_BG + i)] = noise.gyro_bias_rw * noise.gyro_bias_rw * dt_s;
        q[(IDX_BA + i, IDX_BA + i)] = noise.accel_bias_rw * noise.accel_bias_rw * dt_s;
    }
    q
}

/// Sparse covariance prediction `F P Fᵀ + Q` (eq:ekf_predict) for Model I.
///
/// Only the `p`, `q` and `v` block-rows of `F = I + A·dt` differ from the identity, so
/// `T = F·P` is computed for those 9 rows only; the `{p,q,v} × {b_g,b_a}` blocks of the result
/// are blocks of `T` (and their transposes), and the `{p,q,v} × {p,q,v}` block is `T·Fᵀ`
/// restricted to those columns, computed for the upper block triangle and mirrored. The bias
/// blocks are unchanged. Then the block-diagonal `Q` is added. Equal to the dense product up
/// to rounding (see tests).
#[must_use]
pub fn predict_covariance_sparse(p: &Cov15, b: &JacobianBlocks, noise: &ImuNoise, dt_s: f64) -> Cov15 {
    let f_qq = Matrix3::identity() + b.a_qq * dt_s;
    let f_qg = b.g_inv * (-dt_s);
    let f_vq = b.a_vq * dt_s;
    let f_va = b.r * (-dt_s);
    let rows = |i: usize| p.fixed_rows::<3>(i);
    // T = F·P, block-rows p, q, v (3×15 each).
    let t_p: SMatrix<f64, 3, 15> = rows(IDX_P) + rows(IDX_V) * dt_s;
    let t_q: SMatrix<f64, 3, 15> = f_qq * rows(IDX_Q) + f_qg * rows(IDX_BG);
    let t_v: SMatrix<f64, 3, 15> = f_vq * rows(IDX_Q) + rows(IDX_V) + f_va * rows(IDX_BA);
    let f_qq_t = f_qq.transpose();
    let f_qg_t = f_qg.transpose();
    let f_vq_t = f_vq.transpose();
    let f_va_t = f_va.transpose();
    let mut out = *p;
    let t_blocks = [(IDX_P, &t_p), (IDX_Q, &t_q), (IDX_V, &t_v)];
    for (bi, (ri, t)) in t_blocks.iter().enumerate() {
        // {p,q,v} × {b_g, b_a}: (F P Fᵀ)_{i,bias} = T_{i,bias} since the bias rows of F are identity.
        for cj in [IDX_BG, IDX_BA] {
            let blk = t.fixed_columns::<3>(cj).into_owned();
            out.fixed_view_mut::<3, 3>(*ri, cj).copy_from(&blk);
            out.fixed_view_mut::<3, 3>(cj, *ri).copy_from(&blk.transpose());
        }
        let col = |j: usize| t.fixed_columns::<3>(j);
        // (T·Fᵀ) column blocks p, q, v, upper triangle only.
        let c_p = || col(IDX_P) + col(IDX_V) * dt_s;
        let c_q = || col(IDX_Q) * f_qq_t + col(IDX_BG) * f_qg_t;
        let c_v = || col(IDX_Q) * f_vq_t + col(IDX_V) + col(IDX_BA) * f_va_t;
        for (bj, cj) in [IDX_P, IDX_Q, IDX_V].into_iter().enumerate() {
            if bj < bi {
                continue;
            }
            let blk: Matrix3<f64> = match bj {
                0 => c_p(),
                1 => c_q(),
                _ => c_v(),
            };
            out.fixed_view_mut::<3, 3>(*ri, cj).copy_from(&blk);
            if bj != bi {
                out.fixed_view_mut::<3, 3>(cj, *ri).copy_from(&blk.transpose());
            }
        }
    }
    let dt2 = dt_s * dt_s;
    // Q_qq = G⁻¹ Σ G⁻ᵀ dt², Q_vv = R Σ Rᵀ dt² = σ_a² dt² I (R orthonormal, isotropic σ_a).
    let q_qq = b.g_inv * b.g_inv.transpose() * (noise.gyro_sigma * noise.gyro_sigma * dt2);
    let mut blk = out.fixed_view_mut::<3, 3>(IDX_Q, IDX_Q);
    blk += q_qq;
    let q_v = noise.accel_sigma * noise.accel_sigma * dt2;
    let q_g = noise.gyro_bias_rw * noise.gyro_bias_rw * dt_s;
    let q_a = noise.accel_bias_rw * noise.accel_bias_rw * dt_s;
    for i in 0..3 {
        out[(IDX_V + i, IDX_V + i)] += q_v;
        out[(IDX_BG + i, IDX_BG + i)] += q_g;
        out[(IDX_BA + i, IDX_BA + i)] += q_a;
    }
    // The diagonal blocks are symmetric up to rounding; make them exactly symmetric.
    for i in 0..9 {
        for j in (i + 1)..9 {
            let m = 0.5 * (out[(i, j)] + out[(j, i)]);
            out[(i, j)] = m;
            out[(j, i)] = m;
        }
    }
    out
}

/// One Euler step of eq:model1f from precomputed blocks (`G⁻¹`, `R`), avoiding a second
/// evaluation of the trigonometry.
fn euler_step_with(x: &model1::State, u: &ImuInput, b: &JacobianBlocks, dt_s: f64) -> model1::State {
    let mut y = *x;
    let v = model1::block(x, IDX_V);
    let q_dot = b.g_inv * (u.omega_m - model1::block(x, IDX_BG));
    let v_dot = model1::GRAVITY + b.r * (u.a_m - model1::block(x, IDX_BA));
    for i in 0..3 {
        y[IDX_P + i] += v[i] * dt_s;
        y[IDX_Q + i] += q_dot[i] * dt_s;
        y[IDX_V + i] += v_dot[i] * dt_s;
    }
    y
}

/// The Model I filter (eq:model1f, eq:model1g) on top of [`Ekf`].
#[derive(Debug, Clone, PartialEq)]
pub struct Model1Filter {
    ekf: Ekf<15>,
    imu_noise: ImuNoise,
    t: f64,
}

impl Model1Filter {
    /// A filter at time `t0_s` with estimate `x0` and covariance `p0`.
    ///
    /// # Errors
    /// As [`Ekf::new`].
    pub fn new(
        x0: model1::State,
        p0: Cov15,
        t0_s: f64,
        imu_noise: ImuNoise,
        cov_update: CovarianceUpdate,
        guard: DivergenceGuard,
    ) -> Result<Self, FilterError> {
        Ok(Self { ekf: Ekf::new(x0, p0, cov_update, guard)?, imu_noise, t: t0_s })
    }

    /// Filter time in seconds (time of the last prediction or update).
    #[must_use]
    pub fn t(&self) -> f64 {
        self.t
    }

    /// The underlying EKF (estimate and covariance).
    #[must_use]
    pub fn ekf(&self) -> &Ekf<15> {
        &self.ekf
    }

    /// Mutable access to the underlying EKF (e.g. covariance inflation).
    pub fn ekf_mut(&mut self) -> &mut Ekf<15> {
        &mut self.ekf
    }

    /// Predict over `dt_s` seconds with IMU input `u` (zero-order hold), sparse covariance
    /// propagation; wraps the estimated Euler angles afterwards.
    ///
    /// # Errors
    /// [`FilterError::GimbalLock`], or an error of [`Ekf::set_prior`].
    pub fn predict(&mut self, u: &ImuInput, dt_s: f64) -> Result<(), FilterError> {
        let t_next = self.t + dt_s;
        let x = *self.ekf.x();
        let b = model1::jacobian_blocks(&x, u).ok_or(FilterError::GimbalLock { t: self.t })?;
        let x_prior = euler_step_with(&x, u, &b, dt_s);
        let p_prior = predict_covariance_sparse(self.ekf.p(), &b, &self.imu_noise, dt_s);
        self.ekf.set_prior(wrap_state_angles(x_prior), p_prior, t_next)?;
        self.t = t_next;
        Ok(())
    }

    /// Reference dense prediction `P ← F P Fᵀ + Q` with `F = I + A·dt` (same result as
    /// [`Model1Filter::predict`], slower; kept for tests and benchmarks).
    ///
    /// # Errors
    /// As [`Model1Filter::predict`].
    pub fn predict_dense(&mut self, u: &ImuInput, dt_s: f64) -> Result<(), FilterError> {
        let t_next = self.t + dt_s;
        let x = *self.ekf.x();
        let b = model1::jacobian_blocks(&x, u).ok_or(FilterError::GimbalLock { t: self.t })?;
        let a = model1::A(&x, u).ok_or(FilterError::GimbalLock { t: self.t })?;
        let f_jac = Cov15::identity() + a * dt_s;
        let x_prior = model1::euler_step(&x, u, dt_s).ok_or(FilterError::GimbalLock { t: self.t })?;
        let q = process_noise(&b, &self.imu_noise, dt_s);
        self.ekf.predict(wrap_state_angles(x_prior), &f_jac, &q, t_next)?;
        self.t = t_next;
        Ok(())
    }

    /// Pose innovation `r_k = [p_m − p̂; wrap(q_m − q̂)]` (eq:model1g) and `S_k`, without updating.
    ///
    /// # Errors
    /// [`FilterError::NotPositiveDefinite`] for a singular `S_k`.
    pub fn pose_innovation(
        &self,
        p_m: &Vector3<f64>,
        q_m: &Vector3<f64>,
        r_diag: &[f64; 6],
    ) -> Result<Innovation<6>, FilterError> {
        let r_k = self.pose_residue(p_m, q_m);
        self.ekf.innovation(&r_k, &model1::C(), &diag(r_diag), self.t)
    }

    fn pose_residue(&self, p_m: &Vector3<f64>, q_m: &Vector3<f64>) -> SVector<f64, 6> {
        let y_hat = model1::g(self.ekf.x());
        // eq:model1g residue: r_k = y_k − g(x̂_{k|k−1}), angle part wrapped.
        let dq = wrap_euler(&(q_m - Vector3::new(y_hat[3], y_hat[4], y_hat[5])));
        SVector::<f64, 6>::new(p_m[0] - y_hat[0], p_m[1] - y_hat[1], p_m[2] - y_hat[2], dq[0], dq[1], dq[2])
    }

    /// Joint GPS + attitude update with measurement noise variances `r_diag` (m², rad²).
    ///
    /// # Errors
    /// As [`Ekf::update`].
    pub fn update_pose(
        &mut self,
        p_m: &Vector3<f64>,
        q_m: &Vector3<f64>,
        r_diag: &[f64; 6],
    ) -> Result<Innovation<6>, FilterError> {
        let r_k = self.pose_residue(p_m, q_m);
        let inn = self.ekf.update(&r_k, &model1::C(), &diag(r_diag), self.t)?;
        self.ekf.map_state(|x| *x = wrap_state_angles(*x));
        Ok(inn)
    }

    /// GPS position innovation `p_m − p̂` and `S_k`, without updating (e.g. while GPS is
    /// excluded, so a detector can keep watching it).
    ///
    /// # Errors
    /// [`FilterError::NotPositiveDefinite`] for a singular `S_k`.
    pub fn gps_innovation(&self, p_m: &Vector3<f64>, r_diag: &[f64; 3]) -> Result<Innovation<3>, FilterError> {
        let r_k = p_m - model1::block(self.ekf.x(), IDX_P);
        self.ekf.innovation(&r_k, &gps_h(), &diag(r_diag), self.t)
    }

    /// GPS position update alone.
    ///
    /// # Errors
    /// As [`Ekf::update`].
    pub fn update_gps(&mut self, p_m: &Vector3<f64>, r_diag: &[f64; 3]) -> Result<Innovation<3>, FilterError> {
        let r_k = p_m - model1::block(self.ekf.x(), IDX_P);
        let inn = self.ekf.update(&r_k, &gps_h(), &diag(r_diag), self.t)?;
        self.ekf.map_state(|x| *x = wrap_state_angles(*x));
        Ok(inn)
    }

    /// Attitude reference update alone (angle residue wrapped).
    ///
    /// # Errors
    /// As [`Ekf::update`].
    pub fn update_attitude(&mut self, q_m: &Vector3<f64>, r_diag: &[f64; 3]) -> Result<Innovation<3>, FilterError> {
        let r_k = wrap_euler(&(q_m - model1::block(self.ekf.x(), IDX_Q)));
        let mut h = SMatrix::<f64, 3, 15>::zeros();
        h.fixed_view_mut::<3, 3>(0, IDX_Q).copy_from(&Matrix3::identity());
        let inn = self.ekf.update(&r_k, &h, &diag(r_diag), self.t)?;
        self.ekf.map_state(|x| *x = wrap_state_angles(*x));
        Ok(inn)
    }
}

/// `[I₃ 0]` on the 15-state.
fn gps_h() -> SMatrix<f64, 3, 15> {
    SMatrix::<f64, 3, 15>::identity()
}

/// Diagonal matrix from variances.
pub(crate) fn diag<const M: usize>(d: &[f64; M]) -> SMatrix<f64, M, M> {
    SMatrix::<f64, M, M>::from_diagonal(&SVector::<f64, M>::from_column_slice(d))
}

/// Wrap the roll and yaw of a Model I state to (−π, π] (pitch stays continuous).
fn wrap_state_angles<const N: usize>(mut x: SVector<f64, N>) -> SVector<f64, N> {
    x[IDX_Q] = wrap_angle(x[IDX_Q]);
    x[IDX_Q + 2] = wrap_angle(x[IDX_Q + 2]);
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sparse_prediction_equals_dense() {
        let x = model1::state(
            &Vector3::new(1.0, 2.0, 3.0),
            &Vector3::new(0.2, -0.3, 2.5),
            &Vector3::new(1.0, -2.0, 0.5),
            &Vector3::new(0.01, -0.02, 0.005),
            &Vector3::new(0.1, 0.05, -0.2),
        );
        let u = ImuInput { omega_m: Vector3::new(0.3, -0.1, 0.7), a_m: Vector3::new(0.5, -0.4, 9.9) };
        // A random SPD covariance.
        let l = Cov15::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 * 0.1 - 0.4);
        let p0 = l * l.transpose() + Cov15::identity() * 0.5;
        let noise = ImuNoise::default();
        let dt = 0.005;
        let mut a = Model1Filter::new(x, p0, 0.0, noise, CovarianceUpdate::Joseph, DivergenceGuard::default()).unwrap();
        let mut b = a.clone();
        a.predict(&u, dt).unwrap();
        b.predict_dense(&u, dt).unwrap();
        // Same arithmetic reordered: agreement to a few ulps of the entries (|P| ≤ ~10).
        assert!((a.ekf().p() - b.ekf().p()).abs().max() < 1e-12);
        assert!((a.ekf().x() - b.ekf().x()).abs().max() < 1e-15);
    }
}
