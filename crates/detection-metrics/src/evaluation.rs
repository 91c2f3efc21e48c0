//! Evaluation metrics of a detector on labelled residue steps
//! (docs/decisions/060-metric-definitions.md): per-step precision, recall and F1 without point
//! adjustment (paper eq:precision, eq:recall, eq:F1, counted by [`Confusion`]), the
//! ROC curve and its area, PR AUC (average precision), detection delay per attack interval,
//! false alarms per minute of clean flight, and mean ± sample standard deviation over seeds.
//!
//! Inputs are plain slices, one entry per residue step of one flight: time stamps `t` in
//! seconds (strictly increasing), anomaly scores (higher = more anomalous), per-step alarms and
//! ground-truth attack labels. Several flights are evaluated together with [`evaluate`], which
//! pools steps for the confusion counts and the curves, and attack intervals for the delays;
//! it never joins an interval across two flights.
//!
//! Conventions (docs/decisions/060-metric-definitions.md):
//! - an ROC point at score `s` alarms every step with `score >= s`; ties are one point, so the
//!   trapezoidal area gives tied positive/negative pairs half credit (the Mann–Whitney AUC);
//! - average precision is `Σ_n (R_n − R_{n−1}) P_n` over distinct thresholds (no interpolation);
//! - an attack interval is a maximal run of attacked steps; its delay is the time from its first
//!   step to its first alarmed step; intervals without an alarm are counted as missed;
//! - a false-alarm event is a maximal run of alarmed clean steps; clean time is the summed
//!   duration of clean steps, each step lasting until the next one; an event is raised on a
//!   clean step unless it continues the alarm of the attacked step just before it (an alarm
//!   that outlasts its attack);
//! - quantiles interpolate linearly between order statistics (numpy's default);
//! - the spread over seeds is the sample standard deviation (divisor `n − 1`).

use std::fmt;

use crate::confusion::Confusion;

/// A metric could not be computed from the given data.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MetricsError {
    /// Two per-step slices of one flight have different lengths.
    #[error("flight {flight_idx}: `{what}` has {got} steps, expected {expected}")]
    Length {
        /// Index of the flight in the evaluated set.
        flight_idx: usize,
        /// Which slice is wrong.
        what: &'static str,
        /// Number of labelled steps.
        expected: usize,
        /// Number found.
        got: usize,
    },
    /// A score or time stamp is NaN (or a time stamp is infinite).
    #[error("flight {flight_idx}: step {step_idx}: `{what}` is not a number")]
    NonFinite {
        /// Index of the flight in the evaluated set.
        flight_idx: usize,
        /// Index of the step.
        step_idx: usize,
        /// Which value.
        what: &'static str,
    },
    /// Time stamps do not increase strictly.
    #[error("flight {flight_idx}: step {step_idx}: time {t} s does not follow {t_prev} s")]
    Unordered {
        /// Index of the flight in the evaluated set.
        flight_idx: usize,
        /// Index of the step.
        step_idx: usize,
        /// Previous time stamp in seconds.
        t_prev: f64,
        /// This time stamp in seconds.
        t: f64,
    },
    /// A metric needs both classes (or at least one positive) and the data lacks one.
    #[error("{metric} is undefined: {n_attacked} attacked and {n_clean} clean steps")]
    MissingClass {
        /// The metric asked for.
        metric: &'static str,
        /// Number of attacked steps.
        n_attacked: usize,
        /// Number of clean steps.
        n_clean: usize,
    },
    /// Mean and standard deviation of an empty set, or of a set containing NaN.
    #[error("cannot summarise {what}: {why}")]
    Summary {
        /// What was summarised.
        what: String,
        /// Why not.
        why: &'static str,
    },
}

/// Result alias of this module.
pub type Result<T, E = MetricsError> = std::result::Result<T, E>;

// ---------------------------------------------------------------------------------------------
// Per-step confusion (eq:precision, eq:recall, eq:F1).

/// Per-step confusion counts of `alarms` against `labels` (no point adjustment).
///
/// # Errors
/// [`MetricsError::Length`] when the slices differ in length.
pub fn confusion(alarms: &[bool], labels: &[bool]) -> Result<Confusion> {
    check_len(0, "alarms", labels.len(), alarms.len())?;
    // eq:precision, eq:recall, eq:F1 are computed from these counts by `Confusion`.
    Ok(Confusion::count(alarms, labels))
}

fn check_len(flight_idx: usize, what: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got { Ok(()) } else { Err(MetricsError::Length { flight_idx, what, expected, got }) }
}

// ---------------------------------------------------------------------------------------------
// ROC and precision-recall curves.

/// One operating point of a detector: alarm on every step with `score >= threshold`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RocPoint {
    /// Score threshold (`+∞` for the "never alarm" point).
    pub threshold: f64,
    /// False-positive rate `FP / (FP + TN)`.
    pub fpr: f64,
    /// True-positive rate (recall) `TP / (TP + FN)`.
    pub tpr: f64,
    /// Precision `TP / (TP + FP)` at this point (1 for the "never alarm" point).
    pub precision: f64,
}

/// A ROC curve from (0, 0) to (1, 1), one point per distinct score, descending threshold.
#[derive(Debug, Clone, PartialEq)]
pub struct RocCurve {
    points: Vec<RocPoint>,
    auc: f64,
    average_precision: f64,
}

impl RocCurve {
    /// Builds the curve of `scores` against `labels` (one pair of slices per flight; steps are
    /// pooled).
    ///
    /// # Errors
    /// [`MetricsError::Length`] on unequal slices, [`MetricsError::NonFinite`] on a NaN score,
    /// [`MetricsError::MissingClass`] unless there is at least one attacked and one clean step.
    pub fn new<'a>(flights: impl IntoIterator<Item = (&'a [f64], &'a [bool])>) -> Result<Self> {
        let mut pooled: Vec<(f64, bool)> = Vec::new();
        for (flight_idx, (scores, labels)) in flights.into_iter().enumerate() {
            check_len(flight_idx, "scores", labels.len(), scores.len())?;
            for (step_idx, (&s, &l)) in scores.iter().zip(labels).enumerate() {
                if s.is_nan() {
                    return Err(MetricsError::NonFinite { flight_idx, step_idx, what: "score" });
                }
                pooled.push((s, l));
            }
        }
        let n_pos = pooled.iter().filter(|(_, l)| *l).count();
        let n_neg = pooled.len() - n_pos;
        if n_pos == 0 || n_neg == 0 {
            return Err(MetricsError::MissingClass { metric: "ROC curve", n_attacked: n_pos, n_clean: n_neg });
        }
        // Descending score; ties form one group and move the curve diagonally.
        pooled.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut points = vec![RocPoint { threshold: f64::INFINITY, fpr: 0.0, tpr: 0.0, precision: 1.0 }];
        let (mut tp, mut fp) = (0usize, 0usize);
        let (mut auc, mut ap) = (0.0, 0.0);
        let mut i = 0;
        while i < pooled.len() {
            let s = pooled[i].0;
            while i < pooled.len() && pooled[i].0 == s {
                if pooled[i].1 {
                    tp += 1
                } else {
                    fp += 1
                }
                i += 1;
            }
            let prev = points[points.len() - 1];
            let p = RocPoint {
                threshold: s,
                fpr: fp as f64 / n_neg as f64,
                tpr: tp as f64 / n_pos as f64,
                precision: tp as f64 / (tp + fp) as f64,
            };
            // Trapezoid: a tie group spanning both classes contributes half credit.
            auc += (p.fpr - prev.fpr) * 0.5 * (p.tpr + prev.tpr);
            // Average precision: step-wise, Σ (R_n − R_{n−1}) P_n.
            ap += (p.tpr - prev.tpr) * p.precision;
            points.push(p);
        }
        Ok(Self { points, auc, average_precision: ap })
    }

    /// Points from (0, 0) (threshold `+∞`) to (1, 1) (lowest score), threshold descending.
    pub fn points(&self) -> &[RocPoint] {
        &self.points
    }

    /// Area under the ROC curve, in [0, 1]; 0.5 is chance.
    pub fn auc(&self) -> f64 {
        self.auc
    }

    /// Area under the precision–recall curve as average precision, in [0, 1].
    pub fn average_precision(&self) -> f64 {
        self.average_precision
    }

    /// Rebuilds a stored (possibly thinned) curve from `(fpr, tpr)` points and its summary
    /// areas, e.g. from a results cache for plotting. Thresholds and precisions of the points
    /// are not stored and read as NaN.
    ///
    /// # Errors
    /// [`MetricsError::NonFinite`] unless the points are finite, in `[0, 1]`, and non-decreasing
    /// in both coordinates (step index reported as the point index).
    pub fn from_fpr_tpr(points: &[(f64, f64)], auc: f64, average_precision: f64) -> Result<Self> {
        let mut prev = (0.0, 0.0);
        let mut out = Vec::with_capacity(points.len());
        for (step_idx, &(fpr, tpr)) in points.iter().enumerate() {
            let in_unit = (0.0..=1.0).contains(&fpr) && (0.0..=1.0).contains(&tpr);
            if !in_unit || fpr < prev.0 || tpr < prev.1 {
                return Err(MetricsError::NonFinite { flight_idx: 0, step_idx, what: "ROC point" });
            }
            prev = (fpr, tpr);
            out.push(RocPoint { threshold: f64::NAN, fpr, tpr, precision: f64::NAN });
        }
        Ok(Self { points: out, auc, average_precision })
    }
}

/// ROC AUC of one flight's `scores` against `labels`.
///
/// # Errors
/// As [`RocCurve::new`].
pub fn roc_auc(scores: &[f64], labels: &[bool]) -> Result<f64> {
    Ok(RocCurve::new([(scores, labels)])?.auc())
}

/// PR AUC (average precision) of one flight's `scores` against `labels`.
///
/// # Errors
/// As [`RocCurve::new`].
pub fn average_precision(scores: &[f64], labels: &[bool]) -> Result<f64> {
    Ok(RocCurve::new([(scores, labels)])?.average_precision())
}

// ---------------------------------------------------------------------------------------------
// Attack intervals, detection delay, false alarms.

/// A maximal run of attacked steps `[start, end)` of one flight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AttackInterval {
    /// First attacked step.
    pub start: usize,
    /// One past the last attacked step.
    pub end: usize,
}

/// The maximal runs of `true` in `labels`, in order.
pub fn attack_intervals(labels: &[bool]) -> Vec<AttackInterval> {
    let mut out = Vec::new();
    let mut start = None;
    for (k, &l) in labels.iter().enumerate() {
        match (l, start) {
            (true, None) => start = Some(k),
            (false, Some(s)) => {
                out.push(AttackInterval { start: s, end: k });
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push(AttackInterval { start: s, end: labels.len() });
    }
    out
}

/// Detection delays over a set of attack intervals.
#[derive(Debug, Clone, PartialEq)]
pub struct DelayStats {
    /// Delay in seconds of every detected interval (onset → first alarm inside it), in order.
    pub delays_s: Vec<f64>,
    /// Number of attack intervals.
    pub n_intervals: usize,
    /// Intervals without any alarm inside them.
    pub n_missed: usize,
}

impl DelayStats {
    /// Median delay in seconds; `None` when no interval was detected.
    pub fn median_s(&self) -> Option<f64> {
        quantile(&self.delays_s, 0.5)
    }

    /// 90th-percentile delay in seconds; `None` when no interval was detected.
    pub fn p90_s(&self) -> Option<f64> {
        quantile(&self.delays_s, 0.9)
    }
}

/// The `q`-quantile (`q` in [0, 1]) with linear interpolation between order statistics
/// (numpy's default, Hyndman–Fan type 7); `None` for an empty slice or a NaN value.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    if values.is_empty() || values.iter().any(|v| v.is_nan()) || !(0.0..=1.0).contains(&q) {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let h = q * (v.len() - 1) as f64;
    let lo = h.floor() as usize;
    let hi = h.ceil() as usize;
    Some(v[lo] + (h - lo as f64) * (v[hi] - v[lo]))
}

/// False alarms over clean flight time.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FalseAlarmRate {
    /// Number of false-alarm events (maximal runs of alarmed clean steps).
    pub n_events: usize,
    /// Of those, the events raised on a clean step: every event but those that continue an
    /// alarm raised on the attacked step just before (an alarm outlasting its attack).
    pub n_raised_clean: usize,
    /// Summed duration of clean steps in seconds.
    pub clean_time_s: f64,
}

impl FalseAlarmRate {
    /// Events per minute of clean flight; 0 when there is no clean time.
    pub fn per_minute(&self) -> f64 {
        self.rate(self.n_events)
    }

    /// Events raised on a clean step ([`FalseAlarmRate::n_raised_clean`]) per minute of clean
    /// flight; 0 when there is no clean time.
    pub fn raised_clean_per_minute(&self) -> f64 {
        self.rate(self.n_raised_clean)
    }

    fn rate(&self, n: usize) -> f64 {
        if self.clean_time_s > 0.0 { n as f64 * 60.0 / self.clean_time_s } else { 0.0 }
    }
}

/// One flight's outcome: per-step time stamps, scores, alarms and labels.
#[derive(Debug, Clone, Copy)]
pub struct FlightOutcome<'a> {
    /// Time stamps in seconds, strictly increasing.
    pub t: &'a [f64],
    /// Anomaly scores, higher = more anomalous.
    pub scores: &'a [f64],
    /// Per-step alarms at the detector's fitted threshold.
    pub alarms: &'a [bool],
    /// Ground truth: `true` where the step is attacked.
    pub labels: &'a [bool],
}

impl FlightOutcome<'_> {
    /// Checks equal lengths, finite increasing time stamps and non-NaN scores.
    ///
    /// # Errors
    /// [`MetricsError::Length`], [`MetricsError::NonFinite`] or [`MetricsError::Unordered`].
    fn check(&self, flight_idx: usize) -> Result<()> {
        let n = self.labels.len();
        check_len(flight_idx, "t", n, self.t.len())?;
        check_len(flight_idx, "scores", n, self.scores.len())?;
        check_len(flight_idx, "alarms", n, self.alarms.len())?;
        for (step_idx, &t) in self.t.iter().enumerate() {
            if !t.is_finite() {
                return Err(MetricsError::NonFinite { flight_idx, step_idx, what: "t" });
            }
            if step_idx > 0 && t <= self.t[step_idx - 1] {
                return Err(MetricsError::Unordered { flight_idx, step_idx, t_prev: self.t[step_idx - 1], t });
            }
        }
        if let Some(step_idx) = self.scores.iter().position(|s| s.is_nan()) {
            return Err(MetricsError::NonFinite { flight_idx, step_idx, what: "score" });
        }
        Ok(())
    }

    /// Duration of step `k`: until the next step; the last step lasts as long as the one before
    /// it (0 for a one-step flight).
    fn step_duration_s(&self, k: usize) -> f64 {
        let n = self.t.len();
        if k + 1 < n {
            self.t[k + 1] - self.t[k]
        } else if n >= 2 {
            self.t[n - 1] - self.t[n - 2]
        } else {
            0.0
        }
    }
}

/// Detection delays of one flight (see the module conventions).
///
/// # Errors
/// As [`evaluate`].
pub fn detection_delays(t: &[f64], alarms: &[bool], labels: &[bool]) -> Result<DelayStats> {
    let scores = vec![0.0; labels.len()];
    let flight = FlightOutcome { t, scores: &scores, alarms, labels };
    flight.check(0)?;
    let mut stats = DelayStats { delays_s: Vec::new(), n_intervals: 0, n_missed: 0 };
    add_delays(&flight, &mut stats);
    Ok(stats)
}

fn add_delays(flight: &FlightOutcome<'_>, stats: &mut DelayStats) {
    for iv in attack_intervals(flight.labels) {
        stats.n_intervals += 1;
        match (iv.start..iv.end).find(|&k| flight.alarms[k]) {
            Some(k) => stats.delays_s.push(flight.t[k] - flight.t[iv.start]),
            None => stats.n_missed += 1,
        }
    }
}

/// False alarms of one flight per clean time (see the module conventions).
///
/// # Errors
/// As [`evaluate`].
pub fn false_alarms(t: &[f64], alarms: &[bool], labels: &[bool]) -> Result<FalseAlarmRate> {
    let scores = vec![0.0; labels.len()];
    let flight = FlightOutcome { t, scores: &scores, alarms, labels };
    flight.check(0)?;
    let mut rate = FalseAlarmRate::default();
    add_false_alarms(&flight, &mut rate);
    Ok(rate)
}

fn add_false_alarms(flight: &FlightOutcome<'_>, rate: &mut FalseAlarmRate) {
    let mut in_event = false;
    for k in 0..flight.labels.len() {
        let false_alarm = flight.alarms[k] && !flight.labels[k];
        if false_alarm && !in_event {
            rate.n_events += 1;
            let outlasts_attack = k > 0 && flight.labels[k - 1] && flight.alarms[k - 1];
            if !outlasts_attack {
                rate.n_raised_clean += 1;
            }
        }
        in_event = false_alarm;
        if !flight.labels[k] {
            rate.clean_time_s += flight.step_duration_s(k);
        }
    }
}

/// Every metric of one detector on a set of test flights.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// Pooled per-step confusion counts.
    pub confusion: Confusion,
    /// Pooled ROC curve (also gives ROC AUC and average precision).
    pub roc: RocCurve,
    /// Detection delays over every attack interval of every flight.
    pub delays: DelayStats,
    /// False alarms over the clean time of every flight.
    pub false_alarms: FalseAlarmRate,
}

impl Evaluation {
    /// Per-step precision (eq:precision).
    pub fn precision(&self) -> f64 {
        self.confusion.precision()
    }

    /// Per-step recall (eq:recall).
    pub fn recall(&self) -> f64 {
        self.confusion.recall()
    }

    /// Per-step F1 (eq:F1).
    pub fn f1(&self) -> f64 {
        self.confusion.f1()
    }
}

/// Evaluates one detector on a set of flights: steps are pooled for the confusion counts and
/// the ROC curve; intervals and clean time are summed over flights.
///
/// # Errors
/// [`MetricsError::Length`] or [`MetricsError::Unordered`] or [`MetricsError::NonFinite`]
/// naming the flight and step; [`MetricsError::MissingClass`] unless the flights hold both
/// attacked and clean steps.
pub fn evaluate(flights: &[FlightOutcome<'_>]) -> Result<Evaluation> {
    for (flight_idx, f) in flights.iter().enumerate() {
        f.check(flight_idx)?;
    }
    let roc = RocCurve::new(flights.iter().map(|f| (f.scores, f.labels)))?;
    let mut confusion = Confusion::default();
    let mut delays = DelayStats { delays_s: Vec::new(), n_intervals: 0, n_missed: 0 };
    let mut false_alarms = FalseAlarmRate::default();
    for f in flights {
        confusion.add(Confusion::count(f.alarms, f.labels));
        add_delays(f, &mut delays);
        add_false_alarms(f, &mut false_alarms);
    }
    Ok(Evaluation { confusion, roc, delays, false_alarms })
}

// ---------------------------------------------------------------------------------------------
// Mean and spread over seeds.

/// Mean and sample standard deviation (divisor `n − 1`) of a metric over seeds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanStd {
    /// Arithmetic mean.
    pub mean: f64,
    /// Sample standard deviation with divisor `n − 1`; `None` for a single value.
    pub std: Option<f64>,
    /// Number of values.
    pub n: usize,
}

impl MeanStd {
    /// Summarises `values` (one per seed).
    ///
    /// # Errors
    /// [`MetricsError::Summary`] for an empty slice or a NaN value.
    pub fn new(what: &str, values: &[f64]) -> Result<Self> {
        if values.is_empty() {
            return Err(MetricsError::Summary { what: what.to_owned(), why: "no values" });
        }
        if values.iter().any(|v| v.is_nan()) {
            return Err(MetricsError::Summary { what: what.to_owned(), why: "a value is NaN" });
        }
        let n = values.len();
        let mean = values.iter().sum::<f64>() / n as f64;
        let std = (n > 1).then(|| {
            let ss: f64 = values.iter().map(|v| (v - mean) * (v - mean)).sum();
            (ss / (n - 1) as f64).sqrt()
        });
        Ok(Self { mean, std, n })
    }
}

impl fmt::Display for MeanStd {
    /// `mean ± std` with the formatter's precision (default 2 decimals, as the paper's
    /// tables); a single value prints as its mean alone.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let p = f.precision().unwrap_or(2);
        match self.std {
            Some(s) => write!(f, "{:.p$} ± {:.p$}", self.mean, s),
            None => write!(f, "{:.p$}", self.mean),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPS: f64 = 1e-12;

    #[test]
    fn quantile_matches_numpy_linear() {
        // numpy.quantile([1, 2, 3, 4], [0.5, 0.9]) = [2.5, 3.7].
        let v = [4.0, 1.0, 3.0, 2.0];
        assert!((quantile(&v, 0.5).unwrap() - 2.5).abs() < EPS);
        assert!((quantile(&v, 0.9).unwrap() - 3.7).abs() < EPS);
        assert_eq!(quantile(&[], 0.5), None);
        assert_eq!(quantile(&[7.0], 0.9), Some(7.0));
    }

    #[test]
    fn intervals_are_maximal_runs() {
        let l = [true, true, false, true, false, false, true];
        assert_eq!(
            attack_intervals(&l),
            vec![
                AttackInterval { start: 0, end: 2 },
                AttackInterval { start: 3, end: 4 },
                AttackInterval { start: 6, end: 7 }
            ]
        );
        assert!(attack_intervals(&[false; 3]).is_empty());
    }
}
