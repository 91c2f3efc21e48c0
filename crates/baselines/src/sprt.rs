//! Wald's sequential probability ratio test (Wald 1945; Basseville & Nikiforov 1993, §4.3), the
//! SPRT baseline of Muniraj & Farhood (ICUAS 2017) in the paper's tables.
//!
//! Direction handling: the attack direction is unknown, so the detector runs `2m` one-sided
//! tests, one per channel `i` and sign `σ ∈ {+1, −1}`, for a mean shift of `δ` standard
//! deviations on that channel. With the normalised residue `ν_i = r_i / √(S_k)_ii`,
//!
//! ```text
//! l_k = σ·δ·ν_i − δ²/2                      (log-likelihood ratio of N(σδ, 1) against N(0, 1))
//! Λ_k = Λ'_{k−1} + l_k
//! A = ln((1 − β)/α),  B = ln(β/(1 − α))      (Wald's thresholds from P_FA = α, P_miss = β)
//! ```
//!
//! Reset policy (repeated SPRT): when `Λ_k ≤ B` the test accepts H0 and restarts from 0; when
//! `Λ_k > A` it alarms and restarts from 0, so a persistent attack re-alarms as soon as the
//! evidence again exceeds `A`. The step's score is the largest `Λ_k` over the `2m` tests (before
//! resets) and the threshold is `A`. Textbook setting: `δ = 3` (the smallest main-table attack,
//! about 3 GPS σ, docs/decisions/030-attack-model-and-planning.md) and `α = β = 0.01`
//! (`A = 4.595`). Validation setting: a grid over `δ`, `α` and `β` maximising F1.

use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, OnlineDecision, OnlineDetector, ResidueSeries, ResidueStep,
};
use serde::{Deserialize, Serialize};

use crate::common::{Tuning, check_grid, f1_of, fit_channels, labelled_valid};
use crate::error::{BaselineError, Result, step_dim_error};

/// Hyper-parameters of the SPRT detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SprtConfig {
    /// Textbook or validation-chosen `(δ, α, β)`. Default [`Tuning::ValidationF1`] (decision 050).
    pub tuning: Tuning,
    /// Textbook design shift in standard deviations. Default 3 (the smallest attack amplitude of
    /// the main tables, docs/decisions/030).
    pub delta: f64,
    /// Textbook false-alarm probability `α`. Default 0.01, the 1 % design of every textbook
    /// setting (decision 050).
    pub alpha: f64,
    /// Textbook miss probability `β`. Default 0.01 (symmetric Wald design).
    pub beta: f64,
    /// Validation grid of `δ`. Default `[0.5, 1, 2, 3, 5, 10]`.
    pub delta_grid: Vec<f64>,
    /// Validation grid of `α`. Default `[1e-8, 1e-6, 1e-4, 1e-3, 0.01, 0.05, 0.1, 0.2]`.
    pub alpha_grid: Vec<f64>,
    /// Validation grid of `β`. Default `[0.01, 0.1, 0.3]`.
    pub beta_grid: Vec<f64>,
}

impl Default for SprtConfig {
    fn default() -> Self {
        Self {
            tuning: Tuning::ValidationF1,
            delta: 3.0,
            alpha: 0.01,
            beta: 0.01,
            delta_grid: vec![0.5, 1.0, 2.0, 3.0, 5.0, 10.0],
            alpha_grid: vec![1e-8, 1e-6, 1e-4, 1e-3, 0.01, 0.05, 0.1, 0.2],
            beta_grid: vec![0.01, 0.1, 0.3],
        }
    }
}

/// Wald's thresholds `(A, B)` from `α` and `β`.
pub fn wald_thresholds(alpha: f64, beta: f64) -> (f64, f64) {
    (((1.0 - beta) / alpha).ln(), (beta / (1.0 - alpha)).ln())
}

/// A fitted SPRT detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sprt {
    channels: Vec<String>,
    delta: f64,
    alpha: f64,
    beta: f64,
    upper: f64,
    lower: f64,
    tuning: Tuning,
}

impl crate::JsonState for Sprt {
    fn check_state(&self) -> Result<()> {
        crate::state::check_channels(&self.channels)?;
        crate::state::check_finite(
            "delta, alpha, beta, upper, lower",
            &[self.delta, self.alpha, self.beta, self.upper, self.lower],
        )
    }
}

impl Sprt {
    /// The design shift `δ` in standard deviations.
    pub fn delta(&self) -> f64 {
        self.delta
    }

    /// Wald's `(α, β)`.
    pub fn alpha_beta(&self) -> (f64, f64) {
        (self.alpha, self.beta)
    }
}

/// The `2m` log-likelihood-ratio sums, shared by batch scoring and the online detector.
#[derive(Debug, Clone)]
struct SprtState {
    /// `[Λ_{0,+}, Λ_{0,−}, Λ_{1,+}, …]`.
    lambda: Vec<f64>,
}

impl SprtState {
    fn new(m: usize) -> Self {
        Self { lambda: vec![0.0; 2 * m] }
    }

    /// One step on `r_k` and the row-major `S_k`; returns the score and the alarm.
    #[inline]
    fn step(&mut self, r_k: &[f64], s_k: &[f64], delta: f64, upper: f64, lower: f64) -> (f64, bool) {
        let m = r_k.len();
        let half_d2 = 0.5 * delta * delta;
        let mut score = f64::NEG_INFINITY;
        // The diagonal of the row-major S_k is every (m + 1)-th entry.
        let diag = s_k.iter().step_by(m + 1);
        for ((&r, &s_ii), pair) in r_k.iter().zip(diag).zip(self.lambda.chunks_exact_mut(2)) {
            let l = delta * r / s_ii.sqrt();
            // l_k = σ·δ·ν_i − δ²/2 for σ = ±1.
            let v_pos = pair[0] + l - half_d2;
            let v_neg = pair[1] - l - half_d2;
            score = score.max(v_pos.max(v_neg));
            pair[0] = if v_pos <= lower || v_pos > upper { 0.0 } else { v_pos };
            pair[1] = if v_neg <= lower || v_neg > upper { 0.0 } else { v_neg };
        }
        (score, score > upper)
    }
}

fn sprt_run(series: &ResidueSeries, delta: f64, upper: f64, lower: f64, mut sink: impl FnMut(f64, bool)) {
    let m = series.dim();
    let mut st = SprtState::new(m);
    for (r_k, s_k) in series.r().chunks_exact(m).zip(series.s().chunks_exact(m * m)) {
        let (s, a) = st.step(r_k, s_k, delta, upper, lower);
        sink(s, a);
    }
}

impl Fit for SprtConfig {
    type Detector = Sprt;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Sprt> {
        check_grid("delta", &[self.delta], 0.0)?;
        for (field, grid) in
            [("alpha", &[self.alpha, self.beta][..]), ("alpha_grid", &self.alpha_grid), ("beta_grid", &self.beta_grid)]
        {
            if grid.is_empty() || grid.iter().any(|p| !(*p > 0.0 && *p < 0.5)) {
                return Err(BaselineError::Config {
                    field,
                    msg: format!("probabilities must lie in (0, 0.5), got {grid:?}"),
                });
            }
        }
        check_grid("delta_grid", &self.delta_grid, 0.0)?;
        let channels = fit_channels(train, valid)?;
        let (delta, alpha, beta) = match self.tuning {
            Tuning::Textbook => (self.delta, self.alpha, self.beta),
            Tuning::ValidationF1 => {
                let pairs = labelled_valid(valid)?;
                let mut best = (f64::NEG_INFINITY, self.delta, self.alpha, self.beta);
                for &delta in &self.delta_grid {
                    for &alpha in &self.alpha_grid {
                        for &beta in &self.beta_grid {
                            let (upper, lower) = wald_thresholds(alpha, beta);
                            let f1 = f1_of(&pairs, |s, out| sprt_run(s, delta, upper, lower, |_, a| out.push(a)));
                            if f1 > best.0 {
                                best = (f1, delta, alpha, beta);
                            }
                        }
                    }
                }
                (best.1, best.2, best.3)
            }
        };
        let (upper, lower) = wald_thresholds(alpha, beta);
        Ok(Sprt { channels, delta, alpha, beta, upper, lower, tuning: self.tuning })
    }
}

impl Detector for Sprt {
    fn name(&self) -> &str {
        match self.tuning {
            Tuning::Textbook => "SPRT (a=b=1%)",
            Tuning::ValidationF1 => "SPRT",
        }
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        let mut out = Vec::with_capacity(series.len());
        sprt_run(series, self.delta, self.upper, self.lower, |s, _| out.push(s));
        Ok(out)
    }

    fn threshold(&self) -> f64 {
        self.upper
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        self.online_at(self.upper)
    }

    /// The `2m` tests alarming and restarting at `threshold` instead of `A`.
    fn online_at(&self, threshold: f64) -> Box<dyn OnlineDetector + '_> {
        Box::new(SprtOnline { detector: self, upper: threshold, state: SprtState::new(self.channels.len()) })
    }
}

/// Streaming SPRT: the same `2m` recursions one step at a time.
#[derive(Debug, Clone)]
pub struct SprtOnline<'a> {
    detector: &'a Sprt,
    /// Alarm and restart level (`A` unless built by `online_at`).
    upper: f64,
    state: SprtState,
}

impl OnlineDetector for SprtOnline<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let m = self.detector.channels.len();
        if step.dim() != m || step.s_k.len() != m * m {
            return Err(step_dim_error(m, step.dim()));
        }
        let d = self.detector;
        let (score, alarm) = self.state.step(step.r_k, step.s_k, d.delta, self.upper, d.lower);
        Ok(OnlineDecision { score, alarm })
    }

    fn reset(&mut self) {
        self.state.lambda.iter_mut().for_each(|l| *l = 0.0);
    }
}
