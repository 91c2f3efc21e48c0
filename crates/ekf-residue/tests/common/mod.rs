//! Shared helpers for the `ekf-residue` integration tests: simulated flights and χ² quantiles.
#![allow(dead_code, clippy::unwrap_used)]

use uav_dynamics::noise::{NoiseConfig, NoiseShape};
use uav_dynamics::sensors::Flight;
use uav_dynamics::sim::{SimConfig, simulate};
use uav_dynamics::trajectory::{RandomRoute, RandomRouteConfig, ShapeConfig, eight};

/// An eight-shape flight (default shape config) of `duration_s` seconds.
pub fn eight_flight(shape: NoiseShape, duration_s: f64, seed: u64) -> (SimConfig, Flight) {
    let sim = SimConfig { noise: NoiseConfig::with_shape(shape), ..SimConfig::default() };
    let traj = eight(&ShapeConfig::default()).unwrap();
    let flight = simulate(&sim, &traj, duration_s, seed).unwrap();
    (sim, flight)
}

/// A random smooth route flight.
pub fn random_flight(shape: NoiseShape, duration_s: f64, seed: u64) -> (SimConfig, Flight) {
    let sim = SimConfig { noise: NoiseConfig::with_shape(shape), ..SimConfig::default() };
    let route = RandomRoute::new(&RandomRouteConfig { duration_s, ..RandomRouteConfig::default() }, seed).unwrap();
    let flight = simulate(&sim, &route, duration_s, seed ^ 0x5eed).unwrap();
    (sim, flight)
}

/// Standard normal quantile `z_p` for the two values the tests use.
fn z(p: f64) -> f64 {
    if p > 0.5 { 2.575_829_303_549 } else { -2.575_829_303_549 }
}

/// χ²_k quantile by the Wilson–Hilferty approximation (relative error below 1e-3 for k ≥ 30,
/// Johnson, Kotz & Balakrishnan, Continuous Univariate Distributions vol. 1, §18.5); only
/// p = 0.005 and p = 0.995 are supported.
pub fn chi2_quantile(k: f64, p: f64) -> f64 {
    let c = 2.0 / (9.0 * k);
    k * (1.0 - c + z(p) * c.sqrt()).powi(3)
}

/// The 99 % two-sided interval of the mean of `n` independent χ²_m values.
pub fn mean_nis_interval(m: usize, n: usize) -> (f64, f64) {
    let k = (m * n) as f64;
    (chi2_quantile(k, 0.005) / n as f64, chi2_quantile(k, 0.995) / n as f64)
}
