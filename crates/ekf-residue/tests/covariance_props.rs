//! `P` stays symmetric positive semi-definite after every update (Joseph form, eq:ekf_update),
//! for both models, random seeds, noise shapes and GPS fusion patterns; and the sparse
//! Model I prediction equals the dense `F P Fᵀ + Q` for random states and covariances; a state
//! reset (`Ekf::reset_block`, `Estimator::reset_onto_fix`) keeps `P` symmetric positive
//! semi-definite and forgets exactly the reset states.
// Test helpers outside #[test] functions unwrap too (clippy allows it only inside tests).
#![allow(clippy::unwrap_used)]

mod common;

use ekf_residue::model1_filter::{ImuNoise, Model1Filter};
use ekf_residue::{
    CovarianceUpdate, DivergenceGuard, Ekf, Estimator, FilterConfig, GpsFusion, Measurements, ModelKind,
};
use nalgebra::{SMatrix, SVector, Vector3};
use proptest::prelude::*;
use uav_dynamics::model1::{self, ImuInput};
use uav_dynamics::noise::NoiseShape;

fn shape() -> impl Strategy<Value = NoiseShape> {
    prop_oneof![Just(NoiseShape::Gaussian), Just(NoiseShape::Exponential), Just(NoiseShape::Laplace)]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    #[test]
    fn covariance_is_symmetric_psd_after_every_update(
        seed in 0u64..10_000, shape in shape(), model2 in any::<bool>(), skip_mask in any::<u64>()
    ) {
        let (sim, flight) = common::eight_flight(shape, 8.0, seed);
        let model = if model2 { ModelKind::ModelII } else { ModelKind::ModelI };
        let cfg = FilterConfig::for_sim(model, &sim);
        let s = &flight.streams;
        let mut est = Estimator::new(&cfg, s.gps[0].t, &s.gps[0].p, &s.attitude[0].q, true, Some(&s.imu[0])).unwrap();
        let (mut gi, mut ai, mut vi) = (1, 1, 1);
        for (k, imu) in s.imu.iter().enumerate().skip(1) {
            est.imu(imu).unwrap();
            let take = |v: &mut usize, t: f64, ts: &dyn Fn(usize) -> Option<f64>| {
                if ts(*v).is_some_and(|x| (x - t).abs() < 1e-9) { *v += 1; Some(*v - 1) } else { None }
            };
            let g = take(&mut gi, imu.t, &|i| s.gps.get(i).map(|x| x.t));
            let a = take(&mut ai, imu.t, &|i| s.attitude.get(i).map(|x| x.t));
            let v = take(&mut vi, imu.t, &|i| s.vo.get(i).map(|x| x.t));
            if g.is_none() && a.is_none() && v.is_none() {
                continue;
            }
            let m = Measurements {
                t: imu.t,
                gps: g.map(|i| s.gps[i].p),
                attitude: a.map(|i| s.attitude[i].q),
                vo: v.map(|i| s.vo[i]),
            };
            let fusion = if (skip_mask >> (k / 20 % 64)) & 1 == 1 { GpsFusion::Skip } else { GpsFusion::Fuse };
            est.measure(&m, fusion).unwrap();
            let (min_eig, asym) = est.covariance_health();
            let scale = est.covariance_trace();
            // Symmetrised after every update: exactly symmetric. PSD up to rounding of the
            // eigen-solver, ~1e-15 relative to the largest entry.
            prop_assert!(asym == 0.0, "asymmetry {asym}");
            prop_assert!(min_eig > -1e-12 * scale, "min eigenvalue {min_eig} (trace {scale})");
        }
    }

    #[test]
    fn sparse_model1_prediction_equals_dense(
        q in (-1.0..1.0f64, -1.2..1.2f64, -3.0..3.0f64), w in (-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64),
        seed in 0u64..1000
    ) {
        let x = model1::state(&Vector3::new(1.0, -2.0, 10.0), &Vector3::new(q.0, q.1, q.2), &Vector3::new(3.0, -1.0, 0.2),
            &Vector3::new(1e-3, -2e-3, 5e-4), &Vector3::new(0.05, -0.02, 0.1));
        let u = ImuInput { omega_m: Vector3::new(w.0, w.1, w.2), a_m: Vector3::new(0.3, -0.2, 9.7) };
        let l = SMatrix::<f64, 15, 15>::from_fn(|i, j| (((i * 31 + j * 17) as u64 + seed) % 23) as f64 / 23.0 - 0.5);
        let p0 = l * l.transpose() + SMatrix::<f64, 15, 15>::identity() * 0.1;
        let mut a = Model1Filter::new(x, p0, 0.0, ImuNoise::default(), CovarianceUpdate::Joseph, DivergenceGuard::default()).unwrap();
        let mut b = a.clone();
        a.predict(&u, 0.005).unwrap();
        b.predict_dense(&u, 0.005).unwrap();
        // Same products summed in another order: rounding only (entries of P are O(10)).
        prop_assert!((a.ekf().p() - b.ekf().p()).abs().max() < 1e-12);
    }

    #[test]
    fn a_block_reset_forgets_that_block_and_keeps_p_psd(
        seed in 0u64..1000, idx in 0usize..=12, var in 0.0..200.0f64
    ) {
        let l = SMatrix::<f64, 15, 15>::from_fn(|i, j| (((i * 31 + j * 17) as u64 + seed) % 23) as f64 / 23.0 - 0.5);
        let p0 = l * l.transpose() + SMatrix::<f64, 15, 15>::identity() * 0.1;
        let mut ekf = Ekf::<15>::new(SVector::zeros(), p0, CovarianceUpdate::Joseph, DivergenceGuard::default()).unwrap();
        ekf.reset_block::<3>(idx, var).unwrap();
        let p = ekf.p();
        let inside = |i: usize| (idx..idx + 3).contains(&i);
        for i in 0..15 {
            for j in 0..15 {
                let want = match (inside(i), inside(j)) {
                    (false, false) => p0[(i, j)],
                    _ if i == j => var,
                    _ => 0.0,
                };
                prop_assert!(p[(i, j)] == want, "P[{i},{j}] = {} (want {want})", p[(i, j)]);
            }
        }
        let min_eig = p.symmetric_eigenvalues().min();
        prop_assert!(min_eig > -1e-12 * p.trace(), "min eigenvalue {min_eig}");
    }

    #[test]
    fn a_reset_onto_a_fix_moves_the_position_and_forgets_or_sets_the_velocity(
        seed in 0u64..10_000, model2 in any::<bool>(), dx in -50.0..50.0f64, dy in -50.0..50.0f64,
        set_v in any::<bool>(), vx in -10.0..10.0f64, var in 0.0..5.0f64
    ) {
        let (sim, flight) = common::eight_flight(NoiseShape::Gaussian, 4.0, seed);
        let model = if model2 { ModelKind::ModelII } else { ModelKind::ModelI };
        let cfg = FilterConfig::for_sim(model, &sim);
        let s = &flight.streams;
        let mut est = Estimator::new(&cfg, s.gps[0].t, &s.gps[0].p, &s.attitude[0].q, true, Some(&s.imu[0])).unwrap();
        for imu in s.imu.iter().skip(1).take(400) {
            est.imu(imu).unwrap();
        }
        let v0 = est.estimate().v;
        let fix = est.estimate().p + Vector3::new(dx, dy, 1.0);
        let velocity = set_v.then_some((Vector3::new(vx, 1.0, -0.5), var));
        est.reset_onto_fix(&fix, velocity).unwrap();
        let e = est.estimate();
        prop_assert!((e.p - fix).norm() < 1e-12);
        let (want_v, var_v) = velocity.unwrap_or((v0, cfg.init.sigma_v0 * cfg.init.sigma_v0));
        prop_assert!((e.v - want_v).norm() < 1e-12, "{} vs {want_v}", e.v);
        prop_assert!((e.v_cov - SMatrix::<f64, 3, 3>::identity() * var_v).abs().max() == 0.0, "{}", e.v_cov);
        let (min_eig, asym) = est.covariance_health();
        prop_assert!(asym == 0.0 && min_eig > -1e-12 * est.covariance_trace(), "{min_eig} {asym}");
        prop_assert!(est.reset_onto_fix(&Vector3::new(f64::NAN, 0.0, 0.0), None).is_err());
        prop_assert!(est.reset_onto_fix(&fix, Some((Vector3::new(f64::NAN, 0.0, 0.0), 1.0))).is_err());
        prop_assert!(est.reset_onto_fix(&fix, Some((Vector3::zeros(), -1.0))).is_err());
    }
}
