//! Evaluation for QUADFormer-rs: the top library layer.
//!
//! This crate owns dataset building (simulate → attack → EKF → labelled residues, split by
//! flight), metrics, the experiment matrix, tables, plots and the `quadformer` command-line
//! interface. It may use every crate below it.
#![warn(missing_docs)]

pub mod cell;
pub mod cli;
pub mod closed_loop;
pub mod dataset;
pub mod io;
pub mod methods;
pub mod model_dir;
/// The detection metrics (`detection-metrics`), under the name the experiment code uses.
pub use detection_metrics as metrics;
pub mod plot;
pub mod progress;
pub mod reproduce;
pub mod runner;
pub mod runtime;
pub mod scenarios;
pub mod table;
