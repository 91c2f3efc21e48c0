//! Throughput of the CSV file formats (docs/data-format.md): writing and reading a one-minute
//! 200 Hz IMU stream (12,001 rows × 7 columns) and a 600-step Model I residue file (6 channels,
//! upper-triangle `S_k`: 29 columns). Run with `cargo bench -p eval --bench io`.

// A bench that cannot write its temp files has nothing to measure: unwrap is the right failure.
#![allow(clippy::unwrap_used)]

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ekf_residue::ResidueSeries;
use eval::io::{CovarianceLayout, read_imu, read_residues, write_imu, write_residues};
use nalgebra::{DMatrix, Vector3};
use uav_dynamics::ImuSample;

fn imu(n: usize) -> Vec<ImuSample> {
    (0..n)
        .map(|k| {
            let t = k as f64 * 0.005;
            ImuSample {
                t,
                gyro: Vector3::new(0.01 * t.sin(), -0.02 * t.cos(), 1e-3 * t),
                accel: Vector3::new(0.3 * t.cos(), 0.1 * t.sin(), 9.81 + 0.05 * (3.0 * t).sin()),
            }
        })
        .collect()
}

fn residues(n: usize) -> ResidueSeries {
    let channels: Vec<String> =
        ["gps_x", "gps_y", "gps_z", "att_roll", "att_pitch", "att_yaw"].iter().map(|s| (*s).to_owned()).collect();
    let t = (1..=n).map(|k| k as f64 * 0.1).collect();
    let r = (0..n).map(|k| (0..6).map(|i| ((k * 7 + i) as f64).sin()).collect()).collect();
    let s = (0..n)
        .map(|k| {
            let l = DMatrix::from_fn(6, 6, |i, j| if i >= j { 0.1 * ((k + i + 2 * j) as f64).cos() } else { 0.0 });
            &l * l.transpose() + DMatrix::identity(6, 6)
        })
        .collect();
    ResidueSeries::new(t, channels, r, s).unwrap()
}

fn bench_io(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let imu_path = dir.path().join("imu.csv");
    let samples = imu(12_001);
    let mut g = c.benchmark_group("imu_csv");
    g.throughput(Throughput::Elements(samples.len() as u64));
    g.bench_function("write_12001_rows", |b| b.iter(|| write_imu(&imu_path, black_box(&samples)).unwrap()));
    g.bench_function("read_12001_rows", |b| b.iter(|| read_imu(black_box(&imu_path)).unwrap()));
    g.finish();

    let res_path = dir.path().join("residues.csv");
    let series = residues(600);
    let labels: Vec<bool> = (0..600).map(|k| k % 8 == 0).collect();
    let mut g = c.benchmark_group("residue_csv");
    g.throughput(Throughput::Elements(series.len() as u64));
    g.bench_function("write_600_steps_6ch", |b| {
        b.iter(|| write_residues(&res_path, black_box(&series), Some(&labels), CovarianceLayout::Upper).unwrap())
    });
    g.bench_function("read_600_steps_6ch", |b| b.iter(|| read_residues(black_box(&res_path)).unwrap()));
    g.finish();
}

criterion_group!(benches, bench_io);
criterion_main!(benches);
