//! Saved fitted states of the detectors: the statistical detectors ([`crate::Chi2`],
//! [`crate::Cusum`], [`crate::Sprt`], [`crate::Bht`], [`crate::Px4Gate`], [`crate::Glr`]) and the SVM
//! ([`crate::Svm`]) as JSON of their fitted parameters (docs/decisions/110-method-registry.md);
//! the CNN and LSTM as safetensors weights plus a JSON manifest ([`crate::nn`]).
//!
//! Loading checks every field a detector indexes with (channel count against vector lengths,
//! finite parameters), so a hand-edited state is an error, never a panic; a loaded detector
//! scores exactly what the fitted one scored (`f64` round-trips through JSON exactly).

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::error::{BaselineError, Result};

/// A fitted detector whose state is its (serde) fields.
pub trait JsonState: Serialize + DeserializeOwned {
    /// Checks the consistency of the fields (lengths, ranges) after parsing.
    ///
    /// # Errors
    /// [`BaselineError::State`] naming the field.
    fn check_state(&self) -> Result<()>;

    /// The state as pretty JSON, after [`JsonState::check_state`] (so a state that would not
    /// load, e.g. a non-finite threshold written as `null`, is never written).
    ///
    /// # Errors
    /// [`BaselineError::State`] naming the inconsistent field, or if serialising fails.
    fn to_json(&self) -> Result<String> {
        self.check_state()?;
        serde_json::to_string_pretty(self).map_err(|e| state_err(format!("cannot serialise: {e}")))
    }

    /// Parses and checks a state written by [`JsonState::to_json`].
    ///
    /// # Errors
    /// [`BaselineError::State`] with line and column for malformed JSON or naming the
    /// inconsistent field.
    fn from_json(text: &str) -> Result<Self> {
        let s: Self =
            serde_json::from_str(text).map_err(|e| state_err(nn_toolkit::saved::malformed_json("state", &e)))?;
        s.check_state()?;
        Ok(s)
    }
}

/// A [`BaselineError::State`].
pub(crate) fn state_err(msg: String) -> BaselineError {
    BaselineError::State { msg }
}

/// Checks that `channels` is non-empty and has no empty or repeated name.
pub(crate) fn check_channels(channels: &[String]) -> Result<()> {
    if channels.is_empty() {
        return Err(state_err("channels: empty".into()));
    }
    if channels.len() > nn_toolkit::window::MAX_CHANNELS {
        return Err(state_err(format!(
            "channels: {} exceed the budget of {}",
            channels.len(),
            nn_toolkit::window::MAX_CHANNELS
        )));
    }
    for (i, c) in channels.iter().enumerate() {
        if c.is_empty() || channels[..i].contains(c) {
            return Err(state_err(format!("channels[{i}]: `{c}` is empty or repeated")));
        }
    }
    Ok(())
}

/// Checks that `idx` is a non-empty, strictly increasing list of indices into `n_channels`
/// channels (the GPS channels a gate or drift test reads).
pub(crate) fn check_channel_indices(field: &str, idx: &[usize], n_channels: usize) -> Result<()> {
    if idx.is_empty() {
        return Err(state_err(format!("{field}: empty")));
    }
    if let Some(i) = idx.iter().position(|&k| k >= n_channels) {
        return Err(state_err(format!("{field}[{i}]: {} is not a channel index", idx[i])));
    }
    if let Some(i) = idx.windows(2).position(|w| w[0] >= w[1]) {
        return Err(state_err(format!("{field}[{}]: {} does not follow {}", i + 1, idx[i + 1], idx[i])));
    }
    Ok(())
}

/// Checks that every value is finite.
pub(crate) fn check_finite(field: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(state_err(format!("{field}[{i}]: {} is not finite", values[i]))),
        None => Ok(()),
    }
}

/// Checks that `values` has `want` entries.
pub(crate) fn check_len(field: &str, values: usize, want: usize) -> Result<()> {
    if values == want { Ok(()) } else { Err(state_err(format!("{field}: {values} entries, expected {want}"))) }
}
