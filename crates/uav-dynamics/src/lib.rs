//! Quadrotor physics for QUADFormer-rs: the bottom layer of the workspace.
//!
//! This crate owns the rotation convention (ZYX Euler, ENU world, FLU body), the continuous
//! dynamics `f` and measurement functions `g` of the paper's Model I and Model II with their
//! analytic Jacobians, the three noise shapes, reference trajectories, and a flight simulator
//! that produces true states and multi-rate sensor streams. It knows nothing about filters,
//! attacks or learning: the EKF (`ekf-residue`) and everything above build on its types.
#![warn(missing_docs)]

pub mod controller;
pub mod error;
pub mod model1;
pub mod model2;
pub mod noise;
pub mod rotation;
pub mod sensors;
pub mod sim;
pub mod trajectory;

pub use error::{Error, Result};
pub use sensors::{AttitudeSample, Flight, GpsSample, ImuSample, SensorStreams, TruthSample, VoSample};
