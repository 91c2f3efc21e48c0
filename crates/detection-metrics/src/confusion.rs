//! Per-step confusion counts (paper Eqs. of precision, recall and F1) and the threshold search
//! every detector's `fit` uses: the threshold that maximises per-step F1 on validation.

use crate::evaluation::{MetricsError, Result};

/// Confusion counts of per-step alarms against labels (no point adjustment).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Confusion {
    /// Attacked steps that alarmed.
    pub tp: u64,
    /// Clean steps that alarmed.
    pub fp: u64,
    /// Attacked steps that did not alarm.
    pub fn_: u64,
    /// Clean steps that did not alarm.
    pub tn: u64,
}

impl Confusion {
    /// Counts alarms against labels over the common prefix of both slices.
    pub fn count(alarms: &[bool], labels: &[bool]) -> Self {
        let mut c = Self::default();
        for (&a, &l) in alarms.iter().zip(labels) {
            match (a, l) {
                (true, true) => c.tp += 1,
                (true, false) => c.fp += 1,
                (false, true) => c.fn_ += 1,
                (false, false) => c.tn += 1,
            }
        }
        c
    }

    /// Adds another count.
    pub fn add(&mut self, other: Self) {
        self.tp += other.tp;
        self.fp += other.fp;
        self.fn_ += other.fn_;
        self.tn += other.tn;
    }

    /// Precision `TP / (TP + FP)` (paper eq:precision); 0 when nothing alarmed.
    pub fn precision(&self) -> f64 {
        ratio(self.tp, self.tp + self.fp)
    }

    /// Recall `TP / (TP + FN)` (paper eq:recall); 0 when nothing was attacked.
    pub fn recall(&self) -> f64 {
        ratio(self.tp, self.tp + self.fn_)
    }

    /// F1, the harmonic mean of precision and recall (paper eq:F1); 0 when either is 0.
    pub fn f1(&self) -> f64 {
        ratio(2 * self.tp, 2 * self.tp + self.fp + self.fn_)
    }
}

#[allow(clippy::cast_precision_loss)] // counts far below 2^52
fn ratio(num: u64, den: u64) -> f64 {
    if den == 0 { 0.0 } else { num as f64 / den as f64 }
}

/// The threshold that maximises per-step F1 of `score > threshold` over the given
/// `(scores, labels)` pairs (one pair per flight), and that F1.
///
/// Candidates are midpoints between consecutive distinct scores, so the threshold generalises
/// between the observed values; one sort, `O(n log n)`.
///
/// # Errors
/// [`MetricsError::NonFinite`] naming the pair and step of a NaN score;
/// [`MetricsError::MissingClass`] when there are no labelled steps or no attacked step.
pub fn best_f1_threshold<'a>(pairs: impl IntoIterator<Item = (&'a [f64], &'a [bool])>) -> Result<(f64, f64)> {
    let mut points: Vec<(f64, bool)> = Vec::new();
    for (flight_idx, (scores, labels)) in pairs.into_iter().enumerate() {
        if let Some(step_idx) = scores.iter().zip(labels).position(|(s, _)| s.is_nan()) {
            return Err(MetricsError::NonFinite { flight_idx, step_idx, what: "score (threshold search)" });
        }
        points.extend(scores.iter().copied().zip(labels.iter().copied()));
    }
    let n_pos = points.iter().filter(|(_, l)| *l).count() as u64;
    if points.is_empty() || n_pos == 0 {
        #[allow(clippy::cast_possible_truncation)] // step counts fit in usize
        return Err(MetricsError::MissingClass {
            metric: "the F1-maximising threshold",
            n_attacked: 0,
            n_clean: points.len(),
        });
    }
    // Descending by score: alarming the first `i` points is the threshold just below point i-1.
    points.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (mut tp, mut fp) = (0u64, 0u64);
    // Start with "nothing alarms": threshold above the maximum.
    let mut best = (points[0].0 + 1.0_f64.max(points[0].0.abs() * 1e-9), 0.0);
    let mut i = 0;
    while i < points.len() {
        let s = points[i].0;
        while i < points.len() && points[i].0 == s {
            if points[i].1 {
                tp += 1
            } else {
                fp += 1
            }
            i += 1;
        }
        let f1 = ratio(2 * tp, 2 * tp + fp + (n_pos - tp));
        if f1 > best.1 {
            let next = points.get(i).map_or(s - 1.0_f64.max(s.abs() * 1e-9), |p| p.0);
            best = (0.5 * (s + next), f1);
        }
    }
    Ok(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn confusion_metrics_by_hand() {
        let c = Confusion::count(&[true, true, false, false, true], &[true, false, true, false, true]);
        assert_eq!(c, Confusion { tp: 2, fp: 1, fn_: 1, tn: 1 });
        assert!((c.precision() - 2.0 / 3.0).abs() < 1e-15);
        assert!((c.recall() - 2.0 / 3.0).abs() < 1e-15);
        assert!((c.f1() - 2.0 / 3.0).abs() < 1e-15);
        assert_eq!(Confusion::default().f1(), 0.0);
    }

    #[test]
    fn best_threshold_separates_perfectly() {
        let scores = [0.1, 0.2, 0.9, 0.8, 0.3];
        let labels = [false, false, true, true, false];
        let (th, f1) = best_f1_threshold([(&scores[..], &labels[..])]).unwrap();
        assert_eq!(f1, 1.0);
        assert!(th > 0.3 && th < 0.8, "{th}");
    }

    #[test]
    fn best_threshold_handles_ties_and_errors() {
        let scores = [1.0, 1.0, 1.0];
        let labels = [true, false, false];
        let (th, f1) = best_f1_threshold([(&scores[..], &labels[..])]).unwrap();
        assert!((f1 - 0.5).abs() < 1e-12);
        assert!(th < 1.0);
        assert!(matches!(best_f1_threshold([(&scores[..], &[false; 3][..])]), Err(MetricsError::MissingClass { .. })));
        let nan = [0.5, f64::NAN];
        assert!(matches!(
            best_f1_threshold([(&scores[..], &labels[..]), (&nan[..], &[true, false][..])]),
            Err(MetricsError::NonFinite { flight_idx: 1, step_idx: 1, .. })
        ));
    }
}
