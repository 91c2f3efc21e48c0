//! Errors of the `attack-inject` crate: invalid attack configurations, plans and GPS streams.

/// An attack configuration, plan or GPS stream failed validation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AttackError {
    /// A configuration field is out of its valid range.
    #[error("invalid attack config field `{field}` = {value}: {reason}")]
    InvalidConfig {
        /// Dotted field path, e.g. `durations.sparse_s`.
        field: &'static str,
        /// The offending value (first offending element for ranges).
        value: f64,
        /// What the field must satisfy.
        reason: &'static str,
    },
    /// The planning window `[t_start, t_end]` is empty or not finite.
    #[error("invalid planning window [{t_start}, {t_end}] s")]
    InvalidWindow {
        /// Window start in seconds.
        t_start: f64,
        /// Window end in seconds.
        t_end: f64,
    },
    /// The attack intervals and their minimum gaps do not fit into the planning window.
    #[error("attack intervals need {needed_s:.3} s (with gaps) but only {available_s:.3} s are available")]
    PlanDoesNotFit {
        /// Attacked time plus minimum gaps, in seconds.
        needed_s: f64,
        /// Window length after the warm-up, in seconds.
        available_s: f64,
    },
    /// A hand-written attack interval is malformed (empty, non-finite or overlapping).
    #[error("attack interval {interval_idx}: {reason}")]
    InvalidInterval {
        /// Index of the interval in the plan.
        interval_idx: usize,
        /// What is wrong.
        reason: &'static str,
    },
    /// A GPS sample has a non-finite time or position.
    #[error("gps sample {step_idx}: non-finite {what}")]
    NonFiniteGps {
        /// Index of the sample.
        step_idx: usize,
        /// `"t"` or `"p"`.
        what: &'static str,
    },
    /// GPS time stamps are not strictly increasing.
    #[error("gps sample {step_idx}: time {t} s is not after the previous {t_prev} s")]
    UnorderedGps {
        /// Index of the sample.
        step_idx: usize,
        /// Previous time stamp.
        t_prev: f64,
        /// This time stamp.
        t: f64,
    },
}

/// Result alias of this crate.
pub type Result<T, E = AttackError> = std::result::Result<T, E>;
