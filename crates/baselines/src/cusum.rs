//! CUSUM detector on the NIS (Murguia & Ruths, "CUSUM and chi-squared attack detection of
//! compromised sensors", CCA 2016; the paper's CUSUM baseline and its Fig. 9,
//! fig:CUSUM_3_plots).
//!
//! With `z_k = r_kᵀ S_k⁻¹ r_k`:
//!
//! ```text
//! S_k = max(0, S'_{k−1} + z_k − b),   alarm_k = S_k > τ,   S'_k = 0 if alarm_k else S_k
//! ```
//!
//! The bias `b` must exceed `E[z_k] = m` under H0 so that the drift is negative. Reset policy:
//! after an alarm the statistic restarts from 0 and the next step's increment is added to it
//! (the chain of the Markov false-alarm computation, [`crate::stats::cusum_false_alarm_rate`]),
//! so a large persistent residue alarms at every step. The per-step score is `S_k` before the
//! reset, so `score > τ` is exactly the alarm.
//!
//! Textbook setting: `b = 1.5·m` (drift `−m/2` under H0) and `τ` from the Markov chain for a
//! 1 % false-alarm rate under `χ²_m` increments. Validation setting: `b` from a grid of multiples
//! of the clean validation mean NIS, `τ` from quantiles of the unreset statistic and a log-spaced grid,
//! maximising F1 (ties to the largest `b` and the median tied `τ`).

use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, OnlineDecision, OnlineDetector, ResidueSeries, ResidueStep,
};
use serde::{Deserialize, Serialize};

use crate::common::{Tuning, check_grid, f1_of, fit_channels, labelled_valid, quantile_grid};
use crate::error::{BaselineError, Result, step_dim_error};
use crate::stats::{chi2_cdf, cusum_tau_for_far};

/// Hyper-parameters of the CUSUM detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CusumConfig {
    /// Textbook or validation-chosen `(b, τ)`. Default [`Tuning::ValidationF1`] (decision 050).
    pub tuning: Tuning,
    /// Textbook bias as a multiple of `m = E[z_k]`. Default 1.5 (our choice within Murguia &
    /// Ruths' `b > m` rule; docs/baselines.md).
    pub b_over_m: f64,
    /// Design false-alarm rate per step of the textbook `τ`. Default 0.01, the 1 % design of every
    /// textbook setting (decision 050).
    pub far: f64,
    /// Bins of the Markov chain on `(0, τ]`. Default 150 (matches a Monte Carlo simulation of
    /// the recursion to 2 %; tested in `stats`).
    pub n_bins: usize,
    /// Validation grid of `b` as multiples of the clean mean NIS. Default
    /// `[1.05, 1.2, 1.5, 2, 3, 5, 10]` (from "barely negative drift" to chi-squared-like).
    pub b_grid: Vec<f64>,
    /// Number of `τ` candidates per `b`: quantiles of the unreset statistic, plus half as many
    /// log-spaced values from a tenth of the clean mean NIS to the statistic's maximum.
    /// Default 48.
    pub n_tau: usize,
}

impl Default for CusumConfig {
    fn default() -> Self {
        Self {
            tuning: Tuning::ValidationF1,
            b_over_m: 1.5,
            far: 0.01,
            n_bins: 150,
            b_grid: vec![1.05, 1.2, 1.5, 2.0, 3.0, 5.0, 10.0],
            n_tau: 48,
        }
    }
}

/// A fitted CUSUM detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cusum {
    channels: Vec<String>,
    b: f64,
    tau: f64,
    tuning: Tuning,
}

impl crate::JsonState for Cusum {
    fn check_state(&self) -> Result<()> {
        crate::state::check_channels(&self.channels)?;
        crate::state::check_finite("b, tau", &[self.b, self.tau])
    }
}

impl Cusum {
    /// The bias `b` subtracted from every NIS.
    pub fn b(&self) -> f64 {
        self.b
    }

    /// The alarm threshold `τ`.
    pub fn tau(&self) -> f64 {
        self.tau
    }
}

/// The CUSUM recursion, shared by batch scoring and the online detector.
#[derive(Debug, Clone, Copy, Default)]
struct CusumState {
    s: f64,
}

impl CusumState {
    #[inline]
    fn step(&mut self, z: f64, b: f64, tau: f64) -> (f64, bool) {
        // S_k = max(0, S'_{k−1} + z_k − b); alarm and reset above τ.
        let s = (self.s + z - b).max(0.0);
        let alarm = s > tau;
        self.s = if alarm { 0.0 } else { s };
        (s, alarm)
    }
}

/// CUSUM scores `S_k` of a NIS sequence (before each reset).
pub fn cusum_scores(nis: &[f64], b: f64, tau: f64, out: &mut Vec<f64>) {
    let mut st = CusumState::default();
    out.extend(nis.iter().map(|&z| st.step(z, b, tau).0));
}

impl Fit for CusumConfig {
    type Detector = Cusum;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Cusum> {
        check_grid("b_over_m", &[self.b_over_m], 1.0)?;
        check_grid("b_grid", &self.b_grid, 0.0)?;
        if !(self.far > 0.0 && self.far < 1.0) {
            return Err(BaselineError::Config { field: "far", msg: format!("must lie in (0, 1), got {}", self.far) });
        }
        if self.n_tau == 0 || self.n_bins == 0 {
            return Err(BaselineError::Config { field: "n_tau", msg: "n_tau and n_bins must be positive".into() });
        }
        let channels = fit_channels(train, valid)?;
        let m = channels.len() as f64;
        let (b, tau) = match self.tuning {
            Tuning::Textbook => {
                let b = self.b_over_m * m;
                let cdf = |x: f64| chi2_cdf(m, x);
                (b, cusum_tau_for_far(&cdf, b, self.far, self.n_bins)?)
            }
            Tuning::ValidationF1 => self.fit_on_valid(&labelled_valid(valid)?, m)?,
        };
        Ok(Cusum { channels, b, tau, tuning: self.tuning })
    }
}

impl CusumConfig {
    fn fit_on_valid(&self, pairs: &[(&ResidueSeries, &[bool])], m: f64) -> Result<(f64, f64)> {
        let clean: Vec<f64> = pairs
            .iter()
            .flat_map(|(s, l)| s.nis().iter().zip(l.iter()).filter(|(_, a)| !**a).map(|(z, _)| *z))
            .collect();
        // Mean NIS of clean steps, E0[z]; falls back to m when the split has no clean step.
        let z0 = if clean.is_empty() { m } else { clean.iter().sum::<f64>() / clean.len() as f64 };
        // (F1, b, τ) of every candidate.
        let mut cands: Vec<(f64, f64, f64)> = Vec::new();
        let mut buf = Vec::new();
        for &ratio in &self.b_grid {
            let b = ratio * z0;
            // τ candidates: quantiles of the statistic without reset.
            let mut unreset = Vec::new();
            for (s, _) in pairs {
                buf.clear();
                cusum_scores(s.nis(), b, f64::INFINITY, &mut buf);
                unreset.extend(buf.iter().copied().filter(|v| *v > 0.0));
            }
            // Quantiles alone miss low τ when positive values come almost only from attacks
            // (large b): add a log-spaced grid from z0/10 up to the largest value.
            let mut taus = quantile_grid(&unreset, self.n_tau);
            let top = unreset.iter().copied().fold(z0, f64::max);
            let n_log = self.n_tau / 2;
            taus.extend((0..n_log).map(|i| 0.1 * z0 * (top / (0.1 * z0)).powf(i as f64 / (n_log.max(2) - 1) as f64)));
            taus.sort_by(f64::total_cmp);
            taus.dedup();
            for tau in taus {
                let f1 = f1_of(pairs, |s, out| {
                    let mut st = CusumState::default();
                    out.extend(s.nis().iter().map(|&z| st.step(z, b, tau).1));
                });
                cands.push((f1, b, tau));
            }
        }
        // Ties (common when attacks are gross) go to the largest b, the most negative H0 drift,
        // and then to the median tied τ, away from both edges of the tied range.
        let best_f1 = cands.iter().map(|c| c.0).fold(f64::NEG_INFINITY, f64::max);
        let tied: Vec<&(f64, f64, f64)> = cands.iter().filter(|c| c.0 >= best_f1 - 1e-12).collect();
        let b = tied.iter().map(|c| c.1).fold(f64::NEG_INFINITY, f64::max);
        let taus: Vec<f64> = tied.iter().filter(|c| c.1 == b).map(|c| c.2).collect();
        taus.get(taus.len() / 2).map(|&tau| (b, tau)).ok_or_else(|| {
            DetectError::Data { msg: "CUSUM statistic never left 0 on the validation split".into() }.into()
        })
    }
}

impl Detector for Cusum {
    fn name(&self) -> &str {
        match self.tuning {
            Tuning::Textbook => "CUSUM (1% FAR)",
            Tuning::ValidationF1 => "CUSUM",
        }
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        let mut out = Vec::with_capacity(series.len());
        cusum_scores(series.nis(), self.b, self.tau, &mut out);
        Ok(out)
    }

    fn threshold(&self) -> f64 {
        self.tau
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        self.online_at(self.tau)
    }

    /// The recursion alarming and restarting at `threshold` instead of `τ`.
    fn online_at(&self, threshold: f64) -> Box<dyn OnlineDetector + '_> {
        Box::new(CusumOnline { m: self.channels.len(), b: self.b, tau: threshold, state: CusumState::default() })
    }
}

/// Streaming CUSUM: the same recursion one step at a time.
#[derive(Debug, Clone)]
pub struct CusumOnline {
    m: usize,
    b: f64,
    tau: f64,
    state: CusumState,
}

impl OnlineDetector for CusumOnline {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        if step.dim() != self.m {
            return Err(step_dim_error(self.m, step.dim()));
        }
        let (score, alarm) = self.state.step(step.nis, self.b, self.tau);
        Ok(OnlineDecision { score, alarm })
    }

    fn reset(&mut self) {
        self.state = CusumState::default();
    }
}
