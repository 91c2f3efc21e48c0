//! Drift evidence in a whitened innovation sequence: the generalised likelihood ratio of an
//! offset that began within the last `M` steps, constant or growing linearly from zero (Willsky
//! & Jones, "A generalized likelihood ratio approach to the detection and estimation of jumps in
//! linear systems", IEEE TAC 21(1), 1976; Basseville & Nikiforov, *Detection of Abrupt
//! Changes*, 1993, §2.4). A spoofed position that drifts away slowly stays inside a one-step
//! gate for many steps; these sums gather its evidence over several.
//!
//! With `u_k` an innovation whitened so that it is `N(0, I_n)` on clean steps (e.g. `L_k⁻¹ ν_k`
//! with `S_k = L_k L_kᵀ`) and `e_k = clip(u_k, ±c)` per axis (Huber's ψ, *Robust Statistics*,
//! 1981, so one sample of heavy-tailed noise moves the sums by at most `c`):
//!
//! ```text
//! bias_k = max_{1≤m≤M} ‖Σ_{i<m} e_{k−i}‖² / m                    constant offset, onset m back
//! ramp_k = max_{1≤m≤M} ‖Σ_{i<m} (m − i) e_{k−i}‖² / Σ_{j≤m} j²   offset growing from zero
//! ```
//!
//! Each term is twice the log-likelihood ratio of its offset model against none, maximised over
//! the offset (white unit-variance noise). [`DriftMemory::push`] returns `max(bias_k, ramp_k)`.
//!
//! **End test:** when the sum of the newest [`END_STEPS`] innovations fits no offset and departs
//! from the mean level of the [`LEVEL_STEPS`] before them, both at the χ²_n 0.999 quantile, the
//! offset has ended and all but the newest [`END_STEPS`] innovations leave the memory, so later
//! sums start after the end; without it the evidence of an attack would outlast it by up to `M`
//! steps. An onset or a growing drift moves away from zero and does not count.
//!
//! Used by the GLR drift test (`baselines::Glr`, docs/decisions/093-glr-drift-test.md) and as
//! an input channel of the learning detectors (`nn_toolkit::Features::WhitenedLogDrift`).

use std::collections::VecDeque;

use nalgebra::DVector;

use crate::chi2::chi2_quantile;

/// Newest innovations the end test judges: one, so the evidence clears at the first step after
/// an attack; judging 2 or 3 kept alarms a fix or two past nearly every attack, each an alarm
/// event decision 060 counts as false (chosen on validation flights,
/// docs/decisions/093-glr-drift-test.md).
pub const END_STEPS: usize = 1;

/// Innovations before them whose mean is the offset's level.
pub const LEVEL_STEPS: usize = 10;

/// Quantile of χ²_n at which both halves of the end test reject.
const END_QUANTILE: f64 = 0.999;

/// The memory of the drift statistic: the newest whitened innovations `u` and their clipped
/// form `e`, newest last.
#[derive(Debug, Clone, PartialEq)]
pub struct DriftMemory {
    u: VecDeque<DVector<f64>>,
    e: VecDeque<DVector<f64>>,
    /// Longest onset looked back to, steps.
    window: usize,
    capacity: usize,
    /// Huber's clipping constant, in standard deviations.
    huber_c: f64,
    /// The χ²_n quantile of the end test.
    end_bound: f64,
}

impl DriftMemory {
    /// An empty memory for innovations of `n` channels, looking back at most `window` steps,
    /// clipping at `huber_c` standard deviations. With `n = 0` the end test never fires.
    pub fn new(window: usize, n: usize, huber_c: f64) -> Self {
        let window = window.max(1);
        let capacity = window.max(END_STEPS + LEVEL_STEPS);
        #[allow(clippy::cast_precision_loss)]
        let end_bound = chi2_quantile(n as f64, END_QUANTILE).unwrap_or(f64::INFINITY);
        let (u, e) = (VecDeque::with_capacity(capacity + 1), VecDeque::with_capacity(capacity + 1));
        Self { u, e, window, capacity, huber_c, end_bound }
    }

    /// Longest onset looked back to, steps.
    pub fn window(&self) -> usize {
        self.window
    }

    /// Forgets every innovation.
    pub fn clear(&mut self) {
        self.u.clear();
        self.e.clear();
    }

    /// Adds the newest whitened innovation `u` (finite, of the memory's `n` channels) and
    /// returns `max(bias_k, ramp_k)` of the module doc.
    pub fn push(&mut self, u: &[f64]) -> f64 {
        let u = DVector::from_column_slice(u);
        let e = u.map(|x| x.clamp(-self.huber_c, self.huber_c));
        if self.u.len() == self.capacity {
            self.u.pop_front();
            self.e.pop_front();
        }
        self.u.push_back(u);
        self.e.push_back(e);
        if self.ended() {
            // The ended offset's steps leave the memory: later onsets start after it.
            let stale = self.u.len() - END_STEPS;
            self.u.drain(..stale);
            self.e.drain(..stale);
        }
        let n = self.e.back().map_or(0, DVector::len);
        offset_glr(self.e.iter().rev().take(self.window), n)
    }

    /// The end test of the module doc on the newest innovations.
    fn ended(&self) -> bool {
        let len = self.u.len();
        if len < END_STEPS + LEVEL_STEPS {
            return false;
        }
        let sum_of =
            |range: std::ops::Range<usize>| self.u.range(range).fold(DVector::zeros(self.u[0].len()), |acc, u| acc + u);
        let newest = sum_of(len - END_STEPS..len);
        #[allow(clippy::cast_precision_loss)]
        let (r, n_level) = (END_STEPS as f64, LEVEL_STEPS as f64);
        let level = sum_of(len - END_STEPS - LEVEL_STEPS..len - END_STEPS) / n_level;
        // Per axis, the newest sum has variance r under no offset, and its departure from r
        // times the level r + r²/n_level under the level.
        let fits_zero = newest.norm_squared() / r <= self.end_bound;
        let leaves_level = (&newest - level * r).norm_squared() / (r + r * r / n_level) > self.end_bound;
        fits_zero && leaves_level
    }
}

/// `max(bias_k, ramp_k)` of the module doc over the clipped innovations `e`, newest first (as
/// many as the onsets looked back to), each of `n` channels.
pub fn offset_glr<'a>(newest_first: impl Iterator<Item = &'a DVector<f64>>, n: usize) -> f64 {
    let (mut best, mut sum, mut weighted, mut sq) = (0.0_f64, DVector::zeros(n), DVector::zeros(n), 0.0);
    for (m, e) in newest_first.enumerate() {
        // Onset m + 1 steps back: `weighted` = Σ (m + 1 − i) e_{k−i} grows by `sum`.
        sum += e;
        weighted += &sum;
        #[allow(clippy::cast_precision_loss)]
        let mf = (m + 1) as f64;
        sq += mf * mf;
        best = best.max(sum.norm_squared() / mf).max(weighted.norm_squared() / sq);
    }
    best
}

#[cfg(test)]
mod tests {
    use nalgebra::DVector;
    use proptest::prelude::*;

    use super::*;

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

    #[test]
    fn a_ramp_builds_evidence_and_its_end_clears_it() {
        // Clipping at 10 σ leaves these innovations whole.
        let mut mem = DriftMemory::new(30, 3, 10.0);
        let mut g = 0.0;
        // A drift of 0.3 σ per step on one axis, noise-free: after 30 steps the ramp term is
        // ‖Σ j · 0.3 j‖² / Σ j² = 0.09 Σ j² over j ≤ 30, about 851.
        for i in 1..=30 {
            g = mem.push(&[0.3 * f64::from(i), 0.0, 0.0]);
        }
        assert!((g - 0.09 * 9455.0).abs() < 1e-9, "{g}");
        // The offset ends: the newest innovation fits zero and leaves the level of 7.65 σ.
        let after = mem.push(&[0.0; 3]);
        assert!(after < 1e-12, "{after}");
    }
}
