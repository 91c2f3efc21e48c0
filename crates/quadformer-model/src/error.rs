//! Errors of the `quadformer-model` crate: configuration, data, candle back end and checkpoints.

use std::path::PathBuf;

use ekf_residue::{DetectError, ResidueError};

/// Result with [`ModelError`] as the default error.
pub type Result<T, E = ModelError> = std::result::Result<T, E>;

/// Everything that can go wrong while windowing, training, scoring or loading a model.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
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
    /// A checkpoint is missing, truncated, corrupted or does not match its config.
    #[error("checkpoint {path}: {msg}")]
    Checkpoint {
        /// The file that failed.
        path: PathBuf,
        /// What is wrong with it.
        msg: String,
    },
    /// Reading or writing a file failed.
    #[error("i/o on {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A non-finite loss or score appeared.
    #[error("numerical failure: {what}")]
    Numerical {
        /// Where (epoch, step, quantity).
        what: String,
    },
    /// The streaming engine cannot represent a network; the detector streams through the
    /// candle forward pass instead.
    #[error("the streaming engine does not support {what}")]
    StreamingUnsupported {
        /// What it does not support.
        what: String,
    },
    /// Error from the detector layer.
    #[error(transparent)]
    Detect(#[from] DetectError),
    /// Invalid residue input.
    #[error(transparent)]
    Residue(#[from] ResidueError),
}

impl From<nn_toolkit::NnError> for ModelError {
    /// The toolkit's errors keep their kind and message.
    fn from(e: nn_toolkit::NnError) -> Self {
        use nn_toolkit::NnError;
        match e {
            NnError::Config { field, msg } => Self::Config { field, msg },
            NnError::Data { msg } => Self::Data { msg },
            NnError::Candle(c) => Self::Candle(c),
            NnError::Numerical { what } => Self::Numerical { what },
            NnError::Detect(d) => Self::Detect(d),
            NnError::Residue(r) => Self::Residue(r),
            other => Self::Data { msg: other.to_string() },
        }
    }
}

impl From<ModelError> for DetectError {
    fn from(e: ModelError) -> Self {
        match e {
            ModelError::Detect(d) => d,
            ModelError::Residue(r) => DetectError::Residue(r),
            ModelError::Data { msg } => DetectError::Data { msg },
            ModelError::Numerical { what } => DetectError::Numerical { what },
            other => DetectError::Backend(other.to_string()),
        }
    }
}
