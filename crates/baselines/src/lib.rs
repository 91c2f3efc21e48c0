//! Comparison detectors of the paper's Tables I and II as [`ekf_residue::Detector`]s.
#![warn(missing_docs)]
