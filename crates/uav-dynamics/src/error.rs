//! Errors of the `uav-dynamics` crate.

/// Everything that can go wrong in `uav-dynamics`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A configuration value is out of its valid range.
    #[error("invalid config field `{field}`: {msg}")]
    Config {
        /// Name of the offending field.
        field: &'static str,
        /// What is wrong with it.
        msg: String,
    },
    /// A numeric value that must be finite was NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Which quantity.
        what: &'static str,
    },
    /// The reference cannot be flown by a quadrotor at time `t_s` (e.g. free fall or a thrust
    /// direction below the horizon in differential flatness).
    #[error("reference not flyable at t = {t_s} s: {msg}")]
    Flatness {
        /// Time of the offending reference point, seconds.
        t_s: f64,
        /// What is wrong.
        msg: String,
    },
}

/// Result alias with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
