//! GLR drift test on the GPS innovation: the generalised likelihood ratio of a spoofed offset
//! that began within the last `M` fixes, constant or growing linearly from zero (Willsky &
//! Jones, "A generalized likelihood ratio approach to the detection and estimation of jumps in
//! linear systems", IEEE TAC 21(1), 1976; Basseville & Nikiforov, *Detection of Abrupt
//! Changes*, 1993, §2.4). It gathers the evidence of a slow drift over several fixes, where a
//! one-fix test (χ², PX4's gate) waits until the offset alone passes its gate.
//!
//! With `u_k = L_k⁻¹ ν_k` the GPS innovation whitened by the Cholesky factor of its covariance
//! block (`S_k = L_k L_kᵀ` over the `n` GPS channels) and `e_k = clip(u_k, ±c)` per axis
//! (Huber's ψ, *Robust Statistics*, 1981, so one sample of heavy-tailed noise moves the sums by
//! at most `c`):
//!
//! ```text
//! bias_k = max_{1≤m≤M} ‖Σ_{i<m} e_{k−i}‖² / m                    constant offset, onset m back
//! ramp_k = max_{1≤m≤M} ‖Σ_{i<m} (m − i) e_{k−i}‖² / Σ_{j≤m} j²   offset growing from zero
//! g_k    = max(‖u_k‖², bias_k, ramp_k)                            alarm iff g_k > h
//! ```
//!
//! Each term is twice the log-likelihood ratio of its offset model against none, maximised over
//! the offset (white unit-variance noise); the newest fix enters `‖u_k‖²` unclipped, so a gross
//! offset alarms at its first fix (the one-fix χ² test), while the sums over several fixes read
//! the clipped `e` and one heavy-tailed sample cannot hold them up.
//!
//! The sums and their end test (an ended offset leaves the memory, so an alarm does not outlast
//! its attack by up to `M` fixes) are [`ekf_residue::drift`]'s [`DriftMemory`].
//!
//! Validation setting: the window `M` from a grid and the threshold `h` maximising F1.
//! Textbook setting: `M` = 30 fixes and `h` the χ²_n quantile of `1 − far / (2M + 1)`, a union
//! bound over the `2M + 1` statistics of a step.
//!
//! Only the GPS channels (names starting with `gps_channel_prefix`) are read.

use ekf_residue::drift::DriftMemory;
use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, OnlineDecision, OnlineDetector, ResidueSeries, ResidueStep,
};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::common::{Tuning, fit_channels, gps_indices, labelled_valid};
use crate::error::{BaselineError, Result, step_dim_error};
use crate::stats::chi2_quantile;

/// Hyper-parameters of the GLR drift test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GlrConfig {
    /// Textbook or validation-chosen window and threshold. Default [`Tuning::ValidationF1`].
    pub tuning: Tuning,
    /// Longest onset looked back to, fixes, of the textbook setting. Default 30 (3 s at 10 Hz).
    pub window: usize,
    /// Validation grid of the window. Default `[10, 30, 100]` fixes (1, 3 and 10 s at 10 Hz).
    pub window_grid: Vec<usize>,
    /// Huber's clipping constant `c`, in standard deviations of the whitened innovation.
    /// Default 2.
    pub huber_c: f64,
    /// Design false-alarm rate per step of the textbook threshold. Default 0.01.
    pub far: f64,
    /// Prefix of the GPS channel names. Default `"gps_"` (the residue channel naming of
    /// `ekf_residue`).
    pub gps_channel_prefix: String,
}

impl Default for GlrConfig {
    fn default() -> Self {
        Self {
            tuning: Tuning::ValidationF1,
            window: 30,
            window_grid: vec![10, 30, 100],
            huber_c: 2.0,
            far: 0.01,
            gps_channel_prefix: "gps_".into(),
        }
    }
}

/// A fitted GLR drift test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Glr {
    channels: Vec<String>,
    gps_idx: Vec<usize>,
    window: usize,
    huber_c: f64,
    threshold: f64,
    tuning: Tuning,
}

impl crate::JsonState for Glr {
    fn check_state(&self) -> Result<()> {
        use crate::state::{check_channel_indices, check_channels, check_finite, state_err};
        check_channels(&self.channels)?;
        check_finite("huber_c, threshold", &[self.huber_c, self.threshold])?;
        if self.window == 0 || self.window > MAX_WINDOW {
            return Err(state_err(format!("window: {} is not in 1..={MAX_WINDOW}", self.window)));
        }
        if self.huber_c <= 0.0 {
            return Err(state_err(format!("huber_c: {} is not positive", self.huber_c)));
        }
        check_channel_indices("gps_idx", &self.gps_idx, self.channels.len())
    }
}

/// Longest window a configuration or a saved state may hold (10 min at 10 Hz), so a
/// hand-edited state cannot make a step's work unbounded.
const MAX_WINDOW: usize = 6_000;

impl Glr {
    /// The longest onset looked back to, fixes.
    pub fn window(&self) -> usize {
        self.window
    }

    /// Indices of the GPS channels read.
    pub fn gps_channels(&self) -> &[usize] {
        &self.gps_idx
    }
}

/// The recursion's memory over the GPS innovations.
#[derive(Debug, Clone)]
struct GlrState(DriftMemory);

impl GlrState {
    fn new(glr: &Glr, window: usize) -> Self {
        Self(DriftMemory::new(window, glr.gps_idx.len(), glr.huber_c))
    }

    /// Adds the step's innovation and returns `g_k`.
    fn step(&mut self, glr: &Glr, r_k: &[f64], s_k: &[f64]) -> f64 {
        let Some(u) = whitened(&glr.gps_idx, r_k, s_k) else {
            // A non-finite innovation or covariance alarms (as PX4 rejects a non-finite ratio)
            // and is not kept.
            return f64::INFINITY;
        };
        // The newest fix unclipped: a gross offset alarms at its first fix.
        let newest = u.norm_squared();
        newest.max(self.0.push(u.as_slice()))
    }
}

/// The GPS innovation of a step whitened by the Cholesky factor of its covariance block, or
/// `None` when the innovation or the block is not finite or the block not positive definite.
fn whitened(gps_idx: &[usize], r_k: &[f64], s_k: &[f64]) -> Option<DVector<f64>> {
    let m = r_k.len();
    let n = gps_idx.len();
    let nu = DVector::from_iterator(n, gps_idx.iter().map(|&i| r_k[i]));
    let s = DMatrix::from_fn(n, n, |a, b| s_k[gps_idx[a] * m + gps_idx[b]]);
    if !(nu.iter().all(|x| x.is_finite()) && s.iter().all(|x| x.is_finite())) {
        return None;
    }
    let l = s.cholesky()?;
    let u = l.l().solve_lower_triangular(&nu)?;
    u.iter().all(|x| x.is_finite()).then_some(u)
}

/// `g_k` of every step of `series`, looking back at most `window` fixes, from a fresh state.
fn glr_run(glr: &Glr, window: usize, series: &ResidueSeries, mut sink: impl FnMut(f64)) {
    let m = series.dim();
    let mut st = GlrState::new(glr, window);
    for (r_k, s_k) in series.r().chunks_exact(m).zip(series.s().chunks_exact(m * m)) {
        sink(st.step(glr, r_k, s_k));
    }
}

impl Fit for GlrConfig {
    type Detector = Glr;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Glr> {
        let bad_window = |w: usize| w == 0 || w > MAX_WINDOW;
        if bad_window(self.window) || self.window_grid.is_empty() || self.window_grid.iter().any(|&w| bad_window(w)) {
            return Err(BaselineError::Config {
                field: "window, window_grid",
                msg: format!("need windows in 1..={MAX_WINDOW}, got {} and {:?}", self.window, self.window_grid),
            });
        }
        if !(self.huber_c.is_finite() && self.huber_c > 0.0) {
            return Err(BaselineError::Config {
                field: "huber_c",
                msg: format!("must be positive, got {}", self.huber_c),
            });
        }
        if !(self.far > 0.0 && self.far < 1.0) {
            return Err(BaselineError::Config { field: "far", msg: format!("must lie in (0, 1), got {}", self.far) });
        }
        let channels = fit_channels(train, valid)?;
        let gps_idx = gps_indices(&channels, &self.gps_channel_prefix)?;
        let mut glr =
            Glr { channels, gps_idx, window: self.window, huber_c: self.huber_c, threshold: 0.0, tuning: self.tuning };
        match self.tuning {
            Tuning::Textbook => {
                #[allow(clippy::cast_precision_loss)]
                let (n, statistics) = (glr.gps_idx.len() as f64, (2 * self.window + 1) as f64);
                glr.threshold = chi2_quantile(n, 1.0 - self.far / statistics)?;
            }
            Tuning::ValidationF1 => {
                let pairs = labelled_valid(valid)?;
                let mut best: Option<(f64, usize, f64)> = None;
                for &window in &self.window_grid {
                    let scores: Vec<Vec<f64>> = pairs
                        .iter()
                        .map(|(s, _)| {
                            let mut out = Vec::with_capacity(s.len());
                            glr_run(&glr, window, s, |g| out.push(g));
                            out
                        })
                        .collect();
                    let (threshold, f1) = detection_metrics::best_f1_threshold(
                        scores.iter().zip(&pairs).map(|(s, (_, l))| (s.as_slice(), *l)),
                    )?;
                    if best.is_none_or(|(b, _, _)| f1 > b) {
                        best = Some((f1, window, threshold));
                    }
                }
                if let Some((_, window, threshold)) = best {
                    (glr.window, glr.threshold) = (window, threshold);
                }
            }
        }
        Ok(glr)
    }
}

impl Detector for Glr {
    fn name(&self) -> &str {
        match self.tuning {
            Tuning::Textbook => "GLR (1% FAR)",
            Tuning::ValidationF1 => "GLR",
        }
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        let mut out = Vec::with_capacity(series.len());
        glr_run(self, self.window, series, |g| out.push(g));
        Ok(out)
    }

    fn threshold(&self) -> f64 {
        self.threshold
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        Box::new(GlrOnline { glr: self, state: GlrState::new(self, self.window) })
    }
}

/// Streaming GLR drift test.
#[derive(Debug, Clone)]
pub struct GlrOnline<'a> {
    glr: &'a Glr,
    state: GlrState,
}

impl OnlineDetector for GlrOnline<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let m = self.glr.channels.len();
        if step.dim() != m || step.s_k.len() != m * m {
            return Err(step_dim_error(m, step.dim()));
        }
        let score = self.state.step(self.glr, step.r_k, step.s_k);
        Ok(OnlineDecision { score, alarm: score > self.glr.threshold })
    }

    fn reset(&mut self) {
        self.state.0.clear();
    }
}
