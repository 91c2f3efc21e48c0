//! Model I IMU predict throughput per CPU second, for a machine shared with other jobs.
//!
//! Criterion measures wall time, which a loaded machine inflates. This runs a fixed number of
//! sparse Model I predictions and prints the count and wall time; run it under
//! `/usr/bin/time -f "%U s user"` and divide the count by the user CPU time:
//!
//! `cargo bench -p ekf-residue --bench predict_cpu --no-run` then
//! `/usr/bin/time -f "%U s user, %e s wall" target/release/deps/predict_cpu-* 2000000`.

use ekf_residue::model1_filter::{ImuNoise, Model1Filter};
use ekf_residue::{CovarianceUpdate, DivergenceGuard};
use nalgebra::{SMatrix, Vector3};
use std::hint::black_box;
use std::time::Instant;
use uav_dynamics::model1::{self, ImuInput};

fn main() {
    let n: u64 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(2_000_000);
    let x0 = model1::state(
        &Vector3::new(1.0, 2.0, 10.0),
        &Vector3::new(0.05, -0.03, 0.7),
        &Vector3::new(2.0, -1.0, 0.1),
        &Vector3::zeros(),
        &Vector3::zeros(),
    );
    let u = ImuInput { omega_m: Vector3::new(0.01, -0.02, 0.1), a_m: Vector3::new(0.1, 0.05, 9.81) };
    let p0 = SMatrix::<f64, 15, 15>::identity() * 0.1;
    let Ok(mut f) =
        Model1Filter::new(x0, p0, 0.0, ImuNoise::default(), CovarianceUpdate::Joseph, DivergenceGuard::default())
    else {
        return;
    };
    // Pure prediction grows P without bound (no measurements), so restart from P₀ every 1000
    // steps (5 s of flight) to keep measuring the normal path rather than the divergence error.
    let fresh = f.clone();
    let start = Instant::now();
    let mut n_ok = 0u64;
    for k in 0..n {
        if k % 1000 == 0 {
            f = fresh.clone();
        }
        if f.predict(black_box(&u), black_box(0.005)).is_ok() {
            n_ok += 1;
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let mut g = fresh.clone();
    for k in 1..=5000 {
        if g.predict(&u, 0.005).is_err() {
            println!("pure prediction from P0 = 0.1 I stops at step {k} (trace bound)");
            break;
        }
        if k % 1000 == 0 {
            println!("trace(P) after {k} pure predictions: {:.3e}", g.ekf().p().trace());
        }
    }
    println!("{n_ok} Model I predict steps in {wall:.3} s wall ({:.0} steps/s wall)", n_ok as f64 / wall);
}
