//! Resilient state estimation (paper sec:state_estimation, alg:alg3) and the paper's
//! closed-loop flight scenarios.
//!
//! This layer sits above `ekf-residue` and `attack-inject`: it drives the Model II EKF step by
//! step, asks any [`OnlineDetector`](ekf_residue::detector::OnlineDetector) about every GPS
//! innovation, excludes GPS while the detector alarms and re-admits it after a clean hold time
//! ([`estimator`]). [`scenario`] flies the eight, UST, formation, diagonal and square scenarios
//! in closed loop (the controller flies on the estimate, so spoofing moves the vehicle), with and
//! without attack and detection, and returns metrics and trajectories. It knows nothing about
//! learning (candle is not reachable) or tables; the CLI and plots live in `eval`.
//!
//! ```
//! use resilient_fusion::estimator::NisGate;
//! use resilient_fusion::scenario::{Case, Scenario, ScenarioConfig, run_case};
//! # fn main() -> Result<(), resilient_fusion::FusionError> {
//! let mut cfg = ScenarioConfig::default();
//! cfg.resilient.latency_s = 0.0;
//! let gate = |_vehicle: usize| -> resilient_fusion::Result<Box<dyn ekf_residue::detector::OnlineDetector>> {
//!     Ok(Box::new(NisGate::new(NisGate::CHI2_3_999)?))
//! };
//! let res = run_case(Scenario::Diagonal, Case::AttackDetected, &cfg, Some(&gate))?;
//! let m = res.attacked().map(|v| v.metrics);
//! assert!(m.is_some_and(|m| m.time_gps_excluded_s > 0.0));
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod error;
pub mod estimator;
pub mod gates;
pub mod innovation_trend;
pub mod onset;
pub mod recorded;
pub mod scenario;

pub use error::{FusionError, Result};
