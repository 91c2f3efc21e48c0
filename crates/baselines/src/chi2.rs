//! Chi-squared detector on the normalised innovation squared (Murguia & Ruths, CCA 2016; paper
//! Sec. II): alarm at step `k` iff `z_k = r_kᵀ S_k⁻¹ r_k > α`.
//!
//! Under H0 and Gaussian residues `z_k ~ χ²_m`, so the textbook threshold is the `1 − A*`
//! quantile of `χ²_m` (`A*` the design false-alarm rate, 1 % by default: `α = 16.812` for the
//! six Model I channels). Memoryless: the score of a step is its NIS.

use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, OnlineDecision, OnlineDetector, ResidueSeries, ResidueStep,
};
use serde::{Deserialize, Serialize};

use crate::common::{Tuning, fit_channels, labelled_valid};
use crate::error::{BaselineError, Result, step_dim_error};
use crate::stats::chi2_quantile;

/// Hyper-parameters of the chi-squared detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Chi2Config {
    /// Textbook or validation-chosen threshold. Default [`Tuning::ValidationF1`] (decision 050).
    pub tuning: Tuning,
    /// Design false-alarm rate per step of the textbook threshold. Default 0.01, the 1 % design of
    /// every textbook setting (docs/decisions/050-statistical-baseline-variants.md).
    pub far: f64,
}

impl Default for Chi2Config {
    fn default() -> Self {
        Self { tuning: Tuning::ValidationF1, far: 0.01 }
    }
}

/// A fitted chi-squared detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Chi2 {
    channels: Vec<String>,
    alpha: f64,
    tuning: Tuning,
}

impl crate::JsonState for Chi2 {
    fn check_state(&self) -> Result<()> {
        crate::state::check_channels(&self.channels)?;
        crate::state::check_finite("alpha", &[self.alpha])
    }
}

impl Chi2 {
    /// The alarm threshold `α` on the NIS.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }
}

impl Fit for Chi2Config {
    type Detector = Chi2;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Chi2> {
        if !(self.far > 0.0 && self.far < 1.0) {
            return Err(BaselineError::Config { field: "far", msg: format!("must lie in (0, 1), got {}", self.far) });
        }
        let channels = fit_channels(train, valid)?;
        let alpha = match self.tuning {
            Tuning::Textbook => chi2_quantile(channels.len() as f64, 1.0 - self.far)?,
            Tuning::ValidationF1 => {
                let pairs = labelled_valid(valid)?;
                detection_metrics::best_f1_threshold(pairs.iter().map(|(s, l)| (s.nis(), *l)))?.0
            }
        };
        Ok(Chi2 { channels, alpha, tuning: self.tuning })
    }
}

impl Detector for Chi2 {
    fn name(&self) -> &str {
        match self.tuning {
            Tuning::Textbook => "Chi2 (1% FAR)",
            Tuning::ValidationF1 => "Chi2",
        }
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        Ok(series.nis().to_vec())
    }

    fn threshold(&self) -> f64 {
        self.alpha
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        Box::new(Chi2Online { m: self.channels.len(), alpha: self.alpha })
    }
}

/// Streaming chi-squared test (stateless).
#[derive(Debug, Clone)]
pub struct Chi2Online {
    m: usize,
    alpha: f64,
}

impl OnlineDetector for Chi2Online {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        if step.dim() != self.m {
            return Err(step_dim_error(self.m, step.dim()));
        }
        Ok(OnlineDecision { score: step.nis, alarm: step.nis > self.alpha })
    }

    fn reset(&mut self) {}
}
