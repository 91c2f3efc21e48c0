//! False-data-injection attacks on GPS streams (paper eq:fdi, `y_k = g(x_k) + v_k + d_k`), with
//! per-step ground-truth labels.
//!
//! This crate sits above `uav-dynamics` and below the learning crates: it knows sensor sample
//! types but nothing about filters' internals or learning. It owns the attack models of the
//! paper, Attack I (sparse bursts) and Attack II (persistent bias or ramp), plus replay, freeze
//! and random-noise injection; a seeded planner that hits a target attacked fraction (about 12%
//! by default); batch injection with labels; and a per-sample [`AttackPlan::apply`] for
//! closed-loop use. Offsets are in the local ENU frame in metres, times in seconds.
//!
//! ```
//! use attack_inject::{inject, AttackConfig, AttackKind, AttackPlan};
//! use nalgebra::Vector3;
//! use uav_dynamics::GpsSample;
//! # fn main() -> Result<(), attack_inject::AttackError> {
//! // A 10 Hz GPS stream of a vehicle hovering at the origin for 120 s.
//! let gps: Vec<GpsSample> =
//!     (0..1200).map(|k| GpsSample { t: f64::from(k) * 0.1, p: Vector3::zeros() }).collect();
//! let cfg = AttackConfig::new(AttackKind::Sparse).check()?;
//! let plan = AttackPlan::sample(&cfg, 0.0, 119.9, 42)?;
//! let attacked = inject(&gps, &plan)?;
//! assert_eq!(attacked.gps.len(), gps.len());
//! assert!((attacked.attacked_fraction() - 0.12).abs() < 0.02);
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod config;
pub mod error;
pub mod inject;
pub mod plan;

pub use config::{AmplitudeConfig, AttackConfig, AttackKind, DirectionMode, DurationsConfig, ValidAttackConfig};
pub use error::{AttackError, Result};
pub use inject::{AttackedGps, check_gps, inject};
pub use plan::{AttackInterval, AttackPlan, AttackShape, AttackedSample};
