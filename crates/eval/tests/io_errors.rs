//! Bad input files give errors that name the file, the line and the column; failed writes
//! leave nothing behind (docs/data-format.md, "Errors").

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::path::Path;

use eval::io::{
    FlightDir, Overwrite, read_flight_dir, read_gps, read_imu, read_residues, read_vo, write_flight_dir, write_gps,
};
use expect_test::{Expect, expect};
use nalgebra::Vector3;
use uav_dynamics::{GpsSample, ImuSample, SensorStreams};

/// Writes `text` as `name` in a fresh directory, reads it with `read`, and compares the
/// error message (with the directory replaced by `DIR`) to `expect`.
fn check<T: std::fmt::Debug, E: std::fmt::Display>(
    name: &str,
    text: &str,
    read: impl Fn(&Path) -> Result<T, E>,
    expect: Expect,
) {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join(name);
    std::fs::write(&path, text).unwrap();
    let err = read(&path).unwrap_err().to_string();
    expect.assert_eq(&err.replace(&tmp.path().display().to_string(), "DIR"));
}

#[test]
fn missing_column_is_named() {
    check(
        "gps.csv",
        "t,p_x,p_z\n0.0,1.0,2.0\n",
        read_gps,
        expect!["DIR/gps.csv: line 1: missing column `p_y` (header has: t,p_x,p_z)"],
    );
}

#[test]
fn non_numeric_value_names_line_and_column() {
    check(
        "gps.csv",
        "t,p_x,p_y,p_z\n0.0,1.0,2.0,3.0\n0.1,1.0,two,3.0\n",
        read_gps,
        expect!["DIR/gps.csv: line 3, column 3 (`p_y`): not a number: `two`"],
    );
}

#[test]
fn nan_is_rejected() {
    check(
        "imu.csv",
        "t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n0.0,0,0,0,0,0,9.81\n0.005,0,0,NaN,0,0,9.81\n",
        read_imu,
        expect!["DIR/imu.csv: line 3, column 4 (`gyro_z`): value `NaN` is not finite"],
    );
}

#[test]
fn unordered_timestamps_are_rejected() {
    check(
        "gps.csv",
        "t,p_x,p_y,p_z\n0.0,1,2,3\n0.2,1,2,3\n0.1,1,2,3\n",
        read_gps,
        expect!["DIR/gps.csv: line 4, column 1 (`t`): time stamps must increase strictly: 0.1 s is not after 0.2 s"],
    );
}

#[test]
fn wrong_number_of_fields_is_rejected() {
    check(
        "gps.csv",
        "t,p_x,p_y,p_z\n0.0,1,2,3\n0.1,1,2\n",
        read_gps,
        expect!["DIR/gps.csv: line 3: expected 4 fields (as in the header), found 3"],
    );
}

#[test]
fn columns_in_any_order_extra_columns_and_comments_are_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("gps.csv");
    std::fs::write(&path, "# exported from a log\np_z, t, p_y, p_x, hdop\n3, 0.5, 2, 1, 0.9\n").unwrap();
    assert_eq!(read_gps(&path).unwrap(), vec![GpsSample { t: 0.5, p: Vector3::new(1.0, 2.0, 3.0) }]);
    // A spreadsheet export: byte-order mark and CRLF line ends.
    std::fs::write(&path, "\u{feff}t,p_x,p_y,p_z\r\n0.5,1,2,3\r\n").unwrap();
    assert_eq!(read_gps(&path).unwrap(), vec![GpsSample { t: 0.5, p: Vector3::new(1.0, 2.0, 3.0) }]);
}

#[test]
fn decreasing_keyframe_is_rejected() {
    check(
        "vo.csv",
        "t,keyframe,p_rel_x,p_rel_y,p_rel_z,q_rel_roll,q_rel_pitch,q_rel_yaw\n0.0,1,0,0,0,0,0,0\n0.1,0,0,0,0,0,0,0\n",
        read_vo,
        expect!["DIR/vo.csv: line 3, column 2 (`keyframe`): keyframe index must not decrease: 0 after 1"],
    );
}

#[test]
fn empty_file_is_rejected() {
    check("gps.csv", "", read_gps, expect!["DIR/gps.csv: line 1: empty file: no header line"]);
}

#[test]
fn residue_file_errors_name_the_step_line() {
    // S is not positive definite on the second step (line 3).
    check(
        "residues.csv",
        "t,r_a,r_b,s_a_a,s_a_b,s_b_b\n0.0,1,1,1,0,1\n0.1,1,1,1,2,1\n",
        read_residues,
        expect!["DIR/residues.csv: line 3: step 1: S_k is not positive definite"],
    );
    check(
        "residues.csv",
        "t,r_a,r_b,s_a_a,s_b_b\n0.0,1,1,1,1\n",
        read_residues,
        expect!["DIR/residues.csv: line 1: missing column `s_a_b` (header has: t,r_a,r_b,s_a_a,s_b_b)"],
    );
    check(
        "residues.csv",
        "t,r_a,s_a_a,nis\n0.0,2,4,1\n0.1,2,4,2\n",
        read_residues,
        expect!["DIR/residues.csv: line 3, column 4 (`nis`): nis 2.0 disagrees with r and S, which give 1.0"],
    );
    check(
        "residues.csv",
        "t,s_a_a\n0.0,1\n",
        read_residues,
        expect!["DIR/residues.csv: line 1: missing column `r_<channel> (at least one)` (header has: t,s_a_a)"],
    );
    check(
        "residues.csv",
        "t,r_a,s_a_a,label\n0.0,1,1,yes\n",
        read_residues,
        expect!["DIR/residues.csv: line 2, column 4 (`label`): label must be 0 or 1, found `yes`"],
    );
}

#[test]
fn lower_triangle_stands_in_for_upper() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("residues.csv");
    std::fs::write(&path, "t,r_a,r_b,s_a_a,s_b_a,s_b_b\n0.0,1,0,4,1,9\n").unwrap();
    let series = read_residues(&path).unwrap();
    assert_eq!(series.series().s(), &[4.0, 1.0, 1.0, 9.0]);
    assert_eq!(series.labels(), None);
}

#[test]
fn attack_file_must_match_gps_fixes() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("imu.csv"), "t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n0,0,0,0,0,0,9.81\n").unwrap();
    std::fs::write(dir.join("gps.csv"), "t,p_x,p_y,p_z\n0.0,0,0,0\n0.1,0,0,0\n").unwrap();
    std::fs::write(dir.join("attack.csv"), "t,label,d_x,d_y,d_z\n0.0,0,0,0,0\n0.2,1,1,0,0\n").unwrap();
    let err = read_flight_dir(dir).unwrap_err().to_string().replace(&dir.display().to_string(), "DIR");
    expect!["DIR/attack.csv: line 3: time 0.2 s does not match gps.csv line 3 time 0.1 s"].assert_eq(&err);
    std::fs::remove_file(dir.join("imu.csv")).unwrap();
    let err = read_flight_dir(dir).unwrap_err().to_string().replace(&dir.display().to_string(), "DIR");
    expect!["DIR/imu.csv: missing file (every flight directory needs its IMU stream)"].assert_eq(&err);
}

#[test]
fn failed_writes_leave_nothing_behind() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("gps.csv");
    let gps =
        vec![GpsSample { t: 0.0, p: Vector3::zeros() }, GpsSample { t: 0.1, p: Vector3::new(0.0, f64::NAN, 0.0) }];
    let err = write_gps(&path, &gps).unwrap_err().to_string().replace(&tmp.path().display().to_string(), "DIR");
    expect!["DIR/gps.csv: cannot write row 1, field `p_y`: non-finite value NaN"].assert_eq(&err);
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0, "no file and no temporary left");

    // A flight directory whose last file fails is not created at all.
    let imu = vec![ImuSample { t: 0.0, gyro: Vector3::zeros(), accel: Vector3::zeros() }];
    let flight = FlightDir { streams: SensorStreams { imu, gps, ..SensorStreams::default() }, ..FlightDir::default() };
    let dir = tmp.path().join("flight");
    assert!(write_flight_dir(&dir, &flight, Overwrite::Refuse).is_err());
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0, "no directory and no temporary left");
}

#[test]
fn existing_directory_is_refused_or_replaced_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("flight");
    std::fs::create_dir(&dir).unwrap();
    std::fs::write(dir.join("old.txt"), "old").unwrap();
    let imu = vec![ImuSample { t: 0.0, gyro: Vector3::zeros(), accel: Vector3::zeros() }];
    let flight = FlightDir { streams: SensorStreams { imu, ..SensorStreams::default() }, ..FlightDir::default() };
    assert!(write_flight_dir(&dir, &flight, Overwrite::Refuse).is_err());
    assert!(dir.join("old.txt").exists());
    write_flight_dir(&dir, &flight, Overwrite::Replace).unwrap();
    assert!(!dir.join("old.txt").exists());
    assert_eq!(read_flight_dir(&dir).unwrap(), flight);
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 1, "only the flight directory remains");
}

#[test]
fn geodetic_gps_is_converted_to_local_enu_at_the_first_fix() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("gps.csv");
    // HKUST campus; 1e-4° of latitude is about 11.07 m north (meridian radius of curvature
    // 6.3767e6 m at 22.3°), 2 m of height is 2 m up.
    std::fs::write(
        &path,
        "t,lat_deg,lon_deg,h_m\n0.0,22.3364,114.2655,50\n0.1,22.3365,114.2655,50\n0.2,22.3364,114.2655,52\n",
    )
    .unwrap();
    let gps = read_gps(&path).unwrap();
    assert_eq!(gps[0].p, Vector3::zeros());
    assert!(gps[1].p.x.abs() < 1e-6 && (gps[1].p.y - 11.07).abs() < 0.01 && gps[1].p.z.abs() < 1e-4, "{}", gps[1].p);
    assert!((gps[2].p - Vector3::new(0.0, 0.0, 2.0)).norm() < 1e-6, "{}", gps[2].p);
    check(
        "gps.csv",
        "t,lat_deg,lon_deg,h_m\n0.0,22.3,114.2,50\n0.1,91.0,114.2,50\n",
        read_gps,
        expect!["DIR/gps.csv: line 3, column 2 (`lat_deg`): latitude 91 is outside [-90, 90] degrees"],
    );
}
