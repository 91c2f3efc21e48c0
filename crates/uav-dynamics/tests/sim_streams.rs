//! Integration tests of the flight simulator's public boundary (`sim::simulate`): IMU
//! consistency with the truth, sensor rates and time stamps, VO keyframes, determinism, and
//! named configuration errors.

use nalgebra::Vector3;
use uav_dynamics::noise::{NoiseConfig, NoiseShape};
use uav_dynamics::rotation::{body_to_euler_rate, rotation_matrix, wrap_euler};
use uav_dynamics::sim::{SimConfig, gravity, simulate};
use uav_dynamics::trajectory::{RandomRoute, RandomRouteConfig, ShapeConfig, eight};
use uav_dynamics::{Error, Flight};

/// Dead-reckon Model I's kinematics (eq:model1f without noise, Euler steps at the IMU rate)
/// from the truth at `k0` for `n` steps; returns the largest position and attitude error.
fn dead_reckon(flight: &Flight, k0: usize, n: usize) -> (f64, f64) {
    let dt = flight.truth[1].t - flight.truth[0].t;
    let s0 = flight.truth[k0];
    let (mut p, mut q, mut v) = (s0.p, s0.q, s0.v);
    let (mut max_p, mut max_q) = (0.0_f64, 0.0_f64);
    for k in k0..k0 + n {
        let imu = flight.streams.imu[k];
        let Some(g_inv) = body_to_euler_rate(&q) else { return (f64::INFINITY, f64::INFINITY) };
        let a = gravity() + rotation_matrix(&q) * imu.accel;
        p += v * dt;
        q += g_inv * imu.gyro * dt;
        v += a * dt;
        let truth = flight.truth[k + 1];
        max_p = max_p.max((p - truth.p).norm());
        max_q = max_q.max(wrap_euler(&(q - truth.q)).norm());
    }
    (max_p, max_q)
}

#[test]
fn noiseless_imu_integrates_back_to_the_truth() -> Result<(), Error> {
    let cfg = SimConfig::default().noiseless();
    let traj = eight(&ShapeConfig::default())?;
    let flight = simulate(&cfg, &traj, 30.0, 1)?;
    // 5 s of the eight's first loop (t = 10..15 s) at 200 Hz. First-order Euler integration
    // error is O(dt·T·|ȧ|·T) ≈ 0.005·5·0.5·5/2 ≈ 0.03 m at these jerks; the bound is 0.05 m
    // position and 2 mrad attitude (measured 0.016 m and 0.05 mrad).
    let (e_p, e_q) = dead_reckon(&flight, 2000, 1000);
    assert!(e_p < 0.05, "position error {e_p}");
    assert!(e_q < 2e-3, "attitude error {e_q}");
    // The accelerometer reads +thrust on body z (about +9.81 at hover).
    assert!((flight.streams.imu[0].accel - Vector3::new(0.0, 0.0, 9.81)).norm() < 1e-9);
    Ok(())
}

#[test]
fn aggressive_random_route_dead_reckons() -> Result<(), Error> {
    let cfg = SimConfig::default().noiseless();
    let rc = RandomRouteConfig { duration_s: 60.0, speed_min_mps: 10.0, ..Default::default() };
    let traj = RandomRoute::new(&rc, 3)?;
    let flight = simulate(&cfg, &traj, 20.0, 1)?;
    // 3 s at > 10 m/s: bound 0.05 m / 2 mrad as above (measured 0.017 m and 0.1 mrad).
    let (e_p, e_q) = dead_reckon(&flight, 1000, 600);
    assert!(e_p < 0.05, "position error {e_p}");
    assert!(e_q < 2e-3, "attitude error {e_q}");
    Ok(())
}

#[test]
fn rates_and_time_stamps_are_as_configured() -> Result<(), Error> {
    let cfg = SimConfig { gps_rate_hz: 5, ..SimConfig::default() };
    let traj = eight(&ShapeConfig::default())?;
    let flight = simulate(&cfg, &traj, 10.0, 2)?;
    let s = &flight.streams;
    assert_eq!(s.imu.len(), 2001);
    assert_eq!(flight.truth.len(), 2001);
    assert_eq!(s.gps.len(), 51);
    assert_eq!(s.attitude.len(), 101);
    assert_eq!(s.vo.len(), 101);
    for (k, imu) in s.imu.iter().enumerate() {
        assert_eq!(imu.t, k as f64 / 200.0);
        assert_eq!(flight.truth[k].t, imu.t);
    }
    for (m, g) in s.gps.iter().enumerate() {
        assert_eq!(g.t, m as f64 / 5.0);
        // Bit-identical to the coinciding IMU time.
        assert_eq!(g.t, s.imu[m * 40].t);
    }
    for (m, (a, v)) in s.attitude.iter().zip(&s.vo).enumerate() {
        assert_eq!(a.t, m as f64 / 10.0);
        assert_eq!(v.t, a.t);
    }
    Ok(())
}

#[test]
fn vo_keyframes_start_every_period_with_zero_relative_pose() -> Result<(), Error> {
    let cfg = SimConfig::default().noiseless();
    let traj = eight(&ShapeConfig::default())?;
    let flight = simulate(&cfg, &traj, 20.0, 3)?;
    for (m, vo) in flight.streams.vo.iter().enumerate() {
        assert_eq!(vo.keyframe as usize, m / 10);
        if m % 10 == 0 {
            assert!(vo.p_rel.norm() < 1e-12 && vo.q_rel.norm() < 1e-12);
        }
    }
    // Relative pose matches eq:model2g from the truth.
    let vo = flight.streams.vo[57];
    let (kf, now) = (flight.truth[50 * 20], flight.truth[57 * 20]);
    let r_f = rotation_matrix(&kf.q);
    assert!((vo.p_rel - r_f.transpose() * (now.p - kf.p)).norm() < 1e-9);
    Ok(())
}

#[test]
fn seeded_runs_repeat_and_seeds_differ() -> Result<(), Error> {
    let traj = eight(&ShapeConfig::default())?;
    for shape in NoiseShape::ALL {
        let cfg = SimConfig { noise: NoiseConfig::with_shape(shape), ..SimConfig::default() };
        let a = simulate(&cfg, &traj, 3.0, 42)?;
        assert_eq!(a, simulate(&cfg, &traj, 3.0, 42)?);
        assert_ne!(a.streams.gps, simulate(&cfg, &traj, 3.0, 43)?.streams.gps);
    }
    Ok(())
}

#[test]
fn gps_noise_has_the_configured_sigma() -> Result<(), Error> {
    let traj = eight(&ShapeConfig::default())?;
    let cfg = SimConfig { noise: NoiseConfig::with_shape(NoiseShape::Laplace), ..SimConfig::default() };
    let flight = simulate(&cfg, &traj, 200.0, 9)?;
    let errs: Vec<f64> =
        flight.streams.gps.iter().map(|g| g.p.x - flight.truth[(g.t * 200.0).round() as usize].p.x).collect();
    let n = errs.len() as f64;
    let mean = errs.iter().sum::<f64>() / n;
    let std = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    // 2001 samples: standard errors ≈ 0.011 (mean) and ≈ 0.014 (std, Laplace kurtosis 6).
    assert!(mean.abs() < 0.05, "mean {mean}");
    assert!((std - 0.5).abs() < 0.06, "std {std}");
    Ok(())
}

#[test]
fn bad_config_is_a_named_error() {
    let traj = eight(&ShapeConfig::default()).unwrap();
    let check = |cfg: SimConfig, field: &str| {
        let got = simulate(&cfg, &traj, 1.0, 0);
        assert!(matches!(&got, Err(Error::Config { field: f, .. }) if *f == field), "{field}: {got:?}");
    };
    check(SimConfig { gps_rate_hz: 7, ..SimConfig::default() }, "gps_rate_hz");
    check(SimConfig { vo_rate_hz: 0, ..SimConfig::default() }, "vo_rate_hz");
    check(SimConfig { keyframe_period_s: 0.25, ..SimConfig::default() }, "keyframe_period_s");
    check(SimConfig { gps_sigma_m: [0.5, f64::NAN, 0.5], ..SimConfig::default() }, "gps_sigma_m");
    check(SimConfig { accel_bias_walk: -1.0, ..SimConfig::default() }, "accel_bias_walk");
    assert!(matches!(
        simulate(&SimConfig::default(), &traj, f64::NAN, 0),
        Err(Error::Config { field: "duration_s", .. })
    ));
    // A flight longer than the step budget is refused before anything is allocated.
    for duration_s in [1e5, 1e9] {
        let e = simulate(&SimConfig::default(), &traj, duration_s, 0).unwrap_err();
        assert!(e.to_string().contains("more than the 10000000 one flight may hold"), "{e}");
    }
}
