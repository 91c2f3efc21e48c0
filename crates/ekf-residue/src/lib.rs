//! Residue generation for QUADFormer-rs: the EKF layer (paper sec:residue_generator, alg:alg1).
//!
//! This crate owns a generic extended Kalman filter over nalgebra, the Model I (15 states) and
//! Model II (21 states, stochastic keyframe cloning) filters built on `uav-dynamics`, time
//! alignment of multi-rate sensor streams and the geodetic → local ENU transform, the
//! [`ResidueSeries`] type (`t`, channels, `r_k`, `S_k`, NIS), and the [`Detector`]/[`Fit`]
//! traits that every residue consumer implements. It knows nothing about attacks or learning.
//!
//! Modules:
//! - [`ekf`]: generic static-size EKF ([`Ekf`]), eq:ekf_predict / eq:ekf_update with a Joseph
//!   or standard covariance update ([`CovarianceUpdate`]), Cholesky factorisation of `S_k`,
//!   divergence checks ([`DivergenceGuard`]); every numerical failure is a [`FilterError`].
//! - [`model1_filter`]: Model I, 15 states, sparse IMU prediction, pose / GPS / attitude updates.
//! - [`model2_filter`]: Model II, 21 states, stochastic keyframe cloning, VO, GPS and stacked
//!   VO + GPS updates.
//! - [`align`]: alg:alg1 TimeStampAlignment (validation, time ordering, measurement groups).
//! - [`geodetic`]: alg:alg1 CoordinateTransformation, WGS-84 geodetic → ECEF → local ENU.
//! - [`chi2`]: the χ² distribution of NIS (CDF, quantile) for gates and thresholds.
//! - [`drift`]: GLR evidence of a constant or growing offset in a whitened innovation sequence
//!   ([`drift::DriftMemory`]), for drift tests and drift-aware detectors.
//! - [`absorbed`]: sums of a whitened innovation sequence over long horizons
//!   ([`absorbed::AbsorbedSums`]), which remember an offset the filter has absorbed.
//! - [`residues`]: alg:alg1 as one call, [`generate_residues`], and the step-by-step
//!   [`Estimator`] (GPS fusion can be skipped and re-admitted) for the online layers.
//!
//! ```
//! use detection_metrics::Confusion;
//! use ekf_residue::ResidueSeries;
//! use nalgebra::DMatrix;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let series = ResidueSeries::new(
//!     vec![0.0, 0.1],
//!     vec!["gps_x".into()],
//!     vec![vec![0.5], vec![3.0]],
//!     vec![DMatrix::from_element(1, 1, 0.25); 2],
//! )?;
//! assert_eq!(series.nis(), &[1.0, 36.0]);
//! let alarms: Vec<bool> = series.nis().iter().map(|z| *z > 6.635).collect();
//! assert_eq!(Confusion::count(&alarms, &[false, true]).f1(), 1.0);
//! # Ok(())
//! # }
//! ```
//!
//! Residues of a simulated flight (Model I, noise model matched to the simulator):
//!
//! ```
//! use ekf_residue::{FilterConfig, ModelKind, generate_residues};
//! use uav_dynamics::sim::{SimConfig, simulate};
//! use uav_dynamics::trajectory::{ShapeConfig, square};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let sim = SimConfig::default();
//! let flight = simulate(&sim, &square(&ShapeConfig::default())?, 5.0, 7)?;
//! let out = generate_residues(&flight.streams, &FilterConfig::for_sim(ModelKind::ModelI, &sim))?;
//! assert_eq!(out.series.channels()[0], "gps_x");
//! assert_eq!(out.series.len(), out.estimates.len());
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod absorbed;
pub mod align;
pub mod chi2;
pub mod detector;
pub mod drift;
pub mod ekf;
pub mod error;
pub mod geodetic;
pub mod model1_filter;
pub mod model2_filter;
pub mod noise_check;
pub mod residues;
pub mod series;

pub use detector::{
    Confirmed, Detector, Fit, OnlineDecision, OnlineDetector, Rethresholded, TrailingMean, WindowedOnline,
    check_channels,
};
pub use ekf::{CovarianceUpdate, DivergenceGuard, DynInnovation, Ekf, Innovation};
pub use error::{DetectError, FilterError, ResidueError};
pub use model1_filter::{ImuNoise, Model1Filter};
pub use model2_filter::Model2Filter;
pub use residues::{
    Estimator, FilterConfig, GpsFusion, InitConfig, MeasurementNoise, Measurements, ModelKind, ResidueOutput,
    StateEstimate, UpdateOutcome, generate_residues,
};
pub use series::{LabelledResidues, LabelledSeries, ResidueSeries, ResidueStep, checked_step_nis};
