//! Quadrotor physics for QUADFormer-rs: the bottom layer of the workspace.
//!
//! This crate owns the rotation convention (ZYX Euler, ENU world, FLU body), the continuous
//! dynamics `f` and measurement functions `g` of the paper's Model I and Model II with their
//! analytic Jacobians, the three noise shapes, reference trajectories, and a flight simulator
//! that produces true states and multi-rate sensor streams. It knows nothing about filters,
//! attacks or learning: the EKF (`ekf-residue`) and everything above build on its types.
//!
//! ```
//! use nalgebra::Vector3;
//! use uav_dynamics::rotation::{euler_from_matrix, rotation_matrix};
//! // Roll 10°, pitch −5°, yaw 90°: R(q) = Rz(ψ)·Ry(θ)·Rx(φ) maps body (FLU) to world (ENU).
//! let q = Vector3::new(10f64.to_radians(), (-5f64).to_radians(), 90f64.to_radians());
//! let r = rotation_matrix(&q);
//! // Yawed by 90°, the body x axis (forward) points roughly north (world y).
//! assert!((r * Vector3::x() - Vector3::new(0.0, 0.996, 0.087)).norm() < 1e-3);
//! assert!((euler_from_matrix(&r) - q).norm() < 1e-12);
//! ```
#![warn(missing_docs)]

pub mod controller;
pub mod error;
pub mod frames;
pub mod model1;
pub mod model2;
pub mod noise;
pub mod rotation;
pub mod sensors;
pub mod sim;
pub mod trajectory;

pub use error::{Error, Result};
pub use sensors::{AttitudeSample, Flight, GpsSample, ImuSample, SensorStreams, TruthSample, VoSample};
