//! Errors of the toolkit: configuration, data, the candle back end and numerical failures.

use ekf_residue::{DetectError, ResidueError};

/// Result with [`NnError`] as the default error.
pub type Result<T, E = NnError> = std::result::Result<T, E>;

/// Everything that can go wrong while windowing, initialising or training.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NnError {
    /// A configuration field is out of range.
    #[error("invalid config field `{field}`: {msg}")]
    Config {
        /// The offending field.
        field: &'static str,
        /// Why it is invalid.
        msg: String,
    },
    /// Training or scoring data is unusable.
    #[error("unusable data: {msg}")]
    Data {
        /// What is wrong.
        msg: String,
    },
    /// A tensor operation failed in candle.
    #[error("candle: {0}")]
    Candle(#[from] candle_core::Error),
    /// A non-finite loss or score appeared.
    #[error("numerical failure: {what}")]
    Numerical {
        /// Where (epoch, step, quantity).
        what: String,
    },
    /// Error from the detector layer.
    #[error(transparent)]
    Detect(#[from] DetectError),
    /// Invalid residue input.
    #[error(transparent)]
    Residue(#[from] ResidueError),
}

impl From<NnError> for DetectError {
    fn from(e: NnError) -> Self {
        match e {
            NnError::Detect(d) => d,
            NnError::Residue(r) => DetectError::Residue(r),
            NnError::Data { msg } => DetectError::Data { msg },
            NnError::Numerical { what } => DetectError::Numerical { what },
            other => DetectError::Backend(other.to_string()),
        }
    }
}
