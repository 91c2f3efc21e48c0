//! Binary hypothesis test (BHT), the "ellipsoid" baseline of Muniraj & Farhood (ICUAS 2017) in
//! the paper's tables (Sec. V-E: "the BHT assumes that in the absence of attacks, the
//! residue will predominantly lie within an ellipsoid").
//!
//! Exact variant (the source's is not public; docs/decisions/050-statistical-baseline-variants.md):
//! a fixed-sample Neyman–Pearson test of H0 "the residue lies in the clean ellipsoid" whose
//! shape is the mean `μ̂` and covariance `Σ̂` of the clean training residues (steps labelled
//! clean in labelled training flights), not the filter's `S_k`:
//!
//! ```text
//! d_k² = (r_k − μ̂)ᵀ Σ̂⁻¹ (r_k − μ̂)                   (Mahalanobis distance to the ellipsoid centre)
//! T_k  = (1/N) Σ_{i=k−N+1..k} d_i²                    (over the last N steps, fewer at the start)
//! alarm_k = T_k > γ
//! ```
//!
//! Under H0 with Gaussian residues `N·T_k ~ χ²_{N·m}`, so the textbook threshold is
//! `γ = χ²_{N·m}(1 − A*) / N` with `N = 1` (the single-step ellipsoid) and `A* = 1 %`.
//! Validation setting: `N` from a grid and `γ` maximising F1.

use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, OnlineDecision, OnlineDetector, ResidueSeries, ResidueStep,
};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::common::{Tuning, fit_channels, labelled_valid};
use crate::error::{BaselineError, Result, step_dim_error};
use crate::stats::chi2_quantile;

/// Hyper-parameters of the BHT detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BhtConfig {
    /// Textbook or validation-chosen `(N, γ)`. Default [`Tuning::ValidationF1`] (decision 050).
    pub tuning: Tuning,
    /// Textbook sample size `N`. Default 1 (the single-step ellipsoid of the paper's Sec. V-E).
    pub n_samples: usize,
    /// Design false-alarm rate of the textbook `γ`. Default 0.01, the 1 % design of every
    /// textbook setting (decision 050).
    pub far: f64,
    /// Validation grid of `N`. Default `[1, 2, 5, 10, 20]` (up to 2 s at 10 Hz).
    pub n_grid: Vec<usize>,
    /// Ridge added to `Σ̂`'s diagonal, relative to its mean diagonal, so that a channel
    /// without noise stays invertible. Default 1e-9.
    pub ridge: f64,
}

impl Default for BhtConfig {
    fn default() -> Self {
        Self { tuning: Tuning::ValidationF1, n_samples: 1, far: 0.01, n_grid: vec![1, 2, 5, 10, 20], ridge: 1e-9 }
    }
}

/// Largest sample size `N` of the test (a fitted state or a grid entry): 10,000 residues,
/// 1,000 s at the 10 Hz GPS rate.
pub const MAX_BHT_SAMPLES: usize = 10_000;

/// A fitted BHT detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bht {
    channels: Vec<String>,
    mu: Vec<f64>,
    /// `L⁻¹` of the Cholesky factor `Σ̂ = L Lᵀ`, row-major `m × m` (lower triangular).
    whiten: Vec<f64>,
    n_samples: usize,
    gamma: f64,
    tuning: Tuning,
}

impl crate::JsonState for Bht {
    fn check_state(&self) -> Result<()> {
        use crate::state::{check_channels, check_finite, check_len, state_err};
        check_channels(&self.channels)?;
        let m = self.channels.len();
        check_len("mu", self.mu.len(), m)?;
        check_len("whiten", self.whiten.len(), m * m)?;
        check_finite("mu", &self.mu)?;
        check_finite("whiten", &self.whiten)?;
        check_finite("gamma", &[self.gamma])?;
        if self.n_samples == 0 || self.n_samples > MAX_BHT_SAMPLES {
            return Err(state_err(format!("n_samples: {} is not in 1..={MAX_BHT_SAMPLES}", self.n_samples)));
        }
        Ok(())
    }
}

impl Bht {
    /// The clean-residue mean `μ̂`.
    pub fn mu(&self) -> &[f64] {
        &self.mu
    }

    /// The sample size `N` of the test.
    pub fn n_samples(&self) -> usize {
        self.n_samples
    }

    /// `d_k²` of one residue.
    #[inline]
    fn d2(&self, r_k: &[f64]) -> f64 {
        let m = self.mu.len();
        let mut acc = 0.0;
        // Centre once on the stack (up to 32 channels), then y = L⁻¹ c; row i of L⁻¹ has
        // non-zeros in columns 0..=i only.
        let mut buf = [0.0f64; 32];
        if m <= buf.len() {
            for ((c, r), mu) in buf.iter_mut().zip(r_k).zip(&self.mu) {
                *c = r - mu;
            }
            for (i, row) in self.whiten.chunks_exact(m).enumerate() {
                let y: f64 = row[..=i].iter().zip(&buf[..=i]).map(|(w, c)| w * c).sum();
                acc += y * y;
            }
        } else {
            for (i, row) in self.whiten.chunks_exact(m).enumerate() {
                let y: f64 = row[..=i].iter().zip(r_k).zip(&self.mu).map(|((w, r), mu)| w * (r - mu)).sum();
                acc += y * y;
            }
        }
        acc
    }
}

/// The moving mean of the last `N` values of `d²`.
#[derive(Debug, Clone)]
struct Window {
    buf: Vec<f64>,
    next: usize,
    filled: usize,
}

impl Window {
    fn new(n: usize) -> Self {
        Self { buf: vec![0.0; n.max(1)], next: 0, filled: 0 }
    }

    #[inline]
    fn push(&mut self, d2: f64) -> f64 {
        let n = self.buf.len();
        self.buf[self.next] = d2;
        self.next = if self.next + 1 == n { 0 } else { self.next + 1 };
        self.filled = (self.filled + 1).min(n);
        // Summing the ring (N ≤ a few tens) avoids the drift of a running sum.
        self.buf.iter().sum::<f64>() / self.filled as f64
    }

    fn clear(&mut self) {
        self.buf.iter_mut().for_each(|v| *v = 0.0);
        self.next = 0;
        self.filled = 0;
    }
}

fn bht_scores(det: &Bht, n: usize, series: &ResidueSeries) -> Vec<f64> {
    let mut w = Window::new(n);
    let m = series.dim();
    series.r().chunks_exact(m).map(|r_k| w.push(det.d2(r_k))).collect()
}

impl Fit for BhtConfig {
    type Detector = Bht;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Bht> {
        if self.n_samples == 0 || self.n_grid.is_empty() || self.n_grid.contains(&0) {
            return Err(BaselineError::Config { field: "n_grid", msg: "sample sizes must be positive".into() });
        }
        if self.n_samples > MAX_BHT_SAMPLES || self.n_grid.iter().any(|&n| n > MAX_BHT_SAMPLES) {
            return Err(BaselineError::Config {
                field: "n_grid",
                msg: format!("sample sizes must be at most {MAX_BHT_SAMPLES}"),
            });
        }
        if !(self.far > 0.0 && self.far < 1.0) {
            return Err(BaselineError::Config { field: "far", msg: format!("must lie in (0, 1), got {}", self.far) });
        }
        if !(self.ridge >= 0.0 && self.ridge.is_finite()) {
            return Err(BaselineError::Config {
                field: "ridge",
                msg: format!("must be non-negative, got {}", self.ridge),
            });
        }
        let channels = fit_channels(train, valid)?;
        let (mu, whiten) = clean_ellipsoid(train, channels.len(), self.ridge)?;
        let mut det = Bht { channels, mu, whiten, n_samples: self.n_samples, gamma: 0.0, tuning: self.tuning };
        match self.tuning {
            Tuning::Textbook => {
                let dof = (self.n_samples * det.channels.len()) as f64;
                det.gamma = chi2_quantile(dof, 1.0 - self.far)? / self.n_samples as f64;
            }
            Tuning::ValidationF1 => {
                let pairs = labelled_valid(valid)?;
                let mut best = (f64::NEG_INFINITY, 1, 0.0);
                for &n in &self.n_grid {
                    let scores: Vec<Vec<f64>> = pairs.iter().map(|(s, _)| bht_scores(&det, n, s)).collect();
                    let (gamma, f1) = detection_metrics::best_f1_threshold(
                        scores.iter().zip(&pairs).map(|(sc, (_, l))| (sc.as_slice(), *l)),
                    )?;
                    if f1 > best.0 {
                        best = (f1, n, gamma);
                    }
                }
                det.n_samples = best.1;
                det.gamma = best.2;
            }
        }
        Ok(det)
    }
}

/// Mean and whitening matrix of the clean steps of the labelled training flights.
fn clean_ellipsoid(train: &LabelledResidues, m: usize, ridge: f64) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut n = 0usize;
    let mut sum = DVector::<f64>::zeros(m);
    let mut sum_sq = DMatrix::<f64>::zeros(m, m);
    for (series, labels) in train.labelled() {
        for (r_k, _) in series.r().chunks_exact(m).zip(labels).filter(|(_, a)| !**a) {
            let r = DVector::from_column_slice(r_k);
            sum += &r;
            sum_sq += &r * r.transpose();
            n += 1;
        }
    }
    if n <= m {
        return Err(DetectError::Data {
            msg: format!("BHT needs more than {m} clean labelled training steps to estimate the ellipsoid, got {n}"),
        }
        .into());
    }
    let mu = sum / n as f64;
    // Unbiased sample covariance Σ̂ = (Σ r rᵀ − n μ μᵀ) / (n − 1).
    let mut cov = (sum_sq - &mu * mu.transpose() * n as f64) / (n - 1) as f64;
    let scale = cov.diagonal().mean().abs().max(f64::MIN_POSITIVE);
    for i in 0..m {
        cov[(i, i)] += ridge * scale;
    }
    let chol = cov
        .cholesky()
        .ok_or_else(|| DetectError::Numerical { what: "Cholesky of the clean residue covariance".into() })?;
    let l_inv = chol
        .l()
        .try_inverse()
        .ok_or_else(|| DetectError::Numerical { what: "inverse of the clean residue Cholesky factor".into() })?;
    let mut whiten = Vec::with_capacity(m * m);
    for i in 0..m {
        for j in 0..m {
            whiten.push(if j <= i { l_inv[(i, j)] } else { 0.0 });
        }
    }
    Ok((mu.iter().copied().collect(), whiten))
}

impl Detector for Bht {
    fn name(&self) -> &str {
        match self.tuning {
            Tuning::Textbook => "BHT (1% FAR)",
            Tuning::ValidationF1 => "BHT",
        }
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        Ok(bht_scores(self, self.n_samples, series))
    }

    fn threshold(&self) -> f64 {
        self.gamma
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        Box::new(BhtOnline { detector: self, window: Window::new(self.n_samples) })
    }
}

/// Streaming BHT: the moving mean of `d²` over the last `N` steps.
#[derive(Debug, Clone)]
pub struct BhtOnline<'a> {
    detector: &'a Bht,
    window: Window,
}

impl OnlineDetector for BhtOnline<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let m = self.detector.channels.len();
        if step.dim() != m {
            return Err(step_dim_error(m, step.dim()));
        }
        let score = self.window.push(self.detector.d2(step.r_k));
        Ok(OnlineDecision { score, alarm: score > self.detector.gamma })
    }

    fn reset(&mut self) {
        self.window.clear();
    }
}
