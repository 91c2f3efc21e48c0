//! Bad input gives the documented error, never a panic: NaN in a sensor sample, unordered
//! time stamps, wrong-length vectors, a measurement in the past, streams that cannot initialise
//! the model, and a diverging filter.
// Test helpers outside #[test] functions unwrap too (clippy allows it only inside tests).
#![allow(clippy::unwrap_used)]

mod common;

use ekf_residue::{
    CovarianceUpdate, DivergenceGuard, Ekf, Estimator, FilterConfig, FilterError, GpsFusion, Measurements, ModelKind,
    generate_residues,
};
use nalgebra::{DMatrix, DVector, SMatrix, SVector, Vector3};
use uav_dynamics::noise::NoiseShape;

fn flight() -> uav_dynamics::sensors::Flight {
    common::eight_flight(NoiseShape::Gaussian, 3.0, 1).1
}

#[test]
fn nan_in_a_sample_names_stream_index_and_time() {
    let mut f = flight();
    f.streams.gps[7].p[1] = f64::NAN;
    let err = generate_residues(&f.streams, &FilterConfig::new(ModelKind::ModelI)).unwrap_err();
    assert_eq!(err, FilterError::NonFiniteInput { stream: "gps", idx: 7, t: f.streams.gps[7].t, field: "p" });
    assert_eq!(err.to_string(), format!("gps sample 7 (t = {} s): non-finite p", f.streams.gps[7].t));

    let mut f = flight();
    f.streams.imu[100].accel[2] = f64::INFINITY;
    let err = generate_residues(&f.streams, &FilterConfig::new(ModelKind::ModelII)).unwrap_err();
    assert!(matches!(err, FilterError::NonFiniteInput { stream: "imu", idx: 100, field: "accel", .. }), "{err}");

    let mut f = flight();
    f.streams.vo[3].q_rel[0] = f64::NAN;
    let err = generate_residues(&f.streams, &FilterConfig::new(ModelKind::ModelII)).unwrap_err();
    assert!(matches!(err, FilterError::NonFiniteInput { stream: "vo", idx: 3, field: "q_rel", .. }), "{err}");
}

#[test]
fn unordered_timestamps_name_the_stream() {
    let mut f = flight();
    f.streams.attitude.swap(4, 5);
    let err = generate_residues(&f.streams, &FilterConfig::new(ModelKind::ModelI)).unwrap_err();
    assert!(matches!(err, FilterError::Unordered { stream: "attitude", idx: 5, .. }), "{err}");

    let mut f = flight();
    f.streams.imu[50].t = f.streams.imu[49].t;
    let err = generate_residues(&f.streams, &FilterConfig::new(ModelKind::ModelI)).unwrap_err();
    assert!(matches!(err, FilterError::Unordered { stream: "imu", idx: 50, .. }), "{err}");
}

#[test]
fn wrong_length_vectors_are_dimension_errors() {
    let mut ekf =
        Ekf::<15>::new(SVector::zeros(), SMatrix::identity(), CovarianceUpdate::Joseph, DivergenceGuard::default())
            .unwrap();
    let err = ekf.update_dyn(&DVector::zeros(3), &DMatrix::zeros(2, 15), &DMatrix::identity(3, 3), 1.0).unwrap_err();
    assert_eq!(err, FilterError::Dim { what: "rows of H (= length of r_k)", expected: 3, got: 2 });
    let err = ekf.update_dyn(&DVector::zeros(3), &DMatrix::zeros(3, 14), &DMatrix::identity(3, 3), 1.0).unwrap_err();
    assert!(matches!(err, FilterError::Dim { expected: 15, got: 14, .. }));
    let err = ekf.update_dyn(&DVector::zeros(3), &DMatrix::zeros(3, 15), &DMatrix::identity(2, 2), 1.0).unwrap_err();
    assert!(matches!(err, FilterError::Dim { expected: 3, got: 2, .. }));
    // A well-formed runtime-sized update works.
    let mut h = DMatrix::zeros(3, 15);
    h.view_mut((0, 0), (3, 3)).fill_with_identity();
    let inn = ekf.update_dyn(&DVector::from_element(3, 1.0), &h, &DMatrix::identity(3, 3), 1.0).unwrap();
    assert!((inn.nis - 1.5).abs() < 1e-12);
}

#[test]
fn measurement_in_the_past_and_missing_imu() {
    let f = flight();
    let s = &f.streams;
    let cfg = FilterConfig::new(ModelKind::ModelI);
    let mut est = Estimator::new(&cfg, 1.0, &s.gps[10].p, &s.attitude[10].q, true, None).unwrap();
    let m = Measurements { t: 1.1, gps: Some(s.gps[11].p), attitude: None, vo: None };
    assert!(matches!(est.measure(&m, GpsFusion::Fuse), Err(FilterError::NoData { .. })));
    est.imu(&s.imu[200]).unwrap();
    let past = Measurements { t: 0.5, ..m };
    assert_eq!(
        est.measure(&past, GpsFusion::Fuse).unwrap_err(),
        FilterError::InThePast { stream: "measurement", t: 0.5, t_filter: 1.0 }
    );
    let nan = Measurements { gps: Some(Vector3::new(0.0, f64::NAN, 0.0)), ..m };
    assert!(matches!(est.measure(&nan, GpsFusion::Fuse), Err(FilterError::NonFiniteInput { stream: "gps", .. })));
}

#[test]
fn streams_that_cannot_initialise_are_no_data() {
    let mut f = flight();
    f.streams.attitude.clear();
    let err = generate_residues(&f.streams, &FilterConfig::new(ModelKind::ModelI)).unwrap_err();
    assert!(matches!(err, FilterError::NoData { .. }), "{err}");
}

#[test]
fn invalid_config_names_the_field() {
    let mut cfg = FilterConfig::new(ModelKind::ModelI);
    cfg.meas.gps_sigma_m[2] = 0.0;
    let err = generate_residues(&flight().streams, &cfg).unwrap_err();
    assert!(matches!(err, FilterError::Config { field: "meas.gps_sigma_m", .. }), "{err}");
}

#[test]
fn a_persistent_absurd_innovation_is_divergence() {
    // GPS replaced by a position 1 km away with a tiny claimed σ: every NIS is absurd.
    let mut f = flight();
    for g in &mut f.streams.gps {
        g.p += Vector3::new(1000.0, 0.0, 0.0);
    }
    let mut cfg = FilterConfig::new(ModelKind::ModelI);
    cfg.guard.max_absurd_updates = 3;
    cfg.init.sigma_v0 = 0.1;
    // The initial fix is also shifted, so start from the true first fix to make the rest absurd.
    let err = (|| -> Result<(), FilterError> {
        let s = &f.streams;
        let mut est = Estimator::new(
            &cfg,
            s.gps[0].t,
            &(s.gps[0].p - Vector3::new(1000.0, 0.0, 0.0)),
            &s.attitude[0].q,
            true,
            Some(&s.imu[0]),
        )?;
        for (k, imu) in s.imu.iter().enumerate().skip(1) {
            est.imu(imu)?;
            if k % 20 == 0 {
                let m = Measurements {
                    t: imu.t,
                    gps: Some(s.gps[k / 20].p),
                    attitude: Some(s.attitude[k / 20].q),
                    vo: None,
                };
                est.measure(&m, GpsFusion::Fuse)?;
            }
        }
        Ok(())
    })()
    .unwrap_err();
    assert!(matches!(err, FilterError::Diverged { .. }), "{err}");
}
