//! The detector interface every residue consumer implements, and the shared validation-split
//! threshold choice (docs/decisions/002-residue-series-and-detector-traits.md).
//!
//! Training is split from scoring in linfa's style: a [`Fit`] value holds hyper-parameters and
//! turns a training and a validation split into a fitted [`Detector`]; only fitted detectors can
//! score. A detector's decision threshold is chosen on the validation split inside `fit`, never
//! on test data (docs/decisions/001-validation-split-labels.md).

use crate::error::DetectError;
use crate::series::{LabelledResidues, ResidueSeries, ResidueStep};

/// Anything that turns residues into per-step anomaly scores (higher = more anomalous) and
/// alarms.
pub trait Detector: Send + Sync {
    /// Stable short name used in tables, e.g. `"CUSUM"`, `"QUADFormer"`.
    fn name(&self) -> &str;

    /// The channels this detector was fitted on, in order.
    fn channels(&self) -> &[String];

    /// One score per residue step; `scores.len() == series.len()`.
    ///
    /// # Errors
    /// [`DetectError::ChannelMismatch`] if `series` has other channels than the fit data.
    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError>;

    /// The decision threshold chosen on the validation split: a step alarms when its score is
    /// strictly above it.
    fn threshold(&self) -> f64;

    /// Per-step alarms at the fitted threshold.
    ///
    /// # Errors
    /// As [`Detector::score`].
    fn detect(&self, series: &ResidueSeries) -> Result<Vec<bool>, DetectError> {
        let threshold = self.threshold();
        Ok(self.score(series)?.into_iter().map(|s| s > threshold).collect())
    }

    /// The threshold of the streaming detector ([`Detector::online`]): a step alarms when its
    /// streaming score is strictly above it. Detectors whose streaming score differs from the
    /// batch one (a window that sees past and future against one that ends at the step) choose
    /// it on the validation split's streaming scores; the default is [`Detector::threshold`].
    fn streaming_threshold(&self) -> f64 {
        self.threshold()
    }

    /// The scores [`Detector::online`] gives when fed every step of `series` in order from a
    /// fresh start: step `k` scored from steps `0..=k` alone. The default runs the online
    /// detector; detectors with a faster exact route override it.
    ///
    /// # Errors
    /// As [`OnlineDetector::update`].
    fn score_streaming(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        check_channels(self.channels(), series)?;
        let mut online = self.online();
        series.steps().map(|step| online.update(&step).map(|d| d.score)).collect()
    }

    /// A streaming version of this detector for closed-loop use (`resilient-fusion`).
    ///
    /// The default re-scores a sliding window of the last [`Detector::online_window`] steps at
    /// every update, which is exact for detectors whose score depends only on that window;
    /// stateful detectors override it with a true recursion.
    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        Box::new(WindowedOnline::new(self, self.online_window()))
    }

    /// Number of past steps the default [`Detector::online`] keeps. Default 100 (the paper's
    /// window length `l`, sec:attack_detector).
    fn online_window(&self) -> usize {
        100
    }
}

/// Checks that `series` has the channels a detector was fitted on.
///
/// # Errors
/// [`DetectError::ChannelMismatch`] naming both channel lists.
pub fn check_channels(expected: &[String], series: &ResidueSeries) -> Result<(), DetectError> {
    if expected == series.channels() {
        Ok(())
    } else {
        Err(DetectError::ChannelMismatch { expected: expected.to_vec(), got: series.channels().to_vec() })
    }
}

/// Hyper-parameters that can be trained into a [`Detector`].
pub trait Fit {
    /// The fitted detector.
    type Detector: Detector;
    /// Error of fitting.
    type Error: std::error::Error + From<DetectError>;

    /// Fits on `train` (labels only where known) and chooses the threshold on `valid`.
    ///
    /// # Errors
    /// Implementation-specific; unusable data is [`DetectError::Data`].
    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Self::Detector, Self::Error>;
}

/// A detector that consumes one residue step at a time and answers with an alarm.
pub trait OnlineDetector: Send {
    /// Feeds one step; returns its score and whether it alarms.
    ///
    /// # Errors
    /// [`DetectError`] on a channel-dimension mismatch or a numerical failure.
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError>;

    /// Forgets all history.
    fn reset(&mut self);
}

/// What an [`OnlineDetector`] says about one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OnlineDecision {
    /// The anomaly score of the step.
    pub score: f64,
    /// Whether the score is above the fitted threshold.
    pub alarm: bool,
}

/// Streaming adapter that re-scores a sliding window of recent steps with a batch
/// [`Detector`] and reports the newest step.
pub struct WindowedOnline<'a, D: Detector + ?Sized> {
    detector: &'a D,
    window: usize,
    t: std::collections::VecDeque<f64>,
    r: std::collections::VecDeque<Vec<f64>>,
    s: std::collections::VecDeque<Vec<f64>>,
}

impl<'a, D: Detector + ?Sized> WindowedOnline<'a, D> {
    /// Wraps `detector`, keeping at most `window` (at least 1) past steps.
    pub fn new(detector: &'a D, window: usize) -> Self {
        Self { detector, window: window.max(1), t: Default::default(), r: Default::default(), s: Default::default() }
    }
}

impl<D: Detector + ?Sized> OnlineDetector for WindowedOnline<'_, D> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        if self.t.len() == self.window {
            self.t.pop_front();
            self.r.pop_front();
            self.s.pop_front();
        }
        self.t.push_back(step.t);
        self.r.push_back(step.r_k.to_vec());
        self.s.push_back(step.s_k.to_vec());
        let series = ResidueSeries::from_flat(
            self.t.iter().copied().collect(),
            self.detector.channels().to_vec(),
            self.r.iter().flatten().copied().collect(),
            self.s.iter().flatten().copied().collect(),
        );
        let series = match series {
            Ok(s) => s,
            Err(e) => {
                // Drop the offending step so that one bad sample does not poison the window.
                self.t.pop_back();
                self.r.pop_back();
                self.s.pop_back();
                return Err(e.into());
            }
        };
        let scores = self.detector.score(&series)?;
        let score =
            scores.last().copied().ok_or_else(|| DetectError::Numerical { what: "empty score window".into() })?;
        Ok(OnlineDecision { score, alarm: score > self.detector.streaming_threshold() })
    }

    fn reset(&mut self) {
        self.t.clear();
        self.r.clear();
        self.s.clear();
    }
}

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
/// [`DetectError::Data`] when there are no labelled steps or no attacked step;
/// [`DetectError::Numerical`] when a score is NaN.
pub fn best_f1_threshold<'a>(
    pairs: impl IntoIterator<Item = (&'a [f64], &'a [bool])>,
) -> Result<(f64, f64), DetectError> {
    let mut points: Vec<(f64, bool)> = Vec::new();
    for (scores, labels) in pairs {
        points.extend(scores.iter().copied().zip(labels.iter().copied()));
    }
    if points.iter().any(|(s, _)| s.is_nan()) {
        return Err(DetectError::Numerical { what: "NaN score during threshold search".into() });
    }
    let n_pos = points.iter().filter(|(_, l)| *l).count() as u64;
    if points.is_empty() || n_pos == 0 {
        return Err(DetectError::Data { msg: "threshold search needs labelled steps with at least one attack".into() });
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
        assert!(matches!(best_f1_threshold([(&scores[..], &[false; 3][..])]), Err(DetectError::Data { .. })));
    }
}
