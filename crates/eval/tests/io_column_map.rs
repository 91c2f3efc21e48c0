//! Another tool's flight folder: every missing column is named at once, and a column map
//! (`--columns THEIRS=OURS,...` or a TOML file) reads it without renaming a file.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::process::Command;

use eval::io::{ColumnMap, read_flight_dir, read_flight_dir_mapped};

fn foreign_folder() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("imu.csv"), "time,gx,gy,gz,ax,ay,az\n0.0,0,0,0,0,0,9.81\n0.005,0,0,0,0,0,9.81\n")
        .unwrap();
    dir
}

#[test]
fn every_missing_column_is_named_at_once() {
    let dir = foreign_folder();
    let e = read_flight_dir(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains(
            "imu.csv: line 1: missing columns `t`, `gyro_x`, `gyro_y`, `gyro_z`, `accel_x`, `accel_y`, `accel_z`"
        ),
        "{e}"
    );
    assert!(e.contains("--columns THEIRS=OURS"), "{e}");
}

#[test]
fn a_column_map_reads_the_folder_as_it_is() {
    let dir = foreign_folder();
    let map = ColumnMap::parse_pairs("time=t, gx=gyro_x,gy=gyro_y,gz=gyro_z,ax=accel_x,ay=accel_y,az=accel_z").unwrap();
    let f = read_flight_dir_mapped(dir.path(), &map).unwrap();
    assert_eq!(f.streams.imu.len(), 2);
    assert_eq!(f.streams.imu[1].accel[2], 9.81);
    let toml = ColumnMap::parse_toml("[columns]\ntime = \"t\"\ngx = \"gyro_x\"\n").unwrap();
    assert_eq!(toml, ColumnMap::parse_pairs("time=t,gx=gyro_x").unwrap());
    assert!(ColumnMap::parse_pairs("gx").unwrap_err().contains("`gx` is not THEIRS=OURS"));
    assert!(ColumnMap::parse_pairs("gx=a,gx=b").unwrap_err().contains("mapped twice"));
    // Only the named columns are missing once part of the header is mapped.
    let partial = ColumnMap::parse_pairs("time=t,gx=gyro_x").unwrap();
    let e = read_flight_dir_mapped(dir.path(), &partial).unwrap_err().to_string();
    assert!(e.contains("missing columns `gyro_y`, `gyro_z`, `accel_x`"), "{e}");
}

#[test]
fn the_cli_takes_a_column_map_file() {
    let dir = foreign_folder();
    let out_dir = tempfile::tempdir().unwrap();
    let map = out_dir.path().join("map.toml");
    std::fs::write(&map, "time = \"t\"\ngx = \"gyro_x\"\ngy = \"gyro_y\"\ngz = \"gyro_z\"\nax = \"accel_x\"\nay = \"accel_y\"\naz = \"accel_z\"\n")
        .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_quadformer"))
        .args(["residues", "--model", "I", "--in"])
        .arg(dir.path())
        .arg("--columns")
        .arg(&map)
        .arg("--out")
        .arg(out_dir.path().join("r.csv"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    // The IMU now reads; Model I then names the stream the folder lacks.
    assert!(!out.status.success());
    assert!(stderr.contains("gps.csv: missing or empty; Model I needs it"), "{stderr}");
}
