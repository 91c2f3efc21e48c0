//! Round trips of every file format of `eval::io` (docs/data-format.md): write → read gives
//! bit-identical samples, because `f64` is printed in shortest round-trip form.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use ekf_residue::ResidueSeries;
use eval::io::{
    AttackRecord, CovarianceLayout, FlightDir, Overwrite, read_attack, read_flight_dir, read_residues, write_attack,
    write_flight_dir, write_residues,
};
use nalgebra::{DMatrix, Vector3};
use proptest::prelude::*;
use uav_dynamics::{AttitudeSample, GpsSample, ImuSample, SensorStreams, TruthSample, VoSample};

/// Any finite f64 within the readers' tightest plausibility bound (`MAX_GYRO_RAD_S`, 100),
/// including subnormals and every exponent below it.
fn finite() -> impl Strategy<Value = f64> {
    prop_oneof![
        any::<f64>().prop_filter("finite", |v| v.is_finite()).prop_map(|v| v % eval::io::MAX_GYRO_RAD_S),
        -1e2..1e2f64,
        Just(0.1 + 0.2),
        Just(-0.0),
        Just(5e-324)
    ]
}

fn v3() -> impl Strategy<Value = Vector3<f64>> {
    (finite(), finite(), finite()).prop_map(|(a, b, c)| Vector3::new(a, b, c))
}

/// Strictly increasing time stamps from positive increments.
fn times(n: usize) -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(1e-6..1.0f64, n).prop_map(|dts| {
        let mut t = -0.5;
        dts.into_iter()
            .map(|dt| {
                t += dt;
                t
            })
            .collect()
    })
}

fn flight() -> impl Strategy<Value = FlightDir> {
    (1usize..20).prop_flat_map(|n| {
        (
            times(n),
            prop::collection::vec((v3(), v3(), v3(), v3(), v3()), n),
            prop::collection::vec((0u32..3, any::<bool>()), n),
        )
            .prop_map(|(t, vals, extra)| {
                let mut streams = SensorStreams::default();
                let mut truth = Vec::new();
                let mut attack = Vec::new();
                let mut keyframe = 0;
                for (k, (&t, (a, b, c, d, e))) in t.iter().zip(vals).enumerate() {
                    let (dk, label) = extra[k];
                    keyframe += dk;
                    streams.imu.push(ImuSample { t, gyro: a, accel: b });
                    streams.gps.push(GpsSample { t, p: c });
                    streams.attitude.push(AttitudeSample { t, q: d });
                    streams.vo.push(VoSample { t, keyframe, p_rel: e, q_rel: a });
                    truth.push(TruthSample { t, p: a, q: b, v: c, b_g: d, b_a: e });
                    attack.push(AttackRecord { t, label, d: if label { e } else { Vector3::zeros() } });
                }
                FlightDir {
                    streams,
                    truth: Some(truth),
                    attack: Some(attack),
                    config_toml: Some("seed = 7\n".into()),
                    filter_toml: None,
                }
            })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn flight_dir_round_trips_bit_exactly(f in flight()) {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("flight");
        write_flight_dir(&dir, &f, Overwrite::Refuse).unwrap();
        let back = read_flight_dir(&dir).unwrap();
        prop_assert_eq!(back, f);
    }

    #[test]
    fn residues_round_trip_in_both_layouts(
        n in 1usize..12,
        seed_r in prop::collection::vec(-50.0..50.0f64, 36),
        seed_l in prop::collection::vec(-3.0..3.0f64, 9),
        full in any::<bool>(),
    ) {
        let channels = vec!["gps_x".to_owned(), "gps_y".to_owned(), "att_yaw".to_owned()];
        // S_k = L Lᵀ + I is symmetric positive definite for any L.
        let l = DMatrix::from_row_slice(3, 3, &seed_l);
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.1).collect();
        let r: Vec<Vec<f64>> = (0..n).map(|k| seed_r[(3 * k) % 36..(3 * k) % 36 + 3].to_vec()).collect();
        let s: Vec<DMatrix<f64>> = (0..n)
            .map(|k| {
                let lk = &l * (1.0 + k as f64);
                let sk = &lk * lk.transpose() + DMatrix::identity(3, 3);
                (&sk + sk.transpose()) * 0.5
            })
            .collect();
        let series = ResidueSeries::new(t, channels, r, s).unwrap();
        let labels: Vec<bool> = (0..n).map(|k| k % 3 == 1).collect();
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("residues.csv");
        let layout = if full { CovarianceLayout::Full } else { CovarianceLayout::Upper };
        write_residues(&path, &series, Some(&labels), layout).unwrap();
        let back = read_residues(&path).unwrap();
        prop_assert_eq!(back.series(), &series);
        prop_assert_eq!(back.labels(), Some(&labels[..]));
    }
}

#[test]
fn missing_optional_files_read_as_absent() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("own-log");
    let imu = vec![ImuSample { t: 0.0, gyro: Vector3::zeros(), accel: Vector3::new(0.0, 0.0, 9.81) }];
    let flight = FlightDir { streams: SensorStreams { imu, ..SensorStreams::default() }, ..FlightDir::default() };
    write_flight_dir(&dir, &flight, Overwrite::Refuse).unwrap();
    assert_eq!(read_flight_dir(&dir).unwrap(), flight);
    assert!(!dir.join("gps.csv").exists());
}

#[test]
fn attack_file_round_trips() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("attack.csv");
    let recs = vec![
        AttackRecord { t: 0.1, label: false, d: Vector3::zeros() },
        AttackRecord { t: 0.2, label: true, d: Vector3::new(3.0, -1e-9, 1.0 / 3.0) },
    ];
    write_attack(&path, &recs).unwrap();
    assert_eq!(read_attack(&path).unwrap(), recs);
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(text, "t,label,d_x,d_y,d_z\n0.1,0,0.0,0.0,0.0\n0.2,1,3.0,-1e-9,0.3333333333333333\n");
}
