//! Offline smoothing of per-step scores: the centred moving mean of a windowed detector's
//! scores, and the choice of its half-width together with the alarm threshold on the
//! validation split (docs/decisions/048-score-smoothing.md).
//!
//! A step's smoothed score is the mean of the scores within `h` steps on either side, so a
//! detector that sees an attack's onset and end but not its middle (a persistent offset the
//! filter has absorbed) can still mark the steps between them. Smoothing of this kind is the
//! usual last stage of windowed anomaly detectors (Hundman et al., "Detecting Spacecraft
//! Anomalies Using LSTMs and Nonparametric Dynamic Thresholding", KDD 2018, smooth their
//! prediction errors before thresholding). It looks `h` steps ahead, so it belongs to the
//! offline score only; a streaming detector cannot use it.

use crate::Result;
use crate::confusion::best_f1_threshold;

/// Half-widths a detector with windows of `window_len` steps tries: none, a quarter, half and
/// one whole window, without repeats (ascending).
pub fn half_widths(window_len: usize) -> Vec<usize> {
    let mut h: Vec<usize> = [0, window_len / 4, window_len / 2, window_len].to_vec();
    h.dedup();
    h
}

/// The centred moving mean of `scores`: step `i` becomes the mean of steps `i − h ..= i + h`
/// that exist (fewer at the ends). `h = 0` returns the scores unchanged.
pub fn centred_mean(scores: &[f64], half_width: usize) -> Vec<f64> {
    if half_width == 0 {
        return scores.to_vec();
    }
    let n = scores.len();
    let mut prefix = Vec::with_capacity(n + 1);
    prefix.push(0.0);
    let mut sum = 0.0;
    for &s in scores {
        sum += s;
        prefix.push(sum);
    }
    (0..n)
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(half_width), i.saturating_add(half_width).saturating_add(1).min(n));
            #[allow(clippy::cast_precision_loss)] // window lengths far below 2^52
            let len = (hi - lo) as f64;
            (prefix[hi] - prefix[lo]) / len
        })
        .collect()
}

/// A smoothing half-width with the F1-maximising threshold of the smoothed scores.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Smoothing {
    /// Half-width `h` of [`centred_mean`], steps.
    pub half_width: usize,
    /// Alarm threshold on the smoothed scores.
    pub threshold: f64,
    /// Per-step F1 at that threshold.
    pub f1: f64,
}

/// The half-width among `half_widths` (tried in order; the first of equal F1 wins; none given
/// means no smoothing) and the threshold that together maximise the per-step F1 of the
/// smoothed scores of `flights` (`(scores, labels)`, one pair per flight, each smoothed on its
/// own).
///
/// # Errors
/// As [`best_f1_threshold`].
pub fn best_f1_smoothing(flights: &[(&[f64], &[bool])], half_widths: &[usize]) -> Result<Smoothing> {
    let score = |half_width: usize| -> Result<Smoothing> {
        let smoothed: Vec<Vec<f64>> = flights.iter().map(|(s, _)| centred_mean(s, half_width)).collect();
        let (threshold, f1) = best_f1_threshold(smoothed.iter().zip(flights).map(|(s, (_, l))| (s.as_slice(), *l)))?;
        Ok(Smoothing { half_width, threshold, f1 })
    };
    let (first, rest) = half_widths.split_first().unwrap_or((&0, &[]));
    let mut best = score(*first)?;
    for &half_width in rest {
        let candidate = score(half_width)?;
        if candidate.f1 > best.f1 {
            best = candidate;
        }
    }
    Ok(best)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn centred_mean_by_hand() {
        let s = [0.0, 3.0, 6.0, 3.0, 0.0];
        assert_eq!(centred_mean(&s, 0), s.to_vec());
        assert_eq!(centred_mean(&s, 1), vec![1.5, 3.0, 4.0, 3.0, 1.5]);
        assert_eq!(centred_mean(&s, 10), vec![2.4; 5]);
        assert!(centred_mean(&[], 3).is_empty());
        assert_eq!(centred_mean(&[2.0], usize::MAX), vec![2.0]);
    }

    #[test]
    fn half_widths_scale_with_the_window() {
        assert_eq!(half_widths(100), vec![0, 25, 50, 100]);
        assert_eq!(half_widths(2), vec![0, 1, 2]);
        assert_eq!(half_widths(0), vec![0]);
    }

    /// An attack whose middle scores low (its onset and end score high) is recovered by a
    /// half-width that spans the gap; a detector already perfect keeps `h = 0`.
    #[test]
    fn smoothing_bridges_an_interval_and_is_not_forced() {
        let labels: Vec<bool> = (0..200).map(|k| (50..110).contains(&k)).collect();
        let gappy: Vec<f64> =
            (0..200).map(|k| if (50..60).contains(&k) || (100..110).contains(&k) { 1.0 } else { 0.0 }).collect();
        let s = best_f1_smoothing(&[(&gappy, &labels)], &[0, 5, 20]).unwrap();
        assert_eq!(s.half_width, 20);
        assert!(s.f1 >= 0.75, "{s:?}"); // unsmoothed: recall 1/3, F1 0.5
        let exact: Vec<f64> = labels.iter().map(|&a| f64::from(u8::from(a))).collect();
        let s = best_f1_smoothing(&[(&exact, &labels)], &[0, 5, 20]).unwrap();
        assert_eq!((s.half_width, s.f1), (0, 1.0));
        assert_eq!(best_f1_smoothing(&[(&gappy, &labels)], &[]).unwrap().half_width, 0);
    }

    proptest! {
        /// The smoothed score is a mean: within the range of the scores, and unchanged on a
        /// constant series.
        #[test]
        fn centred_mean_stays_in_range(s in prop::collection::vec(-1e3f64..1e3, 1..60), h in 0usize..80) {
            let m = centred_mean(&s, h);
            prop_assert_eq!(m.len(), s.len());
            let (lo, hi) = s.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            for v in &m {
                prop_assert!(*v >= lo - 1e-9 && *v <= hi + 1e-9);
            }
            let c = centred_mean(&vec![s[0]; s.len()], h);
            for v in c {
                prop_assert!((v - s[0]).abs() <= 1e-9 * s[0].abs().max(1.0));
            }
        }
    }
}
