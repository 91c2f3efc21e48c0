//! The Model II filter: 21 states `[p, q, v, b_g, b_a, p_F, q_F]` (paper eq:model2state,
//! eq:model2f) with GPS position updates and visual-odometry relative-pose updates (eq:model2g),
//! and stochastic keyframe cloning.
//!
//! Prediction: `F₂ = blkdiag(F₁, I₆)`, so `P_aa ← F₁ P_aa F₁ᵀ + Q`, `P_ac ← F₁ P_ac`, `P_cc`
//! unchanged (`a` = first 15 states, `c` = keyframe clone), computed with the sparse row
//! operations of [`crate::model1_filter`].
//!
//! Keyframes: when a VO sample carries a new `keyframe` index, the current pose is cloned into
//! `[p_F, q_F]` with its covariance and cross-covariances, `x ← M x`, `P ← M P Mᵀ`
//! ([`uav_dynamics::model2::M`]), before the sample is fused. The clone makes `P` singular (the
//! clone equals the pose); Joseph updates keep it symmetric PSD.
//!
//! Innovations: VO `r = [z_p − ẑ_p; wrap(z_q − ẑ_q)]`; GPS `r = p_m − p̂`; a VO sample and a
//! GPS fix at the same time are stacked into one 9-D update `[vo; gps]`, so that `r_k` and
//! `S_k` come from one update.

use nalgebra::{SMatrix, SVector, Vector3};
use uav_dynamics::model1::{self, ImuInput};
use uav_dynamics::model2::{self, IDX_PF};
use uav_dynamics::rotation::{wrap_angle, wrap_euler};
use uav_dynamics::sensors::VoSample;

use crate::ekf::{CovarianceUpdate, DivergenceGuard, Ekf, Innovation};
use crate::error::FilterError;
use crate::model1_filter::{ImuNoise, apply_transition, diag, predict_covariance_sparse};

/// 21×21 covariance of Model II.
pub type Cov21 = SMatrix<f64, 21, 21>;

/// The Model II filter on top of [`Ekf`].
#[derive(Debug, Clone, PartialEq)]
pub struct Model2Filter {
    ekf: Ekf<21>,
    imu_noise: ImuNoise,
    t: f64,
    keyframe: Option<u32>,
}

impl Model2Filter {
    /// A filter at time `t0_s` from a Model I estimate `x0` and covariance `p0`; the keyframe
    /// block starts as a clone of the initial pose (replaced at the first VO keyframe).
    ///
    /// # Errors
    /// As [`Ekf::new`].
    pub fn new(
        x0: model1::State,
        p0: SMatrix<f64, 15, 15>,
        t0_s: f64,
        imu_noise: ImuNoise,
        cov_update: CovarianceUpdate,
        guard: DivergenceGuard,
    ) -> Result<Self, FilterError> {
        let x = model2::clone_keyframe(&model2::augment(&x0, &Vector3::zeros(), &Vector3::zeros()));
        let mut p = Cov21::zeros();
        p.fixed_view_mut::<15, 15>(0, 0).copy_from(&p0);
        let m = model2::M();
        let p = m * p * m.transpose();
        Ok(Self { ekf: Ekf::new(x, p, cov_update, guard)?, imu_noise, t: t0_s, keyframe: None })
    }

    /// Filter time in seconds.
    #[must_use]
    pub fn t(&self) -> f64 {
        self.t
    }

    /// Current keyframe index (`None` before the first VO sample).
    #[must_use]
    pub fn keyframe(&self) -> Option<u32> {
        self.keyframe
    }

    /// The underlying EKF.
    #[must_use]
    pub fn ekf(&self) -> &Ekf<21> {
        &self.ekf
    }

    /// Mutable access to the underlying EKF (e.g. covariance inflation).
    pub fn ekf_mut(&mut self) -> &mut Ekf<21> {
        &mut self.ekf
    }

    /// Predict over `dt_s` with IMU input `u` (eq:model2f, Euler step, sparse covariance).
    ///
    /// # Errors
    /// [`FilterError::GimbalLock`] or an error of [`Ekf::set_prior`].
    pub fn predict(&mut self, u: &ImuInput, dt_s: f64) -> Result<(), FilterError> {
        let t_next = self.t + dt_s;
        let x = *self.ekf.x();
        let x1 = model2::core(&x);
        let b = model1::jacobian_blocks(&x1, u).ok_or(FilterError::GimbalLock { t: self.t })?;
        let x1_next = model1::euler_step(&x1, u, dt_s).ok_or(FilterError::GimbalLock { t: self.t })?;
        let mut x_prior = x;
        x_prior.fixed_rows_mut::<15>(0).copy_from(&x1_next);
        x_prior[model1::IDX_Q] = wrap_angle(x_prior[model1::IDX_Q]);
        x_prior[model1::IDX_Q + 2] = wrap_angle(x_prior[model1::IDX_Q + 2]);
        let p = self.ekf.p();
        let p_aa: SMatrix<f64, 15, 15> = p.fixed_view::<15, 15>(0, 0).into_owned();
        let p_ac: SMatrix<f64, 15, 6> = p.fixed_view::<15, 6>(0, IDX_PF).into_owned();
        let new_aa = predict_covariance_sparse(&p_aa, &b, &self.imu_noise, dt_s);
        let new_ac = apply_transition(&p_ac, &b, dt_s);
        let mut p_prior = *p;
        p_prior.fixed_view_mut::<15, 15>(0, 0).copy_from(&new_aa);
        p_prior.fixed_view_mut::<15, 6>(0, IDX_PF).copy_from(&new_ac);
        p_prior.fixed_view_mut::<6, 15>(IDX_PF, 0).copy_from(&new_ac.transpose());
        self.ekf.set_prior(x_prior, p_prior, t_next)?;
        self.t = t_next;
        Ok(())
    }

    /// Reference dense prediction with `F₂ = I + A₂·dt` (tests and benchmarks).
    ///
    /// # Errors
    /// As [`Model2Filter::predict`].
    pub fn predict_dense(&mut self, u: &ImuInput, dt_s: f64) -> Result<(), FilterError> {
        let t_next = self.t + dt_s;
        let x = *self.ekf.x();
        let x1 = model2::core(&x);
        let b = model1::jacobian_blocks(&x1, u).ok_or(FilterError::GimbalLock { t: self.t })?;
        let a = model2::A(&x, u).ok_or(FilterError::GimbalLock { t: self.t })?;
        let f_jac = Cov21::identity() + a * dt_s;
        let mut q = Cov21::zeros();
        q.fixed_view_mut::<15, 15>(0, 0).copy_from(&crate::model1_filter::process_noise(&b, &self.imu_noise, dt_s));
        let x1_next = model1::euler_step(&x1, u, dt_s).ok_or(FilterError::GimbalLock { t: self.t })?;
        let mut x_prior = x;
        x_prior.fixed_rows_mut::<15>(0).copy_from(&x1_next);
        x_prior[model1::IDX_Q] = wrap_angle(x_prior[model1::IDX_Q]);
        x_prior[model1::IDX_Q + 2] = wrap_angle(x_prior[model1::IDX_Q + 2]);
        self.ekf.predict(x_prior, &f_jac, &q, t_next)?;
        self.t = t_next;
        Ok(())
    }

    /// Clone the current pose into the keyframe block (stochastic cloning, `P ← M P Mᵀ`) and
    /// record `keyframe` as the current index.
    pub fn clone_keyframe(&mut self, keyframe: u32) {
        self.ekf.apply_linear_map(&model2::M());
        self.keyframe = Some(keyframe);
    }

    /// Clone if `vo.keyframe` differs from the current keyframe.
    fn ensure_keyframe(&mut self, vo: &VoSample) {
        if self.keyframe != Some(vo.keyframe) {
            self.clone_keyframe(vo.keyframe);
        }
    }

    fn vo_residue_and_h(&self, vo: &VoSample) -> Result<(SVector<f64, 6>, SMatrix<f64, 6, 21>), FilterError> {
        let x = self.ekf.x();
        let z_hat = model2::g_vo(x);
        let h = model2::vo_jacobian(x).ok_or(FilterError::GimbalLock { t: self.t })?;
        // eq:model2g residue: r_k = z_k − g(x̂_{k|k−1}), angle part wrapped.
        let dq = wrap_euler(&(vo.q_rel - Vector3::new(z_hat[3], z_hat[4], z_hat[5])));
        let r = SVector::<f64, 6>::new(
            vo.p_rel[0] - z_hat[0],
            vo.p_rel[1] - z_hat[1],
            vo.p_rel[2] - z_hat[2],
            dq[0],
            dq[1],
            dq[2],
        );
        Ok((r, h))
    }

    /// VO relative-pose update (eq:model2g); clones a new keyframe first when `vo.keyframe`
    /// changed. `r_diag` are the variances `[m² ×3, rad² ×3]`.
    ///
    /// # Errors
    /// [`FilterError::GimbalLock`] or an error of [`Ekf::update`].
    pub fn update_vo(&mut self, vo: &VoSample, r_diag: &[f64; 6]) -> Result<Innovation<6>, FilterError> {
        self.ensure_keyframe(vo);
        let (r_k, h) = self.vo_residue_and_h(vo)?;
        let inn = self.ekf.update(&r_k, &h, &diag(r_diag), self.t)?;
        self.rewrap();
        Ok(inn)
    }

    /// GPS innovation `p_m − p̂` and `S_k` without updating.
    ///
    /// # Errors
    /// [`FilterError::NotPositiveDefinite`] for a singular `S_k`.
    pub fn gps_innovation(&self, p_m: &Vector3<f64>, r_diag: &[f64; 3]) -> Result<Innovation<3>, FilterError> {
        let r_k = p_m - model2::g_gps(self.ekf.x());
        self.ekf.innovation(&r_k, &model2::gps_jacobian(), &diag(r_diag), self.t)
    }

    /// GPS position update alone.
    ///
    /// # Errors
    /// As [`Ekf::update`].
    pub fn update_gps(&mut self, p_m: &Vector3<f64>, r_diag: &[f64; 3]) -> Result<Innovation<3>, FilterError> {
        let r_k = p_m - model2::g_gps(self.ekf.x());
        let inn = self.ekf.update(&r_k, &model2::gps_jacobian(), &diag(r_diag), self.t)?;
        self.rewrap();
        Ok(inn)
    }

    /// Stacked VO + GPS innovation `[vo; gps]` (9-D) and `S_k` without updating.
    ///
    /// # Errors
    /// As [`Model2Filter::update_vo_gps`] but never updates.
    pub fn vo_gps_innovation(
        &mut self,
        vo: &VoSample,
        p_m: &Vector3<f64>,
        r_diag: &[f64; 9],
    ) -> Result<Innovation<9>, FilterError> {
        self.ensure_keyframe(vo);
        let (r_k, h) = self.stacked(vo, p_m)?;
        self.ekf.innovation(&r_k, &h, &diag(r_diag), self.t)
    }

    /// One joint update with a VO sample and a GPS fix at the same time: measurement
    /// `[z_vo; p]`, Jacobian `[C_vo; C_gps]`, noise `diag(r_diag)`.
    ///
    /// # Errors
    /// As [`Model2Filter::update_vo`].
    pub fn update_vo_gps(
        &mut self,
        vo: &VoSample,
        p_m: &Vector3<f64>,
        r_diag: &[f64; 9],
    ) -> Result<Innovation<9>, FilterError> {
        self.ensure_keyframe(vo);
        let (r_k, h) = self.stacked(vo, p_m)?;
        let inn = self.ekf.update(&r_k, &h, &diag(r_diag), self.t)?;
        self.rewrap();
        Ok(inn)
    }

    fn stacked(
        &self,
        vo: &VoSample,
        p_m: &Vector3<f64>,
    ) -> Result<(SVector<f64, 9>, SMatrix<f64, 9, 21>), FilterError> {
        let (r_vo, h_vo) = self.vo_residue_and_h(vo)?;
        let r_gps = p_m - model2::g_gps(self.ekf.x());
        let mut r_k = SVector::<f64, 9>::zeros();
        r_k.fixed_rows_mut::<6>(0).copy_from(&r_vo);
        r_k.fixed_rows_mut::<3>(6).copy_from(&r_gps);
        let mut h = SMatrix::<f64, 9, 21>::zeros();
        h.fixed_view_mut::<6, 21>(0, 0).copy_from(&h_vo);
        h.fixed_view_mut::<3, 21>(6, 0).copy_from(&model2::gps_jacobian());
        Ok((r_k, h))
    }

    fn rewrap(&mut self) {
        self.ekf.map_state(|x| {
            for idx in [model1::IDX_Q, model1::IDX_Q + 2, model2::IDX_QF, model2::IDX_QF + 2] {
                x[idx] = wrap_angle(x[idx]);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sparse_prediction_equals_dense_with_clone() {
        let x = model1::state(
            &Vector3::new(1.0, 2.0, 3.0),
            &Vector3::new(0.2, -0.3, 2.5),
            &Vector3::new(1.0, -2.0, 0.5),
            &Vector3::new(0.01, -0.02, 0.005),
            &Vector3::new(0.1, 0.05, -0.2),
        );
        let l = SMatrix::<f64, 15, 15>::from_fn(|i, j| ((i * 5 + j * 3) % 13) as f64 * 0.1 - 0.5);
        let p0 = l * l.transpose() + SMatrix::<f64, 15, 15>::identity() * 0.5;
        let u = ImuInput { omega_m: Vector3::new(0.3, -0.1, 0.7), a_m: Vector3::new(0.5, -0.4, 9.9) };
        let mut a =
            Model2Filter::new(x, p0, 0.0, ImuNoise::default(), CovarianceUpdate::Joseph, DivergenceGuard::default())
                .unwrap();
        // Separate the clone from the pose first so the cross-covariance is non-trivial.
        for _ in 0..10 {
            a.predict(&u, 0.005).unwrap();
        }
        let mut b = a.clone();
        a.predict(&u, 0.005).unwrap();
        b.predict_dense(&u, 0.005).unwrap();
        assert!((a.ekf().p() - b.ekf().p()).abs().max() < 1e-12);
    }
}
