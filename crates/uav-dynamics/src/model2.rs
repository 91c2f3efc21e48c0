//! Model II: Model I augmented with the keyframe pose (paper eq:model2state, eq:model2f), the
//! visual-odometry measurement `g` (eq:model2g) with its analytic 6×21 Jacobian, the GPS
//! measurement Jacobian on the 21-state, and the keyframe clone map `M` (stochastic cloning).
//!
//! State (21): `x = [p, q, v, b_g, b_a, p_F, q_F]`, the first 15 as in [`crate::model1`], then the
//! keyframe position `p_F` (m, ENU) and orientation `q_F` (ZYX Euler, rad). The keyframe pose is
//! constant between keyframes: `ṗ_F = 0`, `q̇_F = 0` (eq:model2f), so `A₂ = blkdiag(A₁, 0₆)`.
//!
//! VO measurement (eq:model2g), with `R_F = R(q_F)`, `d = p − p_F`, `R_rel = R_Fᵀ R(q)`:
//!
//! ```text
//! z = [R_Fᵀ d; Euler(R_rel)]
//! ∂z_p/∂p = R_Fᵀ,  ∂z_p/∂p_F = −R_Fᵀ,  ∂z_p/∂q_F,j = (∂R_F/∂q_F,j)ᵀ d
//! ∂z_q/∂q   =  G(q_rel)⁻¹ G(q)                 (body rate of R_rel is the body rate of R)
//! ∂z_q/∂q_F = −G(q_rel)⁻¹ R_relᵀ G(q_F)       (body rate of R_rel is −R_relᵀ ω_F)
//! ```
//!
//! where `q_rel = Euler(R_rel)`. These hold for any Euler convention whose `G` maps Euler rates
//! to body rates; here ZYX ([`crate::rotation`]).

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use crate::model1;
use crate::rotation::{
    body_to_euler_rate, euler_from_matrix, euler_rate_to_body, rotation_matrix, rotation_matrix_partials,
};

/// Number of Model II states.
pub const N_STATES: usize = 21;
/// VO measurement dimension (eq:model2g).
pub const N_VO: usize = 6;
/// GPS measurement dimension.
pub const N_GPS: usize = 3;
/// Offset of the keyframe position `p_F` in the state.
pub const IDX_PF: usize = 15;
/// Offset of the keyframe orientation `q_F` in the state.
pub const IDX_QF: usize = 18;

/// Model II state vector `[p, q, v, b_g, b_a, p_F, q_F]`.
pub type State = SVector<f64, N_STATES>;
/// State Jacobian `A₂ = ∂f/∂x` (21×21).
pub type StateJacobian = SMatrix<f64, N_STATES, N_STATES>;
/// VO measurement Jacobian (6×21).
pub type VoJacobian = SMatrix<f64, N_VO, N_STATES>;
/// GPS measurement Jacobian (3×21).
pub type GpsJacobian = SMatrix<f64, N_GPS, N_STATES>;

/// The 3-block of `x` at offset `idx`.
#[must_use]
pub fn block(x: &State, idx: usize) -> Vector3<f64> {
    Vector3::new(x[idx], x[idx + 1], x[idx + 2])
}

/// The Model I part (first 15 states) of a Model II state.
#[must_use]
pub fn core(x: &State) -> model1::State {
    x.fixed_rows::<{ model1::N_STATES }>(0).into_owned()
}

/// Build a Model II state from a Model I state and a keyframe pose.
#[must_use]
pub fn augment(x1: &model1::State, p_f: &Vector3<f64>, q_f: &Vector3<f64>) -> State {
    let mut x = State::zeros();
    x.fixed_rows_mut::<{ model1::N_STATES }>(0).copy_from(x1);
    x.fixed_rows_mut::<3>(IDX_PF).copy_from(p_f);
    x.fixed_rows_mut::<3>(IDX_QF).copy_from(q_f);
    x
}

/// Continuous dynamics `f` of eq:model2f (noise-free): Model I for the first 15 states, zero
/// for the keyframe pose. `None` at gimbal lock.
#[must_use]
pub fn f(x: &State, u: &model1::ImuInput) -> Option<State> {
    let f1 = model1::f(&core(x), u)?;
    let mut xdot = State::zeros();
    xdot.fixed_rows_mut::<{ model1::N_STATES }>(0).copy_from(&f1);
    Some(xdot)
}

/// State Jacobian `A₂ = blkdiag(A₁, 0₆)` of eq:model2f. `None` at gimbal lock.
#[allow(non_snake_case)]
#[must_use]
pub fn A(x: &State, u: &model1::ImuInput) -> Option<StateJacobian> {
    let a1 = model1::A(&core(x), u)?;
    let mut a = StateJacobian::zeros();
    a.fixed_view_mut::<{ model1::N_STATES }, { model1::N_STATES }>(0, 0).copy_from(&a1);
    Some(a)
}

/// VO measurement `z = [R(q_F)ᵀ(p − p_F); Euler(R(q_F)ᵀ R(q))]` of eq:model2g.
///
/// The angle part is in (−π, π] for roll and yaw, [−π/2, π/2] for pitch.
#[must_use]
pub fn g_vo(x: &State) -> SVector<f64, N_VO> {
    let r_f = rotation_matrix(&block(x, IDX_QF));
    let d = block(x, model1::IDX_P) - block(x, IDX_PF);
    let z_p = r_f.transpose() * d;
    let z_q = euler_from_matrix(&(r_f.transpose() * rotation_matrix(&block(x, model1::IDX_Q))));
    SVector::<f64, N_VO>::new(z_p[0], z_p[1], z_p[2], z_q[0], z_q[1], z_q[2])
}

/// Analytic VO Jacobian `∂g_vo/∂x` (6×21, see module doc). `None` when `q`, `q_F` or the
/// relative orientation is at gimbal lock.
#[must_use]
pub fn vo_jacobian(x: &State) -> Option<VoJacobian> {
    let q = block(x, model1::IDX_Q);
    let q_f = block(x, IDX_QF);
    let r_f = rotation_matrix(&q_f);
    let r_rel = r_f.transpose() * rotation_matrix(&q);
    let q_rel = euler_from_matrix(&r_rel);
    let g_rel_inv = body_to_euler_rate(&q_rel)?;
    // Reject states where q or q_F itself is at gimbal lock (the model is undefined there).
    body_to_euler_rate(&q)?;
    body_to_euler_rate(&q_f)?;
    let d = block(x, model1::IDX_P) - block(x, IDX_PF);
    let [d_phi, d_theta, d_psi] = rotation_matrix_partials(&q_f);
    let dzp_dqf = Matrix3::from_columns(&[d_phi.transpose() * d, d_theta.transpose() * d, d_psi.transpose() * d]);
    let mut c = VoJacobian::zeros();
    c.fixed_view_mut::<3, 3>(0, model1::IDX_P).copy_from(&r_f.transpose());
    c.fixed_view_mut::<3, 3>(0, IDX_PF).copy_from(&(-r_f.transpose()));
    c.fixed_view_mut::<3, 3>(0, IDX_QF).copy_from(&dzp_dqf);
    c.fixed_view_mut::<3, 3>(3, model1::IDX_Q).copy_from(&(g_rel_inv * euler_rate_to_body(&q)));
    c.fixed_view_mut::<3, 3>(3, IDX_QF).copy_from(&(-g_rel_inv * r_rel.transpose() * euler_rate_to_body(&q_f)));
    Some(c)
}

/// GPS measurement `y = p` on the 21-state.
#[must_use]
pub fn g_gps(x: &State) -> Vector3<f64> {
    block(x, model1::IDX_P)
}

/// GPS measurement Jacobian `[I₃ 0₃ₓ₁₈]` on the 21-state.
#[must_use]
pub fn gps_jacobian() -> GpsJacobian {
    GpsJacobian::identity()
}

/// Keyframe clone map `M` (21×21): keeps the first 15 states and copies the current pose
/// `[p, q]` into `[p_F, q_F]`, so that `x ← M x` and `P ← M P Mᵀ` (stochastic cloning with
/// covariance and cross-covariances; `M = M_a M_r` of the HKUST ELEC5660 augmented EKF).
#[allow(non_snake_case)]
#[must_use]
pub fn M() -> StateJacobian {
    let mut m = StateJacobian::zeros();
    for i in 0..model1::N_STATES {
        m[(i, i)] = 1.0;
    }
    for i in 0..6 {
        m[(IDX_PF + i, model1::IDX_P + i)] = 1.0;
    }
    m
}

/// Apply the clone map to a state: `[p_F, q_F] ← [p, q]`.
#[must_use]
pub fn clone_keyframe(x: &State) -> State {
    let mut y = *x;
    for i in 0..6 {
        y[IDX_PF + i] = x[model1::IDX_P + i];
    }
    y
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vo_at_keyframe_is_zero() {
        let x1 = model1::state(
            &Vector3::new(1.0, 2.0, 3.0),
            &Vector3::new(0.1, -0.2, 1.0),
            &Vector3::zeros(),
            &Vector3::zeros(),
            &Vector3::zeros(),
        );
        let x = clone_keyframe(&augment(&x1, &Vector3::zeros(), &Vector3::zeros()));
        assert!(g_vo(&x).norm() < 1e-12);
        assert!((M() * augment(&x1, &Vector3::zeros(), &Vector3::zeros()) - x).norm() < 1e-15);
    }
}
