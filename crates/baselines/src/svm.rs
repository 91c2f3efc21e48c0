//! Support vector machine with an RBF kernel on windowed residue features (the SVM baseline of
//! Shafique et al. 2021 and Khoei et al. 2022 in the paper's tables, fed residue windows as the
//! paper does in Sec. V-E).
//!
//! Decision function of the fitted machine, with support vectors `x_j`, signed coefficients
//! `w_j = α_j y_j`, bias `b` and kernel width `γ`:
//!
//! ```text
//! f(x) = b + Σ_j w_j · exp(−γ ‖x − x_j‖²),   labels y ∈ {−1 (clean), +1 (attacked)}
//! ```
//!
//! `x` is the standardised feature vector of [`crate::features`]; the per-step score is `f(x)`
//! and the alarm threshold on it is chosen on the validation split (best F1), as are `C` and
//! `γ` from small grids. Training uses smartcore 0.7's `SVC` (LaSVM solver); the fitted SVC
//! borrows its training data, so its support vectors, coefficients and bias are copied out
//! through smartcore's `serde` representation and the detector owns them
//! (docs/decisions/051-svm-owned-support-vectors.md).
//!
//! Tractability: LaSVM's cost grows with the square of the number of samples, so training uses
//! at most `max_train` steps of the labelled training flights, drawn with a seeded generator:
//! up to half of them attacked steps (all of them if fewer), the rest clean.

use ekf_residue::{DetectError, Detector, Fit, LabelledResidues, ResidueSeries};
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};
use smartcore::linalg::basic::matrix::DenseMatrix;
use smartcore::svm::Kernels;
use smartcore::svm::svc::{SVC, SVCParameters};

use crate::common::{fit_channels, labelled_valid};
use crate::error::{BaselineError, Result};
use crate::features::{n_features, window_features};

/// Hyper-parameters of the SVM baseline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SvmConfig {
    /// Feature window `w` in steps. Default 10 (1 s of 10 Hz GPS residues, the span of a short
    /// Attack I burst, docs/decisions/030-attack-model-and-planning.md).
    pub window: usize,
    /// Most training samples given to the solver. Default 500: at paper scale it reached a
    /// validation F1 within 0.01 of 1,000 samples at a quarter of the cost, and 2,000 samples
    /// were no better (docs/decisions/053-baseline-training-budgets.md).
    pub max_train: usize,
    /// Validation grid of the soft-margin penalty `C`. Default `[1, 10]` (scikit-learn's
    /// default 1 and one decade up).
    pub c_grid: Vec<f64>,
    /// Validation grid of `γ` as multiples of `1/n_features` (scikit-learn's `gamma="auto"`).
    /// Default `[0.3, 1, 3]`.
    pub gamma_grid: Vec<f64>,
    /// LaSVM passes over the data. Default 2 (smartcore's default).
    pub epochs: usize,
    /// Solver tolerance. Default 1e-3 (smartcore's default).
    pub tol: f64,
    /// Seed of the training subsample and the solver. Default 0.
    pub seed: u64,
}

impl Default for SvmConfig {
    fn default() -> Self {
        Self {
            window: 10,
            max_train: 500,
            c_grid: vec![1.0, 10.0],
            gamma_grid: vec![0.3, 1.0, 3.0],
            epochs: 2,
            tol: 1e-3,
            seed: 0,
        }
    }
}

/// A fitted RBF SVM over windowed residue features.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Svm {
    channels: Vec<String>,
    window: usize,
    feat_mean: Vec<f64>,
    feat_std: Vec<f64>,
    /// Support vectors, row-major `n_sv × d` (standardised features).
    support: Vec<f64>,
    coef: Vec<f64>,
    bias: f64,
    gamma: f64,
    c: f64,
    threshold: f64,
}

impl crate::JsonState for Svm {
    fn check_state(&self) -> Result<()> {
        use crate::state::{check_channels, check_finite, check_len, state_err};
        check_channels(&self.channels)?;
        if self.window == 0 || self.window > MAX_SVM_WINDOW {
            return Err(state_err(format!("window: {} is not in 1..={MAX_SVM_WINDOW}", self.window)));
        }
        let d = n_features(self.channels.len());
        check_len("feat_mean", self.feat_mean.len(), d)?;
        check_len("feat_std", self.feat_std.len(), d)?;
        check_len("support", self.support.len(), self.coef.len() * d)?;
        for (field, v) in [("feat_mean", &self.feat_mean), ("feat_std", &self.feat_std), ("support", &self.support)] {
            check_finite(field, v)?;
        }
        check_finite("coef", &self.coef)?;
        check_finite("bias, gamma, c, threshold", &[self.bias, self.gamma, self.c, self.threshold])
    }
}

impl Svm {
    /// Number of support vectors.
    pub fn n_support(&self) -> usize {
        self.coef.len()
    }

    /// The chosen `(C, γ)`.
    pub fn c_gamma(&self) -> (f64, f64) {
        (self.c, self.gamma)
    }

    /// Decision values of standardised feature rows (row-major `n × d`).
    fn decision(&self, x: &[f64]) -> Vec<f64> {
        let d = self.feat_mean.len();
        x.chunks_exact(d)
            .map(|row| {
                let mut f = self.bias;
                for (sv, w) in self.support.chunks_exact(d).zip(&self.coef) {
                    let dist2: f64 = sv.iter().zip(row).map(|(a, b)| (a - b) * (a - b)).sum();
                    f += w * (-self.gamma * dist2).exp();
                }
                f
            })
            .collect()
    }

    fn standardised_features(&self, series: &ResidueSeries) -> Vec<f64> {
        let mut x = window_features(series, self.window);
        standardise(&mut x, &self.feat_mean, &self.feat_std);
        x
    }
}

fn standardise(x: &mut [f64], mean: &[f64], std: &[f64]) {
    let d = mean.len();
    for row in x.chunks_exact_mut(d) {
        for ((v, mu), s) in row.iter_mut().zip(mean).zip(std) {
            *v = (*v - mu) / s;
        }
    }
}

/// Budget of `max_train`: the kernel matrix holds `max_train²` numbers (800 MB at the budget).
pub const MAX_SVM_TRAIN: usize = 10_000;
/// Budget of `window`: every step's feature row holds `window × channels` numbers.
pub const MAX_SVM_WINDOW: usize = 2_000;

impl SvmConfig {
    /// Checks sizes and ranges, and the budgets [`MAX_SVM_TRAIN`] and [`MAX_SVM_WINDOW`].
    ///
    /// # Errors
    /// [`BaselineError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        if self.window == 0 {
            return Err(BaselineError::Config { field: "window", msg: "must be at least 1".into() });
        }
        if self.window > MAX_SVM_WINDOW {
            return Err(BaselineError::Config {
                field: "window",
                msg: format!("{} exceeds the budget of {MAX_SVM_WINDOW}", self.window),
            });
        }
        if self.max_train > MAX_SVM_TRAIN {
            return Err(BaselineError::Config {
                field: "max_train",
                msg: format!(
                    "{} exceeds the budget of {MAX_SVM_TRAIN} (the kernel matrix has max_train² entries)",
                    self.max_train
                ),
            });
        }
        if self.max_train < 4 {
            return Err(BaselineError::Config {
                field: "max_train",
                msg: format!("must be at least 4, got {}", self.max_train),
            });
        }
        crate::common::check_grid("c_grid", &self.c_grid, 0.0)?;
        crate::common::check_grid("gamma_grid", &self.gamma_grid, 0.0)?;
        if self.epochs == 0 || self.tol.is_nan() || self.tol <= 0.0 {
            return Err(BaselineError::Config { field: "epochs", msg: "epochs and tol must be positive".into() });
        }
        Ok(())
    }

    /// The seeded, class-balanced training subsample: feature rows and ±1 labels.
    fn training_set(&self, train: &LabelledResidues, d: usize) -> Result<(Vec<f64>, Vec<i32>)> {
        let mut pos = Vec::new();
        let mut neg = Vec::new();
        for (series, labels) in train.labelled() {
            let x = window_features(series, self.window);
            for (row, &a) in x.chunks_exact(d).zip(labels) {
                if a { pos.push(row.to_vec()) } else { neg.push(row.to_vec()) }
            }
        }
        if pos.is_empty() || neg.is_empty() {
            return Err(DetectError::Data {
                msg: format!(
                    "SVM needs attacked and clean labelled training steps, got {} and {}",
                    pos.len(),
                    neg.len()
                ),
            }
            .into());
        }
        let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed);
        let n_pos = pos.len().min(self.max_train / 2);
        let n_neg = neg.len().min(self.max_train - n_pos);
        let mut x = Vec::with_capacity((n_pos + n_neg) * d);
        let mut y = Vec::with_capacity(n_pos + n_neg);
        for (set, n, label) in [(&mut pos, n_pos, 1), (&mut neg, n_neg, -1)] {
            // Partial Fisher–Yates: the first n entries become a uniform sample.
            for i in 0..n {
                let j = rng.random_range(i..set.len());
                set.swap(i, j);
                x.extend_from_slice(&set[i]);
                y.push(label);
            }
        }
        Ok((x, y))
    }
}

/// Support vectors, coefficients and bias of a fitted smartcore SVC.
#[derive(Deserialize)]
struct SvcParts {
    classes: Option<(i32, i32)>,
    instances: Option<Vec<Vec<f64>>>,
    w: Option<Vec<f64>>,
    b: Option<f64>,
}

fn fit_svc(x: &[f64], y: &[i32], d: usize, c: f64, gamma: f64, cfg: &SvmConfig) -> Result<(Vec<f64>, Vec<f64>, f64)> {
    let svm_err = |msg: String| BaselineError::Svm { msg };
    let rows: Vec<Vec<f64>> = x.chunks_exact(d).map(<[f64]>::to_vec).collect();
    let xm = DenseMatrix::from_2d_vec(&rows).map_err(|e| svm_err(e.to_string()))?;
    let yv = y.to_vec();
    let params = SVCParameters::default()
        .with_c(c)
        .with_tol(cfg.tol)
        .with_epoch(cfg.epochs)
        .with_seed(Some(cfg.seed))
        .with_kernel(Kernels::rbf().with_gamma(gamma));
    let svc = SVC::fit(&xm, &yv, &params).map_err(|e| svm_err(e.to_string()))?;
    let value = serde_json::to_value(&svc).map_err(|e| svm_err(format!("serialising the fitted SVC: {e}")))?;
    let parts: SvcParts = serde_json::from_value(value).map_err(|e| svm_err(format!("reading the fitted SVC: {e}")))?;
    let (Some(classes), Some(instances), Some(w), Some(b)) = (parts.classes, parts.instances, parts.w, parts.b) else {
        return Err(svm_err("fitted SVC lacks support vectors".into()));
    };
    // smartcore predicts classes.1 where f > 0; orient f so that positive means attacked.
    let sign = if classes.1 == 1 { 1.0 } else { -1.0 };
    Ok((instances.concat(), w.iter().map(|v| sign * v).collect(), sign * b))
}

impl Fit for SvmConfig {
    type Detector = Svm;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Svm> {
        self.check()?;
        let channels = fit_channels(train, valid)?;
        for f in train.flights() {
            ekf_residue::check_channels(&channels, f.series())?;
        }
        let d = n_features(channels.len());
        let (mut x, y) = self.training_set(train, d)?;
        // Standardise with the subsample's statistics.
        let n = y.len() as f64;
        let mut feat_mean = vec![0.0; d];
        let mut feat_std = vec![0.0; d];
        for row in x.chunks_exact(d) {
            for (m, v) in feat_mean.iter_mut().zip(row) {
                *m += v / n;
            }
        }
        for row in x.chunks_exact(d) {
            for ((s, v), m) in feat_std.iter_mut().zip(row).zip(&feat_mean) {
                *s += (v - m) * (v - m) / n;
            }
        }
        feat_std.iter_mut().for_each(|s| *s = if *s > 1e-24 { s.sqrt() } else { 1.0 });
        standardise(&mut x, &feat_mean, &feat_std);
        let pairs = labelled_valid(valid)?;
        let mut best: Option<(f64, Svm)> = None;
        for &c in &self.c_grid {
            for &g in &self.gamma_grid {
                let gamma = g / d as f64;
                let (support, coef, bias) = fit_svc(&x, &y, d, c, gamma, self)?;
                let mut det = Svm {
                    channels: channels.clone(),
                    window: self.window,
                    feat_mean: feat_mean.clone(),
                    feat_std: feat_std.clone(),
                    support,
                    coef,
                    bias,
                    gamma,
                    c,
                    threshold: 0.0,
                };
                let scores: Vec<Vec<f64>> =
                    pairs.iter().map(|(s, _)| det.decision(&det.standardised_features(s))).collect();
                let (threshold, f1) = detection_metrics::best_f1_threshold(
                    scores.iter().zip(&pairs).map(|(sc, (_, l))| (sc.as_slice(), *l)),
                )?;
                det.threshold = threshold;
                if best.as_ref().is_none_or(|(f, _)| f1 > *f) {
                    best = Some((f1, det));
                }
            }
        }
        best.map(|(_, d)| d).ok_or_else(|| BaselineError::Config { field: "c_grid", msg: "empty grid".into() })
    }
}

impl Detector for Svm {
    fn name(&self) -> &str {
        "SVM"
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        let scores = self.decision(&self.standardised_features(series));
        if scores.iter().any(|s| !s.is_finite()) {
            return Err(DetectError::Numerical { what: "non-finite SVM decision value".into() });
        }
        Ok(scores)
    }

    fn threshold(&self) -> f64 {
        self.threshold
    }

    /// The batch scores are causal already (features of the last `w` steps), so they are the
    /// streaming scores.
    fn score_streaming(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        self.score(series)
    }

    /// The features of a step use the last `w` steps only, so the default windowed online
    /// detector over `w` steps is exact.
    fn online_window(&self) -> usize {
        self.window
    }
}
