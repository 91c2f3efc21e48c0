//! NIS consistency of both models on clean Gaussian flights (Bar-Shalom, Li & Kirubarajan 2001,
//! §5.4: the mean NIS over n steps times n is χ² with m·n degrees of freedom), and a hand-made
//! 10 m GPS bias that clearly leaves the interval.
// Test helpers outside #[test] functions unwrap too (clippy allows it only inside tests).
#![allow(clippy::unwrap_used)]

mod common;

use ekf_residue::{FilterConfig, ModelKind, generate_residues};
use nalgebra::Vector3;
use uav_dynamics::noise::NoiseShape;

/// Residue steps after the first 5 s are scored (the filter starts with `σ_v0` = 12 m/s, so the
/// first fixes mainly learn the velocity).
const WARMUP_S: f64 = 5.0;

fn mean_nis_after(out: &ekf_residue::ResidueOutput, t0: f64, t1: f64) -> (f64, usize) {
    let sel: Vec<f64> =
        out.series.t().iter().zip(out.series.nis()).filter(|(t, _)| **t >= t0 && **t < t1).map(|(_, z)| *z).collect();
    (sel.iter().sum::<f64>() / sel.len() as f64, sel.len())
}

fn check_model(model: ModelKind, seed: u64) {
    let (sim, flight) = common::eight_flight(NoiseShape::Gaussian, 65.0, seed);
    let cfg = FilterConfig::for_sim(model, &sim);
    let out = generate_residues(&flight.streams, &cfg).unwrap();
    let m = out.series.dim();
    let (mean, n) = mean_nis_after(&out, WARMUP_S, f64::INFINITY);
    let (lo, hi) = common::mean_nis_interval(m, n);
    eprintln!("{model:?}: mean NIS {mean:.3} over {n} steps, dim {m}, 99% interval [{lo:.3}, {hi:.3}]");
    assert!(
        mean > lo && mean < hi,
        "{model:?}: mean NIS {mean:.3} over {n} steps of dim {m} outside [{lo:.3}, {hi:.3}]"
    );

    // A 10 m east bias on every GPS fix from t = 30 s on.
    let mut attacked = flight.streams.clone();
    for g in attacked.gps.iter_mut().filter(|g| g.t >= 30.0) {
        g.p += Vector3::new(10.0, 0.0, 0.0);
    }
    let out = generate_residues(&attacked, &cfg).unwrap();
    // The first 2 s of the attack: before the filter has absorbed part of the bias.
    let (mean_att, n_att) = mean_nis_after(&out, 30.0, 32.0);
    let (_, hi_att) = common::mean_nis_interval(m, n_att);
    eprintln!("{model:?}: attacked mean NIS {mean_att:.1} over {n_att} steps");
    assert!(mean_att > 10.0 * hi_att, "{model:?}: attacked mean NIS {mean_att:.1} not clearly above {hi_att:.2}");
}

#[test]
fn model1_mean_nis_is_chi2_consistent_and_a_10m_bias_leaves_it() {
    check_model(ModelKind::ModelI, 11);
}

#[test]
fn model2_mean_nis_is_chi2_consistent_and_a_10m_bias_leaves_it() {
    check_model(ModelKind::ModelII, 12);
}
