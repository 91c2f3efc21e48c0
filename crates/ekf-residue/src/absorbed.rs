//! The offset a filter has absorbed, remembered as sums of its whitened innovations over long
//! horizons.
//!
//! A filter that fuses a spoofed constant offset moves its estimate onto it within a few
//! updates: the innovations answer the onset with a short spike along the offset and are
//! white again afterwards, and the end of the attack with the opposite spike (Model I absorbs
//! a 10 m step in about 2 s). In a window of a few seconds an onset and an end look alike, and
//! the middle of a long attack looks clean. The filter is linear about its estimate, so the
//! two spikes cancel in a sum over a horizon that holds both, while a sum over a horizon that
//! holds the onset alone keeps the offset's signature:
//!
//! ```text
//! a_k(H) = ‖ Σ_{i<min(H, k+1)} u_{k−i} ‖ / √min(H, k+1)
//! ```
//!
//! With `u_k` white `N(0, I_n)` on clean steps (e.g. `L_k⁻¹ ν_k` with `S_k = L_k L_kᵀ`),
//! `a_k(H)` is χ_n-distributed whatever the horizon: about 1.6 for `n = 3`. An attacked onset
//! within the last `H` steps raises it; an attack that ended within them (with its onset)
//! does not. A slow drift that the filter follows with a lag adds up in it as well. Several
//! horizons tell an attack that began a few seconds ago from one that began tens of seconds
//! ago. Unlike the GLR sums of [`crate::drift`], the innovations are not clipped: the size of
//! the onset's spike is the information.
//!
//! Used as input channels of the learning detectors
//! (`nn_toolkit::Features::WhitenedLogDriftAbsorbed`, docs/decisions/095-absorbed-offset-channels.md).

use std::collections::VecDeque;

/// The sums of the newest whitened innovations over each of several horizons.
#[derive(Debug, Clone, PartialEq)]
pub struct AbsorbedSums {
    /// Horizons, steps (each at least 1).
    horizons: Vec<usize>,
    /// The longest horizon: how many innovations are kept.
    longest: usize,
    /// Channels of an innovation.
    n: usize,
    /// The kept innovations, `n` values each, newest last.
    history: VecDeque<f64>,
    /// `Σ` over each horizon's newest innovations, per channel.
    sums: Vec<Vec<f64>>,
}

impl AbsorbedSums {
    /// An empty memory for innovations of `n` channels and sums over each of `horizons` steps
    /// (a horizon of 0 counts as 1).
    pub fn new(horizons: &[usize], n: usize) -> Self {
        let horizons: Vec<usize> = horizons.iter().map(|&h| h.max(1)).collect();
        let longest = horizons.iter().copied().max().unwrap_or(1);
        Self {
            sums: vec![vec![0.0; n]; horizons.len()],
            history: VecDeque::with_capacity((longest + 1) * n),
            horizons,
            longest,
            n,
        }
    }

    /// Forgets every innovation.
    pub fn clear(&mut self) {
        self.history.clear();
        for s in &mut self.sums {
            s.fill(0.0);
        }
    }

    /// Number of innovations kept (0 for innovations of no channel, whose sums stay 0).
    fn kept(&self) -> usize {
        self.history.len().checked_div(self.n).unwrap_or(0)
    }

    /// Adds the newest innovation `u` (its first `n` values, missing ones read 0; a non-finite
    /// one is not kept) and writes `a_k(H)` of the module doc for each horizon into `out` (as
    /// many as both hold). Before any innovation is kept every `a_k` reads 0.
    pub fn push(&mut self, u: &[f64], out: &mut [f64]) {
        let n = self.n;
        let value = |i: usize| u.get(i).copied().unwrap_or(0.0);
        if (0..n).all(|i| value(i).is_finite()) {
            self.history.extend((0..n).map(value));
            let kept = self.kept();
            for (&h, sum) in self.horizons.iter().zip(&mut self.sums) {
                // The innovation that leaves this horizon, if any.
                let leaving = kept.checked_sub(h + 1);
                for (i, s) in sum.iter_mut().enumerate() {
                    *s += self.history[(kept - 1) * n + i] - leaving.map_or(0.0, |j| self.history[j * n + i]);
                }
            }
            if kept > self.longest {
                self.history.drain(..n);
            }
        }
        let kept = self.kept();
        for ((&h, sum), o) in self.horizons.iter().zip(&self.sums).zip(out.iter_mut()) {
            let count = h.min(kept);
            #[allow(clippy::cast_precision_loss)]
            let norm = sum.iter().map(|s| s * s).sum::<f64>().sqrt();
            *o = if count == 0 { 0.0 } else { norm / (count as f64).sqrt() };
        }
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// `a_k(H)` computed from scratch over the kept innovations.
    fn direct(history: &[Vec<f64>], h: usize) -> f64 {
        let take = h.min(history.len());
        if take == 0 {
            return 0.0;
        }
        let n = history[0].len();
        let sum: Vec<f64> = (0..n).map(|i| history[history.len() - take..].iter().map(|u| u[i]).sum::<f64>()).collect();
        sum.iter().map(|s| s * s).sum::<f64>().sqrt() / (take as f64).sqrt()
    }

    proptest! {
        /// The running sums equal the sums over each horizon's newest innovations.
        #[test]
        fn running_sums_equal_direct_sums(
            steps in prop::collection::vec(prop::collection::vec(-50.0f64..50.0, 2), 1..60),
            h in prop::collection::vec(1usize..20, 1..4),
        ) {
            let mut sums = AbsorbedSums::new(&h, 2);
            let mut out = vec![0.0; h.len()];
            for (k, u) in steps.iter().enumerate() {
                sums.push(u, &mut out);
                for (j, &hj) in h.iter().enumerate() {
                    let want = direct(&steps[..=k], hj);
                    prop_assert!((out[j] - want).abs() <= 1e-9 * (1.0 + want), "{} vs {want}", out[j]);
                }
            }
        }
    }

    /// An onset spike is remembered over a horizon that holds it, and cancelled by the
    /// opposite spike of the end once the horizon holds both.
    #[test]
    fn an_onset_is_remembered_until_its_end_cancels_it() {
        let mut sums = AbsorbedSums::new(&[5, 50], 1);
        let mut out = [0.0; 2];
        let spike = |k: usize| match k {
            10 => 20.0,
            30 => -20.0,
            _ => 0.0,
        };
        let mut seen = Vec::new();
        for k in 0..40 {
            sums.push(&[spike(k)], &mut out);
            seen.push(out);
        }
        // The short horizon forgets the onset after 5 steps; the long one holds it.
        assert!(seen[12][0] > 5.0 && seen[16][0] == 0.0, "{seen:?}");
        assert!(seen[29][1] > 3.0, "{seen:?}");
        // The end cancels it in the long horizon.
        assert!(seen[30][1].abs() < 1e-12, "{seen:?}");
    }

    /// Non-finite innovations are skipped; a cleared memory starts again.
    #[test]
    fn non_finite_innovations_are_skipped_and_clear_forgets() {
        let mut sums = AbsorbedSums::new(&[3], 2);
        let mut out = [0.0];
        sums.push(&[f64::NAN, 1.0], &mut out);
        assert_eq!(out[0], 0.0);
        sums.push(&[3.0, 4.0], &mut out);
        assert!((out[0] - 5.0).abs() < 1e-12);
        sums.clear();
        sums.push(&[0.0, 0.0], &mut out);
        assert_eq!(out[0], 0.0);
    }
}
