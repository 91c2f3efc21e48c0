//! Model I: continuous dynamics `f` (paper eq:model1f), measurement `g` (eq:model1g), the Euler
//! discretisation `x_{k+1} = x_k + dt·f(x_k, u_k)` and the analytic Jacobians `A = ∂f/∂x`,
//! `U = ∂f/∂n`, `C = ∂g/∂x`.
//!
//! State (15, `SVector<f64, 15>`): `x = [p, q, v, b_g, b_a]` with position `p` (m, ENU), ZYX Euler
//! angles `q = [φ, θ, ψ]` (rad), velocity `v` (m/s, ENU), gyro bias `b_g` (rad/s) and accelerometer
//! bias `b_a` (m/s², body FLU). Input `u = (ω_m, a_m)` from the IMU (body frame). Noise (12):
//! `n = [n_g, n_a, n_bg, n_ba]`.
//!
//! ```text
//! ṗ   = v
//! q̇   = G(q)⁻¹ (ω_m − b_g − n_g)
//! v̇   = g + R(q) (a_m − b_a − n_a)          g = [0, 0, −9.81] m/s²
//! ḃ_g = n_bg,   ḃ_a = n_ba
//! y   = [p; q]                              (eq:model1g, C = [I₆ 0₆ₓ₉])
//! ```
//!
//! The Jacobians are derived for the ZYX convention of [`crate::rotation`] (the HKUST ELEC5660
//! course's EKF formulas, which these models follow, are Z-X-Y); with `w = ω_m − b_g`,
//! `h(q) = G(q)⁻¹ w`:
//!
//! ```text
//! ∂h/∂φ = [tθ(cφ w₁ − sφ w₂),  −sφ w₁ − cφ w₂,  (cφ w₁ − sφ w₂)/cθ]ᵀ
//! ∂h/∂θ = [(sφ w₁ + cφ w₂)/cθ²,  0,  (sφ w₁ + cφ w₂) sθ/cθ²]ᵀ
//! ∂h/∂ψ = 0
//! ```
//!
//! and `∂(R(q) a)/∂q_j = (∂R/∂q_j) a` from [`crate::rotation::rotation_matrix_partials`].
//! All functions return `None` at gimbal lock (`|cos θ|` below [`GIMBAL_LOCK_COS`]).

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use crate::rotation::{GIMBAL_LOCK_COS, body_to_euler_rate, rotation_matrix};
use crate::sensors::ImuSample;

/// Number of Model I states.
pub const N_STATES: usize = 15;
/// Number of Model I noise inputs `[n_g, n_a, n_bg, n_ba]`.
pub const N_NOISE: usize = 12;
/// Measurement dimension of eq:model1g.
pub const N_MEAS: usize = 6;

/// Offset of `p` in the state.
pub const IDX_P: usize = 0;
/// Offset of `q` in the state.
pub const IDX_Q: usize = 3;
/// Offset of `v` in the state.
pub const IDX_V: usize = 6;
/// Offset of `b_g` in the state.
pub const IDX_BG: usize = 9;
/// Offset of `b_a` in the state.
pub const IDX_BA: usize = 12;

/// Gravity in the ENU world frame, m/s² (docs/ARCHITECTURE.md, "Frames and units").
pub const GRAVITY: Vector3<f64> = Vector3::new(0.0, 0.0, -9.81);

/// Model I state vector `[p, q, v, b_g, b_a]`.
pub type State = SVector<f64, N_STATES>;
/// Model I noise vector `[n_g, n_a, n_bg, n_ba]`.
pub type Noise = SVector<f64, N_NOISE>;
/// State Jacobian `A = ∂f/∂x` (15×15).
pub type StateJacobian = SMatrix<f64, N_STATES, N_STATES>;
/// Noise Jacobian `U = ∂f/∂n` (15×12).
pub type NoiseJacobian = SMatrix<f64, N_STATES, N_NOISE>;
/// Measurement Jacobian `C = ∂g/∂x` (6×15).
pub type MeasJacobian = SMatrix<f64, N_MEAS, N_STATES>;

/// IMU input `u = (ω_m, a_m)` of eq:model1f, body frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuInput {
    /// Measured angular rate `ω_m`, rad/s.
    pub omega_m: Vector3<f64>,
    /// Measured specific force `a_m`, m/s².
    pub a_m: Vector3<f64>,
}

impl From<&ImuSample> for ImuInput {
    fn from(s: &ImuSample) -> Self {
        Self { omega_m: s.gyro, a_m: s.accel }
    }
}

/// Assemble a state from its blocks.
#[must_use]
pub fn state(p: &Vector3<f64>, q: &Vector3<f64>, v: &Vector3<f64>, b_g: &Vector3<f64>, b_a: &Vector3<f64>) -> State {
    let mut x = State::zeros();
    x.fixed_rows_mut::<3>(IDX_P).copy_from(p);
    x.fixed_rows_mut::<3>(IDX_Q).copy_from(q);
    x.fixed_rows_mut::<3>(IDX_V).copy_from(v);
    x.fixed_rows_mut::<3>(IDX_BG).copy_from(b_g);
    x.fixed_rows_mut::<3>(IDX_BA).copy_from(b_a);
    x
}

/// The 3-block of `x` at offset `idx`.
#[must_use]
pub fn block(x: &State, idx: usize) -> Vector3<f64> {
    Vector3::new(x[idx], x[idx + 1], x[idx + 2])
}

/// Continuous dynamics `ẋ = f(x, u, n)` of eq:model1f with explicit noise `n`.
///
/// Returns `None` at gimbal lock.
#[must_use]
pub fn f_noisy(x: &State, u: &ImuInput, n: &Noise) -> Option<State> {
    let q = block(x, IDX_Q);
    let g_inv = body_to_euler_rate(&q)?;
    let r = rotation_matrix(&q);
    let n_g = Vector3::new(n[0], n[1], n[2]);
    let n_a = Vector3::new(n[3], n[4], n[5]);
    let mut xdot = State::zeros();
    // eq:model1f: ṗ = v
    xdot.fixed_rows_mut::<3>(IDX_P).copy_from(&block(x, IDX_V));
    // eq:model1f: q̇ = G(q)⁻¹ (ω_m − b_g − n_g)
    xdot.fixed_rows_mut::<3>(IDX_Q).copy_from(&(g_inv * (u.omega_m - block(x, IDX_BG) - n_g)));
    // eq:model1f: v̇ = g + R(q)(a_m − b_a − n_a)
    xdot.fixed_rows_mut::<3>(IDX_V).copy_from(&(GRAVITY + r * (u.a_m - block(x, IDX_BA) - n_a)));
    // eq:model1f: ḃ_g = n_bg, ḃ_a = n_ba
    for i in 0..3 {
        xdot[IDX_BG + i] = n[6 + i];
        xdot[IDX_BA + i] = n[9 + i];
    }
    Some(xdot)
}

/// Noise-free continuous dynamics `f(x, u, 0)` (eq:model1f). `None` at gimbal lock.
#[must_use]
pub fn f(x: &State, u: &ImuInput) -> Option<State> {
    f_noisy(x, u, &Noise::zeros())
}

/// One Euler step `x_{k+1} = x_k + dt·f(x_k, u_k)`; `None` at gimbal lock.
///
/// Angles are left unwrapped; wrap with [`crate::rotation::wrap_euler`] where needed.
#[must_use]
pub fn euler_step(x: &State, u: &ImuInput, dt_s: f64) -> Option<State> {
    Some(x + f(x, u)? * dt_s)
}

/// Measurement `y = g(x) = [p; q]` of eq:model1g.
#[must_use]
pub fn g(x: &State) -> SVector<f64, N_MEAS> {
    x.fixed_rows::<N_MEAS>(0).into_owned()
}

/// Measurement Jacobian `C = ∂g/∂x = [I₆ 0₆ₓ₉]` (eq:model1g).
#[allow(non_snake_case)]
#[must_use]
pub fn C() -> MeasJacobian {
    MeasJacobian::identity()
}

/// The non-trivial blocks of `A = ∂f/∂x`, in the form the sparse covariance prediction needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JacobianBlocks {
    /// `∂q̇/∂q = ∂(G(q)⁻¹ w)/∂q`, `w = ω_m − b_g` (third column is zero).
    pub a_qq: Matrix3<f64>,
    /// `G(q)⁻¹` (so that `∂q̇/∂b_g = ∂q̇/∂n_g = −G(q)⁻¹`).
    pub g_inv: Matrix3<f64>,
    /// `∂v̇/∂q = [∂R/∂φ a, ∂R/∂θ a, ∂R/∂ψ a]`, `a = a_m − b_a`.
    pub a_vq: Matrix3<f64>,
    /// `R(q)` (so that `∂v̇/∂b_a = ∂v̇/∂n_a = −R(q)`).
    pub r: Matrix3<f64>,
}

/// The non-trivial Jacobian blocks at `(x, u)`; `None` at gimbal lock.
///
/// All blocks come from one evaluation of the six sines and cosines (this is on the hot path
/// of the filter's prediction).
#[must_use]
pub fn jacobian_blocks(x: &State, u: &ImuInput) -> Option<JacobianBlocks> {
    let (sf, cf) = x[IDX_Q].sin_cos();
    let (st, ct) = x[IDX_Q + 1].sin_cos();
    let (sp, cp) = x[IDX_Q + 2].sin_cos();
    if ct.abs() < GIMBAL_LOCK_COS || !ct.is_finite() {
        return None;
    }
    let w = u.omega_m - block(x, IDX_BG);
    let a = u.a_m - block(x, IDX_BA);
    let (tt, ct2) = (st / ct, ct * ct);
    let s = sf * w[1] + cf * w[2];
    let d = cf * w[1] - sf * w[2];
    #[rustfmt::skip]
    let a_qq = Matrix3::new(
        tt * d, s / ct2,      0.0,
        -s,     0.0,          0.0,
        d / ct, s * st / ct2, 0.0,
    );
    // G(q)⁻¹ (crate::rotation::body_to_euler_rate).
    #[rustfmt::skip]
    let g_inv = Matrix3::new(
        1.0, sf * tt, cf * tt,
        0.0, cf,      -sf,
        0.0, sf / ct, cf / ct,
    );
    // R(q) = Rz(ψ)Ry(θ)Rx(φ) (crate::rotation::rotation_matrix).
    #[rustfmt::skip]
    let r = Matrix3::new(
        cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf,
        sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf,
        -st,     ct * sf,                ct * cf,
    );
    // ∂(R a)/∂φ, ∂(R a)/∂θ, ∂(R a)/∂ψ (crate::rotation::rotation_matrix_partials applied to a).
    let d_phi = Vector3::new(
        (cp * st * cf + sp * sf) * a[1] + (-cp * st * sf + sp * cf) * a[2],
        (sp * st * cf - cp * sf) * a[1] + (-sp * st * sf - cp * cf) * a[2],
        ct * cf * a[1] - ct * sf * a[2],
    );
    let d_theta = Vector3::new(
        -cp * st * a[0] + cp * ct * sf * a[1] + cp * ct * cf * a[2],
        -sp * st * a[0] + sp * ct * sf * a[1] + sp * ct * cf * a[2],
        -ct * a[0] - st * sf * a[1] - st * cf * a[2],
    );
    let d_psi = Vector3::new(
        -(r[(1, 0)] * a[0] + r[(1, 1)] * a[1] + r[(1, 2)] * a[2]),
        r[(0, 0)] * a[0] + r[(0, 1)] * a[1] + r[(0, 2)] * a[2],
        0.0,
    );
    let a_vq = Matrix3::from_columns(&[d_phi, d_theta, d_psi]);
    Some(JacobianBlocks { a_qq, g_inv, a_vq, r })
}

/// Dense state Jacobian `A = ∂f/∂x` (15×15) of eq:model1f; `None` at gimbal lock.
#[allow(non_snake_case)]
#[must_use]
pub fn A(x: &State, u: &ImuInput) -> Option<StateJacobian> {
    let b = jacobian_blocks(x, u)?;
    let mut a = StateJacobian::zeros();
    a.fixed_view_mut::<3, 3>(IDX_P, IDX_V).copy_from(&Matrix3::identity());
    a.fixed_view_mut::<3, 3>(IDX_Q, IDX_Q).copy_from(&b.a_qq);
    a.fixed_view_mut::<3, 3>(IDX_Q, IDX_BG).copy_from(&(-b.g_inv));
    a.fixed_view_mut::<3, 3>(IDX_V, IDX_Q).copy_from(&b.a_vq);
    a.fixed_view_mut::<3, 3>(IDX_V, IDX_BA).copy_from(&(-b.r));
    Some(a)
}

/// Noise Jacobian `U = ∂f/∂n` (15×12) of eq:model1f; `None` at gimbal lock.
///
/// Blocks: `q`-rows × `n_g` = `−G(q)⁻¹`, `v`-rows × `n_a` = `−R(q)`, `b_g` × `n_bg` = `I`,
/// `b_a` × `n_ba` = `I`.
#[allow(non_snake_case)]
#[must_use]
pub fn U(x: &State) -> Option<NoiseJacobian> {
    let q = block(x, IDX_Q);
    let g_inv = body_to_euler_rate(&q)?;
    let r = rotation_matrix(&q);
    let mut u = NoiseJacobian::zeros();
    u.fixed_view_mut::<3, 3>(IDX_Q, 0).copy_from(&(-g_inv));
    u.fixed_view_mut::<3, 3>(IDX_V, 3).copy_from(&(-r));
    u.fixed_view_mut::<3, 3>(IDX_BG, 6).copy_from(&Matrix3::identity());
    u.fixed_view_mut::<3, 3>(IDX_BA, 9).copy_from(&Matrix3::identity());
    Some(u)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hover_is_equilibrium() {
        let x = State::zeros();
        let u = ImuInput { omega_m: Vector3::zeros(), a_m: Vector3::new(0.0, 0.0, 9.81) };
        let xdot = f(&x, &u).unwrap();
        assert!(xdot.norm() < 1e-12);
    }
}
