//! QUADFormer as an `ekf_residue` [`Fit`]/[`Detector`]/[`OnlineDetector`]: training with
//! min-max (sec:attack_detector), the scoring modes of alg:alg2 and the Anomaly Transformer,
//! and threshold/mode choice on the validation split.
//!
//! Scoring modes (per window of `l` steps, then stitched per step, [`nn_toolkit::window`]):
//! - [`ScoreMode::Alg2`]: `softmax(−TCD)` over the window, as alg:alg2 writes it;
//! - [`ScoreMode::AnomalyTransformer`]: `softmax(−τ·TCD) ⊙ e`, `e_i = mean_c (R̂_ic − R_ic)²`,
//!   the Anomaly Transformer criterion (temperature `τ` = 50 there);
//! - [`ScoreMode::Classifier`]: the classification head's probability `σ(logit)`;
//! - [`ScoreMode::Combined`]: `½·p + ½·a/(a + a₅₀)` with `a` the Anomaly Transformer criterion
//!   and `a₅₀` its median on the validation split, so both halves lie in `[0, 1]`.
//!
//! Every mode's best-F1 threshold and F1 on the validation split are kept
//! ([`QuadFormerDetector::mode_results`], the ablation table); the mode with the best
//! validation F1 is used unless one is forced. Early stopping uses the same validation F1.
//! The streaming detector ([`OnlineQuadFormer`]) chooses its own mode and threshold the same
//! way on the validation split's streaming scores ([`QuadFormerDetector::stream`]): a step
//! scored as the newest of its window is a different score from the stitched batch one, and
//! the mode that ranks best offline need not rank best there.

use candle_core::{D, Device, Tensor};
use detection_metrics::{best_f1_smoothing, best_f1_threshold, centred_mean, smoothing};
use ekf_residue::{DetectError, Detector, Fit, LabelledResidues, OnlineDetector, ResidueSeries, check_channels};
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
use crate::model::{GradFlow, LossConfig, MinMaxTrainer, NetConfig, QuadFormerNet};
use crate::streaming::StreamingNet;
use nn_toolkit::train::{TrainConfig, TrainReport, train_on};
use nn_toolkit::window::{Features, Normaliser, WindowConfig, Windows};

/// How per-step scores are formed from the network outputs (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ScoreMode {
    /// `softmax(−TCD)` over the window (alg:alg2).
    Alg2,
    /// `softmax(−τ·TCD)` times the reconstruction error (Anomaly Transformer).
    AnomalyTransformer,
    /// Classification-head probability.
    Classifier,
    /// Mean of the probability and the squashed Anomaly Transformer criterion.
    Combined,
}

impl ScoreMode {
    /// All modes, in the order used to break ties.
    pub const ALL: [ScoreMode; 4] =
        [ScoreMode::Combined, ScoreMode::Classifier, ScoreMode::AnomalyTransformer, ScoreMode::Alg2];

    /// Whether the mode reads the window's TCD (every mode but the classifier).
    pub fn reads_tcd(self) -> bool {
        !matches!(self, ScoreMode::Classifier)
    }

    /// Short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            ScoreMode::Alg2 => "softmax(-TCD)",
            ScoreMode::AnomalyTransformer => "AT criterion",
            ScoreMode::Classifier => "classifier",
            ScoreMode::Combined => "combined",
        }
    }
}

/// Scoring settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScoreConfig {
    /// Temperature `τ` of the Anomaly Transformer criterion. Default 50 (Anomaly Transformer
    /// `solver.test`).
    pub temperature: f64,
    /// Steps between windows when scoring a whole series (scores of overlapping windows are
    /// averaged, four per step at the default). Default 25: the same validation F1 as 10 over
    /// the eight cells of the matrix at 2.5 times fewer windows
    /// (docs/decisions/041-window-stride.md).
    pub stride: usize,
    /// Steps between windows when the validation split is scored after each training epoch
    /// for early stopping; the final mode and threshold are always chosen at `stride`. A value
    /// above the window length is treated as the window length. Default 50, half a default
    /// window: every step is still covered twice (docs/decisions/065-training-cost.md).
    #[serde(default = "default_epoch_stride")]
    pub epoch_stride: usize,
    /// Use this mode instead of choosing on validation F1. Default `None`.
    pub mode: Option<ScoreMode>,
    /// Choose, with each mode's threshold, a centred moving mean of its offline scores over
    /// none, a quarter, half or one window on either side
    /// ([`detection_metrics::smoothing`]); `false` keeps the stitched scores. Default `true`
    /// (docs/decisions/048-score-smoothing.md). The streaming score is never smoothed.
    #[serde(default = "default_smoothing")]
    pub smoothing: bool,
    /// Windows per inference batch. Default 64 (memory bound, not a model choice).
    pub batch_size: usize,
}

fn default_epoch_stride() -> usize {
    50
}

fn default_smoothing() -> bool {
    true
}

impl Default for ScoreConfig {
    fn default() -> Self {
        Self {
            temperature: 50.0,
            stride: 25,
            epoch_stride: default_epoch_stride(),
            mode: None,
            smoothing: true,
            batch_size: 64,
        }
    }
}

/// Everything needed to train a QUADFormer detector ([`Fit`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuadFormerConfig {
    /// Window length and training stride.
    pub window: WindowConfig,
    /// Architecture.
    pub net: NetConfig,
    /// Loss weights and min-max schedule.
    pub loss: LossConfig,
    /// Training loop (its `seed` also seeds the weights).
    pub train: TrainConfig,
    /// Scoring.
    pub score: ScoreConfig,
}

impl Default for QuadFormerConfig {
    /// The configuration chosen on validation (docs/decisions/004-training-budget.md,
    /// 044-whitened-inputs.md, 094-drift-channel.md and 095-absorbed-offset-channels.md):
    /// windows of 100 whitened steps with the GLR drift channel and the absorbed-offset
    /// channels every 20 steps, every window in
    /// every epoch with half of each epoch's windows drawn from labelled flights, each window
    /// mirrored with probability ½ and each labelled one mixed with another with probability ½
    /// (docs/decisions/047-mixed-windows.md), up to 20 epochs at a learning rate that falls by
    /// 0.85 per epoch, stopped after 3 epochs without a better validation F1.
    fn default() -> Self {
        Self {
            window: WindowConfig {
                stride: 20,
                features: Features::WhitenedLogDriftAbsorbed,
                ..WindowConfig::default()
            },
            net: NetConfig::default(),
            loss: LossConfig::default(),
            train: TrainConfig {
                epochs: 20,
                lr_decay: 0.85,
                patience: 3,
                labelled_share: Some(0.5),
                mirror: true,
                mix: 0.5,
                ..TrainConfig::default()
            },
            score: ScoreConfig::default(),
        }
    }
}

impl QuadFormerConfig {
    /// A small configuration for tests and quick runs: `l` = `len`, `d_model` 16, 2 layers.
    pub fn tiny(len: usize) -> Self {
        let stride = (len / 4).max(1);
        Self {
            window: WindowConfig { len, stride, ..WindowConfig::default() },
            net: NetConfig { d_model: 16, n_layers: 2, d_ff: 32, d_class: 16, ..NetConfig::default() },
            train: TrainConfig { progress: false, ..TrainConfig::default() },
            score: ScoreConfig { stride, ..ScoreConfig::default() },
            ..Self::default()
        }
    }

    /// Checks every part.
    ///
    /// # Errors
    /// [`ModelError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        self.window.check()?;
        self.net.check()?;
        self.train.check_for(&self.window)?;
        // The largest activation of a batch: attention maps (heads × len²) or hidden states
        // (len × width) of every window of the batch.
        let len = self.window.len as u64;
        let width = (self.net.d_model.max(self.net.d_ff)) as u64;
        let per_window = (self.net.n_heads as u64).saturating_mul(len * len).max(len.saturating_mul(width));
        for (field, batch) in [("train.batch_size", self.train.batch_size), ("score.batch_size", self.score.batch_size)]
        {
            let elems = (batch as u64).saturating_mul(per_window);
            if elems > MAX_ACTIVATIONS {
                return Err(ModelError::Config {
                    field,
                    msg: format!(
                        "{batch} windows of {len} steps make activations of {elems} numbers, more than the budget of \
                         {MAX_ACTIVATIONS}; lower the batch size, window.len or the network's width"
                    ),
                });
            }
        }
        let l = &self.loss;
        for (field, v) in [
            ("loss.lambda", l.lambda),
            ("loss.alpha1", l.alpha1),
            ("loss.alpha2", l.alpha2),
            ("loss.pos_weight", l.pos_weight),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ModelError::Config { field, msg: format!("must be finite and non-negative, got {v}") });
            }
        }
        if !(self.score.temperature.is_finite() && self.score.temperature > 0.0) {
            return Err(ModelError::Config { field: "score.temperature", msg: "must be finite and positive".into() });
        }
        for (field, v) in [
            ("score.stride", self.score.stride),
            ("score.epoch_stride", self.score.epoch_stride),
            ("score.batch_size", self.score.batch_size),
        ] {
            if v == 0 {
                return Err(ModelError::Config { field, msg: "must be at least 1".into() });
            }
            if field == "score.batch_size" && v > nn_toolkit::train::MAX_BATCH_SIZE {
                return Err(ModelError::Config {
                    field,
                    msg: format!("{v} exceeds the budget of {}", nn_toolkit::train::MAX_BATCH_SIZE),
                });
            }
        }
        Ok(())
    }
}

pub use nn_toolkit::train::MAX_ACTIVATIONS;

/// Validation result of one scoring mode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeResult {
    /// The mode.
    pub mode: ScoreMode,
    /// Half-width, in steps, of the centred moving mean applied to the mode's offline scores
    /// ([`detection_metrics::centred_mean`]), chosen with the threshold; 0 = none.
    #[serde(default)]
    pub smooth: usize,
    /// Best-F1 threshold on the (smoothed) scores of the validation split.
    pub threshold: f64,
    /// Per-step F1 at that threshold on the validation split.
    pub valid_f1: f64,
}

/// Per-step scores of the three raw modes for one series.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RawScores {
    /// `softmax(−TCD)`.
    pub alg2: Vec<f64>,
    /// Anomaly Transformer criterion.
    pub at: Vec<f64>,
    /// Classifier probability.
    pub class: Vec<f64>,
}

impl RawScores {
    /// The scores of `mode`; `crit_scale` is `a₅₀` of [`ScoreMode::Combined`].
    pub fn mode(&self, mode: ScoreMode, crit_scale: f64) -> Vec<f64> {
        match mode {
            ScoreMode::Alg2 => self.alg2.clone(),
            ScoreMode::AnomalyTransformer => self.at.clone(),
            ScoreMode::Classifier => self.class.clone(),
            ScoreMode::Combined => self.class.iter().zip(&self.at).map(|(p, a)| combine(*p, *a, crit_scale)).collect(),
        }
    }
}

/// The streaming engine of `net`, or `None` where it cannot represent the network.
///
/// # Errors
/// Errors of [`StreamingNet::new`] other than [`ModelError::StreamingUnsupported`].
pub(crate) fn streaming_engine(net: &QuadFormerNet) -> Result<Option<StreamingNet>> {
    match StreamingNet::new(net) {
        Ok(engine) => Ok(Some(engine)),
        Err(ModelError::StreamingUnsupported { .. }) => Ok(None),
        Err(e) => Err(e),
    }
}

fn combine(p: f64, a: f64, crit_scale: f64) -> f64 {
    0.5 * p + 0.5 * a / (a + crit_scale)
}

/// Per-window per-step raw scores `(alg2, at, class)`, each `b·l` row-major.
fn window_scores(net: &QuadFormerNet, x: &Tensor, temperature: f64) -> candle_core::Result<[Vec<f32>; 3]> {
    let out = net.forward(x)?;
    // Both TCD scores normalise over every step of the window.
    let neg_tcd = QuadFormerNet::tcd(&out, GradFlow::Stop, GradFlow::Stop)?.neg()?;
    let alg2 = candle_nn::ops::softmax(&neg_tcd, D::Minus1)?;
    let err = (&out.r_hat - x)?.sqr()?.mean(D::Minus1)?;
    let at = (candle_nn::ops::softmax(&(neg_tcd * temperature)?, D::Minus1)? * err)?;
    let class = candle_nn::ops::sigmoid(&out.logits)?;
    Ok([alg2.flatten_all()?.to_vec1()?, at.flatten_all()?.to_vec1()?, class.flatten_all()?.to_vec1()?])
}

/// Stitched raw scores of a whole series.
fn raw_scores(
    net: &QuadFormerNet,
    norm: &Normaliser,
    score: &ScoreConfig,
    series: &ResidueSeries,
) -> Result<RawScores> {
    let mut windows = Windows::empty(net.window_len(), net.dim());
    let sw = windows.push_series(series, None, norm, score.stride)?;
    let mut acc: [Vec<f32>; 3] = Default::default();
    let idx: Vec<usize> = (0..windows.len()).collect();
    for chunk in idx.chunks(score.batch_size) {
        let batch = windows.batch(chunk, net.device())?;
        let parts = window_scores(net, &batch.x, score.temperature)?;
        for (a, p) in acc.iter_mut().zip(parts) {
            a.extend(p);
        }
    }
    let [alg2, at, class] = acc;
    Ok(RawScores { alg2: sw.stitch(&alg2)?, at: sw.stitch(&at)?, class: sw.stitch(&class)? })
}

/// Validation calibration: `a₅₀` and every mode's threshold and F1.
struct Calibration {
    crit_scale: f64,
    results: Vec<ModeResult>,
}

fn calibrate(
    net: &QuadFormerNet,
    norm: &Normaliser,
    score: &ScoreConfig,
    valid: &LabelledResidues,
) -> Result<Calibration> {
    let mut scored: Vec<(RawScores, &[bool])> = Vec::new();
    for (series, labels) in valid.labelled() {
        scored.push((raw_scores(net, norm, score, series)?, labels));
    }
    let mut all_at: Vec<f64> = scored.iter().flat_map(|(s, _)| s.at.iter().copied()).collect();
    if all_at.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::Numerical { what: "non-finite anomaly criterion on the validation split".into() });
    }
    all_at.sort_by(f64::total_cmp);
    let crit_scale = all_at.get(all_at.len() / 2).copied().unwrap_or(1.0).max(f64::MIN_POSITIVE);
    let half_widths = if score.smoothing { smoothing::half_widths(net.window_len()) } else { vec![0] };
    let mut results = Vec::with_capacity(ScoreMode::ALL.len());
    for mode in ScoreMode::ALL {
        let per_flight: Vec<Vec<f64>> = scored.iter().map(|(s, _)| s.mode(mode, crit_scale)).collect();
        let flights: Vec<(&[f64], &[bool])> =
            per_flight.iter().zip(&scored).map(|(s, (_, l))| (s.as_slice(), *l)).collect();
        let best = best_f1_smoothing(&flights, &half_widths).map_err(ekf_residue::DetectError::from)?;
        results.push(ModeResult { mode, smooth: best.half_width, threshold: best.threshold, valid_f1: best.f1 });
    }
    Ok(Calibration { crit_scale, results })
}

fn chosen(results: &[ModeResult], forced: Option<ScoreMode>) -> Result<ModeResult> {
    let pick = match forced {
        Some(m) => results.iter().find(|r| r.mode == m),
        // First of the best in `ScoreMode::ALL` order.
        None => results.iter().fold(None::<&ModeResult>, |best, r| match best {
            Some(b) if b.valid_f1 >= r.valid_f1 => Some(b),
            _ => Some(r),
        }),
    };
    pick.copied().ok_or_else(|| ModelError::Data { msg: "no scoring mode could be calibrated".into() })
}

/// The streamed mode: every mode's best-F1 threshold on the validation split's streaming
/// scores, and the best of them (or the forced mode), chosen as [`chosen`] chooses the batch mode.
fn stream_choice(streamed: &[(RawScores, &[bool])], crit_scale: f64, forced: Option<ScoreMode>) -> Result<ModeResult> {
    let mut results = Vec::with_capacity(ScoreMode::ALL.len());
    for mode in ScoreMode::ALL {
        let per_flight: Vec<Vec<f64>> = streamed.iter().map(|(s, _)| s.mode(mode, crit_scale)).collect();
        let flights = per_flight.iter().zip(streamed).map(|(s, (_, l))| (s.as_slice(), *l));
        let (threshold, valid_f1) = best_f1_threshold(flights).map_err(DetectError::from)?;
        results.push(ModeResult { mode, smooth: 0, threshold, valid_f1 });
    }
    chosen(&results, forced)
}

/// A fitted QUADFormer detector.
pub struct QuadFormerDetector {
    pub(crate) config: QuadFormerConfig,
    pub(crate) net: QuadFormerNet,
    /// The network prepared for streaming, cloned by each [`OnlineQuadFormer`]; `None` where
    /// the engine cannot represent the network ([`StreamingNet::unsupported`]), and the online
    /// detector runs the candle forward pass on its window instead.
    pub(crate) streaming: Option<StreamingNet>,
    pub(crate) norm: Normaliser,
    pub(crate) chosen: ModeResult,
    pub(crate) crit_scale: f64,
    /// The streamed mode and its threshold, chosen on the validation split's streaming scores
    /// (`smooth` is always 0: a streaming score reads no later step).
    pub(crate) stream: ModeResult,
    pub(crate) mode_results: Vec<ModeResult>,
    pub(crate) report: Option<TrainReport>,
}

impl std::fmt::Debug for QuadFormerDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QuadFormerDetector")
            .field("channels", &self.norm.channels)
            .field("chosen", &self.chosen)
            .field("stream", &self.stream)
            .field("n_params", &self.net.n_params())
            .finish_non_exhaustive()
    }
}

impl Fit for QuadFormerConfig {
    type Detector = QuadFormerDetector;
    type Error = ModelError;

    /// Trains on the CPU: [`QuadFormerConfig::fit_on`] with [`Device::Cpu`].
    fn fit(&self, train_split: &LabelledResidues, valid: &LabelledResidues) -> Result<QuadFormerDetector> {
        self.fit_on(train_split, valid, &Device::Cpu)
    }
}

impl QuadFormerConfig {
    /// Trains a detector with the network, its batches and its scoring on `device` (the CPU, or
    /// a CUDA device in a build with candle's `cuda` feature; the kernels of
    /// `nn_toolkit::fused` and [`crate::js`] run composed from candle's ops there). The
    /// streaming engine runs on the CPU whatever the device.
    ///
    /// # Errors
    /// As [`Fit::fit`]: bad configuration, empty or unlabelled data, candle errors.
    pub fn fit_on(
        &self,
        train_split: &LabelledResidues,
        valid: &LabelledResidues,
        device: &Device,
    ) -> Result<QuadFormerDetector> {
        self.check()?;
        if train_split.n_steps() == 0 {
            return Err(ModelError::Data { msg: "empty training split".into() });
        }
        if valid.channels() != train_split.channels() {
            return Err(DetectError::ChannelMismatch {
                expected: train_split.channels().to_vec(),
                got: valid.channels().to_vec(),
            }
            .into());
        }
        if !valid.labelled().any(|(_, l)| l.iter().any(|&a| a)) {
            return Err(ModelError::Data {
                msg: "the validation split needs labelled flights with attacks to choose the mode and threshold".into(),
            });
        }
        let norm = Normaliser::fit(train_split, self.window.features)?;
        let windows = Windows::for_training(train_split, &norm, &self.window)?;
        let mut net = QuadFormerNet::new_on(&self.net, self.window.len, norm.dim(), self.train.seed, device)?;
        let report = {
            let trainer = MinMaxTrainer { net: &net, loss: self.loss };
            // Early stopping selects the network, which the streaming detector shares, on its
            // own scores: unsmoothed (smoothing is chosen once, on the final network).
            let epoch_score = ScoreConfig { stride: self.score.epoch_stride, smoothing: false, ..self.score.clone() };
            let mut valid_metric = |t: &MinMaxTrainer<'_>| -> Result<f64> {
                let cal = calibrate(t.net, &norm, &epoch_score, valid)?;
                Ok(-chosen(&cal.results, self.score.mode)?.valid_f1)
            };
            train_on(&trainer, net.varmap(), &windows, &self.train, device, &mut valid_metric)?
        };
        net.freeze()?;
        let cal = calibrate(&net, &norm, &self.score, valid)?;
        let chosen = chosen(&cal.results, self.score.mode)?;
        let mut det = QuadFormerDetector {
            config: self.clone(),
            streaming: streaming_engine(&net)?,
            net,
            norm,
            chosen,
            crit_scale: cal.crit_scale,
            stream: chosen,
            mode_results: cal.results,
            report: Some(report),
        };
        let streamed = valid
            .labelled()
            .map(|(series, labels)| Ok((det.online_quadformer().raw_scores(series)?, labels)))
            .collect::<Result<Vec<_>>>()?;
        det.stream = stream_choice(&streamed, det.crit_scale, self.score.mode)?;
        Ok(det)
    }
}

impl QuadFormerDetector {
    /// The configuration it was trained with.
    pub fn config(&self) -> &QuadFormerConfig {
        &self.config
    }

    /// The network.
    pub fn net(&self) -> &QuadFormerNet {
        &self.net
    }

    /// The normaliser fitted on the training split.
    pub fn normaliser(&self) -> &Normaliser {
        &self.norm
    }

    /// The scoring mode in use, its threshold and validation F1.
    pub fn chosen(&self) -> ModeResult {
        self.chosen
    }

    /// The streamed mode (what [`OnlineQuadFormer`] scores), its threshold and F1 on the
    /// validation split's streaming scores.
    pub fn stream(&self) -> ModeResult {
        self.stream
    }

    /// Every mode's validation threshold and F1 (ablation table).
    pub fn mode_results(&self) -> &[ModeResult] {
        &self.mode_results
    }

    /// The training history (`None` for a loaded checkpoint).
    pub fn train_report(&self) -> Option<&TrainReport> {
        self.report.as_ref()
    }

    /// Stitched raw scores of a series (all modes at once).
    ///
    /// # Errors
    /// Channel mismatch; candle errors.
    pub fn raw_scores(&self, series: &ResidueSeries) -> Result<RawScores> {
        raw_scores(&self.net, &self.norm, &self.config.score, series)
    }

    /// Per-step scores of `series` in every mode, with each mode's validation threshold.
    ///
    /// # Errors
    /// As [`QuadFormerDetector::raw_scores`].
    pub fn scores_by_mode(&self, series: &ResidueSeries) -> Result<Vec<(ModeResult, Vec<f64>)>> {
        let raw = self.raw_scores(series)?;
        Ok(self.mode_results.iter().map(|r| (*r, centred_mean(&raw.mode(r.mode, self.crit_scale), r.smooth))).collect())
    }

    /// Whether streaming decisions run in the streaming engine ([`StreamingNet`]); otherwise
    /// they run the candle forward pass on the sliding window (same scores up to rounding,
    /// slower).
    pub fn streams_with_engine(&self) -> bool {
        self.streaming.is_some()
    }

    /// A streaming detector ([`OnlineQuadFormer`]).
    pub fn online_quadformer(&self) -> OnlineQuadFormer<'_> {
        OnlineQuadFormer::new(self)
    }
}

impl Detector for QuadFormerDetector {
    fn name(&self) -> &str {
        "QUADFormer"
    }

    fn channels(&self) -> &[String] {
        &self.norm.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        check_channels(&self.norm.channels, series)?;
        Ok(centred_mean(&self.raw_scores(series)?.mode(self.chosen.mode, self.crit_scale), self.chosen.smooth))
    }

    fn threshold(&self) -> f64 {
        self.chosen.threshold
    }

    /// Chosen at `fit` with the streamed mode on the validation split's streaming scores: a
    /// window that ends at the step sees no later step, so its scores are distributed
    /// differently from the batch scores.
    fn streaming_threshold(&self) -> f64 {
        self.stream.threshold
    }

    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        Box::new(self.online_quadformer())
    }

    fn online_window(&self) -> usize {
        self.net.window_len()
    }
}

pub use online::OnlineQuadFormer;

mod online;

#[cfg(test)]
mod tests;
