//! Errors of the `baselines` crate: invalid hyper-parameters, unusable data, back-end failures.

use ekf_residue::{DetectError, ResidueError};

/// Why a baseline detector could not be configured, fitted or run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BaselineError {
    /// A hyper-parameter is out of its valid range.
    #[error("invalid config field `{field}`: {msg}")]
    Config {
        /// The offending field.
        field: &'static str,
        /// Why it is invalid.
        msg: String,
    },
    /// Scoring or threshold selection failed (channel mismatch, no labels, NaN, ...).
    #[error(transparent)]
    Detect(#[from] DetectError),
    /// The SVM solver (smartcore) failed.
    #[error("svm training failed: {msg}")]
    Svm {
        /// The solver's message.
        msg: String,
    },
    /// Windowing or training of the shared toolkit (`nn-toolkit`) failed.
    #[error(transparent)]
    Nn(#[from] nn_toolkit::NnError),
    /// A saved fitted state is malformed or inconsistent.
    #[error("saved state: {msg}")]
    State {
        /// What is wrong, naming the field.
        msg: String,
    },
    /// The neural-network back end (candle) failed.
    #[error("candle failed in {context}: {msg}")]
    Candle {
        /// What was being done.
        context: &'static str,
        /// candle's message.
        msg: String,
    },
}

impl From<detection_metrics::MetricsError> for BaselineError {
    /// The threshold search of a fit failed (`DetectError`'s reading of it).
    fn from(e: detection_metrics::MetricsError) -> Self {
        Self::Detect(DetectError::from(e))
    }
}

impl From<ResidueError> for BaselineError {
    fn from(e: ResidueError) -> Self {
        Self::Detect(DetectError::Residue(e))
    }
}

/// Result with [`BaselineError`] as the default error.
pub type Result<T, E = BaselineError> = std::result::Result<T, E>;

/// The `Dim` error of a streamed step whose dimension does not match the fitted channels.
pub(crate) fn step_dim_error(expected: usize, got: usize) -> DetectError {
    DetectError::Residue(ResidueError::Dim { what: "r_k of an online step", expected, got })
}
