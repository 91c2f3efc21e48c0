//! Comparison detectors of the paper's Tables I and II as [`ekf_residue::Detector`]s, plus the
//! innovation gate a PX4 user already has.
//!
//! This crate sits between `quadformer-model` and `resilient-fusion`: it reads residue series
//! (`ekf-residue`) and shares windowing and training with `quadformer-model`; it knows nothing
//! about evaluation. Statistical detectors work per step on `r_k`, `S_k` and the NIS and have
//! true recursive [`ekf_residue::OnlineDetector`]s: [`Chi2`], [`Cusum`], [`Sprt`], [`Bht`],
//! [`Px4Gate`], and the drift test [`Glr`]. Learning detectors classify residue windows: [`Svm`] (RBF kernel, smartcore), [`Cnn`] and
//! [`Lstm`] (candle, sharing windowing and training with `quadformer-model`).
//! Every hyper-parameter struct implements [`ekf_residue::Fit`]; thresholds are chosen on the
//! validation split ([`Tuning::ValidationF1`]) or set to the textbook value
//! ([`Tuning::Textbook`]). Equations and sources: `docs/baselines.md`.
//!
//! ```
//! use baselines::{CusumConfig, Tuning, synthetic::{SyntheticAttack, SyntheticFlight}};
//! use ekf_residue::{Detector, Fit, LabelledResidues};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let attack = SyntheticAttack { start_s: 20.0, end_s: 25.0, bias_m: [20.0, 0.0, 0.0], absorb_tau_s: None };
//! let flight = SyntheticFlight::new(600, 1).generate(&[attack])?;
//! let split = LabelledResidues::new(vec![flight.clone()])?;
//! let cusum = CusumConfig { tuning: Tuning::Textbook, ..CusumConfig::default() }.fit(&split, &split)?;
//! let alarms = cusum.detect(flight.series())?;
//! assert!(alarms[200..250].iter().all(|&a| a));
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod bht;
pub mod chi2;
pub mod common;
pub mod cusum;
pub mod error;
pub mod features;
pub mod glr;
pub mod lstm;
pub mod lstm_online;
pub mod nn;
pub mod px4_gate;
pub mod sprt;
pub mod state;
pub mod stats;
pub mod svm;
pub mod synthetic;

pub use bht::{Bht, BhtConfig};
pub use chi2::{Chi2, Chi2Config};
pub use common::Tuning;
pub use cusum::{Cusum, CusumConfig};
pub use error::{BaselineError, Result};
pub use glr::{Glr, GlrConfig};
pub use nn::{Cnn, CnnConfig, Lstm, LstmConfig, NeuralConfig};
pub use px4_gate::{Px4Gate, Px4GateConfig};
pub use sprt::{Sprt, SprtConfig};
pub use state::JsonState;
pub use svm::{Svm, SvmConfig};
