//! Property tests of the ZYX rotation module (docs/ARCHITECTURE.md, "Frames and units"): `R(q)`
//! orthonormal with det 1, Euler ↔ R round trip away from gimbal lock, `G(q)·G(q)⁻¹ = I`, angle
//! wrap in (−π, π].

use nalgebra::{Matrix3, Vector3};
use proptest::prelude::*;
use std::f64::consts::PI;
use uav_dynamics::rotation::{
    body_to_euler_rate, euler_from_matrix, euler_rate_to_body, rotation_matrix, rotation_matrix_partials, wrap_angle,
    wrap_euler,
};

fn any_angles() -> impl Strategy<Value = Vector3<f64>> {
    (-10.0..10.0f64, -10.0..10.0f64, -10.0..10.0f64).prop_map(|(a, b, c)| Vector3::new(a, b, c))
}

/// Euler angles in the canonical range, at least ~0.6° away from gimbal lock.
fn canonical_angles() -> impl Strategy<Value = Vector3<f64>> {
    (-PI + 1e-6..PI, -PI / 2.0 + 0.01..PI / 2.0 - 0.01, -PI + 1e-6..PI).prop_map(|(a, b, c)| Vector3::new(a, b, c))
}

proptest! {
    #[test]
    fn rotation_is_orthonormal_with_det_one(q in any_angles()) {
        let r = rotation_matrix(&q);
        prop_assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        prop_assert!((r.determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn euler_round_trip(q in canonical_angles()) {
        let back = euler_from_matrix(&rotation_matrix(&q));
        // Tolerance: asin near |θ| = π/2 − 0.01 loses about 1/cos θ ≈ 100 ulps of precision.
        prop_assert!(wrap_euler(&(back - q)).norm() < 1e-9, "q = {q:?}, back = {back:?}");
    }

    #[test]
    fn matrix_round_trip_any_angles(q in any_angles()) {
        // Any angles (even beyond the canonical range) give the same matrix back.
        let r = rotation_matrix(&q);
        prop_assert!((rotation_matrix(&euler_from_matrix(&r)) - r).norm() < 1e-9);
    }

    #[test]
    fn g_times_g_inverse_is_identity(q in canonical_angles()) {
        let gi = body_to_euler_rate(&q).unwrap();
        prop_assert!((euler_rate_to_body(&q) * gi - Matrix3::identity()).norm() < 1e-9);
    }

    #[test]
    fn g_maps_euler_rates_to_body_rates(q in canonical_angles(), qdot in any_angles()) {
        // R(q)ᵀ Ṙ(q) = [ω_B]× with Ṙ = Σ_j ∂R/∂q_j q̇_j.
        let r = rotation_matrix(&q);
        let d = rotation_matrix_partials(&q);
        let rdot = d[0] * qdot[0] + d[1] * qdot[1] + d[2] * qdot[2];
        let w = r.transpose() * rdot;
        let omega = Vector3::new(w[(2, 1)], w[(0, 2)], w[(1, 0)]);
        prop_assert!((omega - euler_rate_to_body(&q) * qdot).norm() < 1e-9);
    }

    #[test]
    fn partials_match_central_differences(q in any_angles()) {
        let h = 1e-6;
        let d = rotation_matrix_partials(&q);
        for j in 0..3 {
            let mut e = Vector3::zeros();
            e[j] = h;
            let fd = (rotation_matrix(&(q + e)) - rotation_matrix(&(q - e))) / (2.0 * h);
            // Central difference error O(h²) ≈ 1e-12 plus rounding 1e-16/h ≈ 1e-10.
            prop_assert!((fd - d[j]).norm() < 1e-8);
        }
    }

    #[test]
    fn wrap_lands_in_half_open_interval(a in -1e4..1e4f64) {
        let w = wrap_angle(a);
        prop_assert!(w > -PI && w <= PI, "wrap({a}) = {w}");
        // Same angle modulo 2π (tolerance grows with |a| through rounding of a itself).
        let k = ((a - w) / (2.0 * PI)).round();
        prop_assert!((a - w - 2.0 * PI * k).abs() < 1e-9 * (1.0 + a.abs()));
    }
}

#[test]
fn wrap_of_minus_pi_is_pi() {
    assert_eq!(wrap_angle(-PI), PI);
    assert!(wrap_angle(f64::NAN).is_nan());
}
