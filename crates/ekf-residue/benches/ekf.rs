//! Criterion benchmarks of the EKF layer: Model I IMU predict (sparse and dense `F P Fᵀ + Q`,
//! eq:ekf_predict), Model I pose update (eq:ekf_update, Joseph), Model II predict + stacked
//! VO/GPS update, and the whole residue generator over a simulated flight.
//!
//! Run: `cargo bench -p ekf-residue`; figures go to docs/performance.md, section "EKF".

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ekf_residue::model1_filter::{ImuNoise, Model1Filter};
use ekf_residue::{CovarianceUpdate, DivergenceGuard, FilterConfig, Model2Filter, ModelKind, generate_residues};
use nalgebra::{SMatrix, Vector3};
use std::hint::black_box;
use std::time::{Duration, Instant};
use uav_dynamics::model1::{self, ImuInput};
use uav_dynamics::sensors::VoSample;
use uav_dynamics::sim::{SimConfig, simulate};
use uav_dynamics::trajectory::{ShapeConfig, eight};

fn x0() -> model1::State {
    model1::state(
        &Vector3::new(1.0, 2.0, 10.0),
        &Vector3::new(0.05, -0.03, 0.7),
        &Vector3::new(2.0, -1.0, 0.1),
        &Vector3::zeros(),
        &Vector3::zeros(),
    )
}

/// A settled covariance: 0.5 m, 0.02 rad, 0.1 m/s, small biases.
fn p0() -> SMatrix<f64, 15, 15> {
    let d = [0.25, 0.25, 0.25, 4e-4, 4e-4, 4e-4, 0.01, 0.01, 0.01, 1e-6, 1e-6, 1e-6, 1e-3, 1e-3, 1e-3];
    SMatrix::<f64, 15, 15>::from_diagonal(&nalgebra::SVector::<f64, 15>::from_column_slice(&d))
}

const U: ImuInput = ImuInput { omega_m: Vector3::new(0.01, -0.02, 0.1), a_m: Vector3::new(0.1, 0.05, 9.81) };

/// Times `iters` IMU predictions on a clone of `filter`. Pure prediction grows P without bound,
/// so every 1000 steps (5 s) the filter restarts from `filter`; otherwise the divergence guard
/// would fire and the error path would be measured.
fn restarting_predictions<F: Clone>(filter: &F, iters: u64, mut predict: impl FnMut(&mut F)) -> Duration {
    let mut f = filter.clone();
    let start = Instant::now();
    for k in 0..iters {
        if k % 1000 == 0 {
            f = filter.clone();
        }
        predict(&mut f);
    }
    start.elapsed()
}

fn bench_model1(c: &mut Criterion) {
    let mut g = c.benchmark_group("model1");
    g.throughput(Throughput::Elements(1));
    let filter =
        Model1Filter::new(x0(), p0(), 0.0, ImuNoise::default(), CovarianceUpdate::Joseph, DivergenceGuard::default())
            .unwrap_or_else(|e| unreachable!("{e}"));
    g.bench_function("predict_sparse", |b| {
        b.iter_custom(|iters| {
            restarting_predictions(&filter, iters, |f| {
                let _ = black_box(f.predict(black_box(&U), black_box(0.005)));
            })
        })
    });
    g.bench_function("predict_dense", |b| {
        b.iter_custom(|iters| {
            restarting_predictions(&filter, iters, |f| {
                let _ = black_box(f.predict_dense(black_box(&U), black_box(0.005)));
            })
        })
    });
    let r6 = [0.25, 0.25, 0.5625, 3e-4, 3e-4, 1.2e-3];
    g.bench_function("update_pose_joseph", |b| {
        b.iter_batched(
            || filter.clone(),
            |mut f| {
                f.update_pose(
                    black_box(&Vector3::new(1.1, 2.1, 10.0)),
                    black_box(&Vector3::new(0.05, -0.03, 0.71)),
                    &r6,
                )
            },
            criterion::BatchSize::SmallInput,
        )
    });
    g.finish();
}

fn bench_model2(c: &mut Criterion) {
    let mut g = c.benchmark_group("model2");
    g.throughput(Throughput::Elements(1));
    let filter =
        Model2Filter::new(x0(), p0(), 0.0, ImuNoise::default(), CovarianceUpdate::Joseph, DivergenceGuard::default())
            .unwrap_or_else(|e| unreachable!("{e}"));
    g.bench_function("predict_sparse", |b| {
        b.iter_custom(|iters| {
            restarting_predictions(&filter, iters, |f| {
                let _ = black_box(f.predict(black_box(&U), black_box(0.005)));
            })
        })
    });
    let vo = VoSample { t: 0.0, keyframe: 0, p_rel: Vector3::new(0.01, 0.0, 0.0), q_rel: Vector3::zeros() };
    let r9 = [0.01, 0.01, 0.01, 2.5e-3, 2.5e-3, 2.5e-3, 0.25, 0.25, 0.5625];
    g.bench_function("predict20_plus_vo_gps_update", |b| {
        b.iter_batched(
            || filter.clone(),
            |mut f| {
                // One 10 Hz measurement period at 200 Hz: 20 predictions and one stacked update.
                for _ in 0..20 {
                    let _ = f.predict(&U, 0.005);
                }
                f.update_vo_gps(black_box(&vo), black_box(&Vector3::new(1.1, 2.0, 10.0)), &r9)
            },
            criterion::BatchSize::SmallInput,
        )
    });
    g.finish();
}

fn bench_generator(c: &mut Criterion) {
    let sim = SimConfig::default();
    let traj = eight(&ShapeConfig::default()).unwrap_or_else(|e| unreachable!("{e}"));
    let flight = simulate(&sim, &traj, 60.0, 1).unwrap_or_else(|e| unreachable!("{e}"));
    let mut g = c.benchmark_group("generate_residues_60s_flight");
    g.sample_size(20);
    g.throughput(Throughput::Elements(flight.streams.imu.len() as u64));
    for model in [ModelKind::ModelI, ModelKind::ModelII] {
        let cfg = FilterConfig::for_sim(model, &sim);
        g.bench_function(format!("{model:?}"), |b| b.iter(|| generate_residues(black_box(&flight.streams), &cfg)));
    }
    g.finish();
}

criterion_group!(benches, bench_model1, bench_model2, bench_generator);
criterion_main!(benches);
