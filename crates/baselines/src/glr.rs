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
//! **End test:** when the sum of the newest `END_FIXES` whitened innovations fits no offset and
//! departs from the mean level of the `LEVEL_FIXES` before them, both at the χ²_n 0.999
//! quantile, the offset has ended and all but the newest `END_FIXES` innovations leave the
//! memory, so later sums start after the end; without it an alarm would outlast its attack by
//! up to `M` fixes. An onset or a growing drift moves away from zero and does not count.
//!
//! Validation setting: the window `M` from a grid and the threshold `h` maximising F1.
//! Textbook setting: `M` = 30 fixes and `h` the χ²_n quantile of `1 − far / (2M + 1)`, a union
//! bound over the `2M + 1` statistics of a step.
//!
//! Only the GPS channels (names starting with `gps_channel_prefix`) are read.

use std::collections::VecDeque;

use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, OnlineDecision, OnlineDetector, ResidueSeries, ResidueStep,
};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::common::{Tuning, fit_channels, gps_indices, labelled_valid};
use crate::error::{BaselineError, Result, step_dim_error};
use crate::stats::chi2_quantile;

/// Newest innovations the end test judges: one, so an alarm clears at the first fix after its
/// attack; judging 2 or 3 kept alarms a fix or two past nearly every attack, each an alarm
/// event decision 060 counts as false (chosen on validation flights,
/// docs/decisions/093-glr-drift-test.md).
const END_FIXES: usize = 1;

/// Innovations before them whose mean is the offset's level.
const LEVEL_FIXES: usize = 10;

/// Quantile of χ²_n at which both halves of the end test reject.
const END_QUANTILE: f64 = 0.999;

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

/// The recursion's memory: the newest whitened innovations `u` and their clipped form `e`,
/// newest last.
#[derive(Debug, Clone)]
struct GlrState {
    u: VecDeque<DVector<f64>>,
    e: VecDeque<DVector<f64>>,
    /// Longest onset looked back to, fixes.
    window: usize,
    capacity: usize,
    /// The χ²_n quantile of the end test.
    end_bound: f64,
}

impl GlrState {
    fn new(window: usize, n_gps: usize) -> Self {
        let capacity = window.max(END_FIXES + LEVEL_FIXES);
        // `n_gps ≥ 1` (checked on fit and load), so the quantile exists; without it the end
        // test would never fire.
        #[allow(clippy::cast_precision_loss)]
        let end_bound = chi2_quantile(n_gps as f64, END_QUANTILE).unwrap_or(f64::INFINITY);
        let (u, e) = (VecDeque::with_capacity(capacity + 1), VecDeque::with_capacity(capacity + 1));
        Self { u, e, window, capacity, end_bound }
    }

    /// Adds the step's innovation and returns `g_k`.
    fn step(&mut self, glr: &Glr, r_k: &[f64], s_k: &[f64]) -> f64 {
        let Some(u) = whitened(&glr.gps_idx, r_k, s_k) else {
            // A non-finite innovation or covariance alarms (as PX4 rejects a non-finite ratio)
            // and is not kept.
            return f64::INFINITY;
        };
        let e = u.map(|x| x.clamp(-glr.huber_c, glr.huber_c));
        if self.u.len() == self.capacity {
            self.u.pop_front();
            self.e.pop_front();
        }
        self.u.push_back(u);
        self.e.push_back(e);
        if self.ended() {
            // The ended offset's fixes leave the memory: later onsets start after it.
            let stale = self.u.len() - END_FIXES;
            self.u.drain(..stale);
            self.e.drain(..stale);
        }
        // The newest fix unclipped: a gross offset alarms at its first fix.
        let newest = self.u.back().map_or(0.0, DVector::norm_squared);
        newest.max(offset_glr(self.e.iter().rev().take(self.window), glr.gps_idx.len()))
    }

    /// The end test of the module doc on the newest innovations.
    fn ended(&self) -> bool {
        let len = self.u.len();
        if len < END_FIXES + LEVEL_FIXES {
            return false;
        }
        let sum_of =
            |range: std::ops::Range<usize>| self.u.range(range).fold(DVector::zeros(self.u[0].len()), |acc, u| acc + u);
        let newest = sum_of(len - END_FIXES..len);
        #[allow(clippy::cast_precision_loss)]
        let (r, n_level) = (END_FIXES as f64, LEVEL_FIXES as f64);
        let level = sum_of(len - END_FIXES - LEVEL_FIXES..len - END_FIXES) / n_level;
        // Per axis, the newest sum has variance r under no offset, and its departure from r
        // times the level r + r²/n_level under the level.
        let fits_zero = newest.norm_squared() / r <= self.end_bound;
        let leaves_level = (&newest - level * r).norm_squared() / (r + r * r / n_level) > self.end_bound;
        fits_zero && leaves_level
    }
}

/// `max(bias_k, ramp_k)` of the module doc over the innovations `e`, newest first (as many as
/// the onsets looked back to), each of `n` channels.
fn offset_glr<'a>(newest_first: impl Iterator<Item = &'a DVector<f64>>, n: usize) -> f64 {
    let (mut best, mut sum, mut weighted, mut sq) = (0.0_f64, DVector::zeros(n), DVector::zeros(n), 0.0);
    for (m, e) in newest_first.enumerate() {
        // Onset m + 1 fixes back: `weighted` = Σ (m + 1 − i) e_{k−i} grows by `sum`.
        sum += e;
        weighted += &sum;
        #[allow(clippy::cast_precision_loss)]
        let mf = (m + 1) as f64;
        sq += mf * mf;
        best = best.max(sum.norm_squared() / mf).max(weighted.norm_squared() / sq);
    }
    best
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
    let mut st = GlrState::new(window, glr.gps_idx.len());
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
        Box::new(GlrOnline { glr: self, state: GlrState::new(self.window, self.gps_idx.len()) })
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
        self.state = GlrState::new(self.glr.window, self.glr.gps_idx.len());
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::DVector;
    use proptest::prelude::*;

    use super::offset_glr;

    /// `max(bias_k, ramp_k)` written out: for every onset `m`, the least-squares offset of
    /// each model and twice its log-likelihood ratio against none, `‖Σ a_i e_i‖² / Σ a_i²`
    /// with the regressor `a_i = 1` (constant) or `a_i = m − i` (ramp from zero).
    fn brute_force(e: &[DVector<f64>]) -> f64 {
        let mut best = 0.0_f64;
        for m in 1..=e.len() {
            for ramp in [false, true] {
                let a = |i: usize| if ramp { (m - i) as f64 } else { 1.0 };
                let num = (0..m).fold(DVector::zeros(e[0].len()), |acc, i| acc + &e[i] * a(i));
                let den: f64 = (0..m).map(|i| a(i) * a(i)).sum();
                best = best.max(num.norm_squared() / den);
            }
        }
        best
    }

    proptest! {
        /// The recursion equals the two likelihood ratios written out, over every onset.
        #[test]
        fn the_recursion_is_the_likelihood_ratio_over_every_onset(
            values in prop::collection::vec(-5.0_f64..5.0, 3..=90),
        ) {
            let e: Vec<DVector<f64>> = values.chunks_exact(3).map(DVector::from_column_slice).collect();
            let fast = offset_glr(e.iter(), 3);
            let slow = brute_force(&e);
            prop_assert!((fast - slow).abs() <= 1e-9 * slow.max(1.0), "{fast} vs {slow}");
        }
    }
}
