//! Analytic Jacobians of Model I (eq:model1f, eq:model1g) and Model II (eq:model2f, eq:model2g)
//! against central differences.

use nalgebra::{DMatrix, SVector, Vector3};
use proptest::prelude::*;
use uav_dynamics::{model1, model2};

/// Central-difference Jacobian of `fun` at `x` with step `h`.
fn numeric_jacobian<const N: usize, const M: usize>(
    fun: impl Fn(&SVector<f64, N>) -> SVector<f64, M>,
    x: &SVector<f64, N>,
    h: f64,
) -> DMatrix<f64> {
    let mut j = DMatrix::zeros(M, N);
    for c in 0..N {
        let mut e = SVector::<f64, N>::zeros();
        e[c] = h;
        let col = (fun(&(x + e)) - fun(&(x - e))) / (2.0 * h);
        for r in 0..M {
            j[(r, c)] = col[r];
        }
    }
    j
}

fn v3(range: f64) -> impl Strategy<Value = Vector3<f64>> {
    (-range..range, -range..range, -range..range).prop_map(|(a, b, c)| Vector3::new(a, b, c))
}

/// Attitudes away from gimbal lock (|θ| ≤ 1.2 rad) and from the yaw wrap of relative angles.
fn attitude() -> impl Strategy<Value = Vector3<f64>> {
    (-1.2..1.2f64, -1.2..1.2f64, -1.4..1.4f64).prop_map(|(a, b, c)| Vector3::new(a, b, c))
}

fn model1_state() -> impl Strategy<Value = model1::State> {
    (v3(50.0), attitude(), v3(10.0), v3(0.1), v3(0.5)).prop_map(|(p, q, v, bg, ba)| model1::state(&p, &q, &v, &bg, &ba))
}

fn imu() -> impl Strategy<Value = model1::ImuInput> {
    (v3(2.0), v3(15.0)).prop_map(|(omega_m, a_m)| model1::ImuInput { omega_m, a_m })
}

// Tolerances: step h = 1e-6, central-difference truncation O(h²·|f'''|) ≈ 1e-10 and rounding
// O(ε·|f|/h) ≈ 1e-9 for |f| ≈ 10; 1e-6 absolute on entries of size ≤ ~50 leaves ample margin
// while any sign or index error (order 1e-2 or more) fails.
const TOL: f64 = 1e-6;

proptest! {
    #[test]
    fn model1_a_matches_central_differences(x in model1_state(), u in imu()) {
        let a = model1::A(&x, &u).unwrap();
        let num = numeric_jacobian(|y| model1::f(y, &u).unwrap(), &x, 1e-6);
        let diff = (DMatrix::from_iterator(15, 15, a.iter().copied()) - num).abs().max();
        prop_assert!(diff < TOL, "max |A − A_fd| = {diff}");
    }

    #[test]
    fn model1_u_matches_central_differences(x in model1_state(), u in imu()) {
        let uj = model1::U(&x).unwrap();
        let num = numeric_jacobian(|n| model1::f_noisy(&x, &u, n).unwrap(), &model1::Noise::zeros(), 1e-6);
        let diff = (DMatrix::from_iterator(15, 12, uj.iter().copied()) - num).abs().max();
        prop_assert!(diff < TOL, "max |U − U_fd| = {diff}");
    }

    #[test]
    fn model1_c_matches_central_differences(x in model1_state()) {
        let num = numeric_jacobian(model1::g, &x, 1e-6);
        let c = model1::C();
        let diff = (DMatrix::from_iterator(6, 15, c.iter().copied()) - num).abs().max();
        prop_assert!(diff < TOL);
    }

    #[test]
    fn model2_a_matches_central_differences(x1 in model1_state(), pf in v3(50.0), qf in attitude(), u in imu()) {
        let x = model2::augment(&x1, &pf, &qf);
        let a = model2::A(&x, &u).unwrap();
        let num = numeric_jacobian(|y| model2::f(y, &u).unwrap(), &x, 1e-6);
        let diff = (DMatrix::from_iterator(21, 21, a.iter().copied()) - num).abs().max();
        prop_assert!(diff < TOL, "max |A₂ − A₂_fd| = {diff}");
    }

    #[test]
    fn model2_vo_jacobian_matches_central_differences(
        p in v3(20.0), q in attitude(), pf in v3(20.0), dq in (-0.6..0.6f64, -0.6..0.6f64, -0.6..0.6f64)
    ) {
        // Keyframe orientation near the current one so that the relative yaw stays far from ±π.
        let qf = q + Vector3::new(dq.0, dq.1, dq.2);
        let x1 = model1::state(&p, &q, &Vector3::zeros(), &Vector3::zeros(), &Vector3::zeros());
        let x = model2::augment(&x1, &pf, &qf);
        let c = model2::vo_jacobian(&x).unwrap();
        let num = numeric_jacobian(model2::g_vo, &x, 1e-6);
        let diff = (DMatrix::from_iterator(6, 21, c.iter().copied()) - num).abs().max();
        prop_assert!(diff < TOL, "max |C_vo − C_fd| = {diff}");
    }

    #[test]
    fn model2_gps_jacobian_matches_central_differences(x1 in model1_state(), pf in v3(50.0), qf in attitude()) {
        let x = model2::augment(&x1, &pf, &qf);
        let num = numeric_jacobian(model2::g_gps, &x, 1e-6);
        let c = model2::gps_jacobian();
        let diff = (DMatrix::from_iterator(3, 21, c.iter().copied()) - num).abs().max();
        prop_assert!(diff < TOL);
    }
}
