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

impl From<detection_metrics::MetricsError> for DetectError {
    /// A metric that cannot be computed in a fit: a NaN score is a numerical failure, anything
    /// else unusable data.
    fn from(e: detection_metrics::MetricsError) -> Self {
        match e {
            detection_metrics::MetricsError::NonFinite { .. } => Self::Numerical { what: e.to_string() },
            other => Self::Data { msg: other.to_string() },
        }
    }
}

/// A filter, the time alignment or a coordinate transform failed.
///
/// Input problems name the stream (`"imu"`, `"gps"`, `"attitude"`, `"vo"`), the sample index in
/// that stream and its time; numerical problems name the filter time `t` in seconds.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FilterError {
    /// A sensor sample holds NaN or an infinite value.
    #[error("{stream} sample {idx} (t = {t} s): non-finite {field}")]
    NonFiniteInput {
        /// Stream name.
        stream: &'static str,
        /// Index in the stream.
        idx: usize,
        /// Sample time in seconds (may itself be the non-finite value).
        t: f64,
        /// Which field.
        field: &'static str,
    },
    /// Measurements continue after the IMU log ends: the filter cannot predict to them.
    #[error(
        "{stream} sample {idx} (t = {t} s) and {n_after} more come after the last IMU sample (t = {t_imu} s); \
         the filter cannot predict to them: trim the {stream} log or extend the IMU log"
    )]
    BeyondImu {
        /// Stream name.
        stream: &'static str,
        /// Index of the first sample after the IMU log.
        idx: usize,
        /// Its time, seconds.
        t: f64,
        /// How many later samples of the stream are also beyond it.
        n_after: usize,
        /// Time of the last IMU sample, seconds.
        t_imu: f64,
    },
    /// Time stamps of one stream are not strictly increasing.
    #[error("{stream} sample {idx}: time {t} s is not after the previous {t_prev} s")]
    Unordered {
        /// Stream name.
        stream: &'static str,
        /// Index in the stream.
        idx: usize,
        /// Previous time stamp.
        t_prev: f64,
        /// This time stamp.
        t: f64,
    },
    /// A measurement arrives before the filter's current time (online API).
    #[error("{stream} sample at t = {t} s is before the filter time {t_filter} s")]
    InThePast {
        /// Stream name.
        stream: &'static str,
        /// Sample time.
        t: f64,
        /// Current filter time.
        t_filter: f64,
    },
    /// A vector or matrix has the wrong size.
    #[error("wrong dimension of {what}: expected {expected}, got {got}")]
    Dim {
        /// What was measured.
        what: &'static str,
        /// Expected size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// An innovation covariance (or the initial `P`) is not symmetric positive definite.
    #[error("t = {t} s: {what} is not positive definite")]
    NotPositiveDefinite {
        /// Filter time in seconds.
        t: f64,
        /// Which matrix.
        what: &'static str,
    },
    /// The state or covariance became NaN or infinite.
    #[error("t = {t} s: non-finite {what}")]
    NonFiniteState {
        /// Filter time in seconds.
        t: f64,
        /// Which quantity.
        what: &'static str,
    },
    /// The filter diverged (see `ekf::DivergenceGuard`).
    #[error("t = {t} s: filter diverged: {reason}")]
    Diverged {
        /// Filter time in seconds.
        t: f64,
        /// Which criterion fired, with its values.
        reason: String,
    },
    /// The estimated pitch reached ±90°, where ZYX Euler rates are undefined.
    #[error("t = {t} s: gimbal lock (pitch at ±90°)")]
    GimbalLock {
        /// Filter time in seconds.
        t: f64,
    },
    /// A configuration value is invalid.
    #[error("invalid filter config field `{field}`: {msg}")]
    Config {
        /// Field name.
        field: &'static str,
        /// What is wrong.
        msg: String,
    },
    /// The streams do not hold what the chosen model needs.
    #[error("insufficient data: {msg}")]
    NoData {
        /// What is missing.
        msg: String,
    },
    /// A geodetic coordinate is out of range.
    #[error("invalid geodetic coordinate {what} = {value}")]
    Geodetic {
        /// Which coordinate.
        what: &'static str,
        /// Its value.
        value: f64,
    },
    /// Building the residue series failed.
    #[error(transparent)]
    Residue(#[from] ResidueError),
}
