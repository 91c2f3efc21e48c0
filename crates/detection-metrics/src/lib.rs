//! Detection metrics of QUADFormer-rs (docs/decisions/060-metric-definitions.md): the per-step
//! confusion counts and the F1-maximising threshold search that every detector's `fit` uses
//! ([`mod@confusion`]), and the evaluation of scored flights ([`evaluation`]: ROC and PR curves,
//! detection delays, false alarms per clean minute, mean ± std over seeds) and the offline
//! smoothing of scores whose half-width a detector chooses with its threshold ([`smoothing`]).
//!
//! The bottom layer of the workspace beside `uav-dynamics`: plain slices of scores, alarms,
//! labels and time stamps in, numbers out; it knows nothing of filters, residues or detectors.
//!
//! ```
//! use detection_metrics::{Confusion, best_f1_threshold};
//! let scores = [0.1, 0.9, 0.8, 0.2];
//! let labels = [false, true, true, false];
//! let (threshold, f1) = best_f1_threshold([(&scores[..], &labels[..])])?;
//! assert_eq!(f1, 1.0);
//! let alarms: Vec<bool> = scores.iter().map(|s| *s > threshold).collect();
//! assert_eq!(Confusion::count(&alarms, &labels).f1(), 1.0);
//! # Ok::<(), detection_metrics::MetricsError>(())
//! ```
#![warn(missing_docs)]

pub mod confusion;
pub mod evaluation;
pub mod smoothing;

pub use confusion::{Confusion, best_f1_threshold};
pub use evaluation::*;
pub use smoothing::{Smoothing, best_f1_smoothing, centred_mean};
