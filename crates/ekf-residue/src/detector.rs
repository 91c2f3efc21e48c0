//! The detector interface every residue consumer implements, and the shared validation-split
//! threshold choice (docs/decisions/002-residue-series-and-detector-traits.md).
//!
//! Training is split from scoring in linfa's style: a [`Fit`] value holds hyper-parameters and
//! turns a training and a validation split into a fitted [`Detector`]; only fitted detectors can
//! score. A detector's decision threshold is chosen on the validation split inside `fit`, never
//! on test data (docs/decisions/001-validation-split-labels.md).

use std::collections::VecDeque;

use crate::error::DetectError;
use crate::series::{LabelledResidues, ResidueSeries, ResidueStep, checked_step_nis};

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

    /// The streaming form alarming at `threshold` of its score instead of the fitted one (the
    /// closed loop picks its own threshold). The default keeps [`Detector::online`] and
    /// re-thresholds its score ([`Rethresholded`]), which is exact for detectors without
    /// state that depends on the threshold; a detector whose recursion restarts at its alarm
    /// (CUSUM, SPRT) overrides it so that it restarts at `threshold`.
    fn online_at(&self, threshold: f64) -> Box<dyn OnlineDetector + '_> {
        Box::new(Rethresholded { inner: self.online(), threshold })
    }

    /// The score of the last step of `series`: what [`WindowedOnline`] reports on the window
    /// it holds. The default scores the whole series and keeps the last score; a detector
    /// that can score that step alone overrides it.
    ///
    /// # Errors
    /// As [`Detector::score`]; [`DetectError::Numerical`] for an empty series.
    fn score_newest(&self, series: &ResidueSeries) -> Result<f64, DetectError> {
        self.score(series)?.last().copied().ok_or_else(|| DetectError::Numerical { what: "empty score window".into() })
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

/// An online detector whose alarm is `score > threshold` at a threshold of the caller's
/// ([`Detector::online_at`]).
pub struct Rethresholded<'a> {
    /// The detector whose score is kept.
    pub inner: Box<dyn OnlineDetector + 'a>,
    /// The alarm threshold of that score.
    pub threshold: f64,
}

impl OnlineDetector for Rethresholded<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let d = self.inner.update(step)?;
        Ok(OnlineDecision { score: d.score, alarm: d.score > self.threshold })
    }

    fn reset(&mut self) {
        self.inner.reset();
    }
}

/// An online detector whose alarm stands only once the inner detector has alarmed on `k`
/// consecutive steps (k-of-k confirmation, the persistence check of fault detection: one
/// outlying step does not raise an alarm, a run of them does). The score is the inner one;
/// `k = 1` (or 0) is the inner detector itself.
pub struct Confirmed<'a> {
    /// The detector whose raw alarms are confirmed.
    pub inner: Box<dyn OnlineDetector + 'a>,
    /// Consecutive raw alarms an alarm needs.
    pub k: usize,
    /// Raw alarms in a row up to the last step.
    run: usize,
}

impl<'a> Confirmed<'a> {
    /// Confirms the alarms of `inner` over `k` consecutive steps.
    #[must_use]
    pub fn new(inner: Box<dyn OnlineDetector + 'a>, k: usize) -> Self {
        Self { inner, k, run: 0 }
    }
}

impl OnlineDetector for Confirmed<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let d = self.inner.update(step)?;
        self.run = if d.alarm { self.run.saturating_add(1) } else { 0 };
        Ok(OnlineDecision { score: d.score, alarm: self.run >= self.k.max(1) })
    }

    fn reset(&mut self) {
        self.inner.reset();
        self.run = 0;
    }
}

/// An online detector whose score is the mean of the inner detector's scores on the newest
/// step and the `width` steps before it (a trailing moving mean: it reads no later step, so a
/// streaming detector can use it), alarming above `threshold`. One outlying score is diluted,
/// a run of high scores is not; a strong onset still alarms on its first step. `width = 0`
/// is the inner detector unchanged, its own alarms included.
pub struct TrailingMean<'a> {
    /// The detector whose scores are averaged.
    pub inner: Box<dyn OnlineDetector + 'a>,
    /// Earlier steps averaged with the newest.
    pub width: usize,
    /// Alarm threshold of the averaged score.
    pub threshold: f64,
    /// The inner scores of the latest `width + 1` steps.
    recent: std::collections::VecDeque<f64>,
}

impl<'a> TrailingMean<'a> {
    /// Averages the scores of `inner` over the newest step and the `width` before it.
    #[must_use]
    pub fn new(inner: Box<dyn OnlineDetector + 'a>, width: usize, threshold: f64) -> Self {
        Self { inner, width, threshold, recent: std::collections::VecDeque::with_capacity(width.saturating_add(1)) }
    }
}

impl OnlineDetector for TrailingMean<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let d = self.inner.update(step)?;
        if self.width == 0 {
            return Ok(d);
        }
        if self.recent.len() > self.width {
            self.recent.pop_front();
        }
        self.recent.push_back(d.score);
        #[allow(clippy::cast_precision_loss)] // a handful of steps
        let score = self.recent.iter().sum::<f64>() / self.recent.len() as f64;
        Ok(OnlineDecision { score, alarm: score > self.threshold })
    }

    fn reset(&mut self) {
        self.inner.reset();
        self.recent.clear();
    }
}

/// A borrowed detector is a detector: [`WindowedOnline`] holds either a reference or a view
/// that owns nothing (such as a detector's scores before a post-processing step).
impl<T: Detector + ?Sized> Detector for &T {
    fn name(&self) -> &str {
        (**self).name()
    }

    fn channels(&self) -> &[String] {
        (**self).channels()
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        (**self).score(series)
    }

    fn threshold(&self) -> f64 {
        (**self).threshold()
    }

    fn streaming_threshold(&self) -> f64 {
        (**self).streaming_threshold()
    }

    fn score_streaming(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        (**self).score_streaming(series)
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        (**self).online()
    }

    fn online_at(&self, threshold: f64) -> Box<dyn OnlineDetector + '_> {
        (**self).online_at(threshold)
    }

    fn online_window(&self) -> usize {
        (**self).online_window()
    }

    fn score_newest(&self, series: &ResidueSeries) -> Result<f64, DetectError> {
        (**self).score_newest(series)
    }
}

/// Streaming adapter that re-scores a sliding window of recent steps with a batch
/// [`Detector`] (usually a reference to one) and reports the newest step
/// ([`Detector::score_newest`]).
pub struct WindowedOnline<D: Detector> {
    detector: D,
    window: usize,
    t: VecDeque<f64>,
    r: VecDeque<Vec<f64>>,
    s: VecDeque<Vec<f64>>,
    /// NIS of every step held, computed when the step was checked on arrival.
    nis: VecDeque<f64>,
}

impl<D: Detector> WindowedOnline<D> {
    /// Wraps `detector`, keeping at most `window` (at least 1) past steps.
    pub fn new(detector: D, window: usize) -> Self {
        let window = window.max(1);
        let (t, r, s, nis) = Default::default();
        Self { detector, window, t, r, s, nis }
    }
}

impl<D: Detector> OnlineDetector for WindowedOnline<D> {
    /// Checks the new step alone ([`checked_step_nis`], at its index in the window), so that a
    /// bad step is refused and leaves the window as it was, then re-scores the window.
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let step_idx = self.t.len().min(self.window - 1);
        let m = self.detector.channels().len();
        let nis = checked_step_nis(step_idx, m, self.t.back().copied(), step.t, step.r_k, step.s_k)?;
        if self.t.len() == self.window {
            self.t.pop_front();
            self.r.pop_front();
            self.s.pop_front();
            self.nis.pop_front();
        }
        self.t.push_back(step.t);
        self.r.push_back(step.r_k.to_vec());
        self.s.push_back(step.s_k.to_vec());
        self.nis.push_back(nis);
        let series = ResidueSeries::from_checked(
            self.t.iter().copied().collect(),
            self.detector.channels().to_vec(),
            self.r.iter().flatten().copied().collect(),
            self.s.iter().flatten().copied().collect(),
            self.nis.iter().copied().collect(),
        );
        let score = self.detector.score_newest(&series)?;
        Ok(OnlineDecision { score, alarm: score > self.detector.streaming_threshold() })
    }

    fn reset(&mut self) {
        self.t.clear();
        self.r.clear();
        self.s.clear();
        self.nis.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::ResidueError;

    /// Alarms when the step's single residue is above 1; the score is the residue.
    struct Above1;

    impl OnlineDetector for Above1 {
        fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
            Ok(OnlineDecision { score: step.r_k[0], alarm: step.r_k[0] > 1.0 })
        }

        fn reset(&mut self) {}
    }

    /// The decisions of `det` on one-channel residues `r`, one step per second.
    fn decisions(det: &mut dyn OnlineDetector, r: &[f64]) -> Vec<OnlineDecision> {
        let s = [1.0];
        r.iter()
            .enumerate()
            .map(|(i, x)| {
                let step = ResidueStep { t: i as f64, r_k: std::slice::from_ref(x), s_k: &s, nis: x * x };
                det.update(&step).unwrap()
            })
            .collect()
    }

    fn alarms(det: &mut dyn OnlineDetector, r: &[f64]) -> Vec<bool> {
        decisions(det, r).iter().map(|d| d.alarm).collect()
    }

    fn scores(det: &mut dyn OnlineDetector, r: &[f64]) -> Vec<f64> {
        decisions(det, r).iter().map(|d| d.score).collect()
    }

    #[test]
    fn a_confirmed_alarm_needs_k_consecutive_raw_alarms() {
        let r = [2.0, 0.0, 2.0, 2.0, 2.0, 0.0, 2.0, 2.0];
        let mut one = Confirmed::new(Box::new(Above1), 1);
        assert_eq!(alarms(&mut one, &r), r.iter().map(|&x| x > 1.0).collect::<Vec<_>>());
        let mut two = Confirmed::new(Box::new(Above1), 2);
        assert_eq!(alarms(&mut two, &r), [false, false, false, true, true, false, false, true]);
        let mut three = Confirmed::new(Box::new(Above1), 3);
        assert_eq!(alarms(&mut three, &r), [false, false, false, false, true, false, false, false]);
    }

    /// The trailing mean averages the newest score with the `width` before it: an isolated
    /// spike is diluted, a run is not, a strong onset alarms at once, and `reset` forgets.
    #[test]
    fn a_trailing_mean_averages_the_newest_scores() {
        let r = [0.0, 3.0, 0.0, 0.0, 1.5, 1.5, 6.0];
        let mut none = TrailingMean::new(Box::new(Above1), 0, 1.0);
        assert_eq!(scores(&mut none, &r), r.to_vec());
        let mut two = TrailingMean::new(Box::new(Above1), 1, 1.0);
        assert_eq!(scores(&mut two, &r), [0.0, 1.5, 1.5, 0.0, 0.75, 1.5, 3.75]);
        two.reset();
        let mut spike = TrailingMean::new(Box::new(Above1), 2, 1.2);
        let run = [0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 1.5, 1.5, 1.5];
        assert_eq!(alarms(&mut spike, &run), [false, false, false, false, false, false, false, false, true]);
        spike.reset();
        assert_eq!(alarms(&mut spike, &[5.0]), [true], "a strong onset alarms on its first step");
    }

    #[test]
    fn reset_forgets_the_run() {
        let mut two = Confirmed::new(Box::new(Above1), 2);
        assert_eq!(alarms(&mut two, &[2.0]), [false]);
        two.reset();
        assert_eq!(alarms(&mut two, &[2.0, 2.0]), [false, true]);
    }

    /// Scores each step of a window by the sum of the NIS of the window's steps up to it.
    struct CumulativeNis(Vec<String>);

    impl Detector for CumulativeNis {
        fn name(&self) -> &str {
            "cumulative NIS"
        }

        fn channels(&self) -> &[String] {
            &self.0
        }

        fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
            Ok(series
                .nis()
                .iter()
                .scan(0.0, |sum, nis| {
                    *sum += nis;
                    Some(*sum)
                })
                .collect())
        }

        fn threshold(&self) -> f64 {
            10.0
        }
    }

    #[test]
    fn a_windowed_detector_sees_the_newest_steps_and_refuses_a_bad_one_whole() {
        let mut det = WindowedOnline::new(CumulativeNis(vec!["x".into()]), 3);
        // NIS of each step is r², S = 1: the window's sum of the last three.
        assert_eq!(scores(&mut det, &[1.0, 2.0, 1.0, 3.0]), [1.0, 5.0, 6.0, 14.0]);
        let s = [1.0];
        let step = |t: f64, r: &'static [f64]| ResidueStep { t, r_k: r, s_k: &s, nis: 0.0 };
        // The window is full (steps at 1, 2, 3 s): a repeated time, a NaN residue and an
        // indefinite S_k are refused at the newest index, and the next good step is scored on
        // the three newest good steps.
        let err = det.update(&step(3.0, &[1.0])).unwrap_err();
        assert!(matches!(err, DetectError::Residue(ResidueError::Unordered { step_idx: 2, .. })), "{err}");
        let err = det.update(&step(4.0, &[f64::NAN])).unwrap_err();
        assert!(matches!(err, DetectError::Residue(ResidueError::NonFinite { step_idx: 2, what: "r_k" })), "{err}");
        let zero = [0.0];
        let err = det.update(&ResidueStep { t: 4.0, r_k: &[1.0], s_k: &zero, nis: 0.0 }).unwrap_err();
        assert!(matches!(err, DetectError::Residue(ResidueError::NotPositiveDefinite { step_idx: 2 })), "{err}");
        assert_eq!(det.update(&step(4.0, &[0.0])).unwrap().score, 1.0 + 9.0);
        det.reset();
        assert_eq!(det.update(&step(0.0, &[2.0])).unwrap().score, 4.0);
    }
}
