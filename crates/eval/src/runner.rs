//! The experiment matrix runner: fits every method of Tables I and II on a cell's training and
//! validation splits, scores the test split, and turns the outcome into a
//! [`crate::table::ResultRow`] with its timings ([`RunRecord`]).
//!
//! Protocol (docs/decisions/001-validation-split-labels.md): each method's thresholds and
//! hyper-parameters are chosen inside its [`Fit::fit`] on the validation split; the test split is scored once,
//! per step, without point adjustment. Finished `(cell, method, seed)` runs are cached as JSON
//! next to the results, keyed by a hash of everything that determines them, so an interrupted
//! run resumes and a changed configuration is recomputed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use ekf_residue::{Detector, Fit, LabelledResidues};
use quadformer_model::{ModeResult, QuadFormerConfig};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::cell::Cell;
use crate::io::write_text_atomic;
use crate::methods::{Method, MethodConfigs};
use crate::metrics::{Evaluation, FlightOutcome, evaluate};
use crate::table::{ResultRow, TimingRow};

/// Largest number of ROC points kept per run for plotting.
const ROC_POINTS_KEPT: usize = 200;

/// Errors of the runner.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunError {
    /// A method failed to fit.
    #[error("{method}: fit failed: {msg}")]
    Fit {
        /// Method name.
        method: &'static str,
        /// The method's error, as text.
        msg: String,
    },
    /// A fitted method failed to score a series.
    #[error("{method}: scoring failed: {source}")]
    Score {
        /// Method name.
        method: &'static str,
        /// The detector's error.
        source: ekf_residue::DetectError,
    },
    /// Metrics could not be computed.
    #[error("{method} on {cell}: {source}")]
    Metrics {
        /// Method name.
        method: &'static str,
        /// The cell.
        cell: Cell,
        /// The metric error.
        source: crate::metrics::MetricsError,
    },
    /// The test split has no labels.
    #[error("test flight {flight_idx} has no labels")]
    UnlabelledTest {
        /// Index of the flight in the test split.
        flight_idx: usize,
    },
    /// Reading or writing the run cache failed.
    #[error("run cache {path}: {msg}")]
    Cache {
        /// The cache file.
        path: PathBuf,
        /// What went wrong.
        msg: String,
    },
}

/// Result alias of the runner.
pub type Result<T, E = RunError> = std::result::Result<T, E>;

/// A fitted detector and how long fitting took.
pub struct Fitted {
    /// The detector, thresholds chosen on validation.
    pub detector: Box<dyn Detector>,
    /// Wall-clock fit time in seconds.
    pub train_s: f64,
}

/// Fits `method` with `cfgs` (already [`MethodConfigs::seeded`]) on `train`, choosing its
/// thresholds on `valid`.
///
/// # Errors
/// [`RunError::Fit`] with the method's own error message.
pub fn fit(method: Method, cfgs: &MethodConfigs, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Fitted> {
    let start = Instant::now();
    let detector = method.fit(cfgs, train, valid).map_err(|msg| RunError::Fit { method: method.name(), msg })?;
    Ok(Fitted { detector, train_s: start.elapsed().as_secs_f64() })
}

/// Per-flight scores and alarms of a detector on a labelled split.
#[derive(Debug, Clone, PartialEq)]
pub struct ScoredSplit {
    /// Scores, one vector per flight.
    pub scores: Vec<Vec<f64>>,
    /// Alarms at the fitted threshold, one vector per flight.
    pub alarms: Vec<Vec<bool>>,
    /// Wall-clock scoring time in seconds.
    pub score_s: f64,
}

/// Scores every flight of `split` with a fitted detector.
///
/// # Errors
/// [`RunError::Score`] with the detector's error.
pub fn score_split(method: Method, detector: &dyn Detector, split: &LabelledResidues) -> Result<ScoredSplit> {
    let start = Instant::now();
    let mut scores = Vec::with_capacity(split.flights().len());
    let mut alarms = Vec::with_capacity(split.flights().len());
    let threshold = detector.threshold();
    for f in split.flights() {
        let s = detector.score(f.series()).map_err(|source| RunError::Score { method: method.name(), source })?;
        alarms.push(s.iter().map(|&v| v > threshold).collect());
        scores.push(s);
    }
    Ok(ScoredSplit { scores, alarms, score_s: start.elapsed().as_secs_f64() })
}

/// One finished run: its metrics and a thinned ROC curve for plotting.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunRecord {
    /// Hash of everything that determined the run (see [`run_key`]).
    pub key: String,
    /// Every metric.
    pub result: ResultRow,
    /// Wall-clock training time in seconds (not written to `results.csv`/`results.json`).
    pub train_s: f64,
    /// Wall-clock scoring time of the test split in seconds (idem).
    pub score_s: f64,
    /// ROC curve as `(false-positive rate, true-positive rate)` points, at most 200.
    pub roc: Vec<(f64, f64)>,
    /// QUADFormer only: every score mode on the same test split (the score-mode ablation).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub modes: Vec<ModeMetrics>,
}

impl RunRecord {
    /// The wall-clock times of the run, as a row of `timings.csv`.
    #[must_use]
    pub fn timing(&self) -> TimingRow {
        TimingRow::of(&self.result, self.train_s, self.score_s)
    }
}

/// One QUADFormer score mode on the test split, at the mode's own validation threshold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeMetrics {
    /// Mode name ([`quadformer_model::ScoreMode::name`]).
    pub mode: String,
    /// Whether validation chose this mode (its scores are the run's scores).
    pub chosen: bool,
    /// Whether validation chose this mode for the streaming detector (on the validation
    /// split's streaming scores, [`quadformer_model::QuadFormerDetector::stream`]).
    #[serde(default)]
    pub streamed: bool,
    /// Validation F1 at the mode's validation threshold.
    pub valid_f1: f64,
    /// Test F1 at the same threshold.
    pub test_f1: f64,
    /// Test ROC AUC of the mode's scores.
    pub test_auc: f64,
}

/// Computes the metrics of a scored test split.
///
/// # Errors
/// [`RunError::UnlabelledTest`] if a test flight has no labels; [`RunError::Metrics`].
pub fn run_record(
    key: String,
    cell: Cell,
    method: Method,
    seed: u64,
    test: &LabelledResidues,
    scored: &ScoredSplit,
    train_s: f64,
) -> Result<RunRecord> {
    let e = evaluate_split(test, &scored.scores, &scored.alarms, method.name(), cell)?;
    let result = ResultRow {
        model: cell.model,
        noise: cell.noise,
        attack: cell.attack,
        method,
        seed,
        precision: e.precision(),
        recall: e.recall(),
        f1: e.f1(),
        roc_auc: e.roc.auc(),
        pr_auc: e.roc.average_precision(),
        delay_median_s: e.delays.median_s(),
        delay_p90_s: e.delays.p90_s(),
        n_intervals: e.delays.n_intervals as u64,
        n_missed: e.delays.n_missed as u64,
        false_alarms_per_min: e.false_alarms.per_minute(),
        n_test_steps: test.n_steps() as u64,
        stream_precision: None,
        stream_recall: None,
        stream_f1: None,
    };
    let points = e.roc.points();
    let stride = points.len().div_ceil(ROC_POINTS_KEPT).max(1);
    let mut roc: Vec<(f64, f64)> = points.iter().step_by(stride).map(|p| (p.fpr, p.tpr)).collect();
    if let Some(last) = points.last()
        && roc.last() != Some(&(last.fpr, last.tpr))
    {
        roc.push((last.fpr, last.tpr));
    }
    Ok(RunRecord { key, result, train_s, score_s: scored.score_s, roc, modes: Vec::new() })
}

/// Evaluates per-flight scores and alarms (one vector per flight of `test`) against the labels
/// of `test`: every metric of [`evaluate`].
///
/// # Errors
/// [`RunError::UnlabelledTest`] if a test flight has no labels; [`RunError::Metrics`] naming the
/// method and cell.
pub fn evaluate_split(
    test: &LabelledResidues,
    scores: &[Vec<f64>],
    alarms: &[Vec<bool>],
    method: &'static str,
    cell: Cell,
) -> Result<Evaluation> {
    let mut outcomes = Vec::with_capacity(test.flights().len());
    for (flight_idx, ((f, scores), alarms)) in test.flights().iter().zip(scores).zip(alarms).enumerate() {
        let labels = f.labels().ok_or(RunError::UnlabelledTest { flight_idx })?;
        outcomes.push(FlightOutcome { t: f.series().t(), scores, alarms, labels });
    }
    evaluate(&outcomes).map_err(|source| RunError::Metrics { method, cell, source })
}

/// Scores `test` with the detector's streaming scores ([`Detector::score_streaming`]) and
/// alarms at its streaming threshold, and evaluates them.
///
/// # Errors
/// [`RunError::Score`]; as [`evaluate_split`].
pub fn evaluate_streaming(
    method: Method,
    detector: &dyn Detector,
    test: &LabelledResidues,
    cell: Cell,
) -> Result<Evaluation> {
    let threshold = detector.streaming_threshold();
    let scores = test
        .flights()
        .iter()
        .map(|f| {
            detector.score_streaming(f.series()).map_err(|source| RunError::Score { method: method.name(), source })
        })
        .collect::<Result<Vec<_>>>()?;
    let alarms: Vec<Vec<bool>> = scores.iter().map(|s| s.iter().map(|&v| v > threshold).collect()).collect();
    evaluate_split(test, &scores, &alarms, method.name(), cell)
}

/// The cache key of a run: SHA-256 over the crate version, the dataset key, the method and its
/// seeded configuration.
pub fn run_key(dataset_key: &str, method: Method, cfgs: &MethodConfigs) -> String {
    let mut h = Sha256::new();
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    h.update([0]);
    h.update(dataset_key.as_bytes());
    h.update([0]);
    h.update(method.slug().as_bytes());
    h.update([0]);
    h.update(method.config_json(cfgs).as_bytes());
    let digest = h.finalize();
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// Where the cached record of a run lives under `cache_dir`: per cell, named by method, seed and
/// the first 12 hex digits of its key, so variants of one run (ablations) coexist and identical
/// runs are shared.
pub fn cache_path(cache_dir: &Path, cell: Cell, method: Method, seed: u64, key: &str) -> PathBuf {
    let short = key.get(..12).unwrap_or(key);
    cache_dir.join(cell.slug()).join(format!("{}-seed{seed}-{short}.json", method.slug()))
}

/// Loads a cached record if it exists, parses, and has the expected key; anything else is a
/// cache miss (a corrupt or stale file is recomputed, never trusted).
pub fn load_cached(path: &Path, key: &str) -> Option<RunRecord> {
    let rec: RunRecord = read_json_cache(path)?;
    (rec.key == key && rec.result.check().is_ok() && rec.timing().check().is_ok()).then_some(rec)
}

/// Writes a record atomically.
///
/// # Errors
/// [`RunError::Cache`] naming the file.
pub fn store_cached(path: &Path, rec: &RunRecord) -> Result<()> {
    write_json_cache(path, rec)
}

/// Reads a JSON cache file; a missing, unreadable or unparsable file is a miss (`None`).
pub(crate) fn read_json_cache<T: serde::de::DeserializeOwned>(path: &Path) -> Option<T> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

/// Writes a JSON cache file atomically, creating its directory.
///
/// # Errors
/// [`RunError::Cache`] naming the file.
pub(crate) fn write_json_cache<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let cache_err = |msg: String| RunError::Cache { path: path.to_owned(), msg };
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| cache_err(e.to_string()))?;
    }
    let text = serde_json::to_string_pretty(value).map_err(|e| cache_err(e.to_string()))?;
    write_text_atomic(path, &text).map_err(|e| cache_err(e.to_string()))
}

/// Fits, scores and evaluates one `(cell, method, seed)`, or returns its cached record; also
/// returns the fitted detector when the run was not cached, for callers that score more data
/// with it (the amplitude sweep).
///
/// `data_key` must identify the training data exactly: the dataset's cache key plus anything
/// applied after loading (the labelled fraction, the channel selection).
///
/// # Errors
/// As [`fit`], [`score_split`], [`run_record`] and [`store_cached`].
pub fn run_one(
    cache_dir: &Path,
    data_key: &str,
    cell: Cell,
    method: Method,
    seed: u64,
    cfgs: &MethodConfigs,
    splits: Splits<'_>,
) -> Result<(RunRecord, Option<Box<dyn Detector>>)> {
    let cfgs = cfgs.seeded(seed);
    let key = run_key(data_key, method, &cfgs);
    let path = cache_path(cache_dir, cell, method, seed, &key);
    // A learning method's record from before streaming metrics existed is recomputed.
    if let Some(rec) = load_cached(&path, &key)
        && !(method.is_learning() && rec.result.stream_f1.is_none())
    {
        return Ok((rec, None));
    }
    let (fitted, scored, modes) = if method == Method::QuadFormer {
        fit_and_score_quadformer(&cfgs.quadformer, splits, cell)?
    } else {
        let fitted = fit(method, &cfgs, splits.train, splits.valid)?;
        let scored = score_split(method, fitted.detector.as_ref(), splits.test)?;
        (fitted, scored, Vec::new())
    };
    let mut rec = run_record(key, cell, method, seed, splits.test, &scored, fitted.train_s)?;
    rec.modes = modes;
    if method.is_learning() {
        let e = evaluate_streaming(method, fitted.detector.as_ref(), splits.test, cell)?;
        rec.result.stream_precision = Some(e.precision());
        rec.result.stream_recall = Some(e.recall());
        rec.result.stream_f1 = Some(e.f1());
    }
    store_cached(&path, &rec)?;
    Ok((rec, Some(fitted.detector)))
}

/// QUADFormer's fit and test scoring, with every score mode evaluated from the same forward
/// passes (the chosen mode's scores are exactly what [`Detector::score`] returns).
fn fit_and_score_quadformer(
    cfg: &QuadFormerConfig,
    splits: Splits<'_>,
    cell: Cell,
) -> Result<(Fitted, ScoredSplit, Vec<ModeMetrics>)> {
    let name = Method::QuadFormer.name();
    let start = Instant::now();
    let qf = cfg.fit(splits.train, splits.valid).map_err(|e| RunError::Fit { method: name, msg: e.to_string() })?;
    let train_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let mut per_mode: Vec<(ModeResult, Vec<Vec<f64>>)> = qf.mode_results().iter().map(|r| (*r, Vec::new())).collect();
    for f in splits.test.flights() {
        let by_mode = qf.scores_by_mode(f.series()).map_err(|e| RunError::Score { method: name, source: e.into() })?;
        for ((_, acc), (_, scores)) in per_mode.iter_mut().zip(by_mode) {
            acc.push(scores);
        }
    }
    let score_s = start.elapsed().as_secs_f64();
    let (chosen, streamed) = (qf.chosen().mode, qf.stream().mode);
    let alarms_at = |res: &ModeResult, scores: &[Vec<f64>]| -> Vec<Vec<bool>> {
        scores.iter().map(|s| s.iter().map(|&v| v > res.threshold).collect()).collect()
    };
    let mut modes = Vec::with_capacity(per_mode.len());
    let mut scored = None;
    for (res, scores) in per_mode {
        let alarms = alarms_at(&res, &scores);
        let e = evaluate_split(splits.test, &scores, &alarms, name, cell)?;
        modes.push(ModeMetrics {
            mode: res.mode.name().to_owned(),
            chosen: res.mode == chosen,
            streamed: res.mode == streamed,
            valid_f1: res.valid_f1,
            test_f1: e.f1(),
            test_auc: e.roc.auc(),
        });
        if res.mode == chosen {
            scored = Some(ScoredSplit { scores, alarms, score_s });
        }
    }
    let scored = scored.ok_or(RunError::Fit { method: name, msg: "the chosen mode has no scores".into() })?;
    Ok((Fitted { detector: Box::new(qf), train_s }, scored, modes))
}

/// The three splits of one cell.
#[derive(Debug, Clone, Copy)]
pub struct Splits<'a> {
    /// Training flights (labels on a fraction of them).
    pub train: &'a LabelledResidues,
    /// Validation flights (labelled; thresholds and early stopping only).
    pub valid: &'a LabelledResidues,
    /// Test flights (labelled; scored once).
    pub test: &'a LabelledResidues,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_key_depends_on_seed_and_method() {
        let c = MethodConfigs::quick();
        let a = run_key("d", Method::QuadFormer, &c.seeded(0));
        let b = run_key("d", Method::QuadFormer, &c.seeded(1));
        let s = run_key("d", Method::Cusum, &c.seeded(0));
        assert_ne!(a, b);
        assert_ne!(a, s);
        assert_eq!(s, run_key("d", Method::Cusum, &c.seeded(1)), "statistical configs have no seed");
    }
}
