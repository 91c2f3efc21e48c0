//! PX4-style GNSS innovation gate (PX4 EKF2: `EKF/ekf.h` `updateAidSourceStatus`,
//! `aid_sources/gnss/gps_control.cpp` `controlGnssPosFusion`, in PX4/PX4-Autopilot
//! `src/modules/ekf2`): the detector a PX4 user already has.
//!
//! Per GPS axis `i` of step `k`, with the innovation `ν_i` and its variance `(S_k)_ii`:
//!
//! ```text
//! test_ratio_i = ν_i² / (γ² · (S_k)_ii)        γ = EKF2_GPS_P_GATE = 5 (PX4 default)
//! rejected_k   = max_i test_ratio_i > 1         (the step's score is that maximum, threshold 1)
//! ```
//!
//! A rejected sample is not fused. When nothing has been fused for `reset_timeout_max = 7 s`
//! (hard-coded in `EKF/common.h`) PX4 resets the position to GNSS, i.e. it accepts the spoofed
//! position. On recorded residues the reset is modelled by an offset: at the reset the current
//! innovation `r_k` is stored as `o`, and later steps are gated on `ν = r_k − o` (the estimate now
//! sits on the spoofed position). So a persistent spoof alarms for 7 s and then goes silent, and
//! when it ends the honest GPS is rejected for another 7 s until the next reset: the known
//! weakness of the gate to persistent spoofing, shown on purpose.
//!
//! Only the GPS channels (names starting with `gps_channel_prefix`) are gated; the others are
//! ignored. Textbook setting: `γ = 5`. Validation setting: `γ` from a grid maximising F1 (the
//! 7 s timeout stays PX4's).

use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, OnlineDecision, OnlineDetector, ResidueSeries, ResidueStep,
};
use serde::{Deserialize, Serialize};

use crate::common::{Tuning, check_grid, f1_of, fit_channels, gps_indices, labelled_valid};
use crate::error::{BaselineError, Result, step_dim_error};

/// Hyper-parameters of the PX4-style gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Px4GateConfig {
    /// Textbook (PX4 default) or validation-chosen gate. Default [`Tuning::ValidationF1`]
    /// (decision 050).
    pub tuning: Tuning,
    /// Gate `γ` in standard deviations. Default 5 (PX4 `EKF2_GPS_P_GATE`, params_gnss.yaml).
    pub gamma: f64,
    /// Time without fusion after which the position is reset to GPS, in seconds. Default 7
    /// (PX4 `reset_timeout_max`, EKF/common.h).
    pub reset_timeout_s: f64,
    /// Prefix of the gated channel names. Default `"gps_"` (the residue channel naming of
    /// `ekf_residue`).
    pub gps_channel_prefix: String,
    /// Validation grid of `γ`. Default `[1, 1.5, 2, 2.5, 3, 4, 5, 7]`.
    pub gamma_grid: Vec<f64>,
}

impl Default for Px4GateConfig {
    fn default() -> Self {
        Self {
            tuning: Tuning::ValidationF1,
            gamma: 5.0,
            reset_timeout_s: 7.0,
            gps_channel_prefix: "gps_".into(),
            gamma_grid: vec![1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0],
        }
    }
}

/// A fitted PX4-style gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Px4Gate {
    channels: Vec<String>,
    gps_idx: Vec<usize>,
    gamma: f64,
    reset_timeout_s: f64,
    tuning: Tuning,
}

impl crate::JsonState for Px4Gate {
    fn check_state(&self) -> Result<()> {
        use crate::state::{check_channel_indices, check_channels, check_finite};
        check_channels(&self.channels)?;
        check_finite("gamma, reset_timeout_s", &[self.gamma, self.reset_timeout_s])?;
        check_channel_indices("gps_idx", &self.gps_idx, self.channels.len())
    }
}

impl Px4Gate {
    /// The gate `γ` in standard deviations.
    pub fn gamma(&self) -> f64 {
        self.gamma
    }

    /// Indices of the gated GPS channels.
    pub fn gps_channels(&self) -> &[usize] {
        &self.gps_idx
    }
}

/// Fusion bookkeeping of the gate, shared by batch scoring and the online detector.
#[derive(Debug, Clone)]
struct GateState {
    /// Innovation at the last reset to GPS, per gated channel.
    offset: Vec<f64>,
    /// Time of the last fused (or reset) sample.
    last_fused_s: Option<f64>,
}

impl GateState {
    fn new(n_gps: usize) -> Self {
        Self { offset: vec![0.0; n_gps], last_fused_s: None }
    }

    #[inline]
    fn step(&mut self, gate: &Px4Gate, gamma: f64, t: f64, r_k: &[f64], s_k: &[f64]) -> (f64, bool) {
        let m = r_k.len();
        let inv_g2 = 1.0 / (gamma * gamma);
        let mut ratio = 0.0_f64;
        for (&i, o) in gate.gps_idx.iter().zip(&self.offset) {
            let nu = r_k[i] - o;
            // test_ratio = ν² / (γ² · S_ii); a non-finite ratio rejects, as in PX4.
            let tr = nu * nu * inv_g2 / s_k[i * m + i];
            ratio = if tr.is_nan() { f64::INFINITY } else { ratio.max(tr) };
        }
        let rejected = ratio > 1.0;
        let last = *self.last_fused_s.get_or_insert(t);
        if !rejected {
            self.last_fused_s = Some(t);
        } else if t - last >= gate.reset_timeout_s {
            // Reset to GNSS: the estimate jumps to the (possibly spoofed) measurement.
            for (&i, o) in gate.gps_idx.iter().zip(self.offset.iter_mut()) {
                *o = r_k[i];
            }
            self.last_fused_s = Some(t);
        }
        (ratio, rejected)
    }
}

fn gate_run(gate: &Px4Gate, gamma: f64, series: &ResidueSeries, mut sink: impl FnMut(f64, bool)) {
    let m = series.dim();
    let mut st = GateState::new(gate.gps_idx.len());
    for ((&t, r_k), s_k) in series.t().iter().zip(series.r().chunks_exact(m)).zip(series.s().chunks_exact(m * m)) {
        let (s, a) = st.step(gate, gamma, t, r_k, s_k);
        sink(s, a);
    }
}

impl Fit for Px4GateConfig {
    type Detector = Px4Gate;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Px4Gate> {
        check_grid("gamma", &[self.gamma], 0.0)?;
        check_grid("gamma_grid", &self.gamma_grid, 0.0)?;
        check_grid("reset_timeout_s", &[self.reset_timeout_s], 0.0)?;
        let channels = fit_channels(train, valid)?;
        let gps_idx = gps_indices(&channels, &self.gps_channel_prefix)?;
        let mut gate = Px4Gate {
            channels,
            gps_idx,
            gamma: self.gamma,
            reset_timeout_s: self.reset_timeout_s,
            tuning: self.tuning,
        };
        if self.tuning == Tuning::ValidationF1 {
            let pairs = labelled_valid(valid)?;
            let mut best = (f64::NEG_INFINITY, self.gamma);
            for &gamma in &self.gamma_grid {
                let f1 = f1_of(&pairs, |s, out| gate_run(&gate, gamma, s, |_, a| out.push(a)));
                if f1 > best.0 {
                    best = (f1, gamma);
                }
            }
            gate.gamma = best.1;
        }
        Ok(gate)
    }
}

impl Detector for Px4Gate {
    fn name(&self) -> &str {
        match self.tuning {
            Tuning::Textbook => "PX4 gate (5 sd)",
            Tuning::ValidationF1 => "PX4 gate",
        }
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        let mut out = Vec::with_capacity(series.len());
        gate_run(self, self.gamma, series, |s, _| out.push(s));
        Ok(out)
    }

    fn threshold(&self) -> f64 {
        1.0
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        Box::new(Px4GateOnline { gate: self, state: GateState::new(self.gps_idx.len()) })
    }
}

/// Streaming PX4-style gate with its reset-to-GPS timer.
#[derive(Debug, Clone)]
pub struct Px4GateOnline<'a> {
    gate: &'a Px4Gate,
    state: GateState,
}

impl OnlineDetector for Px4GateOnline<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let m = self.gate.channels.len();
        if step.dim() != m || step.s_k.len() != m * m {
            return Err(step_dim_error(m, step.dim()));
        }
        let (score, alarm) = self.state.step(self.gate, self.gate.gamma, step.t, step.r_k, step.s_k);
        Ok(OnlineDecision { score, alarm })
    }

    fn reset(&mut self) {
        self.state = GateState::new(self.gate.gps_idx.len());
    }
}
