//! Errors of the `ekf-residue` crate: residue-series validation, filtering and detection.

/// A residue series, label set or step failed validation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ResidueError {
    /// A whole-series length or dimension is wrong.
    #[error("wrong dimension of {what}: expected {expected}, got {got}")]
    Dim {
        /// What was measured.
        what: &'static str,
        /// Expected size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// One step has a wrong dimension.
    #[error("step {step_idx}: wrong dimension of {what}: expected {expected}, got {got}")]
    StepDim {
        /// Index of the step.
        step_idx: usize,
        /// Which field.
        what: &'static str,
        /// Expected size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// A value that must be finite is NaN or infinite.
    #[error("step {step_idx}: non-finite {what}")]
    NonFinite {
        /// Index of the step.
        step_idx: usize,
        /// Which field.
        what: &'static str,
    },
    /// Time stamps are not strictly increasing.
    #[error("step {step_idx}: time {t} s is not after the previous {t_prev} s")]
    Unordered {
        /// Index of the step.
        step_idx: usize,
        /// Previous time stamp.
        t_prev: f64,
        /// This time stamp.
        t: f64,
    },
    /// `S_k` is not symmetric.
    #[error("step {step_idx}: S_k is not symmetric")]
    NotSymmetric {
        /// Index of the step.
        step_idx: usize,
    },
    /// `S_k` is not positive definite.
    #[error("step {step_idx}: S_k is not positive definite")]
    NotPositiveDefinite {
        /// Index of the step.
        step_idx: usize,
    },
    /// A requested channel does not exist.
    #[error("unknown channel `{name}` (available: {available:?})")]
    UnknownChannel {
        /// Requested name.
        name: String,
        /// Channels of the series.
        available: Vec<String>,
    },
    /// Flights of one split have different channels.
    #[error("channel mismatch: expected {expected:?}, got {got:?}")]
    ChannelMismatch {
        /// Channels of the first flight.
        expected: Vec<String>,
        /// Channels of the offending flight.
        got: Vec<String>,
    },
}

/// A detector could not score a series.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DetectError {
    /// The series has other channels than the detector was fitted on.
    #[error("channel mismatch: detector fitted on {expected:?}, series has {got:?}")]
    ChannelMismatch {
        /// Channels seen in `fit`.
        expected: Vec<String>,
        /// Channels of the series.
        got: Vec<String>,
    },
    /// Training data is unusable (empty, no labels where labels are needed, ...).
    #[error("unusable training data: {msg}")]
    Data {
        /// What is missing or wrong.
        msg: String,
    },
    /// A numerical failure (singular matrix, non-finite score, ...).
    #[error("numerical failure in {what}")]
    Numerical {
        /// Where it happened.
        what: String,
    },
    /// An error from a computation back end (e.g. candle), carried as text.
    #[error("backend error: {0}")]
    Backend(String),
    /// Invalid residue input.
    #[error(transparent)]
    Residue(#[from] ResidueError),
}
