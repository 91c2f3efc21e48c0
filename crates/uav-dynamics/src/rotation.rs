//! ZYX Euler rotations `R(q)`, the Euler-rate map `G(q)` and its inverse, matrix → Euler, and
//! angle wrapping (docs/ARCHITECTURE.md, "Frames and units"; used by paper eq:model1f,
//! eq:model1g, eq:model2g).
//!
//! Convention: `q = [φ, θ, ψ]` (roll, pitch, yaw, radians), `R(q) = Rz(ψ)·Ry(θ)·Rx(φ)` maps
//! body-frame (FLU) vectors to the world frame (ENU). Body angular rate `ω_B = G(q)·q̇` with
//!
//! ```text
//!        ⎡1    0        −sin θ     ⎤
//! G(q) = ⎢0   cos φ   sin φ·cos θ  ⎥
//!        ⎣0  −sin φ   cos φ·cos θ  ⎦
//! ```
//!
//! `G(q)` is singular at gimbal lock (`cos θ = 0`); [`body_to_euler_rate`] reports that as `None`.

use nalgebra::{Matrix3, Vector3};
use std::f64::consts::PI;

/// Below this `|cos θ|` the Euler-rate map is treated as singular (gimbal lock).
///
/// `1e-9` keeps `G(q)⁻¹` entries below ~1e9, far beyond any flyable attitude.
pub const GIMBAL_LOCK_COS: f64 = 1e-9;

/// Rotation about the body x axis by `φ` (roll).
#[must_use]
pub fn rot_x(phi: f64) -> Matrix3<f64> {
    let (s, c) = phi.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

/// Rotation about the y axis by `θ` (pitch).
#[must_use]
pub fn rot_y(theta: f64) -> Matrix3<f64> {
    let (s, c) = theta.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

/// Rotation about the z axis by `ψ` (yaw).
#[must_use]
pub fn rot_z(psi: f64) -> Matrix3<f64> {
    let (s, c) = psi.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// Body → world rotation `R(q) = Rz(ψ)·Ry(θ)·Rx(φ)` for `q = [φ, θ, ψ]`.
#[must_use]
pub fn rotation_matrix(q: &Vector3<f64>) -> Matrix3<f64> {
    let (sf, cf) = q[0].sin_cos();
    let (st, ct) = q[1].sin_cos();
    let (sp, cp) = q[2].sin_cos();
    Matrix3::new(
        cp * ct,
        cp * st * sf - sp * cf,
        cp * st * cf + sp * sf,
        sp * ct,
        sp * st * sf + cp * cf,
        sp * st * cf - cp * sf,
        -st,
        ct * sf,
        ct * cf,
    )
}

/// Partial derivatives `[∂R/∂φ, ∂R/∂θ, ∂R/∂ψ]` of [`rotation_matrix`].
///
/// Used by the analytic Jacobians of Model I and Model II.
#[must_use]
pub fn rotation_matrix_partials(q: &Vector3<f64>) -> [Matrix3<f64>; 3] {
    let (sf, cf) = q[0].sin_cos();
    let (st, ct) = q[1].sin_cos();
    let (sp, cp) = q[2].sin_cos();
    let d_phi = Matrix3::new(
        0.0,
        cp * st * cf + sp * sf,
        -cp * st * sf + sp * cf,
        0.0,
        sp * st * cf - cp * sf,
        -sp * st * sf - cp * cf,
        0.0,
        ct * cf,
        -ct * sf,
    );
    let d_theta = Matrix3::new(
        -cp * st,
        cp * ct * sf,
        cp * ct * cf,
        -sp * st,
        sp * ct * sf,
        sp * ct * cf,
        -ct,
        -st * sf,
        -st * cf,
    );
    let d_psi = Matrix3::new(
        -sp * ct,
        -sp * st * sf - cp * cf,
        -sp * st * cf + cp * sf,
        cp * ct,
        cp * st * sf - sp * cf,
        cp * st * cf + sp * sf,
        0.0,
        0.0,
        0.0,
    );
    [d_phi, d_theta, d_psi]
}

/// Euler-rate → body-rate map `G(q)`: `ω_B = G(q)·q̇` (ZYX convention, see module doc).
#[must_use]
pub fn euler_rate_to_body(q: &Vector3<f64>) -> Matrix3<f64> {
    let (sf, cf) = q[0].sin_cos();
    let (st, ct) = q[1].sin_cos();
    Matrix3::new(1.0, 0.0, -st, 0.0, cf, sf * ct, 0.0, -sf, cf * ct)
}

/// Body-rate → Euler-rate map `G(q)⁻¹`: `q̇ = G(q)⁻¹·ω_B`.
///
/// ```text
///          ⎡1  sin φ·tan θ  cos φ·tan θ⎤
/// G(q)⁻¹ = ⎢0     cos φ       −sin φ   ⎥
///          ⎣0  sin φ/cos θ  cos φ/cos θ⎦
/// ```
///
/// Returns `None` at gimbal lock, `|cos θ| < GIMBAL_LOCK_COS`.
#[must_use]
pub fn body_to_euler_rate(q: &Vector3<f64>) -> Option<Matrix3<f64>> {
    let (sf, cf) = q[0].sin_cos();
    let (st, ct) = q[1].sin_cos();
    if ct.abs() < GIMBAL_LOCK_COS || !ct.is_finite() {
        return None;
    }
    let tt = st / ct;
    Some(Matrix3::new(1.0, sf * tt, cf * tt, 0.0, cf, -sf, 0.0, sf / ct, cf / ct))
}

/// ZYX Euler angles `[φ, θ, ψ]` of a rotation matrix (inverse of [`rotation_matrix`]).
///
/// `θ ∈ [−π/2, π/2]`, roll and yaw wrapped to (−π, π]. At gimbal lock only `φ ± ψ` is
/// determined; this returns the solution with `φ = 0`. Entries of `r` outside [−1, 1] through
/// rounding are clamped before `asin`.
#[must_use]
pub fn euler_from_matrix(r: &Matrix3<f64>) -> Vector3<f64> {
    let sin_theta = (-r[(2, 0)]).clamp(-1.0, 1.0);
    let theta = sin_theta.asin();
    let cos_theta = r[(2, 1)].hypot(r[(2, 2)]);
    if cos_theta > 1e-12 {
        let phi = r[(2, 1)].atan2(r[(2, 2)]);
        let psi = r[(1, 0)].atan2(r[(0, 0)]);
        Vector3::new(wrap_angle(phi), theta, wrap_angle(psi))
    } else {
        // Gimbal lock: R[0,1] = cψ sθ sφ − sψ cφ, R[1,1] = sψ sθ sφ + cψ cφ; with φ = 0:
        // R[0,1] = −sin ψ, R[1,1] = cos ψ.
        let psi = (-r[(0, 1)]).atan2(r[(1, 1)]);
        Vector3::new(0.0, theta, wrap_angle(psi))
    }
}

/// Wrap an angle to (−π, π]. Non-finite input is returned unchanged (NaN stays NaN).
#[must_use]
pub fn wrap_angle(a: f64) -> f64 {
    if !a.is_finite() {
        return a;
    }
    if a > -PI && a <= PI {
        return a;
    }
    let two_pi = 2.0 * PI;
    let mut w = a.rem_euclid(two_pi); // [0, 2π)
    if w > PI {
        w -= two_pi;
    }
    // rem_euclid can round to exactly 2π for tiny negative inputs; fold it back.
    if w <= -PI {
        w += two_pi;
    }
    if w > PI {
        w = PI;
    }
    w
}

/// Wrap all three Euler angles to (−π, π] (pitch too: a pitch residue is an angle difference).
#[must_use]
pub fn wrap_euler(q: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(wrap_angle(q[0]), wrap_angle(q[1]), wrap_angle(q[2]))
}

/// Skew-symmetric cross-product matrix `[v]×` with `[v]×·w = v × w`.
#[must_use]
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v[2], v[1], v[2], 0.0, -v[0], -v[1], v[0], 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_is_product_of_elementary_rotations() {
        let q = Vector3::new(0.3, -0.4, 2.0);
        let r = rot_z(q[2]) * rot_y(q[1]) * rot_x(q[0]);
        assert!((rotation_matrix(&q) - r).norm() < 1e-14);
    }

    #[test]
    fn g_inverse_is_inverse() {
        let q = Vector3::new(0.3, -0.4, 2.0);
        let g = euler_rate_to_body(&q);
        let gi = body_to_euler_rate(&q).unwrap();
        assert!((g * gi - Matrix3::identity()).norm() < 1e-12);
        assert!(body_to_euler_rate(&Vector3::new(0.0, std::f64::consts::FRAC_PI_2, 0.0)).is_none());
    }

    #[test]
    fn wrap_edges() {
        assert_eq!(wrap_angle(PI), PI);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-15);
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5 + 4.0 * PI) - 0.5).abs() < 1e-12);
    }
}
