//! Errors of the `resilient-fusion` crate.

use attack_inject::AttackError;
use ekf_residue::error::{DetectError, FilterError};

/// Everything that can go wrong in resilient fusion and the closed-loop scenarios.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FusionError {
    /// The simulator or controller failed (bad config, unflyable state).
    #[error("simulator: {0}")]
    Sim(#[from] uav_dynamics::Error),
    /// The EKF failed (divergence, bad input, bad config).
    #[error("filter: {0}")]
    Filter(#[from] FilterError),
    /// The detector failed on the residue step at time `t`.
    #[error("detector at t = {t} s: {source}")]
    Detect {
        /// Time of the residue step in seconds.
        t: f64,
        /// The detector's error.
        source: DetectError,
    },
    /// The attack plan is invalid.
    #[error("attack: {0}")]
    Attack(#[from] AttackError),
    /// A configuration value is out of range.
    #[error("invalid config field `{field}`: {msg}")]
    Config {
        /// Name of the offending field.
        field: &'static str,
        /// What is wrong with it.
        msg: String,
    },
    /// A channel the detector needs is missing from the filter's innovation.
    #[error("detector channel `{channel}` not in the innovation at t = {t} s (channels {available:?})")]
    MissingChannel {
        /// The missing channel name.
        channel: String,
        /// Time of the innovation in seconds.
        t: f64,
        /// Channels the innovation has.
        available: Vec<String>,
    },
}

/// Result alias with this crate's [`FusionError`].
pub type Result<T, E = FusionError> = std::result::Result<T, E>;
