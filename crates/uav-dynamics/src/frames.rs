//! Frame conversions between PX4's conventions and the project's: world NED ↔ ENU, body
//! FRD ↔ FLU, and a PX4 attitude quaternion to the project's ZYX Euler angles.
//!
//! PX4 logs vectors in a north-east-down world frame and a forward-right-down body frame, and
//! its attitude quaternion `q = [w, x, y, z]` rotates FRD body vectors into NED (PX4 uORB
//! `vehicle_attitude.msg`: "Quaternion rotation from the FRD body frame to the NED earth
//! frame"). The project uses east-north-up and forward-left-up ([`crate::rotation`]).
//!
//! Both changes of axes are symmetric permutation/sign matrices, each its own inverse:
//!
//! ```text
//! T_ne = ⎡0 1  0⎤  (NED → ENU: e = y_ned, n = x_ned, u = −z_ned)
//!        ⎢1 0  0⎥
//!        ⎣0 0 −1⎦
//! T_bf = diag(1, −1, −1)  (FRD → FLU: f = x, l = −y, u = −z)
//! ```
//!
//! so a body → world rotation transforms as `R_enu←flu = T_ne · R_ned←frd · T_bf`.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::rotation::euler_from_matrix;

/// The NED → ENU change of axes `T_ne` (its own inverse).
#[must_use]
pub fn ned_to_enu_matrix() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

/// The FRD → FLU change of body axes `T_bf` (its own inverse).
#[must_use]
pub fn frd_to_flu_matrix() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// A world vector in NED expressed in ENU (also ENU → NED: the map is an involution).
#[must_use]
pub fn ned_to_enu(v: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v[1], v[0], -v[2])
}

/// A body vector in FRD expressed in FLU (also FLU → FRD: the map is an involution).
#[must_use]
pub fn frd_to_flu(v: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v[0], -v[1], -v[2])
}

/// The body (FLU) → world (ENU) rotation of a PX4 quaternion `[w, x, y, z]` that rotates FRD
/// body vectors into NED. The quaternion is normalised first; `None` if its norm is not a
/// finite positive number.
#[must_use]
pub fn px4_quaternion_to_enu_flu(q_wxyz: [f64; 4]) -> Option<Matrix3<f64>> {
    let q = Quaternion::new(q_wxyz[0], q_wxyz[1], q_wxyz[2], q_wxyz[3]);
    let norm = q.norm();
    if !(norm.is_finite() && norm > 1e-9) {
        return None;
    }
    let r_ned_frd = UnitQuaternion::from_quaternion(q).to_rotation_matrix().into_inner();
    Some(ned_to_enu_matrix() * r_ned_frd * frd_to_flu_matrix())
}

/// ZYX Euler angles `[φ, θ, ψ]` (FLU body → ENU world, [`crate::rotation`]) of a PX4 attitude
/// quaternion; `None` for a quaternion of zero or non-finite norm.
///
/// In terms of PX4's own ZYX angles `[φ, θ, ψ]` (NED, FRD): roll carries over (a right-wing-down
/// roll is positive about the forward axis in both frames), pitch changes sign (nose up is
/// positive about FRD's right axis, negative about FLU's left axis), and yaw becomes `π/2 − ψ`
/// (heading counted counter-clockwise from east instead of clockwise from north).
#[must_use]
pub fn px4_quaternion_to_euler(q_wxyz: [f64; 4]) -> Option<Vector3<f64>> {
    px4_quaternion_to_enu_flu(q_wxyz).map(|r| euler_from_matrix(&r))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rotation::{rotation_matrix, wrap_angle};
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    #[test]
    fn level_north_facing_px4_attitude_is_yaw_ninety_degrees_in_enu() {
        let q = px4_quaternion_to_euler([1.0, 0.0, 0.0, 0.0]).unwrap();
        assert_relative_eq!(q, Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2), epsilon = 1e-12);
    }

    #[test]
    fn axes_map_as_stated() {
        // North in NED is (1, 0, 0); in ENU it is (0, 1, 0). Down is −up.
        assert_eq!(ned_to_enu(&Vector3::new(1.0, 0.0, 0.0)), Vector3::new(0.0, 1.0, 0.0));
        assert_eq!(ned_to_enu(&Vector3::new(0.0, 0.0, 1.0)), Vector3::new(0.0, 0.0, -1.0));
        // Right in FRD is −left in FLU; gravity reaction at rest reads −g in FRD, +g in FLU.
        assert_eq!(frd_to_flu(&Vector3::new(0.0, 1.0, -9.81)), Vector3::new(0.0, -1.0, 9.81));
        assert_eq!(ned_to_enu_matrix() * Vector3::new(1.0, 2.0, 3.0), ned_to_enu(&Vector3::new(1.0, 2.0, 3.0)));
        assert_eq!(frd_to_flu_matrix() * Vector3::new(1.0, 2.0, 3.0), frd_to_flu(&Vector3::new(1.0, 2.0, 3.0)));
    }

    #[test]
    fn degenerate_quaternions_are_refused() {
        assert!(px4_quaternion_to_euler([0.0; 4]).is_none());
        assert!(px4_quaternion_to_euler([f64::NAN, 0.0, 0.0, 1.0]).is_none());
    }

    proptest! {
        #[test]
        fn conversions_are_involutions(x in -1e3..1e3f64, y in -1e3..1e3f64, z in -1e3..1e3f64) {
            let v = Vector3::new(x, y, z);
            prop_assert_eq!(ned_to_enu(&ned_to_enu(&v)), v);
            prop_assert_eq!(frd_to_flu(&frd_to_flu(&v)), v);
        }

        /// A PX4 attitude given by its own NED yaw ψ, pitch θ and roll φ (FRD body, ZYX) maps to
        /// roll φ, pitch −θ, yaw π/2 − ψ, and the rotation is orthonormal with determinant 1.
        #[test]
        fn px4_euler_carries_over(
            roll in -1.4..1.4f64, pitch in -1.4..1.4f64, yaw in -3.1..3.1f64,
        ) {
            let r_ned_frd = rotation_matrix(&Vector3::new(roll, pitch, yaw));
            let uq = UnitQuaternion::from_matrix(&r_ned_frd);
            let q = [uq.w, uq.i, uq.j, uq.k];
            let r = px4_quaternion_to_enu_flu(q).unwrap();
            prop_assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-9);
            prop_assert!((r.determinant() - 1.0).abs() < 1e-9);
            let e = px4_quaternion_to_euler(q).unwrap();
            prop_assert!((e[0] - roll).abs() < 1e-7);
            prop_assert!((e[1] + pitch).abs() < 1e-7);
            prop_assert!(wrap_angle(e[2] - (std::f64::consts::FRAC_PI_2 - yaw)).abs() < 1e-7);
        }

        /// A vector seen in the body maps to the same world vector either way round.
        #[test]
        fn rotations_commute_with_the_axis_changes(
            w in -1.0..1.0f64, i in -1.0..1.0f64, j in -1.0..1.0f64, k in -1.0..1.0f64,
            x in -10.0..10.0f64, y in -10.0..10.0f64, z in -10.0..10.0f64,
        ) {
            prop_assume!((w * w + i * i + j * j + k * k).sqrt() > 0.1);
            let uq = UnitQuaternion::from_quaternion(Quaternion::new(w, i, j, k));
            let v_frd = Vector3::new(x, y, z);
            let world_ned = uq * v_frd;
            let r = px4_quaternion_to_enu_flu([w, i, j, k]).unwrap();
            prop_assert!((r * frd_to_flu(&v_frd) - ned_to_enu(&world_ned)).norm() < 1e-9);
        }
    }
}
