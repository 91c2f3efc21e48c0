//! 1-D CNN and LSTM per-step classifiers in candle (the CNN and LSTM baselines of Wu et al.
//! 2023 and Wang et al. 2020 in the paper's tables, fed residue windows as the paper does in
//! Sec. V-E).
//!
//! Both share QUADFormer's data path and loop (`nn_toolkit`): per-channel
//! [`Normaliser`] fitted on the labelled training flights, [`Windows`] of `l` steps × `m`
//! channels (`b × l × m` tensors), the seeded AdamW [`train()`] loop with early stopping on the
//! validation BCE, [`init_vars_seeded`] for seeded initialisation, and
//! [`nn_toolkit::SeriesWindows::stitch`] to turn per-window, per-step logits into one score per step (the
//! mean over the covering windows). The loss is the masked per-step binary cross-entropy with
//! logits; the alarm threshold on the stitched logit is chosen on the validation split (best
//! F1). They train on the labelled flights only (the same subset as QUADFormer's
//! classification head, docs/decisions/001-validation-split-labels.md).
//!
//! Architectures (`b × l × m` in, `b × l` logits out):
//! - CNN: `Conv1d(m→c, k) → ReLU → Conv1d(c→c, k) → ReLU → Conv1d(c→1, 1)`, with `c = 32`,
//!   `k = 5` (a small choice; the paper gives no architecture, decision 052). The
//!   convolutions are causal (`k − 1` zeros on the left only), so a step's logit depends on
//!   the last `2k − 1` steps and the streaming detector (last step of the latest window) agrees
//!   with the stitched batch score except where a window start cuts that history.
//! - LSTM: one forward `LSTM(m→h)` over the window ([`crate::lstm`]), `h = 64`, then
//!   `Linear(h→1)` on every hidden state (decision 052). Only the past inside the
//!   window is seen.
//!
//! Saved state ([`NeuralDetector::encode`], [`Cnn::decode`], [`Lstm::decode`]): the weights as
//! safetensors and a JSON [`NeuralManifest`] (configuration, channels, normaliser, both
//! thresholds, training report, size and SHA-256 of the weights); a decoded detector scores
//! bit for bit what the fitted one scored.

use candle_core::{D, DType, Device, Module, Tensor};
use candle_nn::{Conv1d, Conv1dConfig, Linear, VarBuilder, VarMap};
use ekf_residue::{
    DetectError, Detector, Fit, LabelledResidues, LabelledSeries, OnlineDetector, ResidueSeries, WindowedOnline,
};
use nn_toolkit::loss::masked_bce_with_logits;
use nn_toolkit::saved::sha256_hex;
use nn_toolkit::{
    Batch, Features, Normaliser, TrainConfig, TrainableModel, WindowConfig, Windows, init_vars_seeded, train,
};
use serde::{Deserialize, Serialize};

use crate::common::{fit_channels, labelled_valid};
use crate::error::{BaselineError, Result};
use crate::lstm::LstmLayer;
use crate::lstm_online::{LstmWeights, OnlineLstm};

/// Budget of `hidden` (CNN channels, LSTM hidden size): weights and activations grow with
/// its square.
pub const MAX_HIDDEN: usize = 4_096;

impl NeuralConfig {
    /// Checks sizes and ranges, and the budget [`MAX_HIDDEN`].
    ///
    /// # Errors
    /// [`BaselineError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        self.window.check()?;
        self.train.check_for(&self.window)?;
        if !(self.pos_weight.is_finite() && self.pos_weight >= 0.0) {
            return Err(BaselineError::Config {
                field: "pos_weight",
                msg: format!("must be finite and non-negative, got {}", self.pos_weight),
            });
        }
        if self.hidden > MAX_HIDDEN {
            return Err(BaselineError::Config {
                field: "hidden",
                msg: format!("{} exceeds the budget of {MAX_HIDDEN}", self.hidden),
            });
        }
        let batch = self.train.batch_size.max(SCORE_BATCH) as u64;
        let elems = batch.saturating_mul(self.window.len as u64).saturating_mul(self.hidden as u64);
        if elems > nn_toolkit::train::MAX_ACTIVATIONS {
            return Err(BaselineError::Config {
                field: "train.batch_size",
                msg: format!(
                    "{batch} windows of {} steps × {} hidden make activations of {elems} numbers, more than the \
                     budget of {}",
                    self.window.len,
                    self.hidden,
                    nn_toolkit::train::MAX_ACTIVATIONS
                ),
            });
        }
        if self.kernel > self.window.len {
            return Err(BaselineError::Config {
                field: "kernel",
                msg: format!("{} exceeds the window length {}", self.kernel, self.window.len),
            });
        }
        if self.hidden == 0 || self.kernel == 0 || self.score_stride == 0 {
            return Err(BaselineError::Config {
                field: "hidden",
                msg: format!(
                    "need hidden, kernel and score_stride ≥ 1, got {}, {}, {}",
                    self.hidden, self.kernel, self.score_stride
                ),
            });
        }
        Ok(())
    }
}

/// Windows per forward pass when scoring.
const SCORE_BATCH: usize = 64;

/// Hyper-parameters shared by the CNN and LSTM baselines.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NeuralConfig {
    /// Window length, training stride and features. Default: QUADFormer's windows, `l = 100`
    /// at stride 20 of whitened residues with the drift and absorbed-offset channels
    /// (docs/decisions/044-whitened-inputs.md, 095-absorbed-offset-channels.md).
    pub window: WindowConfig,
    /// Stride between windows when scoring a series (each step's score is the mean over its
    /// covering windows). Default 50 (`l/2`: every step seen twice, half the cost of stride 25).
    pub score_stride: usize,
    /// Training loop. Default: up to 30 epochs at learning rate 3·10⁻³ without decay, stopped
    /// after 4 epochs without a better validation BCE, i.e. trained to convergence
    /// (docs/decisions/053-baseline-training-budgets.md).
    pub train: TrainConfig,
    /// Channels of the CNN's hidden layers, or the LSTM's hidden size. Default 32 for the CNN,
    /// 64 for the LSTM (docs/decisions/052-cnn-lstm-baselines.md).
    pub hidden: usize,
    /// CNN kernel size (unused by the LSTM). Default 5 (docs/decisions/052).
    pub kernel: usize,
    /// Weight of attacked steps in the BCE (class imbalance), as QUADFormer's
    /// `loss.pos_weight`. Default 1.
    #[serde(default = "one")]
    pub pos_weight: f64,
    /// Choose, with the threshold, a centred moving mean of the offline scores over none, a
    /// quarter, half or one window on either side, as QUADFormer does
    /// ([`detection_metrics::smoothing`], docs/decisions/048-score-smoothing.md). Default `true`.
    #[serde(default = "yes")]
    pub smoothing: bool,
    /// Seed of the initial weights. Default 0.
    pub seed: u64,
}

/// Hyper-parameters of the CNN baseline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CnnConfig(pub NeuralConfig);

/// Hyper-parameters of the LSTM baseline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LstmConfig(pub NeuralConfig);

impl Default for CnnConfig {
    fn default() -> Self {
        Self(NeuralConfig {
            window: WindowConfig {
                stride: 20,
                features: Features::WhitenedLogDriftAbsorbed,
                ..WindowConfig::default()
            },
            score_stride: 50,
            train: TrainConfig {
                epochs: 30,
                lr: 3e-3,
                lr_decay: 1.0,
                patience: 4,
                mirror: true,
                mix: 0.5,
                ..TrainConfig::default()
            },
            hidden: 32,
            kernel: 5,
            pos_weight: 1.0,
            smoothing: true,
            seed: 0,
        })
    }
}

impl Default for LstmConfig {
    fn default() -> Self {
        Self(NeuralConfig { hidden: 64, ..CnnConfig::default().0 })
    }
}

fn yes() -> bool {
    true
}

fn one() -> f64 {
    1.0
}

/// A network that maps normalised windows `b × l × m` to per-step logits `b × l`.
pub trait PerStepNet: Send + Sync {
    /// Per-step logits.
    ///
    /// # Errors
    /// Any candle error.
    fn logits(&self, x: &Tensor) -> candle_core::Result<Tensor>;

    /// The network's own streaming detector for windows of `l` steps normalised by `norm`,
    /// alarming when the newest step's logit exceeds `threshold`; it must score exactly what
    /// [`PerStepNet::logits`] gives the last step of the window. `None` (the default): the
    /// detector re-scores each window with [`PerStepNet::logits`] ([`WindowedOnline`]).
    fn online<'a>(&self, _norm: &'a Normaliser, _l: usize, _threshold: f64) -> Option<Box<dyn OnlineDetector + 'a>> {
        None
    }
}

/// The CNN of the module docs.
#[derive(Debug, Clone)]
pub struct CnnNet {
    kernel: usize,
    conv1: Conv1d,
    conv2: Conv1d,
    head: Conv1d,
}

impl CnnNet {
    fn new(m: usize, c: usize, k: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        let valid = Conv1dConfig::default();
        Ok(Self {
            kernel: k,
            conv1: candle_nn::conv1d(m, c, k, valid, vb.pp("conv1"))?,
            conv2: candle_nn::conv1d(c, c, k, valid, vb.pp("conv2"))?,
            head: candle_nn::conv1d(c, 1, 1, Conv1dConfig::default(), vb.pp("head"))?,
        })
    }
}

impl PerStepNet for CnnNet {
    fn logits(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        // Conv1d wants b × channels × l; causal: k − 1 zeros on the left, none on the right.
        let pad = self.kernel - 1;
        let h = x.transpose(1, 2)?.pad_with_zeros(D::Minus1, pad, 0)?;
        let h = conv1d_unfolded(&self.conv1, &h)?.relu()?.pad_with_zeros(D::Minus1, pad, 0)?;
        let h = conv1d_unfolded(&self.conv2, &h)?.relu()?;
        conv1d_unfolded(&self.head, &h)?.squeeze(1)
    }
}

/// `conv.forward(x)` (`b × c_in × l` in, `b × c_out × (l − k + 1)` out, stride 1, no padding)
/// as the product of the unfolded windows with the kernel, so that both gradients are right.
/// candle 0.11.1's CPU `conv1d` backward convolves with a transposed, non-contiguous kernel,
/// and its im2col path then multiplies the kernel's original storage instead of the
/// contiguous copy: the kernel's gradient comes out wrong (huggingface/candle#3836, open;
/// `conv1d` itself against finite differences was off by up to 1.0 on the test case below,
/// where this function is within 10⁻⁸). The weights keep `Conv1d`'s names and shapes.
fn conv1d_unfolded(conv: &Conv1d, x: &Tensor) -> candle_core::Result<Tensor> {
    let cfg = conv.config();
    if (cfg.padding, cfg.stride, cfg.dilation, cfg.groups) != (0, 1, 1, 1) {
        candle_core::bail!("conv1d_unfolded: stride 1, no padding, dilation or groups only");
    }
    let w = conv.weight();
    let (c_out, c_in, k) = w.dims3()?;
    let (b, _, l) = x.dims3()?;
    let Some(l_out) = (l + 1).checked_sub(k).filter(|&n| n > 0) else {
        candle_core::bail!("conv1d_unfolded: {l} steps, shorter than the kernel's {k}");
    };
    let taps = (0..k).map(|j| x.narrow(2, j, l_out)).collect::<candle_core::Result<Vec<_>>>()?;
    // b × c_in × l_out × k → (b · l_out) × (c_in · k), in the order of the kernel's entries.
    let cols = Tensor::stack(&taps, 3)?.permute((0, 2, 1, 3))?.contiguous()?.reshape((b * l_out, c_in * k))?;
    let y = cols.matmul(&w.reshape((c_out, c_in * k))?.t()?)?.reshape((b, l_out, c_out))?.transpose(1, 2)?;
    match conv.bias() {
        Some(bias) => y.broadcast_add(&bias.reshape((1, c_out, 1))?),
        None => Ok(y),
    }
}

/// The LSTM of the module docs.
#[derive(Debug, Clone)]
pub struct LstmNet {
    lstm: LstmLayer,
    head: Linear,
}

impl LstmNet {
    pub(crate) fn new(m: usize, h: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        Ok(Self { lstm: LstmLayer::new(m, h, vb.pp("lstm"))?, head: candle_nn::linear(h, 1, vb.pp("head"))? })
    }

    /// The weights as [`OnlineLstm`] reads them.
    pub(crate) fn weights(&self) -> candle_core::Result<LstmWeights> {
        let (m, h) = self.lstm.dims();
        let (w_ih, w_hh, bias) = self.lstm.weights()?;
        let head_w = self.head.weight().flatten_all()?.to_vec1::<f32>()?;
        let head_b = match self.head.bias() {
            Some(b) => b.flatten_all()?.to_vec1::<f32>()?.first().copied().unwrap_or(0.0),
            None => 0.0,
        };
        Ok(LstmWeights { m, h, w_ih, w_hh, bias, head_w, head_b })
    }
}

impl PerStepNet for LstmNet {
    fn logits(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let h = self.lstm.forward(x)?;
        self.head.forward(&h)?.squeeze(D::Minus1)
    }

    /// [`OnlineLstm`]: the recurrence without candle, the same logits (bit for bit for the
    /// per-step feature maps); `None` if the weights cannot be read into it.
    fn online<'a>(&self, norm: &'a Normaliser, l: usize, threshold: f64) -> Option<Box<dyn OnlineDetector + 'a>> {
        let online = OnlineLstm::new(self.weights().ok()?, norm, l, threshold).ok()?;
        Some(Box::new(online))
    }
}

/// A fitted CNN or LSTM detector.
pub struct NeuralDetector<N> {
    name: &'static str,
    config: NeuralConfig,
    channels: Vec<String>,
    pub(crate) norm: Normaliser,
    pub(crate) net: N,
    // Keeps the trained variables alive alongside the network that reads them.
    _varmap: VarMap,
    pub(crate) window: WindowConfig,
    score_stride: usize,
    /// Half-width of the centred moving mean of the offline scores, chosen on validation.
    smooth: usize,
    threshold: f64,
    /// Threshold of the streaming scores, chosen on validation.
    stream_threshold: f64,
    report: nn_toolkit::TrainReport,
}

/// The fitted CNN baseline.
pub type Cnn = NeuralDetector<CnnNet>;
/// The fitted LSTM baseline.
pub type Lstm = NeuralDetector<LstmNet>;

impl<N> std::fmt::Debug for NeuralDetector<N> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NeuralDetector")
            .field("name", &self.name)
            .field("channels", &self.channels)
            .field("window", &self.window)
            .field("threshold", &self.threshold)
            .finish_non_exhaustive()
    }
}

impl<N: PerStepNet> NeuralDetector<N> {
    /// The training report (epochs, losses, time) of the fit.
    pub fn train_report(&self) -> &nn_toolkit::TrainReport {
        &self.report
    }

    fn score_inner(&self, series: &ResidueSeries) -> Result<Vec<f64>> {
        let mut windows = Windows::empty(self.window.len, self.norm.dim());
        let sw = windows.push_series(series, None, &self.norm, self.score_stride)?;
        let mut logits = Vec::with_capacity(windows.len() * self.window.len);
        let idx: Vec<usize> = (0..windows.len()).collect();
        for chunk in idx.chunks(SCORE_BATCH) {
            let batch = windows.batch(chunk, &Device::Cpu)?;
            let z = self.net.logits(&batch.x).map_err(candle_err("scoring"))?;
            logits.extend(z.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(candle_err("scoring"))?);
        }
        Ok(sw.stitch(&logits)?)
    }

    /// The logit of the last step of `series` at the last position of the window ending at it.
    fn score_newest_inner(&self, series: &ResidueSeries) -> Result<f64> {
        let mut windows = Windows::empty(self.window.len, self.norm.dim());
        windows.push_newest(series, &self.norm)?;
        self.last_logits(&windows)?
            .pop()
            .ok_or_else(|| BaselineError::Detect(DetectError::Numerical { what: "empty score window".into() }))
    }

    /// Each window's logit at its last position, the windows run in batches.
    fn last_logits(&self, windows: &Windows) -> Result<Vec<f64>> {
        let l = self.window.len;
        let mut out = Vec::with_capacity(windows.len());
        let idx: Vec<usize> = (0..windows.len()).collect();
        for chunk in idx.chunks(SCORE_BATCH) {
            let batch = windows.batch(chunk, &Device::Cpu)?;
            let z = self.net.logits(&batch.x).map_err(candle_err("streaming scoring"))?;
            let z = z.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(candle_err("streaming scoring"))?;
            out.extend(z.chunks_exact(l).map(|w| f64::from(w[l - 1])));
        }
        Ok(out)
    }

    /// The streaming logits: step `k` scored at the last position of the window that ends at
    /// `k`, front-padded for `k < l − 1` as [`ekf_residue::WindowedOnline`] pads, so what
    /// [`Detector::online`] gives, to rounding: here the windows run in batches
    /// ([`Self::last_logits`]).
    fn score_streaming_inner(&self, series: &ResidueSeries) -> Result<Vec<f64>> {
        let (l, n) = (self.window.len, series.len());
        let mut windows = Windows::empty(l, self.norm.dim());
        for k in 0..n.min(l - 1) {
            windows.push_series(&series.slice(0..k + 1)?, None, &self.norm, l)?;
        }
        if n >= l {
            windows.push_series(series, None, &self.norm, 1)?;
        }
        self.last_logits(&windows)
    }
}

/// A fitted network's error as the [`Detector`] interface reports it.
fn into_detect_error(e: BaselineError) -> DetectError {
    match e {
        BaselineError::Detect(d) => d,
        BaselineError::Nn(m) => m.into(),
        other => DetectError::Backend(other.to_string()),
    }
}

fn candle_err(context: &'static str) -> impl Fn(candle_core::Error) -> BaselineError {
    move |e| BaselineError::Candle { context, msg: e.to_string() }
}

/// Adapter from a [`PerStepNet`] to the shared training loop: masked per-step BCE with the
/// positive-class weight.
struct Trainable<'a, N>(&'a N, f64);

impl<N: PerStepNet> TrainableModel for Trainable<'_, N> {
    fn loss(&self, batch: &Batch, _phase: usize) -> candle_core::Result<Tensor> {
        let z = self.0.logits(&batch.x)?;
        masked_bce_with_logits(&z, &batch.y, &batch.mask, batch.n_labelled, self.1)
    }
}

/// Only the labelled flights of a split.
fn labelled_only(split: &LabelledResidues) -> Result<LabelledResidues> {
    let flights: Vec<LabelledSeries> = split.flights().iter().filter(|f| f.labels().is_some()).cloned().collect();
    if flights.is_empty() {
        return Err(DetectError::Data { msg: "no labelled training flight".into() }.into());
    }
    Ok(LabelledResidues::new(flights)?)
}

fn fit_neural<N: PerStepNet>(
    name: &'static str,
    cfg: &NeuralConfig,
    train_split: &LabelledResidues,
    valid: &LabelledResidues,
    build: impl FnOnce(usize, VarBuilder) -> candle_core::Result<N>,
) -> Result<NeuralDetector<N>> {
    cfg.check()?;
    let channels = fit_channels(train_split, valid)?;
    let labelled = labelled_only(train_split)?;
    let norm = Normaliser::fit(&labelled, cfg.window.features)?;
    let windows = Windows::for_training(&labelled, &norm, &cfg.window)?;
    let pairs = labelled_valid(valid)?;
    let valid_labelled = labelled_only(valid)?;
    let valid_windows =
        Windows::from_split(&valid_labelled, &norm, &WindowConfig { stride: cfg.window.len, ..cfg.window })?;

    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let net = build(norm.dim(), vb).map_err(candle_err("building the network"))?;
    init_vars_seeded(&varmap, cfg.seed)?;
    let model = Trainable(&net, cfg.pos_weight);
    // Early stopping on the validation BCE (lower is better).
    let mut valid_loss = |m: &Trainable<'_, N>| -> nn_toolkit::Result<f64> {
        let idx: Vec<usize> = (0..valid_windows.len()).collect();
        let (mut sum, mut n) = (0.0, 0usize);
        for chunk in idx.chunks(SCORE_BATCH) {
            let batch = valid_windows.batch(chunk, &Device::Cpu)?;
            let loss = m.loss(&batch, 0)?;
            sum += f64::from(loss.to_scalar::<f32>()?) * batch.n_labelled as f64;
            n += batch.n_labelled;
        }
        Ok(sum / n.max(1) as f64)
    };
    let report = train(&model, &varmap, &windows, &cfg.train, &mut valid_loss)?;
    let mut det = NeuralDetector {
        name,
        config: cfg.clone(),
        channels,
        norm,
        net,
        _varmap: varmap,
        window: cfg.window,
        score_stride: cfg.score_stride,
        smooth: 0,
        threshold: 0.0,
        stream_threshold: 0.0,
        report,
    };
    let scores = pairs.iter().map(|(s, _)| det.score_inner(s)).collect::<Result<Vec<_>>>()?;
    let half_widths = if cfg.smoothing { detection_metrics::smoothing::half_widths(cfg.window.len) } else { vec![0] };
    let flights: Vec<(&[f64], &[bool])> = scores.iter().zip(&pairs).map(|(sc, (_, l))| (sc.as_slice(), *l)).collect();
    let chosen = detection_metrics::best_f1_smoothing(&flights, &half_widths)?;
    (det.smooth, det.threshold) = (chosen.half_width, chosen.threshold);
    let streamed = pairs.iter().map(|(s, _)| det.score_streaming_inner(s)).collect::<Result<Vec<_>>>()?;
    det.stream_threshold =
        detection_metrics::best_f1_threshold(streamed.iter().zip(&pairs).map(|(sc, (_, l))| (sc.as_slice(), *l)))?.0;
    Ok(det)
}

impl Fit for CnnConfig {
    type Detector = Cnn;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Cnn> {
        let (h, k) = (self.0.hidden, self.0.kernel);
        fit_neural("CNN", &self.0, train, valid, |m, vb| CnnNet::new(m, h, k, vb))
    }
}

impl Fit for LstmConfig {
    type Detector = Lstm;
    type Error = BaselineError;

    fn fit(&self, train: &LabelledResidues, valid: &LabelledResidues) -> Result<Lstm> {
        let h = self.0.hidden;
        fit_neural("LSTM", &self.0, train, valid, |m, vb| LstmNet::new(m, h, vb))
    }
}

impl<N: PerStepNet> Detector for NeuralDetector<N> {
    fn name(&self) -> &str {
        self.name
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        Ok(detection_metrics::centred_mean(&Stitched(self).score(series)?, self.smooth))
    }

    fn threshold(&self) -> f64 {
        self.threshold
    }

    fn streaming_threshold(&self) -> f64 {
        self.stream_threshold
    }

    fn score_streaming(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.channels, series)?;
        self.score_streaming_inner(series).map_err(into_detect_error)
    }

    /// Streaming re-scores the last `l` steps as one window and reports its last step's
    /// stitched logit, never smoothed (the batch score averages the windows covering a step,
    /// and may smooth them over later steps, so the two agree only approximately). The LSTM
    /// does so without candle ([`OnlineLstm`], the same logits bit for bit); the CNN through
    /// [`WindowedOnline`], which keeps [`Detector::online_window`] steps so that the window's
    /// features see the history they read.
    fn online(&self) -> Box<dyn OnlineDetector + '_> {
        let (l, threshold) = (self.window.len, self.stream_threshold);
        self.net
            .online(&self.norm, l, threshold)
            .unwrap_or_else(|| Box::new(WindowedOnline::new(Stitched(self), self.online_window())))
    }

    /// The window and the steps before it that its features read
    /// ([`nn_toolkit::Features::context`]):
    /// the stitched score of the newest step is that of the window ending at it alone.
    fn online_window(&self) -> usize {
        self.window.len + self.norm.features.context()
    }
}

/// A fitted network's stitched logits without the offline smoothing: what its streaming
/// detector re-scores on each window.
pub(crate) struct Stitched<'a, N>(pub(crate) &'a NeuralDetector<N>);

impl<N: PerStepNet> Detector for Stitched<'_, N> {
    fn name(&self) -> &str {
        self.0.name
    }

    fn channels(&self) -> &[String] {
        &self.0.channels
    }

    fn score(&self, series: &ResidueSeries) -> Result<Vec<f64>, DetectError> {
        ekf_residue::check_channels(&self.0.channels, series)?;
        self.0.score_inner(series).map_err(into_detect_error)
    }

    /// Not read by [`WindowedOnline`], which alarms at the streaming threshold.
    fn threshold(&self) -> f64 {
        self.0.threshold
    }

    fn streaming_threshold(&self) -> f64 {
        self.0.stream_threshold
    }

    fn online_window(&self) -> usize {
        self.0.online_window()
    }

    /// The newest step's stitched logit is that of the one window ending at it
    /// ([`nn_toolkit::SeriesWindows::newest`]), so only that window is scored.
    fn score_newest(&self, series: &ResidueSeries) -> Result<f64, DetectError> {
        ekf_residue::check_channels(&self.0.channels, series)?;
        self.0.score_newest_inner(series).map_err(into_detect_error)
    }
}

/// Format name of a [`NeuralManifest`].
pub const NEURAL_FORMAT: &str = "baselines-neural";
/// Current [`NeuralManifest`] version.
pub const NEURAL_VERSION: u32 = 1;
/// Largest weights file [`Cnn::decode`] and [`Lstm::decode`] accept, bytes.
pub const MAX_NEURAL_WEIGHTS_BYTES: u64 = 1 << 30;

/// The JSON manifest of a saved CNN or LSTM.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NeuralManifest {
    /// Always [`NEURAL_FORMAT`].
    pub format: String,
    /// [`NEURAL_VERSION`] when written.
    pub version: u32,
    /// `CNN` or `LSTM`.
    pub network: String,
    /// The configuration the network was built and trained with.
    pub config: NeuralConfig,
    /// Training channels, in order.
    pub channels: Vec<String>,
    /// Per-channel normaliser fitted on the labelled training flights.
    pub normaliser: Normaliser,
    /// Half-width of the centred moving mean of the batch scores, chosen on validation (0 in
    /// manifests written before smoothing: none).
    #[serde(default)]
    pub smooth: usize,
    /// Alarm threshold of the batch scores, chosen on validation.
    pub threshold: f64,
    /// Alarm threshold of the streaming scores, chosen on validation.
    pub stream_threshold: f64,
    /// What training did.
    pub report: nn_toolkit::TrainReport,
    /// Size of the weights in bytes.
    pub weights_bytes: u64,
    /// Lower-case hex SHA-256 of the weights.
    pub weights_sha256: String,
}

/// A saved CNN or LSTM: the manifest text and the safetensors bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NeuralFiles {
    /// Text of the JSON manifest.
    pub manifest: String,
    /// Safetensors bytes of the weights.
    pub weights: Vec<u8>,
}

impl<N: PerStepNet> NeuralDetector<N> {
    /// Encodes the fitted detector (module docs).
    ///
    /// # Errors
    /// [`BaselineError::State`] if the weights or the manifest cannot be encoded.
    pub fn encode(&self) -> Result<NeuralFiles> {
        crate::state::check_finite("threshold, stream_threshold", &[self.threshold, self.stream_threshold])?;
        let weights = {
            let data =
                self._varmap.data().lock().map_err(|_| crate::state::state_err("variable map lock poisoned".into()))?;
            let tensors: Vec<(String, Tensor)> = data.iter().map(|(k, v)| (k.clone(), v.as_tensor().clone())).collect();
            safetensors::tensor::serialize(tensors, None)
                .map_err(|e| crate::state::state_err(format!("cannot encode the weights: {e}")))?
        };
        let manifest = NeuralManifest {
            format: NEURAL_FORMAT.into(),
            version: NEURAL_VERSION,
            network: self.name.into(),
            config: self.config.clone(),
            channels: self.channels.clone(),
            normaliser: self.norm.clone(),
            smooth: self.smooth,
            threshold: self.threshold,
            stream_threshold: self.stream_threshold,
            report: self.report.clone(),
            weights_bytes: weights.len() as u64,
            weights_sha256: sha256_hex(&weights),
        };
        let manifest = serde_json::to_string_pretty(&manifest)
            .map_err(|e| crate::state::state_err(format!("cannot serialise the manifest: {e}")))?;
        Ok(NeuralFiles { manifest, weights })
    }
}

/// Decodes a saved network named `name`, built by `build` from the manifest's configuration.
fn decode_neural<N: PerStepNet>(
    name: &'static str,
    manifest: &str,
    weights: &[u8],
    build: impl FnOnce(usize, &NeuralConfig, VarBuilder) -> candle_core::Result<N>,
) -> Result<NeuralDetector<N>> {
    use crate::state::{check_channels, check_finite, state_err};
    let m: NeuralManifest =
        serde_json::from_str(manifest).map_err(|e| state_err(nn_toolkit::saved::malformed_json("manifest", &e)))?;
    if m.format != NEURAL_FORMAT || m.version != NEURAL_VERSION {
        return Err(state_err(format!(
            "format `{}` version {}, this build reads `{NEURAL_FORMAT}` version {NEURAL_VERSION}",
            m.format, m.version
        )));
    }
    if m.network != name {
        return Err(state_err(format!("network: `{}`, expected `{name}`", m.network)));
    }
    m.config.check()?;
    check_channels(&m.channels)?;
    m.normaliser.check()?;
    if m.normaliser.channels != m.channels {
        return Err(state_err("normaliser.channels: differ from channels".into()));
    }
    check_finite("threshold, stream_threshold", &[m.threshold, m.stream_threshold])?;
    if m.weights_bytes > MAX_NEURAL_WEIGHTS_BYTES || weights.len() as u64 != m.weights_bytes {
        return Err(state_err(format!(
            "weights: {} bytes, the manifest says {} (truncated or extended)",
            weights.len(),
            m.weights_bytes
        )));
    }
    if sha256_hex(weights) != m.weights_sha256 {
        return Err(state_err("weights: corrupted, SHA-256 differs from the manifest".into()));
    }
    let tensors = candle_core::safetensors::load_buffer(weights, &Device::Cpu)
        .map_err(|e| state_err(format!("weights: not a safetensors file: {e}")))?;
    let mut varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let net = build(m.normaliser.dim(), &m.config, vb).map_err(candle_err("building the network"))?;
    {
        let data = varmap.data().lock().map_err(|_| state_err("variable map lock poisoned".into()))?;
        let mut expected: Vec<&String> = data.keys().collect();
        expected.sort();
        let mut found: Vec<&String> = tensors.keys().collect();
        found.sort();
        if expected != found {
            return Err(state_err(format!("weights: tensors {found:?} do not match the network's {expected:?}")));
        }
    }
    for (k, t) in &tensors {
        varmap.set_one(k, t).map_err(|e| state_err(format!("weights: {e}")))?;
    }
    Ok(NeuralDetector {
        name,
        window: m.config.window,
        score_stride: m.config.score_stride,
        config: m.config,
        channels: m.channels,
        norm: m.normaliser,
        net,
        _varmap: varmap,
        smooth: m.smooth,
        threshold: m.threshold,
        stream_threshold: m.stream_threshold,
        report: m.report,
    })
}

impl Cnn {
    /// Decodes the files of [`NeuralDetector::encode`] of a CNN.
    ///
    /// # Errors
    /// [`BaselineError::State`] naming what is malformed, inconsistent, truncated or corrupted.
    pub fn decode(manifest: &str, weights: &[u8]) -> Result<Self> {
        decode_neural("CNN", manifest, weights, |m, c, vb| CnnNet::new(m, c.hidden, c.kernel, vb))
    }
}

impl Lstm {
    /// Decodes the files of [`NeuralDetector::encode`] of an LSTM.
    ///
    /// # Errors
    /// As [`Cnn::decode`].
    pub fn decode(manifest: &str, weights: &[u8]) -> Result<Self> {
        decode_neural("LSTM", manifest, weights, |m, c, vb| LstmNet::new(m, c.hidden, vb))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Var;

    #[allow(clippy::cast_precision_loss)]
    fn pattern(n: usize, a: usize, m: usize) -> Vec<f64> {
        (0..n).map(|i| ((i * a % m) as f64 - (m / 2) as f64) / m as f64).collect()
    }

    #[test]
    fn the_unfolded_convolution_is_conv1d_with_gradients_that_match_finite_differences() -> candle_core::Result<()> {
        let dev = Device::Cpu;
        let (b, c_in, c_out, l, k) = (2, 3, 4, 12, 5);
        let x0 = pattern(b * c_in * l, 37, 17);
        let w0 = pattern(c_out * c_in * k, 29, 13);
        let bias = Tensor::from_vec(pattern(c_out, 5, 7), c_out, &dev)?;
        let r = Tensor::from_vec(pattern(b * c_out * (l - k + 1), 11, 19), (b, c_out, l - k + 1), &dev)?;
        let conv = |w: &Tensor| Conv1d::new(w.clone(), Some(bias.clone()), Conv1dConfig::default());
        let loss = |x: &[f64], w: &[f64]| -> candle_core::Result<f64> {
            let x = Tensor::from_slice(x, (b, c_in, l), &dev)?;
            let w = Tensor::from_slice(w, (c_out, c_in, k), &dev)?;
            conv1d_unfolded(&conv(&w), &x)?.mul(&r)?.sum_all()?.to_scalar::<f64>()
        };
        let xv = Var::from_tensor(&Tensor::from_slice(&x0, (b, c_in, l), &dev)?)?;
        let wv = Var::from_tensor(&Tensor::from_slice(&w0, (c_out, c_in, k), &dev)?)?;
        let y = conv1d_unfolded(&conv(wv.as_tensor()), xv.as_tensor())?;
        let reference = conv(wv.as_tensor()).forward(xv.as_tensor())?;
        let diff = (&y - &reference)?.abs()?.max_all()?.to_scalar::<f64>()?;
        assert!(diff < 1e-12, "forward differs from conv1d by {diff}");
        let grads = y.mul(&r)?.sum_all()?.backward()?;
        let gw: Vec<f64> = grads.get(&wv).expect("kernel gradient").flatten_all()?.to_vec1()?;
        let gx: Vec<f64> = grads.get(&xv).expect("input gradient").flatten_all()?.to_vec1()?;
        // Each entry of `grad` against the central difference of the loss at `base` ± h there.
        let check = |what: &str, grad: &[f64], base: &[f64], loss_at: &dyn Fn(&[f64]) -> candle_core::Result<f64>| {
            let h = 1e-6;
            for (i, g) in grad.iter().enumerate() {
                let (mut up, mut down) = (base.to_vec(), base.to_vec());
                up[i] += h;
                down[i] -= h;
                let fd = (loss_at(&up)? - loss_at(&down)?) / (2.0 * h);
                assert!((fd - g).abs() < 1e-8, "{what} entry {i}: {g} against {fd}");
            }
            candle_core::Result::Ok(())
        };
        check("kernel", &gw, &w0, &|w| loss(&x0, w))?;
        check("input", &gx, &x0, &|x| loss(x, &w0))?;
        Ok(())
    }
}
