//! Attack configuration: plain serde data with documented defaults, checked into
//! [`ValidAttackConfig`] before a plan is sampled.
//!
//! The attack model is the paper's FDI measurement equation eq:fdi, `y_k = g(x_k) + v_k + d_k`,
//! applied to GPS positions in the local ENU frame (metres). Defaults come from the paper
//! (Sec. V-B: sparse and persistent attacks of different durations and amplitudes, about 12% of
//! steps attacked), docs/decisions/030-attack-model-and-planning.md (Attack I bursts of 0.2–3 s,
//! Attack II intervals of 10–40 s, amplitudes about 3 σ to 30 m, sweep 0.5 σ to 10 σ), public
//! GPS-spoofing simulators for the shapes (step/bias, ramp, replay, freeze; `gps_spoofer.py` of
//! TDRobertson/carla-autonomous-vehicle-scripts drifts at 0.1 m/s and replays with a 2 s delay)
//! and PX4's `EKF2_GPS_P_NOISE` for the GPS σ (0.5 m horizontal).

use serde::{Deserialize, Serialize};

use crate::error::{AttackError, Result};

/// Which attack an [`AttackConfig`] plans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AttackKind {
    /// Attack I (paper Sec. "Attack Scenario"): sparse FDI, short bursts of a constant offset
    /// (fractions of a second to a few seconds) at random times.
    Sparse,
    /// Attack II: persistent FDI, long intervals (tens of seconds) of a constant bias or of a
    /// slow ramp (drift spoofing), chosen per interval.
    Persistent,
    /// Replay: re-send the clean GPS fixes recorded `delay` seconds earlier.
    Replay,
    /// Freeze: repeat the last clean fix before the interval for its whole duration.
    Freeze,
    /// Random noise injection: an independent zero-mean Gaussian offset on every sample.
    Noise,
    /// Oscillating FDI: `d(t) = A·sin(2π f (t − t0))`, an offset that swings through zero so a
    /// memoryless gate sees it only near its peaks.
    Oscillating,
}

impl AttackKind {
    /// All kinds, in table order.
    pub const ALL: [Self; 6] =
        [Self::Sparse, Self::Persistent, Self::Replay, Self::Freeze, Self::Noise, Self::Oscillating];

    /// Short stable name used in file names and tables (`"sparse"`, `"persistent"`, …).
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Sparse => "sparse",
            Self::Persistent => "persistent",
            Self::Replay => "replay",
            Self::Freeze => "freeze",
            Self::Noise => "noise",
            Self::Oscillating => "oscillating",
        }
    }
}

/// How attack amplitudes `‖d_k‖` are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum AmplitudeConfig {
    /// Main tables: log-uniform between `min_sigma · σ_gps` and `max_m` metres, one draw per
    /// interval: about 3 GPS σ to 30 m (docs/decisions/030).
    Range {
        /// Lower bound in multiples of the GPS σ. Default 3.
        min_sigma: f64,
        /// Upper bound in metres. Default 30.
        max_m: f64,
    },
    /// Amplitude sweep: every interval has amplitude `sigma_multiple · σ_gps`.
    /// The sweep spans 0.5 σ to 10 σ (docs/decisions/005-sweep-and-ablations.md).
    Fixed {
        /// Amplitude in multiples of the GPS σ.
        sigma_multiple: f64,
    },
}

impl Default for AmplitudeConfig {
    /// `Range { min_sigma: 3, max_m: 30 }` (docs/decisions/030).
    fn default() -> Self {
        Self::Range { min_sigma: 3.0, max_m: 30.0 }
    }
}

/// Direction of the injected offset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DirectionMode {
    /// Uniform on the unit sphere (eq:fdi allows any `d_k ∈ R³`). Default.
    #[default]
    Sphere,
    /// Uniform on the horizontal unit circle (typical GPS spoofing pulls the vehicle sideways).
    Horizontal,
}

/// Interval duration ranges `[min, max]` in seconds, per attack kind.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DurationsConfig {
    /// Attack I burst length. Default `[0.2, 3.0]` s: fractions of a second to a few seconds
    /// (docs/decisions/030).
    pub sparse_s: [f64; 2],
    /// Attack II interval length. Default `[10.0, 40.0]` s: tens of seconds (docs/decisions/030).
    pub persistent_s: [f64; 2],
    /// Replay interval length. Default `[3.0, 15.0]` s (choice between the two FDI scales).
    pub replay_s: [f64; 2],
    /// Freeze interval length. Default `[2.0, 10.0]` s (choice between the two FDI scales).
    pub freeze_s: [f64; 2],
    /// Noise-injection interval length. Default `[1.0, 5.0]` s (choice, burst-like).
    pub noise_s: [f64; 2],
    /// Oscillating-attack interval length. Default `[10.0, 40.0]` s (persistent, as Attack II).
    /// Left out of the serialised form at its default, so configurations written before this
    /// field existed keep their dataset cache keys.
    #[serde(skip_serializing_if = "is_default_oscillating_s")]
    pub oscillating_s: [f64; 2],
}

impl Default for DurationsConfig {
    fn default() -> Self {
        Self {
            sparse_s: [0.2, 3.0],
            persistent_s: [10.0, 40.0],
            replay_s: [3.0, 15.0],
            freeze_s: [2.0, 10.0],
            noise_s: [1.0, 5.0],
            oscillating_s: [10.0, 40.0],
        }
    }
}

impl DurationsConfig {
    /// The duration range of `kind`.
    #[must_use]
    pub const fn of(&self, kind: AttackKind) -> [f64; 2] {
        match kind {
            AttackKind::Sparse => self.sparse_s,
            AttackKind::Persistent => self.persistent_s,
            AttackKind::Replay => self.replay_s,
            AttackKind::Freeze => self.freeze_s,
            AttackKind::Noise => self.noise_s,
            AttackKind::Oscillating => self.oscillating_s,
        }
    }
}

/// Everything that defines how a plan of attacks is drawn for one flight.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AttackConfig {
    /// Which attack.
    pub kind: AttackKind,
    /// Target fraction of GPS steps (= residue steps with a GPS fix) under attack.
    /// Default 0.12 (paper Sec. V-B: "approximately 12% of the time steps are under attack").
    #[serde(default = "default_attacked_fraction")]
    pub attacked_fraction: f64,
    /// GPS position noise standard deviation in metres, the unit of amplitudes.
    /// Default 0.5: PX4 EKF2_GPS_P_NOISE, the horizontal σ of the simulator's default
    /// `uav_dynamics::sim::SimConfig::gps_sigma_m` (docs/sensors.md).
    #[serde(default = "default_gps_sigma_m")]
    pub gps_sigma_m: f64,
    /// Amplitude distribution. Default `Range { min_sigma: 3, max_m: 30 }`.
    #[serde(default)]
    pub amplitude: AmplitudeConfig,
    /// Offset direction. Default `Sphere`.
    #[serde(default)]
    pub direction: DirectionMode,
    /// Duration ranges per kind.
    #[serde(default)]
    pub durations: DurationsConfig,
    /// Probability that an Attack II interval is a ramp (drift) rather than a constant bias.
    /// Default 0.5 (constant bias or slow ramp equally often, docs/decisions/030).
    #[serde(default = "default_ramp_probability")]
    pub ramp_probability: f64,
    /// Ramp slope range `[min, max]` in m/s, drawn log-uniformly per ramp interval; the ramp's
    /// end offset is then `slope · duration` along the drawn direction. `None` (default): the
    /// end offset is drawn from `amplitude` like a bias. Drift spoofing is slow: a PX4 user reports a
    /// ~5 m/s drift (<https://github.com/PX4/PX4-Autopilot/issues/27340>); public spoofing simulators drift at 0.1–1 m/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ramp_slope_mps: Option<[f64; 2]>,
    /// Oscillation frequency range `[min, max]` in Hz of [`AttackKind::Oscillating`], drawn
    /// uniformly per interval. Default `[0.1, 0.3]` around 0.2 Hz.
    #[serde(default = "default_oscillation_hz", skip_serializing_if = "is_default_oscillation_hz")]
    pub oscillation_hz: [f64; 2],
    /// Replay delay range `[min, max]` in seconds. Default `[1.0, 5.0]` around the 2 s of
    /// `gps_spoofer.py` (TDRobertson/carla-autonomous-vehicle-scripts).
    #[serde(default = "default_replay_delay_s")]
    pub replay_delay_s: [f64; 2],
    /// Attack-free time at the start of the window, seconds, so the EKF has converged.
    /// Default 5.0 (choice: the filter settles within a few GPS updates).
    #[serde(default = "default_warmup_s")]
    pub warmup_s: f64,
    /// Minimum clean gap between two attack intervals, seconds. Default 1.0 (choice: so that
    /// intervals stay distinct events for detection-delay metrics).
    #[serde(default = "default_min_gap_s")]
    pub min_gap_s: f64,
}

const fn default_attacked_fraction() -> f64 {
    0.12
}
const fn default_gps_sigma_m() -> f64 {
    0.5
}
const fn default_ramp_probability() -> f64 {
    0.5
}
const fn default_oscillation_hz() -> [f64; 2] {
    [0.1, 0.3]
}
#[allow(clippy::trivially_copy_pass_by_ref, clippy::float_cmp)] // serde's signature; exact defaults.
fn is_default_oscillation_hz(v: &[f64; 2]) -> bool {
    *v == default_oscillation_hz()
}
#[allow(clippy::trivially_copy_pass_by_ref, clippy::float_cmp)] // serde's signature; exact defaults.
fn is_default_oscillating_s(v: &[f64; 2]) -> bool {
    *v == DurationsConfig::default().oscillating_s
}
const fn default_replay_delay_s() -> [f64; 2] {
    [1.0, 5.0]
}
const fn default_warmup_s() -> f64 {
    5.0
}
const fn default_min_gap_s() -> f64 {
    1.0
}

impl AttackConfig {
    /// The configuration of `kind` with every other field at its documented default.
    #[must_use]
    pub fn new(kind: AttackKind) -> Self {
        Self {
            kind,
            attacked_fraction: default_attacked_fraction(),
            gps_sigma_m: default_gps_sigma_m(),
            amplitude: AmplitudeConfig::default(),
            direction: DirectionMode::default(),
            durations: DurationsConfig::default(),
            ramp_probability: default_ramp_probability(),
            ramp_slope_mps: None,
            oscillation_hz: default_oscillation_hz(),
            replay_delay_s: default_replay_delay_s(),
            warmup_s: default_warmup_s(),
            min_gap_s: default_min_gap_s(),
        }
    }

    /// Validate every field.
    ///
    /// # Errors
    /// [`AttackError::InvalidConfig`] naming the first field out of range.
    pub fn check(&self) -> Result<ValidAttackConfig> {
        fn bad(field: &'static str, value: f64, reason: &'static str) -> AttackError {
            AttackError::InvalidConfig { field, value, reason }
        }
        fn range(field: &'static str, r: [f64; 2]) -> Result<()> {
            if !(r[0].is_finite() && r[0] > 0.0) {
                return Err(bad(field, r[0], "lower bound must be finite and > 0"));
            }
            if !(r[1].is_finite() && r[1] >= r[0]) {
                return Err(bad(field, r[1], "upper bound must be finite and >= lower bound"));
            }
            Ok(())
        }
        let f = self.attacked_fraction;
        if !(f.is_finite() && (0.0..1.0).contains(&f)) {
            return Err(bad("attacked_fraction", f, "must be in [0, 1)"));
        }
        if !(self.gps_sigma_m.is_finite() && self.gps_sigma_m > 0.0) {
            return Err(bad("gps_sigma_m", self.gps_sigma_m, "must be finite and > 0"));
        }
        match self.amplitude {
            AmplitudeConfig::Range { min_sigma, max_m } => {
                if !(min_sigma.is_finite() && min_sigma > 0.0) {
                    return Err(bad("amplitude.min_sigma", min_sigma, "must be finite and > 0"));
                }
                if !(max_m.is_finite() && max_m >= min_sigma * self.gps_sigma_m) {
                    return Err(bad("amplitude.max_m", max_m, "must be finite and >= min_sigma * gps_sigma_m"));
                }
            }
            AmplitudeConfig::Fixed { sigma_multiple } => {
                if !(sigma_multiple.is_finite() && sigma_multiple > 0.0) {
                    return Err(bad("amplitude.sigma_multiple", sigma_multiple, "must be finite and > 0"));
                }
            }
        }
        range("durations.sparse_s", self.durations.sparse_s)?;
        range("durations.persistent_s", self.durations.persistent_s)?;
        range("durations.replay_s", self.durations.replay_s)?;
        range("durations.freeze_s", self.durations.freeze_s)?;
        range("durations.noise_s", self.durations.noise_s)?;
        range("durations.oscillating_s", self.durations.oscillating_s)?;
        if let Some(r) = self.ramp_slope_mps {
            range("ramp_slope_mps", r)?;
        }
        range("oscillation_hz", self.oscillation_hz)?;
        range("replay_delay_s", self.replay_delay_s)?;
        let p = self.ramp_probability;
        if !(p.is_finite() && (0.0..=1.0).contains(&p)) {
            return Err(bad("ramp_probability", p, "must be in [0, 1]"));
        }
        if !(self.warmup_s.is_finite() && self.warmup_s >= 0.0) {
            return Err(bad("warmup_s", self.warmup_s, "must be finite and >= 0"));
        }
        if !(self.min_gap_s.is_finite() && self.min_gap_s >= 0.0) {
            return Err(bad("min_gap_s", self.min_gap_s, "must be finite and >= 0"));
        }
        Ok(ValidAttackConfig(self.clone()))
    }
}

/// An [`AttackConfig`] that passed [`AttackConfig::check`]; the only input plans accept.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidAttackConfig(AttackConfig);

impl ValidAttackConfig {
    /// The checked configuration.
    #[must_use]
    pub const fn get(&self) -> &AttackConfig {
        &self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_for_every_kind() {
        for kind in AttackKind::ALL {
            assert!(AttackConfig::new(kind).check().is_ok());
        }
    }

    #[test]
    fn bad_fields_are_named() {
        let check = |edit: fn(&mut AttackConfig), field: &str| {
            let mut cfg = AttackConfig::new(AttackKind::Sparse);
            edit(&mut cfg);
            match cfg.check() {
                Err(AttackError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
                other => panic!("expected InvalidConfig for {field}, got {other:?}"),
            }
        };
        check(|c| c.attacked_fraction = 1.5, "attacked_fraction");
        check(|c| c.attacked_fraction = f64::NAN, "attacked_fraction");
        check(|c| c.gps_sigma_m = 0.0, "gps_sigma_m");
        check(|c| c.amplitude = AmplitudeConfig::Range { min_sigma: 3.0, max_m: 1.0 }, "amplitude.max_m");
        check(|c| c.amplitude = AmplitudeConfig::Fixed { sigma_multiple: -1.0 }, "amplitude.sigma_multiple");
        check(|c| c.durations.sparse_s = [2.0, 1.0], "durations.sparse_s");
        check(|c| c.durations.persistent_s = [0.0, 1.0], "durations.persistent_s");
        check(|c| c.replay_delay_s = [f64::INFINITY, 1.0], "replay_delay_s");
        check(|c| c.ramp_probability = 2.0, "ramp_probability");
        check(|c| c.warmup_s = -1.0, "warmup_s");
        check(|c| c.min_gap_s = f64::NAN, "min_gap_s");
    }

    #[test]
    fn toml_like_round_trip_and_unknown_fields_rejected() {
        let cfg = AttackConfig::new(AttackKind::Persistent);
        let json = serde_json_like(&cfg);
        assert!(json.contains("persistent"));
        let partial: AttackConfig = serde_json::from_str(r#"{"kind":"sparse"}"#).unwrap();
        assert_eq!(partial, AttackConfig::new(AttackKind::Sparse));
        let fixed: AttackConfig =
            serde_json::from_str(r#"{"kind":"noise","amplitude":{"fixed":{"sigma_multiple":2.0}}}"#).unwrap();
        assert_eq!(fixed.amplitude, AmplitudeConfig::Fixed { sigma_multiple: 2.0 });
        assert!(serde_json::from_str::<AttackConfig>(r#"{"kind":"sparse","bogus":1}"#).is_err());
    }

    fn serde_json_like(cfg: &AttackConfig) -> String {
        serde_json::to_string(cfg).unwrap()
    }
}
